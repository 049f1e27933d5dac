"""Batched measurement model of the tracker: predicted detections (and Doppler) at sigma points.

Per detection the measurement is ``[x, y]`` (m, frame C) and, with Doppler, its range rate
(m/s): rows ``3 j .. 3 j + 2`` (or ``2 j, 2 j + 1``) of a track's stacked measurement vector.
The contour radius at an angle comes from a lookup table of the GP conditional
(:class:`ContourTable`), linearly interpolated, so the plain model can evaluate it for every
sigma point cheaply.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factors.gp import ContourGP
from factors.measurement import contour_point, plain_angles, range_rate
from fgloc.tracking.ukf import distinct_rows
from fgloc.tracks import N_KIN, YAW, YAWRATE, V, X, Y


@dataclass(frozen=True)
class ContourTable:
    """GP conditional on a regular angle grid: H (B+1, n), mean (B+1,), var (B+1,)."""

    gp: ContourGP
    H: np.ndarray
    mean: np.ndarray
    var: np.ndarray

    @staticmethod
    def of(gp: ContourGP, bins: int = 720) -> ContourTable:
        grid = 2.0 * np.pi * np.arange(bins + 1) / bins
        H, var = gp.conditional(grid)
        return ContourTable(gp, H, gp.mean(grid), var)

    def _locate(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        bins = self.H.shape[0] - 1
        pos = np.mod(theta, 2.0 * np.pi) * (bins / (2.0 * np.pi))
        i = np.minimum(pos.astype(np.int64), bins - 1)
        return i, pos - i

    def interp(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """H (..., n), prior mean (...) and conditional variance (...) at angles theta (...)."""
        i, fr = self._locate(np.asarray(theta, dtype=float))
        H, mean = self._hm(i, fr)
        return H, mean, self.var[i] * (1.0 - fr) + self.var[i + 1] * fr

    def _hm(self, i: np.ndarray, fr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        H = self.H[i] * (1.0 - fr[..., None]) + self.H[i + 1] * fr[..., None]
        return H, self.mean[i] * (1.0 - fr) + self.mean[i + 1] * fr

    def interp_mean(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """H (..., n) and prior mean (...) of :meth:`interp` (without the variance)."""
        return self._hm(*self._locate(np.asarray(theta, dtype=float)))

    def variance(self, theta: np.ndarray) -> np.ndarray:
        """Conditional variance (...) of :meth:`interp`."""
        i, fr = self._locate(np.asarray(theta, dtype=float))
        return self.var[i] * (1.0 - fr) + self.var[i + 1] * fr

    def radius(self, f: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """Conditional-mean radius (m) for basis radii f (..., S, n) at angles theta
        (..., m) shared by the S rows of f (e.g. sigma points): shape (..., S, m)."""
        H, mean = self.interp_mean(theta)
        return mean[..., None, :] + (f - self.gp.mu) @ np.swapaxes(H, -1, -2)


@dataclass
class DetectionBatch:
    """The measurement rows of T tracks in one frame, padded to M per track.

    z (T, M, 2) m in C; rng (T, M) 3D range (m) from the sensor; doppler (T, M) m/s;
    valid (T, M). Plain model: theta = normal = None (angles recomputed from each sigma
    point's centre), every row is ``[x, y(, doppler)]``. Sensor-aware model: theta (T, M)
    contour angles and normal (T, M, 2) fixed unit directions, every row is
    ``[n . z(, doppler)]`` (the offset along the contour normal; extent rows use the axis
    direction); dop_valid (T, M) marks rows whose Doppler is used (not the extent rows);
    extra_var (T, M) m^2 is added to a row's position variance (extent rows).
    """

    z: np.ndarray
    rng: np.ndarray
    doppler: np.ndarray
    valid: np.ndarray
    theta: np.ndarray | None = None
    normal: np.ndarray | None = None
    dop_valid: np.ndarray | None = None
    extra_var: np.ndarray | None = None

    @property
    def rows(self) -> int:
        return self.z.shape[1]

    def doppler_mask(self) -> np.ndarray:
        return self.valid if self.dop_valid is None else self.valid & self.dop_valid


def predict_measurements(X_sig: np.ndarray, det: DetectionBatch, table: ContourTable,
                         sensor: np.ndarray, use_doppler: bool) -> np.ndarray:
    """Predicted measurement vectors (T, S, M k) of sigma points X_sig (T, S, n); k = 2 (plain)
    or 1 (sensor-aware), plus 1 with Doppler; padded rows give zeros."""
    centre = X_sig[..., [X, Y]]
    yaw = X_sig[..., YAW]
    f = X_sig[..., N_KIN:]
    z = det.z[:, None, :, :]                                          # (T, 1, M, 2)
    # what depends on the kinematics only is evaluated once per distinct kinematic sigma
    # point (ukf.distinct_rows: same values, 2 N_KIN + 1 instead of S evaluations)
    rows, inv = distinct_rows(X_sig, N_KIN)
    Xk = X_sig[:, rows]
    if det.theta is None:
        theta = plain_angles(z, centre, yaw)                          # (T, S, M)
        r = table.radius(f[..., None, :], theta)[..., 0, :]
        parts = [contour_point(centre, yaw, r, theta)]
    else:
        # n . contour_point, by components (the (..., 2) stack and sum cost more than this)
        r = table.radius(f, det.theta)                                # (T, S, M)
        a = det.theta[:, None, :] + Xk[..., YAW, None]
        px = X_sig[..., X, None] + np.cos(a)[:, inv] * r
        py = X_sig[..., Y, None] + np.sin(a)[:, inv] * r
        parts = [det.normal[:, None, :, 0] * px + det.normal[:, None, :, 1] * py]
    if use_doppler:
        d = range_rate(z, det.rng[:, None, :], Xk[..., [X, Y]], Xk[..., V], Xk[..., YAW],
                       Xk[..., YAWRATE], sensor)
        parts.append((d * det.doppler_mask()[:, None, :])[:, inv])
    if det.theta is None:
        Z = np.concatenate(parts[:1] + [p[..., None] for p in parts[1:]], axis=-1)
    else:
        Z = np.stack(parts, axis=-1)
    Z *= det.valid[:, None, :, None]
    return Z.reshape(*Z.shape[:2], -1)


def measurement_vector(det: DetectionBatch, use_doppler: bool) -> np.ndarray:
    """Stacked measurements (T, M k) (zeros on padding)."""
    pos = det.z if det.normal is None else np.sum(det.normal * det.z, axis=-1)[..., None]
    parts = [pos, (det.doppler * det.doppler_mask())[..., None]] if use_doppler else [pos]
    zz = np.concatenate(parts, axis=-1) * det.valid[..., None]
    return zz.reshape(zz.shape[0], -1)


def measurement_noise(det: DetectionBatch, x: np.ndarray, table: ContourTable,
                      sensor: np.ndarray, sigma_range: float, sigma_azimuth: float,
                      sigma_contour: float, sigma_doppler: float | None) -> np.ndarray:
    """Diagonal blocks (T, M, k, k) of the block-diagonal noise (T, M k, M k): radar
    range/azimuth noise at each detection, contour scatter sigma_contour (isotropic), the GP
    interpolation variance along the contour ray (at the mean state x (T, n)); the
    sensor-aware rows take the variance of all that along their normal plus extra_var.
    sigma_doppler^2 when given (Doppler rows). Identity on padding and on unused Doppler
    rows."""
    T, M = det.valid.shape
    lx, ly = det.z[..., 0] - sensor[0], det.z[..., 1] - sensor[1]
    r2d = np.maximum(np.sqrt(lx * lx + ly * ly), 1e-6)
    erx, ery = lx / r2d, ly / r2d                      # line of sight; et = (-ery, erx)
    theta = det.theta if det.theta is not None else plain_angles(det.z, x[:, [X, Y]], x[:, YAW])
    var_f = table.variance(theta)
    a = theta + x[:, YAW, None]
    ux, uy = np.cos(a), np.sin(a)
    s_az2 = (sigma_azimuth * r2d) ** 2
    if det.normal is not None:
        # n^T Rp n of the 2x2 position noise below, by components
        nx, ny = det.normal[..., 0], det.normal[..., 1]
        n_er, n_et, n_u = nx * erx + ny * ery, ny * erx - nx * ery, nx * ux + ny * uy
        Rp = (sigma_range**2 * n_er * n_er + s_az2 * n_et * n_et + var_f * n_u * n_u
              + sigma_contour**2 * (nx * nx + ny * ny))
        if det.extra_var is not None:
            Rp = Rp + det.extra_var
        Rp = Rp[..., None, None]
    else:
        er = np.stack([erx, ery], axis=-1)
        et = np.stack([-ery, erx], axis=-1)
        u = np.stack([ux, uy], axis=-1)
        Rp = (sigma_range**2 * er[..., :, None] * er[..., None, :]
              + s_az2[..., None, None] * et[..., :, None] * et[..., None, :]
              + var_f[..., None, None] * u[..., :, None] * u[..., None, :]
              + sigma_contour**2 * np.eye(2))
    kp = Rp.shape[-1]
    k = kp if sigma_doppler is None else kp + 1
    blocks = np.zeros((T, M, k, k))
    blocks[..., :kp, :kp] = Rp
    if sigma_doppler is not None:
        blocks[..., kp, kp] = np.where(det.doppler_mask(), sigma_doppler**2, 1.0)
    blocks[~det.valid] = np.eye(k)
    return blocks
