"""Semantic ICP (SICP) in SE(2) (paper III-C, IV-B) and plain ICP as its label-blind case.

The labelled source points (trajectory points, frame C) are registered to the labelled target
points (road points, frame L); the result ``T`` maps source points into the target frame. Labels
are the codes of :mod:`fgloc.labels` (straight, left, right).

Algorithm (one call of :func:`sicp`)
------------------------------------
1. Label groups. A label with source points but fewer than ``min_points_per_label`` source or
   target points is dropped with a warning; its source and target points take no part. In mode
   "none" all points form one group (one KD-tree over every target point).
2. Correspondences, vectorized per target label (at most three KD-tree queries, each over the
   source points allowed to match that label), within the current maximum distance ``r``:

   * "hard": a source point is matched only within its own label (compatibility = identity);
   * "soft": every target label whose compatibility ``c`` with the source label is positive is
     searched; the candidate of least cost ``d^2 / c`` wins (an incompatible target point looks
     ``1/sqrt(c)`` times farther away) and enters the alignment with weight ``c`` (it also
     pulls less). This is a heuristic, not one consistent objective: on clean data starting
     near the solution it agrees with "hard";
   * "none": plain point-to-point ICP.
3. Alignment: the closed-form weighted 2D Procrustes (Kabsch) solution for the current pairs,
   with weights = user weights x compatibility x the matched target point's weight (if the
   target has weights) x robust-kernel weight of the current residual (iteratively reweighted
   least squares; Huber ``min(1, k/d)``, Cauchy ``1/(1 + (d/k)^2)``).
4. Schedule: ``r`` starts at ``max_correspondence`` (50 m) and is multiplied by ``range_decay``
   per iteration down to ``min_correspondence``. Converged when, with ``r`` at its floor for two
   consecutive iterations, the inlier RMSE changes by less than ``rmse_tol`` and the last
   alignment moved the pose by less than ``step_tol`` / ``step_tol_deg`` (along a weakly
   observed direction ICP creeps while the RMSE hardly changes); otherwise the call stops
   after ``max_iterations`` alignments (``converged = False``). At the floor, a creep (two
   alignments the same way, shrinking) is extrapolated to the end of its geometric series
   (``accelerate``) where that lowers the trimmed matching cost.

Uncertainty
-----------
At the solution, for every inlier i (transformed point ``q_i = R p_i + t``, residual
``r_i = q_i - y_i``, alignment weight ``w_i`` normalised to mean 1),
``J_i = [[1, 0, -(R p_i)_y], [0, 1, (R p_i)_x]]`` is the Jacobian of ``q_i`` w.r.t. the
parameters (tx, ty, yaw) of ``T = se2(tx, ty, yaw)`` and

    information = sum_i w_i J_i^T W_i J_i / sigma^2,
    sigma^2 = max(sum_i w_i |r_i|^2 / (2 n - 3), sigma_floor^2)   (per-axis residual variance).

``W_i`` (2x2, largest eigenvalue 1) shapes the point-to-point weight by the target's local
spread: with ``C_i`` the covariance of the target points of the matched label in a square
window of half-width ``info_window`` around the match, ``W_i = (l_min + e) (C_i + e I)^-1``
(``l_min`` the smaller eigenvalue of C_i, ``e = sigma_floor^2``): isotropic neighbourhoods give
``W_i = I`` (plain point-to-point), a lane strip gives little weight along the lane. The window
sums come from summed-area tables of the target's point moments on a grid of cell
``info_window / 4`` (at least 0.5 m; window edges snap to it), built once per label and cached
in :class:`SemanticTargets`, so the cost does not grow with the window. Holding correspondences
fixed, a plain ``J^T J`` would report sliding along a straight road as well determined as any
other direction; ``W_i`` makes that degeneracy visible. ``covariance`` is its inverse (None when
singular). ``degeneracy`` analyses the information re-expressed in metres: translation of the
inlier centroid and rotation about it as arc length at the inliers' RMS radius, so rotation and
translation are comparable and not mixed through the lever arm to the frame origin.

That covariance treats every point as independent; the points of one vehicle are not (a
driver off the lane centre, a side seen more or less than the target's offset moves all of
them), so it is far too small (NEES 14 on sparse traffic). :func:`track_covariance` is the
calibrated one the methods report: SICP's solution linearized point to line, its errors
modelled with one common offset per track (a track's many points count as one offset's worth,
not their number), and the cluster-robust sandwich over the tracks, never below that model
(as the joint's, :func:`track_robust_covariance`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from fgloc.geo import se2, transform_points
from fgloc.labels import NAMES
from fgloc.registration.config import KERNELS, MODES, SicpConfig
from fgloc.registration.considered import bias_columns, least_squares_consider, side_sign

#: Key of the KD-tree over all target points (mode "none").
ALL: int = -1
#: Smallest grid cell (m) of the summed-area tables of the target moments.
_MIN_CELL: float = 0.5
#: Nearest target points searched per source point when directions gate the candidates.
_DIRECTED_K: int = 32
#: Above this condition number the information matrix counts as singular (no covariance).
_SINGULAR_COND: float = 1e12


@dataclass
class SemanticTargets:
    """Labelled target points with one KD-tree per label, each built once, on first use.

    xy: (M, 2) float64 m in the target frame. label: (M,) int64 label codes. direction: None, or
    (M, 2) unit driving directions in the target frame (lanes: a source point with a direction
    is then matched to a lane driven its way, :func:`sicp`). weight: None, or (M,) weights in
    [0, 1] that multiply the alignment weight of every source point matched to each target
    point (lanes: how sure the map is of where the lane lies there). lane: None, or (M,) int
    id of the lane each target point lies on (lanes: :attr:`LaneCentres.lane`), for the
    per-lane bias :func:`track_covariance` considers. Reuse one object across :func:`sicp`
    calls against the same target to build its trees only once.
    """

    xy: np.ndarray
    label: np.ndarray
    direction: np.ndarray | None = None
    weight: np.ndarray | None = None
    lane: np.ndarray | None = None
    _trees: dict[int, tuple[np.ndarray, cKDTree]] = field(
        default_factory=dict, init=False, repr=False
    )
    _moments: dict[tuple[int, float], _Moments] = field(
        default_factory=dict, init=False, repr=False
    )

    @classmethod
    def build(cls, xy: np.ndarray, label: np.ndarray, direction: np.ndarray | None = None,
              weight: np.ndarray | None = None, lane: np.ndarray | None = None
              ) -> SemanticTargets:
        """Validate and wrap target points (M, 2), labels (M,), optional unit driving
        directions (M, 2), optional weights (M,) in [0, 1] and optional lane ids (M,); trees
        come lazily."""
        xy = np.asarray(xy, dtype=np.float64)
        label = np.asarray(label, dtype=np.int64).reshape(-1)
        if xy.ndim != 2 or xy.shape[1] != 2 or xy.shape[0] != label.shape[0]:
            raise ValueError(f"target_xy must be (M, 2) matching target_label (M,), got "
                             f"{xy.shape} and {label.shape}")
        if direction is not None:
            direction = np.asarray(direction, dtype=np.float64)
            if direction.shape != xy.shape:
                raise ValueError(f"target direction must be (M, 2) like target_xy, got "
                                 f"{direction.shape}")
        if weight is not None:
            weight = np.asarray(weight, dtype=np.float64)
            if weight.shape != label.shape or not np.all((weight >= 0.0) & (weight <= 1.0)):
                span = (f"from {np.nanmin(weight):g} to {np.nanmax(weight):g}"
                        if weight.size and not np.isnan(weight).any() else "NaN values")
                raise ValueError(f"target weight must be {label.shape} values in [0, 1], got "
                                 f"shape {weight.shape}, {span}")
        if lane is not None:
            lane = np.asarray(lane, dtype=np.int64)
            if lane.shape != label.shape:
                raise ValueError(f"target lane must be (M,) like target_label, got {lane.shape}")
        return cls(xy, label, direction, weight, lane)

    def count(self, code: int) -> int:
        """Number of target points of label ``code`` (ALL: every point)."""
        return int(self.xy.shape[0]) if code == ALL else int(np.count_nonzero(self.label == code))

    def tree(self, code: int) -> tuple[np.ndarray, cKDTree]:
        """(indices into xy, KD-tree over those points) of label ``code`` (ALL: every point)."""
        if code not in self._trees:
            idx = np.arange(self.xy.shape[0]) if code == ALL else np.flatnonzero(self.label == code)
            self._trees[code] = (idx, cKDTree(self.xy[idx]))
        return self._trees[code]

    def nearest(self, code: int, xy: np.ndarray, rmax: float, heading: np.ndarray | None = None,
                min_cos: float = -1.0) -> tuple[np.ndarray, np.ndarray]:
        """Distance (n,) (m; inf: none) and index (n,) into ``xy``'s target points (only
        meaningful where the distance is finite) of the nearest target point of label ``code``
        (ALL: any) within ``rmax`` m of each point ``xy`` (n, 2). With ``heading`` (n, 2) (unit
        directions in the target frame; needs target directions) only target points whose
        direction has a cosine above ``min_cos`` with it are candidates: the nearest such among
        the :data:`_DIRECTED_K` nearest (a point nearer to many samples of wrong-way lanes than
        to any of its own lane has none)."""
        idx, tree = self.tree(code)
        if heading is None:
            d, j = tree.query(xy, distance_upper_bound=rmax)
            return d, idx[np.minimum(j, len(idx) - 1)]
        kk = min(_DIRECTED_K, len(idx))
        dk, jk = tree.query(xy, k=kk, distance_upper_bound=rmax)
        dk, jk = dk.reshape(len(xy), kk), jk.reshape(len(xy), kk)
        found = np.isfinite(dk)
        jk = idx[np.where(found, jk, 0)]
        cos = np.einsum("nkj,nj->nk", self.direction[jk], heading)
        dk = np.where(found & (cos > min_cos), dk, np.inf)
        first = np.argmin(dk, axis=1)
        return dk[np.arange(len(xy)), first], jk[np.arange(len(xy)), first]

    def moments(self, code: int, cell: float) -> _Moments:
        """Summed-area tables of the moments of label ``code``'s points on a grid of ``cell`` m."""
        key = (code, cell)
        if key not in self._moments:
            pts = self.xy if code == ALL else self.xy[self.label == code]
            self._moments[key] = _Moments.build(pts, self.xy.min(axis=0), cell,
                                                self.xy.max(axis=0))
        return self._moments[key]


