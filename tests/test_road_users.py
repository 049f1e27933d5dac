"""Tracks of road users that are not motor vehicles (cyclists, pedestrians) are told from the
vehicles' and kept out of the registration, against the simulator's truth."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from factors.gp import rectangle_radius
from fgloc.config import Config, from_dict
from fgloc.io import load_scenario
from fgloc.pipeline import track
from fgloc.scenario import BUILDING_CLASS, AlsCloud, Lanelet, LaneletMap
from fgloc.sim import SimConfig, simulate_detailed
from fgloc.sim.radar import GHOST as SIM_GHOST
from fgloc.sim.real_map import simulate_on_map
from fgloc.tracking.config import TrackingConfig
from fgloc.tracking.road_users import (
    DOUBT_SHARE,
    MapWays,
    Sight,
    area_samples,
    is_motor_vehicle,
    split_road_users,
)
from fgloc.tracking.sightlines import Buildings
from fgloc.tracks import N_KIN, N_STATE, YAW, Track, V, X, Y, contour_angles

CROP = Path(__file__).parent / "data" / "lanelet2_example_crop.osm"


def _box_track(track_id: int, length: float, width: float, steps: int = 5,
               speed: float = 10.0, y: float = 0.0, detections: int = 0,
               heading_deg: float = 0.0, x: float = 0.0) -> Track:
    """A box of ``length`` x ``width`` m driving ``speed`` m/s from (x, y) m, heading
    ``heading_deg``, with ``detections`` detection indices."""
    states = np.zeros((steps, N_STATE))
    yaw = np.deg2rad(heading_deg)
    states[:, V] = speed
    states[:, YAW] = yaw
    states[:, X] = x + np.cos(yaw) * speed * np.arange(steps) * 0.05
    states[:, Y] = y + np.sin(yaw) * speed * np.arange(steps) * 0.05
    states[:, N_KIN:] = rectangle_radius(contour_angles(), length, width)
    return Track(track_id, np.arange(steps) * 0.05, states, np.zeros(steps, dtype=np.int8),
                 det_index=np.arange(detections))


def _strip(lanelet_id: int, y_right: float, y_left: float, subtype: str,
           along_y: bool = False) -> Lanelet:
    """A straight lanelet along x from -50 to 150 m between y_right and y_left (m); with
    ``along_y`` the same turned by 90 deg (along y, between x = -y_right and -y_left)."""
    x = np.array([-50.0, 150.0])
    left = np.column_stack([x, [y_left] * 2, [0.0] * 2])
    right = np.column_stack([x, [y_right] * 2, [0.0] * 2])
    if along_y:
        turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        left, right = left @ turn.T, right @ turn.T
    return Lanelet(lanelet_id, left, right, {"subtype": subtype})


@pytest.mark.parametrize(("length", "width", "vehicle"),
                         [(4.5, 1.8, True), (3.1, 1.5, True), (11.0, 2.5, True), (4.5, 1.35, True),
                          (2.7, 3.2, True), (2.9, 2.5, True), (2.5, 2.0, True),
                          (1.8, 0.6, False), (2.9, 1.8, False), (2.5, 1.99, False),
                          (4.5, 1.2, False), (1.2, 4.5, False), (0.6, 1.8, False)])
def test_contour_size_tells_a_motor_vehicle(length: float, width: float,
                                            vehicle: bool) -> None:
    assert is_motor_vehicle(_box_track(0, length, width), TrackingConfig()) is vehicle
    # both thresholds at 0 keep every track
    keep_all = TrackingConfig(min_vehicle_length=0.0, min_vehicle_width=0.0, walking_speed=0.0)
    assert is_motor_vehicle(_box_track(0, length, width), keep_all)


def test_a_track_at_walking_speed_is_not_a_motor_vehicle() -> None:
    cfg = TrackingConfig()
    assert not is_motor_vehicle(_box_track(0, 4.4, 1.9, speed=1.3), cfg)     # a pedestrian
    assert not is_motor_vehicle(_box_track(0, 4.4, 1.9, speed=-2.4), cfg)    # either way
    assert is_motor_vehicle(_box_track(0, 4.4, 1.9, speed=2.6), cfg)
    # 90th percentile: a car slow for 16 of 20 steps, then driving off, is a car
    car = _box_track(0, 4.5, 1.8, steps=20, speed=0.8)
    car.states[16:, V] = 8.0
    assert is_motor_vehicle(car, cfg)
    car.states[16:, V] = 0.8
    car.states[19, V] = 8.0          # one fast step (a spike) does not make a walker a car
    assert not is_motor_vehicle(car, cfg)
    assert is_motor_vehicle(car, TrackingConfig(walking_speed=0.0))


def test_split_keeps_order_and_uses_the_median_over_steps() -> None:
    car = _box_track(1, 4.5, 1.8)
    bike = _box_track(2, 1.8, 0.6)
    # a car whose contour was cyclist-sized in 2 of 5 steps is still a car
    mixed = _box_track(3, 4.5, 1.8)
    mixed.states[:2, N_KIN:] = rectangle_radius(contour_angles(), 1.8, 0.6)
    users = split_road_users([bike, car, mixed], TrackingConfig())
    assert [t.id for t in users.vehicles] == [1, 3] and [t.id for t in users.others] == [2]


def test_cyclists_tracks_are_dropped_and_the_cars_kept() -> None:
    sim = from_dict(SimConfig, {"traffic": {"cyclists_per_minute": 8.0}}, None)
    res = simulate_detailed("intersection", 1, 30.0, config=sim)
    run = track(res.scenario, Config(), oracle_pose=True)
    kept = run.tracks.tracks
    dropped = set(run.tracks.diagnostics["not_motor_vehicles"])
    assert dropped and not dropped & {t.id for t in kept}

    def majority(det_index: np.ndarray) -> str:
        src = res.source[det_index]
        src = src[src >= 0]
        return res.vehicle_class[np.bincount(src).argmax()] if len(src) else "clutter"

    # at most two kept tracks with most of their detections on a cyclist (seen too sparsely
    # to leave the car-sized prior), and less than half of the cyclists' tracked returns in
    # the kept tracks (38 % here)
    classes = [majority(t.det_index) for t in kept]
    on_bike = np.concatenate([res.source[t.det_index] for t in kept])
    bike_ids = [i for i, c in enumerate(res.vehicle_class) if c == "bicycle"]
    bike_returns_kept = np.isin(on_bike, bike_ids).sum()
    assert classes.count("bicycle") <= 2
    everything = track(res.scenario, Config(tracking=TrackingConfig(
        min_vehicle_length=0.0, min_vehicle_width=0.0, walking_speed=0.0)),
        oracle_pose=True).tracks.tracks
    on_bike_all = np.concatenate([res.source[t.det_index] for t in everything])
    assert bike_returns_kept < 0.5 * np.isin(on_bike_all, bike_ids).sum()
    # no car track lost: the cars' tracks with and without the rule are the same
    cars = sorted(t.id for t in everything if majority(t.det_index) != "bicycle")
    assert cars == sorted(t.id for t, c in zip(kept, classes) if c != "bicycle")


def test_pedestrians_tracks_are_dropped_by_their_speed() -> None:
    """On the example crop with pedestrians on its crosswalks and shared paths: their tracks
    keep car-sized contours, the size rule keeps them, the speed bound drops them; no motor
    vehicle's track goes."""
    sim_cfg = SimConfig()
    sim_cfg.real_map.pedestrians_per_minute = 30.0
    res = simulate_on_map(CROP, 2,
                          duration=40.0, crop_radius=150.0, config=sim_cfg).result
    with_speed = track(res.scenario, Config(), oracle_pose=True).tracks.tracks
    size_only = track(res.scenario, Config(tracking=TrackingConfig(
        walking_speed=0.0, off_lane_margin=np.inf, off_road_margin=np.inf)),
        oracle_pose=True).tracks.tracks

    def walkers(tracks: list[Track]) -> list[int]:
        ids = []
        for t in tracks:
            src = res.source[t.det_index]
            src = src[src >= 0]
            if len(src) and res.vehicle_class[np.bincount(src).argmax()] == "pedestrian":
                ids.append(t.id)
        return ids

    assert len(walkers(size_only)) >= 2
    assert len(walkers(with_speed)) <= 0.25 * len(walkers(size_only))
    vehicles = sorted(set(t.id for t in size_only) - set(walkers(size_only)))
    assert vehicles == sorted(set(t.id for t in with_speed) - set(walkers(with_speed)))


