"""The coarse stage's modes carried to the end: every mode's final fit scored on the same data,
the best one chosen, and an honest ``ambiguous`` status when the data cannot tell them apart.

The coarse stage keeps every distinct pose that fits the lane centres almost as well as the
best one (:func:`fgloc.coarse.localize.coarse_modes`; typically shifts of a lane width along or
across the roads under sparse traffic). Each later method registers every mode (reusing the tracks
placed by the best mode, moved rigidly by the mode's start) and hands its final poses here:

* **Same data, same cost**: each pose ``T_k`` (C -> L) is scored on the same tracked
  detections (the method's labelled source cloud, frame C) against the same kind of target
  (the lane centre lines of each point's label shifted towards mode k's sensor) with the
  robust cost ``rho(d) = min(d, c)^2 / c^2`` (``coarse.mode_cost_scale`` c), summed per track;
  a vehicle's point is scored against the lanes of its driving direction
  (``sicp.direction_gate_deg``).
* **Choice**: the mode of least total cost; when the result is ambiguous, the reported
  one of the tied modes is the one of highest posterior under the user's approximate
  position as a prior (:class:`PositionPrior`): least ``max(z_k, 0)^2 + |p_k - a|^2 /
  sigma^2`` (``z_k`` below, ``p_k`` the mode's position, ``a`` sensor.toml's approx_position,
  sigma ``coarse.approx_position_sigma``), both read as ``-2 log`` of a likelihood ratio and of
  the prior.
* **Valley**: where the data are indifferent along a road (nothing turns) the tied modes are
  samples of a continuum, and where the samples stop says nothing (robustness "combined",
  T-junction seed 4: four modes 2.8-10.7 m from the truth, all on one side of it). Tied modes
  on one line are scanned along it with the test that tied them (:func:`track_valley`; icp:
  the coarse stage's :attr:`~fgloc.coarse.CoarseResult.valley`); the reported pose is then the
  posterior mean along the valley and the covariance spans it (:mod:`fgloc.coarse.valley`,
  :func:`fgloc.pipeline.valley_result`).
* **Height**: a final pose takes the z (and its std. dev.) of the coarse mode nearest to where
  it ended (:func:`height_mode`), which need not be the one it started from.
* **Told apart?** The points of one vehicle share its errors, so the evidence against mode k
  is counted per track: ``D_j`` = track j's cost under k minus under the best mode, read as
  ``z_k`` standard errors by :func:`separation_z` (``coarse.tie_test``: the self-normalized
  ``sum_j D_j / sqrt(sum_j D_j^2)``, about N(0, 1) when k fits as well but at most sqrt(k)
  when k tracks carry the difference; "robust", the default, also an absolute scale from the
  median track, so a few concordant turning tracks count against many indifferent straight
  ones). Mode k is ruled out when ``z_k >= coarse.mode_z``; otherwise the result is
  ``status = "ambiguous"``.
* **Lane models**: where a two-way street is mapped as one lanelet, the coarse stage gives
  its modes in both lane models (:mod:`fgloc.map.lane_models`); each is registered against
  its own model's targets and scored against them, and the two models compete like any two
  modes (a model is ruled out by the tracks' fit, or the result is ambiguous).
* **Starts kept**: a refinement of a mode (the joint's, started from SICP's fit) ends where
  it ends, but moving from its start is not evidence against the start: in a direction the
  cost hardly observes (all traffic on one straight road, nothing turning) the refinements
  of several tied starts slide along the valley into one pose, which must not read as
  "resolved". So a start that ended farther than the mode separation from every final fit
  stays a mode at its own pose with its own cost (``origin = "start"``), compared with the
  best final fit like any other (:func:`choose_mode`'s ``starts``).
* **Pinned to the tolerance?** One mode left is not yet a resolved pose: where only a few
  vehicles fix a direction (a T-junction's main road, fixed by the turning ones) the data
  may not pin the pose to the accuracy asked. When the reported covariance's std. dev. along
  its least determined horizontal direction exceeds ``coarse.resolved_max_std``, the result
  is ``ambiguous`` too (:class:`WeakDirection`), with that covariance (icp, filter-sicp,
  smoother-sicp; the joint's conservative covariance is held to its own, wider
  ``joint.resolved_max_std`` and reports weak directions below it as a warning,
  :func:`fgloc.registration.joint.joint_from_tracks`).
* **Ambiguous**: the reported pose is the selected mode's (above), and the covariance covers
  every mode not ruled out: ``mean_k (C_k + e_k e_k^T)``, ``e_k`` the mode's (x, y, yaw) minus the
  reported one and ``C_k`` its own covariance (where the method has one), so the truth at any
  of them lies within about ``sqrt(number of modes)`` standard deviations.
* **Tied but agreeing**: fits of two lane models stay two modes however near they end (above),
  so they may tie 0.1 m apart (the example map's junction 6: the keep-right and the
  centre-lane fit). Tied modes that all lie within the mode separation of the reported one
  count as one resolved pose when the covariance that covers them (above) passes the
  tolerance (:meth:`ModeChoice.agreeing`; for every method, the joint too: its own
  covariance is not judged when one mode is left, but two tied ones must agree to it with
  it). The reported pose, the covering covariance and the tied flags stay; the status is
  ``resolved``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from fgloc.coarse.localize import same_pose
from fgloc.coarse.valley import Valley, find_valley
from fgloc.config import CoarseConfig, Config
from fgloc.geo import LocalFrame, pose_from_se3, se2_to_se3, transform_points, wrap_angle
from fgloc.labels import NAMES
from fgloc.map import approx_position_local
from fgloc.map.lane_models import KEEP_RIGHT, other_model_note
from fgloc.registration.sicp import ALL, SemanticTargets, label_compatibility
from fgloc.registration.source import SourceCloud

if TYPE_CHECKING:
    from fgloc.coarse import CoarseMode, CoarseResult
    from fgloc.scenario import Scenario

RESOLVED = "resolved"
AMBIGUOUS = "ambiguous"


@dataclass
class ModeFit:
    """One mode's final fit.

    T_fine: 3x3 SE(2) C -> L of the final registration; T_local: 4x4 S -> L of the pose.
    covariance: 3x3 of the sensor's (x [m], y [m], yaw [rad]) in L, or None. track_cost: (J,)
    robust cost per track (the order of :func:`track_costs`'s ids, the same for every mode of
    one run). lane_score: the coarse mode's lane-centre score (a slip start's fit carries that
    of the fit it was turned from). converged: the registration's. start: 3x3 SE(2) C -> L,
    the start it was registered from: the coarse mode's (:attr:`fgloc.coarse.CoarseMode.start`)
    or a slip start (:func:`fgloc.registration.slip.slip_starts`).
    z_std: std. dev. (m) of the height (T_local's z, that of the coarse mode), or None.
    lanes: the lane model of two-way streets it was registered with
    (:mod:`fgloc.map.lane_models`). origin: "final" (a method's own fit) or "start" (the fit a
    refinement started from, kept because the refinement moved away from it without ruling
    it out; module docstring).
    """

    T_fine: np.ndarray
    T_local: np.ndarray
    covariance: np.ndarray | None
    track_cost: np.ndarray
    lane_score: float
    converged: bool
    start: np.ndarray
    z_std: float | None = None
    lanes: str = KEEP_RIGHT
    origin: str = "final"

    @property
    def cost(self) -> float:
        return float(self.track_cost.sum())

    @property
    def sensor(self) -> np.ndarray:
        """(x, y, yaw) of the sensor in L (m, m, rad)."""
        return np.array([self.T_local[0, 3], self.T_local[1, 3],
                         np.arctan2(self.T_local[1, 0], self.T_local[0, 0])])


def height_mode(coarse: CoarseResult, T_local: np.ndarray) -> CoarseMode | None:
    """The coarse mode whose sensor position lies nearest (in the plane) to ``T_local``'s
    (4x4 S -> L), whose height (z, z_std) a final pose there takes; None without modes.

    Each mode's height is the vertical fit at its own planar pose (a mode a lane away stands on
    other road heights). A registration started from one mode may end at another's pose (a
    start in a flat valley creeps to where the data fit: T-junction, 20 vehicles per minute,
    seed 5, a start 5 m away ended 0.09 m from the truth) and must then take the height
    fitted there, not its start's (2.1 m off in that run)."""
    if not coarse.modes:
        return None
    dist = [np.hypot(*(m.pose2d[:2] - T_local[:2, 3])) for m in coarse.modes]
    return coarse.modes[int(np.argmin(dist))]


