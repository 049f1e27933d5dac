"""GTSAM factor graph of GP-EOT tracks: the reusable builder of the smoothers (and of the joint
registration, which adds the sensor pose and point factors to the same graph).

Everything is in the tracks' 2D frame (frame C of the placement, m, rad). One variable per
track and step, key :func:`factors.gtsam_factors.track_key` ``(track.id, step)``, a 26-vector
``[x, y, v, a, yaw, yawrate, r_0..r_19]`` (the :mod:`fgloc.tracks` state layout). Per track:

* a prior on step 0: the filter's state and covariance there (its birth state and P0; without
  stored covariances, P0 rebuilt from the ``[tracking]`` init sigmas and the GP kernel);
* a process factor between consecutive steps: CTRA + contour decay + the length / width random
  walk, the tracker's process noise (``[tracking]`` sigma_jerk, sigma_yaw_acc, sigma_pos, the
  contour forgetting rate ``[smoothing] contour_tau`` (default: the tracker's tau),
  sigma_length_rw, sigma_width_rw), evaluated around the filter's state at the earlier step;
* a stacked contour measurement factor per step with detections (``Track.det_index`` /
  ``det_step``: the filter's association), sensor-aware normal offsets with the association
  re-done at every linearization, per-row radar noise and Huber IRLS weights
  (:func:`factors.gtsam_factors.contour_measurement_factor`).

Long vehicles (trucks, buses; :class:`TrackModels`) get the tracker's long-vehicle contour
model -- GP mean the ``long_length`` x ``long_width`` rectangle -- and, on their first step,
that GP's contour prior instead of the filter's car-sized birth contour. Smoothed states that
drive backwards are turned round (:func:`turn_round`).

Usage::

    det_xy, sensor_xy = placed_detections(scn, T_placement)     # all radar rows in C
    trusted = extent_trusted(scn, T_placement, det_xy, tracking_cfg)   # optional
    tg = build_track_graph(tracks, det_xy, sensor_xy, smoothing_cfg, tracking_cfg, trusted)
    result = gtsam.LevenbergMarquardtOptimizer(tg.graph, tg.values, params).optimize()
    smoothed = tracks_from_values(tracks, result, tg.keys, tracking_cfg)

:class:`TrackModel` makes the individual factors (the fixed-lag smoother adds them step by
step).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import gtsam
import numpy as np

from factors.ctra import ctra_predict
from factors.gp import ContourGP, rectangle_radius_gradient
from factors.gtsam_factors import (
    ConditionalTable,
    ContourMeasurement,
    ExtentRows,
    ExtentSettings,
    RangeRateRows,
    contour_measurement_factor,
    prior_factor,
    process_covariance,
    process_factor,
    track_key,
)
from factors.track_system import sqrt_information
from fgloc.geo import wrap_angle
from fgloc.labels import kappa_labels
from fgloc.scenario import Scenario
from fgloc.smoothing.config import SmoothingConfig
from fgloc.smoothing.length_floor import length_floor_factor
from fgloc.smoothing.standing import StandingTracks, stand_jacobian, standing_factor
from fgloc.tracking.birth import FieldOfView
from fgloc.tracking.config import TrackingConfig
from fgloc.tracks import (
    N_CONTOUR,
    N_KIN,
    N_STATE,
    YAW,
    YAWRATE,
    A,
    Track,
    TrackSet,
    V,
    contour_angles,
    contour_length_width,
)

#: added to the diagonal of a prior covariance taken from the filter (state units squared)
_PRIOR_JITTER = 1e-9


def contour_gp(tcfg: TrackingConfig, long: bool = False) -> ContourGP:
    """The tracker's GP contour model (same kernel, mean shape and basis angles); ``long``:
    its long-vehicle variant, mean shape the ``long_length`` x ``long_width`` rectangle."""
    length, width = ((tcfg.long_length, tcfg.long_width) if long
                     else (tcfg.mean_length, tcfg.mean_width))
    return ContourGP(contour_angles(), tcfg.gp_sf, tcfg.gp_length_rad, tcfg.gp_sr,
                     tcfg.gp_symmetry, length, width, tcfg.gp_sl, tcfg.gp_sw)


def placed_detections(scn: Scenario, T_placement: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All radar rows of ``scn`` placed in frame C by the 4x4 S -> L pose ``T_placement``
    (the pose the tracker used): ``(det_xy (N, 2), sensor_xy (2,))`` in m, rows in the order
    of ``scn.radar`` (so ``Track.det_index`` indexes them)."""
    T = np.asarray(T_placement, dtype=float)
    xy = scn.radar.xyz @ T[:2, :3].T + T[:2, 3]
    return xy, T[:2, 3].copy()


