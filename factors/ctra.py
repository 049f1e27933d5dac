"""CTRA (constant turn rate and acceleration) motion of the kinematic state.

Kinematic state ``k = [x, y, v, a, yaw, yawrate]`` (m, m, m/s, m/s^2, rad, rad/s); every function
takes a leading batch shape ``(...)`` and works on the first six components of the last axis.

Over ``dt`` with ``w = yawrate``: ``yaw' = yaw + w dt``, ``v' = v + a dt``, ``a' = a``, ``w' = w``
and the position moves by ``d = e^{i yaw} (v I_0 + a I_1)`` (complex plane, ``x + i y``) with the
moments ``I_k = int_0^dt t^k e^{i w t} dt``. The moments use their power series when
``|w dt| < SERIES_SWITCH`` and the closed-form recursion ``I_k = (dt^k e^{i w dt} - k I_{k-1}) /
(i w)`` otherwise; both agree to rounding at the switch, so the motion is continuous (and
smooth) through ``w -> 0``, where it becomes straight-line constant-acceleration motion.
"""

from __future__ import annotations

import numpy as np

#: |yawrate * dt| below which the moment integrals use their power series
SERIES_SWITCH: float = 0.1
#: series terms (error < SERIES_SWITCH**SERIES_TERMS / SERIES_TERMS! ~ 1e-15 relative)
SERIES_TERMS: int = 12


def _moments(w: np.ndarray, dt: float | np.ndarray, kmax: int) -> list[np.ndarray]:
    """[I_0, ..., I_kmax] (complex, shape of w), ``I_k = int_0^dt t^k exp(i w t) dt``."""
    w = np.asarray(w, dtype=float)
    T = np.broadcast_to(np.asarray(dt, dtype=float), w.shape)
    small = np.abs(w * T) < SERIES_SWITCH
    n_small = int(np.count_nonzero(small))
    series = closed = None
    if n_small:
        # series: I_k = T^{k+1} sum_j (i w T)^j / (j! (j + k + 1)), every k at once
        z = 1j * np.where(small, w, 0.0) * T
        term = np.ones_like(z)                  # (i w T)^j / j!, shared by every k
        k1 = np.arange(1, kmax + 2).reshape(-1, *([1] * z.ndim))     # k + 1
        acc = term / k1
        for j in range(1, SERIES_TERMS):
            term = term * z / j
            acc = acc + term / (j + k1)
        series = [acc[k] * T ** (k + 1) for k in range(kmax + 1)]
    if n_small < small.size:
        # closed form on the large-|w dt| part
        wl = np.where(small, 1.0, w)
        e = np.exp(1j * wl * T)
        closed = [(e - 1.0) / (1j * wl)]
        for k in range(1, kmax + 1):
            closed.append((T**k * e - k * closed[-1]) / (1j * wl))
    if closed is None or series is None:     # arrays even when 0-d, like np.where's
        return [np.asarray(a) for a in (series if closed is None else closed)]
    return [np.where(small, s, c) for s, c in zip(series, closed)]


def ctra_predict(k: np.ndarray, dt: float | np.ndarray) -> np.ndarray:
    """Kinematic state(s) ``(..., >=6)`` after ``dt`` s of CTRA motion; components beyond the
    sixth are copied unchanged. Yaw is not wrapped."""
    k = np.asarray(k, dtype=float)
    v, a, yaw, w = k[..., 2], k[..., 3], k[..., 4], k[..., 5]
    i0, i1 = _moments(w, dt, 1)
    d = np.exp(1j * yaw) * (v * i0 + a * i1)
    out = k.copy()
    out[..., 0] += d.real
    out[..., 1] += d.imag
    out[..., 2] = v + a * dt
    out[..., 4] = yaw + w * dt
    return out


def ctra_jacobian(k: np.ndarray, dt: float | np.ndarray) -> np.ndarray:
    """``(..., 6, 6)`` Jacobian of :func:`ctra_predict` w.r.t. ``[x, y, v, a, yaw, yawrate]``."""
    k = np.asarray(k, dtype=float)
    v, a, yaw, w = k[..., 2], k[..., 3], k[..., 4], k[..., 5]
    i0, i1, i2 = _moments(w, dt, 2)
    rot = np.exp(1j * yaw)
    cols = {
        2: rot * i0,                               # d(displacement)/dv
        3: rot * i1,                               # d/da
        4: 1j * rot * (v * i0 + a * i1),           # d/dyaw
        5: 1j * rot * (v * i1 + a * i2),           # d/dyawrate (dI_k/dw = i I_{k+1})
    }
    J = np.zeros((*v.shape, 6, 6))
    J[..., 0, 0] = J[..., 1, 1] = 1.0
    for c, val in cols.items():
        J[..., 0, c] = val.real
        J[..., 1, c] = val.imag
    J[..., 2, 2] = J[..., 3, 3] = J[..., 4, 4] = J[..., 5, 5] = 1.0
    J[..., 2, 3] = dt
    J[..., 4, 5] = dt
    return J


def ctra_process_noise(k: np.ndarray, dt: float | np.ndarray, sigma_jerk: float,
                       sigma_yaw_acc: float, sigma_pos: float = 0.0) -> np.ndarray:
    """``(..., 6, 6)`` process noise of one CTRA step.

    Discrete (piecewise-constant over the step) white jerk ``j ~ N(0, sigma_jerk^2)`` (m/s^3)
    and yaw acceleration ``alpha ~ N(0, sigma_yaw_acc^2)`` (rad/s^2), pushed through the
    kinematics (Schubert et al. 2008): ``da = j dt, dv = j dt^2/2, ds = j dt^3/6`` along the
    heading and ``dw = alpha dt, dyaw = alpha dt^2/2, dl = v alpha dt^3/6`` across it. An
    optional isotropic position random walk ``sigma_pos^2 dt`` (m^2/s) absorbs model error.
    """
    k = np.asarray(k, dtype=float)
    v, yaw = k[..., 2], k[..., 4]
    c, s = np.cos(yaw), np.sin(yaw)
    zero = np.zeros_like(v)
    t2, t3 = dt**2 / 2.0, dt**3 / 6.0
    g_j = np.stack([c * t3, s * t3, zero + t2, zero + dt, zero, zero], axis=-1)
    g_a = np.stack([-s * v * t3, c * v * t3, zero, zero, zero + t2, zero + dt], axis=-1)
    Q = (sigma_jerk**2 * g_j[..., :, None] * g_j[..., None, :]
         + sigma_yaw_acc**2 * g_a[..., :, None] * g_a[..., None, :])
    Q[..., 0, 0] += sigma_pos**2 * dt
    Q[..., 1, 1] += sigma_pos**2 * dt
    return Q