def placed_where_ended(coarse: CoarseResult, T_local: np.ndarray
                       ) -> tuple[np.ndarray, float | None]:
    """A final pose ``T_local`` (4x4 S -> L) with the height of :func:`height_mode` and that
    height's std. dev. (m); without coarse modes ``T_local`` as it is and ``coarse.z_std``."""
    near = height_mode(coarse, T_local)
    return (T_local, coarse.z_std) if near is None else (near.placed(T_local), near.z_std)


def track_costs(src: SourceCloud, targets: SemanticTargets, T: np.ndarray, scale: float,
                gate_deg: float = 180.0, compat: np.ndarray | None = None) -> np.ndarray:
    """Summed robust cost ``min(d, scale)^2 / scale^2`` per track (ordered by track id) of the
    source points moved by T (3x3 C -> L); d is the distance (m) to the nearest target point
    of a label compatible with the point's, divided by the square root of that compatibility
    (``compat``, source x target label, :func:`fgloc.registration.sicp.label_compatibility`
    as SICP matches; None: the identity, only the point's own label), of any label when the
    target has none of the compatible ones, and, where the source and the target carry driving
    directions and ``gate_deg`` < 180, of a direction within ``gate_deg`` of the point's (as
    SICP matches, ``sicp.direction_gate_deg``: a vehicle is scored against the lanes of its
    direction, so a lane model with more lines per street does not fit the other direction's
    vehicles better)."""
    xy = transform_points(T, src.xy)
    directed = (src.direction is not None and targets.direction is not None
                and gate_deg < 180.0)
    heading = src.direction @ T[:2, :2].T if directed else None
    min_cos = float(np.cos(np.deg2rad(gate_deg)))
    compat = np.eye(len(NAMES)) if compat is None else np.asarray(compat, float)
    d = np.full(len(xy), np.inf)
    for code in np.unique(src.label):
        sel = np.flatnonzero(src.label == code)
        keys = [(t, float(c)) for t, c in enumerate(compat[int(code)])
                if c > 0.0 and targets.count(t)] or [(ALL, 1.0)]
        for key, c in keys:
            if targets.count(key):
                dk = targets.nearest(key, xy[sel], scale * np.sqrt(c),
                                     None if heading is None else heading[sel], min_cos)[0]
                d[sel] = np.minimum(d[sel], dk / np.sqrt(c))
    rho = np.minimum(d, scale) ** 2 / scale**2
    _, inv = np.unique(src.track_id, return_inverse=True)
    return np.bincount(inv.reshape(-1), weights=rho)