def test_area_samples_cover_the_lanelet() -> None:
    road = _strip(1, -1.75, 1.75, "road")
    pts, axis = area_samples([road], step=0.5)
    assert np.allclose(np.sin(axis), 0.0)                   # along x, either way
    assert np.allclose(area_samples([_strip(2, -1, 1, "rail", along_y=True)])[1], np.pi / 2)
    assert pts[:, 0].min() == -50.0 and pts[:, 0].max() == 150.0
    assert pts[:, 1].min() == -1.75 and pts[:, 1].max() == 1.75
    # every point of the area within half the sampling diagonal of a sample
    rng = np.random.default_rng(0)
    inside = np.column_stack([rng.uniform(-50, 150, 2000), rng.uniform(-1.75, 1.75, 2000)])
    assert cKDTree(pts).query(inside)[0].max() <= 0.5 * np.hypot(0.5, 0.5) + 1e-9


def test_a_track_on_the_rail_bed_beside_the_road_is_not_a_motor_vehicle() -> None:
    """Road y in [-1.75, 5.25] (two lanes), a rail bed y in [6.5, 9.5] (a grass verge between),
    a bicycle lane y in [-3.5, -1.75] (abutting the road): a tram on the rail's centre is off
    lane, a truck on either lane or on the road's edge is not, nor a car whose placement puts
    it 0.8 m into the bicycle lane."""
    lmap = LaneletMap([_strip(1, -1.75, 1.75, "road"), _strip(2, 1.75, 5.25, "road")],
                      ignored=[_strip(3, 6.5, 9.5, "rail"), _strip(4, -3.5, -1.75,
                                                                  "bicycle_lane")])
    ways = MapWays.of(lmap)
    cfg = TrackingConfig()
    tram = _box_track(1, 30.0, 2.65, y=8.0, detections=10)
    trucks = [_box_track(k, 12.0, 2.5, y=y, detections=10)
              for k, y in ((2, 0.0), (3, 3.5), (4, 5.2), (5, -2.55))]
    users = split_road_users([tram, *trucks], cfg, ways)
    assert [t.id for t in users.others] == [1] and users.off_lane == [1]
    assert [t.id for t in users.vehicles] == [2, 3, 4, 5] and users.doubted == []
    # a tram 2.75 m from the road's edge, on the rail bed (up to the samples' spacing)
    assert ways.nearer_other(tram.states[:, [X, Y]], tram.states[:, YAW]) == pytest.approx(
        2.75, abs=0.36)
    # heading across every way (north): none runs along it, -inf, and no NaN on the way
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        across = ways.nearer_other(np.array([[0.0, 8.0], [0.0, 0.0]]), np.full(2, np.pi / 2))
    np.testing.assert_array_equal(across, [-np.inf, -np.inf])
    # inf keeps every track; a map without other ways leaves the rule idle
    assert split_road_users([tram], TrackingConfig(off_lane_margin=np.inf), ways).others == []
    no_rail = MapWays.of(LaneletMap(lmap.lanelets))
    assert no_rail is not None and no_rail.other is None
    assert split_road_users([tram], cfg, no_rail).others == []
    # only the lanelets within reach count: from 300 m away along y the rail (290.5 m) and the
    # road (294.75 m) are out of reach; with only the rail in reach there is no drivable area
    # to tell a way by (None)
    assert MapWays.of(lmap, np.array([50.0, 300.0]), 250.0) is None
    assert MapWays.of(lmap, np.array([50.0, 300.0]), 292.0) is None
    assert MapWays.of(lmap, np.array([50.0, 300.0]), 295.0).other is not None
    # a cyclist rule still applies first: a bike on the bicycle lane goes for its size
    bike = _box_track(6, 1.8, 0.6, y=-2.6, detections=10)
    users = split_road_users([bike, *trucks], cfg, ways)
    assert [t.id for t in users.others] == [6] and users.off_lane == []