def detection_range_rates(scn: Scenario) -> np.ndarray:
    """(N, 2) Doppler (m/s) and 3D range (m, > 0) of every radar row of ``scn`` (the inputs
    of the range-rate rows; a rigid placement keeps the range)."""
    rng = np.maximum(np.linalg.norm(scn.radar.xyz, axis=1), 1e-3)
    return np.column_stack([np.asarray(scn.radar.doppler, dtype=float), rng])


def extent_trusted(scn: Scenario, T_placement: np.ndarray, det_xy: np.ndarray,
                   tracking: TrackingConfig | None = None) -> np.ndarray:
    """(N,) bool: detections (N, 2) in C that may mark a vehicle's end in an extent row: more
    than ``tracking.extent_edge_margin`` (m) inside the field of view (``scn.sensor`` hfov,
    max range, vfov seen from ``T_placement``) and beyond the near blind range by as much
    (the tracker's rule: at the FOV's edge the view of a face may be cut)."""
    c = tracking or TrackingConfig()
    fov = FieldOfView.of(np.asarray(T_placement, dtype=float), scn.sensor.hfov_deg,
                         scn.sensor.max_range, scn.sensor.vfov_deg, c.reflection_height)
    far = np.linalg.norm(det_xy - fov.sensor, axis=1) > fov.min_range + c.extent_edge_margin
    return (fov.outside_distance(det_xy) < -c.extent_edge_margin) & far


def regular_subsample(n: int, m: int) -> np.ndarray:
    """Indices of at most ``m`` regularly spaced items of ``n`` (all when ``m`` is 0 or >= n)."""
    if m <= 0 or n <= m:
        return np.arange(n)
    return np.unique(np.rint(np.linspace(0, n - 1, m)).astype(np.int64))