def mode_track_costs(src: SourceCloud, targets: SemanticTargets, T: np.ndarray,
                     cfg: Config) -> np.ndarray:
    """:func:`track_costs` as every method compares its modes: ``coarse.mode_cost_scale``,
    ``sicp.direction_gate_deg`` and the labels matched as ``sicp.mode`` matches them."""
    return track_costs(src, targets, T, cfg.coarse.mode_cost_scale,
                       cfg.sicp.direction_gate_deg, label_compatibility(cfg.sicp))


def separation_z(worse: np.ndarray, best: np.ndarray, noise_floor: float | None = None
                 ) -> float:
    """Standard errors by which per-track costs ``best`` beat ``worse`` (same tracks), from
    ``D = worse - best``; 0 when they agree exactly.

    Self-normalized (``noise_floor`` None): ``sum D / sqrt(sum D^2)``, about N(0, 1) when the
    differences are symmetric about 0, at most ``sqrt(k)`` when k tracks carry them. With a
    ``noise_floor`` (cost units, :func:`track_costs`) the larger of that and a robust z with
    an absolute scale: the sum of D without the track that favours ``best`` most, over
    ``sqrt(n - 1) s``; ``s`` = 1.4826 median |D| (the spread of an indifferent track's
    difference, the median track taken as one), at least ``noise_floor``. So two tracks that
    fit ``worse`` far worse than the rest differ count against it however many others are
    indifferent (a road's turning tracks against its straight ones), one alone does not
    (fewer than 3 tracks: self-normalized only)."""
    diff = np.asarray(worse, float) - np.asarray(best, float)
    norm = float(np.sqrt((diff**2).sum()))
    z = float(diff.sum() / norm) if norm > 0.0 else 0.0
    if noise_floor is None or len(diff) < 3:
        return z
    s = max(1.4826 * float(np.median(np.abs(diff))), noise_floor)
    return max(z, float(diff.sum() - diff.max()) / (np.sqrt(len(diff) - 1.0) * s))


