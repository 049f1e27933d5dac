"""Simulator settings of the robustness dimensions, each checked against the simulator's truth:
returns per vehicle against range, scattering-centre mix, platoon headway, truck share and
length, junction angle and box size, traffic density."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial import cKDTree
from test_sim import assert_vehicles_apart

from fgloc.config import from_dict
from fgloc.geo import transform_points
from fgloc.sim import SimConfig, SimResult, simulate_detailed
from fgloc.sim.config import RadarSimConfig, RoadSimConfig, TrafficSimConfig
from fgloc.sim.radar import detection_probability
from fgloc.sim.roads import build_network
from fgloc.sim.scenery import box_corners
from fgloc.sim.traffic import ROUTE_DS, VEHICLE_CLASSES, Route, offset_route, simulate_traffic


def _traffic(cfg: TrafficSimConfig, duration: float, seed: int, lanes: int = 1,
             count: int | None = None):
    net = build_network("straight", np.random.default_rng(seed),
                        RoadSimConfig(lanes_per_direction=[lanes]), (18.0, 32.0))
    times = np.arange(0.0, duration, 0.05)
    return simulate_traffic(np.random.default_rng(seed + 100), cfg, net, times, count)


def _per_vehicle_frame(res) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(track id, frame, count of detections) of every (vehicle, frame) whose vehicle centre is
    inside the FOV (20 deg margin), plus its true centre range (m)."""
    scn = res.scenario
    pose = scn.truth.sensor_pose
    rate = 1.0 / np.median(np.diff(np.unique(scn.radar.t)))
    det = res.source >= 0
    key = res.source[det] * 100000 + scn.radar.frame[det]
    ids, counts = np.unique(key, return_counts=True)
    lookup = dict(zip(ids.tolist(), counts.tolist()))
    boresight = np.arctan2(pose[1, 0], pose[0, 0])
    out = []
    for tr in scn.truth.tracks:
        rel = tr.states[:, 1:3] - pose[:2, 3]
        az = np.angle(np.exp(1j * (np.arctan2(rel[:, 1], rel[:, 0]) - boresight)))
        frame = np.rint(tr.states[:, 0] * rate).astype(int)
        for f, a, r in zip(frame, az, np.linalg.norm(rel, axis=1)):
            if abs(a) < np.deg2rad(40.0):
                out.append((r, lookup.get(tr.id * 100000 + f, 0)))
    arr = np.array(out)
    return arr[:, 0], arr[:, 1], rate


def test_returns_per_range_model() -> None:
    """Mean detections per vehicle and frame follow ref * (ref_range / r) ** k * p_det(r)."""
    radar = RadarSimConfig(returns_at_reference=25.0, reference_range=20.0,
                           returns_exponent=0.91, range_half_detection=0.95,
                           false_alarms_per_frame=0.0)
    cfg = SimConfig(radar=radar, road=RoadSimConfig(lanes_per_direction=[1]))
    ranges, counts = [], []
    for seed in (1, 2, 3):
        r, n, _ = _per_vehicle_frame(simulate_detailed("straight", seed, 30.0, vehicles=1,
                                                       config=cfg))
        ranges.append(r)
        counts.append(n)
    r, n = np.concatenate(ranges), np.concatenate(counts)
    expected = 25.0 * (20.0 / r) ** 0.91 * detection_probability(r, radar)
    for lo, hi in ((15.0, 40.0), (40.0, 90.0), (90.0, 170.0)):
        m = (r >= lo) & (r < hi)
        assert m.sum() > 40
        assert np.mean(n[m]) == pytest.approx(np.mean(expected[m]), rel=0.15), (lo, hi)
    far = (r > 140) & (r < 160)
    assert 2.5 < np.mean(n[far]) < 5.0