@dataclass(frozen=True)
class TrackModel:
    """The factors of one track model: tracker noise (``[tracking]``) + smoother settings.
    ``long``: the long-vehicle contour model (:func:`contour_gp`), whose first state's
    contour prior is that GP's prior (:meth:`prior_covariance`)."""

    tracking: TrackingConfig
    smoothing: SmoothingConfig
    gp: ContourGP
    contour_rw: np.ndarray
    table: ConditionalTable
    extent: ExtentSettings | None
    long: bool = False

    @staticmethod
    def of(tracking: TrackingConfig | None = None,
           smoothing: SmoothingConfig | None = None, long: bool = False) -> TrackModel:
        tcfg = tracking or TrackingConfig()
        gp = contour_gp(tcfg, long)
        gl, gw = rectangle_radius_gradient(gp.angles, gp.mean_length, gp.mean_width)
        scfg = smoothing or SmoothingConfig()
        rw = scfg.size_walk_scale * (tcfg.sigma_length_rw**2 * np.outer(gl, gl)
                                     + tcfg.sigma_width_rw**2 * np.outer(gw, gw))
        gap = tcfg.extent_gap_max if tcfg.extent_gap_correction else 0.0
        ext = (ExtentSettings(tcfg.sigma_extent, tcfg.extent_min_points, tcfg.extent_min_cover,
                              tcfg.extent_min_incidence, gap, scfg.extent_face_min_points,
                              2.0 * tcfg.sigma_range, scfg.huber_k)
               if scfg.extent_rows else None)
        return TrackModel(tcfg, scfg, gp, rw, ConditionalTable(gp), ext, long)

    @property
    def tau(self) -> float:
        """Contour forgetting rate (1/s) of the process factors (``smoothing.contour_tau``)."""
        return float(self.smoothing.contour_tau)

    def process(self, key0: int, key1: int, dt: float, x_ref: np.ndarray) -> gtsam.CustomFactor:
        """Process factor between ``key0`` and ``key1``, ``dt`` s apart, noise at ``x_ref``."""
        c = self.tracking
        return process_factor(key0, key1, dt, self.gp, self.tau, c.sigma_jerk, c.sigma_yaw_acc,
                              c.sigma_pos, x_ref=x_ref, contour_rw=self.contour_rw)

    def process_noise(self, x_ref: np.ndarray, dt: np.ndarray) -> np.ndarray:
        """(..., 26, 26) noise of the process factors at ``x_ref`` (..., 26), ``dt`` (...) s
        (the covariance :meth:`process` uses)."""
        c = self.tracking
        return process_covariance(x_ref, dt, self.gp, self.tau, c.sigma_jerk, c.sigma_yaw_acc,
                                  c.sigma_pos, contour_rw=self.contour_rw)

    def predict(self, x: np.ndarray, dt: float) -> np.ndarray:
        """State (26,) after ``dt`` s of the process model's mean motion from ``x`` (26,)."""
        out = ctra_predict(np.asarray(x, dtype=float), dt)
        out[N_KIN:], _ = self.gp.decay(out[N_KIN:], self.tau, dt)
        return out

    def _radar_noise(self) -> tuple[float, float]:
        c = self.tracking
        return ((c.sigma_range, float(np.deg2rad(c.sigma_azimuth_deg)))
                if self.smoothing.radar_noise else (0.0, 0.0))

    def measurement(self, key: int, z: np.ndarray, sensor_xy: np.ndarray,
                    trusted: np.ndarray | None = None,
                    range_rate: np.ndarray | None = None) -> gtsam.CustomFactor:
        """Contour factor of detections ``z`` (m, 2): normal rows of a regular subsample of
        ``max_detections``, extent rows (``extent_rows``) from all of them, ends only at the
        ``trusted`` (m,) ones (all when None; :func:`extent_trusted`), and with ``use_doppler``
        range-rate rows of the subsample from ``range_rate`` (m, 2): Doppler (m/s) and 3D
        range (m) of each detection (None = no range-rate rows)."""
        c, s = self.tracking, self.smoothing
        z_all = np.asarray(z, dtype=float)
        sub = regular_subsample(len(z_all), s.max_detections)
        rr = (None if range_rate is None or not s.use_doppler else
              (range_rate[sub, 0], range_rate[sub, 1]))
        return contour_measurement_factor(key, z_all[sub], sensor_xy, self.gp, c.sigma_contour,
                                          s.huber_k, c.n_candidates, *self._radar_noise(),
                                          gp_variance=s.radar_noise, table=self.table,
                                          extent=self.extent, extent_detections=z_all,
                                          extent_trusted=trusted, range_rate=rr,
                                          sigma_doppler=c.sigma_doppler,
                                          visible_slack=c.visible_slack)

    def measurement_batch(self, z: np.ndarray, valid: np.ndarray, z_all: np.ndarray,
                          valid_all: np.ndarray, trusted: np.ndarray, sensor_xy: np.ndarray,
                          range_rate: np.ndarray | None = None
                          ) -> tuple[ContourMeasurement, ExtentRows | None,
                                     RangeRateRows | None]:
        """The rows of :meth:`measurement` for F frames at once: the subsampled detections
        ``z`` (F, M, 2) / ``valid`` (F, M) with their ``range_rate`` (F, M, 2) (Doppler, 3D
        range; None = none), all of them ``z_all`` (F, K, 2) / ``valid_all`` with ``trusted``
        (F, K) for the extent rows (padding finite, not valid; padded ranges > 0)."""
        c, s = self.tracking, self.smoothing
        meas = ContourMeasurement(z, sensor_xy, self.gp, c.sigma_contour, s.huber_k,
                                  c.n_candidates, *self._radar_noise(),
                                  gp_variance=s.radar_noise, table=self.table, valid=valid,
                                  visible_slack=c.visible_slack)
        ext = (None if self.extent is None else
               ExtentRows(z_all, sensor_xy, self.extent, meas.sigma, trusted & valid_all,
                          valid_all))
        rr = (None if range_rate is None or not s.use_doppler else
              RangeRateRows(z, range_rate[..., 0], range_rate[..., 1], sensor_xy,
                            c.sigma_doppler, meas.sigma, s.huber_k, valid))
        return meas, ext, rr

    def initial_covariance(self) -> np.ndarray:
        """(26, 26) P0 of a new track from the ``[tracking]`` init sigmas and the GP kernel."""
        c = self.tracking
        P0 = np.zeros((N_STATE, N_STATE))
        P0[:N_KIN, :N_KIN] = np.diag(np.square([
            c.init_sigma_pos, c.init_sigma_pos, c.init_sigma_speed, c.init_sigma_accel,
            np.deg2rad(c.init_sigma_yaw_deg), c.init_sigma_yawrate]))
        P0[N_KIN:, N_KIN:] = self.gp.K
        return P0

    def prior_mean(self, track: Track, step: int = 0) -> np.ndarray:
        """(26,) mean of the prior on ``track`` at ``step``: the filter's state; for the long
        model at step 0 with the GP's mean contour (the filter was born car-sized)."""
        x = track.states[step].copy()
        if self.long and step == 0:
            x[N_KIN:] = self.gp.mu
        return x

    def prior_covariance(self, track: Track, step: int = 0) -> np.ndarray:
        """(26, 26) covariance of the prior on ``track`` at ``step``: the filter's (or P0);
        for the long model at step 0 the contour block is the GP's K (no cross terms)."""
        P = (track.covariances[step].copy() if track.covariances is not None
             else self.initial_covariance())
        if self.long and step == 0:
            P[N_KIN:, :] = 0.0
            P[:, N_KIN:] = 0.0
            P[N_KIN:, N_KIN:] = self.gp.K
        return P + _PRIOR_JITTER * np.eye(N_STATE)

    def length_floor(self, track: Track) -> float:
        """Floor (m) under ``track``'s smoothed contour length: the tracker's
        ``track.length_floor`` (its occupied length, whose far end is a detection: up to about
        twice the range noise beyond the vehicle's end) less ``2 tracking.sigma_range``, with
        ``length_floor_sigma`` > 0 and a floor > 0, else 0 (none;
        :mod:`fgloc.smoothing.length_floor`)."""
        if self.smoothing.length_floor_sigma <= 0 or track.length_floor <= 0:
            return 0.0
        return max(float(track.length_floor) - 2.0 * self.tracking.sigma_range, 0.0)

    def standing(self, key: int) -> gtsam.CustomFactor:
        """The standing rows on ``key`` (:mod:`fgloc.smoothing.standing`)."""
        s = self.smoothing
        return standing_factor(key, s.stand_sigma_speed, s.stand_sigma_yawrate)

    def prior(self, key: int, track: Track, step: int = 0) -> gtsam.PriorFactorVector:
        """Prior on ``key``: :meth:`prior_mean` and :meth:`prior_covariance`."""
        return prior_factor(key, self.prior_mean(track, step),
                            self.prior_covariance(track, step))


