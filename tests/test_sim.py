"""Scenario simulator: determinism, geometry/doppler vs truth, map vs ALS, labels, rates."""

from __future__ import annotations

import dataclasses
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from matplotlib.path import Path as MplPath
from scipy.spatial import cKDTree

from fgloc.config import from_dict
from fgloc.geo import pose_from_se3, transform_points
from fgloc.scenario import Scenario, resample_polyline
from fgloc.sim import CASES, SimConfig, SimResult, simulate, simulate_detailed
from fgloc.sim.config import AlsSimConfig, RadarSimConfig, RoadSimConfig, TrafficSimConfig
from fgloc.sim.radar import (
    CLUTTER,
    FALSE_ALARM,
    GHOST,
    GHOST_LOSS_DB,
    Points,
    facing_facades,
    ghost_points,
)
from fgloc.sim.scenery import box_corners
from fgloc.tracking.road_users import area_samples

GAMMA = 0.01
#: config variants, so that nothing is tuned to the defaults
VARIANTS: dict[str, SimConfig] = {
    "default": SimConfig(),
    "sparse-noisy": SimConfig(
        als=AlsSimConfig(extent=300.0, density=1.5, height_sigma=0.05, slope=(0.015, 0.02)),
        radar=RadarSimConfig(sigma_range=0.3, sigma_azimuth_deg=0.5, sigma_elevation_deg=1.0,
                             sigma_doppler=0.15, max_range=150.0, rate_hz=10.0),
    ),
    "dense-traffic": SimConfig(
        road=RoadSimConfig(lanes_per_direction=[2], lane_width=3.25),
        traffic=TrafficSimConfig(arrival_interval=1.2, class_mix=(0.4, 0.3, 0.3),
                                 stop_share=0.3),
    ),
}


@cache
def sim(case: str, seed: int, duration: float = 12.0, variant: str = "default") -> SimResult:
    return simulate_detailed(case, seed, duration, config=VARIANTS[variant])


def _radar_cfg(variant: str) -> RadarSimConfig:
    return VARIANTS[variant].radar


GEOMETRY_PARAMS = [
    pytest.param(case, seed, variant, id=f"{case}-s{seed}-{variant}")
    for case, seed, variant in [
        ("intersection", 1, "default"), ("intersection", 7, "sparse-noisy"),
        ("intersection", 3, "dense-traffic"), ("tjunction", 2, "default"),
        ("tjunction", 5, "dense-traffic"), ("curve", 4, "default"),
        ("curve", 8, "sparse-noisy"), ("straight", 6, "default"), ("straight", 9, "dense-traffic"),
    ]
]