def _corner_shares(cfg: SimConfig) -> tuple[float, float, float]:
    """Shares of vehicle detections within 0.4 m of the corner nearest to the sensor, of
    another corner, and within 0.4 m of an axle (1/6 or 5/6 of the length) on a long side."""
    res = simulate_detailed("intersection", 4, 12.0, config=cfg)
    scn = res.scenario
    det = np.flatnonzero(res.source >= 0)
    pose = scn.truth.sensor_pose
    p = transform_points(pose, scn.radar.xyz[det])[:, :2]
    near = other = wheel = 0
    for tr in scn.truth.tracks:
        m = res.source[det] == tr.id
        if not m.any():
            continue
        k = np.searchsorted(tr.states[:, 0], scn.radar.t[det][m] - 1e-9)
        st = tr.states[k]
        c = box_corners(st[:, 1:3], st[:, 3], np.full(len(k), tr.length),
                        np.full(len(k), tr.width))
        d = np.linalg.norm(c - p[m][:, None], axis=2)
        nearest = np.argmin(np.linalg.norm(c - pose[:2, 3], axis=2), axis=1)
        close = d < 0.4
        near += int(close[np.arange(len(k)), nearest].sum())
        other += int((close.sum(axis=1) - close[np.arange(len(k)), nearest]).sum())
        # along/across the vehicle
        rel = p[m] - st[:, 1:3]
        along = rel[:, 0] * np.cos(st[:, 3]) + rel[:, 1] * np.sin(st[:, 3])
        across = -rel[:, 0] * np.sin(st[:, 3]) + rel[:, 1] * np.cos(st[:, 3])
        axle = np.minimum(np.abs(along - tr.length / 3), np.abs(along + tr.length / 3))
        wheel += int(((axle < 0.4) & (np.abs(np.abs(across) - tr.width / 2) < 0.4)).sum())
    return near / len(det), other / len(det), wheel / len(det)


def test_scattering_centre_mix() -> None:
    exact = dict(sigma_range=0.02, sigma_azimuth_deg=0.02, sigma_elevation_deg=0.02)
    base = _corner_shares(SimConfig(radar=RadarSimConfig(**exact)))
    visible = _corner_shares(SimConfig(radar=RadarSimConfig(corners="visible", **exact)))
    wheels = _corner_shares(SimConfig(radar=RadarSimConfig(corner_fraction=0.1,
                                                           wheel_fraction=0.5, **exact)))
    # default: corner detections pile up at the nearest corner only
    assert base[0] > 2.0 * base[1]
    # "visible": the far visible corners get a large share too
    assert visible[1] > 1.8 * base[1] and visible[0] < base[0]
    # wheels: far more detections at the axles of the long side
    assert wheels[2] > 2.0 * base[2] and wheels[2] > 0.25
    with pytest.raises(Exception, match="corners"):
        from_dict(SimConfig, {"radar": {"corners": "all"}}, None)


def _front_passes(tracks, x0: float = 0.0) -> list[tuple[int, float, float]]:
    """(direction sign, time (s) the front passes the cross-section through the origin normal
    to the road, length) of every track of a straight road along the x' axis."""
    out = []
    for tr in tracks:
        st = tr.states
        h = np.array([np.cos(st[0, 3]), np.sin(st[0, 3])])
        front = st[:, 1:3] + 0.5 * tr.length * h
        s = front @ h - x0
        if s[0] < 0 < s[-1]:
            out.append((h, float(np.interp(0.0, s, st[:, 0])), tr.length))
    return out


def _headways(tracks) -> np.ndarray:
    passes = _front_passes(tracks)
    ref = passes[0][0]
    out = []
    for sign in (1, -1):
        t = np.sort([tp for h, tp, _ in passes if np.dot(h, ref) * sign > 0])
        out.append(np.diff(t))
    return np.concatenate(out)


