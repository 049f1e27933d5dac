"""``--method joint``: one SE(2) sensor-pose correction shared by semantic point-to-point
factors, optimized jointly with every track state, with a calibrated covariance.

Pipeline: target cloud -> coarse pose -> GP-EOT tracks in C -> filter-sicp's registration
(the start, :func:`fgloc.registration.fine.register_tracks`) -> the joint graph below ->
``T_fine`` (C -> L) with its marginal covariance -> ``T_utm = T~_fine · T_coarse``.

The problem (frame C unless stated; the factor graph of docs/method.md section 7)
-------------------------------------------------------------------------------
* the track factors of :mod:`fgloc.smoothing.graph` (prior on each track's first state,
  process factors, stacked contour measurement factors) on every ``step_stride``-th step of
  every track used (``fine.n_trajectories`` / ``trajectory_share`` pick a seeded subset, the same
  one filter-sicp uses);
* the pose ``T = (tx, ty, phi)``: C -> L, started at SICP's result (or the coarse pose), with
  a loose prior at the coarse pose (``pose_prior_sigma``), so a direction no factor observes
  stays finite and shows up as weak instead of taking an arbitrary value;
* per track a lateral offset ``b`` (m) with prior ``N(0, offset_sigma^2)``;
* per (track, step) one point-to-point block (the rows of
  :func:`factors.registration_factors.point_to_point_factor`): the track's contour at the
  object-frame angles of up to ``max_points_per_frame`` of its detections in that frame (the
  sensor-aware angles of the filter's state, fixed), moved by ``T`` into L, against their
  correspondences on the lanelet centre lines (smoothed through lanelet joins,
  ``join_smoothing_length``, :mod:`fgloc.map.lane_joins`) shifted towards the sensor by
  ``coarse.visible_side_offset`` (filter-sicp's default target), point-to-line
  (``along_weight`` 0), each point weighted by its label compatibility and a per-point Huber
  weight inside the factor.

Rounds: correspondences are found for the current estimate with one KD-tree per label (built
once, :class:`fgloc.registration.sicp.SemanticTargets`; least ``d^2 / compatibility`` within
``max_correspondence``), the problem is optimized with a few Levenberg-Marquardt iterations,
the noise levels are re-estimated (``estimate_noise``), and this repeats until the pose moves
by less than ``tol_position`` / ``tol_yaw_deg`` or ``max_rounds``.

Solver: :mod:`fgloc.registration.joint_solver`, vectorized in numpy -- the track factors
as a quadratic model linearized once at the filter's states (``relinearize_tracks``), the
point rows of all frames evaluated in batched calls, and each Gauss-Newton system solved by
eliminating the banded track block (one banded Cholesky for all tracks) onto the pose and
the offsets. The same factors as gtsam CustomFactors (:func:`factors.registration_factors.
point_to_point_factor`, :func:`fgloc.smoothing.graph.build_track_graph`) give the same step
and the same pose marginal (tests); one Python callback per factor and linearization made the
gtsam optimization ~70x slower (docs/experiments.md).

Correlation and the covariance
------------------------------
The points of one vehicle are not independent: a driver off the lane centre, or a side seen
more or less than the mean visible-side offset, moves all of them together. The per-track
offset ``b`` carries that shared error: with it, one track's many points can fix its offset
but tell the pose only as much as one line measurement of std. dev. ``offset_sigma`` does,
and errors of the track shape are shared through its states. ``sigma_line`` (the residual
scatter about the offset line, a robust MAD estimate) and ``offset_sigma`` (RMS of the
estimated offsets) are re-estimated from the data each round, so the covariance follows the
data rather than a tuned constant. The tracker places far vehicles towards the sensor by an
amount that grows with range; a range-proportional side bias (``range_bias_sigma``, a global
parameter beside ``T``) takes it up instead of a rotation. A hand-mapped turn has two centre
lines (the arc-length construction and lanelet2's, up to 2 m apart); the targets lie midway
(``[map] centre_line``), one more global parameter, the centre-line share
(``centre_line_sigma``), moves them towards either, and half the distance between the two
adds to the point noise (``centre_ambiguity``). The model covariance is the
marginal covariance of ``T`` at the solution (the inverse of its Schur complement, equal to
``gtsam.Marginals`` on the equivalent graph); the reported one (``covariance =
"track-robust"``) is the cluster-robust sandwich over tracks, never below the model one
(:func:`fgloc.registration.sicp.track_robust_covariance`); both add the effect of a
constant side bias and of one lateral bias per lanelet that are considered, not estimated
(``consider_side_bias_sigma``, ``consider_lane_bias_sigma``,
:func:`fgloc.registration.considered.consider_covariance`),
and are mapped to the sensor's (x, y, yaw) in L. Their
calibration (NEES) is measured in docs/experiments.md.

Degeneracy report: the information of ``T`` (inverse marginal covariance) re-expressed in
metric coordinates about the matched points' centroid (translation, and rotation as arc length
at their RMS radius, as in :func:`fgloc.registration.sicp.sicp`); every eigen-direction whose
standard deviation exceeds ``weak_sigma`` is listed as weakly observed (on a straight road
without a junction: the along-road translation).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

from factors.gp import ContourGP
from factors.gtsam_factors import ContourMeasurement, huber_weights
from factors.registration_factors import line_sqrt_info
from fgloc.config import Config, MapConfig
from fgloc.errors import LocalizationError
from fgloc.geo import se2, se2_params, se2_to_se3, transform_points, wrap_angle
from fgloc.labels import NAMES
from fgloc.map.lane_models import min_width
from fgloc.progress import Timer
from fgloc.registration.considered import bias_columns, consider_covariance, side_sign
from fgloc.registration.joint_config import JointConfig, check_joint_config
from fgloc.registration.joint_solver import (
    PointSet,
    Priors,
    TrackQuadratic,
    joint_cost,
    linearize,
    solve_arrow,
)
from fgloc.registration.lane_bias import LaneBiases
from fgloc.registration.lane_evidence import decided_lane_model
from fgloc.registration.sicp import _degeneracy, track_robust_covariance
from fgloc.result import LocalizationResult, json_ready
from fgloc.scenario import TWO_WAY_MIN_WIDTH, Scenario, lane_ambiguity
from fgloc.smoothing.banded_lm import BandedLayout
from fgloc.tracks import N_KIN, N_STATE, YAW, Track, TrackSet, X, Y

if TYPE_CHECKING:
    from fgloc.coarse import CoarseResult
    from fgloc.map import TargetCloud


# ---- target lines ------------------------------------------------------------------------
@dataclass
class LaneLines:
    """Labelled, directed target lines in L: samples (M, 2) of the lanelet centre lines
    (optionally shifted sideways towards the sensor), their unit left normals (M, 2) -- the
    driving direction is ``(n_y, -n_x)`` --, label codes (M,), the index (M,) of the
    lanelet each sample belongs to (None: unknown; it groups the points whose lateral bias
    is considered per lanelet, ``consider_lane_bias_sigma``), the offset (M, 2) (m)
    between the two constructions of the centre line at each sample
    (:meth:`fgloc.scenario.Lanelet.centre`; None: 0) and the bend (M,) (m) of a lane bent
    into its neighbour's (:attr:`fgloc.coarse.icp.LaneCentres.bend`; None: 0). One KD-tree
    per label over ``(x, y, w cos psi, w sin psi)`` (psi the driving direction, ``w`` the
    heading weight in m) is built on first use and kept, so a vehicle is matched to a lane it
    drives along, not to a crossing one."""

    xy: np.ndarray
    normal: np.ndarray
    label: np.ndarray
    lane: np.ndarray | None = None
    centre_offset: np.ndarray | None = None
    bend: np.ndarray | None = None
    _trees: dict[tuple[int, float], tuple[np.ndarray, cKDTree]] = field(
        default_factory=dict, init=False, repr=False)

    @classmethod
    def build(cls, scn: Scenario, target: TargetCloud, step: float, sensor_xy: np.ndarray,
              offset: float, two_way_min_width: float = TWO_WAY_MIN_WIDTH,
              join_length: float = 0.0, centre: str = "resampled",
              labels: MapConfig | None = None) -> LaneLines:
        """Lane lines of the lanelets that hold target points (:meth:`LaneCentres.build`;
        labels mirrored on a lane driven against its lanelet, ``two_way_min_width`` sets the
        lane model of two-way lanelets),
        sampled every about ``step`` m and shifted ``offset`` m towards ``sensor_xy`` (2,) (0:
        the centre lines); ``lane`` is the index of each sample's lane line. ``join_length``
        > 0: each lane smoothed through its joins with the lanes before and after it with
        that steering length (m) (:func:`fgloc.map.lane_joins.smooth_lane_joins`); ``centre``:
        the kind of the lanelets' centre lines (``[map] centre_line``); ``labels``: how the
        samples are labelled (:func:`fgloc.registration.fine.lane_labels`)."""
        from fgloc.coarse import LaneCentres
        from fgloc.map.lane_joins import lane_keys, smooth_lane_joins
        from fgloc.registration.fine import lane_labels

        lanelets = target.lanelets(scn.lanelets)
        lanes = LaneCentres.of_target(target, scn.lanelets, step, two_way_min_width, centre)
        if join_length > 0.0 and len(lanes.xy):
            keys = lane_keys(lanelets, lanes.lanelet, lanes.against, lanes.lane)
            xy, normal = smooth_lane_joins(lanes.xy, lanes.lane, keys, join_length, step,
                                           scn.lanelets)
            lanes = dataclasses.replace(lanes, xy=xy, normal=normal)
        side = np.sign(np.einsum("ij,ij->i", np.asarray(sensor_xy) - lanes.xy, lanes.normal))
        return cls.of(lanes.xy + (offset * side)[:, None] * lanes.normal, lanes.normal,
                      lane_labels(target, lanelets, lanes, labels, scn.lanelets), lanes.lane,
                      lanes.centre_offset,
                      lanes.bend)

    @classmethod
    def of(cls, xy: np.ndarray, normal: np.ndarray, label: np.ndarray,
           lane: np.ndarray | None = None, centre_offset: np.ndarray | None = None,
           bend: np.ndarray | None = None) -> LaneLines:
        """Lines from samples (M, 2), unit left normals (M, 2), label codes (M,) and,
        optionally, the lanelet index (M,), the offset (M, 2) (m) between the centre
        line's two constructions of each sample and the bend (M,) (m) of each."""
        xy, normal = np.asarray(xy, dtype=float), np.asarray(normal, dtype=float)
        label = np.asarray(label, dtype=np.int64)
        lane = None if lane is None else np.asarray(lane, dtype=np.int64)
        off = None if centre_offset is None else np.asarray(centre_offset, dtype=float)
        bend = None if bend is None else np.asarray(bend, dtype=float)
        if (normal.shape != xy.shape or label.shape != (xy.shape[0],) or xy.ndim != 2
                or (lane is not None and lane.shape != label.shape)
                or (off is not None and off.shape != xy.shape)
                or (bend is not None and bend.shape != label.shape)):
            raise ValueError(f"LaneLines: xy {xy.shape}, normal {normal.shape}, label "
                             f"{label.shape}, lane {None if lane is None else lane.shape}, "
                             f"centre_offset {None if off is None else off.shape} and bend "
                             f"{None if bend is None else bend.shape} do not match")
        return cls(xy, normal, label, lane, off, bend)

    @property
    def ambiguity(self) -> np.ndarray | None:
        """(M,) how uncertain (m) it is where vehicles drive at each sample
        (:func:`fgloc.scenario.lane_ambiguity`: half the distance between the centre line's
        two constructions, a bend into a neighbouring lane); None without either."""
        if self.centre_offset is None and self.bend is None:
            return None
        return lane_ambiguity(len(self.xy), self.centre_offset, self.bend)

    def tree(self, code: int, weight: float) -> tuple[np.ndarray, cKDTree]:
        """(indices, KD-tree over (x, y, weight * direction)) of label ``code``."""
        key = (code, weight)
        if key not in self._trees:
            idx = np.flatnonzero(self.label == code)
            d = np.column_stack([self.normal[idx, 1], -self.normal[idx, 0]])
            self._trees[key] = (idx, cKDTree(np.hstack([self.xy[idx], weight * d])))
        return self._trees[key]

    def match(self, xy: np.ndarray, heading: np.ndarray, label: np.ndarray, other: float,
              rmax: float, weight: float) -> tuple[np.ndarray, np.ndarray]:
        """Correspondence of points xy (n, 2) (m, L) of vehicles heading ``heading`` (n,)
        (rad, L) with label codes (n,): the line index (-1 none) of least ``d^2 / c``, ``d``
        the distance in (x, y, weight * direction) within ``rmax``, over the labels with
        compatibility ``c > 0`` (1 for the same label, ``other`` otherwise), and that
        compatibility (0 without a match)."""
        n = len(xy)
        q = np.hstack([xy, weight * np.column_stack([np.cos(heading), np.sin(heading)])])
        index, compat, cost = np.full(n, -1, np.int64), np.zeros(n), np.full(n, np.inf)
        for code in NAMES:
            c_all = np.where(label == code, 1.0, other)
            sel = np.flatnonzero(c_all > 0.0)
            if sel.size == 0 or not np.any(self.label == code):
                continue
            idx, tree = self.tree(code, weight)
            d, j = tree.query(q[sel], distance_upper_bound=rmax)
            ok = np.isfinite(d)
            sel, d, j = sel[ok], d[ok], j[ok]
            c = c_all[sel]
            better = d * d / c < cost[sel]
            sel, d, j, c = sel[better], d[better], j[better], c[better]
            index[sel], compat[sel], cost[sel] = idx[j], c, d * d / c
        return index, compat


