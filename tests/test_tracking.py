"""fgloc.tracking: the UKF GP-EOT tracker on constructed scenarios, birth zones, labels."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from factors.gp import rectangle_radius
from factors.measurement import closest_on_chain, contour_candidates, interior_variance
from fgloc.evaluation.tracking import iou_polygon_rectangle
from fgloc.geo import LocalFrame, rot_from_ypr, se3, se3_inv, transform_points, wrap_angle
from fgloc.labels import LEFT, RIGHT, STRAIGHT
from fgloc.order_stats import linear_quantile, median_inplace
from fgloc.scenario import (
    AlsCloud,
    GroundTruth,
    Lanelet,
    LaneletMap,
    RadarData,
    Scenario,
    SensorConfig,
    TrackTruth,
)
from fgloc.tracking import TrackingConfig, kappa_labels, track_scenario
from fgloc.tracking.birth import BirthZones, FieldOfView, LaneHeadings
from fgloc.tracking.tracker import Tracker, _Frame, _Record
from fgloc.tracks import N_KIN, N_STATE

Path = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
RATE = 20.0


# ---------------------------------------------------------------------------------------------
# a constructed radar: points on the sensor-facing box edges, range-rate doppler, no clutter
# ---------------------------------------------------------------------------------------------
def _visible_edge_points(rng: np.random.Generator, c: np.ndarray, yaw: float, length: float,
                         width: float, sensor: np.ndarray, k: int) -> np.ndarray:
    h = np.array([np.cos(yaw), np.sin(yaw)])
    n = np.array([-h[1], h[0]])
    corners = np.array([c + h * length / 2 + n * width / 2, c - h * length / 2 + n * width / 2,
                        c - h * length / 2 - n * width / 2, c + h * length / 2 - n * width / 2])
    e = np.roll(corners, -1, axis=0) - corners
    mid = corners + e / 2
    facing = np.sum(np.stack([e[:, 1], -e[:, 0]], 1) * (sensor - mid), axis=1) > 0
    los = (mid - sensor) / np.linalg.norm(mid - sensor, axis=1, keepdims=True)
    w = np.abs(e[:, 0] * los[:, 1] - e[:, 1] * los[:, 0]) * facing
    edge = rng.choice(4, k, p=w / w.sum())
    return corners[edge] + rng.random(k)[:, None] * e[edge]


def straight(start: tuple[float, float], yaw: float, v: float) -> Path:
    def path(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xy = np.asarray(start) + (v * t)[:, None] * [np.cos(yaw), np.sin(yaw)]
        return xy, np.column_stack([np.full(len(t), yaw), np.full(len(t), v), np.zeros(len(t))])
    return path


def lane(p0: tuple[float, float], p1: tuple[float, float], lid: int = 0) -> Lanelet:
    a, b = np.asarray(p0, float), np.asarray(p1, float)
    h = (b - a) / np.linalg.norm(b - a)
    n = np.array([-h[1], h[0]]) * 1.75
    c = a + np.linspace(0.0, 1.0, 20)[:, None] * (b - a)
    z = np.zeros((20, 1))
    return Lanelet(lid, np.hstack([c + n, z]), np.hstack([c - n, z]))


def constructed(paths: list[Path], sizes: list[tuple[float, float]], duration: float,
                lanes: list[Lanelet], pose: np.ndarray | None = None, k: int = 20,
                seed: int = 0) -> tuple[Scenario, np.ndarray]:
    """A scenario (sensor at the origin of L, boresight +x unless ``pose`` S -> L) and the
    source vehicle of every detection."""
    rng = np.random.default_rng(seed)
    pose = np.eye(4) if pose is None else pose
    s2 = pose[:2, 3]
    t = np.arange(0.0, duration, 1.0 / RATE)
    truths, parts = [], []
    for vid, (path, (length, width)) in enumerate(zip(paths, sizes)):
        xy, kin = path(t)
        truths.append(TrackTruth(vid, length, width, np.column_stack([t, xy, kin])))
    for i, ti in enumerate(t):
        for tr in truths:
            _, x, y, yaw, v, w = tr.states[i]
            p = _visible_edge_points(rng, np.array([x, y]), yaw, tr.length, tr.width, s2, k)
            arm = p - [x, y]
            vel = v * np.array([np.cos(yaw), np.sin(yaw)]) + w * np.column_stack([-arm[:, 1],
                                                                                  arm[:, 0]])
            rel = np.column_stack([p - s2, np.full(k, 0.8 - pose[2, 3])])
            dop = np.sum(vel * rel[:, :2], axis=1) / np.linalg.norm(rel, axis=1)
            p = p + rng.normal(0.0, 0.08, p.shape)
            parts.append((np.full(k, ti), np.column_stack([p, np.full(k, 0.8)]),
                          dop + rng.normal(0.0, 0.05, k), np.full(k, tr.id)))
    tt, xyz, dop, src = (np.concatenate([p[j] for p in parts]) for j in range(4))
    radar = RadarData(tt, transform_points(se3_inv(pose), xyz), dop)
    scn = Scenario(LocalFrame((0.0, 0.0, 0.0)),
                   SensorConfig((0.0, 0.0), "EPSG:25832", hfov_deg=120.0, vfov_deg=30.0,
                                max_range=200.0),
                   radar, AlsCloud(np.zeros((0, 3), np.float32), np.zeros(0, np.uint8)),
                   LaneletMap(lanes), GroundTruth("EPSG:25832", pose, truths))
    return scn, src


def _errors(scn: Scenario, track_states: np.ndarray, track_t: np.ndarray,
            vid: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre error (m), |yaw error| (deg) and IoU of a track's states against vehicle vid."""
    g = scn.truth.tracks[vid]
    j = np.rint(track_t * RATE).astype(int)
    st = g.states[j]
    centre = np.linalg.norm(track_states[:, :2] - st[:, 1:3], axis=1)
    yaw = np.degrees(np.abs(wrap_angle(track_states[:, 4] - st[:, 3])))
    ang = 2 * np.pi * np.arange(20) / 20
    a = ang[None, :] + track_states[:, 4:5]
    poly = np.stack([track_states[:, :1] + track_states[:, 6:] * np.cos(a),
                     track_states[:, 1:2] + track_states[:, 6:] * np.sin(a)], axis=-1)
    n = len(st)
    iou = iou_polygon_rectangle(poly, st[:, 1:3], st[:, 3], np.full(n, g.length),
                                np.full(n, g.width))
    return centre, yaw, iou


