"""Considered biases (fgloc.registration.considered) and the SICP track covariance that adds
them: closed-form shifts and calibration against known truth."""

from __future__ import annotations

import numpy as np
import pytest

from fgloc.geo import se2_params
from fgloc.registration.config import SicpConfig
from fgloc.registration.considered import lane_columns, least_squares_consider, side_sign
from fgloc.registration.sicp import SemanticTargets, sicp, track_covariance


def _wls(a: np.ndarray, w: np.ndarray, r: np.ndarray) -> np.ndarray:
    """The weighted least-squares step ``H^-1 sum w a r``."""
    return np.linalg.solve((w[:, None] * a).T @ a, (w[:, None] * a).T @ r)


def test_least_squares_consider_is_the_shift_each_bias_causes():
    """A bias c_j added to the residuals of group j moves the weighted least-squares estimate
    by k_j c_j; with one bias the added covariance is sigma^2 k k^T exactly, with two
    independent ones the sum of both."""
    g = np.random.default_rng(3)
    a, w, r = g.normal(size=(40, 3)), g.uniform(0.2, 1.0, 40), g.normal(size=40)
    group = np.repeat([0, 1], 20)
    cols = lane_columns(group)
    H = (w[:, None] * a).T @ a
    k = [(_wls(a, w, r + 0.1 * cols[:, j]) - _wls(a, w, r)) / 0.1 for j in range(2)]
    one = least_squares_consider(H, w[:, None] * a, cols[:, :1], np.array([0.3]))
    np.testing.assert_allclose(one, 0.09 * np.outer(k[0], k[0]), rtol=1e-9, atol=1e-12)
    both = least_squares_consider(H, w[:, None] * a, cols, np.array([0.3, 0.2]))
    np.testing.assert_allclose(both, 0.09 * np.outer(k[0], k[0]) + 0.04 * np.outer(k[1], k[1]),
                               rtol=1e-9, atol=1e-12)


def test_side_sign_and_lane_columns():
    normal = np.array([[0.0, 1.0], [0.0, 1.0]])
    assert side_sign(np.array([[0.0, -5.0], [0.0, 5.0]]), normal, np.zeros(2)).tolist() == [1, -1]
    cols = lane_columns(np.array([7, -1, 3, 7]))
    assert cols.tolist() == [[0, 1], [0, 0], [1, 0], [0, 1]]


def _line(p0, p1, step=0.5):
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    n = int(np.linalg.norm(p1 - p0) / step) + 1
    return p0 + np.linspace(0.0, 1.0, n)[:, None] * (p1 - p0)


def _roads(ys: list[float], seed: int, lane_sd: float = 0.0, side: float = 0.0,
           sensor: np.ndarray | None = None):
    """East-west lanes at heights ``ys`` (driven east) and a north-south one at x = 15 (driven
    north), 6 vehicles on each east-west lane and 3 on the north-south one (60 points, own
    offset 0.05 m, point noise 0.05 m): each lane's vehicles all off by the lane's bias ~ N(0,
    lane_sd^2), and every point ``side`` m towards ``sensor``. Targets with lane ids, source
    xy, directions, track ids (truth: the identity)."""
    g = np.random.default_rng(seed)
    lines = [_line((-60, y), (40, y)) for y in ys] + [_line((15, -30), (15, 60))]
    dirs = [np.array([1.0, 0.0])] * len(ys) + [np.array([0.0, 1.0])]
    targets = SemanticTargets.build(
        np.vstack(lines), np.zeros(sum(map(len, lines))),
        np.vstack([np.tile(d, (len(ln), 1)) for d, ln in zip(dirs, lines)]),
        lane=np.concatenate([np.full(len(ln), k) for k, ln in enumerate(lines)]))
    xy, direction, track = [], [], []
    for k, d in enumerate(dirs):
        bias = g.normal(0.0, lane_sd) if lane_sd > 0 else 0.0
        for _ in range(6 if k < len(ys) else 3):
            s = g.uniform(-50.0, 30.0, 60) if k < len(ys) else g.uniform(-20.0, 50.0, 60)
            off = bias + g.normal(0.0, 0.05) + g.normal(0.0, 0.05, 60)
            p = (np.column_stack([s, ys[k] + off]) if k < len(ys)
                 else np.column_stack([15.0 - off, s]))
            if side:
                n = np.tile([-d[1], d[0]], (60, 1))
                p = p + side * side_sign(p, n, sensor)[:, None] * n
            xy.append(p)
            direction.append(np.tile(d, (60, 1)))
            track.append(np.full(60, len(track)))
    return targets, np.vstack(xy), np.vstack(direction), np.concatenate(track)


def _fit(targets, xy, direction, track, cfg, sensor=None):
    res = sicp(xy, np.zeros(len(xy)), targets, None, np.eye(3), cfg, source_direction=direction)
    return np.array(se2_params(res.T)), track_covariance(res, xy, track, targets, cfg, sensor)