def test_the_off_lane_rule_goes_by_the_heading() -> None:
    """A rail and a crosswalk across a road (along y, x in [20, 23] and [40, 44]): a tram on
    the rail crossing the road is off lane (no lane runs its way there), a truck driving along
    the road over the rail and the crosswalk is not."""
    lmap = LaneletMap([_strip(1, -3.5, 3.5, "road")],
                      ignored=[_strip(2, -23.0, -20.0, "rail", along_y=True),
                               _strip(3, -44.0, -40.0, "crosswalk", along_y=True)])
    ways = MapWays.of(lmap)
    tram = _box_track(1, 30.0, 2.65, steps=20, y=-10.0, x=21.5, heading_deg=90.0,
                      detections=10)
    truck = _box_track(2, 12.0, 2.5, steps=200, speed=6.0, y=1.5, x=0.0, detections=10)
    users = split_road_users([tram, truck], TrackingConfig(), ways)
    assert users.off_lane == [1] and [t.id for t in users.vehicles] == [2]
    # heading is an axis: the tram going the other way is off lane too
    back = _box_track(4, 30.0, 2.65, steps=20, y=10.0, x=21.5, heading_deg=-90.0,
                      detections=10)
    assert split_road_users([back, truck], TrackingConfig(), ways).off_lane == [4]