@pytest.mark.parametrize("n", [1, 2, 3, 7, 8, 40])
def test_list_quantile_and_median_are_numpys_numbers(n: int) -> None:
    # the tracker's fast span quantile and noise median: the same floats as numpy's, so the
    # tracks are bit for bit those numpy's calls gave
    rng = np.random.default_rng(n)
    for _ in range(200):
        v = rng.normal(4.0, 2.0, n) * rng.choice([1e-3, 1.0, 1e3])
        if rng.random() < 0.3:
            v = np.round(v, 1)                                    # ties
        for q in (0.0, 0.1, 0.5, 0.8, 0.95, 1.0, float(rng.random())):
            assert linear_quantile(list(v), q) == np.quantile(v, q)
        assert median_inplace(v.copy()) == np.median(v)


# ---------------------------------------------------------------------------------------------
# tests
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("model", ["sensor-aware", "plain"])
def test_single_car_shape_and_pose(model: str) -> None:
    """A car approaching on a lane 8 m right of the boresight, 100 m -> 30 m."""
    yaw = np.pi
    scn, src = constructed([straight((100.0, -8.0), yaw, 10.0)], [(4.6, 1.9)], 7.0,
                           [lane((220.0, -8.0), (-60.0, -8.0))])
    ts = track_scenario(scn, scn.truth.sensor_pose, TrackingConfig(), measurement_model=model)
    assert ts.frame == "C" and len(ts) == 1
    tr = ts.tracks[0]
    assert tr.states.shape == (len(tr), N_STATE)
    assert tr.covariances is not None and tr.covariances.shape == (len(tr), N_STATE, N_STATE)
    assert len(tr.det_index) > 0.9 * len(src) and np.all(src[tr.det_index] == 0)
    assert np.all(np.diff(tr.t) > 0) and tr.det_step.max() < len(tr)
    centre, yaw_err, iou = _errors(scn, tr.states, tr.t, 0)
    late = slice(len(tr) // 3, None)                      # after the first ~2 s
    assert np.sqrt(np.mean(centre[late] ** 2)) < 0.4
    assert np.mean(yaw_err[late]) < 2.0
    assert np.mean(iou[late]) > 0.75
    assert np.all(tr.labels == STRAIGHT)


@pytest.mark.parametrize("length", [4.6, 11.0])
def test_side_view_length_is_not_overestimated(length: float) -> None:
    """A car (a truck) crossing the boresight 40 m ahead, seen from the side: the visible
    extent measures its length, the contour does not grow beyond the detections (and a
    truck's grows to its length), so the centre is right along the heading too."""
    scn, _ = constructed([straight((40.0, -35.0), np.pi / 2, 10.0)], [(length, 2.0)], 6.0,
                         [lane((40.0, -80.0), (40.0, 80.0))])
    ts = track_scenario(scn, scn.truth.sensor_pose, TrackingConfig())
    assert len(ts) == 1
    tr = ts.tracks[0]
    late = tr.t > tr.t[0] + 2.0
    est = tr.states[late, 6] + tr.states[late, 16]                      # r(0) + r(pi)
    centre, yaw_err, _ = _errors(scn, tr.states[late], tr.t[late], 0)
    if length < 5.0:
        assert abs(np.median(est) - length) < 0.4
        assert np.sqrt(np.mean(centre**2)) < 0.3
    else:
        # 20 smooth radii cannot follow an 11 x 2 m box's sharp corners: the contour comes
        # out about 1 m short and too wide, its centre ~0.5 m away from the sensor
        assert abs(np.median(est) - length) < 1.3
        assert np.sqrt(np.mean(centre**2)) < 0.8
    assert np.mean(yaw_err) < 2.0


def test_two_cars_side_by_side_keep_identities() -> None:
    """Two cars on parallel lanes 3.5 m apart, same speed, through the whole field of view."""
    paths = [straight((150.0, -6.0), np.pi, 12.0), straight((150.0, -9.5), np.pi, 12.0)]
    lanes = [lane((230.0, -6.0), (-60.0, -6.0), 0), lane((230.0, -9.5), (-60.0, -9.5), 1)]
    scn, src = constructed(paths, [(4.6, 1.9), (4.4, 1.8)], 9.0, lanes)
    ts = track_scenario(scn, scn.truth.sensor_pose, TrackingConfig())
    assert len(ts) == 2
    for tr in ts.tracks:
        owner = np.bincount(src[tr.det_index], minlength=2)
        vid = int(np.argmax(owner))
        assert owner[vid] >= 0.98 * owner.sum()            # no detections stolen
        assert tr.t[-1] - tr.t[0] > 8.0                    # followed over the whole pass
        centre, _, _ = _errors(scn, tr.states, tr.t, vid)
        # the rear faces are never seen: the length, hence the centre, drifts a little
        assert np.median(centre) < 0.7
    owners = {int(np.argmax(np.bincount(src[tr.det_index], minlength=2))) for tr in ts.tracks}
    assert owners == {0, 1}


def _one_track(x0: tuple[float, float, float], size: tuple[float, float] | None,
               P: np.ndarray, cfg: TrackingConfig | None = None) -> Tracker:
    """A tracker (``cfg``, default: the defaults; 120 deg / 200 m FOV at the origin, no birth
    zones or lanes) holding one confirmed track at x, y, v = x0 (m, m, m/s; yaw 0) with a
    rectangle contour of ``size`` (length, width; m; None: the GP mean) and covariance P."""
    fov = FieldOfView.of(np.eye(4), 120.0, 200.0)
    none = BirthZones(np.zeros((0, 2)), np.zeros(0), np.zeros(0))
    tracker = Tracker(cfg or TrackingConfig(), fov, none, LaneHeadings.of([]))
    x = np.zeros(N_STATE)
    x[[0, 1, 2]] = x0
    x[6:] = tracker.gp.mu if size is None else rectangle_radius(tracker.gp.angles, *size)
    tracker.x, tracker.P = x[None], P[None]
    tracker.recs = [_Record(0, 0, True, 0.0)]
    return tracker


@pytest.mark.parametrize("gate_doppler", [2.0, 0.0])
def test_doppler_gate_keeps_an_oncoming_vehicle_apart(gate_doppler: float) -> None:
    """A track receding at 10 m/s 100 m out; detections on its contour with its range rate
    join it, detections at the same places moving towards the sensor (an oncoming vehicle
    passing it) do not -- unless the Doppler gate is off."""
    tracker = _one_track((100.0, -5.0, 10.0), None, 0.01 * np.eye(N_STATE),
                         TrackingConfig(gate_doppler=gate_doppler))
    z = np.array([[97.7, -5.0], [98.5, -4.1], [99.5, -5.9], [100.0, -4.1]])
    rng = np.hypot(z[:, 0], z[:, 1])
    receding = 10.0 * z[:, 0] / rng                                # range rate of the track
    for dop, joins in ((receding, True), (-receding, gate_doppler == 0.0)):
        owner, _ = tracker._associate(_Frame(z, rng, dop, np.arange(4)))
        assert np.all(owner == (0 if joins else -1))


@pytest.mark.parametrize("sigma_pos", [1.5, 0.05])
def test_a_young_tracks_wide_gate_does_not_take_the_vehicle_behind(sigma_pos: float) -> None:
    """An 11 x 2.5 m truck track heading +x 30 m out, its near side (y = -1.25) seen from the
    sensor at the origin. A young track's centre std. dev. (1.5 m per axis) widens its gate
    to gate_max + gate_long_extra = 5.5 m along the heading; a car 5 m behind the truck (an
    empty gap) is inside it but does not join, while the rest of a truck longer than its
    contour, continuing its returns with no gap, does (the chain). A settled track (0.05 m)
    gates both out by its width alone, and the chain takes the contiguous returns."""
    P = np.diag(np.r_[sigma_pos**2, sigma_pos**2, np.full(N_STATE - 2, 1e-4)])
    tracker = _one_track((0.0, 30.0, 10.0), (11.0, 2.5), P)
    side = np.column_stack([np.linspace(-5.0, 5.0, 11), np.full(11, 28.75)])
    car = np.column_stack([np.linspace(-14.5, -10.5, 5), np.full(5, 28.9)])   # 5 m gap
    rest = np.column_stack([np.linspace(-6.2, -9.8, 5), np.full(5, 28.75)])   # 0.9 m steps
    for behind, joins in ((car, False), (rest, True)):
        z = np.vstack([side, behind])
        rng = np.linalg.norm(z, axis=1)
        dop = 10.0 * z[:, 0] / rng                                 # the track's range rate
        owner, _ = tracker._associate(_Frame(z, rng, dop, np.arange(len(z))))
        assert np.all(owner[:11] == 0)
        assert np.all(owner[11:] == (0 if joins else -1)), owner


@pytest.mark.parametrize("age", [10, 40])
def test_end_on_occupancy_forgets_updates_older_than_span_history(age: int) -> None:
    """A car track (4.5 m) receding end-on 30 m out: its occupancy pool holds the distances
    behind its rear of an end-on update ``age`` frames ago that reached 8.8 m (measured along
    another heading, e.g. a young track's). Within span_history frames they bridge to the
    new frame's returns (the occupied length reaches 8.8 m less the last points); older,
    they are forgotten and the occupied length is the car's own."""
    P = np.diag(np.full(N_STATE, 1e-4))
    tracker = _one_track((32.25, 0.0, 10.0), (4.5, 1.8), P)
    tracker.frame = 100
    rec = tracker.recs[0]
    rec.hits = tracker.cfg.occupancy_min_updates
    old = np.linspace(0.0, 8.8, 45)
    rec.occupancy = [(100 - age, -1, old, np.ones(len(old), dtype=bool),
                      np.ones(len(old), dtype=bool))]
    u = np.linspace(30.0, 34.4, 23)                          # rear face and side, 0-4.4 m
    z = np.column_stack([u, np.where(u > 30.2, -0.9, np.linspace(-0.9, 0.9, 23))])
    rng = np.linalg.norm(z, axis=1)
    det = _Frame(z, rng, 10.0 * z[:, 0] / rng, np.arange(len(z)))
    owner, _ = tracker._associate(det)
    assert np.all(owner == 0)
    assert tracker._occupied_length(rec, det, owner, 0) == -1           # rear seen
    k = tracker.cfg.occupancy_min_points
    if age < tracker.cfg.span_history:
        assert rec.occupied_length == pytest.approx(old[-k], abs=1e-9)
    else:
        assert rec.occupied_length < 4.5


def _truck_side_frame(incidence_deg: float) -> tuple[Tracker, _Frame]:
    """A car-sized track (4.6 x 2.5 m) on the front of a 12 m truck approaching the sensor
    (at the origin), 50 m out along +x with its heading ``incidence_deg`` off the line of
    sight, and one frame of returns: its front face, and its side facing the sensor 0-9.5 m
    behind the front in 0.5 m steps (the pooled frames of a truck's sparse side)."""
    a = np.deg2rad(incidence_deg)
    tracker = _one_track((50.0, 0.0, 10.0), (4.6, 2.5), np.diag(np.full(N_STATE, 1e-4)))
    tracker.x[0, 4] = np.pi - a
    h = np.array([np.cos(np.pi - a), np.sin(np.pi - a)])
    n = np.array([-h[1], h[0]])
    side = 1.2 * np.sign(n @ -tracker.x[0, :2])          # the side facing the sensor
    front = tracker.x[0, :2] + 2.3 * h
    face = front + np.outer(np.linspace(-1.0, 1.0, 5), n)
    rest = front - np.outer(np.linspace(0.0, 9.5, 20), h) + side * n
    z = np.vstack([face, rest])
    rng = np.linalg.norm(z, axis=1)
    dop = -10.0 * (z @ -h) / rng           # the track's range rate, approaching at 10 m/s
    return tracker, _Frame(z, rng, dop, np.arange(len(z)))


@pytest.mark.parametrize(("incidence", "hits", "measured"), [
    (10.0, 10, True), (30.0, 10, True), (45.0, 10, False), (10.0, 1, True), (30.0, 9, False)])
def test_occupied_length_is_measured_up_to_37_deg_on_an_established_track(
        incidence: float, hits: int, measured: bool) -> None:
    """The truck's front is seen (+1) and its side returns reach 9.5 m behind it: the
    occupied length is measured end-on and at 30 deg off the heading (sin 0.5 <=
    ``occupancy_max_incidence``), not at 45 deg (the side seen broadside: the span and
    the chain measure it); on a track with fewer than ``occupancy_min_updates`` updates
    end-on only (``occupancy_young_incidence``)."""
    tracker, det = _truck_side_frame(incidence)
    rec = tracker.recs[0]
    rec.hits = hits
    assert tracker.cfg.occupancy_min_updates == 10
    owner, _ = tracker._associate(det)
    end = tracker._occupied_length(rec, det, owner, 0)
    if measured:
        assert end == 1
        k = tracker.cfg.occupancy_min_points
        assert rec.occupied_length == pytest.approx(9.5 - 0.5 * (k - 1), abs=0.3)
    else:
        assert end == 0 and rec.occupied_length == 0.0 and not rec.occupancy


@pytest.mark.parametrize("lateral", [1.2, 2.5])
def test_occupied_length_counts_corridor_returns_beside_the_contour_only(
        lateral: float) -> None:
    """The same track at 30 deg, its own returns on its front face and side 0-4.5 m behind
    the front; free returns in its corridor continue them to 9.5 m behind the front, 1.2 m
    (the truck's side) or 2.5 m (a car in the next lane, inside a grown gate) to the side of
    the heading: the first count, the second do not (the contour's half width 1.25 m and
    TOWARD_SIDE_MARGIN)."""
    tracker, det = _truck_side_frame(30.0)
    rec = tracker.recs[0]
    rec.hits = tracker.cfg.occupancy_min_updates
    x = tracker.x[0]
    h = np.array([np.cos(x[4]), np.sin(x[4])])
    n = np.array([-h[1], h[0]])
    lo = (det.z - x[:2]) @ h
    beyond = lo < 2.3 - 4.6 - 0.2                  # behind the contour's rear (4.6 m)
    z = det.z.copy()
    z[beyond] += np.outer((lateral - 1.2) * np.sign((z[beyond] - x[:2]) @ n), n)
    det = _Frame(z, np.linalg.norm(z, axis=1), det.doppler, det.index)
    owner = np.where(beyond, -1, 0)
    tracker._corridor = beyond[None].copy()
    assert tracker._occupied_length(rec, det, owner, 0) == 1
    k = tracker.cfg.occupancy_min_points
    if lateral < 2.0:
        assert rec.occupied_length == pytest.approx(9.5 - 0.5 * (k - 1), abs=0.3)
    else:
        assert rec.occupied_length < 4.6


def _receding_frames(case: str, frames: int, seed: int = 0) -> list[_Frame]:
    """Frames of returns behind a track's car-sized contour (x 32.7-37.3 m, y 0, receding
    along +x from a sensor at the origin: its rear is seen end-on). "truck": the rest of a
    12.3 m truck (x 25-37.3 m): 4 returns on its rear face, 3 along its side at y -1.25 m,
    anywhere; "follower": a 4.5 m car 3 m behind the contour (rear face at 25.2 m, side
    returns up to its front at 29.7 m) and 3 side returns on the contour's own part; a
    "neighbour": the truck's returns 3.5 m to the side (the next lane)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(frames):
        if case == "follower":
            face = np.column_stack([25.2 + rng.normal(0, 0.1, 4), rng.uniform(-0.9, 0.9, 4)])
            side = np.column_stack([np.r_[rng.uniform(25.2, 29.7, 3), rng.uniform(32.7, 37.3, 3)],
                                    np.full(6, -0.9)])
        else:
            lat = -3.5 if case == "neighbour" else 0.0
            face = np.column_stack([25.0 + rng.normal(0, 0.1, 4), lat + rng.uniform(-1.2, 1.2, 4)])
            side = np.column_stack([rng.uniform(25.0, 37.3, 3), np.full(3, lat - 1.25)])
        z = np.vstack([face, side])
        r = np.linalg.norm(z, axis=1)
        out.append(_Frame(z, r, 10.0 * z[:, 0] / r, np.arange(len(z))))
    return out


@pytest.mark.parametrize(("case", "toward", "reaches"), [
    ("truck", True, True), ("truck", False, False), ("follower", True, False),
    ("neighbour", True, False)])
def test_a_track_on_a_vehicles_far_part_grows_towards_the_sensor(case: str, toward: bool,
                                                                 reaches: bool) -> None:
    """A car-sized track (4.6 x 2.5 m) on the front of a 12.3 m truck receding end-on (born
    on its far part: a truck that passed the sensor enters the view front first). The truck's
    side returns between the contour and its rear face, sparse in each frame (no chain), fill
    densely pooled over the frames: the contour grows towards the sensor until its rear is
    the truck's (``tracking.occupancy_toward``; 0.5 m short: the seen face's range noise is
    left out), its front about in place. A following car 3 m
    behind (an empty band) and a truck in the next lane (beside a young track's wide gate,
    not beside its contour) do not grow it."""
    sd = 1.5 if case == "neighbour" else 0.01            # a young track's wide gate
    P = np.diag(np.r_[sd**2, sd**2, np.full(N_STATE - 2, 1e-4)])
    tracker = _one_track((35.0, 0.0, 10.0), (4.6, 2.5), P, TrackingConfig(
        occupancy_toward=toward))
    tracker.recs[0].hits = tracker.cfg.span_history            # an established track
    half = tracker.gp.n // 2
    for det in _receding_frames(case, 60):
        tracker.frame += 1
        owner, _ = tracker._associate(det)
        tracker._span_length(det, owner, np.array([0]))
        tracker.recs[0].states.append(tracker.x[0].copy())         # the row of the frame
    x = tracker.x[0]
    front, rear = x[0] + x[6], x[0] - x[6 + half]
    assert front == pytest.approx(37.3, abs=0.8)      # the length bound may pull it in
    if reaches:
        assert rear == pytest.approx(25.0, abs=0.6), rear
    else:
        assert rear > 32.0, rear
    # a young track that grew: its earlier rows are retrodicted from their far end
    assert (tracker.recs[0].toward_rows > 0) == reaches


@pytest.mark.parametrize("reach_now", [False, True])
def test_toward_growth_goes_no_farther_than_this_frames_returns(reach_now: bool) -> None:
    """A car track (4.5 m) receding end-on whose pool holds an update of 10 frames ago with
    returns up to 3 m beyond its rear (measured before its updates moved the rear there):
    this frame's returns end at its rear face, so it does not grow towards the sensor; with
    this frame's returns 3 m beyond the rear too, it does."""
    P = np.diag(np.full(N_STATE, 1e-4))
    tracker = _one_track((32.25, 0.0, 10.0), (4.5, 1.8), P)
    tracker.frame = 100
    rec = tracker.recs[0]
    rec.hits = tracker.cfg.span_history
    old = np.linspace(-3.0, 4.4, 40)
    rec.occupancy = [(90, -1, old, old >= 0.0, np.ones(len(old), dtype=bool))]
    u = np.linspace(27.0 if reach_now else 30.0, 34.4, 23)
    z = np.column_stack([u, np.where(u > 30.2, -0.9, np.linspace(-0.9, 0.9, 23))])
    rng = np.linalg.norm(z, axis=1)
    det = _Frame(z, rng, 10.0 * z[:, 0] / rng, np.arange(len(z)))
    owner, _ = tracker._associate(det)
    rear = tracker.x[0, 0] - tracker.x[0, 6 + tracker.gp.n // 2]
    tracker._span_length(det, owner, np.array([0]))
    moved = rear - (tracker.x[0, 0] - tracker.x[0, 6 + tracker.gp.n // 2])
    if reach_now:
        assert moved > 0.5, moved
    else:
        assert moved == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize(("width", "misfit", "ends"), [
    (2.5, 0.2, False), (4.5, 0.2, True), (2.5, 1.2, True)])
def test_a_diverged_track_ends_and_is_reported_up_to_its_last_calm_row(
        width: float, misfit: float, ends: bool) -> None:
    """A confirmed track with 30 rows whose last calm row (misfit at most half
    ``diverge_excess``) is row 19: a contour wider than ``max_width`` (no single road
    vehicle) or a misfit beyond ``diverge_excess`` ends it, and it is reported up to row 19
    with only the detections of those rows; a plausible, fitting track lives on."""
    tracker = _one_track((30.0, 0.0, 10.0), (10.0, width), np.diag(np.full(N_STATE, 1e-4)))
    rec = tracker.recs[0]
    rec.confirmed, rec.hits, rec.misfit = True, 30, misfit
    for step in range(30):
        rec.t.append(0.05 * step)
        rec.states.append(tracker.x[0].copy())
        rec.len_var.append(0.01)
        rec.held.append(False)
        rec.occupied.append(0.0)
        rec.det_index.append(np.array([2 * step, 2 * step + 1]))
        rec.det_step.append(np.array([step, step]))
    rec.last_update_step, rec.calm_step, rec.last_update_t = 29, 19, 1.45
    tracker.t = 1.45
    tracker._manage(1.45)
    assert (len(tracker.recs) == 0) == ends
    if ends:
        (tr,) = tracker.done
        assert len(tr.t) == 20
        assert np.array_equal(tr.det_step, np.repeat(np.arange(20), 2))


@pytest.mark.parametrize("shift", [0.0, 1.5])
def test_a_truck_tracks_misfit_is_its_returns_distance_to_the_contour(shift: float) -> None:
    """A truck track heading +x 50 m out and 20 m to the left, seen from the sensor at the
    origin, with the contour the tracker held for a 15.4 m truck on the independent
    generator's held-out junction 11 seed 1 (1.25 s; 13.9 x 2.8 m, its smooth radii 18 deg
    off the axis longer than on it); returns of a 13.9 x 2.5 m box about its centre along
    its near side and its rear face with 0.2 m noise, one in four on its top (inside the
    contour). The radial excess about the centre (along the ray from it) of the returns on
    its top reaches metres (that track's median of it passed the old divergence threshold,
    1 m, 2 s later though it followed its truck); a return inside lies at most half the
    width from the contour, and the misfit, the returns' distance to the contour, settles
    below ``diverge_excess``. The same returns ``shift`` = 1.5 m to the right (the track
    slid off its vehicle) exceed it."""
    rng = np.random.default_rng(4)
    tracker = _one_track((50.0, 20.0, 8.0), None, np.diag(np.full(N_STATE, 1e-4)))
    tracker.x[0, N_KIN:] = [6.96, 7.27, 2.06, 1.54, 1.39, 1.37, 1.39, 1.54, 2.06, 7.26, 6.95,
                            7.25, 2.03, 1.52, 1.42, 1.42, 1.43, 1.58, 2.09, 7.29]
    side = np.column_stack([rng.uniform(43.05, 56.95, 12), np.full(12, 18.75)])
    rear = np.column_stack([np.full(4, 43.05), rng.uniform(18.75, 21.25, 4)])
    top = np.column_stack([rng.uniform(43.05, 56.95, 5), rng.uniform(18.75, 21.25, 5)])
    z = np.vstack([side, rear, top]) + rng.normal(0.0, 0.2, (21, 2)) - [0.0, shift]
    excess = tracker._local(z)[2][0]
    owner = np.zeros(len(z), dtype=np.int64)
    for _ in range(40):
        tracker._misfit(owner, excess, z, 0.1)
    limit = tracker.cfg.diverge_excess
    if shift == 0.0:
        assert np.max(np.abs(excess[-5:])) > 2.0
        # the returns inside count at their distance to the contour (0.28 against 0.50 m)
        assert tracker.recs[0].misfit < min(limit, 0.7 * np.median(np.abs(excess)))
    else:
        assert tracker.recs[0].misfit > limit


def _interior(z: np.ndarray, sigmas: float) -> np.ndarray:
    """The extra variance (m^2) of the outline rows of detections z (k, 2) on a 4.5 x 1.8 m
    car track at (30, 0) heading +x away from the sensor at the origin (its rear face at
    x = 27.75 m faces it), ``interior_sigmas`` = sigmas."""
    cfg = TrackingConfig(interior_sigmas=sigmas)
    tracker = _one_track((30.0, 0.0, 8.0), (4.5, 1.8), np.diag(np.full(N_STATE, 1e-4)), cfg)
    _, pts = tracker._dense_contour(tracker.x)
    sensor = tracker.fov.sensor
    theta, normal = closest_on_chain(z[None], pts, tracker.cand_theta,
                                     contour_candidates(pts, sensor))
    valid = np.ones((1, len(z)), dtype=bool)
    return interior_variance(z[None], valid, pts, theta, normal, sensor, cfg.sigma_range,
                             np.deg2rad(cfg.sigma_azimuth_deg), cfg.sigma_contour,
                             sigmas)[0]


@pytest.mark.parametrize("sigmas", [1.0, 0.0])
def test_returns_deep_inside_the_contour_weigh_less(sigmas: float) -> None:
    """Eight returns on the car's rear face and two from its roof, 1 and 2 m behind it: the
    roof rows gain about the square of their depth below the face's median offset as
    variance (1 and 4 m^2; the face rows none); off (0), nothing. Returns that all lie 0.8 m
    inside the contour (a contour too long) gain none: the depth counts from their median."""
    face = np.column_stack([np.full(8, 27.75), np.linspace(-0.7, 0.7, 8)])
    roof = np.array([[28.75, 0.1], [29.75, -0.1]])
    extra = _interior(np.vstack([face, roof]), sigmas)
    if sigmas == 0.0:
        assert np.all(extra == 0.0)
        return
    np.testing.assert_allclose(extra[:8], 0.0)
    np.testing.assert_allclose(extra[8:], [1.0, 4.0], rtol=0.1)
    np.testing.assert_allclose(_interior(face + [0.8, 0.0], sigmas), 0.0)


@pytest.mark.parametrize("towards", [True, False])
def test_a_track_heading_against_its_vehicles_motion_diverges(towards: bool) -> None:
    """A car track 30 m out heading +x (away from the sensor at the origin) at 0.5 m/s; its
    returns, on its contour, come from a car driving towards the sensor at 3 m/s (range rate
    -3 m/s): every update wants a negative speed (clipped to 0), and after
    ``reverse_updates`` of them in a row the track has diverged. Returns of a car driving
    away at 3 m/s, as the track heads, leave it alive."""
    tracker = _one_track((30.0, 0.0, 0.5), (4.5, 1.9), np.diag(np.r_[
        0.01, 0.01, 1.0, 1.0, 0.01, 0.01, np.full(N_STATE - 6, 1e-3)]))
    rec = tracker.recs[0]
    rec.confirmed = True
    z = np.array([[27.75, -0.5], [27.75, 0.4], [28.5, -0.95], [30.0, -0.95], [31.5, -0.95]])
    rng = np.linalg.norm(z, axis=1)
    dop = (-3.0 if towards else 3.0) * z[:, 0] / rng
    owner = np.zeros(len(z), dtype=np.int64)
    cfg = tracker.cfg
    for _ in range(cfg.reverse_updates):
        assert len(tracker.recs) == 1
        tracker.t += 0.05
        tracker._predict(0.05)
        tracker._update(_Frame(z, rng, dop, np.arange(len(z))), owner)
        rec.last_update_t = tracker.t
        tracker._manage(tracker.t)
    assert (rec.reverse_run == cfg.reverse_updates) == towards
    assert (len(tracker.recs) == 0) == towards
    assert tracker.x.shape[0] == (0 if towards else 1)


@pytest.mark.parametrize("oncoming", [False, True])
def test_a_young_tracks_loose_gate_holds_births_of_its_own_motion_only(oncoming: bool) -> None:
    """The car 5 m behind a young 11 m truck track joins it neither way. Its returns inside
    the truck's gate only by the gate's growth with the centre's std. dev. (1.5 m: up to
    gate_max + gate_long_extra behind the truck's rear) are kept from births for the frame
    when they move with the truck (they may yet be the truck's); moving towards the sensor
    (an oncoming vehicle, outside the Doppler gate) they are free to seed a birth."""
    P = np.diag(np.r_[2.25, 2.25, np.full(N_STATE - 2, 1e-4)])
    tracker = _one_track((0.0, 30.0, 10.0), (11.0, 2.5), P)
    z = np.vstack([np.column_stack([np.linspace(-5.0, 5.0, 11), np.full(11, 28.75)]),
                   np.column_stack([np.linspace(-14.5, -10.5, 5), np.full(5, 28.9)])])
    rng = np.linalg.norm(z, axis=1)
    dop = 10.0 * z[:, 0] / rng
    if oncoming:
        dop[11:] = -dop[11:]
    owner, _ = tracker._associate(_Frame(z, rng, dop, np.arange(len(z))))
    assert np.all(owner[:11] == 0) and np.all(owner[11:] == -1), owner
    cfg = tracker.cfg
    band = z[:, 0] >= -5.5 - cfg.gate_max - cfg.gate_long_extra
    assert band[11:].any() and not band[11:].all()
    assert np.all(tracker._held == (band & (np.arange(len(z)) >= 11) & (not oncoming)))


def test_a_young_track_misplaced_along_its_vehicle_keeps_its_returns() -> None:
    """A young car track (4.6 x 1.9 m contour, centre std. dev. 1.5 m) placed 2.5 m ahead of
    its car: the car's returns behind the contour's rear, 2 m beyond the returns inside it
    (a gap: corner and wheel returns), join it -- a shift of the contour within its
    uncertainty explains them (the returns span 4.4 m, at most the contour's length plus the
    ungrown gate at both ends); they are neither left free for a second birth."""
    P = np.diag(np.r_[2.25, 2.25, np.full(N_STATE - 2, 1e-4)])
    tracker = _one_track((0.0, 30.0, 10.0), (4.6, 1.9), P)
    z = np.column_stack([[-1.6, -1.9, -2.2, -4.4, -5.2, -6.0], np.full(6, 29.05)])
    rng = np.linalg.norm(z, axis=1)
    owner, _ = tracker._associate(_Frame(z, rng, 10.0 * z[:, 0] / rng, np.arange(6)))
    assert np.all(owner == 0), owner
    assert not tracker._held.any()


def _born_on_the_far_part(reanchor: bool, seed: int, group: int = -1
                          ) -> tuple[float, float, float, float]:
    """A 4 x 1.8 m car receding along +x at 10 m/s, 3 m beside the sensor at the origin,
    whose track was born from 3 returns on its front part: a birth's box (4.6 x 1.9 m, the
    birth covariance) with its sensor-side end there, the car's front 1 m inside it and its
    rear 3 m behind it (the centres 3.3 m apart). 20 frames of 20 returns on the car's
    visible edges follow. Returns the largest centre error along the heading (m) and |yaw|
    (deg) over the first 5 updates, the contour's final length (m) and the birth row's
    centre error along the heading (m)."""
    cfg = TrackingConfig(birth_reanchor=reanchor)
    P = np.zeros((N_STATE, N_STATE))
    P[:6, :6] = np.diag(np.square([1.0, 1.0, 3.0, 1.0, np.deg2rad(15.0), 0.15]))
    c0, v = np.array([32.0, -3.0]), 10.0
    tracker = _one_track((c0[0] + 3.3, c0[1] + 0.5, v), (4.6, 1.9), P, cfg)
    tracker.P[0, 6:, 6:] = tracker.gp.K
    rec = tracker.recs[0]
    rec.hits, rec.n_det, rec.group = 1, 3, group
    rec.states.append(tracker.x[0].copy())                 # the birth row
    rng = np.random.default_rng(seed)
    along, yaw = [], []
    for j in range(1, 21):
        c = c0 + [v * j / RATE, 0.0]
        z = _visible_edge_points(rng, c, 0.0, 4.0, 1.8, np.zeros(2), 20)
        z += rng.normal(0.0, 0.08, z.shape)
        r = np.linalg.norm(z, axis=1)
        tracker.step(j / RATE, _Frame(z, r, v * z[:, 0] / r, np.arange(20)))
        along.append(abs(tracker.x[0, 0] - c[0]))
        yaw.append(abs(np.degrees(tracker.x[0, 4])))
    x = tracker.x[0]
    # the birth row holds the re-placed box (at the birth's time: the car's centre at x 32)
    birth_along = abs(rec.states[0][0] - c0[0])
    return max(along[:5]), max(yaw[:5]), float(x[6] + x[6 + tracker.gp.n // 2]), birth_along


@pytest.mark.parametrize("seed", [0, 2, 4])
def test_a_track_born_on_a_vehicles_far_part_is_replaced_at_its_first_update(seed: int
                                                                            ) -> None:
    """Born from a few returns on the far part of its car (the near part withheld next to
    the blind range), a track's box is metres ahead of the car. Its first update, with
    7 times the birth's returns, re-places the box (``birth_reanchor``): it follows the car
    within 0.5 m and 5 deg from then on and keeps a car's length, and its birth row holds
    the re-placed box (the smoothers' and the joint's prior on a track's first state: a
    truck's birth row left 7.8 m off pulled the joint 0.2 m off on the real map). Without
    it the UKF turned the box by 15-38 deg to reach the returns and the contour grew
    (robustness combined seed 5: 8 m for 14 s). A track in a heading-hypothesis group is
    left to the rivalry."""
    along, yaw, length, birth = _born_on_the_far_part(True, seed)
    assert along < 0.5 and yaw < 5.0 and length < 4.8, (along, yaw, length)
    assert birth < 0.5, birth
    off = _born_on_the_far_part(False, seed)
    assert off[0] > 0.8 and off[1] > 2.5 and off[3] == pytest.approx(3.3), off
    assert _born_on_the_far_part(True, seed, group=0) == off


@pytest.mark.parametrize(("size", "long"), [((11.0, 2.55), True), ((4.5, 1.8), False)])
def test_head_on_long_vehicle_gets_a_long_contour(size: tuple[float, float],
                                                  long: bool) -> None:
    """A truck (a car) approaching head-on from 150 m on a lane 3 m beside the sensor: only
    its front is seen, so its length is unobservable; once its width (2.55 m) is measured
    (here within ~6 s) it is a long vehicle and its centre lies behind the front by about
    half a truck's length, while a car keeps the car-sized contour."""
    scn, src = constructed([straight((150.0, -3.0), np.pi, 10.0)], [size], 10.0,
                           [lane((230.0, -3.0), (-60.0, -3.0))], k=25)
    ts = track_scenario(scn, scn.truth.sensor_pose, TrackingConfig())
    tr = max(ts.tracks, key=lambda t: len(t.det_index))
    assert len(tr.det_index) > 0.9 * len(src)
    late = tr.t > tr.t[0] + 7.0
    est = np.median(tr.states[late, 6] + tr.states[late, 16])             # r(0) + r(pi)
    centre, _, _ = _errors(scn, tr.states[late], tr.t[late], 0)
    if long:
        assert est > 8.5
        assert np.sqrt(np.mean(centre**2)) < 1.2          # car-sized contour: ~3 m
    else:
        assert est < 5.5
        assert np.sqrt(np.mean(centre**2)) < 0.4


def test_tracking_in_coarse_frame_follows_t_coarse() -> None:
    """The same traffic recorded by a rotated, tilted sensor (radar points in its frame S)
    and tracked with T = S -> L gives the same tracks (in L) as an untilted sensor at the same
    place: tracking runs in C = T(S)."""
    t = np.array([3.0, -2.0, 6.0])
    upright = se3(np.eye(3), t)
    tilted = se3(rot_from_ypr(0.4, np.deg2rad(4.0), np.deg2rad(-1.0)), t)
    args = ([straight((90.0, 12.0), np.pi, 9.0)], [(4.6, 1.9)], 4.0,
            [lane((200.0, 12.0), (-50.0, 12.0))])
    scenarios = [constructed(*args, pose=pose)[0] for pose in (upright, tilted)]
    assert not np.allclose(scenarios[0].radar.xyz, scenarios[1].radar.xyz, atol=1.0)
    a, b = (track_scenario(scn, pose, TrackingConfig())
            for scn, pose in zip(scenarios, (upright, tilted)))
    assert len(a) == len(b) == 1
    np.testing.assert_allclose(a.tracks[0].t, b.tracks[0].t)
    np.testing.assert_allclose(a.tracks[0].states, b.tracks[0].states, atol=1e-6)
    np.testing.assert_array_equal(b.T_frame_to_L, np.eye(3))


def test_birth_zones_at_fov_entries() -> None:
    fov = FieldOfView.of(np.eye(4), 90.0, 100.0)           # +-45 deg about +x, 100 m
    lanes = [
        lane((60.0, -120.0), (60.0, 120.0), 0),            # enters through the right edge
        lane((-20.0, 60.0), (-20.0, -60.0), 1),            # never in the FOV
        lane((200.0, 0.0), (0.0, 0.0), 2),                 # enters at max range
        lane((20.0, 5.0), (200.0, 5.0), 3),                # starts inside: entry at its start
    ]
    zones = BirthZones.from_map(lanes, fov, radius=10.0, depth=5.0)
    assert len(zones) == 3
    order = np.argsort(zones.centre[:, 0])
    c, yaw = zones.centre[order], np.rad2deg(zones.yaw[order])
    # lane 3 starts inside the FOV (no predecessor): its entry is its start (+ depth)
    np.testing.assert_allclose(c[0], [25.0, 5.0], atol=1.5)
    assert yaw[0] == pytest.approx(0.0, abs=1.0)
    # lane 0 crosses the -45 deg edge at (60, -60); the zone is 5 m further along the lane
    np.testing.assert_allclose(c[1], [60.0, -55.0], atol=1.5)
    assert yaw[1] == pytest.approx(90.0, abs=1.0)
    # lane 2 enters at 100 m
    np.testing.assert_allclose(c[2], [95.0, 0.0], atol=1.5)
    assert abs(wrap_angle(np.deg2rad(yaw[2]) - np.pi)) < np.deg2rad(1.0)
    assert zones.locate(np.array([60.0, -52.0])) is not None
    assert zones.locate(np.array([30.0, 30.0])) is None
    explicit = BirthZones.explicit([[1.0, 2.0, 5.0, 90.0]])
    assert explicit.locate(np.array([1.0, 6.0])) == 0
    assert explicit.yaw[0] == pytest.approx(np.pi / 2)


def test_kappa_labels() -> None:
    states = np.zeros((5, N_STATE))
    states[:, 2] = [10.0, 10.0, 10.0, 0.5, -10.0]          # v
    states[:, 5] = [0.2, -0.2, 0.05, 0.3, 0.2]             # yaw rate -> kappa 0.02, -0.02...
    np.testing.assert_array_equal(kappa_labels(states, 0.01, 1.0),
                                  [LEFT, RIGHT, STRAIGHT, STRAIGHT, RIGHT])


def test_unknown_measurement_model_is_rejected() -> None:
    scn, _ = constructed([straight((80.0, 0.0), np.pi, 8.0)], [(4.6, 1.9)], 0.5, [])
    with pytest.raises(ValueError, match="measurement_model"):
        track_scenario(scn, np.eye(4), TrackingConfig(), measurement_model="bogus")


def test_simulated_intersection_regression_guard() -> None:
    """A short simulated intersection (30 s, 20 vehicles, oracle pose) tracked with both
    measurement models.

    This guards the current level; the issue-4 acceptance bar (centre RMS <= 0.49 m per-track
    mean, yaw <= 3.8 deg, IoU >= 0.59, >= 60 % tracked on >= 50 vehicles) is checked by
    bench/tracking_speed.py on the full runs. Values at the time of writing: sensor-aware share
    0.92, per-track RMS 0.30 m (pooled 0.31 m), yaw 0.84 deg, IoU 0.83, no false track; plain
    per-track RMS 0.70 m (pooled 0.80 m), IoU 0.62, 3 false tracks.
    """
    from fgloc.evaluation.tracking import evaluate_tracks
    from fgloc.sim import simulate

    scn = simulate("intersection", 1, duration=30.0, vehicles=20)
    pose = scn.truth.sensor_pose
    metrics = {}
    for model in ("sensor-aware", "plain"):
        ts = track_scenario(scn, pose, TrackingConfig(), measurement_model=model)
        metrics[model] = evaluate_tracks(ts, scn.truth, sensor_pose=pose,
                                         hfov_deg=scn.sensor.hfov_deg,
                                         max_range=scn.sensor.max_range)
    m = metrics["sensor-aware"]
    assert m.tracked_share >= 0.9
    assert m.centre_rms_track_mean < 0.4
    assert m.centre_rms < 0.45
    assert m.yaw_error_deg < 1.5
    assert m.iou >= 0.78
    assert m.false_tracks <= 1
    assert m.iou > metrics["plain"].iou + 0.1
    assert m.centre_rms_track_mean < metrics["plain"].centre_rms_track_mean
