"""Traffic on two-way streets of a real Lanelet2 map (one lanelet, ``one_way`` = no).

The routing graph per driving direction (lanelet2's inverted lanelets), the simulator's
directed lanelets, junctions and routes through two-way lanelets both ways, and where the
simulated vehicles drive there (``[real_map] two_way_traffic``: "keep-right" or "centre"),
checked against the map's geometry. Uses a crop of the official Lanelet2 example map around a
junction of two-way streets (tests/data/lanelet2_example_twoway_crop.osm, BSD-3-Clause,
copyright 2018 FZI, see tests/data/LICENSE-lanelet2_mapping_example).
"""

from __future__ import annotations

from pathlib import Path

import lanelet2
import numpy as np
import pytest
from lanelet2.io import Origin
from lanelet2.projection import UtmProjector
from scipy.spatial import cKDTree
from test_sim_settings import check_stands

from fgloc.config import MapConfig
from fgloc.errors import InputError
from fgloc.geo import LocalFrame, transformer
from fgloc.io.lanelet_map import read_lanelet_map
from fgloc.map import map_labels, points_in_polygon
from fgloc.scenario import Lanelet, LaneletMap, MapSettings, resample_polyline
from fgloc.sim.config import SimConfig
from fgloc.sim.real_map import simulate_on_map
from fgloc.sim.real_roads import directed_lanelets, find_junctions, junction_routes

DATA = Path(__file__).parent / "data"
TWO_WAY_CROP = DATA / "lanelet2_example_twoway_crop.osm"
ONE_WAY_CROP = DATA / "lanelet2_example_crop.osm"   # no two-way lanelet
CRS = "EPSG:25832"
SITE = (49.01089, 8.42329)


def frame_at(site: tuple[float, float]) -> LocalFrame:
    e, n = transformer("EPSG:4326", CRS).transform(site[1], site[0])
    return LocalFrame.around(e, n, 0.0, CRS)


@pytest.fixture(scope="module")
def two_way_map() -> LaneletMap:
    return read_lanelet_map(TWO_WAY_CROP, CRS, frame_at(SITE))


def lanelet2_following(path: Path) -> dict[tuple[int, bool], set[tuple[int, bool]]]:
    """The reference, straight from lanelet2 (Germany, vehicle): the followers of every
    drivable lanelet and of its inverted lanelet where the rules let a vehicle drive it so."""
    lmap = lanelet2.io.load(str(path), UtmProjector(Origin(*SITE)))
    rules = lanelet2.traffic_rules.create("de", "vehicle")
    graph = lanelet2.routing.RoutingGraph(lmap, rules)
    out = {}
    for ll in lmap.laneletLayer:
        if not rules.canPass(ll):
            continue
        for d in (ll, ll.invert()):
            got = {(f.id, f.inverted()) for f in graph.following(d)}
            if got:
                out[(ll.id, d.inverted())] = got
    return out


# --------------------------------------------------------------------------------------------
# routing graph per driving direction
# --------------------------------------------------------------------------------------------
def test_directed_routing_is_lanelet2s_and_successors_keep_their_meaning(
        two_way_map: LaneletMap) -> None:
    ref = lanelet2_following(TWO_WAY_CROP)
    got = {k: set(v) for k, v in two_way_map.directed_successors.items()}
    assert got == ref
    two_way = {ll.id for ll in two_way_map.lanelets if ll.two_way}
    assert len(two_way) >= 10
    # inverted lanelets lead on to inverted ones and out of the street in the lanelets' way
    assert sum(k[1] for k in got) >= 10
    assert any(a[1] and b[1] for a, v in got.items() for b in v)
    assert any(a[1] and not b[1] for a, v in got.items() for b in v)
    assert {k[0] for k in got if k[1]} <= two_way
    # successors (routing labels, the lane models) stay the graph in the lanelets' direction
    forward = {a[0]: {b[0] for b in v if not b[1]} for a, v in ref.items() if not a[1]}
    assert {k: set(v) for k, v in two_way_map.successors.items()} == {
        k: v for k, v in forward.items() if v}
    # maps read without lanelet2's rules: bound-node adjacency, two-way lanelets both ways
    tags = read_lanelet_map(TWO_WAY_CROP, CRS, frame_at(SITE),
                            settings=MapSettings(location="xx"))
    assert tags.directed_successors == two_way_map.directed_successors
    assert tags.successors == two_way_map.successors


