"""Semantic point-to-point factor of the joint registration: one shared SE(2) sensor pose, one
track state, the track's contour points matched to labelled map points.

Variables (all ``gtsam`` Vectors, so the marginal covariance is directly in these units):

* pose ``T = (tx, ty, phi)`` (m, m, rad): the SE(2) correction mapping the tracking frame C to
  the local frame L, ``q = R(phi) s + t``;
* track state ``x`` (26,) of :mod:`factors.state` in C;
* optionally a per-track lateral offset ``b`` (1,) (m): how far the track runs beside its
  target lines along their normals (a driver off the lane centre, a side seen more or less
  than the mean visible-side offset). It is the same for every point and frame of one track,
  so it carries the correlation of one vehicle's points (section "Correlation" of
  ``fgloc.registration.joint``).

Rows of one (track, frame) with ``m`` points: ``s_i(x) = c + u(theta_i + yaw) f(theta_i)``,
the track's contour at the fixed object-frame angles ``theta_i`` (rad) of the measured
detections (``f(theta_i)`` the GP conditional mean of the radii), and a correspondence
``p_i`` (m, L) with unit normal ``n_i`` of its target line. The residual of point i is the
point-to-point difference, whitened by its 2x2 square-root information ``A_i`` (1/m):

    r_i = A_i (R s_i(x) + t - p_i - b n_i)                 (2 rows)

With ``A_i = n_i n_i^T / sigma_n + t_i t_i^T / sigma_t`` (``t_i`` the line's tangent) it is
point-to-line for ``sigma_t = inf``: where on a lane a vehicle is says nothing about the pose.
Per-point robust weights (Huber on ``|r_i|``, recomputed at each evaluation) times the label
compatibility ``c_i`` (1 for the same label) scale the two rows of point i by ``sqrt(w_i c_i)``
inside the callback: a gtsam robust model on the stacked block would weigh the whole block.
The noise model is ``Unit`` (whitening is in ``A_i``). Jacobians are analytic, checked for
shape and finiteness in Python and handed to gtsam Fortran-ordered.

Depends only on numpy, gtsam and the ``factors`` modules (never on ``fgloc``).
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from factors.gp import ContourGP
from factors.gtsam_factors import _check_gp, _fortran, _state, huber_weights
from factors.measurement import contour_point, contour_point_jacobian
from factors.state import N_KIN, N_STATE, YAW, X, Y

#: symbol character of the per-track lateral offset keys
OFFSET_CHAR: str = "b"
#: parameter count of the pose variable (tx, ty, phi)
N_POSE: int = 3


def offset_key(track_id: int) -> int:
    """gtsam key of the lateral offset (1,) of track ``track_id``."""
    return int(gtsam.symbol(OFFSET_CHAR, int(track_id)))


def pose_matrix(pose: np.ndarray) -> np.ndarray:
    """3x3 SE(2) homogeneous matrix of ``(tx, ty, phi)``."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return np.array([[c, -s, pose[0]], [s, c, pose[1]], [0.0, 0.0, 1.0]])


def line_sqrt_info(normal: np.ndarray, sigma_n: float | np.ndarray,
                   sigma_t: float | np.ndarray = np.inf) -> np.ndarray:
    """(m, 2, 2) square-root informations ``n n^T / sigma_n + t t^T / sigma_t`` (1/m) of
    points on lines with unit normals (m, 2); sigmas scalar or per point (m,) (m);
    ``sigma_t = inf`` gives point-to-line."""
    n = np.asarray(normal, dtype=float)
    t = np.stack([-n[:, 1], n[:, 0]], axis=1)
    a = np.einsum("mi,mj->mij", n, n) / np.broadcast_to(sigma_n, n.shape[:1])[:, None, None]
    st = np.broadcast_to(sigma_t, n.shape[:1])
    if np.any(np.isfinite(st)):
        a = a + np.einsum("mi,mj->mij", t, t) / st[:, None, None]
    return a