def tie_z(worse: np.ndarray, best: np.ndarray, cfg: CoarseConfig) -> float:
    """:func:`separation_z` as the modes are compared (``coarse.tie_test``,
    ``coarse.tie_noise_floor``)."""
    return separation_z(worse, best, cfg.tie_noise_floor if cfg.tie_test == "robust" else None)


def distinct(fit: ModeFit, others: list[ModeFit], cfg: CoarseConfig,
             yaw_deg: float | None = None) -> bool:
    """Whether ``fit`` lies at least ``mode_separation`` m or ``yaw_deg`` (default
    ``mode_separation_deg``) away from each of ``others`` of its lane model (a pose of its
    own, not one of theirs). Fits of
    two lane models are two hypotheses however near they end (the coarse stage keeps each
    model's modes apart too): on the example map's junction 5 the keep-right fit ended 0.05 m
    from the truth and the centre-lane fit 0.81 m away with a 1 % lower cost; merged, the
    truth was gone."""
    return not any(fit.lanes == k.lanes and same_pose(fit.sensor, k.sensor, cfg, yaw_deg)
                   for k in others)


def merge_modes(fits: list[ModeFit], cfg: CoarseConfig,
                yaw_deg: float | None = None) -> list[ModeFit]:
    """The fits best (least cost) first, without those that ended within
    ``mode_separation`` m and ``yaw_deg`` (default ``mode_separation_deg``) of a better one
    (the same pose)."""
    kept: list[ModeFit] = []
    for fit in sorted(fits, key=lambda f: f.cost):
        if distinct(fit, kept, cfg, yaw_deg):
            kept.append(fit)
    return kept


@dataclass(frozen=True)
class PositionPrior:
    """The user's approximate sensor position as a prior: xy (2,) in L (m), sigma (m) its
    std. dev. per axis."""

    xy: np.ndarray
    sigma: float


def position_prior(scn: Scenario, cfg: CoarseConfig) -> PositionPrior:
    """sensor.toml's approx_position in L with ``cfg.approx_position_sigma``."""
    return PositionPrior(approx_position_local(scn), cfg.approx_position_sigma)


@dataclass(frozen=True)
class WeakDirection:
    """The least determined horizontal direction of a pose the modes resolve, when the data
    do not pin it to the tolerance: direction (2,) unit vector in L, std (m) the sensor
    position's std. dev. along it, tolerance (m) the setting it exceeds (named by
    ``setting``)."""

    direction: np.ndarray
    std: float
    tolerance: float
    setting: str = "coarse.resolved_max_std"

    @property
    def heading_deg(self) -> float:
        """Grid heading of ``direction`` (deg CCW from east, in (-90, 90])."""
        h = float(np.rad2deg(np.arctan2(self.direction[1], self.direction[0])))
        return h - 180.0 if h > 90.0 else h + 180.0 if h <= -90.0 else h


def weak_direction(cov: np.ndarray | None, tolerance: float,
                   setting: str = "coarse.resolved_max_std") -> WeakDirection | None:
    """The :class:`WeakDirection` of the 3x3 covariance ``cov`` of (x, y, yaw) (m, m, rad):
    the eigenvector of its largest x-y eigenvalue when that std. dev. exceeds ``tolerance``
    (m; the config field ``setting``); None when it does not, or without a covariance."""
    if cov is None:
        return None
    vals, vecs = np.linalg.eigh(np.asarray(cov, float)[:2, :2])
    std = float(np.sqrt(max(vals[-1], 0.0)))
    return WeakDirection(vecs[:, -1], std, tolerance, setting) if std > tolerance else None