def test_one_way_map_routes_as_before() -> None:
    """On a crop without two-way lanelets the directed graph is the forward one and the
    directed lanelets are the map's own."""
    lmap = read_lanelet_map(ONE_WAY_CROP, CRS, frame_at((49.00519, 8.415632)))
    assert not any(k[1] for k in lmap.directed_successors)
    assert {k[0]: tuple(i for i, _ in v) for k, v in lmap.directed_successors.items()} \
        == lmap.successors
    view = directed_lanelets(lmap)
    assert view.map.successors == lmap.successors
    assert [ll.id for ll in view.map.lanelets] == [ll.id for ll in lmap.lanelets]


def test_directed_lanelets_invert_two_way_lanelets(two_way_map: LaneletMap) -> None:
    view = directed_lanelets(two_way_map)
    by_id = {ll.id: ll for ll in two_way_map.lanelets}
    inverted = {i: src for i, (src, inv) in view.source.items() if inv}
    graph = two_way_map.directed_successors
    assert set(inverted.values()) == {i for i, inv in (*graph, *(x for v in graph.values()
                                                                   for x in v)) if inv}
    assert min(inverted) > max(abs(i) for i in by_id)
    for ll in view.map.lanelets:
        src, inv = view.source[ll.id]
        orig = by_id[src]
        if not inv:
            assert ll is orig
            continue
        # the right half of the inverted direction is the lanelet's left half, driven backwards
        np.testing.assert_allclose(ll.line_at(0.25, 20), orig.line_at(0.75, 20)[::-1])
        np.testing.assert_allclose(ll.centerline(20), orig.centerline(20)[::-1])
        assert ll.attributes == orig.attributes
    for a, succ in view.map.successors.items():
        assert {view.source[b] for b in succ} == set(
            two_way_map.directed_successors[view.source[a]])
    # a map built in memory (no directed graph) is driven in the lanelets' direction
    mem = LaneletMap(two_way_map.lanelets, successors=two_way_map.successors)
    assert directed_lanelets(mem).map.successors == two_way_map.successors


def test_routing_labels_unchanged_by_the_directed_graph(two_way_map: LaneletMap) -> None:
    """The labels read the forward graph only: the same without the directed graph."""
    bare = LaneletMap(two_way_map.lanelets, successors=two_way_map.successors)
    assert map_labels(two_way_map, MapConfig()) == map_labels(bare, MapConfig())
    assert "routing" in map_labels(two_way_map, MapConfig()).source.values()


def test_junction_routes_run_both_ways_through_two_way_streets(
        two_way_map: LaneletMap) -> None:
    view = directed_lanelets(two_way_map)
    junctions = find_junctions(view.map)
    assert junctions
    junction = min(junctions, key=lambda j: float(np.linalg.norm(j.centre)))
    assert float(np.linalg.norm(junction.centre)) < 30.0
    routes = junction_routes(view.map, junction, 150.0)
    directions = [[view.source[i] for i in r] for r in routes]
    # movements into or out of a two-way street against its direction, and with it
    assert any(inv for r in directions for _, inv in r)
    assert any(not any(inv for _, inv in r) for r in directions)
    two_way = {ll.id for ll in two_way_map.lanelets if ll.two_way}
    both = {i for r in directions for i, inv in r if inv} & {
        i for r in directions for i, inv in r if not inv}
    assert len(both & two_way) >= 3
    # every route is connected along the directed graph
    for r in directions:
        for a, b in zip(r, r[1:]):
            assert b in two_way_map.directed_successors[a]