def test_platoon_headway() -> None:
    cfg = TrafficSimConfig(platoon_size=(3, 3), platoon_headway=(0.8, 1.2), headway=0.3,
                           arrival_interval=4.0)
    hw = _headways(_traffic(cfg, 240.0, 5).tracks)
    base = _headways(_traffic(TrafficSimConfig(arrival_interval=4.0), 240.0, 5).tracks)
    in_band = np.mean((hw > 0.75) & (hw < 1.25))
    # two of three successive gaps lie inside a platoon
    assert in_band > 0.5, in_band
    assert np.mean((base > 0.75) & (base < 1.25)) < 0.2
    assert hw.min() > 0.3   # never closer than the minimum gap
    with pytest.raises(Exception, match="platoon_size"):
        from_dict(SimConfig, {"traffic": {"platoon_size": [0, 2]}}, None)


def test_truck_share_and_length() -> None:
    cfg = TrafficSimConfig(class_mix=(0.85, 0.0, 0.15), truck_length=(9.0, 12.0))
    tr = _traffic(cfg, 60.0, 2, lanes=2, count=400)
    truck = tr.kinds == [vc.name for vc in VEHICLE_CLASSES].index("truck")
    assert 0.10 < truck.mean() < 0.20
    lengths = np.array([t.length for t in tr.tracks])[truck]
    assert lengths.min() >= 9.0 and lengths.max() <= 12.0
    assert lengths.std() > 0.6   # uniform over 3 m (sd 0.87), not the default's 0.6 m normal
    assert np.all(np.abs(np.array([t.length for t in tr.tracks])[~truck] - 4.5) < 1.5)


@pytest.mark.parametrize("case", ["intersection", "tjunction"])
def test_junction_angle_and_box(case: str) -> None:
    for seed in range(6):
        cfg = RoadSimConfig(crossing_angle_deg=(70.0, 80.0))
        net = build_network(case, np.random.default_rng(seed), cfg, (18.0, 32.0))
        axes = np.array([p.heading % np.pi for p in net.pieces if p.turn is None])
        # two road axes (mod pi): the spread within each is numerical only
        lo, hi = np.sort(axes)[[0, -1]]
        split = axes < 0.5 * (lo + hi)
        assert np.ptp(axes[split]) < 1e-6 and np.ptp(axes[~split]) < 1e-6
        ang = np.degrees(hi - lo)
        assert 70.0 <= min(ang, 180.0 - ang) <= 80.0
    small, large = (build_network(case, np.random.default_rng(3),
                                  RoadSimConfig(junction_margin=m, lanes_per_direction=[1]),
                                  (18.0, 32.0)) for m in (8.0, 16.0))
    r_small = np.linalg.norm(small.junction, axis=1)
    r_large = np.linalg.norm(large.junction, axis=1)
    # the box corners move 8 m further out along the arms (the diagonal grows by >= 8 m)
    assert np.all(r_large - r_small > 7.5)


def test_traffic_density() -> None:
    for per_min in (10.0, 24.0):
        cfg = TrafficSimConfig(arrival_interval=60.0 / per_min)
        tracks = _traffic(cfg, 600.0, 7, lanes=2).tracks
        entered = sum(t.states[0, 0] > 0.0 for t in tracks)
        rate = entered / 10.0
        assert rate == pytest.approx(per_min, rel=0.2)


def test_defaults_are_todays_simulator() -> None:
    """The new settings' defaults reproduce the scenario bit for bit (explicit = implicit)."""
    explicit = SimConfig(radar=dataclasses.replace(RadarSimConfig(), corners="nearest",
                                                   wheel_fraction=0.0, return_height=None,
                                                   roof_fraction=0.0),
                         traffic=dataclasses.replace(TrafficSimConfig(), platoon_abreast=False))
    a = simulate_detailed("tjunction", 2, 4.0).scenario
    b = simulate_detailed("tjunction", 2, 4.0, config=explicit).scenario
    np.testing.assert_array_equal(a.radar.xyz, b.radar.xyz)