@dataclass
class PointRows:
    """Whitened point-to-point rows of one track in one frame (module docstring).

    theta: (m,) object-frame contour angles (rad). target: (m, 2) correspondences p_i (m, L).
    normal: (m, 2) unit normals n_i of their lines (direction of the offset b). sqrt_info:
    (m, 2, 2) A_i (1/m). compat: (m,) label compatibilities in [0, 1]. huber_k: Huber
    threshold on ``|r_i|`` (whitened units; inf = none). gp: the contour model. H, mean:
    the GP conditional ``(m, n)`` and prior mean radius ``(m,)`` at theta, computed here
    unless given (they depend on theta only, so a caller may compute them once). weights:
    (m,) fixed per-point weights used instead of the per-evaluation Huber x compatibility
    (a caller doing IRLS rounds computes them once per round with :meth:`rows`, so the
    optimizer sees a smooth objective).
    """

    theta: np.ndarray
    target: np.ndarray
    normal: np.ndarray
    sqrt_info: np.ndarray
    compat: np.ndarray
    huber_k: float
    gp: ContourGP
    H: np.ndarray | None = None
    mean: np.ndarray | None = None
    weights: np.ndarray | None = None

    def __post_init__(self) -> None:
        _check_gp(self.gp)
        m = int(np.size(self.theta))
        shapes = {"theta": (np.shape(self.theta), (m,)),
                  "target": (np.shape(self.target), (m, 2)),
                  "normal": (np.shape(self.normal), (m, 2)),
                  "sqrt_info": (np.shape(self.sqrt_info), (m, 2, 2)),
                  "compat": (np.shape(self.compat), (m,))}
        for name, (got, want) in shapes.items():
            if got != want:
                raise ValueError(f"PointRows.{name} shape {got}, expected {want}")
        if m < 1:
            raise ValueError("PointRows needs at least one point")
        for name in ("theta", "target", "normal", "sqrt_info", "compat"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ValueError(f"PointRows.{name} is not finite")
        if np.any((self.compat < 0.0) | (self.compat > 1.0)):
            raise ValueError("PointRows.compat outside [0, 1]")
        if self.H is None or self.mean is None:
            self.H, _ = self.gp.conditional(self.theta)      # (m, n), fixed angles
            self.mean = self.gp.mean(self.theta)
        if self.weights is not None and (np.shape(self.weights) != (m,)
                                         or np.any(np.asarray(self.weights) < 0.0)):
            raise ValueError(f"PointRows.weights must be ({m},) and non-negative")
        if self.H.shape != (m, self.gp.n) or self.mean.shape != (m,):
            raise ValueError(f"PointRows.H / mean shapes {self.H.shape} / {self.mean.shape}, "
                             f"expected ({m}, {self.gp.n}) / ({m},)")

    @property
    def dim(self) -> int:
        """Residual rows (2 per point)."""
        return 2 * int(self.theta.shape[0])

    def points(self, x: np.ndarray) -> np.ndarray:
        """(m, 2) contour points s_i(x) in the tracking frame (m)."""
        radius = self.mean + (x[N_KIN:] - self.gp.mu) @ self.H.T
        return contour_point(x[[X, Y]], x[YAW], radius, self.theta)

    def rows(self, pose: np.ndarray, x: np.ndarray, b: float = 0.0,
             weights: np.ndarray | None = None, jacobian: bool = False
             ) -> tuple[np.ndarray, list[np.ndarray] | None, np.ndarray]:
        """Weighted residual (2m,), Jacobians ``[d/pose (2m, 3), d/x (2m, 26), d/b (2m, 1)]``
        if asked, and the per-point weights (m,) (robust x compatibility; recomputed from the
        unweighted residual unless given, so tests can freeze them)."""
        pose = np.asarray(pose, dtype=float)
        x = np.asarray(x, dtype=float)
        if pose.shape != (N_POSE,) or x.shape != (N_STATE,):
            raise ValueError(f"pose shape {pose.shape} / state shape {x.shape}, expected "
                             f"({N_POSE},) / ({N_STATE},)")
        one = (self.theta[None], self.H[None], self.mean[None], self.target[None],
               self.normal[None], self.sqrt_info[None])
        if weights is None:
            weights = self.weights
        if weights is None:
            r = point_rows_batch(pose, x[None], np.full((1, 1), b), *one,
                                 np.ones((1, len(self.theta))), self.gp.mu)[0][0]
            weights = huber_weights(np.linalg.norm(r, axis=1), self.huber_k) * self.compat
        e, J = point_rows_batch(pose, x[None], np.full((1, 1), b), *one,
                                np.asarray(weights, dtype=float)[None], self.gp.mu, jacobian)
        if not jacobian:
            return e.reshape(-1), None, weights
        return e.reshape(-1), [J[0].reshape(-1, N_POSE), J[1].reshape(-1, N_STATE),
                               J[2].reshape(-1, 1)], weights


def point_rows_batch(pose: np.ndarray, x: np.ndarray, b: np.ndarray, theta: np.ndarray,
                     H: np.ndarray, mean: np.ndarray, target: np.ndarray, normal: np.ndarray,
                     sqrt_info: np.ndarray, weights: np.ndarray, gp_mu: np.ndarray,
                     jacobian: bool = False
                     ) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray] | None]:
    """The rows of :class:`PointRows` for F frames of K points each at once (padding points
    get weight 0): pose (3,), states x (F, 26), offsets b (F, K) or (F, 1) (m, of each
    point along its normal; 0 without), angles theta
    (F, K), GP conditional H (F, K, n) and mean (F, K), targets (F, K, 2) and normals
    (F, K, 2) in L, sqrt_info (F, K, 2, 2), fixed weights (F, K), prior mean radii gp_mu (n,).
    Returns the weighted residual (F, K, 2) and, with ``jacobian``, its derivatives w.r.t. the
    pose (F, K, 2, 3), the state (F, K, 2, 26) and the point's offset (F, K, 2)."""
    radius = mean + np.einsum("fkn,fn->fk", H, x[:, N_KIN:] - gp_mu)
    s = contour_point(x[:, [X, Y]], x[:, YAW], radius, theta)            # (F, K, 2)
    c, sn = np.cos(pose[2]), np.sin(pose[2])
    R = np.array([[c, -sn], [sn, c]])
    rs = s @ R.T
    d = rs + pose[:2] - target - b[..., None] * normal
    sw = np.sqrt(weights)[..., None]
    e = sw * (sqrt_info @ d[..., None])[..., 0]
    if not jacobian:
        return e, None
    dq_pose = np.zeros((*theta.shape, 2, N_POSE))
    dq_pose[..., 0, 0] = dq_pose[..., 1, 1] = 1.0
    dq_pose[..., 0, 2], dq_pose[..., 1, 2] = -rs[..., 1], rs[..., 0]
    js = contour_point_jacobian(x[:, YAW], radius, theta, H)              # (F, K, 2, 3 + n)
    dq_x = np.zeros((*theta.shape, 2, N_STATE))
    dq_x[..., [X, Y, YAW]] = R @ js[..., :3]
    dq_x[..., N_KIN:] = R @ js[..., 3:]
    scale = sw[..., None] * sqrt_info                                     # (F, K, 2, 2)
    return e, (scale @ dq_pose, scale @ dq_x, -(scale @ normal[..., None])[..., 0])