def test_the_off_lane_rule_doubts_a_placement_that_drops_most_detections() -> None:
    """A coarse pose 7 m off puts most vehicles on the rail bed: the rule keeps them all and
    says which it doubted."""
    lmap = LaneletMap([_strip(1, -1.75, 1.75, "road")], ignored=[_strip(2, 5.0, 9.0, "rail")])
    ways = MapWays.of(lmap)
    shifted = [_box_track(k, 4.5, 1.8, y=7.0, detections=30) for k in (1, 2)]
    on_road = _box_track(3, 4.5, 1.8, y=0.5, detections=50)
    users = split_road_users([*shifted, on_road], TrackingConfig(), ways)
    assert [t.id for t in users.vehicles] == [1, 2, 3]
    assert users.doubted == [1, 2] and users.off_lane == []
    # with fewer detections on the rail than the DOUBT_SHARE, they go
    users = split_road_users([shifted[0], on_road], TrackingConfig(), ways)
    assert [t.id for t in users.vehicles] == [3] and users.off_lane == [1]


def test_a_track_far_off_every_drivable_lanelet_is_dropped() -> None:
    """A road y in [-1.75, 5.25] and nothing else: a multipath ghost mirrored 10 m behind a
    facade beside it (any heading) is off the road, a car on it, on its edge or 2.5 m beside
    it (a coarse pose a lane off) is not; the median over the steps decides; ``inf`` keeps
    every track; both rules count towards the doubt guard."""
    lmap = LaneletMap([_strip(1, -1.75, 1.75, "road"), _strip(2, 1.75, 5.25, "road")])
    ways = MapWays.of(lmap)
    cfg = TrackingConfig()
    ghosts = [_box_track(1, 4.5, 1.8, y=15.0, detections=10),
              _box_track(2, 4.5, 1.8, y=-12.0, heading_deg=70.0, detections=10)]
    cars = [_box_track(k, 4.5, 1.8, y=y, detections=40)
            for k, y in ((3, 0.0), (4, 5.2), (5, -1.75 - 2.5))]
    users = split_road_users([*ghosts, *cars], cfg, ways)
    assert users.off_road == [1, 2] and users.off_lane == [] and users.doubted == []
    assert [t.id for t in users.vehicles] == [3, 4, 5]
    # the distance it goes by: 15 - 5.25 m from the road's edge (up to the samples' spacing)
    assert np.median(ways.off_road(ghosts[0].states[:, [X, Y]])) == pytest.approx(
        9.75, abs=0.36)
    assert split_road_users(ghosts, TrackingConfig(off_road_margin=np.inf), ways).others == []
    # a car crossing a verge for 2 of its 5 steps stays; for 3 of them it goes
    verge = _box_track(6, 4.5, 1.8, y=0.0, detections=10)
    verge.states[:2, Y] = 20.0
    assert split_road_users([verge, *cars], cfg, ways).off_road == []
    verge.states[:3, Y] = 20.0
    assert split_road_users([verge, *cars], cfg, ways).off_road == [6]
    # the doubt guard: more than DOUBT_SHARE of the detections off the road keeps them all
    heavy = [_box_track(k, 4.5, 1.8, y=15.0, detections=100) for k in (7, 8)]
    users = split_road_users([*heavy, *cars], cfg, ways)
    assert 200 > DOUBT_SHARE * (200 + 120)
    assert users.doubted == [7, 8] and users.off_road == [] and len(users.vehicles) == 5