def test_roof_returns_inside_the_footprint() -> None:
    """``roof_fraction`` of a car's returns lie inside its footprint (not on its outline),
    spread over its length, at its roof height; none without it (the default)."""
    exact = dict(sigma_range=0.01, sigma_azimuth_deg=0.01, sigma_elevation_deg=0.01,
                 clutter_per_frame=0.0, false_alarms_per_frame=0.0, return_height=(0.3, 0.3))
    shares = []
    for frac in (0.0, 0.3):
        cfg = SimConfig(radar=RadarSimConfig(roof_fraction=frac, **exact))
        res = simulate_detailed("straight", 1, 20.0, vehicles=1, config=cfg)
        scn, tr = res.scenario, res.scenario.truth.tracks[0]
        det = np.flatnonzero(res.source >= 0)
        p = transform_points(scn.truth.sensor_pose, scn.radar.xyz[det])
        st = tr.states[np.searchsorted(tr.states[:, 0], scn.radar.t[det] - 1e-9)]
        h = np.column_stack([np.cos(st[:, 3]), np.sin(st[:, 3])])
        d = p[:, :2] - st[:, 1:3]
        along = np.sum(d * h, axis=1)
        across = d[:, 0] * h[:, 1] - d[:, 1] * h[:, 0]
        # depth inside the outline (m): 0 on it
        depth = np.minimum(0.5 * tr.length - np.abs(along), 0.5 * tr.width - np.abs(across))
        inside = depth > 0.05
        shares.append(inside.mean())
        if frac:
            assert np.ptp(along[inside]) > 0.9 * tr.length
            # the road under a roof return: the nearest face return (all 0.3 m up) less 0.3 m
            face = cKDTree(p[~inside, :2]).query(p[inside, :2])[1]
            above = p[inside, 2] - (p[~inside, 2][face] - 0.3)
            car = next(vc.height for vc in VEHICLE_CLASSES if vc.name == "car")
            assert np.median(np.abs(above - car)) < 0.05
    assert shares[0] < 0.002                                 # noise, timing
    # 0.3 of the drawn returns; a 0.05 m rim of the footprint counts as outline, and low face
    # returns are occluded (by the scenery) more often than roof ones
    assert 0.25 < shares[1] < 0.4
    with pytest.raises(ValueError, match="roof_fraction"):
        RadarSimConfig(roof_fraction=1.5)


def _side_by_side_pairs(tracks: list) -> int:
    """Pairs of true vehicles 2-4.5 m apart across the first one's heading and at most 5 m
    along it for at least 20 common samples (one second)."""
    pairs = 0
    for i, a in enumerate(tracks):
        for b in tracks[i + 1:]:
            _, ia, ib = np.intersect1d(np.round(a.states[:, 0], 3), np.round(b.states[:, 0], 3),
                                       return_indices=True)
            d, h = a.states[ia, 1:3] - b.states[ib, 1:3], a.states[ia, 3]
            lat = np.abs(d[:, 0] * np.sin(h) - d[:, 1] * np.cos(h))
            lon = np.abs(d[:, 0] * np.cos(h) + d[:, 1] * np.sin(h))
            pairs += int(np.sum((lat > 2.0) & (lat < 4.5) & (lon < 5.0)) >= 20)
    return pairs


def test_platoons_abreast_drive_side_by_side() -> None:
    """With ``platoon_abreast`` a platoon's follower drives the lane beside its leader's:
    pairs of vehicles side by side, several times as many as when it follows in line."""
    counts = {}
    for abreast in (False, True):
        cfg = from_dict(SimConfig, {"road": {"lane_width": 3.0, "lanes_per_direction": [2]},
                                    "traffic": {"platoon_size": [2, 2],
                                                "platoon_headway": [0.0, 0.5],
                                                "platoon_abreast": abreast}}, None)
        counts[abreast] = _side_by_side_pairs(
            simulate_detailed("intersection", 3, 60.0, config=cfg).scenario.truth.tracks)
    assert counts[True] >= 8 and counts[True] >= 2 * counts[False]