# --------------------------------------------------------------------------------------------
# small independent helpers
# --------------------------------------------------------------------------------------------
def menger_label(left: np.ndarray, gamma: float = GAMMA) -> str:
    """Paper IV-A: Menger curvature of start/middle/end of the left bound, sign = orientation."""
    a, b, c = left[0, :2], left[len(left) // 2, :2], left[-1, :2]
    cross = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    k = 2.0 * abs(cross) / (np.linalg.norm(a - b) * np.linalg.norm(b - c) * np.linalg.norm(c - a))
    return "straight" if k <= gamma else ("left" if cross > 0 else "right")


def track_rows(res: SimResult, det: np.ndarray) -> np.ndarray:
    """(n, 6) truth state of each detection's source track at the detection's time."""
    scn = res.scenario
    out = np.full((len(det), 6), np.nan)
    for tr in scn.truth.tracks:
        m = res.source[det] == tr.id
        k = np.searchsorted(tr.states[:, 0], scn.radar.t[det][m] - 1e-9)
        out[m] = tr.states[k]
    return out


def horizontal_sigma(xyz_s: np.ndarray, pose: np.ndarray, cfg: RadarSimConfig) -> np.ndarray:
    """Std. dev. of the horizontal (L) position error of detections given the radar noise."""
    r = np.linalg.norm(xyz_s, axis=1)
    az = np.arctan2(xyz_s[:, 1], xyz_s[:, 0])
    el = np.arcsin(xyz_s[:, 2] / r)
    dirs = [
        (cfg.sigma_range, xyz_s / r[:, None]),
        (r * np.deg2rad(cfg.sigma_azimuth_deg),
         np.column_stack([-np.sin(az), np.cos(az), np.zeros_like(az)])),
        (r * np.deg2rad(cfg.sigma_elevation_deg),
         np.column_stack([-np.sin(el) * np.cos(az), -np.sin(el) * np.sin(az), np.cos(el)])),
    ]
    var = sum((s * np.linalg.norm((d @ pose[:3, :3].T)[:, :2], axis=1)) ** 2 for s, d in dirs)
    return np.sqrt(var)


def edge_distance(p: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Distance of (n, 2) points to the boundary of their (n, 4, 2) rectangles."""
    a = corners
    b = np.roll(corners, -1, axis=1)
    ab = b - a
    t = np.clip(np.sum((p[:, None] - a) * ab, axis=2) / np.sum(ab * ab, axis=2), 0, 1)
    return np.linalg.norm(p[:, None] - (a + t[..., None] * ab), axis=2).min(axis=1)


# --------------------------------------------------------------------------------------------
# determinism and API
# --------------------------------------------------------------------------------------------
def _arrays(scn) -> list[np.ndarray]:
    r, t = scn.radar, scn.truth
    out = [r.t, r.xyz, r.doppler, r.rcs, r.frame, scn.als.xyz, scn.als.classification,
           t.sensor_pose, np.asarray(scn.frame.origin), np.asarray(scn.sensor.approx_position)]
    out += [ll.left for ll in scn.lanelets.lanelets] + [ll.right for ll in scn.lanelets.lanelets]
    return out + [tr.states for tr in t.tracks]


@pytest.mark.parametrize("case", CASES)
def test_deterministic_per_seed(case: str) -> None:
    cfg = SimConfig(als=AlsSimConfig(density=0.5))
    a, b = (simulate(case, 11, duration=2.0, config=cfg) for _ in range(2))
    for x, y in zip(_arrays(a), _arrays(b), strict=True):
        np.testing.assert_array_equal(x, y)
    assert a.sensor == b.sensor
    c = simulate(case, 12, duration=2.0, config=cfg)
    assert not np.array_equal(a.truth.sensor_pose, c.truth.sensor_pose)
    assert len(a.radar) != len(c.radar) or not np.array_equal(a.radar.xyz, c.radar.xyz)


def test_vehicle_count_and_config_from_dict() -> None:
    cfg = from_dict(SimConfig, {"radar": {"rate_hz": 10.0}, "als": {"density": 0.5}}, None)
    scn = simulate("straight", 3, duration=4.0, vehicles=5, config=cfg)
    assert 1 <= len(scn.truth.tracks) <= 5
    np.testing.assert_allclose(np.diff(np.unique(scn.radar.t)), 0.1, atol=1e-9)
    assert np.all(np.diff(scn.radar.t) >= 0)
    assert scn.radar.frame.dtype == np.int64 and scn.radar.xyz.dtype == np.float64
    with pytest.raises(ValueError, match="unknown case"):
        simulate("roundabout", 0)


@pytest.mark.parametrize("case", CASES)
def test_scenario_contract(case: str) -> None:
    res = sim(case, 21)
    scn = res.scenario
    e0, n0, z0 = scn.frame.origin
    assert 676000 < e0 < 681000 and 5399000 < n0 < 5404000 and 360 < z0 < 380
    assert scn.crs == scn.sensor.crs == scn.truth.crs == "EPSG:25832"
    assert scn.path is None
    assert scn.als.xyz.dtype == np.float32 and scn.als.classification.dtype == np.uint8
    assert {1, 2, 5, 6, 11} <= set(np.unique(scn.als.classification).tolist())
    true_xy = scn.frame.to_world(scn.truth.sensor_pose[None, :2, 3])[0]
    assert np.linalg.norm(np.asarray(scn.sensor.approx_position) - true_xy) < 15.0
    x, y, z, yaw, pitch, roll = pose_from_se3(scn.truth.sensor_pose)
    dyaw = (scn.sensor.yaw_guess_deg - np.rad2deg(yaw) + 180) % 360 - 180
    assert abs(dyaw) < 15.0
    assert 2.0 <= np.rad2deg(pitch) <= 6.0 and abs(np.rad2deg(roll)) <= 1.5
    # mast height above the road: road = ground under the mast + road raise
    ground = scn.als.xyz[(scn.als.classification == 2)
                         & (np.hypot(scn.als.xyz[:, 0] - x, scn.als.xyz[:, 1] - y) < 4.0)]
    height = z - (np.median(ground[:, 2]) + AlsSimConfig().road_raise)
    assert 4.9 <= height <= 8.1 and abs(scn.sensor.approx_height - height) <= 0.3
    # the mast stands off every lanelet, a few metres from the nearest one
    inside = [MplPath(ll.polygon()).contains_point((x, y)) for ll in scn.lanelets.lanelets]
    assert not any(inside)
    bounds = np.vstack([np.vstack([ll.left, ll.right]) for ll in scn.lanelets.lanelets])
    assert 1.5 < np.hypot(bounds[:, 0] - x, bounds[:, 1] - y).min() < 8.0
    sizes = {name: [] for name in ("car", "van", "truck")}
    for tr, name in zip(scn.truth.tracks, res.vehicle_class, strict=True):
        sizes[name].append((tr.length, tr.width))
    for name, (lo, hi) in {"car": (3.8, 5.2), "van": (4.8, 6.3), "truck": (9.5, 12.5)}.items():
        assert all(lo < ln < hi for ln, _ in sizes[name])


# --------------------------------------------------------------------------------------------
# radar vs truth
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("case,seed,variant", GEOMETRY_PARAMS)
def test_detections_lie_on_true_footprints(case: str, seed: int, variant: str) -> None:
    res = sim(case, seed, variant=variant)
    scn = res.scenario
    det = np.flatnonzero(res.source >= 0)
    assert len(det) > 500
    st = track_rows(res, det)
    size = {tr.id: (tr.length, tr.width) for tr in scn.truth.tracks}
    lw = np.array([size[i] for i in res.source[det]])
    corners = box_corners(st[:, 1:3], st[:, 3], lw[:, 0], lw[:, 1])
    p = transform_points(scn.truth.sensor_pose, scn.radar.xyz[det])
    dist = edge_distance(p[:, :2], corners)
    sigma = horizontal_sigma(scn.radar.xyz[det], scn.truth.sensor_pose, _radar_cfg(variant))
    assert np.mean(dist < 3.0 * sigma + 0.02) >= 0.95
    # and nothing static lands on a vehicle systematically: clutter is off the footprints
    assert np.median(dist) < 2.0 * np.median(sigma)


@pytest.mark.parametrize("case,seed,variant", GEOMETRY_PARAMS)
def test_doppler_is_true_range_rate(case: str, seed: int, variant: str) -> None:
    res = sim(case, seed, variant=variant)
    scn = res.scenario
    cfg = _radar_cfg(variant)
    det = np.flatnonzero(res.source >= 0)
    st = track_rows(res, det)
    p = transform_points(scn.truth.sensor_pose, scn.radar.xyz[det])
    arm = p[:, :2] - st[:, 1:3]
    vel = st[:, 4:5] * np.column_stack([np.cos(st[:, 3]), np.sin(st[:, 3])])
    vel += st[:, 5:6] * np.column_stack([-arm[:, 1], arm[:, 0]])
    los = p - scn.truth.sensor_pose[:3, 3]
    rate = np.sum(vel * los[:, :2], axis=1) / np.linalg.norm(los, axis=1)
    sig_h = horizontal_sigma(scn.radar.xyz[det], scn.truth.sensor_pose, cfg)
    r = np.linalg.norm(los, axis=1)
    sig = np.sqrt(cfg.sigma_doppler**2 + (st[:, 5] * sig_h) ** 2 + (st[:, 4] * sig_h / r) ** 2)
    assert np.mean(np.abs(scn.radar.doppler[det] - rate) < 3.0 * sig + 0.01) >= 0.95
    moving_away = rate > 1.0
    assert np.mean(scn.radar.doppler[det][moving_away] > 0) > 0.99


@pytest.mark.parametrize("case", CASES)
def test_static_clutter_and_false_alarms(case: str) -> None:
    res = sim(case, 31)
    dop = res.scenario.radar.doppler
    clutter = res.source == CLUTTER
    fa = res.source == FALSE_ALARM
    assert clutter.sum() > 100 and fa.sum() > 10
    assert np.std(dop[clutter]) < 0.15
    assert np.std(dop[fa]) > 5.0
    rcs = res.scenario.radar.rcs
    assert -10 < np.median(rcs[clutter]) < 15 and np.median(rcs[res.source >= 0]) > 8


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_rate_fov_and_range(seed: int) -> None:
    duration = 20.0
    res = sim("intersection", seed, duration)
    scn = res.scenario
    cfg = RadarSimConfig()
    rate = len(scn.radar) / duration
    assert 6000 <= rate <= 14000
    assert 0.35 <= np.mean(res.source >= 0) <= 0.85
    xyz = scn.radar.xyz
    r = np.linalg.norm(xyz, axis=1)
    az = np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0]))
    el = np.degrees(np.arcsin(xyz[:, 2] / r))
    assert r.max() <= cfg.max_range and np.abs(az).max() <= 60.0 and np.abs(el).max() <= 15.0
    # fewer vehicle detections per track and frame far away
    det = res.source >= 0
    near, far = det & (r < 50), det & (r > 100)
    per_frame = [len(np.unique(scn.radar.frame[m] * 1000 + res.source[m])) for m in (near, far)]
    assert near.sum() / per_frame[0] > 2.0 * far.sum() / max(per_frame[1], 1)


# --------------------------------------------------------------------------------------------
# map, ALS, labels
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("case,seed,variant", GEOMETRY_PARAMS[::2])
def test_lanelets_lie_on_als_road(case: str, seed: int, variant: str) -> None:
    scn = sim(case, seed, variant=variant).scenario
    als_cfg = VARIANTS[variant].als
    road = scn.als.xyz[scn.als.classification == 11].astype(float)
    tree = cKDTree(road[:, :2])
    lo, hi = scn.als.xyz[:, :2].min(axis=0) + 2, scn.als.xyz[:, :2].max(axis=0) - 2
    rng = np.random.default_rng(0)
    # 99 % of nearest-neighbour distances in a Poisson cloud of this density are below r99
    r99 = np.sqrt(np.log(100.0) / (np.pi * als_cfg.density))
    for ll in scn.lanelets.lanelets:
        n = 50
        left, right = resample_polyline(ll.left, n), resample_polyline(ll.right, n)
        f = rng.random((200, 1))
        i = rng.integers(0, n, 200)
        pts = left[i] * f + right[i] * (1 - f)
        pts = pts[np.all((pts[:, :2] > lo) & (pts[:, :2] < hi), axis=1)]
        if not len(pts):
            continue
        d, k = tree.query(pts[:, :2])
        assert np.quantile(d, 0.99) < max(1.0, 1.5 * r99) and d.max() < 3.0 * r99
        dz = np.abs(road[k, 2] - pts[:, 2])
        assert np.median(dz) < 2.0 * als_cfg.height_sigma
        assert np.quantile(dz, 0.99) < 4.0 * als_cfg.height_sigma + 0.03
    ground = scn.als.xyz[scn.als.classification == 2]
    slope = np.linalg.lstsq(np.column_stack([ground[:, :2], np.ones(len(ground))]),
                            ground[:, 2], rcond=None)[0][:2]
    assert als_cfg.slope[0] - 0.002 < np.linalg.norm(slope) < als_cfg.slope[1] + 0.002
    assert len(scn.als) / als_cfg.extent**2 == pytest.approx(als_cfg.density, rel=0.05)


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_menger_labels_match_turn_direction(case: str, seed: int) -> None:
    scn = simulate(case, seed, duration=1.0, config=SimConfig(als=AlsSimConfig(density=0.2)))
    labels = []
    for ll in scn.lanelets.lanelets:
        expected = ll.attributes.get("turn_direction", "straight")
        assert menger_label(ll.left) == expected, (ll.id, expected)
        labels.append(expected)
        if expected == "straight":   # exactly straight bounds
            rel = ll.left[:, :2] - ll.left[0, :2]
            d = rel[-1] / np.linalg.norm(rel[-1])
            off = d[0] * rel[:, 1] - d[1] * rel[:, 0]
            assert np.abs(off).max() < 1e-6
        assert np.all(np.abs(np.linalg.norm(ll.left - ll.right, axis=1) - 3.5) < 0.05)
    counts = {k: labels.count(k) for k in ("left", "right", "straight")}
    if case in ("intersection", "tjunction"):
        assert counts["left"] >= 2 and counts["right"] >= 2 and counts["straight"] >= 4
    elif case == "curve":
        assert counts["left"] >= 1 and counts["right"] >= 1
    else:
        assert counts == {"left": 0, "right": 0, "straight": len(labels)}


# --------------------------------------------------------------------------------------------
# truth kinematics
# --------------------------------------------------------------------------------------------
def _ctra_step(s: np.ndarray, dt: np.ndarray, n: int = 20) -> np.ndarray:
    """Integrate [x, y, yaw, v] with the yaw rate and a constant acceleration over dt."""
    x, y, yaw, v, w, a = s.T
    h = dt / n
    for _ in range(n):
        vm, ym = v + 0.5 * a * h, yaw + 0.5 * w * h
        x, y, yaw, v = x + vm * np.cos(ym) * h, y + vm * np.sin(ym) * h, yaw + w * h, v + a * h
    return np.column_stack([x, y])


@pytest.mark.parametrize("case,seed,variant", GEOMETRY_PARAMS[::2])
def test_truth_states_are_ctra_consistent(case: str, seed: int, variant: str) -> None:
    scn = sim(case, seed, variant=variant).scenario
    assert scn.truth.tracks
    for tr in scn.truth.tracks:
        t, x, y, yaw, v, w = tr.states.T
        dt = np.diff(t)
        acc = np.diff(v) / dt
        yaw_u = np.unwrap(yaw)
        w_mid = 0.5 * (w[1:] + w[:-1])
        pred = _ctra_step(np.column_stack([x[:-1], y[:-1], yaw_u[:-1], v[:-1], w_mid, acc]), dt)
        assert np.abs(pred - np.column_stack([x[1:], y[1:]])).max() < 0.02
        assert np.abs(np.diff(yaw_u) - w_mid * dt).max() < 2e-3
        assert np.all(np.abs(acc) <= 2.5) and v.max() <= 15.0 + 1e-9
        standing = v == 0.0               # a stop ([traffic] stop_share): it stands still
        assert np.all(v > 0.5) or standing.any()
        still = standing[1:] & standing[:-1]
        assert np.all(np.diff(x)[still] == 0) and np.all(np.diff(y)[still] == 0)
        assert np.all(w[standing] == 0)
        assert np.abs(np.diff(w) / dt).max() < 1.0   # smooth yaw rate (curvature ramps)
        turning = ~standing & (np.abs(w) > 0.05 * v)     # curvature w / v above 0.05 1/m
        if turning.any():
            assert v[turning].max() <= 8.0 + 1e-6


@pytest.mark.parametrize("case,seed,variant", GEOMETRY_PARAMS)
def test_vehicles_keep_to_their_lane_centre_lines(case: str, seed: int, variant: str) -> None:
    """Truth centres lie on the centre line of a lanelet running their way: the curvature
    ramps cut a junction turn's corner by a few decimetres, and the vehicle is back on the
    exit lane's centre line within a few tens of metres (not off it for the rest of its way)."""
    scn = sim(case, seed, variant=variant).scenario
    points, headings = [], []
    for ll in scn.lanelets.lanelets:
        c = ll.centerline(400)
        d = np.diff(c, axis=0)
        points.append(0.5 * (c[1:] + c[:-1]))
        headings.append(np.arctan2(d[:, 1], d[:, 0]))
    p, h = np.vstack(points), np.concatenate(headings)
    tree = cKDTree(np.column_stack([p, 4 * np.cos(h), 4 * np.sin(h)]))
    lateral = []
    for tr in scn.truth.tracks:
        _, x, y, yaw, _, _ = tr.states.T
        _, i = tree.query(np.column_stack([x, y, 4 * np.cos(yaw), 4 * np.sin(yaw)]))
        lateral.append((x - p[i, 0]) * -np.sin(h[i]) + (y - p[i, 1]) * np.cos(h[i]))
    lateral = np.abs(np.concatenate(lateral))
    assert lateral.max() < 0.25
    assert lateral.mean() < 0.03


def _overlap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Separating-axis test of (n, 4, 2) rectangle pairs; True where they overlap."""
    sep = np.zeros(len(a), dtype=bool)
    for poly in (a, b):
        for k in range(2):
            axis = poly[:, k + 1] - poly[:, k]
            pa, pb = np.einsum("nij,nj->ni", a, axis), np.einsum("nij,nj->ni", b, axis)
            sep |= (pa.max(1) < pb.min(1)) | (pb.max(1) < pa.min(1))
    return ~sep


def assert_vehicles_apart(scn: Scenario) -> None:
    """No two truth boxes of ``scn`` overlap at any time stamp they share."""
    rows = np.vstack([np.column_stack([tr.states[:, :4], np.full((len(tr.states), 2),
                                                                 (tr.length, tr.width))])
                      for tr in scn.truth.tracks])
    corners = box_corners(rows[:, 1:3], rows[:, 3], rows[:, 4], rows[:, 5])
    pairs = 0
    for t in np.unique(rows[:, 0]):
        k = np.flatnonzero(rows[:, 0] == t)
        i, j = np.triu_indices(len(k), 1)
        pairs += len(i)
        assert not _overlap(corners[k[i]], corners[k[j]]).any(), f"overlap at t = {t}"
    assert pairs > 0


@pytest.mark.parametrize("case,seed,variant", GEOMETRY_PARAMS[1::2])
def test_vehicles_never_overlap(case: str, seed: int, variant: str) -> None:
    assert_vehicles_apart(sim(case, seed, variant=variant).scenario)


# --------------------------------------------------------------------------------------------
# round trip through a scenario directory
# --------------------------------------------------------------------------------------------
def test_write_load_round_trip(tmp_path: Path) -> None:
    io = pytest.importorskip("fgloc.io", reason="fgloc.io (write_scenario/load_scenario) missing")
    if not (hasattr(io, "write_scenario") and hasattr(io, "load_scenario")):
        pytest.skip("fgloc.io has no write_scenario/load_scenario yet")
    cfg = SimConfig(als=AlsSimConfig(extent=200.0, density=1.0))
    scn = simulate("tjunction", 4, duration=2.0, config=cfg)
    io.write_scenario(scn, tmp_path / "scn")
    back = io.load_scenario(tmp_path / "scn")
    np.testing.assert_allclose(back.radar.t, scn.radar.t, atol=1e-6)
    np.testing.assert_allclose(back.radar.xyz, scn.radar.xyz, atol=1e-3)
    np.testing.assert_allclose(back.radar.doppler, scn.radar.doppler, atol=1e-3)

    def w(s: Scenario, p: np.ndarray) -> np.ndarray:
        return s.frame.to_world(p)

    np.testing.assert_allclose(w(back, back.als.xyz), w(scn, scn.als.xyz), atol=2e-3)
    np.testing.assert_array_equal(back.als.classification, scn.als.classification)
    assert len(back.lanelets) == len(scn.lanelets)
    by_id = {ll.id: ll for ll in back.lanelets.lanelets}
    for ll in scn.lanelets.lanelets:
        got = by_id[ll.id]
        np.testing.assert_allclose(w(back, got.left[:, :2]), w(scn, ll.left[:, :2]), atol=0.01)
        assert got.attributes.get("turn_direction") == ll.attributes.get("turn_direction")
    t_back = back.frame.pose_to_world(back.truth.sensor_pose)
    np.testing.assert_allclose(t_back, scn.frame.pose_to_world(scn.truth.sensor_pose), atol=1e-6)
    assert len(back.truth.tracks) == len(scn.truth.tracks)
    for a, b in zip(back.truth.tracks, scn.truth.tracks, strict=True):
        np.testing.assert_allclose(w(back, a.states[:, 1:3]), w(scn, b.states[:, 1:3]), atol=1e-6)
    for f in dataclasses.fields(scn.sensor):
        got, want = getattr(back.sensor, f.name), getattr(scn.sensor, f.name)
        assert got == (want if isinstance(want, str) else pytest.approx(want)), f.name


@pytest.mark.parametrize("curb", [0.05, 0.15, 0.35])
def test_curb_height_setting(curb: float) -> None:
    """The static returns low above the road (below the poles' 0.5 m, the trunks' 0.8 m and
    the facades' 1 m) are the curbs': their median height above the ALS road under them is
    ``[radar] curb_height``."""
    cfg = SimConfig(radar=RadarSimConfig(curb_height=curb, sigma_elevation_deg=0.0,
                                         sigma_range=0.0, sigma_azimuth_deg=0.0))
    scn = simulate("straight", 3, 5.0, config=cfg)
    p = transform_points(scn.truth.sensor_pose, scn.radar.xyz)
    road = scn.als.xyz[scn.als.classification == 11].astype(float)
    _, k = cKDTree(road[:, :2]).query(p[:, :2], k=8)
    h = p[:, 2] - np.median(road[k, 2], axis=1)
    low = (np.abs(scn.radar.doppler) < 0.05) & (h < 0.45)
    assert low.sum() > 200
    assert abs(np.median(h[low]) - curb) < 0.03, np.median(h[low])
    with pytest.raises(Exception, match="curb_height"):
        from_dict(SimConfig, {"radar": {"curb_height": -0.1}}, None)


@pytest.mark.parametrize("band", [None, (0.2, 1.5), (0.5, 0.9)])
def test_return_height_setting(band: tuple[float, float] | None) -> None:
    """Vehicle returns lie within [low, high] above the road (clipped at the roof), mean as
    expected; default (None): 0.3 m to 90 % of the roof."""
    cfg = SimConfig(radar=RadarSimConfig(return_height=band, sigma_elevation_deg=0.0,
                                         sigma_range=0.0, sigma_azimuth_deg=0.0))
    res = simulate_detailed("straight", 5, 12.0, config=cfg)
    scn = res.scenario
    det = np.flatnonzero(res.source >= 0)
    assert len(det) > 300
    p = transform_points(scn.truth.sensor_pose, scn.radar.xyz[det])
    # road under each return: median of the nearest ALS road points
    road = scn.als.xyz[scn.als.classification == 11].astype(float)
    tree = cKDTree(road[:, :2])
    _, k = tree.query(p[:, :2], k=8)
    h = p[:, 2] - np.median(road[k, 2], axis=1)
    cls = {tr.id: name for tr, name in zip(scn.truth.tracks, res.vehicle_class, strict=True)}
    roof = np.array([{"car": 1.5, "van": 2.2, "truck": 3.6}[cls[s]] for s in res.source[det]])
    tol = 0.1    # ALS height noise and road interpolation
    if band is None:
        lo, hi = 0.3 * np.ones_like(roof), 0.9 * roof
    else:
        lo, hi = np.minimum(band[0], roof), np.minimum(band[1], roof)
    assert np.all(h > lo - tol) and np.all(h < hi + tol)
    assert abs(np.mean(h) - np.mean(0.5 * (lo + hi))) < 0.05
    with pytest.raises(Exception, match="return_height"):
        from_dict(SimConfig, {"radar": {"return_height": [1.5, 0.2]}}, None)


def test_a_facade_mirrors_a_vehicle_return_into_a_ghost_moving_mirrored() -> None:
    """A building x in [0, 20], y in [10, 30] (8 m high), the sensor at the origin 6 m up:
    its facade y = 10 faces the sensor and mirrors a return at (5, 6, 1) moving (3, 1) m/s
    to (5, 14, 1) moving (3, -1); a return whose image's sight line passes beside the facade
    (x = 30) or above its top (through a 2 m high building) has none; the facades facing
    away mirror nothing."""
    corners = box_corners(np.array([[10.0, 20.0]]), np.array([0.0]), np.array([20.0]),
                          np.array([20.0]))
    sensor = np.array([0.0, 0.0, 6.0])
    # only y = 10 faces it (x = 0 runs through the sensor's x: edge-on)
    assert [(a.tolist(), c.tolist(), b) for a, c, b in facing_facades(corners, sensor)] == [
        ([0.0, 10.0], [20.0, 10.0], 0)]
    xyz = np.array([[5.0, 6.0, 1.0], [30.0, 6.0, 1.0], [5.0, 6.0, 1.0]])
    pts = Points(np.zeros(3, dtype=np.int64), xyz, np.array([[3.0, 1.0]] * 3), np.zeros(3),
                 np.full(3, 10.0), np.array([4, 4, CLUTTER]), np.array([4, 4, -1]))
    g = ghost_points(np.random.default_rng(0), 1.0, pts, corners, np.array([8.0]), sensor)
    assert g.xyz.tolist() == [[5.0, 14.0, 1.0]]
    assert g.vel.tolist() == [[3.0, -1.0]] and g.source.tolist() == [GHOST]
    assert g.rcs.tolist() == [10.0 - GHOST_LOSS_DB]
    # the sight line meets the facade at 6 - 5 * 10 / 14 = 2.43 m: a 2 m building is too low
    low = ghost_points(np.random.default_rng(0), 1.0, pts, corners, np.array([2.0]), sensor)
    assert len(low.xyz) == 0
    assert len(ghost_points(np.random.default_rng(0), 0.0, pts, corners, np.array([8.0]),
                            sensor).xyz) == 0


def test_ghosts_are_added_and_every_other_detection_is_the_same() -> None:
    """ghost_fraction > 0 adds ghosts (source GHOST) behind the facades and changes nothing
    else: the other detections equal those without ghosts, draw for draw."""
    base = sim("curve", 3)
    cfg = dataclasses.replace(VARIANTS["default"], radar=dataclasses.replace(
        VARIANTS["default"].radar, ghost_fraction=0.3))
    res = simulate_detailed("curve", 3, 12.0, config=cfg)
    ghost = res.source == GHOST
    assert ghost.sum() > 500
    radar, ref = res.scenario.radar, base.scenario.radar
    for field in ("t", "xyz", "doppler", "rcs"):
        assert np.array_equal(getattr(radar, field)[~ghost], getattr(ref, field))
    # behind facades at least building_clearance (6 m) off the road edge, the ghosts lie off
    # the road (up to the measurement noise)
    pose = res.scenario.truth.sensor_pose
    road = cKDTree(area_samples(res.scenario.lanelets.lanelets)[0])
    off = road.query(transform_points(pose, radar.xyz[ghost])[:, :2])[0]
    assert np.mean(off > 5.0) > 0.95