@dataclass
class ModeChoice:
    """The comparison of merged fits, the reported one first (the least cost, or when
    ambiguous the tied mode :func:`choose_mode` selects with the prior): z (M,) standard errors
    by which the least-cost fit beats each (0 for itself); tied: indices of the modes not ruled
    out (the reported one included); status "resolved" (only one, or tied ones that agree,
    pinned to the tolerance) or "ambiguous". valley: the line the tied modes are samples of
    (:mod:`fgloc.coarse.valley`), or None; with one the reported pose is its posterior mean
    (:meth:`reported`), not the first fit's. weak: the direction in which the only mode left is
    not pinned to the tolerance (:meth:`with_tolerance`), or None. agreed: the tied modes count
    as one resolved pose (:meth:`agreeing`)."""

    fits: list[ModeFit]
    z: np.ndarray
    tied: list[int]
    valley: Valley | None = None
    weak: WeakDirection | None = None
    agreed: bool = False

    @property
    def status(self) -> str:
        one = len(self.tied) == 1 or (self.agreed and self.valley is None)
        return RESOLVED if one and self.weak is None else AMBIGUOUS

    def agreeing(self, cfg: CoarseConfig) -> ModeChoice:
        """The same comparison, ``agreed`` (resolved) when there are tied modes, all within
        ``cfg.mode_separation`` m and ``mode_separation_deg`` of the reported one, and the
        covariance covering them (:meth:`covariance`) is pinned to ``cfg.resolved_max_std``
        (no :func:`weak_direction`; module docstring)."""
        if len(self.tied) < 2 or self.valley is not None:
            return self
        if not all(same_pose(self.fits[k].sensor, self.best.sensor, cfg) for k in self.tied):
            return self
        return replace(self, agreed=weak_direction(self._covering(cfg),
                                                   cfg.resolved_max_std) is None)

    def with_tolerance(self, tolerance: float, setting: str = "coarse.resolved_max_std",
                       require_covariance: bool = False) -> ModeChoice:
        """The same comparison, ambiguous when one mode is left but its covariance's std. dev.
        along the least determined horizontal direction exceeds ``tolerance`` (m; the config
        field ``setting``), or, with ``require_covariance`` (a method whose fit has one), when
        the data give it none (too few matched points, or a geometry that fixes no pose: one
        straight track): a :class:`WeakDirection` of infinite std. dev. and no direction."""
        if len(self.tied) != 1:
            return self
        if require_covariance and self.best.covariance is None:
            return replace(self, weak=WeakDirection(np.full(2, np.nan), np.inf, tolerance,
                                                    setting))
        return replace(self, weak=weak_direction(self.best.covariance, tolerance, setting))

    @property
    def best(self) -> ModeFit:
        """The reported fit."""
        return self.fits[0]

    def selected_by(self, prior: PositionPrior | None,
                    lane_z: Mapping[str, float] | None = None) -> ModeChoice:
        """The same comparison with the tied mode of highest posterior under ``prior`` first
        (module docstring); ``lane_z``: lane model -> standard errors by which another
        model's evidence beats it (:mod:`fgloc.registration.lane_evidence`; missing: 0), one
        more independent term of each mode's score. Unchanged when resolved, or without a
        prior and lane evidence."""
        if len(self.tied) == 1 or (prior is None and not lane_z):
            return self
        lane_z = lane_z or {}
        score = [max(float(self.z[k]), 0.0) ** 2
                 + max(float(lane_z.get(self.fits[k].lanes, 0.0)), 0.0) ** 2
                 + (0.0 if prior is None else
                    float(np.sum((self.fits[k].sensor[:2] - prior.xy) ** 2)) / prior.sigma**2)
                 for k in self.tied]
        pick = self.tied[int(np.argmin(score))]
        order = [pick, *(k for k in range(len(self.fits)) if k != pick)]
        return ModeChoice([self.fits[k] for k in order], self.z[order],
                          sorted(order.index(k) for k in self.tied), self.valley)

    def reported(self) -> np.ndarray:
        """(x, y, yaw) of the reported sensor pose in L (m, m, rad): the valley's posterior
        mean with its yaw, else the first fit's."""
        if self.valley is None:
            return self.best.sensor
        return np.array([*self.valley.point(self.valley.posterior()[0]), self.valley.yaw])

    def covariance(self, cfg: CoarseConfig) -> np.ndarray | None:
        """The best mode's covariance when one mode is resolved; else (also when tied modes
        agree) the covering one (module docstring), about the reported pose (None when resolved
        without a covariance). A mode without a covariance of its own counts with the mode
        set's resolution, half the separation (``cfg.mode_separation`` m,
        ``mode_separation_deg``) as std. dev. With a valley, the variance along it is the
        posterior's (plus that resolution) instead of the modes' spread along it. None also for
        one mode left without the covariance its method requires (:meth:`with_tolerance`): the
        data give none."""
        if len(self.tied) == 1 and (self.status == RESOLVED or not np.isfinite(self.weak.std)):
            return self.best.covariance
        acc = self._covering(cfg)
        if self.valley is None:
            return acc
        res = self._resolution(cfg)
        u = self.valley.direction
        B = np.array([[u[0], u[1], 0.0], [-u[1], u[0], 0.0], [0.0, 0.0, 1.0]])
        along = B @ acc @ B.T               # rows / columns: along, across, yaw
        along[0, :] = along[:, 0] = 0.0
        along[0, 0] = self.valley.posterior()[1] + res[0] ** 2
        return B.T @ along @ B

    @staticmethod
    def _resolution(cfg: CoarseConfig) -> np.ndarray:
        """The mode set's resolution (m, m, rad): half the mode separation."""
        return 0.5 * np.array([cfg.mode_separation, cfg.mode_separation,
                               np.deg2rad(cfg.mode_separation_deg)])

    def _covering(self, cfg: CoarseConfig) -> np.ndarray:
        """``mean_k (C_k + e_k e_k^T)`` over the tied modes about the reported pose (module
        docstring; ``C_k`` the resolution's when the mode has none)."""
        centre = self.reported()
        floor = np.diag(np.square(self._resolution(cfg)))
        acc = np.zeros((3, 3))
        for k in self.tied:
            e = self.fits[k].sensor - centre
            e[2] = wrap_angle(e[2])
            own = self.fits[k].covariance
            acc += np.outer(e, e) + (floor if own is None else own)
        return acc / len(self.tied)

    def summary(self, frame: LocalFrame) -> list[dict[str, object]]:
        """JSON-ready modes, best first: world pose, cost, z, tied, lane score, std. devs."""
        out = []
        for k, fit in enumerate(self.fits):
            x, y, z, yaw, _, _ = pose_from_se3(frame.pose_to_world(fit.T_local))
            cov = fit.covariance
            out.append({
                "x": x, "y": y, "z": z, "yaw_deg": float(np.rad2deg(yaw)),
                "z_std_m": fit.z_std,
                "cost": fit.cost if len(fit.track_cost) else None, "separation_z": float(self.z[k]),
                "selected": k == 0, "tied": k in self.tied,
                "coarse_lane_score": fit.lane_score, "converged": fit.converged,
                "lanes": fit.lanes, "origin": fit.origin,
                "std": None if cov is None else {
                    "x_m": float(np.sqrt(cov[0, 0])), "y_m": float(np.sqrt(cov[1, 1])),
                    "yaw_deg": float(np.rad2deg(np.sqrt(cov[2, 2])))},
            })
        return out

    def valley_summary(self, frame: LocalFrame) -> dict[str, object] | None:
        """JSON-ready valley: its ends (world x, y), heading (deg CCW from grid east),
        length (m) and which end the prior bounds rather than the data; None without one."""
        v = self.valley
        if v is None:
            return None
        ends = []
        for s in (v.lo, v.hi):
            x, y = frame.to_world(v.point(s)[None])[0]
            ends.append({"x": float(x), "y": float(y)})
        return {"from": ends[0], "to": ends[1],
                "heading_deg": float(np.rad2deg(np.arctan2(v.direction[1], v.direction[0]))),
                "length_m": float(v.hi - v.lo),
                "bounded_by_prior": {"from": bool(v.open_lo), "to": bool(v.open_hi)}}

    def weak_summary(self, frame: LocalFrame) -> dict[str, object] | None:
        """JSON-ready weak direction: heading (deg CCW from grid east), the std. dev. (m) along
        it, the tolerance it exceeds and the ends (world x, y) of the reported position +-2
        std. devs. along it; None without one or without a covariance."""
        w = self.weak
        if w is None or not np.isfinite(w.std):
            return None
        ends = frame.to_world(self.reported()[:2] + np.outer([-2.0, 2.0], w.std * w.direction))
        return {"heading_deg": w.heading_deg, "std_m": w.std, "tolerance_m": w.tolerance,
                "from": {"x": float(ends[0, 0]), "y": float(ends[0, 1])},
                "to": {"x": float(ends[1, 0]), "y": float(ends[1, 1])}}

    def warnings(self, method: str) -> list[str]:
        """The ambiguity warning (none when one mode is resolved; a note of the tie when tied
        modes agree)."""
        if self.status == RESOLVED and len(self.tied) == 1:
            return []
        if self.weak is not None and not np.isfinite(self.weak.std):
            return [f"{method}: ambiguous pose: the data give no covariance (fewer than 3 "
                    "matched points, or a geometry that fixes no pose, such as one straight "
                    "track): nothing pins the pose to the tolerance "
                    f"{self.weak.setting} = {self.weak.tolerance:g} m"]
        if self.weak is not None:
            w = self.weak
            return [f"{method}: ambiguous pose: the position along {w.heading_deg:.0f} deg "
                    f"(grid) is determined only to {w.std:.2f} m (std. dev.), more than the "
                    f"tolerance {w.setting} = {w.tolerance:g} m: the data do not pin "
                    "it (few vehicles fix that direction); the covariance says how far it may "
                    "be off"]
        if self.valley is not None:
            v = self.valley
            heading = float(np.rad2deg(np.arctan2(v.direction[1], v.direction[0])))
            ends = ("both ends set by the prior" if v.open_lo and v.open_hi
                    else "one end set by the data, the other by the prior"
                    if v.open_lo or v.open_hi else "both ends set by the data")
            return [f"{method}: ambiguous pose: the position along {heading:.0f} deg (grid) is "
                    f"not determined: every pose over {v.hi - v.lo:.1f} m along it fits the data "
                    f"alike ({len(self.tied)} tied modes lie on it; {ends}); the "
                    "reported one is where the approximate position puts it, with a covariance "
                    "over that extent"]
        c = self.best.sensor
        parts = [f"{np.hypot(*(self.fits[k].sensor[:2] - c[:2])):.1f} m / "
                 f"{np.rad2deg(abs(wrap_angle(self.fits[k].sensor[2] - c[2]))):.1f} deg "
                 f"(z {self.z[k]:.1f}{other_model_note(self.fits[k].lanes, self.best.lanes)})"
                 for k in self.tied[1:]]
        if self.status == RESOLVED:
            return [f"{method}: tied modes agree: {len(self.tied)} modes fit the data alike "
                    f"(the reported one and {'; '.join(parts)} away), all pinned to the tolerance "
                    "coarse.resolved_max_std: resolved, the covariance covers them all"]
        return [f"{method}: ambiguous pose: {len(self.tied)} modes fit the data alike (the "
                f"reported one and {'; '.join(parts)} away); the covariance covers them all"]