def point_to_point_factor(pose_key: int, state_key: int, rows: PointRows,
                          offset: int | None = None) -> gtsam.CustomFactor:
    """One ``CustomFactor`` for all points of one track in one frame: keys ``[pose_key
    (Vector 3), state_key (Vector 26)]`` plus ``offset`` (a Vector 1 key, see
    :func:`offset_key`) when given, residual :meth:`PointRows.rows` with a ``Unit`` noise
    model. Shapes are checked in Python before gtsam sees them (``ValueError``)."""
    dim = rows.dim
    shapes = [(dim, N_POSE), (dim, N_STATE), (dim, 1)]
    keys = [int(pose_key), int(state_key)] + ([int(offset)] if offset is not None else [])

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list) -> np.ndarray:
        ks = this.keys()
        pose = np.asarray(values.atVector(ks[0]), dtype=float)
        if pose.shape != (N_POSE,):
            raise ValueError(f"point_to_point_factor: pose of key {ks[0]} has shape "
                             f"{pose.shape}, expected ({N_POSE},)")
        x = _state(values, ks[1], "point_to_point_factor")
        b = float(values.atVector(ks[2])[0]) if len(ks) == 3 else 0.0
        e, J, _ = rows.rows(pose, x, b, jacobian=H is not None)
        if H is not None:
            for i in range(len(ks)):
                H[i] = _fortran(J[i], shapes[i], "point_to_point_factor")
        return e

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(dim), keys, error)