@dataclass
class _Moments:
    """Summed-area tables (6, nx + 1, ny + 1) of 1, x, y, xx, xy, yy of points binned on a grid
    of ``cell`` m anchored at ``origin`` (2,); coordinates relative to origin."""

    origin: np.ndarray
    cell: float
    table: np.ndarray

    @classmethod
    def build(cls, pts: np.ndarray, origin: np.ndarray, cell: float, top: np.ndarray) -> _Moments:
        shape = np.floor((top - origin) / cell).astype(np.int64) + 1
        rel = pts - origin
        ij = np.floor(rel / cell).astype(np.int64)
        flat = ij[:, 0] * shape[1] + ij[:, 1]
        x, y = rel[:, 0], rel[:, 1]
        table = np.zeros((6, shape[0] + 1, shape[1] + 1))
        for k, v in enumerate((np.ones_like(x), x, y, x * x, x * y, y * y)):
            grid = np.bincount(flat, v, shape[0] * shape[1]).reshape(shape)
            table[k, 1:, 1:] = grid.cumsum(axis=0).cumsum(axis=1)
        return cls(origin, cell, table)

    def covariance(self, xy: np.ndarray, half: float) -> tuple[np.ndarray, ...]:
        """(sxx, sxy, syy) of the points in the square window of half-width ``half`` m (snapped
        to the grid) around each of xy (n, 2), which must lie inside the grid."""
        h = int(round(half / self.cell))
        ij = np.floor((xy - self.origin) / self.cell).astype(np.int64)
        nx, ny = self.table.shape[1] - 1, self.table.shape[2] - 1
        i0, i1 = np.clip(ij[:, 0] - h, 0, nx), np.clip(ij[:, 0] + h + 1, 0, nx)
        j0, j1 = np.clip(ij[:, 1] - h, 0, ny), np.clip(ij[:, 1] + h + 1, 0, ny)
        t = self.table
        n, sx, sy, sxx, sxy, syy = t[:, i1, j1] - t[:, i0, j1] - t[:, i1, j0] + t[:, i0, j0]
        mx, my = sx / n, sy / n
        return sxx / n - mx * mx, sxy / n - mx * my, syy / n - my * my


