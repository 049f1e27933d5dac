"""bench/independent_gen.py, the scenario generator written without fgloc's code: it imports
nothing of the project, and what it writes fgloc reads as a scenario whose ground truth holds
together (vehicles on drivable lanelets, radar points on the true vehicles).

Uses a crop of the Lanelet2 example map (tests/data/lanelet2_example_crop.osm, BSD-3-Clause,
copyright 2018 FZI, see tests/data/LICENSE-lanelet2_mapping_example) around its junction 3.
"""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest
from matplotlib.path import Path as Polygon

from bench.independent_gen import (
    CONFLICT_BOX,
    BoxSamples,
    Driver,
    Returns,
    Route,
    Sensor,
    Terrain,
    Vehicle,
    Walls,
    _obstacle,
    conflict_zones,
    crossing_spans,
    generate,
    ghost_returns,
    occluded,
)
from fgloc.io import load_scenario
from fgloc.scenario import Scenario
from fgloc.sim.scenery import box_corners

ROOT = Path(__file__).resolve().parent.parent
GENERATOR = ROOT / "bench" / "independent_gen.py"
DATA = Path(__file__).parent / "data"
CROP = DATA / "lanelet2_example_crop.osm"
#: junction 3 of the example map (lat, lon), inside the crop
JUNCTION_3 = (49.00519, 8.41563)


def imported_modules(path: Path) -> set[str]:
    """Every module an ``import`` / ``from ... import`` anywhere in ``path`` names."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            out.add("." * node.level + (node.module or ""))
    return out


def test_generator_imports_nothing_of_the_project():
    modules = imported_modules(GENERATOR)
    assert {"numpy", "lanelet2", "laspy", "pyproj"} <= modules  # the parse found its imports
    tops = {m.split(".")[0] for m in modules}
    assert not tops & {"fgloc", "factors", "bench"}, sorted(modules)
    assert not any(m.startswith(".") for m in modules), sorted(modules)


@pytest.fixture(scope="module")
def scenario(tmp_path_factory) -> Scenario:
    out = generate(CROP, JUNCTION_3, 1, tmp_path_factory.mktemp("independent") / "j3",
                   vehicles_per_minute=30.0, duration=10.0)
    assert (out / "LICENSE-lanelet2_mapping_example").read_text() == (
        DATA / "LICENSE-lanelet2_mapping_example").read_text()
    return load_scenario(out)


def test_truth_vehicles_drive_on_drivable_lanelets(scenario):
    assert scenario.truth is not None and len(scenario.truth.tracks) >= 5
    states = np.concatenate([tr.states for tr in scenario.truth.tracks])
    inside = np.zeros(len(states), bool)
    for ll in scenario.lanelets.lanelets:
        inside |= Polygon(ll.polygon()).contains_points(states[:, 1:3])
    assert inside.mean() >= 0.95


def footprint_distance(p: np.ndarray, state: np.ndarray, length: float, width: float
                       ) -> np.ndarray:
    """(n,) distance (m) in the plane of the points ``p`` (n, 2) to the footprint of a box
    ``length`` x ``width`` at the states (n, >= 4: t, x, y, yaw); 0 inside."""
    c, s = np.cos(state[:, 3]), np.sin(state[:, 3])
    dx, dy = p[:, 0] - state[:, 1], p[:, 1] - state[:, 2]
    along, across = c * dx + s * dy, -s * dx + c * dy
    return np.hypot(np.maximum(np.abs(along) - length / 2, 0.0),
                    np.maximum(np.abs(across) - width / 2, 0.0))


def nearest_vehicle(scn: Scenario, rows: np.ndarray) -> np.ndarray:
    """(n,) distance (m) in the plane of the radar detections ``rows`` (index or mask into
    ``scn.radar``), placed in L with the true pose, to the nearest true vehicle's footprint at
    their frame's time (the state stamped with the same t); inf where no vehicle is."""
    radar, truth = scn.radar, scn.truth
    T = truth.sensor_pose
    p = radar.xyz[rows] @ T[:3, :3].T + T[:3, 3]
    t = radar.t[rows]
    nearest = np.full(len(t), np.inf)
    for tr in truth.tracks:
        k = np.clip(np.searchsorted(tr.states[:, 0], t - 1e-6), 0, len(tr.states) - 1)
        same_time = np.abs(tr.states[k, 0] - t) < 1e-3
        d = footprint_distance(p[:, :2], tr.states[k], tr.length, tr.width)
        nearest = np.minimum(nearest, np.where(same_time, d, np.inf))
    return nearest