def _wheel_doppler_ratios(wheel_radius: float) -> tuple[np.ndarray, np.ndarray]:
    """One car passing on the straight road, every detection at a wheel, noise-free: per
    detection (where the body's along-heading velocity is at least 1 m/s on the line of sight)
    the Doppler beyond the rigid body's divided by that along-heading part, and the detection
    (m, in L, (n, 3))."""
    exact = dict(sigma_range=0.01, sigma_azimuth_deg=0.01, sigma_elevation_deg=0.01,
                 sigma_doppler=1e-4, clutter_per_frame=0.0, false_alarms_per_frame=0.0)
    cfg = SimConfig(radar=RadarSimConfig(corner_fraction=0.0, wheel_fraction=1.0,
                                         wheel_radius=wheel_radius, **exact))
    res = simulate_detailed("straight", 1, 20.0, vehicles=1, config=cfg)
    scn = res.scenario
    det = np.flatnonzero(res.source >= 0)
    pose = scn.truth.sensor_pose
    p = transform_points(pose, scn.radar.xyz[det])
    tr = scn.truth.tracks[0]
    st = tr.states[np.searchsorted(tr.states[:, 0], scn.radar.t[det] - 1e-9)]
    rel = p - pose[:3, 3]
    r = np.linalg.norm(rel, axis=1)
    h = np.column_stack([np.cos(st[:, 3]), np.sin(st[:, 3])])
    arm = p[:, :2] - st[:, 1:3]
    body = st[:, 4:5] * h + st[:, 5:6] * np.column_stack([-arm[:, 1], arm[:, 0]])
    rigid = np.sum(body * rel[:, :2], axis=1) / r
    along = st[:, 4] * np.sum(h * rel[:, :2], axis=1) / r
    ok = np.abs(along) > 1.0
    return (scn.radar.doppler[det] - rigid)[ok] / along[ok], p[ok]


def test_wheel_micro_doppler() -> None:
    """With ``wheel_radius`` the wheel returns move with the wheel's surface: the Doppler beyond
    the rigid body's is (h / R - 1) times the body's along-heading part, h uniform on [0, 2R]
    and the return's height; without, they move with the body."""
    ratio, xyz = _wheel_doppler_ratios(0.35)
    assert len(ratio) > 500
    assert ratio.min() < -0.9 and ratio.max() > 0.9 and np.all(np.abs(ratio) <= 1.0 + 1e-3)
    assert abs(np.mean(ratio)) < 0.1 and np.std(ratio) == pytest.approx(1 / np.sqrt(3), rel=0.1)
    # the height above the road is (ratio + 1) R: what is left is the road's own profile, a
    # smooth function of the position along the road (here within 2 cm of a cubic)
    road = xyz[:, 2] - (ratio + 1.0) * 0.35
    u = np.linalg.svd(xyz[:, :2] - xyz[:, :2].mean(axis=0), full_matrices=False)[2][0]
    s = (xyz[:, :2] - xyz[:, :2].mean(axis=0)) @ u
    assert np.std(road - np.polyval(np.polyfit(s, road, 3), s)) < 0.02
    assert np.std(xyz[:, 2] - np.polyval(np.polyfit(s, xyz[:, 2], 3), s)) > 0.15
    still, _ = _wheel_doppler_ratios(0.0)
    assert np.max(np.abs(still)) < 0.01
    with pytest.raises(ValueError, match="wheel_radius"):
        RadarSimConfig(wheel_radius=-0.1)


def test_offset_route_is_the_parallel_curve() -> None:
    # a left quarter circle of radius 20 m: 2 m to its right it is a circle of radius 22 m
    r0 = 20.0
    s = np.arange(0.0, 0.5 * np.pi * r0, ROUTE_DS)
    heading = s / r0
    xy = np.column_stack([r0 * np.sin(heading), r0 * (1.0 - np.cos(heading))])
    arc = Route([0], s, xy, heading, np.full(len(s), 1.0 / r0))
    out = offset_route(arc, 2.0)
    assert np.allclose(np.hypot(out.xy[:, 0], out.xy[:, 1] - r0), r0 + 2.0, atol=1e-3)
    assert np.allclose(out.kappa, 1.0 / (r0 + 2.0))
    assert out.s[-1] == pytest.approx(s[-1] * (r0 + 2.0) / r0, abs=ROUTE_DS)
    assert np.allclose(np.diff(out.s), ROUTE_DS)
    tangent = np.arctan2(*np.diff(out.xy, axis=0)[:, ::-1].T)
    assert np.allclose(tangent, 0.5 * (out.heading[1:] + out.heading[:-1]), atol=1e-3)
    # to the left (negative) on a straight: 1.5 m across, same length
    line = Route([0], s, np.column_stack([s, np.zeros_like(s)]), np.zeros_like(s),
                 np.zeros_like(s))
    left = offset_route(line, -1.5)
    assert np.allclose(left.xy[:, 1], 1.5) and left.s[-1] == pytest.approx(s[-1])