@dataclass(frozen=True)
class TrackModels:
    """The car and the long-vehicle track model and which track gets which.

    Seen head-on or from behind, a truck's length is unobservable and the car-sized GP prior
    places its centre metres off; the tracker then switches the track to a long-vehicle
    contour (``[tracking] long_*``). The batch smoother gives every track whose filtered
    contour reaches ``[smoothing] long_vehicle_length`` and keeps it (:meth:`is_long`:
    trucks and buses, promoted by the filter or seen long) the long model for the whole track
    (``long`` None: off).
    """

    car: TrackModel
    long: TrackModel | None

    @staticmethod
    def of(tracking: TrackingConfig | None = None,
           smoothing: SmoothingConfig | None = None) -> TrackModels:
        scfg = smoothing or SmoothingConfig()
        return TrackModels(TrackModel.of(tracking, scfg),
                           (TrackModel.of(tracking, scfg, long=True)
                            if scfg.long_vehicle_length > 0 else None))

    def _reached(self, track: Track) -> np.ndarray:
        """(n,) steps at which ``track``'s filtered contour (front + rear radius) is at least
        ``long_vehicle_length`` (m) long."""
        return contour_length_width(track.states)[0] >= self.car.smoothing.long_vehicle_length

    def is_long(self, track: Track) -> bool:
        """Whether ``track``'s filtered contour reaches ``long_vehicle_length`` and stays that
        long on at least half of the steps from then on (a car whose contour grows for a
        moment is not a truck), or the tracker measured an occupied length behind its seen end
        (``track.length_floor`` > 0: at least ``[tracking] large_length``, truck-sized; seen
        end-on the filter's contour may stay shorter than ``long_vehicle_length``)."""
        if self.long is None or not len(track):
            return False
        if track.length_floor > 0:
            return True
        reached = self._reached(track)
        if not reached.any():
            return False
        return bool(reached[np.argmax(reached):].mean() >= 0.5)

    def long_from(self, track: Track, hold: float) -> int:
        """Online (causal) variant of :meth:`is_long`: the first step at which ``track``'s
        filtered contour has been at least ``long_vehicle_length`` (m) for ``hold`` s without
        a break (``len(track)``: never, or the long model is off)."""
        if self.long is None:
            return len(track)
        reached = self._reached(track)
        run_start = np.maximum.accumulate(np.where(~reached, np.arange(len(track)) + 1, 0))
        ok = reached & (track.t - track.t[np.minimum(run_start, len(track) - 1)] >= hold)
        return int(np.argmax(ok)) if ok.any() else len(track)

    def for_track(self, track: Track) -> TrackModel:
        """The model of ``track`` (:meth:`is_long`)."""
        return self.long if self.is_long(track) else self.car


