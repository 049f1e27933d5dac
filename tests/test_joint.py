"""Joint refinement on constructed scenes: a known pose offset is recovered and covered by
the covariance; on a straight road the along-road direction is flagged as weakly observed."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from factors.gp import rectangle_radius
from fgloc.config import Config
from fgloc.errors import LocalizationError
from fgloc.geo import se2, se2_params, transform_points, wrap_angle
from fgloc.labels import STRAIGHT
from fgloc.registration.joint import LaneLines, degeneracy_report, joint_refine
from fgloc.registration.joint_config import JointConfig, check_joint_config
from fgloc.tracks import N_STATE, Track, TrackSet, contour_angles

LENGTH, WIDTH = 4.6, 1.9          # the tracker's mean contour (Config().tracking)
LANE_HALF = 1.75


def _lanes(crossing: bool) -> list[tuple[np.ndarray, float]]:
    """(start point, heading) of 80 m straight lanes in L: an east-west road, and with
    ``crossing`` a north-south road across it."""
    lanes = [(np.array([-40.0, -LANE_HALF]), 0.0), (np.array([40.0, LANE_HALF]), np.pi)]
    if crossing:
        lanes += [(np.array([LANE_HALF, -40.0]), np.pi / 2),
                  (np.array([-LANE_HALF, 40.0]), -np.pi / 2)]
    return lanes


def _visible_points(centre: np.ndarray, yaw: float, sensor: np.ndarray,
                    rng: np.random.Generator) -> np.ndarray:
    """Noisy points spread over the whole length of each side of a LENGTH x WIDTH rectangle
    that faces the sensor (corners included, as a radar sees a car's near faces)."""
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.array([[c, -s], [s, c]])
    sides = [((LENGTH / 2, 0.0), (0.0, 1.0), WIDTH), ((-LENGTH / 2, 0.0), (0.0, 1.0), WIDTH),
             ((0.0, WIDTH / 2), (1.0, 0.0), LENGTH), ((0.0, -WIDTH / 2), (1.0, 0.0), LENGTH)]
    pts = []
    for mid, along, size in sides:
        mid_l, along_l = R @ np.array(mid), R @ np.array(along)
        outward = R @ (np.array(mid) / np.linalg.norm(mid))
        if outward @ (sensor - (centre + mid_l)) > 0:
            u = np.linspace(-size / 2, size / 2, max(3, int(size / 0.5)))
            pts.append(centre + mid_l + u[:, None] * along_l)
    p = np.vstack(pts)
    return p + rng.normal(0.0, 0.05, p.shape)


def _scene(crossing: bool, T_true: np.ndarray, sensor_l: np.ndarray, seed: int,
           per_lane: int | tuple[int, ...] = 4, offset: float = 0.0, range_bias: float = 0.0,
           lane_shift: tuple[int, float] | None = None, lateral_sd: float = 0.1):
    """Tracks in C = T_true^-1 L of vehicles on the lanes (each with its own lateral offset
    from the lane centre), their detections in C, the sensor in C and the target lines in L
    (lane centres, shifted ``offset`` m towards the sensor; each lane one lanelet);
    ``per_lane`` vehicles on each lane (a tuple: per lane, in :func:`_lanes`' order).
    ``range_bias`` (m per 100 m): every vehicle, its states and its detections, lies that far
    per 100 m of its range towards the sensor's side of its lane (a tracker's range-growing
    bias). ``lane_shift`` (lane index, m): that lane's line moved along its left normal.
    ``lateral_sd`` (m): std. dev. of the vehicles' lateral offsets from their lane centres."""
    rng = np.random.default_rng(seed)
    Tinv = np.linalg.inv(T_true)
    yaw_c = se2_params(Tinv)[2]
    radii = rectangle_radius(contour_angles(), LENGTH, WIDTH)
    det, tracks, xy_l, nrm_l = [], [], [], []
    lanes = _lanes(crossing)
    counts = per_lane if isinstance(per_lane, tuple) else (per_lane,) * len(lanes)
    for (start, heading), count in zip(lanes, counts, strict=True):
        d = np.array([np.cos(heading), np.sin(heading)])
        left = np.array([-d[1], d[0]])
        u = np.arange(0.0, 80.0, 0.25)
        xy_l.append(start + u[:, None] * d)
        nrm_l.append(np.tile(left, (len(u), 1)))
        for _ in range(count):
            lateral = rng.normal(0.0, lateral_sd)
            s0 = rng.uniform(2.0, 30.0)
            n = 16                                   # 5 Hz, 3.2 s, 10 m/s
            centres = start + (s0 + 2.0 * np.arange(n))[:, None] * d + lateral * left
            towards = np.sign(left @ (sensor_l - start)) * left
            centres = centres + (range_bias / 100.0 * np.linalg.norm(centres - sensor_l,
                                                                     axis=1))[:, None] * towards
            states = np.zeros((n, N_STATE))
            states[:, :2] = transform_points(Tinv, centres)
            states[:, 2] = 10.0
            states[:, 4] = heading + yaw_c
            states[:, 6:] = radii
            di, ds = [], []
            for step, c in enumerate(centres):
                z = _visible_points(c, heading, sensor_l, rng)
                di += list(range(len(det), len(det) + len(z)))
                ds += [step] * len(z)
                det += list(transform_points(Tinv, z))
            tracks.append(Track(len(tracks), 0.2 * np.arange(n), states,
                                np.full(n, STRAIGHT, np.int8), None,
                                np.array(di, np.int64), np.array(ds, np.int64)))
    lane = np.repeat(np.arange(len(xy_l)), [len(p) for p in xy_l])
    xy, nrm = np.vstack(xy_l), np.vstack(nrm_l)
    side = np.sign(np.einsum("ij,ij->i", sensor_l - xy, nrm))
    shift = offset * side
    if lane_shift is not None:
        shift = shift + np.where(lane == lane_shift[0], lane_shift[1], 0.0)
    lines = LaneLines.of(xy + shift[:, None] * nrm, nrm, np.full(len(xy), STRAIGHT), lane)
    return (TrackSet(tracks), np.array(det), transform_points(Tinv, sensor_l[None])[0], lines)


def _cfg(**joint) -> Config:
    cfg = Config()
    cfg.joint = dataclasses.replace(cfg.joint, step_stride=1, max_points_per_frame=6, **joint)
    return cfg


@pytest.mark.parametrize("seed,pose,sensor", [
    (1, (0.4, -0.3, 0.6), (12.0, -12.0)),
    (2, (-0.5, 0.2, -0.8), (-9.0, 15.0)),
])
def test_known_offset_recovered_and_covered(seed, pose, sensor):
    T_true = se2(pose[0], pose[1], np.deg2rad(pose[2]))
    tracks, det, sensor_c, lines = _scene(True, T_true, np.array(sensor), seed)
    res = joint_refine(tracks, det, sensor_c, lines, np.eye(3), _cfg())
    est, true = np.array(se2_params(res.T)), np.array(se2_params(T_true))
    e = est - true
    e[2] = wrap_angle(e[2])
    assert np.hypot(e[0], e[1]) < 0.15 and abs(np.rad2deg(e[2])) < 0.15, e
    assert res.covariance is not None
    nees = float(e @ np.linalg.solve(res.covariance, e))
    assert nees < 16.3, (nees, e, np.sqrt(np.diag(res.covariance)))   # chi2(3) 99.9 %
    sd = np.sqrt(np.diag(res.covariance))
    assert sd[0] < 0.2 and sd[1] < 0.2                                  # informative, too
    deg = degeneracy_report(res.covariance, res.T, res.matched, 0.3)
    assert deg["available"] and not deg["weakly_observed"]
    assert res.converged and len(res.tracks) == len(tracks)


@pytest.mark.parametrize("error", [(0.0, 0.5, 0.0), (0.4, -0.3, 0.3)])
def test_noise_levels_do_not_grow_with_the_pose_error(error):
    """The offset level is the vehicles' lateral scatter about their lanes (known: 0.3 m) at
    the true pose and at a pose off by ``error`` (m, m, deg) alike: estimated at a pose off
    across a road, every track on it shares the error, and an offset level that grew with it
    let the joint drift (T-junction at 10 vehicles per minute, seed 2: 0.35 m)."""
    from fgloc.registration.joint import _correspondences, frame_points, noise_levels
    from fgloc.smoothing.graph import contour_gp

    T_true = se2(0.2, -0.1, np.deg2rad(0.3))
    tracks, det, sensor_c, lines = _scene(True, T_true, np.array([12.0, -12.0]), 5,
                                          per_lane=8, lateral_sd=0.3)
    cfg = _cfg()
    gp = contour_gp(cfg.tracking)
    x = np.concatenate([tr.states for tr in tracks.tracks])
    start = np.concatenate([[0], np.cumsum([len(tr) for tr in tracks.tracks])])
    fp = frame_points(tracks, start, det, sensor_c, gp, 6)
    T_off = se2(error[0], error[1], np.deg2rad(error[2])) @ T_true
    levels = []
    for T in (T_true, T_off):
        idx, _, target, normal = _correspondences(fp, x, np.array(se2_params(T)), lines, gp,
                                                  cfg.joint)
        assert np.count_nonzero(idx >= 0) > 0.95 * len(idx)
        levels.append(noise_levels(fp, x[fp.frame_state], T, idx, target, normal, gp,
                                   len(tracks), 0.01))
    at_truth, off = levels
    assert 0.2 < at_truth.offset < 0.4, at_truth
    assert abs(off.offset - at_truth.offset) < 0.02, (at_truth, off)
    assert abs(off.frame - at_truth.frame) < 0.2 * at_truth.frame, (at_truth, off)


def test_straight_road_flags_the_along_road_direction():
    T_true = se2(0.6, 0.25, np.deg2rad(0.5))
    tracks, det, sensor_c, lines = _scene(False, T_true, np.array([5.0, -14.0]), 3, per_lane=5)
    res = joint_refine(tracks, det, sensor_c, lines, np.eye(3), _cfg())
    e = np.array(se2_params(res.T)) - np.array(se2_params(T_true))
    # across the road and in yaw the pose is found ...
    assert abs(e[1]) < 0.15 and abs(np.rad2deg(wrap_angle(e[2]))) < 0.2, e
    # ... along it (x) nothing observes it: a large variance and the flag, not a confident 0.6
    deg = degeneracy_report(res.covariance, res.T, res.matched, 0.3)
    assert deg["weakly_observed"]
    weak = max(deg["weak_directions"], key=lambda d: d["std_m"])
    assert abs(np.cos(np.deg2rad(weak["translation_heading_deg"]))) > 0.95
    assert weak["std_m"] > 1.0
    assert np.sqrt(res.covariance[0, 0]) > 1.0 and np.sqrt(res.covariance[1, 1]) < 0.2


def test_range_bias_is_estimated_with_the_pose():
    """Vehicles placed towards the sensor by 0.6 m per 100 m of range (the tracker's bias
    the joint models, ``range_bias_sigma``): with the bias parameter (prior 0.5 m / 100 m)
    the pose is found and covered and the bias comes out towards the sensor; without it the
    bias is read as a confident pose error twice as large (the considered constant bias, which
    would widen that covariance, off in both)."""
    T_true = se2(0.3, -0.2, np.deg2rad(0.4))
    tracks, det, sensor_c, lines = _scene(True, T_true, np.array([30.0, -30.0]), 4,
                                          per_lane=6, range_bias=0.6)
    out = {}
    for sd in (0.5, 0.0):
        res = joint_refine(tracks, det, sensor_c, lines, np.eye(3),
                           _cfg(range_bias_sigma=sd, consider_side_bias_sigma=0.0))
        e = np.array(se2_params(res.T)) - np.array(se2_params(T_true))
        e[2] = wrap_angle(e[2])
        out[sd] = (float(np.hypot(e[0], e[1])), float(np.rad2deg(abs(e[2]))),
                   float(e @ np.linalg.solve(res.covariance, e)), res.history[-1]["side_bias_m"])
        assert res.converged
    with_bias, without = out[0.5], out[0.0]
    assert with_bias[0] < 0.25 and with_bias[1] < 0.1 and with_bias[2] < 16.3, out
    assert 0.3 < with_bias[3][0] < 0.8, out
    assert without[0] > 2 * with_bias[0] and without[2] > 16.3, out


@pytest.mark.parametrize("sensor", [(12.0, -12.0), (0.5, -12.0)])
def test_considered_side_bias_is_the_pose_shift_a_real_bias_causes(sensor):
    """The considered constant side bias (``consider_side_bias_sigma``, not estimated) adds
    ``sigma^2 K K^T`` to the covariance, K the pose's sensitivity to the bias. Checked
    against central differences: the joint on the same scene with the target lines moved
    +-0.1 m towards the sensor (a real side bias of 0.1 m) moves the pose by K * 0.1 (noise
    levels fixed, so both runs weigh the points alike). The sensor in a quadrant of the
    crossing has every lane on one side (the bias is a translation, as on a T-junction);
    between the north-south lanes it is told apart there."""
    T_true = se2(0.3, -0.2, np.deg2rad(0.4))
    runs = {}
    for offset in (-0.1, 0.0, 0.1):
        scene = _scene(True, T_true, np.array(sensor), 6, offset=offset)
        runs[offset] = joint_refine(*scene, np.eye(3), _cfg(consider_side_bias_sigma=0.0,
                                                            estimate_noise=False))
    considered = joint_refine(*_scene(True, T_true, np.array(sensor), 6), np.eye(3),
                              _cfg(consider_side_bias_sigma=0.1, estimate_noise=False))
    assert np.allclose(se2_params(considered.T), se2_params(runs[0.0].T), atol=1e-9)
    extra = considered.covariance_model - runs[0.0].covariance_model
    shift = 0.5 * (np.array(se2_params(runs[0.1].T)) - np.array(se2_params(runs[-0.1].T)))
    assert abs(shift[1]) > 0.08                         # the bias does move the pose
    assert np.allclose(np.diag(extra), shift**2, rtol=0.1, atol=(2e-5, 2e-5, 1e-9)), (
        np.diag(extra), shift**2)
    assert np.all(np.linalg.eigvalsh(considered.covariance - runs[0.0].covariance) > -1e-12)


@pytest.mark.parametrize("sensor", [(12.0, -12.0), (0.5, -12.0)])
def test_considered_lane_biases_are_the_pose_shifts_real_lane_biases_cause(sensor):
    """One lateral bias per lanelet, considered (``consider_lane_bias_sigma``): the
    covariance gains ``sum_j sigma^2 K_j K_j^T``. Checked against central differences: the
    joint with lane j's line moved +-0.1 m along its normal (every vehicle of that lane off
    its line alike) moves the pose by ``K_j 0.1``; the added covariance is the sum of those
    squared shifts over the four lanes (noise levels fixed)."""
    T_true = se2(0.3, -0.2, np.deg2rad(0.4))
    plain = _cfg(consider_side_bias_sigma=0.0, consider_lane_bias_sigma=0.0,
                 estimate_noise=False)
    expected = np.zeros((3, 3))
    for lane in range(4):
        pose = {}
        for shift in (-0.1, 0.1):
            scene = _scene(True, T_true, np.array(sensor), 6, lane_shift=(lane, shift))
            pose[shift] = np.array(se2_params(joint_refine(*scene, np.eye(3), plain).T))
        d = 0.5 * (pose[0.1] - pose[-0.1])
        expected += np.outer(d, d)
    scene = _scene(True, T_true, np.array(sensor), 6)
    base = joint_refine(*scene, np.eye(3), plain)
    considered = joint_refine(*scene, np.eye(3), dataclasses.replace(
        plain, joint=dataclasses.replace(plain.joint, consider_lane_bias_sigma=0.1)))
    assert np.allclose(se2_params(considered.T), se2_params(base.T), atol=1e-9)
    extra = considered.covariance_model - base.covariance_model
    assert np.sqrt(expected[0, 0] + expected[1, 1]) > 0.02      # the lanes do move the pose
    scale = np.sqrt(np.outer(np.diag(expected), np.diag(expected)))
    assert np.all(np.abs(extra - expected) <= 0.1 * scale + 1e-12), (extra, expected)


@pytest.mark.parametrize("sensor", [(12.0, -12.0), (0.5, -12.0)])
def test_estimated_lane_biases_weigh_each_lane_alike(sensor):
    """``lane_bias_sigma`` (the noise levels fixed): one lateral bias per
    lane, estimated. The east-west road's two lanes carry 8 and 2 vehicles; moving either
    lane's line 0.4 m (every vehicle of that lane off its line alike) moves the plain
    estimate across that road in proportion to the lane's vehicles (the busy lane at least
    twice as far as the quiet one), the estimate with the biases (the generalized
    least-squares one) far more alike (its ratio above 0.7 and under 0.6 of the plain
    one's: 1.7 against 3.7 with the sensor at (12, -12)), and the estimated biases of that road's
    two lanes take up the shift (each at least 0.08 m, the other road's under a third of
    that). Each error stays within 2.5 std. devs. of the covariance that holds the biases."""
    T_true = se2(0.3, -0.2, np.deg2rad(0.4))
    counts = (8, 2, 4, 4)
    base = _scene(True, T_true, np.array(sensor), 3, per_lane=counts)
    moved = {}
    for lb in (0.0, 0.2):
        cfg = _cfg(lane_bias_sigma=lb, estimate_noise=False)
        y0 = se2_params(joint_refine(*base, np.eye(3), cfg).T)[1]
        for lane in (0, 1):
            scene = _scene(True, T_true, np.array(sensor), 3, per_lane=counts,
                           lane_shift=(lane, 0.4))
            res = joint_refine(*scene, np.eye(3), cfg)
            moved[lb, lane] = abs(se2_params(res.T)[1] - y0)
            err = np.array(se2_params(res.T)[:2]) - se2_params(T_true)[:2]
            if lb > 0:
                assert np.all(np.abs(err) < 2.5 * np.sqrt(np.diag(res.covariance)[:2]))
                bias = res.history[-1]["lane_bias_m"]
                road = np.abs([bias["0"], bias["1"]])
                assert road.min() > 0.08, bias
                assert max(abs(bias["2"]), abs(bias["3"])) < road.min() / 3, bias
    plain, gls = moved[0.0, 0] / moved[0.0, 1], moved[0.2, 0] / moved[0.2, 1]
    assert plain > 2.0, moved
    assert 0.7 < gls < 0.6 * plain, moved


def test_estimated_lane_biases_replace_the_considered_ones():
    """With ``lane_bias_sigma`` (the noise levels fixed) the lane biases are
    parameters of the graph: its marginal covariance holds them, and only what
    ``consider_lane_bias_sigma`` exceeds them by is considered on top (0.1 against 0.1:
    nothing, the same covariance as with 0; 0.3: a wider one, the same estimate); without
    biases in the data the estimate stays within 0.05 m of the plain one, and a larger
    ``lane_bias_sigma`` gives a larger covariance."""
    T_true = se2(0.3, -0.2, np.deg2rad(0.4))
    scene = _scene(True, T_true, np.array([12.0, -12.0]), 6)
    runs = {(lb, c): joint_refine(*scene, np.eye(3), _cfg(
        lane_bias_sigma=lb, consider_lane_bias_sigma=c, estimate_noise=False))
            for lb, c in [(0.0, 0.0), (0.1, 0.0), (0.1, 0.1), (0.1, 0.3), (0.3, 0.0)]}
    assert np.allclose(runs[0.1, 0.0].covariance, runs[0.1, 0.1].covariance, rtol=1e-9)
    assert np.allclose(se2_params(runs[0.1, 0.0].T), se2_params(runs[0.1, 0.3].T), atol=1e-12)
    var = {k: np.trace(r.covariance[:2, :2]) for k, r in runs.items()}
    assert var[0.1, 0.3] > 1.2 * var[0.1, 0.0], var
    assert np.hypot(*(np.array(se2_params(runs[0.1, 0.0].T)[:2])
                      - se2_params(runs[0.0, 0.0].T)[:2])) < 0.05
    assert var[0.0, 0.0] < var[0.1, 0.0] < var[0.3, 0.0], var


def test_tracks_too_short_for_the_graph_are_a_localization_error():
    """No track long enough for ``[joint] min_track_steps``: the data do not support the
    joint graph (exit 2 from the CLI), with the longest track's length in the message."""
    tracks, det, sensor_c, lines = _scene(True, np.eye(3), np.array([12.0, -12.0]), 1)
    longest = max(len(tr) for tr in tracks.tracks)
    with pytest.raises(LocalizationError, match=rf"no track has {longest + 1} steps at stride "
                       rf"1 \({len(tracks)} tracks, the longest {longest} steps"):
        joint_refine(tracks, det, sensor_c, lines, np.eye(3),
                     _cfg(min_track_steps=longest + 1))


def test_config_fields_are_checked():
    check_joint_config(JointConfig())
    for field, value in [("start", "x"), ("smoother", "kalman"), ("step_stride", 0),
                         ("along_weight", 2.0),
                         ("label_weight_other", -0.1), ("max_rounds", 0),
                         ("consider_side_bias_sigma", -0.1),
                         ("consider_lane_bias_sigma", -0.1), ("lane_bias_sigma", -0.1)]:
        with pytest.raises(ValueError, match=field):
            check_joint_config(dataclasses.replace(JointConfig(), **{field: value}))


def _small_round(cfg: Config, glob: np.ndarray, sensor_l: np.ndarray) -> SimpleNamespace:
    """One round's problem on a small crossing scene (4 tracks of 6 steps, states perturbed):
    tracks, stacked states x, track quadratic tq, contour GP gp, frame points fp, the
    round's PointSet pts at global parameters ``glob`` (pose, then the side-bias ones) with the
    sensor at ``sensor_l`` in L, track offsets b, lengths, owner, det, sensor_c."""
    from fgloc.registration import joint as J

    T_true = se2(0.3, -0.2, np.deg2rad(0.4))
    tracks, det, sensor_c, lines = _scene(True, T_true, np.array([12.0, -12.0]), 5,
                                          per_lane=1)
    # the two constructions of the centre lines up to 0.4 m apart, varying along the lanes
    off = 0.3 * np.column_stack([np.sin(lines.xy[:, 0] / 7.0), np.cos(lines.xy[:, 1] / 5.0)])
    lines = J.LaneLines.of(lines.xy, lines.normal, lines.label, lines.lane, off)
    tracks = dataclasses.replace(tracks, tracks=[dataclasses.replace(
        t, t=t.t[:6], states=t.states[:6], labels=t.labels[:6],
        det_index=t.det_index[t.det_step < 6], det_step=t.det_step[t.det_step < 6])
        for t in tracks.tracks])
    lengths = [len(t) for t in tracks.tracks]
    start = np.concatenate([[0], np.cumsum(lengths)])
    owner = np.repeat(np.arange(len(lengths)), lengths)
    x = np.concatenate([t.states for t in tracks.tracks])
    x = x + np.random.default_rng(1).normal(0, 0.02, x.shape)
    tq, gp = J.track_quadratic(tracks, det, sensor_c, cfg, x)
    fp = J.frame_points(tracks, start, det, sensor_c, gp, 6)
    b = np.array([0.05, -0.02, 0.0, 0.03])
    index, compat, target, normal = J._correspondences(fp, x, glob[:3], lines, gp, cfg.joint)
    sigma = np.full(len(index), 0.2)
    pts = J._point_set(fp, fp.padded(6), index, compat, target, normal, sigma, x, glob, b,
                       0.2, gp, cfg.joint, sensor_l, J.centre_shift(lines, index, normal))
    return SimpleNamespace(tracks=tracks, x=x, tq=tq, gp=gp, fp=fp, pts=pts, pose=glob, b=b,
                           lengths=lengths, owner=owner, det=det, sensor_c=sensor_c)


def test_side_bias_jacobians_match_central_differences():
    """The point rows' derivatives w.r.t. the global parameters -- the pose, the constant
    and the range-proportional side bias, the centre-line share -- equal central
    differences."""
    cfg = _cfg(side_bias_sigma=0.1, range_bias_sigma=0.2, centre_line_sigma=0.5)
    glob = np.array([0.25, -0.1, 0.005, 0.05, 0.1, 0.2])
    r = _small_round(cfg, glob, np.array([12.0, -12.0]))
    assert r.pts.n_global == 6 and r.pts.side.shape[-1] == 3
    _, (Jp, _, _) = r.pts.rows(r.x, glob, r.b, jacobian=True)
    num = np.zeros_like(Jp)
    for i in range(6):
        d = np.zeros(6)
        d[i] = 1e-6
        num[..., i] = (r.pts.rows(r.x, glob + d, r.b)[0]
                       - r.pts.rows(r.x, glob - d, r.b)[0]) / 2e-6
    np.testing.assert_allclose(Jp, num, atol=1e-6 * max(1.0, np.abs(num).max()))
    assert (np.abs(Jp[..., 3:]).max(axis=(0, 1, 2)) > 0.05).all()   # no empty column


def test_arrow_solve_and_covariance_match_gtsam():
    """One Gauss-Newton step and the pose's marginal covariance of the vectorized joint
    problem equal gtsam's on the equivalent factor graph (the track graph, one
    point_to_point_factor per frame, the pose and offset priors)."""
    import gtsam

    from factors.gtsam_factors import sensor_key
    from factors.registration_factors import PointRows, offset_key, point_to_point_factor
    from fgloc.registration.joint_solver import Priors, linearize, solve_arrow
    from fgloc.smoothing.banded_lm import BandedLayout
    from fgloc.smoothing.graph import build_track_graph

    cfg = _cfg(range_bias_sigma=0.0, centre_line_sigma=0.0, extent_rows=True)
    # every frame's extent rows: with the smoothers' face test (12 detections on a face) this
    # small scene keeps none, and gtsam's Cholesky calls the graph indeterminate
    cfg.smoothing.extent_face_min_points = 0
    r = _small_round(cfg, np.array([0.25, -0.1, 0.005]), np.zeros(2))
    tracks, x, tq, gp, fp, pts, pose, b = r.tracks, r.x, r.tq, r.gp, r.fp, r.pts, r.pose, r.b
    lengths, owner, det, sensor_c = r.lengths, r.owner, r.det, r.sensor_c
    pri = Priors(np.zeros(3), np.array([1 / 20, 1 / 20, 1 / 0.03]), 1 / 0.3)
    sol = solve_arrow(linearize(tq, pts, pri, len(lengths), x, pose, b),
                      BandedLayout(len(x), tq.below), owner, True)

    scfg = dataclasses.replace(cfg.smoothing, extent_rows=cfg.joint.extent_rows)
    tg = build_track_graph(tracks, det, sensor_c, scfg, cfg.tracking)
    values = gtsam.Values()
    for k, v in zip(np.concatenate(tg.keys), x):
        values.update(int(k), v) if values.exists(int(k)) else values.insert(int(k), v)
    G = sensor_key()
    values.insert(G, pose)
    graph = tg.graph
    graph.add(gtsam.PriorFactorVector(G, np.zeros(3),
                                      gtsam.noiseModel.Diagonal.Sigmas(1 / pri.pose_w)))
    for i, t in enumerate(tracks.tracks):
        values.insert(offset_key(t.id), b[i:i + 1])
        graph.add(gtsam.PriorFactorVector(offset_key(t.id), np.zeros(1),
                                          gtsam.noiseModel.Isotropic.Sigma(1, 0.3)))
    for f in range(len(fp.frame_state)):
        w = pts.weights[f]
        use = w > 0
        if not use.any():
            continue
        rows = PointRows(pts.theta[f][use], pts.target[f][use], pts.normal[f][use],
                         pts.sqrt_info[f][use], np.ones(use.sum()), np.inf, gp,
                         pts.H[f][use], pts.mean[f][use], w[use])
        t = tracks.tracks[fp.frame_track[f]]
        graph.add(point_to_point_factor(G, int(tg.keys[fp.frame_track[f]][fp.frame_step[f]]),
                                        rows, offset_key(t.id)))
    delta = graph.linearize(values).optimize()
    np.testing.assert_allclose(sol.dp, delta.at(G), rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(sol.db, [delta.at(offset_key(t.id))[0] for t in tracks.tracks],
                               rtol=1e-6, atol=1e-9)
    dx = np.array([delta.at(int(k)) for k in np.concatenate(tg.keys)])
    np.testing.assert_allclose(sol.dx, dx, rtol=1e-5, atol=1e-7 * np.abs(dx).max())
    expect = gtsam.Marginals(graph, values).marginalCovariance(G)
    np.testing.assert_allclose(np.linalg.inv(sol.pose_information), expect, rtol=1e-6)


@pytest.mark.slow
def test_localize_joint_end_to_end():
    """``localize(..., "joint")`` on a short simulated intersection: a pose near the truth, a
    covariance, refined tracks and the degeneracy report in the diagnostics."""
    from fgloc.evaluation.pose import pose_error
    from fgloc.pipeline import localize
    from fgloc.sim import simulate

    scn = simulate("intersection", 3, duration=30.0)
    res = localize(scn, "joint")
    err = pose_error(res.T_local, scn.truth.sensor_pose)
    assert err.d2d < 0.5 and err.dyaw_deg < 0.5
    assert res.covariance is not None and np.all(np.linalg.eigvalsh(res.covariance) > 0)
    doc = res.to_json()
    assert doc["method"] == "joint" and len(doc["covariance"]) == 3
    assert "degeneracy" in doc["diagnostics"]["joint"]
    assert res.tracks is not None and len(res.tracks) > 0


def _lines_moved(lines: LaneLines, lanes: tuple[int, ...], shift: np.ndarray) -> LaneLines:
    """``lines`` with the samples of ``lanes`` moved along their normals by ``shift`` (M,)."""
    on = np.isin(lines.lane, lanes)
    xy = lines.xy + np.where(on, shift, 0.0)[:, None] * lines.normal
    return LaneLines.of(xy, lines.normal, lines.label, lines.lane)


def test_lane_evidence_prefers_the_lines_the_tracks_follow():
    """Vehicles drive the crossing's four lanes; a second set of lines bends two of them
    sideways by 1.5 m over 20 m of their length (as the two lane models of a two-way street
    differ where a lane bends out of its right half, :mod:`fgloc.registration.lane_evidence`).
    The joint's track misfits rule the bent lines out whichever model names them, the tracks
    on the bent lanes carrying it. Drivers each 0.4 m (sd) off their lane's centre cost as
    little as drivers on it: a track's constant offset is no misfit."""
    from fgloc.registration.lane_evidence import decided_lane_model

    T_true = se2(0.2, -0.1, np.deg2rad(0.3))
    tracks, det, sensor_c, lines = _scene(True, T_true, np.array([12.0, -12.0]), 7, per_lane=8)
    u = np.concatenate([np.arange(0.0, 80.0, 0.25)] * 4)          # along each lane (m)
    bent = _lines_moved(lines, (0, 2), 1.5 * np.clip((u - 20.0) / 20.0, 0.0, 1.0))
    cfg = _cfg()
    true, off = (joint_refine(tracks, det, sensor_c, lines, np.eye(3), cfg),
                 joint_refine(tracks, det, sensor_c, bent, np.eye(3), cfg))
    on_bent = np.repeat(np.isin(np.arange(4), (0, 2)), 8)         # 8 tracks per lane, in order
    excess = off.track_misfit - true.track_misfit
    # (the other tracks' excess: the pose's compromise with the bent lines, a tenth of it)
    assert excess[on_bent].min() > 1.0
    assert np.abs(excess[~on_bent]).max() < 0.1 * excess[on_bent].mean(), excess
    for good, bad in (("keep-right", "centre"), ("centre", "keep-right")):
        decided, ev = decided_lane_model([(good, true.track_misfit), (bad, off.track_misfit)],
                                         3.0)
        assert decided == good and ev["z"][bad] >= 3.0 and ev["z"][good] == 0.0, ev
    # one model only: nothing to decide
    assert decided_lane_model([("keep-right", true.track_misfit)], 3.0)[0] is None
    wide = _scene(True, T_true, np.array([12.0, -12.0]), 7, per_lane=8, lateral_sd=0.4)
    spread = joint_refine(*wide, np.eye(3), cfg).track_misfit
    # per track 0.002 on the line and 0.03-0.04 at 0.4 m off it (the offsets themselves would
    # cost about 1.1: 16 frames of 0.4^2 / 1.5^2), against 1-3.5 more on a bent lane
    assert max(spread.max(), true.track_misfit.max()) < 0.03 * excess[on_bent].mean(), spread