@dataclass
class Degeneracy:
    """Eigen-analysis of the information in metric coordinates (u, v, a) about ``centre``.

    centre: (2,) m, weighted centroid of the matched source points in the target frame.
    radius: m, their weighted RMS distance from it; ``a = radius * yaw`` (arc length, m).
    eigenvalues: (3,) ascending, 1/m^2. eigenvectors: (3, 3) unit columns in (u, v, a).
    condition_number: largest / smallest eigenvalue (inf when the smallest is <= 0).
    weakest_direction: (3,) unit (du, dv, da) of the smallest eigenvalue (largest variance).
    """

    centre: np.ndarray
    radius: float
    eigenvalues: np.ndarray
    eigenvectors: np.ndarray
    condition_number: float
    weakest_direction: np.ndarray


@dataclass
class SicpResult:
    """Outcome of :func:`sicp`.

    T: 3x3 SE(2), source frame -> target frame. fitness: share of all source points with a
    correspondence within ``final_range`` (m). inlier_rmse: RMS distance (m) of those pairs.
    iterations: alignments performed. converged: stopped on the RMSE criterion (False on the
    iteration limit or for lack of correspondences). stop_reason: "rmse_converged",
    "max_iterations" or "too_few_correspondences". label_counts: label name -> number of
    matched source points of that label. information: 3x3 of (tx, ty, yaw) (1/m^2, 1/(m rad),
    1/rad^2), see the module docstring; covariance: its inverse or None when singular;
    degeneracy: None without correspondences. sigma: residual std. dev. (m) used there.
    target_index: (N,) index into the target of each source point's final match, -1 if none.
    weights: (N,) final alignment weight of each source point (0 if unmatched).
    dropped_labels: names of labels dropped for too few points; warnings: why.
    """

    T: np.ndarray
    fitness: float
    inlier_rmse: float
    iterations: int
    converged: bool
    stop_reason: str
    label_counts: dict[str, int]
    information: np.ndarray
    covariance: np.ndarray | None
    degeneracy: Degeneracy | None
    sigma: float
    final_range: float
    target_index: np.ndarray
    weights: np.ndarray
    dropped_labels: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


@dataclass
class _Groups:
    """Label groups of one call: target label codes searched, each source point's group."""

    codes: list[int]
    source_group: np.ndarray
    compat: np.ndarray
    dropped: list[str]
    warnings: list[str]


