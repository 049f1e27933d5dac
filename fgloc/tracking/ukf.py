"""Unscented Kalman filter steps, batched over tracks (leading axis T).

State rows follow fgloc.tracks (component YAW is an angle: means are taken over wrapped
differences from the first sigma point, deviations are wrapped). Measurement vectors contain no
angles. Covariances are symmetrized after every step and factored with a growing jitter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack

from fgloc.geo import wrap_angle
from fgloc.tracks import YAW


@dataclass(frozen=True)
class UnscentedWeights:
    """Sigma-point weights for dimension n: mean wm, covariance wc (2n+1,), spread gamma."""

    wm: np.ndarray
    wc: np.ndarray
    gamma: float

    @staticmethod
    def of(n: int, alpha: float, beta: float, kappa: float) -> UnscentedWeights:
        lam = alpha**2 * (n + kappa) - n
        wm = np.full(2 * n + 1, 0.5 / (n + lam))
        wm[0] = lam / (n + lam)
        wc = wm.copy()
        wc[0] += 1.0 - alpha**2 + beta
        return UnscentedWeights(wm, wc, float(np.sqrt(n + lam)))


def robust_cholesky(P: np.ndarray) -> np.ndarray:
    """Lower Cholesky factors of (T, n, n) covariances; jitter grows on the failing ones."""
    P = 0.5 * (P + np.swapaxes(P, -1, -2))
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        pass
    n = P.shape[-1]
    out = np.empty_like(P)
    for i in range(P.shape[0]):
        scale = max(float(np.trace(P[i])) / n, 1e-12)
        jitter = 1e-10 * scale
        while True:
            try:
                out[i] = np.linalg.cholesky(P[i] + jitter * np.eye(n))
                break
            except np.linalg.LinAlgError:
                jitter *= 10.0
    return out


def sigma_points(x: np.ndarray, P: np.ndarray, w: UnscentedWeights) -> np.ndarray:
    """(T, 2n+1, n) sigma points of means x (T, n) and covariances P (T, n, n)."""
    L = robust_cholesky(P) * w.gamma
    dev = np.swapaxes(L, -1, -2)                              # rows = columns of L
    return np.concatenate([x[:, None, :], x[:, None, :] + dev, x[:, None, :] - dev], axis=1)


def solve_spd(S: np.ndarray, B: np.ndarray) -> np.ndarray:
    """S^-1 B for symmetric positive definite S (T, m, m) and B (T, m, k): Cholesky (LAPACK
    posv, about half the work of an LU solve), an LU solve where S is not positive definite."""
    out = np.empty(B.shape)
    for i in range(S.shape[0]):
        _, x, info = lapack.dposv(S[i], B[i], lower=1)
        out[i] = x if info == 0 else np.linalg.solve(S[i], B[i])
    return out


def distinct_rows(X: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Sigma points X (T, S, n) whose first k components (the kinematics) are bitwise those
    of the first point in every track need not be pushed through a function of those
    components again. Returns rows (r,) -- the first point and every point differing from it
    somewhere -- and inv (S,) with ``X[:, rows][:, inv, :k] == X[..., :k]`` exactly.

    With the kinematics first in the state, the lower Cholesky factor of :func:`sigma_points`
    has exact zeros there in the columns of the other components, so only 2 k + 1 rows stay
    (the contour radii enter the measurement and the motion after these nonlinear parts)."""
    same = np.all(X[..., :k] == X[:, :1, :k], axis=(0, 2))
    same[0] = False
    rows = np.flatnonzero(~same)
    inv = np.zeros(X.shape[1], dtype=np.int64)
    inv[rows] = np.arange(len(rows))
    return rows, inv


def state_mean(X: np.ndarray, w: UnscentedWeights) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean (T, n) of sigma points X (T, S, n) and their deviations (T, S, n), with
    the yaw averaged over wrapped differences."""
    ref = X[:, :1, YAW]
    Xw = X.copy()
    Xw[:, :, YAW] = ref + wrap_angle(X[:, :, YAW] - ref)
    mean = w.wm @ Xw
    return mean, Xw - mean[:, None, :]


def covariance(dA: np.ndarray, dB: np.ndarray, w: UnscentedWeights) -> np.ndarray:
    """(T, a, b) weighted cross covariance of deviations dA (T, S, a) and dB (T, S, b)."""
    return np.swapaxes(dA * w.wc[:, None], -1, -2) @ dB


def predict(X: np.ndarray, Q: np.ndarray, w: UnscentedWeights) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of propagated sigma points X (T, S, n) plus process noise Q."""
    mean, dev = state_mean(X, w)
    P = covariance(dev, dev, w) + Q
    return mean, 0.5 * (P + np.swapaxes(P, -1, -2))


def update(x: np.ndarray, P: np.ndarray, X: np.ndarray, Z: np.ndarray, z: np.ndarray,
           R: np.ndarray, w: UnscentedWeights) -> tuple[np.ndarray, np.ndarray]:
    """UKF update of (T, n) means / (T, n, n) covariances with sigma points X (T, S, n) drawn
    from them, their predicted measurements Z (T, S, m), measurements z (T, m) and noise R:
    (T, m, m), or its diagonal blocks (T, M, k, k) with m = M k (zero elsewhere). Padded
    measurement rows must have Z = z = 0 and R = identity there."""
    _, dx = state_mean(X, w)
    zhat = w.wm @ Z
    dz = Z - zhat[:, None, :]
    S = covariance(dz, dz, w)
    if R.ndim == 4:
        T, M, k, _ = R.shape
        idx = np.arange(M)
        S.reshape(T, M, k, M, k)[:, idx, :, idx, :] += np.moveaxis(R, 0, 1)
    else:
        S += R
    Pxz = covariance(dx, dz, w)
    K = np.swapaxes(solve_spd(S, np.swapaxes(Pxz, -1, -2)), -1, -2)       # Pxz S^-1
    x_new = x + (K @ (z - zhat)[..., None])[..., 0]
    x_new[:, YAW] = wrap_angle(x_new[:, YAW])
    P_new = P - K @ np.swapaxes(Pxz, -1, -2)                       # K S K^T = K Pxz^T
    return x_new, 0.5 * (P_new + np.swapaxes(P_new, -1, -2))