def step_detections(track: Track) -> list[np.ndarray]:
    """Per step of ``track`` the indices (into the radar rows) of its detections."""
    order = np.argsort(track.det_step, kind="stable")
    steps = track.det_step[order]
    bounds = np.searchsorted(steps, np.arange(len(track) + 1))
    return [track.det_index[order[a:b]] for a, b in zip(bounds[:-1], bounds[1:])]


@dataclass
class TrackGraph:
    """A factor graph over all steps of a track set.

    graph: the factors (prior, process, measurement of every track). values: the initial
    estimate (the filter's states). keys: per track (in ``tracks.tracks`` order) the (n,)
    int64 array of its state keys, one per step. models: the factor makers used.
    """

    graph: gtsam.NonlinearFactorGraph
    values: gtsam.Values
    keys: list[np.ndarray]
    models: TrackModels


def build_track_graph(tracks: TrackSet, det_xy: np.ndarray, sensor_xy: np.ndarray,
                      smoothing: SmoothingConfig | None = None,
                      tracking: TrackingConfig | None = None,
                      det_trusted: np.ndarray | None = None,
                      det_range_rate: np.ndarray | None = None) -> TrackGraph:
    """Prior, process and measurement factors of every track step, initialised from the
    filter's states (module docstring).

    tracks: in any 2D frame (normally C), each with ``det_index`` into ``det_xy``.
    det_xy (N, 2): all radar rows in the same frame (:func:`placed_detections`).
    sensor_xy (2,): the sensor position in that frame. smoothing / tracking: configs
    (defaults when None). det_trusted (N,) bool: detections that may mark an end in the
    extent rows (``smoothing.extent_rows``; :func:`extent_trusted`; None = all).
    det_range_rate (N, 2): Doppler (m/s) and 3D range (m) of every row for the range-rate
    rows (``smoothing.use_doppler``; :func:`detection_range_rates`; None = none). Raises
    ``ValueError`` on a wrong shape or a track id beyond
    ``factors.gtsam_factors.MAX_TRACK_ID``.
    """
    det_xy = np.asarray(det_xy, dtype=float)
    sensor_xy = np.asarray(sensor_xy, dtype=float)
    if det_xy.ndim != 2 or det_xy.shape[1] != 2:
        raise ValueError(f"det_xy shape {det_xy.shape}, expected (N, 2)")
    if sensor_xy.shape != (2,):
        raise ValueError(f"sensor_xy shape {sensor_xy.shape}, expected (2,)")
    models = TrackModels.of(tracking, smoothing)
    graph, values, keys = gtsam.NonlinearFactorGraph(), gtsam.Values(), []
    for tr in tracks.tracks:
        model = models.for_track(tr)
        if tr.states.shape != (len(tr), N_STATE):
            raise ValueError(f"track {tr.id}: states shape {tr.states.shape}, expected "
                             f"({len(tr)}, {N_STATE})")
        if len(tr.det_index) and tr.det_index.max() >= len(det_xy):
            raise ValueError(f"track {tr.id}: det_index beyond the {len(det_xy)} detections")
        k = np.array([track_key(tr.id, s) for s in range(len(tr))], dtype=np.int64)
        keys.append(k)
        floor = model.length_floor(tr)
        for s, idx in enumerate(step_detections(tr)):
            values.insert(int(k[s]), tr.states[s])
            if s == 0:
                graph.add(model.prior(int(k[0]), tr))
            else:
                graph.add(model.process(int(k[s - 1]), int(k[s]), float(tr.t[s] - tr.t[s - 1]),
                                        tr.states[s - 1]))
            if len(idx):
                graph.add(model.measurement(
                    int(k[s]), det_xy[idx], sensor_xy,
                    None if det_trusted is None else det_trusted[idx],
                    None if det_range_rate is None else det_range_rate[idx]))
            if floor > 0:
                graph.add(length_floor_factor(int(k[s]), floor,
                                              model.smoothing.length_floor_sigma))
        for s in tr.standing_steps():
            graph.add(model.standing(int(k[s])))
    return TrackGraph(graph, values, keys, models)