@dataclass
class _Matches:
    """Correspondences: target index (-1 none), distance (m), compatibility, tree group."""

    index: np.ndarray
    dist: np.ndarray
    compat: np.ndarray
    group: np.ndarray

    @property
    def ok(self) -> np.ndarray:
        return self.index >= 0


def check_config(cfg: SicpConfig) -> None:
    """Raise ValueError naming the first invalid SicpConfig field."""
    try:
        compat = np.asarray(cfg.compatibility, dtype=float)
    except ValueError:  # ragged rows
        compat = np.zeros(0)
    problems = {
        "mode": cfg.mode not in MODES,
        "kernel": cfg.kernel not in KERNELS,
        "compatibility": compat.shape != (len(NAMES), len(NAMES))
        or bool(np.any((compat < 0.0) | (compat > 1.0))),
        "max_correspondence": not cfg.max_correspondence > 0.0,
        "min_correspondence": not 0.0 < cfg.min_correspondence <= cfg.max_correspondence,
        "range_decay": not 0.0 < cfg.range_decay <= 1.0,
        "max_iterations": cfg.max_iterations < 0,
        "rmse_tol": cfg.rmse_tol < 0.0,
        "step_tol": cfg.step_tol < 0.0,
        "step_tol_deg": cfg.step_tol_deg < 0.0,
        "kernel_scale": not cfg.kernel_scale > 0.0,
        "min_points_per_label": cfg.min_points_per_label < 1,
        "sigma_floor": not cfg.sigma_floor > 0.0,
        "offset_sigma_floor": cfg.offset_sigma_floor < 0.0,
        "info_window": cfg.info_window < 0.0,
        "direction_gate_deg": not 0.0 < cfg.direction_gate_deg <= 180.0,
    }
    bad = [k for k, v in problems.items() if v]
    if bad:
        raise ValueError(f"invalid sicp config field {bad[0]}: {getattr(cfg, bad[0])!r}")


def label_compatibility(cfg: SicpConfig) -> np.ndarray:
    """3x3 compatibility (source label x target label, codes of :mod:`fgloc.labels`) of the
    correspondences of ``cfg.mode``: identity ("hard"), ``cfg.compatibility`` ("soft"), all
    ones ("none")."""
    if cfg.mode == "none":
        return np.ones((len(NAMES), len(NAMES)))
    return np.eye(len(NAMES)) if cfg.mode == "hard" else np.asarray(cfg.compatibility, float)


def _groups(source_label: np.ndarray, targets: SemanticTargets, cfg: SicpConfig) -> _Groups:
    """Label groups, dropped labels and the compatibility matrix (source code x group)."""
    n_min = cfg.min_points_per_label
    if cfg.mode == "none":
        ok = source_label.size >= n_min and targets.count(ALL) >= n_min
        warn = [] if ok else [f"fewer than {n_min} source or target points: no registration"]
        group = np.full(source_label.shape, 0 if ok else -1, dtype=np.int64)
        return _Groups([ALL] if ok else [], group, np.ones((1, 1)), [], warn)
    unknown = np.setdiff1d(source_label, list(NAMES))
    if unknown.size:
        raise ValueError(f"unknown source label codes {unknown.tolist()}")
    codes, dropped, warnings = [], [], []
    for code in sorted(NAMES):
        n_src, n_tgt = int(np.count_nonzero(source_label == code)), targets.count(code)
        if 0 < n_src and (n_src < n_min or n_tgt < n_min):
            dropped.append(NAMES[code])
            warnings.append(f"label {NAMES[code]!r} dropped: {n_src} source / {n_tgt} target "
                            f"points (< min_points_per_label = {n_min})")
        elif n_tgt >= n_min:
            codes.append(code)
    compat = label_compatibility(cfg)
    kept = np.array([NAMES[c] not in dropped for c in sorted(NAMES)])
    group = np.where(kept[source_label], source_label, -1)
    return _Groups(codes, group, compat[:, codes], dropped, warnings)


def _match(moved: np.ndarray, g: _Groups, targets: SemanticTargets, rmax: float,
           heading: np.ndarray | None = None, min_cos: float = -1.0) -> _Matches:
    """Least-cost (d^2 / compatibility) correspondence of every source point within rmax (m).
    With ``heading`` (n, 2) (unit directions in the target frame) only target points of a
    direction within the gate are candidates (:meth:`SemanticTargets.nearest`)."""
    n = moved.shape[0]
    index, group = np.full(n, -1, dtype=np.int64), np.full(n, -1, dtype=np.int64)
    dist, compat, cost = np.full(n, np.inf), np.zeros(n), np.full(n, np.inf)
    src = np.flatnonzero(g.source_group >= 0)
    for k, code in enumerate(g.codes):
        c_all = g.compat[g.source_group[src], k]
        q = src[c_all > 0.0]
        d, j = targets.nearest(code, moved[q], rmax, None if heading is None else heading[q],
                               min_cos)
        c = c_all[c_all > 0.0]
        better = np.isfinite(d) & (d * d / c < cost[q])
        q, d, j, c = q[better], d[better], j[better], c[better]
        index[q], dist[q], compat[q], cost[q], group[q] = j, d, c, d * d / c, k
    return _Matches(index, dist, compat, group)