def coarse_choice(coarse: CoarseResult, cfg: CoarseConfig,
                  prior: PositionPrior | None = None) -> ModeChoice:
    """The coarse stage's modes as they stand (the icp method): the lane-centre scores cannot
    rule a mode out (they are all within ``mode_margin``), so more than one is ambiguous (the
    reported one selected by ``prior``). The best mode carries the covariance of its lane-score
    tie (:attr:`fgloc.coarse.CoarseResult.tie_covariance`), which decides whether one mode is
    pinned to ``cfg.resolved_max_std`` (:meth:`ModeChoice.with_tolerance`)."""
    fits = [ModeFit(m.start, m.placed(se2_to_se3(m.start) @ coarse.T_coarse),
                    coarse.tie_covariance if k == 0 else None, np.zeros(0), m.lane_score,
                    coarse.converged, m.start, m.z_std, m.lanes)
            for k, m in enumerate(coarse.modes)]
    choice = ModeChoice(fits, np.zeros(len(fits)), list(range(len(fits))))
    return choice.selected_by(prior).agreeing(cfg).with_tolerance(cfg.resolved_max_std)


def choose_mode(fits: list[ModeFit], cfg: CoarseConfig,
                starts: list[ModeFit] | None = None,
                prior: PositionPrior | None = None, tolerance: bool = True,
                require_covariance: bool = False,
                merge_deg: float | None = None,
                lane_z: Mapping[str, float] | None = None) -> ModeChoice:
    """Merge the fits, pick the least cost and rule out modes by ``cfg.mode_z`` (module
    docstring). ``starts``: the fits the ``fits`` were refined from (their track costs on the
    same tracks); each one distinct from every merged fit is added after them as a mode of
    its own (``origin = "start"``), so the best final fit must rule it out. ``prior``: selects
    the reported mode of an ambiguous result (:meth:`ModeChoice.selected_by`). ``tolerance``:
    whether one mode left must also be pinned to ``cfg.resolved_max_std``
    (:meth:`ModeChoice.with_tolerance`, with ``require_covariance``; the joint's is False: it
    applies its own, see :func:`fgloc.registration.joint.joint_from_tracks`). ``merge_deg``:
    the yaw (deg) within which ``fits`` merge (None: ``cfg.mode_separation_deg``; the fine
    stage passes ``[fine] merge_deg``, :mod:`fgloc.registration.slip`). ``lane_z``: lane
    model -> standard errors by which another model's evidence beats it
    (:mod:`fgloc.registration.lane_evidence`; missing: 0, at least one model 0): the fits and
    starts of a model beaten by ``cfg.mode_z`` are ruled out, a weaker z is weighed in the
    selection (:meth:`ModeChoice.selected_by`)."""
    lane_z = lane_z or {}
    if lane_z:
        fits, starts = ([f for f in group if lane_z.get(f.lanes, 0.0) < cfg.mode_z]
                        for group in (fits, starts or []))
    merged = merge_modes(fits, cfg, merge_deg)
    merged += [replace(s, origin="start") for s in merge_modes(starts or [], cfg)
               if distinct(s, merged, cfg)]
    best = merged[0].track_cost
    z = np.array([tie_z(f.track_cost, best, cfg) for f in merged])
    tied = [k for k in range(len(merged)) if k == 0 or z[k] < cfg.mode_z]
    choice = ModeChoice(merged, z, tied).selected_by(prior, lane_z).agreeing(cfg)
    return choice.with_tolerance(cfg.resolved_max_std,
                                 require_covariance=require_covariance) if tolerance else choice


