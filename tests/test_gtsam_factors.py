"""Tests of factors.gtsam_factors: keys, Jacobians vs. central differences, shape checks and a
tiny Levenberg-Marquardt smoothing problem (one simulated car seen by a radar)."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from factors.ctra import ctra_predict
from factors.gp import ContourGP, rectangle_radius
from factors.gtsam_factors import (
    N_KIN,
    N_STATE,
    YAW,
    ConditionalTable,
    ContourMeasurement,
    ExtentRows,
    ExtentSettings,
    _fortran,
    contour_measurement_factor,
    decode_track_key,
    huber_weights,
    prior_factor,
    process_factor,
    sensor_key,
    track_key,
)

DT = 0.1
TAU = 0.05
SIGMA_JERK, SIGMA_YAW_ACC, SIGMA_POS = 2.0, 0.6, 0.05


def make_gp() -> ContourGP:
    """The tracker's default GP (TrackingConfig values)."""
    angles = 2.0 * np.pi * np.arange(20) / 20
    return ContourGP(angles, sf=0.15, length=0.35, sr=0.1, symmetry=0.8, mean_length=4.6,
                     mean_width=1.9, sl=1.5, sw=0.2)


GP = make_gp()


def random_state(rng: np.random.Generator, yawrate: float) -> np.ndarray:
    """A plausible random state (26,) with the given yaw rate (rad/s)."""
    x = np.zeros(N_STATE)
    x[:2] = rng.uniform(-20, 20, 2)
    x[2] = rng.uniform(2, 15)
    x[3] = rng.uniform(-2, 2)
    x[YAW] = rng.uniform(-2.5, 2.5)
    x[5] = yawrate
    x[N_KIN:] = GP.mu + rng.normal(0, 0.05, 20)
    return x