# ---- the points of the tracks ------------------------------------------------------------
def decimate(tracks: TrackSet, stride: int, min_steps: int) -> TrackSet:
    """Every ``stride``-th step of every track (with the detections of those steps only);
    tracks with fewer than ``min_steps`` steps left are dropped."""
    out = []
    for tr in tracks.tracks:
        keep = np.arange(0, len(tr), stride)
        if keep.size < min_steps:
            continue
        new_step = np.full(len(tr), -1, np.int64)
        new_step[keep] = np.arange(keep.size)
        sel = new_step[tr.det_step] >= 0
        out.append(Track(tr.id, tr.t[keep], tr.states[keep], tr.labels[keep],
                         None if tr.covariances is None else tr.covariances[keep],
                         tr.det_index[sel], new_step[tr.det_step[sel]],
                         standing=None if tr.standing is None else tr.standing[keep]))
    return dataclasses.replace(tracks, tracks=out)


@dataclass
class FramePoints:
    """The contour points of all (track, step) frames, stacked.

    frame_track / frame_step / frame_state: (F,) track index, step in the track and index of
    the state in the stacked steps of all tracks. start: (F + 1,) offsets of each frame's
    points. theta: (P,) object-frame angles (rad).
    label: (P,) label code of each point (its track's label at that step). H, mean: (P, n),
    (P,) GP conditional of each angle.
    """

    frame_track: np.ndarray
    frame_step: np.ndarray
    frame_state: np.ndarray
    start: np.ndarray
    theta: np.ndarray
    label: np.ndarray
    H: np.ndarray
    mean: np.ndarray

    @property
    def point_frame(self) -> np.ndarray:
        return np.repeat(np.arange(len(self.frame_state)), np.diff(self.start))

    def padded(self, width: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(index (F, width), valid (F, width))``: each frame's points as indices into the
        P points (padding repeats the frame's first point and is not valid; width: the
        largest frame by default)."""
        from fgloc.smoothing.graph import ragged_index

        return ragged_index(np.diff(self.start), width)

    def points(self, states: np.ndarray, gp_mu: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For the per-frame states (F, 26): the (P, 2) contour points in C, their (P,)
        lateral coordinates in the vehicle frame (m, left positive) and their (P,) vehicles'
        yaw (rad, C)."""
        s = states[self.point_frame]
        radius = self.mean + np.einsum("pn,pn->p", s[:, N_KIN:] - gp_mu, self.H)
        ang = self.theta + s[:, YAW]
        xy = s[:, [X, Y]] + radius[:, None] * np.column_stack([np.cos(ang), np.sin(ang)])
        return xy, radius * np.sin(self.theta), s[:, YAW]


def frame_points(tracks: TrackSet, start: np.ndarray, det_xy: np.ndarray,
                 sensor_xy: np.ndarray, gp, max_points: int) -> FramePoints:
    """Per (track, step) with detections: the sensor-aware contour angles of up to
    ``max_points`` of them (a regular subsample) on the track's state there; ``start``
    (T + 1,) the offsets of the tracks' steps in the stacked states."""
    from fgloc.smoothing.graph import regular_subsample, step_detections

    ft, fs, fk, theta, label, offs = [], [], [], [], [], [0]
    for j, tr in enumerate(tracks.tracks):
        for s, idx in enumerate(step_detections(tr)):
            if len(idx) == 0:
                continue
            z = det_xy[idx[regular_subsample(len(idx), max_points)]]
            th, _ = ContourMeasurement(z, sensor_xy, gp).associate(tr.states[s])
            ft.append(j)
            fs.append(s)
            fk.append(int(start[j]) + s)
            theta.append(th)
            label.append(np.full(len(th), tr.labels[s], np.int64))
            offs.append(offs[-1] + len(th))
    th = np.concatenate(theta) if theta else np.zeros(0)
    H, _ = gp.conditional(th)
    return FramePoints(np.array(ft, np.int64), np.array(fs, np.int64), np.array(fk, np.int64),
                       np.array(offs, np.int64), th,
                       np.concatenate(label) if label else np.zeros(0, np.int64), H,
                       gp.mean(th))


# ---- the joint optimization --------------------------------------------------------------
@dataclass
class JointResult:
    """Outcome of :func:`joint_refine`.

    T: 3x3 SE(2) C -> L. covariance: 3x3 of (tx, ty, phi) of T (m^2, m rad, rad^2) or None,
    as ``[joint] covariance`` asks; covariance_model: the model one (inverse information).
    tracks: the refined tracks (decimated, frame C, ``T_frame_to_L = T``). rounds: rounds run;
    converged: the pose (and the noise levels) settled before ``max_rounds``. noise: the final
    :class:`NoiseLevels` (summary). offsets: track id -> lateral offset (m).
    matched: (P, 2) matched contour points in L, matched_label (P,) their labels. history:
    per round pose, noise and cost. timing: seconds of building (track factors and points),
    association, point-row linearization with the system assembly, banded solves, cost
    evaluations, the final marginal covariance, and the iteration count. track_misfit (n_tracks,):
    :func:`track_misfit` of the tracks (in ``tracks``' order) at T, the lane-model evidence
    (:mod:`fgloc.registration.lane_evidence`).
    """

    T: np.ndarray
    covariance: np.ndarray | None
    covariance_model: np.ndarray | None
    tracks: TrackSet
    rounds: int
    converged: bool
    noise: dict[str, float]
    offsets: dict[int, float]
    matched: np.ndarray
    matched_label: np.ndarray
    n_points: int
    n_tracks: int
    n_states: int
    history: list[dict[str, float]]
    timing: dict[str, float]
    track_misfit: np.ndarray


def _add_time(timing: dict[str, float], key: str, t0: float) -> None:
    timing[key] = timing.get(key, 0.0) + time.perf_counter() - t0


def track_quadratic(tracks: TrackSet, det_xy: np.ndarray, sensor_xy: np.ndarray, cfg: Config,
                    x_lin: np.ndarray, det_trusted: np.ndarray | None = None,
                    det_range_rate: np.ndarray | None = None
                    ) -> tuple[TrackQuadratic, ContourGP]:
    """The track factors' quadratic model about ``x_lin`` (the stacked states) and the contour
    model; without ``refine_tracks`` a tight hold (information 1e8 per state unit) instead.
    det_trusted / det_range_rate: as in :func:`fgloc.smoothing.graph.stack_tracks`."""
    from fgloc.smoothing.graph import contour_gp, stack_tracks

    # one contour model for all tracks: the point rows take one (no long-vehicle model)
    scfg = dataclasses.replace(cfg.smoothing, long_vehicle_length=0.0,
                               extent_rows=cfg.joint.extent_rows)
    gp = contour_gp(cfg.tracking)
    if cfg.joint.refine_tracks:
        system = stack_tracks(tracks, det_xy, sensor_xy, scfg, cfg.tracking, det_trusted,
                              det_range_rate)
        ne = system.evaluate(x_lin)
        return (TrackQuadratic(x_lin, float(ne.cost.sum()), ne.g, ne.D, ne.B,
                               system.proc_step), gp)
    n = len(x_lin)
    return (TrackQuadratic(x_lin, 0.0, np.zeros_like(x_lin),
                           np.broadcast_to(1e8 * np.eye(N_STATE), (n, N_STATE, N_STATE)).copy(),
                           np.zeros((0, N_STATE, N_STATE)), np.zeros(0, np.int64)), gp)


def _bias_terms(jc: JointConfig) -> tuple[np.ndarray, np.ndarray]:
    """Prior std. devs. of the shared shifts of the targets (constant side bias m,
    range-proportional side bias m per 100 m, centre-line share 1) and which of them are in
    use (std. dev. > 0)."""
    sd = np.array([jc.side_bias_sigma, jc.range_bias_sigma, jc.centre_line_sigma])
    return sd, sd > 0.0


def bias_sigmas(jc: JointConfig) -> np.ndarray:
    """Prior std. devs. of the shared shifts in use: the constant side bias (m) with
    ``side_bias_sigma``, the range-proportional one (m per 100 m) with ``range_bias_sigma``,
    then the centre-line share with ``centre_line_sigma``."""
    sd, used = _bias_terms(jc)
    return sd[used]


def side_basis(target: np.ndarray, normal: np.ndarray, sensor_l: np.ndarray,
               jc: JointConfig, centre: np.ndarray | None = None) -> np.ndarray | None:
    """(P, nb) each point's coefficients of the shared shifts (:func:`bias_sigmas`): of the
    side biases the sign of the sensor's side of its line along ``normal`` (so a positive
    bias moves the point towards the sensor), times 1 and / or the target's range from
    ``sensor_l`` in hm; of the centre-line share ``centre`` (P,), the offset (m) along
    ``normal`` from the arc-length centre line to lanelet2's where the point is matched
    (:func:`centre_shift`; None: 0). target, normal (P, 2) and sensor_l (2,) in L. None
    without shared shifts."""
    _, used = _bias_terms(jc)
    if not used.any():
        return None
    share = np.zeros(len(target)) if centre is None else centre
    return np.column_stack([_side_columns(target, normal, sensor_l), share])[:, used]


def centre_shift(lines: LaneLines, index: np.ndarray, normal: np.ndarray) -> np.ndarray | None:
    """(P,) the offset (m) from the arc-length centre line to lanelet2's along each point's
    oriented ``normal`` (P, 2) at its matched sample (``index``, -1 none: 0); None when the
    lines have no centre offsets. The centre-line share moves each target by its value
    times this."""
    if lines.centre_offset is None:
        return None
    ok = index >= 0
    out = np.zeros(len(index))
    out[ok] = np.einsum("pi,pi->p", lines.centre_offset[index[ok]], normal[ok])
    return out


def shift_basis(basis: np.ndarray | None, lane_cols: np.ndarray | None) -> np.ndarray | None:
    """(P, nb + L) the coefficients of every shared shift of the targets: the side biases and
    centre-line share (``basis`` (P, nb), :func:`side_basis`) then the estimated lane biases
    (``lane_cols`` (P, L), :class:`~fgloc.registration.lane_bias.LaneBiases`); either may be
    None. None without any."""
    parts = [c for c in (basis, lane_cols) if c is not None and c.shape[1]]
    return np.concatenate(parts, axis=1) if parts else None


def _side_columns(target: np.ndarray, normal: np.ndarray, sensor_l: np.ndarray) -> np.ndarray:
    """(P, 2) coefficients of a constant (m) and a range-proportional (m per 100 m) side bias
    of each point (:func:`side_basis`)."""
    sign = side_sign(target, normal, sensor_l)
    hm = np.linalg.norm(target - sensor_l, axis=1) / 100.0
    return np.column_stack([sign, sign * hm])


#: Prior sqrt information (1/m) of a considered bias while it rides the final linearization
#: as a global parameter: it only keeps that solve regular (a lanelet's bias may be
#: confounded with the constant one); it enters the considered parameters' own block of the
#: reduced information, which :func:`consider_covariance` does not use.
CONSIDERED_PRIOR_W = 1e-3


def matched_lane(lines: LaneLines, index: np.ndarray) -> np.ndarray | None:
    """(P,) the lane id of each point's matched line sample (``index``, -1 none: -1); None
    when the lines have no lane ids."""
    if lines.lane is None:
        return None
    return np.where(index >= 0, lines.lane[np.maximum(index, 0)], -1)


def considered_columns(target: np.ndarray, normal: np.ndarray, index: np.ndarray,
                       sensor_l: np.ndarray, lines: LaneLines, jc: JointConfig,
                       lane_sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """The biases that are considered, not estimated: each point's coefficients (P, C) and
    their std. devs. (C,) m. The constant side bias towards the sensor
    (``consider_side_bias_sigma``, when ``side_bias_sigma`` does not estimate it), then one
    lateral bias per lanelet that holds matched points (std. dev. ``lane_sigma``:
    ``consider_lane_bias_sigma``, or what of it the estimated lane biases' std. dev. leaves;
    the shift of its points along their normal; needs ``lines.lane``). target, normal (P, 2) in
    L, index (P,) the matched line sample (-1 none), sensor_l (2,)."""
    return bias_columns(side_sign(target, normal, sensor_l),
                        jc.consider_side_bias_sigma if jc.side_bias_sigma == 0.0 else 0.0,
                        matched_lane(lines, index), lane_sigma)


def with_considered_biases(pts: PointSet, pri: Priors, glob: np.ndarray, columns: np.ndarray
                           ) -> tuple[PointSet, Priors, np.ndarray]:
    """The point set, priors and global parameters with C more bias parameters last, at 0
    (prior :data:`CONSIDERED_PRIOR_W`): each point's offset along its normal is ``columns``
    (F, K, C) times them. Their rows of the reduced information give
    :func:`consider_covariance`."""
    C = columns.shape[-1]
    side = columns if pts.side is None else np.concatenate([pts.side, columns], axis=-1)
    return (dataclasses.replace(pts, side=side),
            Priors(np.append(pri.pose_mean, np.zeros(C)),
                   np.append(pri.pose_w, np.full(C, CONSIDERED_PRIOR_W)), pri.offset_w),
            np.append(glob, np.zeros(C)))


def _point_set(fp: FramePoints, pad: tuple[np.ndarray, np.ndarray], index: np.ndarray,
               compat: np.ndarray, target: np.ndarray, normal: np.ndarray, sigma: np.ndarray,
               x: np.ndarray, glob: np.ndarray, b: np.ndarray | None, huber_scale: float,
               gp: ContourGP, jc: JointConfig, sensor_l: np.ndarray,
               centre: np.ndarray | None = None,
               lane_cols: np.ndarray | None = None) -> PointSet:
    """The round's matched points, padded per frame (:class:`PointSet`); sigma: (P,) std.
    dev. (m) of each point across its line; glob: the global parameters (pose, the shared
    shifts in use, then the estimated lane biases); sensor_l (2,): the sensor in L (the side
    of each line); centre (P,): each point's coefficient of the centre-line share
    (:func:`centre_shift`); lane_cols (P, L): its coefficients of the estimated lane biases
    (None: none). The per-point weights (label compatibility x Huber of the across-line
    residual at (x, glob, b) in units of ``huber_scale`` m) are fixed for the round (IRLS), so
    the optimizer sees a smooth objective."""
    pi, valid = pad
    ok = index >= 0
    sig_t = sigma / np.sqrt(jc.along_weight) if jc.along_weight > 0 else np.inf
    n = np.where(ok[:, None], normal, np.array([1.0, 0.0]))
    info = line_sqrt_info(n, np.where(ok, sigma, 1.0), sig_t)
    basis = shift_basis(side_basis(target, n, sensor_l, jc, centre), lane_cols)
    side = None if basis is None else basis[pi]
    pts = PointSet(fp.frame_state, fp.frame_track, fp.theta[pi], fp.H[pi], fp.mean[pi],
                   target[pi], n[pi], info[pi], (valid & ok[pi]).astype(float), gp.mu, side)
    e, _ = pts.rows(x, glob, b)
    across = np.linalg.norm(e, axis=-1) * sigma[pi]               # m (the along row is 0)
    w = compat[pi] * (huber_weights(across / huber_scale, jc.huber_k) if jc.huber_k > 0
                      else 1.0)
    pts.weights = np.where(valid & ok[pi], w, 0.0)
    return pts


def _correspondences(fp: FramePoints, x: np.ndarray, pose: np.ndarray, lines: LaneLines,
                     gp: ContourGP, jc: JointConfig) -> tuple[np.ndarray, ...]:
    """Match every contour point at the estimate (stacked states x, pose): the target index
    (-1 none), the compatibility, the target point (P, 2) and the offset direction (P, 2) of
    each.

    "contour" model: a point's lateral place in its vehicle (``r sin theta``) is where it
    should lie beside the lane centre line; it is matched by its foot on the vehicle's axis and
    its target is the matched line point moved by that lateral place along the vehicle's left
    normal. "visible-side": the point itself is matched to the shifted lines."""
    T = se2(*pose[:3])
    xy, lateral, yaw = fp.points(x[fp.frame_state], gp.mu)
    if jc.lateral_model == "visible-side":
        lateral = np.zeros_like(lateral)
    yaw_l = yaw + np.arctan2(T[1, 0], T[0, 0])
    left = np.column_stack([-np.sin(yaw_l), np.cos(yaw_l)])
    foot = transform_points(T, xy) - lateral[:, None] * left
    index, compat = lines.match(foot, yaw_l, fp.label, jc.label_weight_other,
                                jc.max_correspondence, jc.heading_weight)
    ok = index >= 0
    n = np.zeros_like(xy)
    n[ok] = lines.normal[index[ok]]
    n *= np.where(np.einsum("pi,pi->p", n, left) < 0.0, -1.0, 1.0)[:, None]
    target = np.zeros_like(xy)
    target[ok] = lines.xy[index[ok]] + lateral[ok, None] * n[ok]
    return index, compat, target, n


@dataclass
class NoiseLevels:
    """Noise of the point factors, estimated from the data (:func:`noise_levels`).

    within: scatter (m) of a point about its frame's mean (sets the Huber scale). frame: scatter
    (m) of a frame's mean about its track's offset line. rho: correlation of consecutive frame
    means of one track (a vehicle's deviation from its line wanders slowly). offset: scatter (m)
    of the tracks' offsets (the prior of ``b``).
    """

    within: float
    frame: float
    rho: float
    offset: float

    @property
    def inflation(self) -> float:
        """``(1 + rho) / (1 - rho)``: a run of n correlated frames weighs like n / inflation
        independent ones (AR(1))."""
        return (1.0 + self.rho) / (1.0 - self.rho)

    def point_sigma(self, per_frame: np.ndarray, ambiguity: np.ndarray | float = 0.0
                    ) -> np.ndarray:
        """Std. dev. (m) of each point of frames with ``per_frame`` matched points, such that
        a frame weighs like one measurement of its mean, deflated by the frame correlation;
        ``ambiguity`` (m; one, or per point) of the line where a point is matched adds to
        the frame noise in quadrature."""
        frame = np.sqrt(self.frame**2 + np.square(ambiguity))
        return frame * np.sqrt(self.inflation * np.maximum(per_frame, 1))

    def settled(self, other: NoiseLevels, tol: float = 0.1) -> bool:
        """Every level within ``tol`` (relative; rho: absolute) of ``other``'s."""
        rel = [abs(a / b - 1.0) for a, b in ((self.frame, other.frame),
                                                (self.offset, other.offset)) if b > 0]
        return max(rel, default=0.0) < tol and abs(self.rho - other.rho) < tol

    def summary(self) -> dict[str, float]:
        return {"within_m": self.within, "frame_m": self.frame, "rho": self.rho,
                "offset_m": self.offset, "inflation": self.inflation}


def _ambiguity(lines: LaneLines, index: np.ndarray, scale: float) -> np.ndarray | float:
    """(P,) ``scale`` times the centre-line ambiguity (m) where each point is matched
    (``index`` into the lines, -1 none: 0); 0 when the lines have none or ``scale`` is 0."""
    if lines.ambiguity is None or scale == 0.0:
        return 0.0
    return scale * np.where(index >= 0, lines.ambiguity[np.maximum(index, 0)], 0.0)


@dataclass(frozen=True)
class FrameResiduals:
    """Across-line residuals of the filter's track centres about a pose (:func:`frame_residuals`).

    dev (P,): each matched point's residual (m) about its track's offset; frame (P,): its
    frame (index into the :class:`FramePoints` frames); fmean (F,): each frame's mean of
    ``dev`` (0 without matched points); has (F,): frames with matched points; raw (T,): each
    track's offset (m, its mean residual); seen (T,): tracks with matched points; rank: the
    pose directions (at most three) the correction of the offsets took up."""

    dev: np.ndarray
    frame: np.ndarray
    fmean: np.ndarray
    has: np.ndarray
    raw: np.ndarray
    seen: np.ndarray
    rank: int


def frame_residuals(fp: FramePoints, states0: np.ndarray, T: np.ndarray, index: np.ndarray,
                    target: np.ndarray, normal: np.ndarray, gp: ContourGP, n_tracks: int,
                    shift: np.ndarray | None = None) -> FrameResiduals:
    """The residuals of :func:`noise_levels` (its docstring): the matched points of the
    filter's states ``states0`` moved by T against ``target`` along ``normal`` (minus
    ``shift``), the pose correction that fits the tracks' offsets best taken off, about each
    track's offset."""
    ok = index >= 0
    q = transform_points(T, fp.points(states0, gp.mu)[0])[ok]
    n = normal[ok]
    res = np.einsum("pi,pi->p", q - target[ok], n)
    if shift is not None:
        res = res - shift[ok]
    frame = fp.point_frame[ok]
    track = fp.frame_track[frame]
    count = np.bincount(track, minlength=n_tracks)
    seen = count > 0
    # d res / d (tx, ty, phi) of T = se2(tx, ty, phi): n . (1, 0), n . (0, 1), n . perp(R p)
    rp = q - T[:2, 2]
    jac = np.column_stack([n, n[:, 1] * rp[:, 0] - n[:, 0] * rp[:, 1]])
    mean_jac = np.column_stack([np.bincount(track, jac[:, k], minlength=n_tracks)
                                for k in range(3)]) / np.maximum(count, 1)[:, None]
    raw = np.bincount(track, res, minlength=n_tracks) / np.maximum(count, 1)
    dp, _, rank, _ = np.linalg.lstsq(mean_jac[seen], raw[seen], rcond=1e-9)
    res = res - jac @ dp
    raw = raw - mean_jac @ dp
    dev = res - raw[track]
    nf = len(fp.frame_state)
    fcount = np.bincount(frame, minlength=nf)
    fmean = np.bincount(frame, dev, minlength=nf) / np.maximum(fcount, 1)
    return FrameResiduals(dev, frame, fmean, fcount > 0, raw, seen, int(rank))


def noise_levels(fp: FramePoints, states0: np.ndarray, T: np.ndarray, index: np.ndarray,
                 target: np.ndarray, normal: np.ndarray, gp: ContourGP, n_tracks: int,
                 floor: float, shift: np.ndarray | None = None) -> NoiseLevels:
    """Moment estimates of the :class:`NoiseLevels` about the pose T from the filter's states
    ``states0`` (F, 26), not the refined ones (which the point factors pull towards the
    lines). Each track's mean across-line residual is its raw offset. The pose correction
    ``dp`` (tx, ty, phi of a change of T) that fits the raw offsets best (least squares on
    each track's mean of the residuals' derivatives) is taken off every residual first, so
    the levels are those about the pose the offsets themselves favour, not inflated by T's
    own error (estimated at a T off across a road, every track on that road would share T's
    error in its offset: the offset level grows with it, the offsets' prior loosens and lets
    T drift farther at the next estimate). The offsets' RMS with ``n_tracks - rank``
    degrees of freedom (the pose takes up as many as it can move the offsets, at most
    three) is the offset level; about them, the per-frame means give the frame level (MAD)
    and the lag-1 correlation of consecutive frames of one track (clipped to [0, 0.95]);
    the points about their frame mean the within level (MAD). Levels are at least
    ``floor`` m. shift (P,): the points' side bias along ``normal`` (m; None = 0), taken
    off the residuals."""
    r = frame_residuals(fp, states0, T, index, target, normal, gp, n_tracks, shift)
    fmean, has = r.fmean, r.has
    within = 1.4826 * float(np.median(np.abs(r.dev - fmean[r.frame])))
    level = 1.4826 * float(np.median(np.abs(fmean[has])))
    pair = has[:-1] & has[1:] & (fp.frame_track[:-1] == fp.frame_track[1:])
    rho = 0.0
    if np.count_nonzero(pair) > 10 and level > 0:
        a = np.clip(fmean[:-1][pair], -3 * level, 3 * level)
        b = np.clip(fmean[1:][pair], -3 * level, 3 * level)
        rho = float(np.clip(np.sum(a * b) / np.sqrt(np.sum(a * a) * np.sum(b * b)), 0.0, 0.95))
    offset = float(np.sqrt(np.sum(r.raw[r.seen] ** 2) / max(1, int(r.seen.sum()) - r.rank)))
    return NoiseLevels(max(floor, within), max(floor, level), rho, max(floor, offset))


def track_misfit(fp: FramePoints, residuals: FrameResiduals, n_tracks: int, scale: float
                 ) -> np.ndarray:
    """(T,) each track's summed robust cost ``min(m, scale)^2 / scale^2`` of its frames' mean
    residuals m (m, :class:`FrameResiduals`), a frame without matched points costing 1 (as
    an unmatched detection does in :func:`fgloc.registration.modes.track_costs`): how far the
    track's centre wanders across its line beyond a constant offset. The lane models of a
    two-way street differ there (:mod:`fgloc.registration.lane_evidence`)."""
    m = np.minimum(np.abs(residuals.fmean), scale)
    rho = np.where(residuals.has, m**2 / scale**2, 1.0)
    return np.bincount(fp.frame_track, weights=rho, minlength=n_tracks)


def joint_refine(tracks: TrackSet, det_xy: np.ndarray, sensor_xy: np.ndarray,
                 lines: LaneLines, T0: np.ndarray, cfg: Config,
                 det_trusted: np.ndarray | None = None,
                 det_range_rate: np.ndarray | None = None) -> JointResult:
    """The joint optimization of the module docstring.

    tracks: the filter's tracks in C (their ``det_index`` into ``det_xy``). det_xy (N, 2): all
    radar rows placed in C; sensor_xy (2,): the sensor in C. lines: the target lines in L
    (lane centres for ``lateral_model = "contour"``, shifted ones for "visible-side"). T0: 3x3
    start of T (C -> L); the pose prior is at the identity (the coarse pose). det_trusted
    (N,) / det_range_rate (N, 2): the detections that may mark a vehicle's end and their
    Doppler and 3D range, for the track factors (None = all / no range-rate rows). Raises
    ValueError on an invalid ``cfg.joint``, :class:`fgloc.errors.LocalizationError` when no
    track is long enough.
    """
    jc: JointConfig = cfg.joint
    check_joint_config(jc)
    timing: dict[str, float] = {}
    t0 = time.perf_counter()
    dec = decimate(tracks, jc.step_stride, jc.min_track_steps)
    if not dec.tracks:
        longest = max((len(tr) for tr in tracks.tracks), default=0)
        raise LocalizationError(
            f"joint: no track has {jc.min_track_steps} steps at stride {jc.step_stride} "
            f"({len(tracks)} tracks, the longest {longest} steps before the stride): too short for "
            "the joint graph; record longer, or lower [joint] min_track_steps or step_stride")
    lengths = [len(tr) for tr in dec.tracks]
    start = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    owner = np.repeat(np.arange(len(lengths)), lengths)
    x = np.concatenate([tr.states for tr in dec.tracks])
    tq, gp = track_quadratic(dec, det_xy, sensor_xy, cfg, x, det_trusted, det_range_rate)
    fp = frame_points(dec, start, det_xy, sensor_xy, gp, jc.max_points_per_frame)
    pad = fp.padded()
    states0 = x[fp.frame_state]
    layout = BandedLayout(len(x), tq.below)
    offsets = jc.offset_sigma > 0.0
    bias_sd = bias_sigmas(jc)
    n_side = len(bias_sd) - int(jc.centre_line_sigma > 0)      # side biases before the share
    pose = np.concatenate([se2_params(T0), np.zeros(len(bias_sd))])
    b = np.zeros(len(dec.tracks)) if offsets else None
    prior_sd = np.array([jc.pose_prior_sigma, jc.pose_prior_sigma,
                         np.deg2rad(jc.pose_prior_sigma_yaw_deg), *bias_sd])
    n_fixed = len(prior_sd)                     # pose and shared shifts; lane biases after
    lanes = (LaneBiases(jc.lane_bias_sigma)
             if jc.lane_bias_sigma > 0.0 and lines.lane is not None else None)
    lane_cols: np.ndarray | None = None
    _add_time(timing, "build", t0)

    fixed = NoiseLevels(jc.sigma_line, jc.sigma_line, 0.0, jc.offset_sigma)
    noise: NoiseLevels | None = None if jc.estimate_noise else fixed
    history: list[dict[str, object]] = []
    converged, rounds, lam = False, 0, 1e-5
    gauss_newton = jc.optimizer == "gauss-newton"
    for rounds in range(1, jc.max_rounds + 1):
        t0 = time.perf_counter()
        if jc.relinearize_tracks and rounds > 1 and jc.refine_tracks:
            tq, gp = track_quadratic(dec, det_xy, sensor_xy, cfg, x, det_trusted,
                                     det_range_rate)
        _add_time(timing, "linearize_tracks", t0)
        t0 = time.perf_counter()
        index, compat, target, normal = _correspondences(fp, x, pose, lines, gp, jc)
        ok = index >= 0
        if noise is None:        # first round: the noise levels at the start pose
            noise = noise_levels(fp, states0, se2(*pose[:3]), index, target, normal, gp,
                                 len(dec.tracks), jc.min_sigma)
        per_frame = np.bincount(fp.point_frame[ok], minlength=len(fp.frame_state))
        sigma = noise.point_sigma(per_frame[fp.point_frame],
                                  _ambiguity(lines, index, jc.centre_ambiguity))
        sensor_l = transform_points(se2(*pose[:3]), sensor_xy[None])[0]
        centre = centre_shift(lines, index, normal)
        prior_w = 1.0 / prior_sd
        if lanes is not None:       # this round's lanes' biases follow the fixed parameters
            lane_cols = lanes.select(matched_lane(lines, index))
            pose = np.concatenate([pose[:n_fixed], lanes.params()])
            prior_w = np.concatenate([prior_w, lanes.prior_weights()])
        pts = _point_set(fp, pad, index, compat, target, normal, sigma, x, pose, b,
                         noise.within, gp, jc, sensor_l, centre, lane_cols)
        pri = Priors(np.zeros(len(pose)), prior_w, 1.0 / noise.offset if offsets else 0.0)
        _add_time(timing, "associate", t0)
        before = pose.copy()
        cost = joint_cost(tq, pts, pri, x, pose, b)
        for _ in range(jc.iterations):
            t0 = time.perf_counter()
            arrow = linearize(tq, pts, pri, len(dec.tracks), x, pose, b)
            _add_time(timing, "linearize", t0)
            t0 = time.perf_counter()
            sol = solve_arrow(arrow, layout, owner, offsets, 0.0 if gauss_newton else lam)
            _add_time(timing, "solve", t0)
            t0 = time.perf_counter()
            cand = (x + sol.dx, pose + sol.dp, None if b is None else b + sol.db)
            new_cost = joint_cost(tq, pts, pri, *cand)
            _add_time(timing, "cost", t0)
            timing["iterations"] = timing.get("iterations", 0) + 1
            if gauss_newton or new_cost < cost:
                x, pose, b = cand
                lam = max(lam / 10.0, 1e-9)
                done = (cost - new_cost) < 1e-6 * cost
                cost = new_cost
                if done:
                    break
            else:
                lam *= 10.0
        if lanes is not None:
            lanes.store(pose[n_fixed:])
        step_xy = float(np.hypot(*(pose[:2] - before[:2])))
        step_yaw = float(abs(wrap_angle(pose[2] - before[2])))
        history.append({"round": rounds, "tx": float(pose[0]), "ty": float(pose[1]),
                        "yaw_deg": float(np.rad2deg(pose[2])), "step_m": step_xy,
                        "side_bias_m": pose[3:3 + n_side].tolist(),
                        "centre_line_share": (float(pose[n_fixed - 1])
                                              if jc.centre_line_sigma > 0 else None),
                        "lane_bias_m": None if lanes is None else lanes.summary(),
                        "step_yaw_deg": float(np.rad2deg(step_yaw)), "noise": noise.summary(),
                        "matched": int(ok.sum()), "error": float(cost)})
        if step_xy >= jc.tol_position or step_yaw >= np.deg2rad(jc.tol_yaw_deg):
            continue
        if not jc.estimate_noise or np.count_nonzero(ok) < 10:
            converged = True
            break
        # the pose settled: re-estimate the noise levels; done when they settled too
        basis = shift_basis(side_basis(target, normal, sensor_l, jc, centre), lane_cols)
        again = noise_levels(fp, states0, se2(*pose[:3]), index, target, normal, gp,
                             len(dec.tracks), jc.min_sigma,
                             None if basis is None else basis @ pose[3:])
        settled, noise = again.settled(noise), again
        if settled:
            converged = True
            break

    # how far each track wanders across its line at the final pose (lane-model evidence)
    basis = shift_basis(side_basis(target, normal, sensor_l, jc, centre), lane_cols)
    misfit = track_misfit(fp, frame_residuals(fp, states0, se2(*pose[:3]), index, target, normal,
                                              gp, len(dec.tracks),
                                              None if basis is None else basis @ pose[3:]),
                          len(dec.tracks), cfg.coarse.mode_cost_scale)
    t0 = time.perf_counter()
    # the final information, with the considered biases as more (last) global parameters
    # estimated lane biases: consider what of consider_lane_bias_sigma their std. dev. leaves
    lane_sigma = (jc.consider_lane_bias_sigma if lanes is None else
                  float(np.sqrt(max(jc.consider_lane_bias_sigma**2 - lanes.sigma**2, 0.0))))
    columns, consider_sd = considered_columns(target, normal, index, sensor_l, lines, jc,
                                              lane_sigma)
    G = pts.n_global
    final_pts, final_pri, final_glob = pts, pri, pose
    if len(consider_sd):
        final_pts, final_pri, final_glob = with_considered_biases(pts, pri, pose,
                                                                  columns[pad[0]])
    arrow_final = linearize(tq, final_pts, final_pri, len(dec.tracks), x, final_glob, b)
    info_all = solve_arrow(arrow_final, layout, owner, offsets).pose_information
    info = info_all[:G, :G]
    cov = cov_model = None
    if np.linalg.cond(info) < 1e12:
        cov_model = np.linalg.inv(info)
        cov = cov_model if jc.covariance == "model" else track_robust_covariance(
            info, arrow_final.gp_track[:, :G], pri.pose_w**2,
            None if lanes is None else n_fixed + lanes.free_params(np.diag(cov_model)[n_fixed:]))
        if len(consider_sd):
            extra = consider_covariance(info_all, consider_sd)
            cov, cov_model = cov + extra, cov_model + extra
        cov, cov_model = cov[:3, :3], cov_model[:3, :3]
    _add_time(timing, "marginals", t0)

    from fgloc.smoothing.graph import tracks_from_states

    T = se2(*pose[:3])
    refined = dataclasses.replace(
        tracks_from_states(dec, np.split(x, start[1:-1]), cfg.tracking, smoother="joint"),
        T_frame_to_L=T)
    matched = transform_points(T, fp.points(x[fp.frame_state], gp.mu)[0])[ok]
    offs = ({} if b is None else
            {int(tr.id): float(v) for tr, v in zip(dec.tracks, b)})
    return JointResult(T, cov, cov_model, refined, rounds, converged, noise.summary(), offs,
                       matched, fp.label[ok], int(ok.sum()), len(dec.tracks), len(x),
                       history, timing, misfit)


# ---- degeneracy --------------------------------------------------------------------------
def degeneracy_report(cov_T: np.ndarray | None, T: np.ndarray, matched: np.ndarray,
                      weak_sigma: float) -> dict[str, object]:
    """JSON-ready eigen-analysis of the pose information ``inv(cov_T)`` in metric coordinates
    (module docstring): eigenvalues (1/m^2), eigenvectors (unit columns in (u, v, a): centroid
    translation east / north, arc length), the std. dev. (m) along each, and the weakly
    observed ones (std. dev. above ``weak_sigma`` m) with their direction in L (deg from east,
    for the translation part)."""
    if cov_T is None or len(matched) < 3:
        return {"available": False, "weakly_observed": True, "weak_directions": []}
    deg = _degeneracy(np.linalg.inv(cov_T), T, matched, np.ones(len(matched)))
    sd = 1.0 / np.sqrt(np.maximum(deg.eigenvalues, 1e-300))
    weak = []
    for i in np.flatnonzero(sd > weak_sigma):
        v = deg.eigenvectors[:, i]
        weak.append({"std_m": float(sd[i]), "direction_u_v_arc": v.tolist(),
                     "translation_heading_deg": float(np.rad2deg(np.arctan2(v[1], v[0]))),
                     "rotation_share": float(v[2] ** 2)})
    return {
        "available": True,
        "centre_L": deg.centre.tolist(),
        "radius_m": deg.radius,
        "eigenvalues": deg.eigenvalues.tolist(),
        "eigenvectors_u_v_arc": deg.eigenvectors.tolist(),
        "std_m": sd.tolist(),
        "condition_number": deg.condition_number,
        "weak_sigma_m": weak_sigma,
        "weakly_observed": bool(weak),
        "weak_directions": weak,
    }


def _sensor_std(cov: np.ndarray | None) -> dict[str, float] | None:
    """JSON-ready std. devs. of the sensor's x, y (m) and yaw (deg) from their 3x3 covariance."""
    if cov is None:
        return None
    return {"x_m": float(np.sqrt(cov[0, 0])), "y_m": float(np.sqrt(cov[1, 1])),
            "yaw_deg": float(np.rad2deg(np.sqrt(cov[2, 2])))}


# ---- the method ----------------------------------------------------------------------------
def joint_from_tracks(scn: Scenario, cfg: Config, target: TargetCloud, coarse: CoarseResult,
                      tracks: TrackSet, timer: Timer,
                      start: LocalizationResult | None = None,
                      smoothed: TrackSet | None = None) -> LocalizationResult:
    """The joint stage on the filter's ``tracks`` (frame C of ``coarse.T_coarse``): filter-sicp's
    registration as the start (``start``, computed here when None), then
    :func:`joint_refine` on the same trajectory subset of ``smoothed`` (the same tracks
    smoothed, ``[joint] smoother``; None: ``tracks`` themselves), the covariance mapped to the
    sensor's (x, y, yaw) in L and the degeneracy report. Every mode of the start
    (``start.mode_fits``: filter-sicp's registrations of the coarse modes) is refined from its
    registration against lines seen from its sensor position, and the fits are compared as in
    :mod:`fgloc.registration.modes` (``status``, ``modes``, a covering covariance when
    ambiguous); a mode's evidence is the better of its two fits' costs (the joint's and the
    start's: the joint optimizes another objective and may end where the shared cost is
    higher, which must not count against the mode); a start that its refinement left by more
    than the mode separation stays a mode of its own (:func:`~fgloc.registration.modes.
    choose_mode`'s ``starts``: sliding along a flat direction is no evidence against it).
    When ambiguous the reported mode is selected with the approximate position as a prior
    (possibly a kept start: then the diagnostics are those of the joint run that left it).
    One mode left is held to ``cfg.joint.resolved_max_std`` (1 m), not to the other methods'
    ``coarse.resolved_max_std`` (weakly observed directions below it are a warning,
    ``weak_sigma``): the joint's covariance adds considered biases that no amount of data
    shrinks and is conservative (sparse traffic: mean NEES 1.0), so the coarse tolerance
    turned 5 of its 30 sparse runs with 0.05-0.14 m errors ambiguous (docs/experiments.md);
    a covariance of metres (a few vehicles on a small junction) is no resolved pose.
    Raises ValueError when ``smoothed`` holds other tracks than ``tracks``."""
    from fgloc.registration.fine import (
        coarse_tilt_covariance,
        mode_targets,
        register_tracks,
        sensor_covariance,
    )
    from fgloc.registration.modes import (
        ModeFit,
        choose_mode,
        mode_track_costs,
        placed_where_ended,
        position_prior,
    )
    from fgloc.registration.source import build_source_cloud, choose_tracks
    from fgloc.smoothing.graph import detection_range_rates, extent_trusted, placed_detections

    check_joint_config(cfg.joint)
    if smoothed is not None and [t.id for t in smoothed.tracks] != [t.id for t in tracks.tracks]:
        raise ValueError("smoothed: expected the same tracks as tracks, in the same order")
    if start is None:
        start = register_tracks(scn, cfg, target, coarse, tracks, timer, method="filter-sicp")
    with timer.stage("joint"):
        det_xy, sensor_c = placed_detections(scn, coarse.T_coarse)
        offset = (cfg.coarse.visible_side_offset if cfg.joint.lateral_model == "visible-side"
                  else 0.0)
        used = choose_tracks(len(tracks), cfg.fine, np.random.default_rng(cfg.seed))
        refined = tracks if smoothed is None else smoothed
        subset = dataclasses.replace(refined, tracks=[refined.tracks[i] for i in used])
        trusted = extent_trusted(scn, coarse.T_coarse, det_xy, cfg.tracking)
        rates = detection_range_rates(scn)
        cloud = build_source_cloud(scn, tracks, coarse.T_coarse, cfg)
        tilt = coarse_tilt_covariance(coarse) if cfg.joint.consider_coarse_tilt else None
        runs: list[JointResult] = []
        fits: list[ModeFit] = []
        for mode in start.mode_fits or [ModeFit(
                start.tracks.T_frame_to_L, start.T_local, None, np.zeros(0), 1.0,
                start.converged, np.eye(3), start.z_std)]:
            mode_sensor = transform_points(mode.start, sensor_c[None])[0]
            lines = LaneLines.build(scn, target, cfg.fine.lane_sample_step, mode_sensor, offset,
                                    min_width(mode.lanes, cfg.map.two_way_min_width),
                                    cfg.joint.join_smoothing_length, cfg.map.centre_line,
                                    cfg.map)
            T0 = mode.T_fine if cfg.joint.start == "sicp" else mode.start
            jr = joint_refine(subset, det_xy, sensor_c, lines, T0, cfg, trusted, rates)
            cov = sensor_covariance(jr.covariance, jr.T, sensor_c, tilt)
            targets = mode_targets(scn, target, cfg, coarse, mode.start, mode.lanes)
            T_local, z_std = placed_where_ended(coarse, se2_to_se3(jr.T) @ coarse.T_coarse)
            cost = mode_track_costs(cloud, targets, jr.T, cfg)
            if mode.track_cost.shape == cost.shape and mode.cost < cost.sum():
                cost = mode.track_cost      # the mode's evidence: its start fits the data better
            fits.append(ModeFit(jr.T, T_local, cov, cost, mode.lane_score, jr.converged,
                                mode.start, z_std, mode.lanes))
            runs.append(jr)
        comparable = [m for m in start.mode_fits if m.track_cost.shape == cost.shape]
        _, lane_evidence = decided_lane_model(
            [(f.lanes, r.track_misfit) for f, r in zip(fits, runs)], cfg.coarse.mode_z)
        choice = choose_mode(fits, cfg.coarse, comparable, position_prior(scn, cfg.coarse),
                             tolerance=False, lane_z=lane_evidence["z"]).with_tolerance(
                                 cfg.joint.resolved_max_std, "joint.resolved_max_std")
        # the joint run of the reported mode (of a kept start: the run that left it)
        jr = runs[next(i for i, f in enumerate(fits) if f is choice.best
                       or (f.lanes == choice.best.lanes and np.array_equal(f.start,
                                                                           choice.best.start)))]
    cov = choice.best.covariance
    cov_model = sensor_covariance(jr.covariance_model, jr.T, sensor_c)
    if tilt is not None and cov_model is not None:
        cov_model = cov_model + tilt
    degen = degeneracy_report(jr.covariance, jr.T, jr.matched, cfg.joint.weak_sigma)
    warnings = [w for w in start.warnings
                if not w.startswith((f"{start.method}: ambiguous", f"{start.method}: tied"))]
    warnings += choice.warnings("joint")
    if not jr.converged:
        warnings.append(f"joint: the pose or the noise levels still moved after {jr.rounds} "
                        "rounds (max_rounds)")
    if degen["weakly_observed"]:
        dirs = ", ".join(f"{d['std_m']:.2f} m at {d['translation_heading_deg']:.0f} deg"
                         for d in degen["weak_directions"])
        warnings.append(f"joint: weakly observed pose direction(s) (std. dev. > "
                        f"{cfg.joint.weak_sigma} m): " + (
                            dirs or "not analysed, the joint's own fit gives no covariance "
                            "(fewer than 3 matched track points)"))
    tx, ty, yaw = se2_params(jr.T)
    diag = {
        "start": cfg.joint.start,
        "smoother": cfg.joint.smoother,
        "T_fine": {"x": tx, "y": ty, "yaw_deg": float(np.rad2deg(yaw))},
        "rounds": jr.rounds,
        "converged": jr.converged,
        "n_tracks": jr.n_tracks,
        "n_states": jr.n_states,
        "n_points": jr.n_points,
        "noise": jr.noise,
        "covariance": cfg.joint.covariance,
        "sensor_std": _sensor_std(cov),
        "sensor_std_model": _sensor_std(cov_model),
        "sensor_covariance_model": cov_model,
        "coarse_tilt_std_m": None if tilt is None else _sensor_std(tilt),
        "degeneracy": degen,
        "lane_models": lane_evidence,
        "history": jr.history,
        "timing_s": jr.timing,
    }
    # the start's source points, moved from SICP's pose to the reported one (for the plot)
    delta = choice.best.T_fine @ np.linalg.inv(start.tracks.T_frame_to_L)
    src = start.source_xyz.copy()
    src[:, :2] = transform_points(delta, src[:, :2])
    return dataclasses.replace(
        start,
        method="joint",
        T_local=choice.best.T_local,
        converged=start.converged and jr.converged and jr.covariance is not None,
        covariance=choice.covariance(cfg.coarse),
        diagnostics=json_ready({**start.diagnostics, "joint": diag}),
        warnings=warnings,
        source_xyz=src,
        tracks=dataclasses.replace(jr.tracks, T_frame_to_L=choice.best.T_fine),
        status=choice.status,
        modes=json_ready(choice.summary(scn.frame)),
        mode_fits=choice.fits,
        z_std=choice.best.z_std,
        weak_direction=choice.weak_summary(scn.frame),
    )