def test_lane_bias_is_counted_once_per_lane_whatever_its_vehicles():
    """Every vehicle of a lane shares that lane's bias (0.2 m): the per-track covariance,
    which takes the vehicles as independent, claims far too much (mean NEES of (tx, ty, yaw)
    over 30 draws far above 3); with the lane bias considered at its true std. dev. it is
    calibrated."""
    off = SicpConfig(consider_lane_bias_sigma=0.0, consider_side_bias_sigma=0.0)
    on = SicpConfig(consider_lane_bias_sigma=0.2, consider_side_bias_sigma=0.0)
    nees_off, nees_on = [], []
    for seed in range(30):
        data = _roads([0.0], seed, lane_sd=0.2)
        e, cov = _fit(*data, off)
        nees_off.append(e @ np.linalg.solve(cov, e))
        e, cov = _fit(*data, on)
        nees_on.append(e @ np.linalg.solve(cov, e))
    assert np.mean(nees_off) > 10.0
    assert 1.0 < np.mean(nees_on) < 4.5


@pytest.mark.parametrize("ys, grows", [([-8.0], True), ([-8.0, 8.0], False)])
def test_side_bias_widens_only_where_the_lanes_cannot_tell_it(ys, grows):
    """A shift of every point 0.1 m towards the sensor at the origin: with the east-west lane
    south of it only (and the north-south one east: all on one side) the shift is a
    translation, and the considered side bias widens x and y by about its std. dev.; with
    lanes north and south of it the shifts cancel across the road and y hardly widens (x,
    fixed by the north-south lane alone, still does)."""
    sensor = np.zeros(2)
    off = SicpConfig(consider_lane_bias_sigma=0.0, consider_side_bias_sigma=0.0)
    on = SicpConfig(consider_lane_bias_sigma=0.0, consider_side_bias_sigma=0.1)
    data = _roads(ys, 1, side=0.1, sensor=sensor)
    e, cov_off = _fit(*data, off, sensor)
    _, cov_on = _fit(*data, on, sensor)
    added = np.sqrt(np.diag(cov_on - cov_off)[:2])
    if grows:
        np.testing.assert_allclose(added, 0.1, rtol=0.2)
        # the shift moves the pose across the east-west road: unseen, then covered
        assert abs(e[1]) > 2.5 * np.sqrt(cov_off[1, 1])
        assert abs(e[1]) < 1.5 * np.sqrt(cov_on[1, 1])
    else:
        assert added[1] < 0.02


def _lane_centres(ys: list[float]):
    """LaneCentres of east-west lanes at heights ``ys`` (driven east) and a north-south one at
    x = 15 (driven north), samples 0.25 m apart."""
    from fgloc.coarse.icp import LaneCentres

    lines = [_line((-60, y), (40, y), 0.25) for y in ys] + [_line((15, -30), (15, 60), 0.25)]
    normals = [np.array([0.0, 1.0])] * len(ys) + [np.array([-1.0, 0.0])]
    return LaneCentres(np.vstack(lines),
                       np.vstack([np.tile(n, (len(ln), 1)) for n, ln in zip(normals, lines)]),
                       np.zeros(sum(map(len, lines)), bool),
                       np.concatenate([np.full(len(ln), k) for k, ln in enumerate(lines)]),
                       np.concatenate([np.full(len(ln), k) for k, ln in enumerate(lines)]))


@pytest.mark.parametrize("ys, grows", [([-8.0], True), ([-8.0, 8.0], False)])
def test_lane_fit_considered_is_the_lane_icps_shift_under_a_side_bias(ys, grows):
    """icp's considered side bias (sigma 0.1 m) against the lane-centre ICP itself: points on
    lanes seen from the sensor at the origin, every one moved 0.15 m away from the sensor (the
    visible-side offsets, :func:`fgloc.coarse.localize.side_offsets`, 0.15 m too small;
    spread along their lanes between the samples), are fitted from the truth; the fit moves
    by the linearized shift per unit bias times 0.15 (the square root of the considered variance
    over sigma^2) to within a centimetre: with every lane on one side of the sensor by about
    the bias in x and y, with lanes on both sides not across them (y)."""
    from fgloc.coarse.icp import icp_planar
    from fgloc.coarse.localize import _seen_from, lane_fit_considered, side_offsets
    from fgloc.config import CoarseConfig

    cfg = CoarseConfig(lane_doppler_gate_deg=90.0, consider_lane_bias_sigma=0.0)
    lanes = _lane_centres(ys)
    pose = np.zeros(3)
    seen = lanes.towards(pose[:2], side_offsets(lanes, pose[:2], cfg)).xy
    along = np.column_stack([lanes.normal[:, 1], -lanes.normal[:, 0]])
    jitter = np.random.default_rng(2).uniform(-0.125, 0.125, len(seen))[:, None] * along
    lev = seen + jitter - 0.15 * side_sign(seen, lanes.normal, pose[:2])[:, None] * lanes.normal
    receding = np.ones(len(lev), bool)
    extra = lane_fit_considered(pose, seen, receding, lanes, cfg)
    end = icp_planar(lev, _seen_from(lanes, pose[:2], cfg), pose, cfg.lane_icp_ranges,
                     cfg.icp_iterations, receding=receding).pose
    predicted = np.sqrt(np.diag(extra)) / cfg.consider_side_bias_sigma * 0.15
    np.testing.assert_allclose(np.abs(end[:2]), predicted[:2], atol=0.01)
    assert (predicted[1] > 0.1) == grows