def test_cyclists_ride_beside_the_unchanged_motor_traffic() -> None:
    base = TrafficSimConfig(arrival_interval=4.0)
    with_cyclists = dataclasses.replace(base, cyclists_per_minute=6.0, cyclist_offset=1.4)
    cars, mixed = (_traffic(c, 120.0, 4) for c in (base, with_cyclists))
    bicycle = [vc.name for vc in VEHICLE_CLASSES].index("bicycle")
    motor = mixed.kinds != bicycle
    # the motor vehicles are those without cyclists, track for track
    assert motor.sum() == len(cars.tracks)
    for a, b in zip(cars.tracks, [t for t, m in zip(mixed.tracks, motor) if m]):
        assert np.array_equal(a.states, b.states)
    bikes = [t for t, m in zip(mixed.tracks, motor) if not m]
    assert 6 <= len(bikes) <= 30          # 6 per minute over 2 minutes plus the warm-up
    cars_xy = np.vstack([t.states[:, 1:3] for t in cars.tracks])
    for t in bikes:
        assert 1.5 < t.length < 2.1 and 0.4 < t.width < 0.8
        v = t.states[:, 4]
        assert v.max() <= 7.0 + 1e-9 and np.median(v) >= 4.0 - 1e-9
        # 1.4 m right of the lane centre line the cars drive: across the heading, to the right
        d = t.states[:, 1:3][:, None, :] - cars_xy[None, ::20, :]
        near = np.argmin(np.hypot(d[..., 0], d[..., 1]), axis=1)
        rel = d[np.arange(len(d)), near]
        right = rel[:, 0] * np.sin(t.states[:, 3]) - rel[:, 1] * np.cos(t.states[:, 3])
        assert np.median(right) == pytest.approx(1.4, abs=0.15)
    with pytest.raises(Exception, match="cyclists_per_minute"):
        from_dict(SimConfig, {"traffic": {"cyclists_per_minute": -1.0}}, None)
    with pytest.raises(Exception, match="cyclist_speed"):
        from_dict(SimConfig, {"traffic": {"cyclist_speed": [5.0, 3.0]}}, None)


