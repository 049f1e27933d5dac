"""The GP-EOT multi-object tracker (UKF per track, batched over tracks) in the coarse frame C.

Per radar frame:

1. dynamic detections (|doppler| >= doppler_min) in C (x, y after T_coarse);
2. UKF prediction of every track (CTRA + contour decay), tracks leaving the FOV end;
3. association per detection: each detection goes to the track whose predicted contour it is
   deepest inside / least outside of (signed radial excess), within that track's gate (tight:
   ``gate`` + 2 sigma_centre; ``gate_long_extra`` more lengthwise for a truck-sized contour);
   so detections of vehicles side by side or queued split at the gap between their contours.
   Tracks whose centre is in the near blind range (only vehicle tops seen) are not updated;
4. UKF update of every track with detections, batched over tracks: plain model (2D point at
   the angle from the centre) or sensor-aware model (1D offsets along the normal of the
   contour part visible from the sensor, plus visible-extent rows: the extreme detections
   along a face that is seen fix where the contour ends; see :meth:`Tracker._aware_batch`);
5. births: unassociated detections are clustered; a cluster in a birth zone starts a tentative
   track confirmed after ``confirm_hits_zone`` updates within ``confirm_window_zone`` frames;
   elsewhere (``birth_anywhere``) the stricter ``confirm_hits_anywhere`` / window applies; its
   heading prior is the nearest lane's that explains its Doppler, and where crossing lanes tie
   one tentative track per heading starts (rivals: the one with most detections goes on);
6. a track whose centre lies next to a stronger (confirmed, more updates) track's contour --
   within ``gate`` sideways, ``duplicate_long`` lengthwise -- is a duplicate and is dropped;
   confirmed tracks missed for ``delete_after`` s end (the unmeasured tail is cut).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from factors.ctra import ctra_predict, ctra_process_noise
from factors.gp import ContourGP, rectangle_radius, rectangle_radius_gradient
from factors.measurement import (
    closest_on_chain,
    contour_candidates,
    contour_distance,
    contour_point,
    interior_variance,
    range_rate,
    unit,
    visibility_slack,
)
from fgloc.labels import kappa_labels
from fgloc.order_stats import linear_quantile, median_inplace
from fgloc.scenario import Scenario
from fgloc.tracking import ukf
from fgloc.tracking.birth import BirthZones, FieldOfView, LaneHeadings, initial_kinematics
from fgloc.tracking.cluster import cluster_labels
from fgloc.tracking.config import TrackingConfig
from fgloc.tracking.measure import (
    ContourTable,
    DetectionBatch,
    measurement_noise,
    measurement_vector,
    predict_measurements,
)
from fgloc.tracking.relink import relink
from fgloc.tracking.retrodict import length_variance, retrodict_length
from fgloc.tracking.road_users import MapWays, Sight, split_road_users
from fgloc.tracking.sightlines import Buildings
from fgloc.tracks import (
    N_KIN,
    N_STATE,
    YAW,
    YAWRATE,
    A,
    Track,
    TrackSet,
    V,
    X,
    Y,
    contour_angles,
    contour_length_width,
)

MODELS = ("sensor-aware", "plain")
#: yaw std. dev. (rad) of a new track whose heading only comes from the Doppler sign
LOS_YAW_SIGMA = np.deg2rad(45.0)
#: detections within this distance (m) along the heading of a seen front / rear lie on it
FACE_BAND = 0.5
#: detections continuing a vehicle towards the sensor lie within its contour's half width
#: and this (m) sideways (``occupancy_toward``)
TOWARD_SIDE_MARGIN = 0.3
#: lanelets within the sensor's range plus this (m) tell the tracks' ways
#: (:class:`fgloc.tracking.road_users.MapWays`)
WAYS_MARGIN = 50.0


def _connected_reach(d: np.ndarray, gap: float, k: int) -> float:
    """How far (m) sorted non-negative distances d reach from 0 before their first step wider
    than ``gap`` (m), less their last k (0 when no more than k are connected)."""
    steps = np.flatnonzero(np.diff(np.concatenate([[0.0], d])) > gap)
    connected = d[: steps[0]] if len(steps) else d
    return float(connected[-k]) if len(connected) > k else 0.0


@dataclass
class _Record:
    """History of one track while it is alive."""

    id: int
    birth_frame: int
    in_zone: bool
    last_update_t: float
    hits: int = 0
    confirmed: bool = False
    last_update_step: int = -1
    #: the last row recorded while its misfit was at most half ``diverge_excess`` (a track
    #: that diverges is reported up to there)
    calm_step: int = 0
    misfit: float = 0.0
    #: updates in a row whose UKF estimate of the speed, before the clip at 0, was below
    #: -``reverse_speed``: the vehicle moves against the track's heading
    reverse_run: int = 0
    #: the row at which that run began (its rows are not reported)
    reverse_from: int = 0
    #: ended inside the field of view, missed or diverged (:mod:`fgloc.tracking.relink`)
    lost: bool = False
    #: updates in a row with a contour at least ``long_trigger_width`` wide
    wide_run: int = 0
    #: updates that saw a long side of the vehicle (its length is measured)
    side_hits: int = 0
    #: promoted to the long-vehicle prior (see :meth:`Tracker._long_vehicles`)
    long: bool = False
    #: heading-hypothesis group (the id of its first track; -1: born alone): tracks started
    #: from one cluster with different headings, rivals until one is confirmed
    group: int = -1
    #: detections associated since birth (the rivals' score)
    n_det: int = 0
    #: lengthwise spans (m) of the associated detections of recent updates
    spans: list[float] = field(default_factory=list)
    #: lower bound (m) of the vehicle's length from ``spans`` (0: none yet)
    span_length: float = 0.0
    #: per end-on update of the last ``span_history`` frames: (frame, end seen: +1 front /
    #: -1 rear, distances (m) behind that end of its detections and of the others in its
    #: lengthwise corridor, which of them are its own, which lie beside its contour)
    occupancy: list[tuple[int, int, np.ndarray, np.ndarray, np.ndarray]] = field(
        default_factory=list)
    #: lower bound (m) of the vehicle's length from ``occupancy`` (0: none yet)
    occupied_length: float = 0.0
    #: how far (m) the pooled end-on detections continue the vehicle beyond the seen end,
    #: towards the sensor (the mirror of ``occupied_length``; 0: none yet)
    toward_length: float = 0.0
    #: rows recorded before the contour first grew towards the sensor, if it did so within
    #: its first 2 ``span_history`` updates (born on the far part of its vehicle, their
    #: seen end was not the vehicle's: retrodiction anchors their far end)
    toward_rows: int = 0
    #: farthest (m) behind the seen end its own pooled end-on detections reach (0: none yet)
    reached_length: float = 0.0
    t: list[float] = field(default_factory=list)
    states: list[np.ndarray] = field(default_factory=list)
    covs: list[np.ndarray] = field(default_factory=list)
    #: variance (m^2) of the contour's length (front + rear radius) per step
    len_var: list[float] = field(default_factory=list)
    #: per step: the length held by the long-vehicle prior (promoted, side not seen yet)
    held: list[bool] = field(default_factory=list)
    #: per step: the occupied length (m) where the contour's length is reached by a
    #: truck-sized occupied length that reaches farther than the spans of its own detections
    #: (measured end-on), else 0
    occupied: list[float] = field(default_factory=list)
    det_index: list[np.ndarray] = field(default_factory=list)
    det_step: list[np.ndarray] = field(default_factory=list)


@dataclass
class _Frame:
    """Dynamic detections of one frame in C: z (D, 2), rng (D,) 3D range, doppler (D,),
    index (D,) into the RadarData."""

    z: np.ndarray
    rng: np.ndarray
    doppler: np.ndarray
    index: np.ndarray


class Tracker:
    """Stateful multi-object tracker; feed frames in time order with :meth:`step`."""

    def __init__(self, cfg: TrackingConfig, fov: FieldOfView, zones: BirthZones,
                 lanes: LaneHeadings) -> None:
        if cfg.measurement_model not in MODELS:
            raise ValueError(f"measurement_model must be one of {MODELS}, "
                             f"got {cfg.measurement_model!r}")
        self.cfg = cfg
        self.fov = fov
        self.zones = zones
        self.lanes = lanes
        self.gp = ContourGP(contour_angles(), cfg.gp_sf, cfg.gp_length_rad, cfg.gp_sr,
                            cfg.gp_symmetry, cfg.mean_length, cfg.mean_width, cfg.gp_sl,
                            cfg.gp_sw)
        self.table = ContourTable.of(self.gp)
        gl, gw = rectangle_radius_gradient(self.gp.angles, cfg.mean_length, cfg.mean_width)
        #: random walk of the length / width (per second): a vehicle longer than its first
        #: view (a truck coming out of occlusion) grows into its length
        self.Q_size = (cfg.sigma_length_rw**2 * np.outer(gl, gl)
                       + cfg.sigma_width_rw**2 * np.outer(gw, gw))
        self.g_size = (gl, gw)
        #: long-vehicle prior mean contour minus the car's (decay target offset)
        self.long_shift = (rectangle_radius(self.gp.angles, cfg.long_length, cfg.long_width)
                           - self.gp.mu)
        self.w = ukf.UnscentedWeights.of(N_STATE, cfg.ukf_alpha, cfg.ukf_beta, cfg.ukf_kappa)
        self.cand_theta = 2.0 * np.pi * np.arange(cfg.n_candidates) / cfg.n_candidates
        self.cand_H, self.cand_mean, _ = self.table.interp(self.cand_theta)
        if cfg.n_candidates % 4:
            raise ValueError("n_candidates must be a multiple of 4 (samples on the axes)")
        self.axis_idx = np.arange(4) * (cfg.n_candidates // 4)
        #: GP conditional at the axis angles 0, pi/2, pi, 3 pi/2 (front, left, rear, right)
        self.axis_H, self.axis_mean, _ = self.table.interp(np.arange(4) * (np.pi / 2))
        self.x = np.zeros((0, N_STATE))
        self.P = np.zeros((0, N_STATE, N_STATE))
        self.recs: list[_Record] = []
        self.done: list[Track] = []
        #: ids of the reported tracks that ended inside the field of view, missed or
        #: diverged (not by leaving it, as duplicates or at the end of the recording)
        self.lost: set[int] = set()
        self.next_id = 0
        self.frame = -1
        self._corridor: np.ndarray | None = None
        #: (D,) detections of the frame inside a track's gate only by its growth with the
        #: centre's uncertainty that no chain took: kept from births (:meth:`_associate`)
        self._held: np.ndarray = np.zeros(0, dtype=bool)
        self.t = 0.0

    # ---------------------------------------------------------------------------------------
    def step(self, t: float, det: _Frame) -> None:
        """Advance to time t (s) and process one frame's dynamic detections."""
        self.frame += 1
        dt = t - self.t
        self.t = t
        if len(self.recs):
            self._predict(dt)
            self._end(self.fov.outside_distance(self.x[:, [X, Y]]) > self.cfg.fov_margin)
        owner, excess = self._associate(det)
        if self.cfg.blind_no_update and len(self.recs):
            # under the mast only vehicle tops are seen: their detections are kept from the
            # tracks (which coast) and from births
            blind = self.fov.blind(self.x[:, [X, Y]])
            owner = np.where((owner >= 0) & blind[np.maximum(owner, 0)], -2, owner)
        self._misfit(owner, excess, det.z, dt)
        self._reanchor(det, owner)
        updated = self._update(det, owner)
        self._long_vehicles(updated)
        self._span_length(det, owner, updated)
        self._record(t, det, owner, updated)
        self._births(det, (owner == -1) & ~self._held)
        self._manage(t)

    def finish(self) -> list[Track]:
        """End every live track; the confirmed tracks so far, by id."""
        self._end(np.ones(len(self.recs), dtype=bool))
        return sorted(self.done, key=lambda tr: tr.id)

    # ---------------------------------------------------------------------------------------
    def _predict(self, dt: float) -> None:
        cfg = self.cfg
        Xs = ukf.sigma_points(self.x, self.P, self.w)
        rows, inv = ukf.distinct_rows(Xs, N_KIN)
        Xs[..., :N_KIN] = ctra_predict(Xs[:, rows, :N_KIN], dt)[:, inv]
        f_new, Qc = self.gp.decay(Xs[..., N_KIN:], cfg.tau, dt)
        long = np.array([r.long for r in self.recs], dtype=bool)
        if long.any():
            # a long vehicle's contour decays towards the long rectangle, not the car's
            f_new[long] += (1.0 - np.exp(-cfg.tau * max(dt, 0.0))) * self.long_shift
        Xs[..., N_KIN:] = f_new
        Q = np.zeros_like(self.P)
        Q[:, :N_KIN, :N_KIN] = ctra_process_noise(self.x, dt, cfg.sigma_jerk, cfg.sigma_yaw_acc,
                                                  cfg.sigma_pos)
        Q[:, N_KIN:, N_KIN:] = Qc + max(dt, 0.0) * self.Q_size
        self.x, self.P = ukf.predict(Xs, Q, self.w)

    def _local(self, p: np.ndarray, excess: bool = True
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Points p (D, 2) in every track's vehicle frame: longitudinal, lateral offsets (T, D)
        (m) and the radial excess (T, D) (m) outside the predicted contour (< 0 inside; None
        unless ``excess``)."""
        dx = p[None, :, 0] - self.x[:, X, None]
        dy = p[None, :, 1] - self.x[:, Y, None]
        c, s = np.cos(self.x[:, YAW, None]), np.sin(self.x[:, YAW, None])
        lo = c * dx + s * dy
        la = -s * dx + c * dy
        if not excess:
            return lo, la, None
        dist = np.hypot(lo, la)
        # the contour only where it matters: far from a track (beyond its largest basis
        # radius + the widest gate) the excess is bounded below by dist - max radius
        f = self.x[:, N_KIN:]
        rmax = f.max(axis=1)[:, None]
        excess = dist - rmax
        ti, di = np.nonzero(dist < rmax + self.cfg.gate_max + self.cfg.gate_long_extra + 1.0)
        if len(ti):
            H, mean = self.table.interp_mean(np.arctan2(la[ti, di], lo[ti, di]))
            r = mean + np.sum(H * (f[ti] - self.gp.mu), axis=1)
            excess[ti, di] = dist[ti, di] - r
        return lo, la, excess

    def _outside(self, p: np.ndarray, excess: bool = True) -> tuple[np.ndarray, ...]:
        """For points p (D, 2) and every track: the distance (m) outside the contour's
        axis-aligned extent in the vehicle frame along (T, D) and across (T, D) the heading,
        the radial excess (T, D) (m) outside the contour (< 0 inside; None unless
        ``excess``) and the longitudinal offset (T, D) (m) from the centre."""
        lo, la, ex = self._local(p, excess)
        axes = self.axis_mean + (self.x[:, N_KIN:] - self.gp.mu) @ self.axis_H.T
        out_long = np.maximum(np.maximum(lo - axes[:, :1], -axes[:, 2:3] - lo), 0.0)
        out_lat = np.maximum(np.maximum(la - axes[:, 1:2], -axes[:, 3:4] - la), 0.0)
        return out_long, out_lat, ex, lo

    def _large(self) -> np.ndarray:
        """(T,) tracks whose contour is large (truck-like): length >= large_length or
        width >= large_width (from the basis radii on the axes)."""
        length, width = contour_length_width(self.x)
        return (length >= self.cfg.large_length) | (width >= self.cfg.large_width)

    def _associate(self, det: _Frame) -> tuple[np.ndarray, np.ndarray]:
        """Owner track index per detection (-1: none) and its radial excess (m) about that
        track's contour: least radial excess among the tracks
        whose gate holds it. The gate is the contour's axis-aligned extent in the vehicle frame
        grown by gate + 2 sigma_centre (<= gate_max) sideways and, for a large contour (length
        >= large_length or width >= large_width), by gate_long_extra more lengthwise (a
        vehicle longer than its contour so far, e.g. a truck, grows into it). With
        ``gate_doppler`` > 0 a detection whose Doppler differs from the track's predicted
        range rate at that point by more than gate_doppler + 3 sigma_v (m/s) is outside the
        gate too: vehicles passing each other in opposite directions stay apart. Beyond the
        contour's end by more than the gate before its growth with sigma_centre, a detection
        joins only through :meth:`_chain` (with ``chain_gap`` > 0), and one that does not
        is kept from births in this frame (``_held``)."""
        z = det.z
        self._corridor = None
        self._held = np.zeros(len(z), dtype=bool)
        if not len(self.recs) or not len(z):
            return np.full(len(z), -1, dtype=np.int64), np.zeros(len(z))
        cfg = self.cfg
        out_long, out_lat, ex, lo = self._outside(z)
        sig = np.sqrt(np.trace(self.P[:, :2, :2], axis1=1, axis2=2))
        gate = np.minimum(cfg.gate + 2.0 * sig, cfg.gate_max)[:, None]
        extra = np.where(self._large(), cfg.gate_long_extra, 0.0)[:, None]
        long_gate = gate + extra
        side = out_lat <= gate
        far = ~side | (out_long > long_gate)
        # lengthwise beyond the gate but within reach of a chain along the vehicle's axis
        reach = side & far & (out_long <= cfg.chain_reach)
        # inside the gate only by its growth with the centre's uncertainty: along the
        # heading, such a detection joins only as part of a chain (a young track's wide gate
        # would take the vehicle behind across an empty gap)
        loose = side & ~far & (out_long > cfg.gate + extra) & (cfg.chain_gap > 0.0)
        reach |= loose
        far |= loose
        if cfg.gate_doppler > 0.0:
            ti, di = np.nonzero(~far | reach)
            x = self.x[ti]
            pred = range_rate(z[di, None], det.rng[di, None], x[:, [X, Y]], x[:, V], x[:, YAW],
                              x[:, YAWRATE], self.fov.sensor)[:, 0]
            dgate = cfg.gate_doppler + 3.0 * np.sqrt(np.maximum(self.P[ti, V, V], 0.0))
            bad = np.abs(det.doppler[di] - pred) > dgate
            far[ti, di] |= bad
            reach[ti[bad], di[bad]] = False
            loose[ti[bad], di[bad]] = False
        loose_ex = np.where(loose, ex, np.inf)
        ex[far] = np.inf
        #: (T, D) detections beside a track beyond its gate lengthwise, up to chain_reach
        #: (Doppler-consistent), for :meth:`_occupied_length`
        self._corridor = reach
        owner = np.argmin(ex, axis=0)
        best = ex[owner, np.arange(len(z))]
        owner = np.where(np.isfinite(best), owner, -1)
        if cfg.chain_gap > 0.0:
            span = contour_length_width(self.x)[0] + 2.0 * (cfg.gate + extra[:, 0])
            self._chain(owner, best, reach, lo, loose_ex, span)
            self._held = (owner == -1) & np.isfinite(loose_ex).any(axis=0)
        return owner, best

    def _chain(self, owner: np.ndarray, excess: np.ndarray, reach: np.ndarray,
               lo: np.ndarray, loose_ex: np.ndarray, span: np.ndarray) -> None:
        """Grow associations along each track's axis (in place): free detections beside the
        contour (within the sideways gate, Doppler-consistent, up to ``chain_reach`` beyond
        its ends: ``reach`` (T, D)) join a track when they continue its associated detections
        lengthwise without a gap wider than ``chain_gap`` (m) -- the rest of a vehicle longer
        than its contour (a truck coming into view), never a vehicle behind it with a gap.
        lo (T, D): longitudinal offsets (m). loose_ex (T, D): the radial excess (m) of the
        detections in ``reach`` that are inside the gate only by its growth with the
        centre's uncertainty (inf for the others). Those join before the chain, gap or not,
        when the track's detections still span at most ``span`` (T,) (m: the contour's length
        plus the ungrown gate at both ends) lengthwise -- a shift of the contour within its
        uncertainty explains them; a track without associated detections starts from the one
        of them nearest its contour. A joined detection keeps that excess; beyond the gate
        it gets 0 (explained by the growth, not a misfit)."""
        gap = self.cfg.chain_gap
        for i in np.flatnonzero(reach.any(axis=1)):
            cand = np.flatnonzero(reach[i] & (owner < 0))
            if not len(cand):
                continue
            if not np.any(owner == i):
                first = cand[np.argmin(loose_ex[i, cand])]
                if not np.isfinite(loose_ex[i, first]):
                    continue
                owner[first], excess[first] = i, loose_ex[i, first]
            for sign in (1.0, -1.0):
                own = sign * lo[i, owner == i]
                c = cand[(owner[cand] < 0) & (sign * lo[i, cand] > own.max())]
                shift = np.isfinite(loose_ex[i, c]) & (sign * lo[i, c] <= own.min() + span[i])
                owner[c[shift]], excess[c[shift]] = i, loose_ex[i, c[shift]]
                end = max(float(own.max()), float(np.max(sign * lo[i, c[shift]], initial=-np.inf)))
                c = c[~shift & (sign * lo[i, c] > end)]
                c = c[np.argsort(sign * lo[i, c])]
                steps = np.diff(np.concatenate([[end], sign * lo[i, c]]))
                n = int(np.argmax(steps > gap)) if (steps > gap).any() else len(c)
                owner[c[:n]] = i
                excess[c[:n]] = np.where(np.isfinite(loose_ex[i, c[:n]]), loose_ex[i, c[:n]], 0.0)

    def _dense_contour(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Radii (T, m) (m) and points (T, m, 2) in C of the contours of states x (T, N_STATE)
        at the ``n_candidates`` dense angles ``cand_theta``."""
        r = self.cand_mean + (x[:, N_KIN:] - self.gp.mu) @ self.cand_H.T
        return r, contour_point(x[:, [X, Y]], x[:, YAW], r, self.cand_theta)

    def _misfit(self, owner: np.ndarray, excess: np.ndarray, z: np.ndarray, dt: float
                ) -> None:
        """Smoothed median offset (m) of each track's associated detections z (D, 2) from its
        predicted contour (the divergence monitor of :meth:`_manage`): the distance to the
        closest contour point, as the measurement rows measure it, and no more than the
        radial ``excess`` (0 for a detection the chain explains by the vehicle's growth). The
        radial excess alone grows with the contour's elongation: a 13 m truck's returns from
        inside its contour (its top, its far side) lie up to its half length inside along
        the ray from the centre but at most its half width from a side, and the 20 smooth
        radii bulge between a long contour's corners (``TrackingConfig.diverge_excess``)."""
        if not len(self.recs):
            return
        g = 1.0 - np.exp(-max(dt, 0.0) / max(self.cfg.diverge_time, 1e-6))
        mine = np.flatnonzero(owner >= 0)
        if not len(mine):
            return
        tracks, inv = np.unique(owner[mine], return_inverse=True)
        pts = self._dense_contour(self.x[tracks])[1]
        dist = contour_distance(z[mine, None], pts[inv])[:, 0]
        # per-track median of the offsets: sort by (track, offset), take the middle element(s)
        a = np.minimum(np.abs(excess[mine]), dist)
        a = a[np.lexsort((a, inv))]
        count = np.bincount(inv)
        start = np.concatenate([[0], np.cumsum(count)[:-1]])
        med = 0.5 * (a[start + (count - 1) // 2] + a[start + count // 2])
        for i, m in zip(tracks, med):
            rec = self.recs[i]
            rec.misfit += g * (float(m) - rec.misfit)

    def _aware_batch(self, tracks: np.ndarray, z: np.ndarray, valid: np.ndarray,
                     zall: np.ndarray, vall: np.ndarray) -> tuple[np.ndarray, ...]:
        """Sensor-aware rows of the tracks (T,) for their padded detections: z (T, K, 2) with
        mask valid (T, K) enter as normal-offset rows, each matched to the closest point of
        the contour part visible from the sensor (facing it, not self-occluded, inside the
        FOV and beyond the blind range) and measuring its offset along the normal there;
        zall (T, Ka, 2) / vall (T, Ka) are all the tracks' detections, whose extremes give the
        extent rows (``use_extent``): for a face seen at an incidence of at least
        ``extent_min_incidence``, whose detections cover at least ``extent_min_cover`` of it
        and whose ends are in view, the extreme detections along the face measure where the
        contour ends along that axis (a detection beyond the end by more than ``grow_margin``
        also inflates the size and centre covariance: the vehicle is larger than its contour,
        e.g. a truck coming into view). Returns the rows (T, K + 4): z, theta, normal, valid,
        Doppler mask, extra variance and the index into zall of the extent rows' detection
        (-1 for the normal rows)."""
        cfg = self.cfg
        sensor = self.fov.sensor
        x = self.x[tracks]
        T, K = valid.shape
        r, pts = self._dense_contour(x)
        vis = contour_candidates(pts, sensor)
        in_fov = self.fov.seen(pts, cfg.chain_fov_margin)
        use_fov = (vis & in_fov).any(axis=1, keepdims=True)
        vis = np.where(use_fov, vis & in_fov, vis)
        vis |= ~vis.any(axis=1, keepdims=True)
        slack = visibility_slack(z, sensor, cfg.sigma_range, np.deg2rad(cfg.sigma_azimuth_deg),
                                 cfg.visible_slack)
        theta, normal = closest_on_chain(z, pts, self.cand_theta, vis, slack)
        interior = interior_variance(z, valid, pts, theta, normal, sensor, cfg.sigma_range,
                                     np.deg2rad(cfg.sigma_azimuth_deg), cfg.sigma_contour,
                                     cfg.interior_sigmas)
        zr = np.concatenate([z, np.zeros((T, 4, 2))], axis=1)
        th = np.concatenate([theta, np.zeros((T, 4))], axis=1)
        nm = np.concatenate([normal, np.zeros((T, 4, 2))], axis=1)
        ok = np.concatenate([valid, np.zeros((T, 4), dtype=bool)], axis=1)
        dop_ok = ok.copy()
        jidx = np.full((T, K + 4), -1, dtype=np.int64)
        if cfg.use_extent:
            c = x[:, [X, Y]]
            h = unit(x[:, YAW])
            lat = np.stack([-h[:, 1], h[:, 0]], axis=1)
            rax = r[:, self.axis_idx]                          # front, left, rear, right
            srel = sensor - c
            s_lo, s_la = np.sum(srel * h, axis=1), np.sum(srel * lat, axis=1)
            dz = zall - c[:, None]
            lo, la = np.sum(dz * h[:, None], axis=2), np.sum(dz * lat[:, None], axis=2)
            axes = np.stack([h, lat, -h, -lat], axis=1)                       # (T, 4, 2)
            ends = c[:, None] + axes * rax[..., None]
            ok_end = self.fov.seen(ends)
            los = ends - sensor
            inc = (np.abs(np.sum(los * axes, axis=2))
                   / np.maximum(np.linalg.norm(los, axis=2), 1e-6))
            seen = np.stack([s_lo > rax[:, 0], s_la > rax[:, 1], s_lo < -rax[:, 2],
                             s_la < -rax[:, 3]], axis=1) & (inc >= cfg.extent_min_incidence)
            lo_max, lo_min = np.where(vall, lo, -np.inf), np.where(vall, lo, np.inf)
            la_max, la_min = np.where(vall, la, -np.inf), np.where(vall, la, np.inf)
            j = np.stack([lo_max.argmax(1), la_max.argmax(1), lo_min.argmin(1),
                          la_min.argmin(1)], axis=1)                          # (T, 4)
            span_lo = lo_max.max(1) - lo_min.min(1)
            span_la = la_max.max(1) - la_min.min(1)
            side = (seen[:, 1] | seen[:, 3]) & (span_lo >= cfg.extent_min_cover
                                                * (rax[:, 0] + rax[:, 2]))
            face = (seen[:, 0] | seen[:, 2]) & (span_la >= cfg.extent_min_cover
                                                * (rax[:, 1] + rax[:, 3]))
            enough = vall.sum(axis=1) >= cfg.extent_min_points
            zj = np.take_along_axis(zall, j[..., None], axis=1)                # (T, 4, 2)
            # sampling gap (m) between each row's extreme detection and the end it measures
            gap = np.zeros((T, 4))
            if cfg.extent_gap_correction:
                # lengthwise: n detections spanning span_lo leave span_lo / (n - 1) per end
                n_det = np.maximum(vall.sum(axis=1) - 1, 1)
                g_lo = np.where(np.isfinite(span_lo), span_lo, 0.0) / n_det
                gap[:, 0::2] = np.clip(g_lo, 0.0, cfg.extent_gap_max)[:, None]
            if cfg.extent_width_gap:
                # across the heading, at a side that is not seen: its extreme detection is one
                # of the n_f on the seen front / rear (within FACE_BAND of it), about
                # width / (n_f + 1) short of the corner (uniform samples; the contour's width,
                # not their span, which is azimuth noise far out)
                end_lo = np.where(seen[:, 0], rax[:, 0], -rax[:, 2])
                n_f = (vall & (np.abs(lo - end_lo[:, None]) < FACE_BAND)).sum(axis=1)
                g_la = np.clip((rax[:, 1] + rax[:, 3]) / (n_f + 1.0), 0.0, cfg.extent_gap_max)
                gap[:, 1::2] = np.where(seen[:, 1::2], 0.0, g_la[:, None])
            zm = zj + axes * gap[..., None]
            # an extreme detection next to the FOV's edge (or the blind range) may be where
            # the view is cut, not where the vehicle ends
            zin = ((self.fov.outside_distance(zj) < -cfg.extent_edge_margin)
                   & (np.linalg.norm(zj - sensor, axis=2)
                      > self.fov.min_range + cfg.extent_edge_margin))
            use = (np.stack([side, face, side, face], axis=1) & enough[:, None] & ok_end
                   & zin)
            zr[:, K:], nm[:, K:], ok[:, K:] = zm, axes, use
            th[:, K:] = np.arange(4) * (np.pi / 2)
            jidx[:, K:] = np.where(use, j, -1)
            beyond = np.where(use, np.sum(axes * (zj - ends), axis=2) - cfg.grow_margin, 0.0)
            for mode in (0, 1):
                ex = np.maximum(beyond[:, mode::2].max(axis=1), 0.0)
                if (ex > 0).any():
                    g = self.g_size[mode]
                    ax = axes[:, mode]
                    self.P[tracks, N_KIN:, N_KIN:] += (ex**2)[:, None, None] * np.outer(g, g)
                    self.P[tracks, :2, :2] += ((0.25 * ex**2)[:, None, None]
                                               * ax[:, :, None] * ax[:, None, :])
        extra_var = np.where(dop_ok, 0.0, cfg.sigma_extent**2)
        extra_var[:, :K] += interior
        return zr, th, nm, ok, dop_ok, extra_var, jidx

    def _reanchor(self, det: _Frame, owner: np.ndarray) -> None:
        """Re-place the box of each track in its first update (``birth_reanchor``): with at
        least twice its birth cluster's detections and ``extent_min_points``, those of them
        with a neighbour within ``cluster_eps`` (lone false alarms out) give the box a birth
        would give it along the track's heading (:func:`initial_kinematics`: the sensor-side
        edges at the detections', the size at least the contour's); it replaces the
        contour's rectangle when the centres lie more than ``init_sigma_pos`` (m) apart
        (within that, the update moves it); the birth row moves by the same change (the
        smoothers and the joint put their prior on a track's first state). Not for tracks in
        a heading-hypothesis group: re-placed, a wrong heading fitted the returns better and
        won the rivalry."""
        cfg = self.cfg
        if not cfg.birth_reanchor:
            return
        for i, rec in enumerate(self.recs):
            if rec.hits != 1 or rec.group >= 0:
                continue
            need = max(2 * rec.n_det, cfg.extent_min_points)
            k = np.flatnonzero(owner == i)
            if len(k) >= need:
                k = k[cluster_labels(det.z[k], cfg.cluster_eps, 2) >= 0]
            if len(k) < need:
                continue
            x = self.x[i]
            length, width = contour_length_width(x[None])
            centre, _, _, size = initial_kinematics(
                det.z[k], det.doppler[k], det.rng[k], float(x[YAW]), self.fov.sensor,
                float(length[0]), float(width[0]), float(x[V]), self._cluster_noise(det.rng[k]))
            if np.linalg.norm(centre - x[[X, Y]]) <= cfg.init_sigma_pos:
                continue
            change = np.zeros(N_STATE)
            change[[X, Y]] = centre - x[[X, Y]]
            change[N_KIN:] = (rectangle_radius(self.gp.angles, size[0], size[1])
                              - rectangle_radius(self.gp.angles, length[0], width[0]))
            self.x[i] += change
            rec.states[0] = rec.states[0] + change      # the birth row: the box re-placed

    def _cluster_noise(self, rng: np.ndarray) -> float:
        """Position noise std. dev. (m) of detections at the 3D ranges ``rng`` (m): the range
        noise or the azimuth noise's lateral spread at their mean range, the larger."""
        cfg = self.cfg
        return max(cfg.sigma_range, np.deg2rad(cfg.sigma_azimuth_deg) * float(np.mean(rng)))

    def _update(self, det: _Frame, owner: np.ndarray) -> np.ndarray:
        """UKF update of every track owning detections; returns their indices."""
        cfg = self.cfg
        tracks = np.unique(owner[owner >= 0])
        if not len(tracks):
            return tracks
        Mmax = cfg.max_detections_per_update
        aware = cfg.measurement_model == "sensor-aware"
        T = len(tracks)
        mine = np.flatnonzero(owner >= 0)
        pos = np.searchsorted(tracks, owner[mine])
        order = np.argsort(pos, kind="stable")
        didx, pos = mine[order], pos[order]                 # detections grouped by track
        counts = np.bincount(pos, minlength=T)
        start = np.concatenate([[0], np.cumsum(counts)[:-1]])
        Ka = int(counts.max())
        rank = np.arange(len(didx)) - start[pos]
        all_idx = np.zeros((T, Ka), dtype=np.int64)
        vall = np.zeros((T, Ka), dtype=bool)
        all_idx[pos, rank], vall[pos, rank] = didx, True
        M = min(Ka, Mmax)
        # a regular subsample of at most Mmax detections per track enters the update
        spread = np.rint(np.arange(M)[None, :] * ((counts - 1) / max(M - 1, 1))[:, None])
        pick = np.where(counts[:, None] > M, spread.astype(np.int64), np.arange(M)[None, :])
        idx = np.take_along_axis(all_idx, pick, axis=1)
        valid = np.take_along_axis(vall, pick, axis=1)
        z = det.z[idx]
        if aware:
            z, theta, normal, valid, dop_valid, extra_var, jidx = self._aware_batch(
                tracks, z, valid, det.z[all_idx], vall)
            idx = np.concatenate([idx, np.zeros((T, 4), dtype=np.int64)], axis=1)
            ext = jidx >= 0
            idx[ext] = np.take_along_axis(all_idx, np.maximum(jidx, 0), axis=1)[ext]
        else:
            theta = normal = dop_valid = extra_var = None
        rng = np.where(valid, det.rng[idx], 1.0)
        dop = np.where(valid, det.doppler[idx], 0.0)
        z = np.where(valid[..., None], z, 0.0)
        batch = DetectionBatch(z, rng, dop, valid, theta, normal, dop_valid, extra_var)
        x, P = self.x[tracks], self.P[tracks]
        Xs = ukf.sigma_points(x, P, self.w)
        sensor = self.fov.sensor
        Z = predict_measurements(Xs, batch, self.table, sensor, cfg.use_doppler)
        R = measurement_noise(batch, x, self.table, sensor, cfg.sigma_range,
                              np.deg2rad(cfg.sigma_azimuth_deg), cfg.sigma_contour,
                              cfg.sigma_doppler if cfg.use_doppler else None)
        x, self.P[tracks] = ukf.update(x, P, Xs, Z, measurement_vector(batch, cfg.use_doppler),
                                       R, self.w)
        for i, backwards in zip(tracks, x[:, V] < -cfg.reverse_speed):
            rec = self.recs[i]
            if backwards and not rec.reverse_run:
                rec.reverse_from = len(rec.states)
            rec.reverse_run = rec.reverse_run + 1 if backwards else 0
        self.x[tracks] = self._plausible(x)
        return tracks

    def _long_vehicles(self, updated: np.ndarray) -> None:
        """Long-vehicle hypothesis of the updated tracks (T,).

        Seen head-on or from behind, a vehicle's length is unobservable: its contour keeps
        the car-sized prior length and its centre sits half that length behind the seen
        face -- metres off for a truck. Its width is observed, and road vehicles wider than
        ``long_trigger_width`` are trucks and buses. A track is promoted once when its
        contour's width less half its std. dev. is at least that in ``long_wide_updates`` updates
        in a row while its misfit is at most ``long_max_misfit`` (noisy detections widen a
        face's extremes: far out, azimuth noise makes cars look wide), its long side was seen
        (sensor beyond it, sin(incidence) >= ``extent_min_incidence``) in fewer than
        ``long_side_updates`` updates and its contour is shorter than ``long_length``: the
        contour becomes ``long_length`` long, the centre
        moves away from the seen face by half the added length, and the covariance gains
        ``long_sigma_length``^2 along that joint (unobservable) direction. From then on its
        contour decays towards the long rectangle, and while its side stays unseen each
        update is followed by the length pseudo-measurement of :meth:`_length_prior`."""
        cfg = self.cfg
        if not len(updated) or cfg.long_length <= 0.0:
            return
        x = self.x[updated]
        q = self.gp.n // 4
        length, width = contour_length_width(x)
        iw = N_KIN + np.array([q, 3 * q])
        sd_w = np.sqrt(np.maximum(self.P[updated][:, iw][:, :, iw].sum(axis=(1, 2)), 0.0))
        h = unit(x[:, YAW])
        lat = np.stack([-h[:, 1], h[:, 0]], axis=1)
        rel = self.fov.sensor - x[:, [X, Y]]
        s_lo, s_la = np.sum(rel * h, axis=1), np.sum(rel * lat, axis=1)
        # a long side is seen when the sensor is beyond it at a useful incidence
        side_pt = x[:, [X, Y]] + lat * (np.sign(s_la) * 0.5 * width)[:, None]
        los = side_pt - self.fov.sensor
        inc = np.abs(np.sum(los * lat, axis=1)) / np.maximum(np.linalg.norm(los, axis=1), 1e-6)
        side = (np.abs(s_la) > 0.5 * width) & (inc >= cfg.extent_min_incidence)
        hold = []
        for k, i in enumerate(updated):
            rec = self.recs[i]
            rec.side_hits += int(side[k])
            unseen = rec.side_hits < cfg.long_side_updates
            if rec.long and unseen:
                hold.append(i)
            wide = ((width[k] - 0.5 * sd_w[k] >= cfg.long_trigger_width)
                    and rec.misfit <= cfg.long_max_misfit)
            rec.wide_run = rec.wide_run + 1 if wide else 0
            if (rec.long or rec.wide_run < cfg.long_wide_updates or not unseen
                    or length[k] >= cfg.long_length):
                continue
            rec.long = True
            grow = cfg.long_length - length[k]
            back = -np.sign(s_lo[k]) * h[k]            # away from the seen face
            f_new = rectangle_radius(self.gp.angles, cfg.long_length, width[k])
            f_old = rectangle_radius(self.gp.angles, length[k], width[k])
            d = np.zeros(N_STATE)
            d[[X, Y]] = 0.5 * back
            d[N_KIN:] = (f_new - f_old) / grow
            self.x[i] += grow * d
            self.P[i] += cfg.long_sigma_length**2 * np.outer(d, d)
        if hold:
            self._length_prior(np.asarray(hold))

    def _length_prior(self, tracks: np.ndarray) -> None:
        """Linear Kalman update of the tracks (T,) with the pseudo-measurement length
        (front + rear radius) = long_length +- long_sigma_length (m): while a long vehicle's
        side is unseen, the 20 smooth radii fit its seen face's corners best with a car-sized
        length, so without it the length would shrink back."""
        cfg = self.cfg
        a = np.zeros(N_STATE)
        a[[N_KIN, N_KIN + self.gp.n // 2]] = 1.0
        P = self.P[tracks]
        Pa = P @ a                                                      # (T, n)
        s = Pa @ a + cfg.long_sigma_length**2                           # (T,)
        K = Pa / s[:, None]
        target = np.maximum(cfg.long_length, [max(self.recs[i].span_length,
                                                   self.recs[i].occupied_length)
                                               for i in tracks])
        self.x[tracks] += K * (target - self.x[tracks] @ a)[:, None]
        self.P[tracks] = P - K[:, :, None] * Pa[:, None, :]

    def _span_length(self, det: _Frame, owner: np.ndarray, updated: np.ndarray) -> None:
        """Visible length over the track history (``span_history``): record each updated
        track's lengthwise detection span less twice the position noise along the heading,
        keep the ``span_quantile`` of the recent ones as ``span_length`` and grow a contour
        shorter than it by more than ``span_margin`` by ``span_gain`` of the shortfall,
        towards the end beyond which the detections reach farther (centre moved by half the
        growth, radii to the rectangle of the new length). The occupied length of
        :meth:`_occupied_length` grows a contour the same way, away from the end seen; the
        length its own detections reach there shrinks a contour longer than every bound
        towards the end seen (``occupancy_bound``). Sensor-aware model only (the plain model
        has no extent rows to hold the seen end)."""
        cfg = self.cfg
        if cfg.span_history <= 0 or not len(updated) or cfg.measurement_model != "sensor-aware":
            return
        sensor = self.fov.sensor
        q = self.gp.n // 4
        sig_az = np.deg2rad(cfg.sigma_azimuth_deg)
        for i in updated:
            rec, x = self.recs[i], self.x[i]
            h = unit(np.asarray(x[YAW]))
            end = self._occupied_length(rec, det, owner, i)
            if end:
                self._grow_toward_sensor(rec, i, end * h)
            f = x[N_KIN:]
            length = f[0] + f[2 * q]
            short_occ = rec.occupied_length - length if end else -np.inf
            z = det.z[owner == i]
            short = -np.inf
            if len(z) >= cfg.extent_min_points:
                lo = (z - x[[X, Y]]) @ h
                los = z - sensor
                r = np.maximum(np.linalg.norm(los, axis=1), 1e-6)
                cos_a = np.abs(los @ h) / r
                noise = median_inplace(np.hypot(cfg.sigma_range * cos_a, sig_az * r
                                                * np.sqrt(np.maximum(1.0 - cos_a**2, 0.0))))
                rec.spans.append(float(np.ptp(lo)) - 2.0 * noise)
                del rec.spans[:-cfg.span_history]
                rec.span_length = linear_quantile(rec.spans, cfg.span_quantile)
                short = rec.span_length - length
                beyond_front, beyond_rear = lo.max() - f[0], -lo.min() - f[2 * q]
                direction = h if beyond_front >= beyond_rear else -h
            # the occupied length takes over only where it reaches farther than the spans of
            # the track's own detections (its corridor holds more of the vehicle)
            if short_occ > short and (rec.occupied_length
                                      > rec.span_length + cfg.span_margin):
                short, direction = short_occ, -end * h
            if short <= cfg.span_margin:
                over = length - max(rec.reached_length, rec.occupied_length, rec.span_length)
                if not (end and cfg.occupancy_bound and over > cfg.span_margin
                        and rec.reached_length >= max(cfg.extent_min_cover * length,
                                                      cfg.mean_length)
                        and not (rec.long and rec.side_hits < cfg.long_side_updates)):
                    continue
                short, direction = -over, -end * h
            self._lengthen(i, cfg.span_gain * short, direction)

    def _lengthen(self, i: int, grow: float, direction: np.ndarray) -> None:
        """Lengthen track i's contour by ``grow`` (m; < 0 shortens) towards the unit vector
        ``direction`` along its heading: the centre moves by half of it, the radii by the
        change of the rectangle of that length and the contour's width (the other end stays
        put)."""
        length, width = contour_length_width(self.x[i:i + 1])
        self.x[i, [X, Y]] += 0.5 * grow * direction
        self.x[i, N_KIN:] += (rectangle_radius(self.gp.angles, length[0] + grow, width[0])
                              - rectangle_radius(self.gp.angles, length[0], width[0]))

    def _grow_toward_sensor(self, rec: _Record, i: int, toward: np.ndarray) -> None:
        """Grow track i's contour towards the sensor (unit vector ``toward``, along its
        heading) when the pooled end-on detections continue its vehicle beyond the seen end
        (``rec.toward_length``: from detections within its half width and
        TOWARD_SIDE_MARGIN sideways) by more than ``span_margin`` plus twice the range noise
        that spreads the seen face's own returns there, once it has ``span_history``
        updates (a young track's heading and place may still be another vehicle's): by
        ``span_gain`` of that excess, the
        far end staying put, the pooled distances shifted to the new seen end. A track born
        on a vehicle's far part -- a truck passing the sensor enters the FOV front first and
        recedes end-on -- so takes its near part, and a second track born there becomes its
        duplicate (``occupancy_toward``)."""
        cfg = self.cfg
        excess = rec.toward_length - 2.0 * cfg.sigma_range
        if (not cfg.occupancy_toward or excess <= cfg.span_margin
                or rec.hits < cfg.span_history):
            return
        grow = cfg.span_gain * excess
        self._lengthen(i, grow, toward)
        end = rec.occupancy[-1][1]
        rec.occupancy = [(fr, e, v + grow if e == end else v, o, b)
                         for fr, e, v, o, b in rec.occupancy]
        if not rec.toward_rows and rec.hits <= 2 * cfg.span_history:
            rec.toward_rows = len(rec.states)       # a young track: born on the far part

    def _occupied_length(self, rec: _Record, det: _Frame, owner: np.ndarray, i: int) -> int:
        """Occupied length of track i while one end of its vehicle faces the sensor (the
        sensor beyond its front or rear: the length is unobservable in one frame, a truck's
        long side shows at grazing incidence with a few returns, most of them outside the
        gate of a car-sized contour). The distances (m) behind the seen end of its detections
        and of the Doppler-consistent detections in its lengthwise corridor (beside the
        contour, up to ``chain_reach`` beyond its ends; free or held by another track, e.g.
        a second track on a truck's other end; not those in the blind range; counted within
        its half width and TOWARD_SIDE_MARGIN sideways only) are kept from
        the end-on updates of the last ``span_history`` frames; pooled, they fill the
        vehicle's side densely, and the occupied length is where the sorted distances first
        leave a gap wider than
        ``occupancy_gap`` (a following vehicle leaves an empty band that no frame fills),
        less its last ``occupancy_min_points`` detections (``rec.occupied_length``: reached
        by that many; 0 without); ``rec.reached_length``: the distance that many of the
        track's own pooled detections reach, gaps or not. End-on: the sensor beyond the
        front or rear and sin(angle between the line of sight and the heading) at most
        ``occupancy_max_incidence`` (there the lengthwise position is nearly the precise
        range); ``occupancy_young_incidence`` until the track has ``occupancy_min_updates``
        updates. Returns the end seen (+1 front, -1 rear) or 0 (not end-on, or off)."""
        cfg = self.cfg
        if cfg.occupancy_gap <= 0.0 or self._corridor is None:
            return 0
        x = self.x[i]
        c, h = x[[X, Y]], unit(np.asarray(x[YAW]))
        front, rear = x[N_KIN], x[N_KIN + self.gp.n // 2]
        rel = self.fov.sensor - c
        s_lo = float(rel @ h)
        end = 1 if s_lo > front else (-1 if s_lo < -rear else 0)
        # sin of the angle between the line of sight and the heading (the side's incidence)
        most = (cfg.occupancy_max_incidence if rec.hits >= cfg.occupancy_min_updates
                else min(cfg.occupancy_max_incidence, cfg.occupancy_young_incidence))
        if not end or abs(rel[0] * h[1] - rel[1] * h[0]) > most * float(np.linalg.norm(rel)):
            return 0
        sel = (owner == i) | (self._corridor[i] & (owner != -2))
        lo = (det.z[sel] - c) @ h
        # within the contour's half width and TOWARD_SIDE_MARGIN sideways: its own side, not
        # a neighbour in the next lane that a young track's wide gate takes in
        width = contour_length_width(x[None])[1][0]
        beside = np.abs((det.z[sel] - c) @ np.array([-h[1], h[0]])) <= (
            0.5 * width + TOWARD_SIDE_MARGIN)
        behind = front - lo if end > 0 else lo + rear      # this frame's, behind the seen end
        rec.occupancy.append((self.frame, end, behind, owner[sel] == i, beside))
        # the last span_history frames only: an entry from before a long side-on phase
        # (a turn, a young track's heading) measured along another heading
        rec.occupancy = [o for o in rec.occupancy if self.frame - o[0] < cfg.span_history]
        same = [o for o in rec.occupancy if o[1] == end]
        d = np.concatenate([[0.0]] + [o[2] for o in same])
        own = np.concatenate([[True]] + [o[3] for o in same])
        near = np.concatenate([[True]] + [o[4] for o in same])       # beside the contour
        beyond = d[near]
        k = cfg.occupancy_min_points
        # pooled, up to the first gap; no farther than this frame's detections reach (the
        # pool's older entries were measured from a seen end the updates have moved since)
        rec.toward_length = min(
            _connected_reach(np.sort(-beyond[beyond < 0.0]), cfg.occupancy_gap, k),
            float(-np.min(behind[beside], initial=0.0)))
        # the track's own detections, and of the others those beside its contour
        keep = (d >= 0.0) & (own | near)
        d, own = d[keep], own[keep]
        order = np.argsort(d)
        d, own = d[order], own[order]
        rec.occupied_length = _connected_reach(d, cfg.occupancy_gap, k)
        reached = d[own]
        rec.reached_length = float(reached[-k]) if len(reached) > k else 0.0
        return end

    def _plausible(self, x: np.ndarray) -> np.ndarray:
        """States (T, n) clipped to road-vehicle limits: 0 <= v <= max_speed, |a| <= max_accel,
        |yawrate| <= max_yawrate, radii >= min_radius (a UKF update can overshoot them)."""
        cfg = self.cfg
        x = x.copy()
        x[:, V] = np.clip(x[:, V], 0.0, cfg.max_speed)
        x[:, A] = np.clip(x[:, A], -cfg.max_accel, cfg.max_accel)
        x[:, YAWRATE] = np.clip(x[:, YAWRATE], -cfg.max_yawrate, cfg.max_yawrate)
        x[:, N_KIN:] = np.maximum(x[:, N_KIN:], cfg.min_radius)
        return x

    def _record(self, t: float, det: _Frame, owner: np.ndarray, updated: np.ndarray) -> None:
        store = self.cfg.store_covariances
        xs = self.x.copy()                          # one copy per frame, rows per track
        Ps = self.P.copy() if store else None
        len_var = length_variance(self.P)
        length = contour_length_width(xs)[0]
        for i, rec in enumerate(self.recs):
            rec.t.append(t)
            rec.states.append(xs[i])
            rec.len_var.append(float(len_var[i]))
            rec.held.append(rec.long and rec.side_hits < self.cfg.long_side_updates)
            occ = rec.occupied_length
            reached = (occ >= self.cfg.large_length
                       and rec.span_length + self.cfg.span_margin < occ
                       <= length[i] + self.cfg.span_margin)
            rec.occupied.append(occ if reached else 0.0)
            if rec.misfit <= 0.5 * self.cfg.diverge_excess:
                rec.calm_step = len(rec.t) - 1
            if Ps is not None:
                rec.covs.append(Ps[i])
        for i in updated:
            rec = self.recs[i]
            idx = det.index[owner == i]
            step = len(rec.t) - 1
            rec.det_index.append(idx)
            rec.det_step.append(np.full(len(idx), step, dtype=np.int64))
            rec.hits += 1
            rec.n_det += len(idx)
            rec.last_update_t = self.t
            rec.last_update_step = step

    def _births(self, det: _Frame, free: np.ndarray) -> None:
        cfg = self.cfg
        idx = np.flatnonzero(free)
        if len(idx) < cfg.cluster_min_points:
            return
        lab = cluster_labels(det.z[idx], cfg.cluster_eps, cfg.cluster_min_points)
        sensor = self.fov.sensor
        dist = np.linalg.norm(det.z[idx] - sensor, axis=1)
        # free detections in the range withheld from births (next to the blind range)
        withheld = idx[dist < self.fov.min_range + cfg.birth_blind_margin]
        # clusters in order of range: a vehicle split in two is born first (a lower id: the
        # stronger under the duplicate rule) from its nearer part, whose sensor-side end is
        # its own
        n_clusters = int(lab.max(initial=-1)) + 1
        for c in np.argsort([dist[lab == c].mean() for c in range(n_clusters)]):
            k = idx[lab == c]
            z, dop, rng = det.z[k], det.doppler[k], det.rng[k]
            centroid = z.mean(axis=0)
            if (np.linalg.norm(centroid - sensor)
                    < self.fov.min_range + cfg.birth_blind_margin):
                continue
            zone = self.zones.locate(centroid)
            if zone is None and not cfg.birth_anywhere:
                continue
            los = (centroid - sensor) / max(float(np.linalg.norm(centroid - sensor)), 1e-6)
            md = float(np.mean(dop))
            yaw_sigma = np.deg2rad(cfg.init_sigma_yaw_deg)
            # the lane the cluster is on, else the zone's: a zone's disc may hold other
            # lanes than the one whose entry it marks (a junction box near the sensor)
            yaws = self.lanes.headings_near(
                centroid, cfg.lane_search_radius, z, dop, rng, sensor, cfg.birth_sigma_doppler,
                cfg.max_speed, cfg.max_yawrate, cfg.birth_hypotheses,
                cfg.birth_hypothesis_margin, np.deg2rad(cfg.birth_hypothesis_sep_deg))
            if not len(yaws) and zone is not None:
                yaws = self.zones.yaw[[zone]]
            if not len(yaws):
                yaws = np.array([np.arctan2(los[1], los[0]) + (0.0 if md > 0 else np.pi)])
                yaw_sigma = LOS_YAW_SIGMA
            # the vehicle may go on into the withheld range: born once it has left it
            near = withheld[~np.isin(withheld, k)]
            if self._continues_into(z, md, float(yaws[0]), det.z[near], det.doppler[near]):
                continue
            group = self.next_id if len(yaws) > 1 else -1
            for yaw in yaws:
                self._birth(det, k, z, dop, rng, float(yaw), yaw_sigma, zone, group)

    def _continues_into(self, z: np.ndarray, doppler: float, yaw: float,
                        near_z: np.ndarray, near_doppler: np.ndarray) -> bool:
        """Whether a birth cluster z (k, 2) (mean Doppler ``doppler``, m/s; heading prior
        ``yaw``, rad) may continue towards the sensor into the detections ``near_z`` (m, 2)
        (Doppler ``near_doppler`` (m,)): free ones in the range withheld from births (closer
        than ``min_range + birth_blind_margin``). Seen end-on
        (the sensor beyond one of its ends along the heading), one of them of the same Doppler
        sign lies in its lengthwise corridor (its lateral extent grown by ``cluster_eps``)
        beyond its sensor-side end, within ``mean_length + chain_reach`` (m; the longest the
        association grows a track to) of its far end. Such a cluster waits: a sparse vehicle
        leaving the blind range splits into a withheld cluster on its rear and a few returns
        at its front, and born from those its box's sensor-side end (the cluster's) was metres
        ahead of the vehicle's (far-sparse: 2.5-6.6 m in the track's first second)."""
        if not len(near_z):
            return False
        cfg = self.cfg
        h = unit(np.asarray(yaw))
        axes = np.stack([h, [-h[1], h[0]]])
        q, qn, s = z @ axes.T, near_z @ axes.T, axes @ self.fov.sensor
        lo, hi = q.min(axis=0), q.max(axis=0)
        if lo[0] <= s[0] <= hi[0]:
            return False
        # lengthwise coordinate growing towards the sensor: the cluster spans [u0, u1]
        toward = 1.0 if s[0] > hi[0] else -1.0
        u, (u0, u1) = toward * qn[:, 0], sorted((toward * lo[0], toward * hi[0]))
        inside = ((qn[:, 1] >= lo[1] - cfg.cluster_eps) & (qn[:, 1] <= hi[1] + cfg.cluster_eps)
                  & (np.sign(near_doppler) == np.sign(doppler)))
        return bool(np.any(inside & (u > u1) & (u - u0 <= cfg.mean_length + cfg.chain_reach)))

    def _birth(self, det: _Frame, k: np.ndarray, z: np.ndarray, dop: np.ndarray,
               rng: np.ndarray, yaw: float, yaw_sigma: float, zone: int | None,
               group: int = -1) -> None:
        """A tentative track from the detections k (indices into the frame) z, dop, rng with
        the heading prior yaw (rad) +- yaw_sigma, in the heading-hypothesis group ``group``
        (-1: none)."""
        cfg = self.cfg
        sensor = self.fov.sensor
        centre, yaw, v, size = initial_kinematics(z, dop, rng, yaw, sensor, cfg.mean_length,
                                                  cfg.mean_width, cfg.default_speed,
                                                  self._cluster_noise(rng))
        x0 = np.zeros(N_STATE)
        x0[[X, Y]] = centre
        x0[V], x0[YAW] = v, yaw
        x0[N_KIN:] = rectangle_radius(self.gp.angles, size[0], size[1])
        P0 = np.zeros((N_STATE, N_STATE))
        P0[:N_KIN, :N_KIN] = np.diag(np.square([
            cfg.init_sigma_pos, cfg.init_sigma_pos, cfg.init_sigma_speed,
            cfg.init_sigma_accel, yaw_sigma, cfg.init_sigma_yawrate]))
        P0[N_KIN:, N_KIN:] = self.gp.K
        rec = _Record(self.next_id, self.frame, zone is not None, self.t, group=group,
                      n_det=len(k))
        self.next_id += 1
        rec.t.append(self.t)
        rec.states.append(x0.copy())
        rec.len_var.append(float(length_variance(P0)))
        rec.held.append(False)
        rec.occupied.append(0.0)
        if cfg.store_covariances:
            rec.covs.append(P0.copy())
        rec.det_index.append(det.index[k])
        rec.det_step.append(np.zeros(len(k), dtype=np.int64))
        rec.hits, rec.last_update_step = 1, 0
        self.recs.append(rec)
        self.x = np.vstack([self.x, x0[None]])
        self.P = np.concatenate([self.P, P0[None]])

    def _manage(self, t: float) -> None:
        cfg = self.cfg
        n = len(self.recs)
        if not n:
            return
        end = np.zeros(n, dtype=bool)
        # duplicates: a centre within gate sideways / duplicate_long lengthwise of a stronger
        # track's contour extent -> the weaker one dies
        out_long, out_lat, _, _ = self._outside(self.x[:, [X, Y]], excess=False)
        dup = (out_lat <= cfg.gate) & (out_long <= cfg.duplicate_long)
        np.fill_diagonal(dup, False)
        group = np.array([r.group for r in self.recs])
        dup &= ~((group[:, None] == group[None, :]) & (group[:, None] >= 0))
        end |= self._rivals(group)
        rank = np.array([(r.confirmed, r.hits, -r.id) for r in self.recs],
                        dtype=[("c", bool), ("h", int), ("i", int)])
        order = np.argsort(rank, order=("c", "h", "i"))[::-1]          # strongest first
        pos = np.empty(n, dtype=np.int64)
        pos[order] = np.arange(n)
        for j in order:
            end[j] |= bool(np.any(dup[:, j] & ~end & (pos < pos[j])))
        # a duplicate followed part of a vehicle a stronger track follows: not reported
        silent = end.copy() if cfg.drop_duplicates else np.zeros(n, dtype=bool)
        blind = self.fov.blind(self.x[:, [X, Y]])
        wide = contour_length_width(self.x)[1] > cfg.max_width
        for i, rec in enumerate(self.recs):
            reverse = 0 < cfg.reverse_updates <= rec.reverse_run
            if rec.misfit > cfg.diverge_excess or wide[i] or reverse:
                # diverged: no longer one vehicle (or heading against it); reported up to
                # its last calm row (before it turned against its vehicle)
                rec.last_update_step = min(rec.last_update_step, rec.calm_step)
                if reverse:
                    rec.last_update_step = min(rec.last_update_step, rec.reverse_from - 1)
                end[i] = rec.lost = True
                continue
            if rec.confirmed:
                patience = cfg.delete_after_blind if blind[i] else cfg.delete_after
                rec.lost = t - rec.last_update_t > patience
                end[i] |= rec.lost
                continue
            hits, window = self._confirmation(rec)
            if rec.hits >= hits:
                rec.confirmed = True
            elif self.frame - rec.birth_frame >= window - 1:
                end[i] = True
        self._end(end, silent)

    def _confirmation(self, rec: _Record) -> tuple[int, int]:
        """(hits, window frames) that confirm the tentative track ``rec``: born in a birth
        zone or anywhere else."""
        cfg = self.cfg
        if rec.in_zone:
            return cfg.confirm_hits_zone, cfg.confirm_window_zone
        return cfg.confirm_hits_anywhere, cfg.confirm_window_anywhere

    def _rivals(self, group: np.ndarray) -> np.ndarray:
        """(n,) tracks that lose their heading-hypothesis rivalry: in a group (tracks born
        from one cluster with different headings, ``group`` (n,)) of which a track has reached
        its confirmation hits, every track but the one with the most detections associated
        since birth (ties: the smaller misfit) ends; the winner leaves the group. Its rivals
        with a wrong heading drift off the vehicle and take fewer of its detections."""
        lose = np.zeros(len(group), dtype=bool)
        for g in np.unique(group[group >= 0]):
            members = np.flatnonzero(group == g)
            recs = [self.recs[i] for i in members]
            ready = [r.hits >= self._confirmation(r)[0] for r in recs]
            if len(members) > 1 and not any(ready):
                continue
            best = min(range(len(recs)), key=lambda a: (-recs[a].n_det, recs[a].misfit))
            lose[members] = True
            lose[members[best]] = False
            recs[best].group = -1
        return lose

    def _end(self, mask: np.ndarray, silent: np.ndarray | None = None) -> None:
        """End the tracks in ``mask``; report the confirmed ones with enough updates up to
        their last reported row unless ``silent``."""
        if not mask.any():
            return
        for i in np.flatnonzero(mask):
            rec = self.recs[i]
            if silent is not None and silent[i]:
                continue
            hits = sum(len(s) > 0 and s[0] <= rec.last_update_step for s in rec.det_step)
            if rec.confirmed and hits >= self.cfg.min_output_hits:
                self.done.append(self._to_track(rec))
                if rec.lost:
                    self.lost.add(rec.id)
        keep = ~mask
        self.recs = [r for r, k in zip(self.recs, keep) if k]
        self.x, self.P = self.x[keep], self.P[keep]

    def _to_track(self, rec: _Record) -> Track:
        n = rec.last_update_step + 1
        states = retrodict_length(np.asarray(rec.states[:n]), np.sqrt(rec.len_var[:n]),
                                  self.fov.sensor, self.cfg.retrodict_window,
                                  self.cfg.retrodict_max_sd, np.asarray(rec.held[:n]),
                                  np.asarray(rec.occupied[:n]) > 0.0,
                                  np.arange(n) < rec.toward_rows, np.asarray(rec.t[:n]))
        det_step = np.concatenate(rec.det_step).astype(np.int64)
        kept = det_step < n
        return Track(
            id=rec.id,
            t=np.asarray(rec.t[:n]),
            states=states,
            labels=kappa_labels(states, self.cfg.eta, self.cfg.label_min_speed),
            covariances=np.asarray(rec.covs[:n]) if self.cfg.store_covariances else None,
            det_index=np.concatenate(rec.det_index).astype(np.int64)[kept],
            det_step=det_step[kept],
            length_floor=max(rec.occupied[:n], default=0.0),
        )


def _frames(scn: Scenario, T: np.ndarray, doppler_min: float,
            sensor3: np.ndarray) -> tuple[np.ndarray, list[_Frame]]:
    """Frame times (F,) and each frame's dynamic detections in C."""
    radar = scn.radar
    fid = radar.frame_ids()
    order = np.argsort(fid, kind="stable")
    fid_sorted = fid[order]
    first = np.flatnonzero(np.concatenate([[True], np.diff(fid_sorted) != 0]))
    times = radar.t[order[first]]
    bounds = np.append(first, len(order))
    pC = radar.xyz @ T[:3, :3].T + T[:3, 3]
    rng = np.linalg.norm(pC - sensor3, axis=1)
    dyn = np.abs(radar.doppler) >= doppler_min
    frames = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        idx = order[a:b]
        idx = idx[dyn[idx]]
        frames.append(_Frame(pC[idx, :2], rng[idx], radar.doppler[idx], idx.astype(np.int64)))
    return times, frames


def track_scenario(scn: Scenario, T_coarse: np.ndarray, cfg: TrackingConfig | None = None, *,
                   measurement_model: str | None = None) -> TrackSet:
    """Track every vehicle of a scenario in the coarse frame C.

    T_coarse: 4x4 S -> L estimate (pass the true sensor pose for oracle tracking: C == L).
    Birth zones come from ``cfg.birth_zones`` (L) or the lanelet map and the FOV of
    ``scn.sensor`` (hfov_deg, max_range) seen from T_coarse. Returns the confirmed tracks of
    motor vehicles in frame "C" with T_frame_to_L = identity (fine registration fills it
    later); those of other road users (:mod:`fgloc.tracking.road_users`: by size, speed and,
    on maps with lanelets no motor vehicle may drive, where they run) are dropped, their ids in
    the diagnostics' ``not_motor_vehicles`` (``off_lane``: those the map's other ways told;
    ``off_road``: those off every drivable lanelet; ``hidden``: those behind the ALS's
    buildings, seen from the sensor; ``off_lane_doubted``: those any of the three rules would
    have told, kept with the placement doubted).
    measurement_model ("sensor-aware" or "plain") overrides cfg.measurement_model.
    """
    t0 = time.perf_counter()
    cfg = cfg or TrackingConfig()
    if measurement_model is not None:
        cfg = dataclasses.replace(cfg, measurement_model=measurement_model)
    T = np.asarray(T_coarse, dtype=float)
    fov = FieldOfView.of(T, scn.sensor.hfov_deg, scn.sensor.max_range, scn.sensor.vfov_deg,
                         cfg.reflection_height)
    lanelets = scn.lanelets.lanelets
    zones = (BirthZones.explicit(cfg.birth_zones) if cfg.birth_zones is not None
             else BirthZones.from_map(lanelets, fov, cfg.birth_zone_radius, cfg.birth_zone_depth))
    tracker = Tracker(cfg, fov, zones, LaneHeadings.of(lanelets))
    times, frames = _frames(scn, T, cfg.doppler_min, T[:3, 3])
    if len(times):
        tracker.t = float(times[0])
    for t, det in zip(times, frames):
        tracker.step(float(t), det)
    tracks, links = relink(tracker.finish(), tracker.lost, times, cfg)
    ways = MapWays.of(scn.lanelets, T[:2, 3], scn.sensor.max_range + WAYS_MARGIN)
    # hidden_share >= 1 drops no track: the buildings' grid is not needed then
    buildings = (Buildings.of(scn.als, T[:2, 3], scn.sensor.max_range + WAYS_MARGIN)
                 if cfg.hidden_share < 1.0 else None)
    users = split_road_users(tracks, cfg, ways,
                             None if buildings is None else Sight(T[:3, 3], buildings))
    tracks = users.vehicles
    diag = {
        "measurement_model": cfg.measurement_model,
        "frames": len(times),
        "tracks": len(tracks),
        "not_motor_vehicles": [tr.id for tr in users.others],
        "off_lane": users.off_lane,
        "off_road": users.off_road,
        "hidden": users.hidden,
        "off_lane_doubted": users.doubted,
        "relinked": [[k.first, k.then] for k in links],
        "relinked_stands": [[k.first, k.then] for k in links if k.stand],
        "birth_zones": np.column_stack([zones.centre, zones.radius,
                                        np.rad2deg(zones.yaw)]).tolist(),
        "seconds": time.perf_counter() - t0,
    }
    return TrackSet(tracks, frame="C", T_frame_to_L=np.eye(3), diagnostics=diag)
