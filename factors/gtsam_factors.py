"""GTSAM factors of the GP-EOT tracking model: CTRA + contour process, stacked contour
measurements (sensor-aware normal offsets) and a Gaussian prior.

State variable of one track at one step: a ``gtsam`` Vector of ``N_STATE = 26`` values
``[x, y, v, a, yaw, yawrate, r_0..r_19]`` (m, m, m/s, m/s^2, rad, rad/s, m): centre and yaw in
the 2D tracking frame, radii of the star-convex contour at the basis angles of the
:class:`factors.gp.ContourGP` (object frame, x along the heading), measured from the centre.

Every factor is a ``gtsam.CustomFactor`` whose Python callback fills the requested Jacobians
with Fortran-ordered float64 arrays of the exact shape (``(dim, 26)``), checked in Python
before they reach gtsam: a wrong shape raises ``ValueError`` in the callback instead of the
segfault gtsam would produce. The callback numerics are plain functions (``process_error``,
``ContourMeasurement.rows``) so they can be tested without gtsam.

Depends only on numpy, scipy, gtsam and the ``factors`` modules (never on ``fgloc``).
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from factors.ctra import ctra_jacobian, ctra_predict, ctra_process_noise
from factors.gp import ContourGP, decay_mean, periodic_kernel, rectangle_radius_gradient
from factors.measurement import (
    closest_on_chain,
    contour_candidates,
    contour_point,
    normal_offset,
    normal_offset_jacobian,
    unit,
    visibility_slack,
)
from factors.state import N_CONTOUR, N_KIN, N_STATE, YAW, YAWRATE, V, X, Y

# ---- keys ------------------------------------------------------------------------------------
#: symbol character of the track-state keys and of the sensor pose key
TRACK_CHAR: str = "t"
SENSOR_CHAR: str = "G"
#: bits of the step index inside a track-state key (the track id takes the next 24 bits)
STEP_BITS: int = 32
MAX_TRACK_ID: int = (1 << 24) - 1
MAX_STEP: int = (1 << STEP_BITS) - 1


def track_key(track_id: int, step: int) -> int:
    """gtsam key of the state of track ``track_id`` at ``step``.

    ``gtsam.symbol(TRACK_CHAR, track_id << 32 | step)``: a gtsam symbol holds an 8-bit
    character and a 56-bit index, split here into 24 bits of track id (``0 <= track_id <
    2^24``) and 32 bits of step (``0 <= step < 2^32``); out-of-range values raise
    ``ValueError``. Keys print as ``t<index>`` in gtsam output; decode with
    :func:`decode_track_key`."""
    track_id, step = int(track_id), int(step)
    if not 0 <= track_id <= MAX_TRACK_ID:
        raise ValueError(f"track id {track_id} outside [0, {MAX_TRACK_ID}]")
    if not 0 <= step <= MAX_STEP:
        raise ValueError(f"step {step} outside [0, {MAX_STEP}]")
    return int(gtsam.symbol(TRACK_CHAR, (track_id << STEP_BITS) | step))


def decode_track_key(key: int) -> tuple[int, int]:
    """``(track_id, step)`` of a key made by :func:`track_key` (``ValueError`` otherwise)."""
    sym = gtsam.Symbol(int(key))
    if chr(sym.chr()) != TRACK_CHAR:
        raise ValueError(f"key {key} is not a track-state key")
    idx = int(sym.index())
    return idx >> STEP_BITS, idx & MAX_STEP


def sensor_key(index: int = 0) -> int:
    """gtsam key of the sensor pose ``G`` (``gtsam.symbol('G', index)``; one per recording,
    ``index`` distinguishes several sensors)."""
    return int(gtsam.symbol(SENSOR_CHAR, int(index)))


# ---- helpers ---------------------------------------------------------------------------------
def wrap_angle(a: np.ndarray | float) -> np.ndarray:
    """Angle(s) (rad) wrapped to ``[-pi, pi)``."""
    return (np.asarray(a, dtype=float) + np.pi) % (2.0 * np.pi) - np.pi


def _fortran(J: np.ndarray, shape: tuple[int, int], what: str) -> np.ndarray:
    """``J`` as a Fortran-ordered float64 array, after checking its shape (``ValueError``)."""
    J = np.asarray(J, dtype=np.float64)
    if J.shape != shape:
        raise ValueError(f"{what}: Jacobian shape {J.shape}, expected {shape}")
    if not np.all(np.isfinite(J)):
        raise ValueError(f"{what}: non-finite Jacobian")
    return np.asfortranarray(J)


def _state(values: gtsam.Values, key: int, what: str) -> np.ndarray:
    """The 26-vector of ``key`` in ``values`` (``ValueError`` on a wrong length)."""
    x = np.asarray(values.atVector(key), dtype=float)
    if x.shape != (N_STATE,):
        raise ValueError(f"{what}: state of key {key} has shape {x.shape}, expected "
                         f"({N_STATE},)")
    return x


class _LastEvaluation:
    """The last residual (and Jacobian) a factor's callback computed and the state it was
    computed at: ISAM2 often linearizes a factor again at the very same point (about a third
    of the fixed-lag smoother's calls), which is then served from here. The callbacks are
    deterministic functions of the state, so this changes nothing but the time."""

    def __init__(self) -> None:
        self.x: np.ndarray | None = None
        self.e: np.ndarray | None = None
        self.J: np.ndarray | None = None

    def get(self, x: np.ndarray, jacobian: bool) -> tuple[np.ndarray, np.ndarray | None] | None:
        """``(e, J)`` if the last evaluation was at exactly ``x`` (and had the Jacobian when
        ``jacobian``), else None."""
        if (self.x is None or (jacobian and self.J is None)
                or not np.array_equal(self.x, x)):
            return None
        return self.e, self.J

    def put(self, x: np.ndarray, e: np.ndarray, J: np.ndarray | None) -> None:
        self.x, self.e, self.J = x, e, J


def _check_gp(gp: ContourGP) -> None:
    if gp.n != N_CONTOUR:
        raise ValueError(f"ContourGP has {gp.n} basis angles, the state holds {N_CONTOUR}")


# ---- process ---------------------------------------------------------------------------------
def process_error(x0: np.ndarray, x1: np.ndarray, dt: float | np.ndarray,
                  gp: ContourGP | None, tau: float, mean: np.ndarray | None = None
                  ) -> np.ndarray:
    """Process residual (..., 26) ``x1 - f(x0, dt)``: CTRA for the kinematics (yaw difference
    wrapped to ``[-pi, pi)``), decay ``mu + exp(-tau dt) (f - mu)`` for the radii. Units of
    the state; ``dt`` (...) in s, ``tau`` in 1/s; leading axes are a batch. ``mean``
    (..., 20) m: the decay target ``mu`` per factor (a batch of tracks with different
    contour models), else ``gp.mu``."""
    x0 = np.asarray(x0, dtype=float)
    x1 = np.asarray(x1, dtype=float)
    pred_k = ctra_predict(x0[..., :N_KIN], dt)
    pred_f = decay_mean(x0[..., N_KIN:], gp.mu if mean is None else mean, tau, dt)
    e = np.concatenate([x1[..., :N_KIN] - pred_k, x1[..., N_KIN:] - pred_f], axis=-1)
    e[..., YAW] = wrap_angle(e[..., YAW])
    return e


def process_jacobian_x0(x0: np.ndarray, dt: float | np.ndarray, tau: float) -> np.ndarray:
    """(..., 26, 26) Jacobian of :func:`process_error` w.r.t. ``x0`` (w.r.t. ``x1`` it is I)."""
    x0 = np.asarray(x0, dtype=float)
    J = np.zeros((*x0.shape[:-1], N_STATE, N_STATE))
    J[..., :N_KIN, :N_KIN] = -ctra_jacobian(x0[..., :N_KIN], dt)
    decay = np.exp(-tau * np.asarray(dt, dtype=float))
    idx = np.arange(N_KIN, N_STATE)
    J[..., idx, idx] = -decay[..., None]
    return J


def process_covariance(x_ref: np.ndarray, dt: float | np.ndarray, gp: ContourGP, tau: float,
                       sigma_jerk: float, sigma_yaw_acc: float, sigma_pos: float = 0.0,
                       q_floor: float = 1e-8, contour_rw: np.ndarray | None = None
                       ) -> np.ndarray:
    """(..., 26, 26) process noise ``Q_ctra(x_ref) (+) ((1 - exp(-2 tau dt)) K + dt
    contour_rw)`` plus ``q_floor`` on the diagonal (each component's squared unit): the CTRA
    noise has rank 4 of 6 (jerk and yaw acceleration only), the floor makes ``Q`` invertible.
    ``Q_ctra`` depends on the speed and yaw of ``x_ref`` (..., 26) (the state the factor is
    built around); it is kept fixed. ``contour_rw`` (20, 20) m^2/s is an optional random walk
    of the radii (the tracker's length/width random walk ``Q_size``), None for none. ``dt``
    (...) s; leading axes are a batch."""
    x_ref = np.asarray(x_ref, dtype=float)
    dt = np.asarray(dt, dtype=float)
    Q = np.zeros((*x_ref.shape[:-1], N_STATE, N_STATE))
    Q[..., :N_KIN, :N_KIN] = ctra_process_noise(x_ref[..., :N_KIN], dt, sigma_jerk,
                                                sigma_yaw_acc, sigma_pos)
    Q[..., N_KIN:, N_KIN:] = (1.0 - np.exp(-2.0 * tau * dt))[..., None, None] * gp.K
    if contour_rw is not None:
        rw = np.asarray(contour_rw, dtype=float)
        if rw.shape != (N_CONTOUR, N_CONTOUR):
            raise ValueError(f"contour_rw shape {rw.shape}, expected ({N_CONTOUR}, "
                             f"{N_CONTOUR})")
        Q[..., N_KIN:, N_KIN:] += dt[..., None, None] * rw
    idx = np.arange(N_STATE)
    Q[..., idx, idx] += q_floor
    return 0.5 * (Q + np.swapaxes(Q, -1, -2))


def process_factor(key_k: int, key_k1: int, dt: float, gp: ContourGP, tau: float,
                   sigma_jerk: float, sigma_yaw_acc: float, sigma_pos: float = 0.0,
                   x_ref: np.ndarray | None = None, q_floor: float = 1e-8,
                   contour_rw: np.ndarray | None = None) -> gtsam.CustomFactor:
    """Factor between consecutive states of one track, ``dt`` s apart.

    Residual (26,) = :func:`process_error` ``(x_k, x_{k+1})``, whitened by a
    ``noiseModel.Gaussian.Covariance`` of :func:`process_covariance` evaluated at ``x_ref``
    (the speed/heading that scale the CTRA noise; default: a state at rest, heading 0 -- pass
    the initial estimate of ``x_k``). Noise parameters as in ``TrackingConfig``: ``tau``
    (1/s), ``sigma_jerk`` (m/s^3), ``sigma_yaw_acc`` (rad/s^2), ``sigma_pos`` (m/sqrt(s)),
    ``contour_rw`` (m^2/s, see :func:`process_covariance`). Jacobians analytic:
    ``d/dx_k = -blockdiag(J_ctra, exp(-tau dt) I)``, ``d/dx_{k+1} = I``.
    """
    _check_gp(gp)
    if not dt > 0:
        raise ValueError(f"dt must be > 0, got {dt}")
    x_ref = np.zeros(N_STATE) if x_ref is None else np.asarray(x_ref, dtype=float)
    if x_ref.shape != (N_STATE,):
        raise ValueError(f"x_ref shape {x_ref.shape}, expected ({N_STATE},)")
    Q = process_covariance(x_ref, dt, gp, tau, sigma_jerk, sigma_yaw_acc, sigma_pos, q_floor,
                           contour_rw)
    noise = gtsam.noiseModel.Gaussian.Covariance(Q)
    eye = np.asfortranarray(np.eye(N_STATE))
    memo = _LastEvaluation()

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list) -> np.ndarray:
        k0, k1 = this.keys()[0], this.keys()[1]
        x = np.concatenate([_state(values, k0, "process_factor"),
                            _state(values, k1, "process_factor")])
        hit = memo.get(x, H is not None)
        if hit is not None:
            e, J0 = hit
        else:
            x0, x1 = x[:N_STATE], x[N_STATE:]
            e = process_error(x0, x1, dt, gp, tau)
            J0 = (None if H is None else
                  _fortran(process_jacobian_x0(x0, dt, tau), (N_STATE, N_STATE),
                           "process_factor"))
            memo.put(x, e, J0)
        if H is not None:
            H[0] = J0
            H[1] = eye
        return e

    return gtsam.CustomFactor(noise, [int(key_k), int(key_k1)], error)


# ---- contour measurement ---------------------------------------------------------------------
def huber_weights(r: np.ndarray, k: float) -> np.ndarray:
    """Huber IRLS weights of whitened residuals ``r`` (dimensionless): 1 for ``|r| <= k``,
    ``k / |r|`` beyond (``k <= 0`` or ``inf`` disables: all ones)."""
    a = np.abs(np.asarray(r, dtype=float))
    if not (k > 0 and np.isfinite(k)):
        return np.ones_like(a)
    return np.where(a <= k, 1.0, k / np.maximum(a, 1e-300))


class ConditionalTable:
    """The GP conditional ``H`` and variance of a :class:`ContourGP` at any angle from a
    regular grid of ``bins`` angles over ``[0, 2 pi]``, linearly interpolated; the parts with
    kinks at the rectangle's corners (the prior mean and the size modes of ``H``) are exact:
    evaluating the exact conditional at every linearization costs more than the rest of a
    factor. The variance (only a noise weight) is interpolated as a whole. The
    interpolated ``H`` is used for both the residual and the Jacobian, so they stay exact
    derivatives of each other; it differs from the exact conditional by < 1e-3 m in radius
    at 720 bins (tests)."""

    def __init__(self, gp: ContourGP, bins: int = 720) -> None:
        _check_gp(gp)
        self.gp, self.bins = gp, int(bins)
        grid = 2.0 * np.pi * np.arange(self.bins + 1) / self.bins
        _, self.var = gp.conditional(grid)
        # H = k(theta, A) K^-1 = smooth periodic part + sl^2 gL(theta) gL(A) K^-1 + (width);
        # gL, gW jump at the rectangle's corners: evaluated exactly, not interpolated
        per = periodic_kernel(grid[:, None], gp.angles[None, :], gp.sf, gp.length, gp.sr,
                              gp.symmetry)
        self.H = per @ gp.K_inv
        gl, gw = rectangle_radius_gradient(gp.angles, gp.mean_length, gp.mean_width)
        self.size_rows = np.stack([gp.sl**2 * gl @ gp.K_inv, gp.sw**2 * gw @ gp.K_inv])
        self._candidates: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def candidates(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """``(H (n, 20), prior mean (n,))`` at the ``n`` equally spaced candidate angles
        ``2 pi k / n`` of :class:`ContourMeasurement`, computed once per ``n`` (every factor
        of a table shares them; treat as read-only)."""
        if n not in self._candidates:
            H, mean, _ = self(2.0 * np.pi * np.arange(n) / n)
            self._candidates[n] = (H, mean)
        return self._candidates[n]

    def __call__(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(H (m, n), prior mean (m,), variance (m,))`` at angles ``theta`` (m,) (rad)."""
        pos = np.mod(np.asarray(theta, dtype=float), 2.0 * np.pi) * (self.bins / (2 * np.pi))
        i = np.minimum(pos.astype(np.int64), self.bins - 1)
        fr = pos - i
        H = self.H[i] * (1.0 - fr)[:, None] + self.H[i + 1] * fr[:, None]
        gl, gw = rectangle_radius_gradient(theta, self.gp.mean_length, self.gp.mean_width)
        H += np.column_stack([gl, gw]) @ self.size_rows
        return H, self.gp.mean(theta), self.var[i] * (1.0 - fr) + self.var[i + 1] * fr


class _FrameRows:
    """Rows of the detections of one frame, or of a batch of frames padded to a common
    length: ``detections`` (m, 2) or (F, M, 2) with ``valid`` (F, M) marking the real ones
    (None = all). Stored with the frame axis (``z`` (F, M, 2), ``valid`` (F, M)); ``_in`` adds
    it to an argument and ``_out`` removes it from a result when the object holds one frame,
    so every method takes and returns arrays shaped like the detections it was given."""

    def __init__(self, detections: np.ndarray, valid: np.ndarray | None) -> None:
        z = np.asarray(detections, dtype=float)
        self.single = z.ndim == 2
        self.z = z[None] if self.single else z
        if self.z.ndim != 3 or self.z.shape[2] != 2 or self.z.shape[1] < 1:
            raise ValueError(f"detections shape {z.shape}, expected (m >= 1, 2) or "
                             "(F, M >= 1, 2)")
        shape = self.z.shape[:2]
        self.valid = (np.ones(shape, dtype=bool) if valid is None
                      else np.asarray(valid, dtype=bool).reshape(shape))

    def _in(self, a: np.ndarray | float) -> np.ndarray:
        return np.asarray(a)[None] if self.single else np.asarray(a)

    def _out(self, a: np.ndarray) -> np.ndarray:
        return a[0] if self.single else a


class ContourMeasurement(_FrameRows):
    """Sensor-aware normal-offset rows of all detections of one track in one frame, or of a
    batch of frames (one track-step each) at once.

    detections (m, 2) -- one frame -- or (F, M, 2) -- F frames padded to M detections, with
    ``valid`` (F, M) marking the real ones (padding must be finite; its rows are zero) --
    and sensor (2,) in m, tracking frame. Every method takes and returns arrays with the
    frame axis exactly when the detections had it (state (26,) or (F, 26)). The contour of
    the state is sampled at ``n_candidates`` equally spaced object-frame angles (GP
    conditional mean); the samples visible from the sensor (outward normal facing it, not
    self-occluded: :func:`factors.measurement.contour_candidates`) form the visible chain,
    each detection is matched to its closest point on that chain (:func:`closest_on_chain`;
    on the whole contour when that is closer by more than :func:`visibility_slack` of
    ``visible_slack`` m and the radar noise), giving a contour angle ``theta*`` and a unit
    normal ``n``; the row is ``n . (z - c - u(theta* + yaw) f(theta*))`` (m), ``f(theta*)``
    the GP conditional mean. Field-of-view limits are not applied (the caller should pass
    only detections it trusts).

    The association (theta*, n) is **re-done at every evaluation** (each linearization of the
    optimizer, like point-to-plane ICP); the Jacobian treats it as fixed, which is exact up to
    the (small) mismatch between the polyline and the smooth contour. Robust weights: Huber
    on ``row / sigma`` with threshold ``huber_k`` (in sigmas), recomputed at each evaluation
    (IRLS); rows of residual and Jacobian are scaled by ``sqrt(w)``.

    Per-row noise (optional, like the tracker's measurement noise): with ``sigma_range`` (m)
    and/or ``sigma_azimuth`` (rad) > 0, or ``gp_variance``, row i has the std. dev.
    ``s_i = sqrt(sigma^2 + var_f (u . n)^2 + sigma_range^2 (e_r . n)^2
    + (sigma_azimuth r)^2 (e_t . n)^2)`` (``e_r``, ``e_t`` the radial and tangential
    directions of the detection seen from the sensor at 2D range ``r``, ``u`` the contour ray,
    ``var_f`` the GP interpolation variance at ``theta*``); the row enters with the weight
    ``(sigma / s_i)^2`` (times the Huber weight of ``row / s_i``), fixed per evaluation like
    the association, so the factor keeps its isotropic ``sigma`` noise model.
    """

    def __init__(self, detections: np.ndarray, sensor: np.ndarray, gp: ContourGP,
                 sigma: float = 0.3, huber_k: float = 1.345, n_candidates: int = 48,
                 sigma_range: float = 0.0, sigma_azimuth: float = 0.0,
                 gp_variance: bool = False, table: ConditionalTable | None = None,
                 valid: np.ndarray | None = None, visible_slack: float = np.inf) -> None:
        _check_gp(gp)
        super().__init__(detections, valid)
        z = self.z
        s = np.asarray(sensor, dtype=float)
        if s.shape != (2,):
            raise ValueError(f"sensor shape {s.shape}, expected (2,)")
        if not sigma > 0:
            raise ValueError(f"sigma must be > 0, got {sigma}")
        if not np.all(np.isfinite(z)) or not np.all(np.isfinite(s)):
            raise ValueError("non-finite detections or sensor position")
        self.sensor, self.gp = s, gp
        self.sigma, self.huber_k = float(sigma), float(huber_k)
        self.slack = visibility_slack(z, s, float(sigma_range), float(sigma_azimuth),
                                      float(visible_slack))
        self.gp_variance = bool(gp_variance)
        self.radar_var = None
        if sigma_range > 0 or sigma_azimuth > 0:
            los = z - s
            r2d = np.maximum(np.linalg.norm(los, axis=-1), 1e-6)
            self.e_r = los / r2d[..., None]
            self.e_t = np.stack([-self.e_r[..., 1], self.e_r[..., 0]], axis=-1)
            self.radar_var = (float(sigma_range) ** 2, (float(sigma_azimuth) * r2d) ** 2)
        self.cand_theta = 2.0 * np.pi * np.arange(int(n_candidates)) / int(n_candidates)
        self.table = table
        if table is None:
            self.cand_H, self.cand_mean, _ = self.conditional(self.cand_theta)
        else:
            self.cand_H, self.cand_mean = table.candidates(int(n_candidates))

    @property
    def dim(self) -> int:
        """Number of residual rows per frame (one per detection, padding included)."""
        return int(self.z.shape[1])

    def _states(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        want = (N_STATE,) if self.single else (len(self.z), N_STATE)
        if x.shape != want:
            raise ValueError(f"state shape {x.shape}, expected {want}")
        return self._in(x)


    def associate(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(theta* (m,), normal (m, 2))`` of the detections for state ``x`` (26,) (with a
        leading frame axis for a batch)."""
        theta, normal = self._associate(self._states(x))
        return self._out(theta), self._out(normal)

    def _associate(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r = self.cand_mean + (x[:, N_KIN:] - self.gp.mu) @ self.cand_H.T       # (F, c)
        pts = contour_point(x[:, [X, Y]], x[:, YAW], r, self.cand_theta)       # (F, c, 2)
        vis = contour_candidates(pts, self.sensor)
        return closest_on_chain(self.z, pts, self.cand_theta, vis, self.slack)

    def conditional(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(H (..., n), prior mean (...), variance (...))`` of the GP at ``theta`` (...):
        from the table when given, else exact."""
        theta = np.asarray(theta, dtype=float)
        flat = theta.ravel()
        if self.table is not None:
            H, mean, var = self.table(flat)
        else:
            H, var = self.gp.conditional(flat)
            mean = self.gp.mean(flat)
        return (H.reshape(*theta.shape, -1), mean.reshape(theta.shape),
                var.reshape(theta.shape))

    def row_sigma(self, yaw: np.ndarray | float, theta: np.ndarray, normal: np.ndarray,
                  var_f: np.ndarray) -> np.ndarray:
        """(m,) std. dev. (m) of each row (class doc) for yaw, theta (m,), normal (m, 2),
        var_f (m,) (each with a leading frame axis for a batch); ``sigma`` everywhere without
        per-row noise."""
        yaw, theta, normal, var_f = (self._in(a) for a in (yaw, theta, normal, var_f))
        return self._out(self._row_sigma(yaw, theta, normal, var_f))

    def _row_sigma(self, yaw: np.ndarray, theta: np.ndarray, normal: np.ndarray,
                   var_f: np.ndarray) -> np.ndarray:
        var = np.full(theta.shape, self.sigma**2)
        if self.gp_variance:
            var += var_f * np.sum(unit(theta + yaw[:, None]) * normal, axis=-1) ** 2
        if self.radar_var is not None:
            var += (self.radar_var[0] * np.sum(self.e_r * normal, axis=-1) ** 2
                    + self.radar_var[1] * np.sum(self.e_t * normal, axis=-1) ** 2)
        return np.sqrt(var)

    def rows(self, x: np.ndarray, assoc: tuple[np.ndarray, np.ndarray] | None = None,
             weights: np.ndarray | None = None, jacobian: bool = False
             ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        """Weighted rows (m,) (m), their Jacobian (m, 26) if asked, and the weights (m,)
        (each with a leading frame axis for a batch; padding rows and weights are 0).

        ``assoc`` and ``weights`` are recomputed from ``x`` unless given (tests freeze them to
        differentiate the rows exactly as the Jacobian does)."""
        x = self._states(x)
        if assoc is None:
            theta, normal = self._associate(x)
        else:
            theta, normal = (self._in(a) for a in assoc)
        H, mean, var_f = self.conditional(theta)
        radius = mean + np.einsum("fmn,fn->fm", H, x[:, N_KIN:] - self.gp.mu)
        e = normal_offset(self.z, x[:, [X, Y]], x[:, YAW], radius, theta, normal)
        if weights is None:
            scale = self._row_sigma(x[:, YAW], theta, normal, var_f) / self.sigma
            weights = huber_weights(e / (self.sigma * scale), self.huber_k) / scale**2
            weights = np.where(self.valid, weights, 0.0)
        else:
            weights = self._in(weights)
        sw = np.sqrt(weights)
        J = None
        if jacobian:
            Jr = normal_offset_jacobian(x[:, YAW], radius, theta, H, normal)   # (F, M, 3 + n)
            J = np.zeros((*theta.shape, N_STATE))
            J[..., [X, Y, YAW]] = Jr[..., :3]
            J[..., N_KIN:] = Jr[..., 3:]
            J *= sw[..., None]
            J = self._out(J)
        return self._out(sw * e), J, self._out(weights)


@dataclass(frozen=True)
class ExtentSettings:
    """When and how the visible-extent rows of :class:`ExtentRows` apply (the tracker's
    ``extent_*`` settings): std. dev. ``sigma`` (m) of a row, at least ``min_points``
    detections, detections spanning at least ``min_cover`` of the contour's extent along the
    face, ``sin(incidence) >= min_incidence`` of the line of sight on the face; ``gap_max``
    (m): cap of the lengthwise sampling-gap correction (the tracker's
    ``extent_gap_correction``: with n detections spanning s along the heading, each end lies
    s / (n - 1) beyond its extreme detection; 0 = no correction); ``face_min_points``: the
    rows of a face's ends need at least this many detections on that face -- within
    ``face_band`` (m) of its outermost detection across it (the seen side for the length
    rows, the seen front or rear for the width rows) -- 0 = no such test. With a few returns
    on a face its extremes stop short of the far end (the corner away from the sensor) by
    about the sampling gap, and a smoother that sums these rows over a whole track shrinks
    the vehicle to that bias. ``huber_k``: Huber IRLS threshold (in sigmas) on each row's
    ``row / sigma``, as on the normal-offset rows (0 = none): an extreme detection that is
    not the vehicle's end (its far part hidden behind a nearer vehicle) moves the end by
    metres in one frame."""

    sigma: float = 0.35
    min_points: int = 4
    min_cover: float = 0.5
    min_incidence: float = 0.25
    gap_max: float = 0.0
    face_min_points: int = 0
    face_band: float = 0.5
    huber_k: float = 0.0


class ExtentRows(_FrameRows):
    """Visible-extent rows of one track in one frame, or of a batch of frames (the tracker's
    extent measurement).

    For a side face seen from the sensor (the sensor beyond the contour's lateral extent,
    incidence at least ``min_incidence``) whose detections span at least ``min_cover`` of the
    contour's length, the extreme detections along the heading lie at the front and rear
    ends: rows ``a . (z_j - c) - f_a`` (m) for the axis directions ``a`` = heading and
    -heading, ``f_a`` the contour radius on that axis (a basis radius: the basis holds the
    four axis angles), ``z_j`` the extreme detection along ``a``. Likewise the width from a
    seen front or rear face. With ``settings.gap_max`` > 0 the lengthwise ends are measured one
    sampling gap beyond the extreme detections (``s / (n - 1)`` for n detections spanning s
    along the heading, at most ``gap_max``; held constant in the Jacobian, like the
    selection): sparse returns rarely reach a vehicle's ends, and without it the contour
    shrinks to the detections. With ``settings.face_min_points`` > 0 the rows of a face's
    ends apply only with that many detections within ``settings.face_band`` of the face (the
    seen side for the length rows, the seen front or rear for the width rows; the side /
    face the sensor is on). Always 4 rows (front, left, rear, right); a row that does not
    apply is zero with a zero Jacobian, so the factor's dimension stays fixed while the
    selection (like the contour association) is re-done at every evaluation. Rows enter
    scaled by ``sigma_factor / settings.sigma`` (the factor's noise model is isotropic), with
    Huber IRLS weights on ``row / settings.sigma`` when ``settings.huber_k`` > 0 (held
    constant in the Jacobian, like the selection). Field-of-view cuts are the caller's:
    ``trusted`` (k,) marks the detections that may be an end (e.g. not next to the FOV's
    edge, where the view may be cut); a row whose extreme detection is not trusted does not
    apply.

    detections (k, 2) for one frame, or (F, K, 2) padded with ``valid`` (F, K) for a batch;
    states, rows and Jacobians then carry the frame axis too.
    """

    def __init__(self, detections: np.ndarray, sensor: np.ndarray, settings: ExtentSettings,
                 sigma_factor: float, trusted: np.ndarray | None = None,
                 valid: np.ndarray | None = None) -> None:
        if N_CONTOUR % 4:
            raise ValueError("the contour basis must hold the four axis angles")
        super().__init__(detections, valid)
        shape = self.z.shape[:2]
        trusted = (np.ones(shape[self.single:], dtype=bool) if trusted is None
                   else np.asarray(trusted, dtype=bool))
        if trusted.shape != shape[self.single:]:
            raise ValueError(f"trusted shape {trusted.shape}, expected {shape[self.single:]}")
        self.trusted = trusted.reshape(shape)
        self.sensor = np.asarray(sensor, dtype=float)
        self.cfg = settings
        self.scale = float(sigma_factor) / float(settings.sigma)
        self.axis_idx = N_KIN + np.arange(4) * (N_CONTOUR // 4)

    @staticmethod
    def axes(yaw: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """(..., 4, 2) axis directions front, left, rear, right and their yaw derivatives for
        yaw (...)."""
        yaw = np.asarray(yaw, dtype=float)
        h = np.stack([np.cos(yaw), np.sin(yaw)], axis=-1)
        lat = np.stack([-h[..., 1], h[..., 0]], axis=-1)
        return np.stack([h, lat, -h, -lat], axis=-2), np.stack([lat, -h, -lat, h], axis=-2)

    def select(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(j (4,), use (4,))``: index of the extreme detection along each axis and which
        rows apply, for state ``x`` (26,) (each with a leading frame axis for a batch)."""
        j, use = self._select(self._in(x))
        return self._out(j), self._out(use)

    def _select(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cfg = self.cfg
        c = x[:, [X, Y]]
        ax, _ = self.axes(x[:, YAW])                                    # (F, 4, 2)
        rax = x[:, self.axis_idx]                                       # (F, 4)
        proj = np.einsum("fkd,fad->fka", self.z - c[:, None], ax)       # (F, K, 4)
        proj[~self.valid] = -np.inf
        j = np.argmax(proj, axis=1)                                     # (F, 4)
        s = np.einsum("fd,fad->fa", self.sensor - c, ax)
        los = c[:, None] + ax * rax[..., None] - self.sensor
        inc = (np.abs(np.sum(los * ax, axis=-1))
               / np.maximum(np.linalg.norm(los, axis=-1), 1e-6))
        seen = (s > rax) & (inc >= cfg.min_incidence)
        top = proj.max(axis=1)
        span = top[:, :2] + top[:, 2:]                                  # along heading, across
        side = (seen[:, 1] | seen[:, 3]) & (span[:, 0] >= cfg.min_cover * (rax[:, 0] + rax[:, 2]))
        face = (seen[:, 0] | seen[:, 2]) & (span[:, 1] >= cfg.min_cover * (rax[:, 1] + rax[:, 3]))
        enough = self.valid.sum(axis=1) >= cfg.min_points
        use = (np.stack([side, face, side, face], axis=1) & enough[:, None]
               & np.take_along_axis(self.trusted, j, axis=1))
        if cfg.face_min_points > 0:
            # detections on the seen side (length rows) and on the seen front / rear (width
            # rows): within face_band of the outermost one across that face
            f_ax = np.stack([np.where(s[:, 1] > 0, 1, 3), np.where(s[:, 0] > 0, 0, 2)], axis=1)
            p = np.take_along_axis(proj, f_ax[:, None, :], axis=2)          # (F, K, 2)
            t = np.take_along_axis(top, f_ax, axis=1)                        # (F, 2)
            n_on = np.sum(p >= t[:, None, :] - cfg.face_band, axis=1)       # (F, 2)
            use &= np.tile(n_on >= cfg.face_min_points, 2)
        return j, use

    def rows(self, x: np.ndarray, sel: tuple[np.ndarray, np.ndarray] | None = None,
             jacobian: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
        """Scaled rows (4,) and their Jacobian (4, 26) if asked (each with a leading frame axis
        for a batch); ``sel`` from :meth:`select` (recomputed from ``x`` unless given)."""
        x = self._in(x).astype(float)
        j, use = self._select(x) if sel is None else (self._in(a) for a in sel)
        ax, dax = self.axes(x[:, YAW])
        d = np.take_along_axis(self.z, j[..., None], axis=1) - x[:, None, [X, Y]]   # (F, 4, 2)
        reach = np.sum(ax * d, axis=-1)                                              # (F, 4)
        if self.cfg.gap_max > 0.0:
            n = np.maximum(self.valid.sum(axis=1) - 1, 1)
            gap = np.clip((reach[:, 0] + reach[:, 2]) / n, 0.0, self.cfg.gap_max)
            reach = reach + gap[:, None] * np.array([1.0, 0.0, 1.0, 0.0])
        r = reach - x[:, self.axis_idx]
        w = use * self.scale * np.sqrt(huber_weights(r / self.cfg.sigma, self.cfg.huber_k))
        e = w * r
        J = None
        if jacobian:
            J = np.zeros((len(x), 4, N_STATE))
            J[..., [X, Y]] = -ax
            J[..., YAW] = np.sum(dax * d, axis=-1)
            J[:, np.arange(4), self.axis_idx] = -1.0
            J = self._out(J * w[..., None])
        return self._out(e), J


class RangeRateRows(_FrameRows):
    """Range-rate (Doppler) rows of the detections of one track in one frame, or of a batch of
    frames: the rigid-body velocity of the state at each detection, projected on the line of
    sight, against the measured range rate (the tracker's Doppler measurement,
    :func:`factors.measurement.range_rate`):

        row_i = (v u(yaw) + yawrate e_z x (z_i - c)) . (z_i - s) / rng_i - doppler_i   (m/s)

    (positive away from the sensor; rng the 3D range). It observes the speed, the heading and
    the yaw rate, which the contour rows alone leave to the process model (a vehicle seen from
    behind only: its speed then drifts and the contour grows). Rows enter scaled by
    ``sigma_factor / sigma`` (the factor's noise model is isotropic) with Huber weights on
    ``row / sigma`` (threshold ``huber_k``); padding rows (``valid`` False) are zero.
    Jacobian: ``d/dv = u(yaw) . l``, ``d/dyaw = v u'(yaw) . l``, ``d/dyawrate = (e_z x (z -
    c)) . l``, ``d/dc = yawrate (-l_y, l_x)`` with ``l = (z - s) / rng``.

    detections (m, 2), doppler and rng (m,) for one frame (states (26,)), or (F, M, 2) / (F, M)
    with ``valid`` (F, M) for a batch (states (F, 26)); sensor (2,) m.
    """

    def __init__(self, detections: np.ndarray, doppler: np.ndarray, rng: np.ndarray,
                 sensor: np.ndarray, sigma: float, sigma_factor: float, huber_k: float,
                 valid: np.ndarray | None = None) -> None:
        super().__init__(detections, valid)
        shape = self.z.shape[:2]
        self.doppler = np.asarray(doppler, dtype=float).reshape(shape)
        rng = np.asarray(rng, dtype=float).reshape(shape)
        if not sigma > 0 or not np.all(rng > 0):
            raise ValueError("RangeRateRows needs sigma > 0 and positive ranges")
        self.los = (self.z - np.asarray(sensor, dtype=float)) / rng[..., None]     # (F, M, 2)
        self.sigma, self.scale, self.huber_k = float(sigma), sigma_factor / sigma, huber_k

    def rows(self, x: np.ndarray, jacobian: bool = False
             ) -> tuple[np.ndarray, np.ndarray | None]:
        """Scaled rows (m,) and their Jacobian (m, 26) if asked (with a leading frame axis
        for a batch)."""
        x = self._in(x).astype(float)
        c, v, yaw, w = x[:, [X, Y]], x[:, V], x[:, YAW], x[:, YAWRATE]
        h = np.stack([np.cos(yaw), np.sin(yaw)], axis=-1)[:, None, :]            # (F, 1, 2)
        d = self.z - c[:, None, :]
        rot = np.stack([-d[..., 1], d[..., 0]], axis=-1)                         # e_z x (z - c)
        vel = v[:, None, None] * h + w[:, None, None] * rot
        r = np.sum(vel * self.los, axis=-1) - self.doppler
        wgt = np.where(self.valid, huber_weights(r / self.sigma, self.huber_k), 0.0)
        sw = self.scale * np.sqrt(wgt)
        e = sw * r
        J = None
        if jacobian:
            lx, ly = self.los[..., 0], self.los[..., 1]
            J = np.zeros((*r.shape, N_STATE))
            J[..., V] = np.sum(h * self.los, axis=-1)
            J[..., YAW] = v[:, None] * (-h[..., 1] * lx + h[..., 0] * ly)
            J[..., YAWRATE] = np.sum(rot * self.los, axis=-1)
            J[..., X] = -w[:, None] * ly
            J[..., Y] = w[:, None] * lx
            J = self._out(J * sw[..., None])
        return self._out(e), J


def measurement_rows(meas: ContourMeasurement,
                     extras: tuple[ExtentRows | RangeRateRows | None, ...], x: np.ndarray,
                     jacobian: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """The normal-offset rows of ``meas`` followed by each block of ``extras`` (None ones
    skipped) at state(s) ``x``, and their Jacobian if asked: rows (m',) / (F, M') and Jacobian
    (m', 26) / (F, M', 26), the frame axis as the detections had it."""
    e, J, _ = meas.rows(x, jacobian=jacobian)
    for extra in extras:
        if extra is not None:
            e2, J2 = extra.rows(x, jacobian=jacobian)
            e = np.concatenate([e, e2], axis=-1)
            J = None if J is None else np.concatenate([J, J2], axis=-2)
    return e, J


def contour_measurement_factor(key: int, detections_xy: np.ndarray, sensor_xy: np.ndarray,
                               gp: ContourGP, sigma: float = 0.3, huber_k: float = 1.345,
                               n_candidates: int = 48, sigma_range: float = 0.0,
                               sigma_azimuth: float = 0.0, gp_variance: bool = False,
                               table: ConditionalTable | None = None,
                               extent: ExtentSettings | None = None,
                               extent_detections: np.ndarray | None = None,
                               extent_trusted: np.ndarray | None = None,
                               range_rate: tuple[np.ndarray, np.ndarray] | None = None,
                               sigma_doppler: float = 1.0, visible_slack: float = np.inf
                               ) -> gtsam.CustomFactor:
    """One factor for all ``m`` detections (m, 2) (m, tracking frame) of one track in one
    frame, seen from ``sensor_xy`` (2,) (m): ``m`` stacked normal-offset rows of
    :class:`ContourMeasurement`, noise ``Isotropic.Sigma(m, sigma)`` (``sigma`` m, the
    contour scatter, ``TrackingConfig.sigma_contour``), Huber weights with threshold
    ``huber_k`` sigmas applied per row inside the callback (a gtsam robust model on the
    stacked block would weigh the block as one residual); optional per-row radar noise
    ``sigma_range`` (m), ``sigma_azimuth`` (rad) and GP interpolation variance
    (``gp_variance``) as in :class:`ContourMeasurement`; ``table`` (a
    :class:`ConditionalTable` of ``gp``, shared by many factors) makes it faster. With
    ``extent``, 4 visible-extent rows (:class:`ExtentRows`) follow the ``m`` rows, from
    ``extent_detections`` (k, 2) when given (e.g. all detections of the frame when only a
    subsample enters the normal rows: the extremes need them all), else the same detections,
    and ``extent_trusted`` their mask of possible ends (:class:`ExtentRows`). With
    ``range_rate = (doppler (m,) m/s, rng (m,) m)`` of the same detections, ``m`` range-rate
    rows (:class:`RangeRateRows`, noise ``sigma_doppler`` m/s) follow. Wrong input shapes raise
    ``ValueError`` here, before gtsam sees anything."""
    if table is not None and table.gp is not gp:
        raise ValueError("table was built for another ContourGP")
    meas = ContourMeasurement(detections_xy, sensor_xy, gp, sigma, huber_k, n_candidates,
                              sigma_range, sigma_azimuth, gp_variance, table,
                              visible_slack=visible_slack)
    if extent_detections is not None:
        extent_detections = np.asarray(extent_detections, dtype=float)
        if extent_detections.ndim != 2 or extent_detections.shape[1:] != (2,):
            raise ValueError(f"extent_detections shape {extent_detections.shape}, expected "
                             "(k, 2)")
    ext = None if extent is None else ExtentRows(
        meas.z if extent_detections is None else extent_detections, meas.sensor, extent,
        meas.sigma, extent_trusted)
    rr = (None if range_rate is None else
          RangeRateRows(meas.z[0], *range_rate, meas.sensor, sigma_doppler, meas.sigma, huber_k))
    dim = meas.dim * (1 if rr is None else 2) + (0 if ext is None else 4)
    shape = (dim, N_STATE)

    memo = _LastEvaluation()

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list) -> np.ndarray:
        x = _state(values, this.keys()[0], "contour_measurement_factor")
        hit = memo.get(x, H is not None)
        if hit is not None:
            e, J = hit
        else:
            e, J = measurement_rows(meas, (ext, rr), x, H is not None)
            if J is not None:
                J = _fortran(J, shape, "contour_measurement_factor")
            memo.put(x, e, J)
        if H is not None:
            H[0] = J
        return e

    noise = gtsam.noiseModel.Isotropic.Sigma(dim, meas.sigma)
    return gtsam.CustomFactor(noise, [int(key)], error)


# ---- prior -----------------------------------------------------------------------------------
def prior_factor(key: int, mean: np.ndarray, cov: np.ndarray) -> gtsam.PriorFactorVector:
    """Gaussian prior ``x ~ N(mean (26,), cov (26, 26))`` on a track state (state units).
    The yaw residual is not wrapped (keep the mean's yaw near the estimate's)."""
    mean = np.asarray(mean, dtype=float)
    cov = np.asarray(cov, dtype=float)
    if mean.shape != (N_STATE,):
        raise ValueError(f"mean shape {mean.shape}, expected ({N_STATE},)")
    if cov.shape != (N_STATE, N_STATE):
        raise ValueError(f"cov shape {cov.shape}, expected ({N_STATE}, {N_STATE})")
    cov = 0.5 * (cov + cov.T)
    try:
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError as exc:
        raise ValueError("prior covariance is not positive definite") from exc
    return gtsam.PriorFactorVector(int(key), mean, gtsam.noiseModel.Gaussian.Covariance(cov))