def kernel_weights(d: np.ndarray, kernel: str, scale: float) -> np.ndarray:
    """IRLS weights of residual distances d (m): none 1, Huber min(1, k/d), Cauchy 1/(1+(d/k)^2)."""
    if kernel == "huber":
        return np.minimum(1.0, scale / np.maximum(d, 1e-300))
    if kernel == "cauchy":
        return 1.0 / (1.0 + (d / scale) ** 2)
    return np.ones_like(d)


def weighted_procrustes(p: np.ndarray, q: np.ndarray, w: np.ndarray) -> np.ndarray:
    """3x3 SE(2) minimising sum w |T p - q|^2 over pairs of points p, q (n, 2), weights w (n,)."""
    w = w / w.sum()
    pc, qc = w @ p, w @ q
    h = (p - pc).T @ ((q - qc) * w[:, None])
    ang = float(np.arctan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1]))
    c, s = np.cos(ang), np.sin(ang)
    t = qc - np.array([[c, -s], [s, c]]) @ pc
    return se2(t[0], t[1], ang)


def _shape_weights(
    target_idx: np.ndarray, group: np.ndarray, g: _Groups, targets: SemanticTargets,
    cfg: SicpConfig,
) -> np.ndarray:
    """(n, 2, 2) weight matrices W_i from the matched label's target spread (module docstring)."""
    n = target_idx.size
    out = np.broadcast_to(np.eye(2), (n, 2, 2)).copy()
    if cfg.info_window <= 0.0:
        return out
    eps = cfg.sigma_floor**2
    cell = max(cfg.info_window / 4.0, _MIN_CELL)
    for k, code in enumerate(g.codes):
        sel = np.flatnonzero(group == k)
        cxx, cxy, cyy = targets.moments(code, cell).covariance(targets.xy[target_idx[sel]],
                                                               cfg.info_window)
        lmin = (cxx + cyy) / 2.0 - np.hypot((cxx - cyy) / 2.0, cxy)
        a, c = cxx + eps, cyy + eps
        scale = (np.maximum(lmin, 0.0) + eps) / (a * c - cxy * cxy)
        inv = np.stack([np.stack([c, -cxy], -1), np.stack([-cxy, a], -1)], -2)
        out[sel] = inv * scale[:, None, None]
    return out


def _degeneracy(info: np.ndarray, T: np.ndarray, moved: np.ndarray, w: np.ndarray) -> Degeneracy:
    """Eigen-analysis of the information in metric coordinates about the inlier centroid."""
    centre = (w @ moved) / w.sum()
    radius = float(np.sqrt(w @ np.sum((moved - centre) ** 2, axis=1) / w.sum()))
    radius = max(radius, 1e-9)
    lever = T[:2, 2] - centre
    # (tx, ty, yaw) = A (u, v, a): translating the centroid by (u, v) and turning by a / radius
    a_mat = np.array([[1.0, 0.0, -lever[1] / radius], [0.0, 1.0, lever[0] / radius],
                      [0.0, 0.0, 1.0 / radius]])
    vals, vecs = np.linalg.eigh(a_mat.T @ info @ a_mat)
    cond = float(vals[-1] / vals[0]) if vals[0] > 0.0 else float("inf")
    return Degeneracy(centre, radius, vals, vecs, cond, vecs[:, 0])


def _information(
    T: np.ndarray, moved: np.ndarray, target_xy: np.ndarray, w: np.ndarray,
    shape: np.ndarray, sigma_floor: float,
) -> tuple[np.ndarray, float]:
    """3x3 information of (tx, ty, yaw) and the residual std. dev. (m) (module docstring)."""
    n = moved.shape[0]
    w = w / w.mean()
    res2 = np.sum((moved - target_xy) ** 2, axis=1)
    sigma2 = max(float(w @ res2) / (2 * n - 3), sigma_floor**2) if n > 1 else sigma_floor**2
    rot = moved - T[:2, 2]
    jac = np.zeros((n, 2, 3))
    jac[:, 0, 0] = jac[:, 1, 1] = 1.0
    jac[:, 0, 2], jac[:, 1, 2] = -rot[:, 1], rot[:, 0]
    info = np.einsum("n,nia,nij,njb->ab", w, jac, shape, jac) / sigma2
    return info, float(np.sqrt(sigma2))


#: Largest extrapolation, in steps of the last alignment (Besl & McKay 1992 cap theirs at 25).
_MAX_EXTRAPOLATION: float = 25.0
#: Consecutive alignments pointing within this angle (deg) of each other are extrapolated.
_SAME_WAY_DEG: float = 10.0


