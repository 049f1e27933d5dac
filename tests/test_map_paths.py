"""Pedestrians, cyclists and trams on a real map's own ways (``[real_map]
pedestrians_per_minute``, ``path_cyclists_per_minute``, ``trams_per_minute``): the ways found
by their tags, chained where they continue one another, walked both ways; the routes in closed
form; and on the example crop the users on their ways while the motor traffic stays track for
track."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from fgloc.scenario import Lanelet
from fgloc.sim.config import SimConfig
from fgloc.sim.map_paths import is_cycle_way, is_pedestrian_way, is_rail, way_routes
from fgloc.sim.real_map import simulate_on_map
from fgloc.sim.traffic import ROUTE_DS, polyline_route

CROP = Path(__file__).parent / "data" / "lanelet2_example_crop.osm"


def _way(k: int, start: tuple[float, float], end: tuple[float, float], width: float = 2.0,
         **tags: str) -> Lanelet:
    """A straight lanelet from ``start`` to ``end`` (m, L), ``width`` m wide."""
    a, b = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
    d = (b - a) / np.linalg.norm(b - a)
    left = np.array([-d[1], d[0]]) * width / 2
    line = np.linspace(a, b, 5)
    pad = np.zeros((5, 1))
    return Lanelet(k, np.hstack([line + left, pad]), np.hstack([line - left, pad]),
                   {"type": "lanelet", **tags})


def test_polyline_route_of_a_line_and_an_arc() -> None:
    line = polyline_route(np.array([[0.0, 0.0], [3.0, 4.0]]))
    assert line.s[-1] == pytest.approx(5.0) and np.allclose(np.diff(line.s), ROUTE_DS)
    assert np.allclose(line.heading, np.arctan2(4.0, 3.0)) and np.allclose(line.kappa, 0.0)
    r = 12.0
    a = np.linspace(0.0, np.pi / 2, 400)
    arc = polyline_route(np.column_stack([r * np.cos(a), r * np.sin(a)]))
    assert arc.s[-1] == pytest.approx(r * np.pi / 2, abs=ROUTE_DS)
    assert np.allclose(arc.kappa[2:-2], 1.0 / r, rtol=0.01)      # left turn: positive
    assert np.allclose(np.hypot(*arc.xy.T), r, atol=1e-3)


def test_ways_are_found_by_subtype_and_participant_tags() -> None:
    assert is_pedestrian_way(_way(1, (0, 0), (5, 0), subtype="crosswalk"))
    assert is_pedestrian_way(_way(2, (0, 0), (5, 0), subtype="walkway"))
    shared = _way(3, (0, 0), (5, 0), subtype="road", **{"participant:pedestrian": "yes",
                                                         "participant:bicycle": "yes"})
    assert is_pedestrian_way(shared) and is_cycle_way(shared)
    assert is_cycle_way(_way(4, (0, 0), (5, 0), subtype="bicycle_lane"))
    assert is_rail(_way(9, (0, 0), (5, 0), subtype="rail"))
    assert not is_rail(_way(10, (0, 0), (5, 0), subtype="road"))
    for ll in (_way(5, (0, 0), (5, 0), subtype="road"), _way(6, (0, 0), (5, 0), subtype="rail"),
               _way(7, (0, 0), (5, 0), subtype="crosswalk", **{"participant:pedestrian": "no"})):
        assert not is_cycle_way(ll)
    assert not is_pedestrian_way(_way(8, (0, 0), (5, 0), subtype="bicycle_lane"))


def test_continuing_ways_chain_into_one_route_each_way() -> None:
    a = _way(1, (0, 0), (10, 0), subtype="walkway")
    b = _way(2, (10.5, 0.2), (20, 3), subtype="walkway")       # continues a: 0.54 m gap
    c = _way(3, (10, 0), (10, 8), subtype="walkway")            # turns off a by 90 deg
    routes = way_routes([a, b, c], both_ways=True)
    lengths = sorted(round(r.s[-1]) for r in routes)
    chained = 10.0 + np.hypot(0.5, 0.2) + np.hypot(9.5, 2.8)
    assert lengths == sorted([round(chained)] * 2 + [8] * 2)
    forward = next(r for r in routes if np.allclose(r.xy[0], (0.0, 0.0), atol=0.01))
    assert np.allclose(forward.xy[-1], (20.0, 3.0), atol=ROUTE_DS)
    # a cycle way tagged one_way=yes is ridden only its own way
    one_way = _way(4, (0, 0), (10, 0), subtype="bicycle_lane", one_way="yes")
    two_way = _way(5, (0, 5), (10, 5), subtype="bicycle_lane", one_way="no")
    starts = [tuple(np.round(r.xy[0])) for r in way_routes([one_way, two_way], both_ways=False)]
    assert sorted(starts) == [(0.0, 0.0), (0.0, 5.0), (10.0, 5.0)]


def _distance_to(lines: list[np.ndarray], xy: np.ndarray) -> np.ndarray:
    """Distance (m) of each point ``xy`` (N, 2) to the nearest of the polylines ``lines``
    (each densified 20-fold)."""
    dense = np.vstack([np.column_stack([np.interp(np.linspace(0, len(c) - 1, 20 * len(c)),
                                                  np.arange(len(c)), c[:, k]) for k in (0, 1)])
                       for c in lines])
    return cKDTree(dense).query(xy)[0]


def test_users_walk_and_ride_the_crops_ways_and_motor_traffic_stays() -> None:
    base = simulate_on_map(CROP, 3, duration=20.0, crop_radius=150.0)
    cfg = SimConfig()
    cfg.real_map.pedestrians_per_minute = 30.0
    cfg.real_map.path_cyclists_per_minute = 30.0
    cfg.real_map.trams_per_minute = 6.0
    sim = simulate_on_map(CROP, 3, duration=20.0, crop_radius=150.0, config=cfg)
    kinds = np.array(sim.result.vehicle_class)
    tracks = sim.result.scenario.truth.tracks
    motor = [t for t, k in zip(tracks, kinds) if k in ("car", "van", "truck")]
    assert len(motor) == len(base.result.scenario.truth.tracks)
    for a, b in zip(motor, base.result.scenario.truth.tracks):
        assert np.array_equal(a.states, b.states) and a.length == b.length
    ignored = sim.result.scenario.lanelets.ignored
    for kind, is_way, speeds, least in (("pedestrian", is_pedestrian_way, (1.0, 1.6), 3),
                                        ("bicycle", is_cycle_way, (1.0, 7.0), 3),
                                        ("tram", is_rail, (1.0, 12.0), 1)):
        users = [t for t, k in zip(tracks, kinds) if k == kind]
        assert len(users) >= least, kind
        lines = [ll.centerline(40) for ll in ignored if is_way(ll)]
        others = [ll.centerline(40) for ll in sim.result.scenario.lanelets.lanelets]
        for t in users:
            xy = t.states[:, 1:3]
            assert _distance_to(lines, xy).max() < 0.3, kind        # on its ways
            if kind == "bicycle":                                      # beside the road
                assert np.median(_distance_to(others, xy)) > 0.5
            v = t.states[:, 4]
            assert speeds[0] - 1e-9 <= v.min() and v.max() <= speeds[1] + 1e-9
        size = np.array([(t.length, t.width) for t in users])
        if kind == "tram":
            assert np.all(np.abs(size - (35.0, 2.65)) < (8.0, 0.2))
        else:
            assert np.all(size < 2.2) and np.all(size[:, 1] < 0.8)
    # the radar sees them
    for kind in ("pedestrian", "bicycle", "tram"):
        assert np.isin(sim.result.source, np.flatnonzero(kinds == kind)).any(), kind


def test_user_rates_are_validated() -> None:
    from fgloc.sim.config import RealMapSimConfig

    with pytest.raises(ValueError, match="pedestrians_per_minute"):
        RealMapSimConfig(pedestrians_per_minute=-1.0)
    with pytest.raises(ValueError, match="pedestrian_speed"):
        RealMapSimConfig(pedestrian_speed=(1.5, 1.0))
    with pytest.raises(ValueError, match="tram_speed"):
        RealMapSimConfig(tram_speed=(0.0, 10.0))


def test_cli_simulate_map_counts_the_road_users(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    from fgloc.cli import main

    toml = tmp_path / "sim.toml"
    toml.write_text("[real_map]\npedestrians_per_minute = 30.0\npath_cyclists_per_minute = 30.0\n"
                    "trams_per_minute = 6.0\n")
    assert main(["simulate", "--map", str(CROP), "--seed", "3", "--duration", "5",
                 "--sim-config", str(toml), "--out", str(tmp_path / "scn")]) == 0
    m = re.search(r"(\d+) road users: (\d+) motor vehicles, (\d+) pedestrians, (\d+) cyclists, "
                  r"(\d+) trams", capsys.readouterr().out)
    assert m and int(m[1]) == sum(int(m[k]) for k in (2, 3, 4, 5)) and min(
        int(m[k]) for k in (2, 3, 4, 5)) > 0
    toml.write_text("[real_map]\npedestrian_speed = [2.0, 1.0]\n")
    assert main(["simulate", "--map", str(CROP), "--sim-config", str(toml),
                 "--out", str(tmp_path / "bad")]) == 2
    assert "pedestrian_speed" in capsys.readouterr().err
