"""Tests of the vectorized track factors (factors.track_system, fgloc.smoothing.graph.stack_tracks)
against the gtsam graph of the same tracks, of the batched measurement rows against the
one-frame ones, of the banded storage, and of the banded Levenberg-Marquardt against gtsam's."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from test_gtsam_factors import GP, random_state
from test_smoothing_graph import make_track

from factors.gp import rectangle_radius
from factors.gtsam_factors import (
    ContourMeasurement,
    ExtentRows,
    ExtentSettings,
    RangeRateRows,
    contour_measurement_factor,
)
from factors.measurement import range_rate
from fgloc.smoothing import SmoothingConfig
from fgloc.smoothing.banded_lm import BandedLayout, damped_step, levenberg_marquardt
from fgloc.smoothing.graph import (
    TrackModel,
    TrackModels,
    build_track_graph,
    pad_ragged,
    stack_tracks,
)
from fgloc.tracking.config import TrackingConfig
from fgloc.tracks import N_KIN, Track, TrackSet, contour_angles


def three_tracks(seed: int) -> tuple[TrackSet, np.ndarray, np.ndarray]:
    """Three filter-like tracks of different lengths sharing one detection array."""
    rng = np.random.default_rng(seed)
    tracks, dets, sensor = [], [], None
    for i, n in enumerate((25, 40, 12)):
        tr, det, sensor, _ = make_track(rng, n=n, track_id=i + 3)
        off = sum(len(d) for d in dets)
        tracks.append(type(tr)(tr.id, tr.t + 0.37 * i, tr.states, tr.labels, None,
                               tr.det_index + off, tr.det_step))
        dets.append(det)
    return TrackSet(tracks), np.vstack(dets), sensor


def values_of(keys: list[np.ndarray], x: np.ndarray) -> gtsam.Values:
    v = gtsam.Values()
    for k, s in zip(np.concatenate(keys), x):
        v.insert(int(k), s)
    return v


def assert_equals_graph(st, tg, x: np.ndarray) -> None:
    """The stacked system ``st`` at states ``x`` has the cost, diagonal and off-diagonal
    blocks and gradient of the gtsam graph ``tg`` (a :class:`TrackGraph` of the same tracks)."""
    order = gtsam.Ordering()
    for k in np.concatenate(tg.keys):
        order.push_back(int(k))
    values = values_of(tg.keys, x)
    ne = st.evaluate(x)
    np.testing.assert_allclose(np.sum(ne.cost), tg.graph.error(values), rtol=1e-10)
    H, eta = tg.graph.linearize(values).hessian(order)
    blocks = np.array([H[26 * i:26 * i + 26, 26 * i:26 * i + 26] for i in range(len(x))])
    np.testing.assert_allclose(ne.D, blocks, rtol=1e-9, atol=1e-9 * np.abs(H).max())
    np.testing.assert_allclose(ne.g.ravel(), -eta, rtol=1e-9, atol=1e-9 * np.abs(eta).max())
    below = np.array([H[26 * p:26 * p + 26, 26 * (p - 1):26 * p] for p in st.proc_step])
    np.testing.assert_allclose(ne.B, below, rtol=1e-9, atol=1e-9 * np.abs(H).max())


@pytest.mark.parametrize("truck", [False, True])
def test_stacked_cost_and_normal_equations_equal_the_gtsam_graph(truck: bool) -> None:
    tracks, det, sensor = three_tracks(1)
    cfg = SmoothingConfig(max_detections=6)
    tcfg = TrackingConfig()
    if truck:       # the second track's filter contour a 10.5 m truck: the long-vehicle model
        tr = tracks.tracks[1]
        tr.states[:, N_KIN:] = rectangle_radius(contour_angles(), 10.5, 2.5)
        tr.states[0, N_KIN:] = TrackModel.of(tcfg, cfg).gp.mu      # born car-sized
    rng = np.random.default_rng(2)
    trusted = rng.random(len(det)) > 0.2
    rr = np.column_stack([rng.normal(8.0, 2.0, len(det)), rng.uniform(5.0, 60.0, len(det))])
    tg = build_track_graph(tracks, det, sensor, cfg, det_trusted=trusted, det_range_rate=rr)
    st = stack_tracks(tracks, det, sensor, cfg, det_trusted=trusted, det_range_rate=rr,
                      chunk=7)
    long_mu = TrackModel.of(tcfg, cfg, long=True).gp.mu
    is_truck = np.all(np.isclose(st.proc_mean, long_mu), axis=1)
    owner = st.track_of_step()[st.proc_step]
    np.testing.assert_array_equal(is_truck, truck & (owner == 1))
    # the truck's first state gets the long GP's contour prior, not its car-sized birth
    np.testing.assert_allclose(st.prior_mean[1, N_KIN:],
                               long_mu if truck else tracks.tracks[1].states[0, N_KIN:])
    x0 = np.concatenate([tr.states for tr in tracks.tracks])
    rng = np.random.default_rng(3)
    for x in (x0, x0 + rng.normal(0, 0.05, x0.shape)):
        assert_equals_graph(st, tg, x)
    # no coupling between tracks: the first step of a track has no block to the left
    assert not set(st.start[1:-1]) & set(st.proc_step)


def test_batched_rows_equal_the_one_frame_rows() -> None:
    rng = np.random.default_rng(5)
    sensor = np.array([3.0, -30.0])
    xs = np.array([random_state(rng, w) for w in (0.0, 0.2, -0.1, 1e-9)])
    counts = np.array([5, 1, 9, 3])
    z = np.vstack([x[:2] + rng.normal(0, 1.5, (c, 2)) for x, c in zip(xs, counts)])
    zp, valid = pad_ragged(z, counts)
    assert zp.shape == (4, 9, 2) and valid.sum() == counts.sum()
    batch = ContourMeasurement(zp, sensor, GP, 0.3, 1.345, sigma_range=0.2,
                               sigma_azimuth=0.01, gp_variance=True, valid=valid)
    ext_set = ExtentSettings(min_points=2, min_cover=0.1)
    ext = ExtentRows(zp, sensor, ext_set, 0.3, valid, valid)
    e, J, w = batch.rows(xs, jacobian=True)
    e2, J2 = ext.rows(xs, jacobian=True)
    for f, (a, b) in enumerate(zip(np.cumsum(counts) - counts, np.cumsum(counts))):
        one = ContourMeasurement(z[a:b], sensor, GP, 0.3, 1.345, sigma_range=0.2,
                                 sigma_azimuth=0.01, gp_variance=True)
        e1, J1, w1 = one.rows(xs[f], jacobian=True)
        m = counts[f]
        np.testing.assert_allclose(e[f, :m], e1, atol=1e-12)
        np.testing.assert_allclose(J[f, :m], J1, atol=1e-12)
        np.testing.assert_allclose(w[f, :m], w1, atol=1e-12)
        assert np.all(e[f, m:] == 0) and np.all(J[f, m:] == 0) and np.all(w[f, m:] == 0)
        ee1, JJ1 = ExtentRows(z[a:b], sensor, ext_set, 0.3).rows(xs[f], jacobian=True)
        np.testing.assert_allclose(e2[f], ee1, atol=1e-12)
        np.testing.assert_allclose(J2[f], JJ1, atol=1e-12)


def test_banded_layout_matches_the_dense_matrix() -> None:
    rng = np.random.default_rng(7)
    n, below = 5, np.array([1, 2, 4])                 # steps 2|3 belong to different tracks
    D = rng.normal(size=(n, 26, 26))
    D = D + np.swapaxes(D, 1, 2)
    B = rng.normal(size=(len(below), 26, 26))
    A = np.zeros((26 * n, 26 * n))
    for i in range(n):
        A[26 * i:26 * i + 26, 26 * i:26 * i + 26] = D[i]
    for b, p in zip(B, below):
        A[26 * p:26 * p + 26, 26 * (p - 1):26 * p] = b
        A[26 * (p - 1):26 * p, 26 * p:26 * p + 26] = b.T
    ab = BandedLayout(n, below).fill(D, B)
    for d in range(52):
        np.testing.assert_array_equal(ab[d, :26 * n - d], np.diagonal(A, -d))
    assert not np.any(np.diagonal(A, -52))


def test_gauss_newton_step_equals_gtsam_linear_solve() -> None:
    tracks, det, sensor = three_tracks(4)
    cfg = SmoothingConfig()
    st = stack_tracks(tracks, det, sensor, cfg)
    x0 = np.concatenate([tr.states for tr in tracks.tracks])
    step = damped_step(BandedLayout(st.n, st.proc_step), st.evaluate(x0), np.zeros(st.n))
    tg = build_track_graph(tracks, det, sensor, cfg)
    delta = tg.graph.linearize(tg.values).optimize()
    ref = np.array([delta.at(int(k)) for k in np.concatenate(tg.keys)])
    np.testing.assert_allclose(step, ref, rtol=1e-6, atol=1e-8 * np.abs(ref).max())


def test_banded_lm_smooths_towards_the_truth() -> None:
    rng = np.random.default_rng(11)
    tracks, dets, truths, sensor = [], [], [], None
    for i, n in enumerate((40, 60, 25)):
        tr, det, sensor, truth = make_track(rng, n=n, track_id=i)
        off = sum(len(d) for d in dets)
        tracks.append(type(tr)(tr.id, tr.t, tr.states, tr.labels, None, tr.det_index + off,
                               tr.det_step))
        dets.append(det)
        truths.append(truth)
    ts, det, truth = TrackSet(tracks), np.vstack(dets), np.vstack(truths)
    st = stack_tracks(ts, det, sensor, SmoothingConfig())
    x0 = np.concatenate([tr.states for tr in tracks])
    res = levenberg_marquardt(st, x0)
    tg = build_track_graph(ts, det, sensor, SmoothingConfig())
    np.testing.assert_allclose(np.sum(res.cost_final),
                               tg.graph.error(values_of(tg.keys, res.states)), rtol=1e-10)
    assert np.all(res.cost_final < 0.2 * res.cost_initial), (res.cost_initial, res.cost_final)
    err0, err1 = (np.sqrt(np.mean(np.sum((x[:, :2] - truth[:, :2]) ** 2, axis=1)))
                  for x in (x0, res.states))
    yaw0, yaw1 = (np.mean(np.abs(x[:, 4] - truth[:, 4])) for x in (x0, res.states))
    assert err1 < 0.5 * err0 and yaw1 < 0.5 * yaw0, (err0, err1, yaw0, yaw1)


def test_range_rate_rows_jacobian_batch_and_model() -> None:
    rng = np.random.default_rng(9)
    sensor = np.array([2.0, -25.0])
    for w in (0.0, 0.3, -1e-9):
        x = random_state(rng, w)
        z = x[:2] + rng.normal(0, 1.5, (7, 2))
        r3 = np.linalg.norm(z - sensor, axis=1) + 0.5
        dop = range_rate(z, r3, x[:2], x[2], x[4], x[5], sensor) + rng.normal(0, 0.3, 7)
        rows = RangeRateRows(z, dop, r3, sensor, 1.0, 0.3, np.inf)
        e, J = rows.rows(x, jacobian=True)
        pred = range_rate(z, r3, x[:2], x[2], x[4], x[5], sensor)
        np.testing.assert_allclose(e, 0.3 * (pred - dop), atol=1e-12)
        h = 1e-6
        Jn = np.array([(rows.rows(x + h * d)[0] - rows.rows(x - h * d)[0]) / (2 * h)
                       for d in np.eye(26)]).T
        np.testing.assert_allclose(J, Jn, atol=1e-6)
    # a batch of two frames (the second padded) equals the frames alone
    zp, valid = pad_ragged(np.vstack([z, z[:3]]), np.array([7, 3]))
    dp, _ = pad_ragged(np.concatenate([dop, dop[:3]])[:, None], np.array([7, 3]))
    rp, _ = pad_ragged(np.concatenate([r3, r3[:3]])[:, None], np.array([7, 3]))
    batch = RangeRateRows(zp, dp[..., 0], rp[..., 0], sensor, 1.0, 0.3, 2.0, valid)
    xs = np.stack([x, x + 0.1])
    eb, Jb = batch.rows(xs, jacobian=True)
    e1, J1 = RangeRateRows(z[:3], dop[:3], r3[:3], sensor, 1.0, 0.3, 2.0).rows(xs[1], True)
    np.testing.assert_allclose(eb[1, :3], e1, atol=1e-12)
    np.testing.assert_allclose(Jb[1, :3], J1, atol=1e-12)
    assert np.all(eb[1, 3:] == 0) and np.all(Jb[1, 3:] == 0)
    # in the factor: 2 m rows (contour, then range rate), Jacobian of the whole stack
    fac = contour_measurement_factor(1, z, sensor, GP, range_rate=(dop, r3), sigma_doppler=1.0)
    assert fac.dim() == 14


def _track_of_lengths(lengths: np.ndarray, dt: float = 0.05) -> Track:
    """A track whose filtered contours are rectangles of ``lengths`` (m) x 2 m, steps dt s."""
    n = len(lengths)
    states = np.zeros((n, 26))
    states[:, N_KIN:] = [rectangle_radius(contour_angles(), L, 2.0) for L in lengths]
    return Track(1, np.arange(n) * dt, states, np.zeros(n, dtype=np.int8))


def test_long_vehicle_choice_offline_and_online() -> None:
    models = TrackModels.of(TrackingConfig(), SmoothingConfig(long_vehicle_length=9.0))
    truck = _track_of_lengths(np.r_[np.full(10, 4.6), np.full(40, 10.0)])
    blip = _track_of_lengths(np.r_[np.full(10, 4.6), np.full(8, 9.5), np.full(40, 4.8)])
    assert models.is_long(truck) and models.for_track(truck) is models.long
    assert not models.is_long(blip) and models.for_track(blip) is models.car
    # online: long once the contour has stayed >= 9 m for the hold time (1 s = 20 steps)
    assert models.long_from(truck, 1.0) == 30
    assert models.long_from(blip, 1.0) == len(blip)
    assert models.long_from(blip, 0.3) == 16
    off = TrackModels.of(TrackingConfig(), SmoothingConfig(long_vehicle_length=0.0))
    assert off.long is None and not off.is_long(truck) and off.long_from(truck, 1.0) == 50