def _extrapolation(now: np.ndarray, last: np.ndarray, centre: np.ndarray, turn: float
                   ) -> np.ndarray | None:
    """The rest of a creep (accelerated ICP, after Besl & McKay 1992): when the last two
    alignments at the floor range, ``last`` then ``now`` (each the move (m) of the matched
    points' centroid and its turn as arc length at their RMS radius), point the same way
    (within ``_SAME_WAY_DEG``) and shrink by the ratio ``r < 1``, the iterations go on as a
    geometric series: ``r / (1 - r)`` more steps like ``now`` (at most
    ``_MAX_EXTRAPOLATION``), returned as one 3x3 transform in the target frame that turns by
    that many times ``turn`` (rad) about ``centre`` (the centroid after ``now``, (2,) m) and
    moves it that many times ``now``'s move. None when they do not."""
    a, b = float(np.linalg.norm(now)), float(np.linalg.norm(last))
    if a == 0.0 or b == 0.0 or a >= b:
        return None
    if now @ last < np.cos(np.deg2rad(_SAME_WAY_DEG)) * a * b:
        return None
    k = min(a / (b - a), _MAX_EXTRAPOLATION)
    c, s = np.cos(k * turn), np.sin(k * turn)
    R = np.array([[c, -s], [s, c]])
    out = np.eye(3)
    out[:2, :2] = R
    out[:2, 2] = centre - R @ centre + k * now[:2]
    return out


def sicp(
    source_xy: np.ndarray,
    source_label: np.ndarray,
    target_xy: np.ndarray | SemanticTargets,
    target_label: np.ndarray | None,
    T0: np.ndarray,
    cfg: SicpConfig,
    *,
    weights: np.ndarray | None = None,
    source_direction: np.ndarray | None = None,
) -> SicpResult:
    """Register labelled source points to labelled target points in SE(2) (module docstring).

    source_xy: (N, 2) m in the source frame; source_label: (N,) label codes. target_xy: (M, 2) m
    in the target frame with target_label (M,), or a prebuilt :class:`SemanticTargets` (then
    target_label is None) whose KD-trees are reused. T0: 3x3 initial source -> target
    transform. weights: optional (N,) non-negative per-point weights. source_direction:
    optional (N, 2) unit driving directions of the source points (source frame); with target
    directions and ``cfg.direction_gate_deg < 180`` a source point is matched only to target
    points whose direction lies within that angle of its own (rotated by the current pose): a
    vehicle is never registered to the lane of the other direction. Plain ICP is
    ``cfg.mode = "none"``. Raises ValueError on malformed input or config.
    """
    check_config(cfg)
    if isinstance(target_xy, SemanticTargets):
        if target_label is not None:
            raise ValueError("pass target_label=None with a prebuilt SemanticTargets")
        targets = target_xy
    else:
        targets = SemanticTargets.build(target_xy, target_label)
    src = np.asarray(source_xy, dtype=np.float64)
    lab = np.asarray(source_label, dtype=np.int64).reshape(-1)
    if src.ndim != 2 or src.shape[1] != 2 or src.shape[0] != lab.shape[0]:
        raise ValueError(f"source_xy must be (N, 2) matching source_label (N,), got {src.shape} "
                         f"and {lab.shape}")
    user_w = np.ones(src.shape[0]) if weights is None else np.asarray(weights, float).reshape(-1)
    if user_w.shape != lab.shape or np.any(user_w < 0.0):
        raise ValueError("weights must be (N,) and non-negative")
    g = _groups(lab, targets, cfg)
    directed = (source_direction is not None and targets.direction is not None
                and cfg.direction_gate_deg < 180.0)
    if directed:
        u_src = np.asarray(source_direction, dtype=np.float64)
        if u_src.shape != src.shape:
            raise ValueError(f"source_direction must be (N, 2) like source_xy, got {u_src.shape}")

    T = np.asarray(T0, dtype=np.float64).copy()
    rng, prev_rng, prev_rmse = cfg.max_correspondence, np.nan, np.nan
    stop, iterations = "max_iterations", 0
    moved_by, turned_by = np.inf, np.inf        # the last alignment's move (m) and turn (rad)
    last: np.ndarray | None = None              # the last alignment's (move, arc) at the floor
    min_cos = float(np.cos(np.deg2rad(cfg.direction_gate_deg)))

    ahead: _Matches | None = None               # matches at T made by the extrapolation test

    def match_at(T: np.ndarray, moved: np.ndarray | None = None) -> _Matches:
        """Correspondences of the source points moved by T (``moved``, when given)."""
        moved = transform_points(T, src) if moved is None else moved
        return _match(moved, g, targets, rng, u_src @ T[:2, :2].T if directed else None,
                      min_cos)

    def trimmed_cost(mm: _Matches) -> float:
        """sum_i w_i min(d_i^2 / c_i, r^2) of the matches ``mm`` (user weights w, matching
        cost d^2 / c; unmatched points at the range r): the objective an extrapolation must
        lower."""
        cost = np.where(mm.ok, mm.dist**2 / np.where(mm.ok, mm.compat, 1.0), rng**2)
        return float(np.sum(user_w * np.minimum(cost, rng**2)))

    while True:  # each pass matches at the current T and range, so m always belongs to T
        moved = transform_points(T, src)
        m = match_at(T, moved) if ahead is None else ahead
        ahead = None
        ok = m.ok & (user_w > 0.0)
        w_all = np.zeros(src.shape[0])
        w_all[ok] = user_w[ok] * m.compat[ok] * kernel_weights(m.dist[ok], cfg.kernel,
                                                               cfg.kernel_scale)
        if targets.weight is not None:
            w_all[ok] *= targets.weight[m.index[ok]]
        if np.count_nonzero(ok) < 3:
            stop = "too_few_correspondences"
            break
        rmse = float(np.sqrt(np.mean(m.dist[ok] ** 2)))
        settled = ((cfg.step_tol == 0.0 or moved_by < cfg.step_tol)
                   and (cfg.step_tol_deg == 0.0 or turned_by < np.deg2rad(cfg.step_tol_deg)))
        if rng == prev_rng and abs(rmse - prev_rmse) < cfg.rmse_tol and settled:
            stop = "rmse_converged"
            break
        if iterations == cfg.max_iterations:
            break
        step = weighted_procrustes(moved[ok], targets.xy[m.index[ok]], w_all[ok])
        centre = moved[ok].mean(axis=0)         # the move of the matched points' centroid
        move = step[:2, :2] @ centre + step[:2, 2] - centre
        turn = float(np.arctan2(step[1, 0], step[0, 0]))
        moved_by, turned_by = float(np.hypot(*move)), abs(turn)
        T = step @ T
        if cfg.accelerate and rng == prev_rng:
            radius = float(np.sqrt(np.mean(np.sum((moved[ok] - centre) ** 2, axis=1))))
            now = np.array([*move, turn * radius])
            extra = None if last is None else _extrapolation(now, last, centre + move, turn)
            if extra is None:
                last = now
            else:   # the range stays at its floor: the next pass reuses the chosen T's matches
                at_step, at_jump = match_at(T), match_at(extra @ T)
                if trimmed_cost(at_jump) < trimmed_cost(at_step):
                    T, ahead, last = extra @ T, at_jump, None
                else:
                    ahead, last = at_step, now
        iterations += 1
        prev_rng, prev_rmse = rng, rmse
        rng = max(cfg.min_correspondence, rng * cfg.range_decay)

    n_ok = int(np.count_nonzero(ok))
    counts = {name: int(np.count_nonzero(ok & (lab == code))) for code, name in NAMES.items()}
    info, sigma, cov, degen = np.zeros((3, 3)), float("nan"), None, None
    if n_ok >= 3 and w_all[ok].sum() > 0.0:
        shape = _shape_weights(m.index[ok], m.group[ok], g, targets, cfg)
        info, sigma = _information(T, moved[ok], targets.xy[m.index[ok]], w_all[ok], shape,
                                   cfg.sigma_floor)
        degen = _degeneracy(info, T, moved[ok], w_all[ok])
        cov = np.linalg.inv(info) if degen.condition_number < _SINGULAR_COND else None
    return SicpResult(
        T=T,
        fitness=n_ok / max(1, src.shape[0]),
        inlier_rmse=float(np.sqrt(np.mean(m.dist[ok] ** 2))) if n_ok else float("nan"),
        iterations=iterations,
        converged=stop == "rmse_converged",
        stop_reason=stop,
        label_counts=counts,
        information=info,
        covariance=cov,
        degeneracy=degen,
        sigma=sigma,
        final_range=rng,
        target_index=np.where(ok, m.index, -1),
        weights=w_all,
        dropped_labels=g.dropped,
        warnings=g.warnings,
    )