def test_trams_tracks_off_the_roads_are_dropped_and_every_vehicle_kept() -> None:
    """On the example crop with trams on its rails: the trams' tracks are long, wide and fast
    (size and speed keep them); those on the rails' own bed go by the map, those crossing the
    junction on the road's area stay (there a tram shares the lanes); no motor vehicle's track
    goes."""
    sim_cfg = SimConfig()
    sim_cfg.real_map.trams_per_minute = 4.0
    res = simulate_on_map(CROP, 1, duration=40.0, crop_radius=150.0, config=sim_cfg).result
    ruled = track(res.scenario, Config(), oracle_pose=True).tracks
    unruled = track(res.scenario, Config(tracking=TrackingConfig(
        off_lane_margin=np.inf, off_road_margin=np.inf)),
                    oracle_pose=True).tracks.tracks
    tram_ids = [i for i, c in enumerate(res.vehicle_class) if c == "tram"]

    def on_tram(t: Track) -> np.ndarray:
        """Whether each of the track's detections is a tram's."""
        return np.isin(res.source[t.det_index], tram_ids)

    trams = {t.id for t in unruled if on_tram(t).mean() > 0.5}
    assert len(trams) >= 4
    # the dropped tracks are trams', at least 4 of them and a third of their detections
    dropped = set(ruled.diagnostics["off_lane"])
    assert dropped <= trams and len(dropped) >= 4
    tram_returns = sum(on_tram(t).sum() for t in unruled)
    assert sum(on_tram(t).sum() for t in ruled.tracks) < 2 / 3 * tram_returns
    assert {t.id for t in unruled} - dropped == {t.id for t in ruled.tracks}


def test_multipath_ghost_tracks_are_dropped_and_every_vehicle_kept(tmp_path) -> None:
    """The independent generator's multipath ghosts (facades beside the road mirror the
    vehicles' returns, labelled in its _gen/labels.npz) on the example crop: the tracker makes
    tracks of them; the off-road rule drops those and no other."""
    from bench.independent_gen import GHOST, generate

    out = generate(CROP, (49.00519, 8.41563), 4, tmp_path / "ghosts", vehicles_per_minute=30.0,
                   duration=20.0, ghosts=True)
    scn = load_scenario(out)
    label = np.load(out / "_gen" / "labels.npz")["label"]
    ruled = track(scn, Config(), oracle_pose=True).tracks
    unruled = track(scn, Config(tracking=TrackingConfig(off_road_margin=np.inf)),
                    oracle_pose=True).tracks.tracks
    ghosts = {t.id for t in unruled if (label[t.det_index] == GHOST).mean() > 0.5}
    assert len(ghosts) >= 1
    assert set(ruled.diagnostics["off_road"]) == ghosts
    assert {t.id for t in unruled} - ghosts == {t.id for t in ruled.tracks}


def _als(boxes: list[tuple[float, float, float, float, float]]) -> AlsCloud:
    """Flat ground (z = 0, class 2) on a 1 m grid over [-10, 80] x [-40, 40] and buildings
    (x0, x1, y0, y1, top): their roofs every 0.5 m at the top, class 6."""
    gx, gy = np.meshgrid(np.arange(-10.0, 80.0), np.arange(-40.0, 40.0))
    parts = [np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])]
    cls = [np.full(gx.size, 2)]
    for x0, x1, y0, y1, top in boxes:
        bx, by = np.meshgrid(np.arange(x0, x1, 0.5), np.arange(y0, y1, 0.5))
        parts.append(np.column_stack([bx.ravel(), by.ravel(), np.full(bx.size, top)]))
        cls.append(np.full(bx.size, BUILDING_CLASS))
    return AlsCloud(np.vstack(parts).astype(np.float32), np.concatenate(cls).astype(np.uint8))


SENSOR = np.array([0.0, 0.0, 6.0])


def test_points_behind_a_building_are_hidden_and_the_rest_seen() -> None:
    """A 10 m building across x = 20-30, |y| < 5, and a 1 m wall across x = 10-11, |y| < 20,
    seen from 6 m: behind the building (also 1.5 m behind its back wall) is hidden; beside it,
    in front of it and behind the low wall (the sight line passes 3 m over it) is seen."""
    b = Buildings.of(_als([(20, 30, -5, 5, 10.0), (10, 11, -20, 20, 1.0)]), np.zeros(2), 100.0)
    assert b is not None
    xy = np.array([[40.0, 0.0], [31.5, 0.0], [60.0, 3.0],      # behind the building
                   [40.0, 20.0], [15.0, 0.0], [40.0, -12.0]])  # beside, in front, beside
    np.testing.assert_array_equal(b.hidden(SENSOR, xy), [True, True, True, False, False, False])
    # tested in chunks: 3000 points give the same answers
    np.testing.assert_array_equal(b.hidden(SENSOR, np.tile(xy, (500, 1))),
                                  np.tile(b.hidden(SENSOR, xy), 500))
    # a sensor higher than the building sees over it to far points
    assert not b.hidden(np.array([0.0, 0.0, 30.0]), np.array([[70.0, 0.0]]))[0]