def track_valley(choice: ModeChoice, cost_at: Callable[[ModeFit, np.ndarray], np.ndarray],
                 prior: PositionPrior, cfg: CoarseConfig) -> Valley | None:
    """The valley of an ambiguous comparison of final fits (:mod:`fgloc.coarse.valley`), or
    None (resolved, tied modes of two lane models, or not samples of one line). The line
    passes through the least-cost tied fit with its yaw; a pose on it ties when that fit does
    not beat it by ``cfg.mode_z`` (:func:`separation_z` of the per-track costs
    ``cost_at(fit, T)`` against ``cost_at(fit, fit.T_fine)``: T the 3x3 SE(2) C -> L of the
    pose, scored against the targets of ``fit``'s mode) -- the test that tied the modes, under
    one scoring (not against ``fit.track_cost``: a joint fit may carry its start's costs)."""
    if choice.status == RESOLVED or len({choice.fits[k].lanes for k in choice.tied}) > 1:
        return None
    tied = [choice.fits[k] for k in choice.tied]
    at = min(range(len(tied)), key=lambda k: tied[k].cost)
    ref = tied[at]
    base = cost_at(ref, np.array(ref.T_fine, dtype=float))

    def z_at(xy: np.ndarray) -> float:
        T = np.array(ref.T_fine, dtype=float)
        T[:2, 2] += xy - ref.sensor[:2]
        return tie_z(cost_at(ref, T), base, cfg)

    poses = np.array([f.sensor for f in tied])
    return find_valley(poses, at, prior.xy, prior.sigma, cfg, z_at)