def ragged_index(counts: np.ndarray, width: int | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """``(index (F, width), valid (F, width))``: groups of consecutive items with sizes
    ``counts`` (F,) (each >= 1) as indices into the items, one row per group, padded to
    ``width`` (default: the largest group) by repeating the group's first item."""
    counts = np.asarray(counts, dtype=np.int64)
    off = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    grp = np.repeat(np.arange(len(counts)), counts)
    pos = np.arange(len(grp)) - off[grp]
    if width is None:
        width = int(counts.max()) if len(counts) else 1
    index = np.repeat(off[:, None], width, axis=1)
    index[grp, pos] = np.arange(len(grp))
    valid = np.zeros(index.shape, dtype=bool)
    valid[grp, pos] = True
    return index, valid


def pad_ragged(values: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Groups of consecutive rows of ``values`` (K, ...) with sizes ``counts`` (F,) (each
    >= 1) as ``(padded (F, max count, ...), valid (F, max count))``; padding repeats each
    group's first row (finite wherever the values are)."""
    index, valid = ragged_index(counts)
    return np.asarray(values)[index], valid


def stack_tracks(tracks: TrackSet, det_xy: np.ndarray, sensor_xy: np.ndarray,
                 smoothing: SmoothingConfig | None = None,
                 tracking: TrackingConfig | None = None,
                 det_trusted: np.ndarray | None = None,
                 det_range_rate: np.ndarray | None = None,
                 chunk: int = 1024) -> StandingTracks:
    """The factors of :func:`build_track_graph` (same arguments, same residuals and noise,
    same model per track) as one :class:`factors.track_system.StackedTracks` (with the
    length floor rows: :class:`fgloc.smoothing.length_floor.FlooredTracks`, and the standing
    rows: :class:`fgloc.smoothing.standing.StandingTracks`) over the steps
    of all tracks, in ``tracks.tracks`` order; measurement frames in chunks of at most
    ``chunk`` frames of one model (bounds the memory of an evaluation)."""
    det_xy = np.asarray(det_xy, dtype=float)
    sensor_xy = np.asarray(sensor_xy, dtype=float)
    models = TrackModels.of(tracking, smoothing)
    per_track = [models.for_track(tr) for tr in tracks.tracks]
    trusted = (np.ones(len(det_xy), dtype=bool) if det_trusted is None
               else np.asarray(det_trusted, dtype=bool))
    lengths = np.array([len(tr) for tr in tracks.tracks], dtype=np.int64)
    start = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    prior_mean = np.array([m.prior_mean(tr) for m, tr in zip(per_track, tracks.tracks)]
                          ).reshape(-1, N_STATE)
    prior_cov = np.array([m.prior_covariance(tr) for m, tr in zip(per_track, tracks.tracks)])
    prior_W = (sqrt_information(prior_cov) if len(prior_cov)
               else np.zeros((0, N_STATE, N_STATE)))
    x_ref = np.concatenate([tr.states[:-1] for tr in tracks.tracks] or [np.zeros((0, 26))])
    dt = np.concatenate([np.diff(tr.t) for tr in tracks.tracks] or [np.zeros(0)])
    if np.any(dt <= 0):
        raise ValueError("track times must increase")
    proc_step = np.concatenate([start[i] + np.arange(1, n) for i, n in enumerate(lengths)]
                               or [np.zeros(0, np.int64)]).astype(np.int64)
    proc_model = np.repeat(np.array([m.long for m in per_track], dtype=bool),
                           np.maximum(lengths - 1, 0))
    proc_W = np.zeros((len(dt), N_STATE, N_STATE))
    proc_mean = np.zeros((len(dt), N_CONTOUR))
    meas_step, meas, bounds = [], [], [0]
    m_max = models.car.smoothing.max_detections
    for model in (models.car, models.long):
        if model is None:
            continue
        sel = proc_model == model.long
        if sel.any():
            proc_W[sel] = sqrt_information(model.process_noise(x_ref[sel], dt[sel]))
        proc_mean[sel] = model.gp.mu
        # measurement frames: the steps with detections of this model's tracks
        frames = [(start[i] + s, idx) for i, tr in enumerate(tracks.tracks)
                  if per_track[i] is model
                  for s, idx in enumerate(step_detections(tr)) if len(idx)]
        for a in range(0, len(frames), chunk):
            part = frames[a:a + chunk]
            sub = [idx[regular_subsample(len(idx), m_max)] for _, idx in part]
            full = [idx for _, idx in part]
            pos, valid = ragged_index([len(i) for i in sub])
            rows = np.concatenate(sub)[pos]                       # (F, M) radar rows, padded
            pos_all, valid_all = ragged_index([len(i) for i in full])
            rows_all = np.concatenate(full)[pos_all]
            rr = None if det_range_rate is None else det_range_rate[rows]
            meas.append(model.measurement_batch(det_xy[rows], valid, det_xy[rows_all],
                                                valid_all, trusted[rows_all], sensor_xy, rr))
            meas_step += [f[0] for f in part]
            bounds.append(bounds[-1] + len(part))
    floor = np.repeat([m.length_floor(tr) for m, tr in zip(per_track, tracks.tracks)],
                      lengths)
    floor_step = np.flatnonzero(floor > 0)
    stand_step = np.concatenate([start[i] + tr.standing_steps()
                                 for i, tr in enumerate(tracks.tracks)]
                                or [np.zeros(0, np.int64)]).astype(np.int64)
    scfg = models.car.smoothing
    return StandingTracks(start, prior_mean, prior_W, proc_step, dt, proc_W,
                          np.array(meas_step, dtype=np.int64), meas,
                          np.array(bounds, dtype=np.int64), proc_mean, models.car.tau,
                          floor_step, floor[floor_step], float(scfg.length_floor_sigma),
                          stand_step,
                          stand_jacobian(scfg.stand_sigma_speed, scfg.stand_sigma_yawrate))


def tracks_from_states(tracks: TrackSet, states: list[np.ndarray],
                       tracking: TrackingConfig | None = None,
                       covariances: list[np.ndarray] | None = None,
                       smoother: str = "smoother") -> TrackSet:
    """The same tracks with new ``states`` (one (n, 26) array per track, in order), states
    driving backwards faster than ``label_min_speed`` turned round (:func:`turn_round`: the
    same motion, heading the way the vehicle moves), then clipped to the tracker's
    road-vehicle limits (0 <= v <= max_speed, |a| <= max_accel, |yaw rate| <= max_yawrate,
    radii >= min_radius), labels recomputed from kappa = yawrate / v (``tracking.eta``,
    ``label_min_speed``) and ``covariances`` ((n, 26, 26) per track, None = without). Same
    frame, T_frame_to_L, ids, times and detections; diagnostics gain ``smoother``."""
    c = tracking or TrackingConfig()
    out = []
    for i, (tr, s) in enumerate(zip(tracks.tracks, states)):
        s = np.array(s, dtype=float).reshape(-1, N_STATE)
        s = turn_round(s, s[:, V] < -c.label_min_speed)
        s[:, V] = np.clip(s[:, V], 0.0, c.max_speed)
        s[:, A] = np.clip(s[:, A], -c.max_accel, c.max_accel)
        s[:, YAWRATE] = np.clip(s[:, YAWRATE], -c.max_yawrate, c.max_yawrate)
        s[:, N_KIN:] = np.maximum(s[:, N_KIN:], c.min_radius)
        out.append(dataclasses.replace(
            tr, t=tr.t.copy(), states=s,
            covariances=None if covariances is None else covariances[i],
            labels=kappa_labels(s, c.eta, c.label_min_speed),
            det_index=tr.det_index.copy(), det_step=tr.det_step.copy()))
    return dataclasses.replace(tracks, tracks=out,
                               diagnostics={**tracks.diagnostics, "smoother": smoother})


def turn_round(states: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """States (n, 26) with the ``mask`` (n,) rows turned round: heading + pi, speed and
    acceleration negated, contour radii rolled by half the basis (radius at object angle
    theta + pi). The same vehicle in the same motion: a smoother can reach the mirrored
    solution (heading against the motion, negative speed) of a track whose filter heading was
    wrong, which clipping the speed to 0 would turn into a parked vehicle facing backwards."""
    out = np.array(states, dtype=float)
    m = np.asarray(mask, dtype=bool)
    out[m, YAW] = wrap_angle(out[m, YAW] + np.pi)
    out[m, V] *= -1.0
    out[m, A] *= -1.0
    out[m, N_KIN:] = np.roll(out[m, N_KIN:], N_CONTOUR // 2, axis=1)
    return out


def tracks_from_values(tracks: TrackSet, values: gtsam.Values, keys: list[np.ndarray],
                       tracking: TrackingConfig | None = None,
                       marginals: gtsam.Marginals | None = None,
                       smoother: str = "smoother") -> TrackSet:
    """:func:`tracks_from_states` with the states read from ``values`` (``keys`` as in
    :class:`TrackGraph`) and covariances from ``marginals`` (None without)."""
    states = [np.array([values.atVector(int(key)) for key in k], dtype=float) for k in keys]
    covs = (None if marginals is None else
            [np.array([marginals.marginalCovariance(int(key)) for key in k]) for k in keys])
    return tracks_from_states(tracks, states, tracking, covs, smoother)