def test_moving_radar_points_lie_on_true_vehicles(scenario):
    """The detections with |Doppler| >= 0.5 m/s (the static clutter's Doppler noise is
    0.05 m/s), placed in L with the true pose, lie within 1 m of a true vehicle's footprint at
    their frame's time (the state stamped with the same t)."""
    radar = scenario.radar
    nearest = nearest_vehicle(scenario, np.arange(len(radar)))
    moving = np.abs(radar.doppler) >= 0.5
    assert moving.mean() >= 0.5
    assert np.mean(nearest[moving] <= 1.0) >= 0.95


def boxes_overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether the convex quadrilaterals ``a`` and ``b`` (4, 2) overlap (no separating axis
    among their edges' normals)."""
    for poly in (a, b):
        for e in np.diff(np.vstack([poly, poly[:1]]), axis=0):
            axis = np.array([-e[1], e[0]])
            pa, pb = a @ axis, b @ axis
            if pa.max() < pb.min() or pb.max() < pa.min():
                return False
    return True


def test_true_vehicles_do_not_drive_through_each_other(tmp_path):
    """Vehicles on routes that share a lane or cross see each other (follow, yield, wait
    before a crossing): on the crop at 30 vehicles a minute (seed 5, 10 s) no two true boxes
    overlap in any frame; the generator before, which kept vehicles apart on one route only,
    had them overlap in 41 frames there."""
    scn = load_scenario(generate(CROP, JUNCTION_3, 5, tmp_path / "busy", vehicles_per_minute=30.0,
                                 duration=10.0))
    tracks, pairs = scn.truth.tracks, 0
    for i, a in enumerate(tracks):
        for b in tracks[i + 1:]:
            ka, kb = np.nonzero(np.abs(a.states[:, None, 0] - b.states[None, :, 0]) < 1e-3)
            near = np.hypot(*(a.states[ka, 1:3] - b.states[kb, 1:3]).T) < 20.0
            for x, y in zip(a.states[ka[near]], b.states[kb[near]]):
                pairs += 1
                assert not boxes_overlap(box_corners(x[1:3], x[3], a.length, a.width),
                                         box_corners(y[1:3], y[3], b.length, b.width)), (
                    a.id, b.id, x[0])
    assert pairs > 100                       # vehicles came within 20 m of each other
    assert any((tr.states[:, 4] < 0.1).any() for tr in tracks)   # some waited


def test_a_vehicle_hides_the_returns_behind_it_below_its_roof():
    """Closed form: the sensor 6 m over flat ground at the origin, a truck (10 x 2.5 x 3.5 m,
    id 1) centred 10 m out on the x axis in frame 0. A return 0.3 m high at (19, 0) sees
    the truck's far end at x = 15 at 6 - 5.7 x 15/19 = 1.5 m: hidden. At (19, 3) the sight line
    leaves the truck's side (y = 1.25) at x = 7.9, 3.63 m high: seen over it. At (19, 5) it
    passes beside the truck, a roof return 1.5 m high at (60, 0) passes over it (4.9 m at
    x = 15); the truck's own return and a return of frame 1 (no truck there) are not hidden."""
    truck = Vehicle(1, "truck", 10.0, 2.5, 3.5, 0, np.array([[0, 10.0, 0, 0, 0, 0]]),
                    np.array([0]))
    sensor = Sensor(np.array([0.0, 0.0, 6.0]), 0.0, 10.0, 0.0, 6.0)
    flat = Terrain(np.zeros(2), 0.0, np.zeros(2))
    p_w = np.array([[19, 0, 0.3], [19, 3, 0.3], [19, 5, 0.3], [60, 0, 1.5], [14, 0, 1.0],
                    [19, 0, 0.3]])
    n = len(p_w)
    ret = Returns(np.array([0, 0, 0, 0, 0, 1]), p_w, np.zeros(n), np.zeros(n),
                  np.array([2, 2, 2, 2, 1, 2]), np.zeros(n, bool), np.zeros(n))
    hidden = occluded(ret, BoxSamples.of([truck]), sensor, flat)
    assert hidden.tolist() == [True, False, False, False, False, False]
    # the truck turned across the axis (10 m wide now): all three sight lines to (19, y)
    # leave it at x = 11.25, 2.6 m high, hidden; the roof return's at 5.2 m still passes
    truck.states[0, 3] = np.pi / 2
    assert occluded(ret, BoxSamples.of([truck]), sensor, flat).tolist() == [
        True, True, True, False, False, False]


def test_a_facade_mirrors_a_vehicle_return_into_a_ghost_moving_mirrored(monkeypatch):
    """Closed form: a facade along y = -10 from x = 0 to 100 (8 m high), the sensor 6 m over
    the origin. A return at (50, 0, 1) of a vehicle driving (10, 2) m/s appears at its mirror
    image (50, -20, 1), moving (10, -2), its Doppler that velocity along the sight line. No
    ghost of a return behind the facade (y = -15), nor of one whose image is seen past the
    facade's end (at (250, 0) the sight line meets y = -10 at x = 125)."""
    monkeypatch.setattr("bench.independent_gen.GHOST_PROB", 1.0)
    v = np.array([10.0, 2.0])
    states = np.array([[0, 50, 0, np.arctan2(v[1], v[0]), np.hypot(*v), 0],
                       [0, 50, -15, 0, 10, 0], [0, 250, 0, 0, 10, 0]])
    boxes = BoxSamples(np.zeros(3, int), np.array([1, 2, 3]), states,
                       np.tile([4.5, 1.8, 1.5], (3, 1)))
    p_w = np.array([[50.0, 0, 1], [50, -15, 1], [250, 0, 1]])
    vret = Returns(np.zeros(3, int), p_w, np.zeros(3), np.zeros(3), np.array([1, 2, 3]),
                   np.zeros(3, bool), np.zeros(3))
    sensor = Sensor(np.array([0.0, 0.0, 6.0]), 0.0, 10.0, 0.0, 6.0)
    walls = Walls(np.array([[0.0, -10]]), np.array([[1.0, 0]]), np.array([100.0]),
                  np.array([8.0]))
    g = ghost_returns(vret, boxes, walls, sensor, Terrain(np.zeros(2), 0.0, np.zeros(2)),
                      np.random.default_rng(0))
    assert len(g.frame) == 1
    np.testing.assert_allclose(g.p_w[0], [50, -20, 1])
    ray = (g.p_w[0] - sensor.position) / np.linalg.norm(g.p_w[0] - sensor.position)
    assert g.doppler_true[0] == pytest.approx(10 * ray[0] - 2 * ray[1])


def straight_route(start: tuple[float, float], heading_deg: float, length: float = 100.0
                   ) -> Route:
    """A straight route of ``length`` m from ``start`` (m) at ``heading_deg``, 0.2 m steps."""
    s = np.arange(0.0, length + 1e-9, 0.2)
    h = np.radians(heading_deg)
    xy = np.asarray(start) + s[:, None] * [np.cos(h), np.sin(h)]
    return Route([], xy, s, np.full(len(s), h), np.zeros(len(s)))


def test_conflict_zones_of_a_crossing_a_shared_road_and_adjacent_lanes():
    """Closed form: a road crossed at right angles conflicts where the paths are closer than
    half the conflict box's length and width apart (3.85 m each side of the crossing), a
    crossing; a route with itself is one shared stretch; a parallel lane 3.5 m beside it and
    the oncoming direction on it do not conflict."""
    road, cross = straight_route((0.0, 0.0), 0.0), straight_route((50.0, -50.0), 90.0)
    reach = 0.5 * (CONFLICT_BOX[0] + CONFLICT_BOX[1])
    (zone,) = conflict_zones(cross, road)
    assert zone.crossing
    assert zone.s_a[0] == pytest.approx(50.0 - reach, abs=0.2)
    assert zone.s_a[-1] == pytest.approx(50.0 + reach, abs=0.2)
    assert np.allclose(zone.s_b, 50.0)
    (own,) = conflict_zones(road, road)
    assert not own.crossing and np.array_equal(own.s_a, road.s)
    assert conflict_zones(road, straight_route((0.0, 3.5), 0.0)) == []
    assert conflict_zones(road, straight_route((100.0, 0.0), 180.0)) == []
    assert np.allclose(crossing_spans(1, {(1, 0): [zone], (1, 1): [own]}, 2),
                       [[zone.s_a[0], zone.s_a[-1]]])


def test_a_vehicle_follows_waits_at_a_crossing_and_yields_to_one_there_sooner():
    """Closed form, ``_obstacle``: (1) a car 20 m behind a 12 m truck on one road stops
    behind the truck's rear; (2) a car on the crossing road 20 m before the crossing with
    the truck in it stops at the crossing's entry; (3) of two cars approaching the crossing
    at 10 m/s, the one 30 m from it yields (its obstacle the entry) to the one 15 m from
    it, which sees nothing ahead."""
    road, cross = straight_route((0.0, 0.0), 0.0), straight_route((50.0, -50.0), 90.0)
    routes = [road, cross]
    zones = {(a, b): conflict_zones(routes[a], routes[b]) for a in range(2) for b in range(2)}
    spans = [crossing_spans(k, zones, 2) for k in range(2)]
    reach = 0.5 * (CONFLICT_BOX[0] + CONFLICT_BOX[1])

    def car(i: int, route: int, s: float, v: float, length: float = 4.5) -> Driver:
        return Driver(i, ("car", length, 1.8, 1.5), route, np.full(len(road.s), v), s, v)

    truck = car(0, 0, 50.0, 10.0, length=12.0)
    follower = car(1, 0, 50.0 - 20.0, 10.0)
    assert _obstacle(follower, [truck], zones, spans[0]) == pytest.approx(
        (50.0 - 6.0) - (30.0 + 2.25), abs=0.2)
    waiting = car(2, 1, 50.0 - reach - 2.25 - 20.0, 10.0)
    assert _obstacle(waiting, [truck], zones, spans[1]) == pytest.approx(20.0, abs=0.2)
    near = car(3, 0, 50.0 - reach - 2.25 - 15.0, 10.0)
    far = car(4, 1, 50.0 - reach - 2.25 - 30.0, 10.0)
    assert _obstacle(far, [near], zones, spans[1]) == pytest.approx(30.0, abs=0.2)
    assert _obstacle(near, [far], zones, spans[0]) == np.inf


def test_the_benchmark_finds_its_sites_in_the_maps_routing_graph():
    """bench/independent.py takes a map's largest junctions from its routing graph (any map:
    ``--map``): on the crop, junction 3 of the whole map is among them, to 1e-5 deg (the
    generator seeds from the site at that resolution); asking for more than the map has is
    an error that names the map."""
    from bench.independent import junctions, run_one

    sites = junctions(CROP, 3)
    assert list(sites) == [1, 2, 3][: len(sites)] and sites
    assert JUNCTION_3 in sites.values()
    assert all(round(lat, 5) == lat and round(lon, 5) == lon for lat, lon in sites.values())
    with pytest.raises(ValueError, match="lanelet2_example_crop.osm: .* no junction 7"):
        run_one(7, 1, "static", 1.0, map_path=CROP)


def test_the_benchmark_reports_held_out_junctions_on_rows_of_their_own():
    from bench.independent import LOOKED_AT, table

    def row(junction: int, d2d: float) -> dict:
        return {"setting": "static", "junction": junction, "seed": 1, "method": "joint",
                "status": "resolved", "n_modes": 1, "d2d": d2d, "dyaw_deg": 0.1,
                "nees": 2.0, "dz": -0.1}

    ambiguous = {**row(LOOKED_AT + 2, 6.0), "status": "ambiguous"}
    lines = table([row(1, 0.1), row(LOOKED_AT, 0.3), row(LOOKED_AT + 1, 4.0), ambiguous])
    joint = [ln for ln in lines if "| joint |" in ln]
    assert joint[0].startswith("| static | joint | 2 | 2 | 0.200 / 0.300 | 0.200 / 0.300 |")
    assert joint[1].startswith("| static, held-out junctions | joint | 2 | 1 | 5.000 / 6.000 | "
                               "4.000 / 4.000 |")


def test_the_tracking_benchmark_follows_the_generators_vehicles():
    """bench/independent_tracking.py on a generated scenario (the crop's junction 1, 40 s):
    the filter with the true pose follows the generator's vehicles (at most one in seven
    missed, at most 1.5 tracks per vehicle, centres within a metre RMS) and the batch
    smoother brings the centres closer; the table puts the held-out junctions' runs on a row
    of their own, with the track counts."""
    from bench.independent import HELD_OUT
    from bench.independent_tracking import run_one, table
    from bench.robustness import RunResult

    run = run_one(1, 1, "static", 40.0, map_path=CROP)
    f = run.figures
    assert run.setting == "static" and run.case == "junction 1" and run.vehicles >= 7
    assert f["missed"] <= run.vehicles / 7 and f["tracks_per_vehicle"] <= 1.5
    assert f["filter.rms"] < 1.0 and f["batch.rms"] < f["filter.rms"]
    assert f["filter.iou"] > 0.6 and f["batch.iou"] > 0.6
    held = RunResult(f"static, {HELD_OUT}", 2, "junction 9", 5, {**f, "false": 3.0})
    lines = table([held, run])
    assert lines[0].startswith("| setting | runs | vehicles | tracks/veh | false | fragments "
                               "| missed | cover 2 |")
    assert lines[2].startswith("| static | 1 |") and lines[3].startswith(
        f"| static, {HELD_OUT} | 1 | 5 |")
    assert f"| {f['false']:.1f} / {f['false']:.1f} |" in lines[2]
    assert "| 3.0 / 3.0 |" in lines[3]
