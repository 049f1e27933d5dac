"""The semantic point-to-point factor: Jacobians against central differences, per-point robust
weights, shape checks, and the gtsam wrapper."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from factors.gp import ContourGP
from factors.gtsam_factors import track_key
from factors.registration_factors import (
    PointRows,
    line_sqrt_info,
    offset_key,
    point_to_point_factor,
    pose_matrix,
)
from factors.state import N_CONTOUR, N_STATE

GP = ContourGP(2.0 * np.pi * np.arange(N_CONTOUR) / N_CONTOUR)


def _state(rng: np.random.Generator) -> np.ndarray:
    x = np.zeros(N_STATE)
    x[:6] = [rng.uniform(-30, 30), rng.uniform(-30, 30), rng.uniform(0, 15), rng.normal(),
             rng.uniform(-np.pi, np.pi), rng.normal(0, 0.2)]
    x[6:] = GP.mu + rng.normal(0, 0.2, N_CONTOUR)
    return x


def _rows(rng: np.random.Generator, m: int, sigma_t: float = np.inf,
          huber_k: float = 1.0) -> PointRows:
    ang = rng.uniform(-np.pi, np.pi, m)
    normal = np.column_stack([np.cos(ang), np.sin(ang)])
    return PointRows(theta=rng.uniform(0, 2 * np.pi, m), target=rng.uniform(-30, 30, (m, 2)),
                     normal=normal, sqrt_info=line_sqrt_info(normal, 0.3, sigma_t),
                     compat=rng.choice([1.0, 0.1], m), huber_k=huber_k, gp=GP)


def _numeric(f, v: np.ndarray, h: float = 1e-6) -> np.ndarray:
    cols = []
    for k in range(v.size):
        d = np.zeros_like(v)
        d[k] = h
        cols.append((f(v + d) - f(v - d)) / (2 * h))
    return np.column_stack(cols)


@pytest.mark.parametrize("seed,sigma_t", [(0, np.inf), (1, 2.0), (2, np.inf), (3, 0.5)])
def test_jacobians_match_central_differences(seed: int, sigma_t: float) -> None:
    rng = np.random.default_rng(seed)
    rows = _rows(rng, 7, sigma_t)
    pose = np.array([rng.normal(0, 2), rng.normal(0, 2), rng.normal(0, 0.5)])
    x = _state(rng)
    b = float(rng.normal(0, 0.3))
    e, J, w = rows.rows(pose, x, b, jacobian=True)
    assert e.shape == (14,) and [j.shape for j in J] == [(14, 3), (14, N_STATE), (14, 1)]
    np.testing.assert_allclose(J[0], _numeric(lambda p: rows.rows(p, x, b, w)[0], pose),
                               atol=1e-6)
    np.testing.assert_allclose(J[1], _numeric(lambda s: rows.rows(pose, s, b, w)[0], x),
                               atol=1e-6)
    np.testing.assert_allclose(
        J[2], _numeric(lambda v: rows.rows(pose, x, float(v[0]), w)[0], np.array([b])),
        atol=1e-6)


def test_points_follow_pose_and_residual_is_point_to_line() -> None:
    rng = np.random.default_rng(5)
    x = _state(rng)
    rows0 = _rows(rng, 5)
    pose = np.array([1.5, -2.0, 0.3])
    q = rows0.points(x) @ pose_matrix(pose)[:2, :2].T + pose[:2]
    normal = rows0.normal
    tangent = np.column_stack([-normal[:, 1], normal[:, 0]])
    # targets slid along their lines by arbitrary amounts and 0.1 m across: only 0.1 m counts
    target = q + rng.uniform(-3, 3, 5)[:, None] * tangent - 0.1 * normal
    rows = PointRows(rows0.theta, target, normal, line_sqrt_info(normal, 0.2), np.ones(5),
                     np.inf, GP)
    e, _, _ = rows.rows(pose, x)
    np.testing.assert_allclose(np.linalg.norm(e.reshape(-1, 2), axis=1), 0.1 / 0.2, rtol=1e-9)
    # the offset b moves the target along its normal: b = 0.1 m cancels it
    np.testing.assert_allclose(rows.rows(pose, x, 0.1)[0], 0.0, atol=1e-9)


def test_robust_weight_is_per_point() -> None:
    rng = np.random.default_rng(6)
    x = _state(rng)
    pose = np.zeros(3)
    s = PointRows(np.linspace(0, 6, 4), np.zeros((4, 2)), np.tile([0.0, 1.0], (4, 1)),
                  np.tile(np.eye(2), (4, 1, 1)), np.ones(4), 1.0, GP).points(x)
    target = s.copy()
    target[0] += [0.0, 10.0]          # one outlier 10 sigma away, three exact points
    target[1:] += [0.0, 0.5]
    rows = PointRows(np.linspace(0, 6, 4), target, np.tile([0.0, 1.0], (4, 1)),
                     np.tile(np.eye(2), (4, 1, 1)), np.array([1.0, 1.0, 1.0, 0.1]), 1.0, GP)
    e, _, w = rows.rows(pose, x)
    np.testing.assert_allclose(w, [0.1, 1.0, 1.0, 0.1])        # Huber 1/10 and compat 0.1
    np.testing.assert_allclose(np.abs(e.reshape(-1, 2)[:, 1]),
                               [np.sqrt(0.1) * 10, 0.5, 0.5, np.sqrt(0.1) * 0.5])


def test_bad_shapes_raise_before_gtsam() -> None:
    rng = np.random.default_rng(7)
    good = _rows(rng, 3)
    with pytest.raises(ValueError, match="target"):
        PointRows(good.theta, good.target[:2], good.normal, good.sqrt_info, good.compat, 1.0, GP)
    with pytest.raises(ValueError, match="compat"):
        PointRows(good.theta, good.target, good.normal, good.sqrt_info, good.compat + 2, 1.0, GP)
    with pytest.raises(ValueError, match="shape"):
        good.rows(np.zeros(2), _state(rng))


def test_gtsam_factor_linearizes_to_the_rows() -> None:
    rng = np.random.default_rng(8)
    rows = _rows(rng, 6, sigma_t=1.0)
    pose = np.array([0.4, -0.3, 0.05])
    x = _state(rng)
    kp, kx, kb = gtsam.symbol("G", 0), track_key(3, 11), offset_key(3)
    values = gtsam.Values()
    values.insert(kp, pose)
    values.insert(kx, x)
    values.insert(kb, np.array([0.2]))
    fac = point_to_point_factor(kp, kx, rows, kb)
    e, J, _ = rows.rows(pose, x, 0.2, jacobian=True)
    assert fac.error(values) == pytest.approx(0.5 * e @ e)
    lin = fac.linearize(values)
    A, rhs = lin.jacobian()
    np.testing.assert_allclose(A, np.hstack(J))
    np.testing.assert_allclose(rhs, -e)
    # without an offset key the factor has two keys and b = 0
    fac2 = point_to_point_factor(kp, kx, rows)
    assert fac2.error(values) == pytest.approx(0.5 * np.sum(rows.rows(pose, x)[0] ** 2))