def clipped_below(cov: np.ndarray, floor: np.ndarray) -> np.ndarray:
    """``cov`` (G, G) raised to at least ``floor`` (G, G, positive definite) in every
    direction: its generalized eigenvalues relative to ``floor`` clipped from below at 1."""
    L = np.linalg.cholesky(0.5 * (floor + floor.T))
    A = np.linalg.solve(L, np.linalg.solve(L, cov).T)
    w, V = np.linalg.eigh(0.5 * (A + A.T))
    LV = L @ V
    return (LV * np.maximum(w, 1.0)) @ LV.T


def track_robust_covariance(info: np.ndarray, scores: np.ndarray,
                            prior_info: np.ndarray, n_params: float | None = None
                            ) -> np.ndarray:
    """Covariance (G, G) of the global parameters robust to errors shared within a track.

    info (G, G): their reduced information at the solution (``S``, the model covariance is
    ``S^-1``); scores (T, G): each track's point rows' share of their gradient there
    (:attr:`fgloc.registration.joint_solver.ArrowSystem.gp_track`; a track's own variables are
    stationary, so this is the track's whole influence); prior_info (G,): the prior's diagonal
    information. The cluster-robust sandwich ``S^-1 (c/(c-G) sum_t g_t g_t^T + P) S^-1`` over
    the c tracks with points counts how far the tracks actually disagree, whatever their
    points' noise and correlation; it is clipped from below at the model covariance
    (:func:`clipped_below`), so it never claims more than the factors' noise model.
    ``n_params``: the number of parameters the small-sample factor ``c/(c-G)`` counts
    (None: G; fewer where some are held mostly by their prior)."""
    G = len(info) if n_params is None else n_params
    model = np.linalg.inv(0.5 * (info + info.T))
    used = scores[np.any(scores != 0.0, axis=1)]
    c = len(used)
    meat = used.T @ used * (c / max(c - G, 1)) + np.diag(prior_info)
    return clipped_below(model @ meat @ model, model)