def check_stands(res: SimResult, traffic: TrafficSimConfig, sigma_doppler: float
                 ) -> tuple[int, int, np.ndarray]:
    """Check every stand of ``res``'s vehicles (``traffic`` with ``stop_share`` > 0): one per
    vehicle, still (no motion, yaw rate 0), its front out of the paths that cross its
    heading; queued behind a standing vehicle on its lane (``queue_gap`` m behind its rear,
    moving off at least ``queue_discharge`` s after it) or, standing alone, ``stop_time`` s
    long. Returns the number of stands, of queued stands and the Doppler (m/s) of the
    standing vehicles' returns."""
    scn = res.scenario
    dt = float(np.median(np.diff(np.unique(scn.radar.t))))
    paths = np.vstack([tr.states[:, [1, 2, 3]] for tr in scn.truth.tracks])
    stands = []       # (track, first, last standing time, centre, heading, whole)
    static = [np.zeros(0)]
    for tr in scn.truth.tracks:
        t, x, y, yaw, v, w = tr.states.T
        standing = v == 0.0
        if not standing.any():
            continue
        edges = np.flatnonzero(np.diff(np.concatenate([[0], standing.astype(int), [0]])))
        assert len(edges) == 2                       # one stop
        first, last = edges[0], edges[1] - 1
        whole = 0 < first and last < len(t) - 1      # the whole stand in the recording
        stands.append((tr, t[first], t[last], np.array([x[first], y[first]]), yaw[first], whole))
        assert np.ptp(x[standing]) == 0 and np.ptp(y[standing]) == 0
        assert np.all(w[standing] == 0)
        # the front stands out of the paths that cross its heading (30-150 deg)
        front = np.array([x[first], y[first]]) + 0.5 * tr.length * np.array(
            [np.cos(yaw[first]), np.sin(yaw[first])])
        turn = np.abs(np.angle(np.exp(1j * (paths[:, 2] - yaw[first]))))
        crossing = paths[(turn > np.deg2rad(30)) & (turn < np.deg2rad(150)), :2]
        assert np.linalg.norm(crossing - front, axis=1).min() > 1.0
        det = ((res.source == tr.id) & (scn.radar.t >= t[first] + dt)
               & (scn.radar.t <= t[last] - dt))
        static.append(scn.radar.doppler[det])
    queued = 0
    for tr, t0, t1, c, h, whole in stands:
        ahead = [(o, o0, o1) for o, o0, o1, oc, oh, _ in stands
                 if o is not tr and o0 <= t0 <= o1 and abs(np.angle(np.exp(1j * (oh - h)))) < 0.1
                 and abs(np.linalg.norm(oc - c) - 0.5 * (o.length + tr.length)
                         - traffic.queue_gap) < 0.3]
        if ahead:             # queued: moves off after the one ahead (later if it must wait)
            queued += 1
            assert not whole or t1 - ahead[0][2] >= traffic.queue_discharge - 2 * dt
        elif whole:                                   # at its stop line for stop_time
            assert traffic.stop_time[0] - 2 * dt <= t1 - t0 <= traffic.stop_time[1] + 2 * dt
    static_doppler = np.concatenate(static)
    if len(static_doppler):
        assert np.sqrt(np.mean(static_doppler**2)) < 1.5 * sigma_doppler
    return len(stands), queued, static_doppler


def test_stopping_vehicles_stand_before_the_crossing_with_static_returns() -> None:
    """``stop_share``: that share of the vehicles stands still (v 0, no motion, zero yaw rate)
    for ``stop_time`` s short of its route's first crossing, out of the crossing traffic's
    paths, its returns static; a vehicle coming up behind a standing one queues
    ``queue_gap`` m behind it and moves off at least ``queue_discharge`` s after it
    (:func:`check_stands`); the others do not stop, and no two vehicles overlap."""
    cfg = SimConfig(traffic=TrafficSimConfig(stop_share=0.5, stop_time=(4.0, 8.0)))
    res = simulate_detailed("intersection", 2, 40.0, config=cfg)
    stands, queued, static = check_stands(res, cfg.traffic, cfg.radar.sigma_doppler)
    assert stands >= 0.25 * len(res.scenario.truth.tracks)
    assert queued >= 1 and len(static) > 1000
    assert_vehicles_apart(res.scenario)
    plain = simulate_detailed("intersection", 2, 40.0).scenario
    assert all(np.all(tr.states[:, 4] > 0.5) for tr in plain.truth.tracks)
    # a platoon whose leader stops: its followers keep the free profile and wait
    platoons = SimConfig(traffic=TrafficSimConfig(stop_share=0.5, platoon_size=(2, 3)))
    scn = simulate_detailed("tjunction", 3, 30.0, config=platoons).scenario
    assert any((tr.states[:, 4] == 0).any() for tr in scn.truth.tracks)
    assert all(np.isfinite(tr.states).all() for tr in scn.truth.tracks)
    assert_vehicles_apart(scn)
    with pytest.raises(Exception, match="stop_share"):
        from_dict(SimConfig, {"traffic": {"stop_share": 1.5}}, None)