# --------------------------------------------------------------------------------------------
# where vehicles drive
# --------------------------------------------------------------------------------------------
def _distance(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Distance (m) of points (n, 2) to a polyline sampled every ~2 cm."""
    length = float(np.linalg.norm(np.diff(line, axis=0), axis=1).sum())
    dense = resample_polyline(line, max(2, int(length / 0.02) + 1))
    return cKDTree(dense).query(points)[0]


def _on_two_way(lanelets: list[Lanelet], tracks) -> list[tuple[Lanelet, bool, np.ndarray]]:
    """(two-way lanelet >= 5 m wide, against its direction, true centres (n, 2)) of the truth
    states driving along it (heading within 20 deg of its centre line's either way) at least
    5 m from its ends."""
    out = []
    for ll in lanelets:
        if not ll.two_way or ll.width() < 5.0:
            continue
        c = ll.centerline(ll.samples(0.5))
        tangent = np.diff(c, axis=0)
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(tangent, axis=1))])
        tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
        tree = cKDTree(0.5 * (c[1:] + c[:-1]))
        for tr in tracks:
            xy, yaw = tr.states[:, 1:3], tr.states[:, 3]
            inside = points_in_polygon(xy, ll.polygon())
            if not inside.any():
                continue
            k = tree.query(xy[inside])[1]
            cos = np.cos(yaw[inside]) * tangent[k, 0] + np.sin(yaw[inside]) * tangent[k, 1]
            mid = (s[k] > 5.0) & (s[k + 1] < s[-1] - 5.0)
            for back, along in ((False, cos > np.cos(np.radians(20))),
                                (True, cos < -np.cos(np.radians(20)))):
                if (along & mid).any():
                    out.append((ll, back, xy[inside][along & mid]))
    return out


@pytest.mark.parametrize("traffic", ["keep-right", "centre"])
def test_vehicles_drive_two_way_streets_both_ways_where_the_setting_says(traffic: str) -> None:
    """The truth on a two-way street (>= 5 m wide) lies on the lane of the setting: with
    "centre" the lanelet's centre line in both directions, with "keep-right" the centre of the
    right half of the driving direction (the left half for vehicles driving against the
    lanelet); the other setting's lane is 1.5-2 m away."""
    cfg = SimConfig()
    cfg.real_map.two_way_traffic = traffic
    sim = simulate_on_map(TWO_WAY_CROP, 2, duration=30.0, config=cfg, crop_radius=150.0)
    runs = _on_two_way(sim.scenario.lanelets.lanelets, sim.scenario.truth.tracks)
    both = {ll.id for ll, back, _ in runs if back} & {ll.id for ll, back, _ in runs if not back}
    assert len(both) >= 2, "no two-way lanelet driven both ways"
    on, off = [], []
    for ll, back, xy in runs:
        n = ll.samples(0.5)
        right_half = ll.line_at(0.75, n) if back else ll.line_at(0.25, n)
        lane, other = ((right_half, ll.centerline(n)) if traffic == "keep-right"
                       else (ll.centerline(n), right_half))
        on.append(_distance(xy, lane))
        off.append(_distance(xy, other))
    on_all, off_all = np.concatenate(on), np.concatenate(off)
    assert len(on_all) >= 100
    # measured (seeds 1-3, 20-30 s, both settings): 95th percentile 0.12-0.23 m, worst
    # 0.13-0.31 m (route smoothing at the lanelets' kinks, the path follower)
    assert np.percentile(on_all, 95) < 0.3 and on_all.max() < 0.4
    assert np.median(off_all) > 1.2


def test_two_way_traffic_setting_is_validated(tmp_path: Path) -> None:
    from fgloc.cli import main
    from fgloc.config import from_dict

    assert from_dict(SimConfig, {"real_map": {"two_way_traffic": "centre"}}, "x.toml") \
        .real_map.two_way_traffic == "centre"
    with pytest.raises(InputError, match="two_way_traffic"):
        from_dict(SimConfig, {"real_map": {"two_way_traffic": "left"}}, "x.toml")
    good, bad = tmp_path / "good.toml", tmp_path / "bad.toml"
    good.write_text('[real_map]\ntwo_way_traffic = "centre"\n')
    bad.write_text('[real_map]\ntwo_way_traffic = "middle"\n')
    args = ["simulate", "--map", str(TWO_WAY_CROP), "--seed", "1", "--duration", "2"]
    assert main([*args, "--sim-config", str(good), "--out", str(tmp_path / "a")]) == 0
    assert main([*args, "--sim-config", str(bad), "--out", str(tmp_path / "b")]) == 2


def test_bench_table_has_a_row_group_per_traffic_kind() -> None:
    """bench/real_map.py's table: per traffic kind and labels mode, each junction's and all
    runs' mean and worst, the height error's signed mean and largest magnitude and the
    ambiguous runs (known rows in, their statistics out)."""
    from bench.real_map import METHODS, errors_of, table

    sites = [(49.0, 8.4), (49.1, 8.5)]
    rows = [{"traffic": kind, "labels": "routing", "junction": k + 1, "method": m, "seed": seed,
             "d2d": d2d, "dyaw_deg": dyaw, "dz": dz, "status": status}
            for kind, scale in (("keep-right", 1.0), ("centre", 10.0))
            for k in range(2) for m in METHODS
            for seed, d2d, dyaw, dz, status in (
                (1, 0.1 * (k + 1) * scale, 0.01, -0.2, "resolved"),
                (2, 0.3 * scale, 0.05, 0.1 * (k + 1),
                 "ambiguous" if kind == "centre" else "resolved"))]
    lines = table(sites, [1, 2], ["routing"], errors_of(rows)).splitlines()
    assert len(lines) == 2 + 2 * 3 * len(METHODS)
    cells = [[c.strip() for c in r.strip("|").split("|")] for r in lines[2:]]
    assert [c[0] for c in cells] == ["keep-right"] * 12 + ["centre"] * 12
    first = {(c[0], c[1], c[3]): [float(v) for v in c[4:10]] + [c[10]] for c in cells}
    assert first[("keep-right", "2 (49.10000, 8.50000)", "icp")] == [0.25, 0.3, 0.03, 0.05,
                                                                      0.0, 0.2, "0/2"]
    assert first[("keep-right", "1 (49.00000, 8.40000)", "icp")][4:6] == [-0.05, 0.2]
    assert first[("centre", "all 2 x 2 runs", "joint")] == pytest.approx(
        [(1.0 + 2.0 + 3.0 + 3.0) / 4, 3.0, 0.03, 0.05, (-0.4 + 0.3) / 4, 0.2, "2/4"])


def test_bench_traffic_kinds_set_the_simulator(monkeypatch: pytest.MonkeyPatch) -> None:
    """bench/real_map.py's traffic kinds are valid ``[real_map]`` settings of the simulator,
    and its scenario is simulated with them (keep-right-mapped: keep-right on the lane lines
    as mapped, no path smoothing; centre-lanelet2: lanelet2's centre lines as mapped; the
    other kinds on the default smoothed paths)."""
    import bench.real_map as rm
    from fgloc.sim.config import RealMapSimConfig

    configs = []

    class Simulated:
        scenario = None

    def fake(map_path, seed, *, site, duration, config):
        configs.append(config.real_map)
        return Simulated()

    monkeypatch.setattr(rm, "simulate_on_map", fake)
    default = RealMapSimConfig()
    for kind, settings in rm.TRAFFIC.items():
        RealMapSimConfig(**settings)                       # raises on an invalid value
        rm.scenario(Path("map.osm"), kind, (49.0, 8.4), 1, 1.0)
        got = configs[-1]
        assert {k: getattr(got, k) for k in settings} == settings
        assert got.path_smoothing == settings.get("path_smoothing", default.path_smoothing)
    assert rm.TRAFFIC["keep-right-mapped"] == {"two_way_traffic": "keep-right",
                                                "path_smoothing": "none"}
    assert configs[list(rm.TRAFFIC).index("centre-lanelet2")].centre_line == "lanelet2"
    assert default.centre_line == "resampled"
    assert default.path_smoothing != "none"


# --------------------------------------------------------------------------------------------
# [real_map] centre_line: lanelet2's centre lines
# --------------------------------------------------------------------------------------------
def _lanelet2_reference_lines(path: Path) -> dict[tuple[int, bool], np.ndarray]:
    """lanelet2's own ``centerline`` of every lanelet of the map file and of its inverted
    lanelet, each relative to its first point (the frames differ by a translation)."""
    lmap = lanelet2.io.load(str(path), UtmProjector(Origin(*SITE)))
    out = {}
    for ll in lmap.laneletLayer:
        for d in (ll, ll.invert()):
            c = np.array([[p.x, p.y] for p in d.centerline])
            out[(ll.id, d.inverted())] = c - c[0]
    return out


def test_lanelet2_centre_lines_are_lanelet2s(two_way_map: LaneletMap) -> None:
    """Built from fgloc's lanelets, the lines are those lanelet2 computes from the file, for
    inverted lanelets too (its centre line reversed, not the centre line of the swapped
    bounds), and they differ from fgloc's resampled centre lines on some lanelets."""
    from fgloc.sim.real_roads import lanelet2_centre_lines

    view = directed_lanelets(two_way_map)
    lines = lanelet2_centre_lines(view)
    ref = _lanelet2_reference_lines(TWO_WAY_CROP)
    assert set(lines) == {ll.id for ll in view.map.lanelets}
    assert any(inv for _, inv in view.source.values())
    by_id = {ll.id: ll for ll in view.map.lanelets}
    apart = []
    for lid, line in lines.items():
        want = ref[view.source[lid]]
        assert line.shape == want.shape
        np.testing.assert_allclose(line - line[0], want, atol=0.01)
        ours = by_id[lid].centerline(200)
        apart.append(_distance(resample_polyline(line, 200), ours).max())
    # measured on this crop: up to about 1 m apart on turns drawn with few nodes
    assert max(apart) > 0.3


@pytest.mark.parametrize("centre_line", ["lanelet2", "resampled"])
def test_vehicles_drive_the_centre_lines_the_setting_says(centre_line: str) -> None:
    """``centre_line``: the truth lies on lanelet2's centre lines ("lanelet2") or on fgloc's
    resampled ones ("resampled"; both directions on the centre line, kinks at the joins
    turned within 1 m, path_smoothing "none"); the other kind of line is farther away."""
    from fgloc.sim.real_roads import lanelet2_centre_lines

    cfg = SimConfig()
    cfg.real_map.two_way_traffic = "centre"
    cfg.real_map.path_smoothing = "none"
    cfg.real_map.centre_line = centre_line
    sim = simulate_on_map(TWO_WAY_CROP, 1, duration=30.0, config=cfg, crop_radius=150.0)
    lmap = sim.scenario.lanelets
    view = directed_lanelets(lmap)
    resampled = np.vstack([ll.centerline(ll.samples(0.25)) for ll in view.map.lanelets])
    l2 = np.vstack([resample_polyline(c, 200) for c in lanelet2_centre_lines(view).values()])
    own, other = (l2, resampled) if centre_line == "lanelet2" else (resampled, l2)
    xy = np.vstack([np.asarray(tr.states)[:, 1:3] for tr in sim.scenario.truth.tracks])
    inside = np.zeros(len(xy), bool)
    for ll in lmap.lanelets:
        inside |= points_in_polygon(xy, ll.polygon())
    d_own, d_other = _distance(xy[inside], own), _distance(xy[inside], other)
    assert len(d_own) >= 500
    # measured (seed 1, 30 s): 99th percentile 0.30 m (lanelet2) / 0.26 m (resampled) from
    # the own lines, 0.62 / 0.69 m from the other ones (turns drawn with few nodes)
    own99, other99 = np.percentile(d_own, 99), np.percentile(d_other, 99)
    assert own99 < 0.4 and other99 > 0.5 and other99 > 1.5 * own99


def test_centre_line_setting_is_validated() -> None:
    from fgloc.config import from_dict

    assert SimConfig().real_map.centre_line == "resampled"
    assert from_dict(SimConfig, {"real_map": {"centre_line": "lanelet2"}}, "x.toml") \
        .real_map.centre_line == "lanelet2"
    with pytest.raises(InputError, match="centre_line"):
        from_dict(SimConfig, {"real_map": {"centre_line": "spline"}}, "x.toml")


def test_vehicles_stop_and_queue_on_a_real_map() -> None:
    """``[traffic] stop_share`` on a real map (routes along the routing graph, two-way
    streets): vehicles stand short of their first crossing, still, their returns static, and
    queue behind one another (:func:`test_sim_settings.check_stands`). The centre-line
    conflict model keeps paths within 3.2 m apart; a long vehicle's corners in a turn can
    reach farther (seed 2 here: an 11.5 m truck and a car touch for 0.2 s), so overlaps are
    not checked on this map."""
    cfg = SimConfig()
    cfg.traffic.stop_share, cfg.traffic.stop_time = 0.6, (4.0, 8.0)
    stands = queued = static = 0
    for seed in (1, 2, 3):
        sim = simulate_on_map(TWO_WAY_CROP, seed, duration=30.0, config=cfg, crop_radius=150.0)
        n, q, doppler = check_stands(sim.result, cfg.traffic, cfg.radar.sigma_doppler)
        stands, queued, static = stands + n, queued + q, static + len(doppler)
    assert stands >= 6 and queued >= 1 and static > 500