def track_covariance(res: SicpResult, source_xy: np.ndarray, track: np.ndarray,
                     targets: SemanticTargets, cfg: SicpConfig,
                     sensor_xy: np.ndarray | None = None) -> np.ndarray | None:
    """3x3 covariance of (tx, ty, yaw) of ``res.T`` that counts the evidence per track.

    source_xy (N, 2) m and track (N,) the id of the track each source point came from (the
    points of :func:`sicp`'s call); targets: its target, with driving directions (lane lines:
    each match's residual is taken along its lane's normal, point to line). SICP's solution
    is, linearized there, the weighted least-squares one ``dT = H^-1 sum_i w_i a_i r_i``,
    ``H = sum_i w_i a_i a_i^T`` (``r_i`` the residual along the normal, ``a_i`` its Jacobian
    w.r.t. (tx, ty, yaw), ``w_i`` the final alignment weight normalised to mean 1). Its
    errors are not independent: for the matched points i of track j, ``r_i = b_j + e_i``
    with a common offset ``b_j ~ N(0, tau^2)`` and ``e_i ~ N(0, sigma^2 / w_i)``. ``sigma^2``
    is the scatter of the residuals about their track's weighted mean, ``tau^2`` the spread
    of those means beyond what ``sigma`` explains (at least ``cfg.offset_sigma_floor^2``).
    The model covariance is then ``sigma^2 H^-1 + tau^2 H^-1 (sum_j u_j u_j^T) H^-1``,
    ``u_j = sum_{i in j} w_i a_i``: a track's points count as one offset's worth along their
    summed Jacobian, whatever their number. The reported one is the cluster-robust sandwich
    ``H^-1 (c/(c-3) sum_j s_j s_j^T) H^-1`` over the c tracks (``s_j = sum_{i in j} w_i a_i
    r_i``, centred: SICP minimises the point-to-point cost, so they need not sum to zero),
    which counts how far the tracks actually disagree, clipped from below at the model
    (:func:`clipped_below`). Both ignore errors the tracks share; the biases of
    :mod:`fgloc.registration.considered` are added to it: a constant shift of every point
    towards the sensor (``cfg.consider_side_bias_sigma``; needs the sensor's position
    ``sensor_xy`` (2,) m in the source frame) and one per lane (``cfg.consider_lane_bias_sigma``;
    needs ``targets.lane``). None without target directions, with fewer than 3 matched points
    or a singular ``H``."""
    ok = (res.target_index >= 0) & (res.weights > 0.0)
    if targets.direction is None or np.count_nonzero(ok) < 3:
        return None
    T, idx = res.T, res.target_index[ok]
    moved = transform_points(T, np.asarray(source_xy, float)[ok])
    d = targets.direction[idx]
    n = np.column_stack([-d[:, 1], d[:, 0]])
    arm = moved - T[:2, 2]
    a = np.column_stack([n[:, 0], n[:, 1], n[:, 1] * arm[:, 0] - n[:, 0] * arm[:, 1]])
    r = np.einsum("ij,ij->i", n, moved - targets.xy[idx])
    w = res.weights[ok] / res.weights[ok].mean()
    H = (w[:, None] * a).T @ a
    if np.linalg.cond(H) > _SINGULAR_COND:
        return None
    _, j = np.unique(np.asarray(track)[ok], return_inverse=True)
    j = j.reshape(-1)
    k = int(j.max()) + 1
    w_sum = np.bincount(j, w, k)
    mean = np.bincount(j, w * r, k) / w_sum
    sigma2 = max(float(w @ (r - mean[j]) ** 2) / max(len(r) - k, 1), cfg.sigma_floor**2)
    tau2 = max(float(np.mean(mean**2 - sigma2 / w_sum)), cfg.offset_sigma_floor**2)
    u = np.zeros((k, 3))
    np.add.at(u, j, w[:, None] * a)
    scores = np.zeros((k, 3))
    np.add.at(scores, j, (w * r)[:, None] * a)
    scores -= scores.mean(axis=0)
    Hi = np.linalg.inv(H)
    model = sigma2 * Hi + tau2 * Hi @ (u.T @ u) @ Hi
    sandwich = Hi @ (scores.T @ scores) @ Hi * (k / max(k - 3, 1))
    cov = clipped_below(sandwich, model)
    sign = np.zeros(len(r))                     # without the sensor: no side bias
    if sensor_xy is not None:
        sign = side_sign(targets.xy[idx], n,
                         transform_points(T, np.asarray(sensor_xy, float).reshape(1, 2))[0])
    columns, sd = bias_columns(sign, 0.0 if sensor_xy is None else cfg.consider_side_bias_sigma,
                               None if targets.lane is None else targets.lane[idx],
                               cfg.consider_lane_bias_sigma)
    return cov + least_squares_consider(H, w[:, None] * a, columns, sd) if len(sd) else cov