def test_a_tree_over_the_road_does_not_lift_the_sight_line() -> None:
    """A vehicle 40 m away behind a 10 m building, under a 14 m tree crown (class 5, every
    0.25 m over 4 x 4 m, denser than the ground): the sight line ends 2 m above the ground
    (passes 3-4 m high at the building: hidden), not 2 m above the crown (12 m: seen)."""
    als = _als([(20, 30, -5, 5, 10.0)])
    cx, cy = np.meshgrid(np.arange(38.0, 42.0, 0.25), np.arange(-2.0, 2.0, 0.25))
    crown = np.column_stack([cx.ravel() + 0.1, cy.ravel() + 0.1, np.full(cx.size, 14.0)])
    treed = AlsCloud(np.vstack([als.xyz, crown]).astype(np.float32),
                     np.concatenate([als.classification, np.full(cx.size, 5)]).astype(np.uint8))
    b = Buildings.of(treed, np.zeros(2), 100.0)
    vehicle = np.array([[40.1, 0.1]])             # under a crown point, 0.14 m from the ground's
    assert b is not None and b.hidden(SENSOR, vehicle)[0]
    # without ground classes the other points give the ground (here the crown: seen over)
    building = treed.classification == BUILDING_CLASS
    unclassified = AlsCloud(treed.xyz, np.where(building, BUILDING_CLASS, 1).astype(np.uint8))
    b = Buildings.of(unclassified, np.zeros(2), 100.0)
    assert b is not None and not b.hidden(SENSOR, vehicle)[0]


def test_no_buildings_no_rule() -> None:
    assert Buildings.of(_als([]), np.zeros(2), 100.0) is None


def _car(track_id: int, y: float) -> Track:
    """A car driving along +x at 10 m/s from x = 35 m at ``y`` m, 20 steps, 200 detections."""
    return _box_track(track_id, 4.5, 1.8, steps=20, y=y, detections=200, x=35.0)


def test_tracks_behind_a_building_are_dropped_unless_most_are() -> None:
    """One track behind the building, two in the open: the hidden one is dropped and named;
    with ``hidden_share = 1`` every track stays; when the hidden ones carry most of the
    detections the placement is doubted and none is dropped."""
    sight = Sight(SENSOR, Buildings.of(_als([(20, 30, -5, 5, 10.0)]), np.zeros(2), 100.0))
    cfg = TrackingConfig()
    ghost, cars = _car(1, 0.0), [_car(2, 15.0), _car(3, -15.0)]
    users = split_road_users([ghost, *cars], cfg, None, sight)
    assert users.hidden == [1] and [t.id for t in users.vehicles] == [2, 3]
    kept = split_road_users([ghost, *cars], TrackingConfig(hidden_share=1.0), None, sight)
    assert kept.hidden == [] and len(kept.vehicles) == 3
    doubted = split_road_users([ghost, _car(4, 1.0), cars[0]], cfg, None, sight)
    assert doubted.doubted == [1, 4] and len(doubted.vehicles) == 3


def test_simulated_ghosts_on_the_road_behind_facades_are_dropped() -> None:
    """fgloc's simulator with 16 buildings 2 m from the road mirroring 30 % of the returns
    (the robustness matrix's ghosts setting), intersection seed 3, the true pose: tracks made
    mostly of ghosts are dropped (off the road or behind a building), among them some that
    the off-road rule keeps (a facade at the junction mirrors one arm onto another); no track
    made mostly of vehicle returns is."""
    cfg = from_dict(SimConfig, {"radar": {"ghost_fraction": 0.3},
                                "als": {"buildings": 16, "building_clearance": 2.0}}, None)
    det = simulate_detailed("intersection", 3, duration=40.0, config=cfg)
    ruled = track(det.scenario, Config(), oracle_pose=True).tracks
    unruled = track(det.scenario, Config(tracking=TrackingConfig(
        off_road_margin=np.inf, hidden_share=1.0)), oracle_pose=True).tracks.tracks
    ghosts = {t.id for t in unruled if (det.source[t.det_index] == SIM_GHOST).mean() > 0.5}
    hidden = set(ruled.diagnostics["hidden"])
    assert len(hidden & ghosts) >= 3
    assert set(ruled.diagnostics["off_road"]) | hidden <= ghosts
    assert ghosts <= set(ruled.diagnostics["not_motor_vehicles"])