def numeric_jacobian(fun, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """Central-difference Jacobian of fun: (n,) -> (m,)."""
    cols = []
    for i in range(len(x)):
        d = np.zeros_like(x)
        d[i] = h
        cols.append((np.asarray(fun(x + d)) - np.asarray(fun(x - d))) / (2 * h))
    return np.stack(cols, axis=1)


def values_of(states: dict[int, np.ndarray]) -> gtsam.Values:
    v = gtsam.Values()
    for k, x in states.items():
        v.insert(k, np.asarray(x, dtype=float))
    return v


# ---- keys ------------------------------------------------------------------------------------
def test_keys_roundtrip_and_limits() -> None:
    keys = {track_key(t, s) for t in (0, 1, 2**24 - 1) for s in (0, 1, 2**32 - 1)}
    assert len(keys) == 9
    assert decode_track_key(track_key(123, 4567)) == (123, 4567)
    assert sensor_key() not in keys
    for bad in ((-1, 0), (2**24, 0), (0, -1), (0, 2**32)):
        with pytest.raises(ValueError):
            track_key(*bad)
    with pytest.raises(ValueError):
        decode_track_key(sensor_key())


# ---- process factor --------------------------------------------------------------------------
@pytest.mark.parametrize("yawrate", [0.0, 1e-9, -1e-5, 0.3, -1.5, 4.0])
def test_process_jacobian_matches_central_differences(yawrate: float) -> None:
    rng = np.random.default_rng(abs(hash(yawrate)) % 2**32)
    k0, k1 = track_key(3, 10), track_key(3, 11)
    for _ in range(3):
        x0 = random_state(rng, yawrate)
        x1 = ctra_predict(x0, DT) + rng.normal(0, 0.05, N_STATE)
        fac = process_factor(k0, k1, DT, GP, TAU, SIGMA_JERK, SIGMA_YAW_ACC, SIGMA_POS,
                             x_ref=x0)
        lin = fac.linearize(values_of({k0: x0, k1: x1}))
        A, b = lin.jacobian()                                # whitened, [d/dx0, d/dx1]

        def werr(x: np.ndarray, which: int, x0=x0, x1=x1, fac=fac) -> np.ndarray:
            xs = {k0: x0, k1: x1}
            xs[(k0, k1)[which]] = x
            return fac.whitenedError(values_of(xs))

        for which, x in ((0, x0), (1, x1)):
            Jn = numeric_jacobian(lambda v, w=which: werr(v, w), x)
            Ja = A[:, which * N_STATE:(which + 1) * N_STATE]
            scale = max(1.0, np.abs(Ja).max())
            np.testing.assert_allclose(Ja, Jn, atol=1e-6 * scale, rtol=1e-6)
        np.testing.assert_allclose(-b, fac.whitenedError(values_of({k0: x0, k1: x1})),
                                   atol=1e-9)


def test_process_error_zero_on_exact_motion_and_yaw_wrapped() -> None:
    rng = np.random.default_rng(1)
    x0 = random_state(rng, 0.4)
    x0[N_KIN:] = GP.mu
    x1 = ctra_predict(x0, DT)
    x1[YAW] += 2 * np.pi
    k0, k1 = track_key(0, 0), track_key(0, 1)
    fac = process_factor(k0, k1, DT, GP, TAU, SIGMA_JERK, SIGMA_YAW_ACC, SIGMA_POS)
    assert np.abs(fac.unwhitenedError(values_of({k0: x0, k1: x1}))).max() < 1e-9


# ---- contour measurement factor --------------------------------------------------------------
def box_detections(x: np.ndarray, sensor: np.ndarray, per_edge: int = 6,
                   length: float = 4.6, width: float = 1.9) -> np.ndarray:
    """Noiseless detections (k, 2) on the edges of the true box of state x that face the
    sensor (a convex box: facing means visible), ``per_edge`` interior points per edge."""
    c, yaw = x[:2], x[YAW]
    h = np.array([np.cos(yaw), np.sin(yaw)])
    lat = np.array([-h[1], h[0]])
    pts = []
    for axis, half, other, ohalf in ((h, length / 2, lat, width / 2),
                                     (lat, width / 2, h, length / 2)):
        for sgn in (1.0, -1.0):
            n = sgn * axis
            mid = c + n * half
            if np.dot(sensor - mid, n) <= 0:
                continue
            for s in np.linspace(-0.8, 0.8, per_edge):
                pts.append(mid + other * ohalf * s)
    return np.array(pts)


def test_measurement_jacobian_matches_central_differences() -> None:
    rng = np.random.default_rng(7)
    sensor = np.array([0.0, -25.0])
    key = track_key(0, 0)
    for yawrate in (0.0, 1e-9, 1e-5, 3.0):
        x = random_state(rng, yawrate)
        z = box_detections(x, sensor) + rng.normal(0, 0.1, (1, 2))
        z = np.vstack([z, z[0] + [3.0, 0.0]])                     # one outlier row
        meas = ContourMeasurement(z, sensor, GP, sigma=0.3, huber_k=1.345)
        assoc = meas.associate(x)
        e, J, w = meas.rows(x, jacobian=True)
        assert w.min() < 1.0                                      # the outlier is down-weighted
        # exact: association and weights frozen at the linearization point
        Jn = numeric_jacobian(lambda v, m=meas, a=assoc, w=w: m.rows(v, a, w)[0], x)
        np.testing.assert_allclose(J, Jn, atol=1e-7, rtol=1e-6)
        # the gtsam factor returns the same (whitened by 1 / sigma)
        fac = contour_measurement_factor(key, z, sensor, GP, sigma=0.3, huber_k=1.345)
        A, b = fac.linearize(values_of({key: x})).jacobian()
        np.testing.assert_allclose(A, J / 0.3, atol=1e-9)
        np.testing.assert_allclose(-b, e / 0.3, atol=1e-9)
        # re-associating, unweighted error: the frozen-association Jacobian is close
        plain = ContourMeasurement(z[:-1], sensor, GP, sigma=0.3, huber_k=np.inf)
        _, Jp, _ = plain.rows(x, jacobian=True)
        Jfull = numeric_jacobian(lambda v, m=plain: m.rows(v)[0], x, h=1e-5)
        # (a Gauss-Newton approximation, not exact: theta* and the chain's edge normal move
        # with the state and the 48-sample polyline's normal is not the smooth contour's;
        # measured: most rows within a few %, rows near a rounded corner up to ~25 %)
        row_err = np.abs(Jp - Jfull).max(axis=1) / max(1.0, np.abs(Jp).max())
        assert np.median(row_err) < 0.05 and row_err.max() < 0.35, row_err


def test_huber_weights() -> None:
    w = huber_weights(np.array([0.0, 1.0, -2.0, 4.0]), 2.0)
    np.testing.assert_allclose(w, [1.0, 1.0, 1.0, 0.5])
    np.testing.assert_allclose(huber_weights(np.array([10.0]), np.inf), [1.0])


# ---- shape checks ----------------------------------------------------------------------------
def test_wrong_shapes_raise_before_gtsam() -> None:
    sensor = np.zeros(2)
    key = track_key(0, 0)
    with pytest.raises(ValueError):
        contour_measurement_factor(key, np.zeros((5, 3)), sensor, GP)
    with pytest.raises(ValueError):
        contour_measurement_factor(key, np.zeros((0, 2)), sensor, GP)
    with pytest.raises(ValueError):
        contour_measurement_factor(key, np.ones((5, 2)), np.zeros(3), GP)
    with pytest.raises(ValueError):
        prior_factor(key, np.zeros(25), np.eye(N_STATE))
    with pytest.raises(ValueError):
        prior_factor(key, np.zeros(N_STATE), np.eye(25))
    with pytest.raises(ValueError):
        prior_factor(key, np.zeros(N_STATE), -np.eye(N_STATE))
    with pytest.raises(ValueError):
        process_factor(key, track_key(0, 1), 0.0, GP, TAU, 1.0, 1.0)
    with pytest.raises(ValueError):
        _fortran(np.zeros((3, 25)), (3, N_STATE), "test")
    J = _fortran(np.zeros((3, N_STATE)), (3, N_STATE), "test")
    assert J.flags.f_contiguous and J.dtype == np.float64
    # a state of the wrong length in Values raises a Python error inside the callback
    fac = contour_measurement_factor(key, np.array([[1.0, 2.0], [1.5, 2.0]]), sensor, GP)
    with pytest.raises(Exception, match="shape"):
        fac.linearize(values_of({key: np.zeros(N_STATE - 1)}))


def test_prior_factor_error() -> None:
    key = track_key(2, 5)
    mean = random_state(np.random.default_rng(3), 0.1)
    fac = prior_factor(key, mean, 4.0 * np.eye(N_STATE))
    x = mean + 1.0
    assert fac.error(values_of({key: x})) == pytest.approx(0.5 * N_STATE / 4.0)


# ---- tiny smoothing problem ------------------------------------------------------------------
def simulate(n: int = 20) -> np.ndarray:
    """(n, 26) true states: 10 m/s, straight for half the run, then turning at 0.5 rad/s."""
    x = np.zeros(N_STATE)
    x[:2] = [-10.0, 5.0]
    x[2] = 10.0
    x[N_KIN:] = GP.mu                      # the true box is the mean rectangle
    out = [x]
    for k in range(1, n):
        x = ctra_predict(out[-1], DT)
        if k == n // 2:
            x[5] = 0.5
        out.append(x)
    return np.array(out)


def test_levenberg_marquardt_recovers_trajectory() -> None:
    rng = np.random.default_rng(42)
    truth = simulate(20)
    sensor = np.array([0.0, -12.0])
    offset = np.zeros(N_STATE)
    offset[:2] = [1.0, -0.8]
    offset[2] = 1.5
    offset[YAW] = 0.12
    graph = gtsam.NonlinearFactorGraph()
    init = gtsam.Values()
    P0 = np.diag([2.0**2, 2.0**2, 3.0**2, 1.0, 0.3**2, 0.2**2] + [0.3**2] * 20)
    for k, xt in enumerate(truth):
        key = track_key(1, k)
        guess = xt + offset
        guess[:2] += rng.normal(0, 0.3, 2)
        init.insert(key, guess)
        z = box_detections(xt, sensor)
        graph.add(contour_measurement_factor(key, z, sensor, GP, sigma=0.3))
        if k == 0:
            graph.add(prior_factor(key, guess, P0))
        else:
            graph.add(process_factor(track_key(1, k - 1), key, DT, GP, TAU, SIGMA_JERK,
                                     SIGMA_YAW_ACC, SIGMA_POS, x_ref=init.atVector(
                                         track_key(1, k - 1))))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(50)
    result = gtsam.LevenbergMarquardtOptimizer(graph, init, params).optimize()
    assert graph.error(result) < graph.error(init)

    def centre_rmse(values: gtsam.Values) -> float:
        est = np.array([values.atVector(track_key(1, k)) for k in range(len(truth))])
        return float(np.sqrt(np.mean(np.sum((est[:, :2] - truth[:, :2]) ** 2, axis=1))))

    e0, e1 = centre_rmse(init), centre_rmse(result)
    print(f"centre RMSE {e0:.3f} -> {e1:.3f} m")
    assert e1 < e0 / 4, (e0, e1)
    yaw_err = np.array([result.atVector(track_key(1, k))[YAW] - truth[k, YAW]
                        for k in range(len(truth))])
    assert np.abs(yaw_err).max() < 0.05


def test_per_row_radar_noise_weights_and_jacobian() -> None:
    rng = np.random.default_rng(11)
    sensor = np.array([0.0, -40.0])
    x = random_state(rng, 0.2)
    z = box_detections(x, sensor) + rng.normal(0, 0.05, (1, 2))
    sr, sa = 0.25, np.deg2rad(0.5)
    meas = ContourMeasurement(z, sensor, GP, sigma=0.3, huber_k=np.inf, sigma_range=sr,
                              sigma_azimuth=sa, gp_variance=True)
    theta, normal = meas.associate(x)
    _, var_f = GP.conditional(theta)
    los = z - sensor
    r = np.linalg.norm(los, axis=1)
    er = los / r[:, None]
    et = np.stack([-er[:, 1], er[:, 0]], axis=1)
    u = np.stack([np.cos(theta + x[YAW]), np.sin(theta + x[YAW])], axis=1)
    expect = np.sqrt(0.09 + var_f * np.sum(u * normal, 1) ** 2
                     + sr**2 * np.sum(er * normal, 1) ** 2
                     + (sa * r) ** 2 * np.sum(et * normal, 1) ** 2)
    np.testing.assert_allclose(meas.row_sigma(x[YAW], theta, normal, var_f), expect)
    e, J, w = meas.rows(x, jacobian=True)
    np.testing.assert_allclose(w, (0.3 / expect) ** 2)              # no Huber: noise only
    Jn = numeric_jacobian(lambda v: meas.rows(v, (theta, normal), w)[0], x)
    np.testing.assert_allclose(J, Jn, atol=1e-7, rtol=1e-6)
    plain = ContourMeasurement(z, sensor, GP, sigma=0.3, huber_k=np.inf)
    np.testing.assert_allclose(e, plain.rows(x)[0] * 0.3 / expect, atol=1e-12)


def test_conditional_table_matches_the_exact_conditional() -> None:
    rng = np.random.default_rng(5)
    table = ConditionalTable(GP)
    theta = np.concatenate([rng.uniform(-7, 7, 200), np.arctan2(1.9, 4.6) + [-1e-4, 1e-4]])
    H, mean, var = table(theta)
    He, vare = GP.conditional(theta)
    f = GP.mu + rng.normal(0, 0.3, 20)
    r, re = mean + (f - GP.mu) @ H.T, GP.mean(theta) + (f - GP.mu) @ He.T
    assert np.abs(r - re).max() < 1e-3
    assert np.abs(var - vare).max() < 0.005          # m^2, a weight next to sigma^2 = 0.09
    x = random_state(rng, 0.1)
    sensor = np.array([5.0, -30.0])
    z = box_detections(x, sensor)
    fast = ContourMeasurement(z, sensor, GP, table=table)
    e, J, w = fast.rows(x, jacobian=True)
    Jn = numeric_jacobian(lambda v: fast.rows(v, fast.associate(x), w)[0], x)
    np.testing.assert_allclose(J, Jn, atol=1e-7, rtol=1e-6)
    np.testing.assert_allclose(e, ContourMeasurement(z, sensor, GP).rows(x)[0], atol=2e-3)
    with pytest.raises(ValueError, match="another ContourGP"):
        contour_measurement_factor(track_key(0, 0), z, sensor, make_gp(), table=table)


def test_extent_rows_selection_and_jacobian() -> None:
    rng = np.random.default_rng(9)
    x = random_state(rng, 0.05)
    h = np.array([np.cos(x[YAW]), np.sin(x[YAW])])
    lat = np.array([-h[1], h[0]])
    sensor = x[:2] + 30.0 * lat + 5.0 * h              # beside the car: its left side is seen
    z = box_detections(x, sensor, per_edge=8) + rng.normal(0, 0.05, (1, 2))
    ext = ExtentRows(z, sensor, ExtentSettings(), sigma_factor=0.3)
    j, use = ext.select(x)
    np.testing.assert_array_equal(use, [True, False, True, False])   # length rows only
    e, J = ext.rows(x, jacobian=True)
    assert e[1] == e[3] == 0.0 and not J[[1, 3]].any()
    lo = (z - x[:2]) @ h
    np.testing.assert_allclose(e[[0, 2]] * 0.35 / 0.3,
                               [lo.max() - x[N_KIN], -lo.min() - x[N_KIN + 10]])
    Jn = numeric_jacobian(lambda v: ext.rows(v, (j, use))[0], x)
    np.testing.assert_allclose(J, Jn, atol=1e-7, rtol=1e-6)
    # a front view with too few detections gives no rows at all
    few = ExtentRows(z[:3], x[:2] + 30.0 * h, ExtentSettings(), 0.3)
    assert not few.select(x)[1].any()
    # in the factor: 4 rows after the detection rows
    fac = contour_measurement_factor(track_key(0, 0), z, sensor, GP, extent=ExtentSettings())
    assert fac.dim() == len(z) + 4


def test_extent_rows_sampling_gap_correction() -> None:
    """With gap_max > 0 the length rows measure each end one sampling gap (span / (n - 1),
    capped) beyond the extreme detection; the width rows and the Jacobian are unchanged."""
    rng = np.random.default_rng(4)
    x = random_state(rng, 0.05)
    h = np.array([np.cos(x[YAW]), np.sin(x[YAW])])
    lat = np.array([-h[1], h[0]])
    sensor = x[:2] + 30.0 * lat + 5.0 * h
    z = box_detections(x, sensor, per_edge=8) + rng.normal(0, 0.05, (1, 2))
    plain = ExtentRows(z, sensor, ExtentSettings(), sigma_factor=0.35)
    lo = (z - x[:2]) @ h
    for cap in (0.05, 10.0):
        fixed = ExtentRows(z, sensor, ExtentSettings(gap_max=cap), sigma_factor=0.35)
        gap = min(float(np.ptp(lo)) / (len(z) - 1), cap)
        e0, J0 = plain.rows(x, jacobian=True)
        e1, J1 = fixed.rows(x, jacobian=True)
        np.testing.assert_allclose(e1 - e0, [gap, 0.0, gap, 0.0], atol=1e-12)
        np.testing.assert_allclose(J1, J0)


def test_extent_rows_huber_weights() -> None:
    """With huber_k > 0 a row whose end lies more than k sigma from the contour's (an extreme
    detection cut short) enters with the Huber IRLS weight k sigma / |row|: its residual is
    sqrt(k sigma |row|) instead of |row| (in sigmas: quadratic cost k |r| - k^2 / 2 grows
    linearly); a row within k sigma is unchanged; the Jacobian is the unweighted one times
    the same weight (held constant)."""
    rng = np.random.default_rng(4)
    x = random_state(rng, 0.05)
    h = np.array([np.cos(x[YAW]), np.sin(x[YAW])])
    lat = np.array([-h[1], h[0]])
    sensor = x[:2] + 30.0 * lat + 5.0 * h              # the left side is seen: length rows
    z = box_detections(x, sensor, per_edge=8) + rng.normal(0, 0.05, (1, 2))
    lo = (z - x[:2]) @ h
    z = z[lo > -0.8]                    # its rear part hidden: the rear row is cut short
    plain = ExtentRows(z, sensor, ExtentSettings(), sigma_factor=0.35)
    robust = ExtentRows(z, sensor, ExtentSettings(huber_k=2.0), sigma_factor=0.35)
    e0, J0 = plain.rows(x, jacobian=True)
    e1, J1 = robust.rows(x, jacobian=True)
    r = e0                                              # sigma_factor = sigma: rows in m
    assert abs(r[2]) > 2.0 * 0.35 > abs(r[0]) > 0.0     # the cut rear row, the seen front
    w = np.where(np.abs(r) > 0.7, np.sqrt(0.7 / np.maximum(np.abs(r), 1e-12)), 1.0)
    np.testing.assert_allclose(e1, w * r, atol=1e-12)
    np.testing.assert_allclose(e1[2] ** 2, 0.7 * abs(r[2]), rtol=1e-12)
    np.testing.assert_allclose(J1, w[:, None] * J0, atol=1e-12)


def test_extent_rows_need_enough_detections_on_the_face_they_measure() -> None:
    """A 4.5 x 1.8 m car seen from ahead and to its left (front face and left side seen):
    with ``face_min_points`` the width rows need that many detections on the front face and
    the length rows that many on the left side (within ``face_band`` of the outermost one);
    a face with a few returns gives no rows for its ends, the other face's rows stay."""
    x = np.zeros(N_STATE)
    x[N_KIN:] = rectangle_radius(GP.angles, 4.5, 1.8)
    sensor = np.array([30.0, 12.0])
    rng = np.random.default_rng(2)

    def car(n_front: int, n_side: int) -> np.ndarray:
        front = np.column_stack([np.full(n_front, 2.25), np.linspace(-0.8, 0.8, n_front)])
        side = np.column_stack([np.linspace(-2.1, 2.1, n_side), np.full(n_side, 0.9)])
        return np.vstack([front, side]) + rng.normal(0.0, 0.03, (n_front + n_side, 2))

    def use(z: np.ndarray, k: int) -> np.ndarray:
        return ExtentRows(z, sensor, ExtentSettings(face_min_points=k, face_band=0.5),
                          0.3).select(x)[1]

    # order of the rows: front, left, rear, right (length, width, length, width)
    sparse_front = car(3, 14)
    np.testing.assert_array_equal(use(sparse_front, 0), [True, True, True, True])
    np.testing.assert_array_equal(use(sparse_front, 12), [True, False, True, False])
    sparse_side = car(14, 3)
    np.testing.assert_array_equal(use(sparse_side, 0), [True, True, True, True])
    np.testing.assert_array_equal(use(sparse_side, 12), [False, True, False, True])
    np.testing.assert_array_equal(use(car(14, 14), 12), [True, True, True, True])


def test_smoother_rows_match_side_returns_hidden_by_a_lagging_heading() -> None:
    """The smoother's contour factor uses the tracker's ``visible_slack``: a contour 40 m
    ahead of the sensor, seen head-on (its front face only), and returns on its right side,
    1.5-3.5 m behind the front (a turning car shows that side while the contour's heading
    lags). With the slack their rows measure them about that side (0.05 m); without, about
    the front face's corner, metres away."""
    x = np.zeros(N_STATE)
    x[N_KIN:] = rectangle_radius(GP.angles, 4.6, 1.9)
    sensor = np.array([40.0, 0.3])
    z = np.array([[0.8, -1.0], [-0.2, -1.0], [-1.2, -1.0]])
    key = track_key(0, 0)
    rows = {}
    for slack in (np.inf, 1.0):
        meas = ContourMeasurement(z, sensor, GP, sigma=0.3, huber_k=np.inf,
                                  visible_slack=slack)
        rows[slack] = meas.rows(x)[0]
        fac = contour_measurement_factor(key, z, sensor, GP, sigma=0.3, huber_k=np.inf,
                                         visible_slack=slack)
        np.testing.assert_allclose(fac.unwhitenedError(values_of({key: x})), rows[slack],
                                   atol=1e-9)
    np.testing.assert_allclose(np.abs(rows[1.0]), 0.05, atol=0.05)
    assert np.all(np.abs(rows[np.inf]) > 1.0), rows[np.inf]
