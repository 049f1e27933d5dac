"""GTSAM factor graph of GP-EOT tracks: the reusable builder of the smoothers (and of the joint
registration, which adds the sensor pose and point factors to the same graph).

Everything is in the tracks' 2D frame (frame C of the placement, m, rad). One variable per
track and step, key :func:`factors.gtsam_factors.track_key` ``(track.id, step)``, a 26-vector
``[x, y, v, a, yaw, yawrate, r_0..r_19]`` (the :mod:`fgloc.tracks` state layout). Per track:

* a prior on step 0: the filter's state and covariance there (its birth state and P0; without
  stored covariances, P0 rebuilt from the ``[tracking]`` init sigmas and the GP kernel);
* a process factor between consecutive steps: CTRA + contour decay + the length / width random
  walk, the tracker's process noise (``[tracking]`` sigma_jerk, sigma_yaw_acc, sigma_pos, tau,
  sigma_length_rw, sigma_width_rw), evaluated around the filter's state at the earlier step;
* a stacked contour measurement factor per step with detections (``Track.det_index`` /
  ``det_step``: the filter's association), sensor-aware normal offsets with the association
  re-done at every linearization, per-row radar noise and Huber IRLS weights
  (:func:`factors.gtsam_factors.contour_measurement_factor`).

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
    ExtentSettings,
    contour_measurement_factor,
    prior_factor,
    process_factor,
    track_key,
)
from fgloc.scenario import Scenario
from fgloc.smoothing.config import SmoothingConfig
from fgloc.tracking.birth import FieldOfView
from fgloc.tracking.config import TrackingConfig
from fgloc.tracking.tracker import kappa_labels
from fgloc.tracks import N_KIN, N_STATE, YAWRATE, A, Track, TrackSet, V, contour_angles

#: added to the diagonal of a prior covariance taken from the filter (state units squared)
_PRIOR_JITTER = 1e-9


def contour_gp(tcfg: TrackingConfig) -> ContourGP:
    """The tracker's GP contour model (same kernel, mean shape and basis angles)."""
    return ContourGP(contour_angles(), tcfg.gp_sf, tcfg.gp_length_rad, tcfg.gp_sr,
                     tcfg.gp_symmetry, tcfg.mean_length, tcfg.mean_width, tcfg.gp_sl,
                     tcfg.gp_sw)


def placed_detections(scn: Scenario, T_placement: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All radar rows of ``scn`` placed in frame C by the 4x4 S -> L pose ``T_placement``
    (the pose the tracker used): ``(det_xy (N, 2), sensor_xy (2,))`` in m, rows in the order
    of ``scn.radar`` (so ``Track.det_index`` indexes them)."""
    T = np.asarray(T_placement, dtype=float)
    xy = scn.radar.xyz @ T[:2, :3].T + T[:2, 3]
    return xy, T[:2, 3].copy()


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
    """The factors of one track model: tracker noise (``[tracking]``) + smoother settings."""

    tracking: TrackingConfig
    smoothing: SmoothingConfig
    gp: ContourGP
    contour_rw: np.ndarray
    table: ConditionalTable
    extent: ExtentSettings | None

    @staticmethod
    def of(tracking: TrackingConfig | None = None,
           smoothing: SmoothingConfig | None = None) -> TrackModel:
        tcfg = tracking or TrackingConfig()
        gl, gw = rectangle_radius_gradient(contour_angles(), tcfg.mean_length, tcfg.mean_width)
        scfg = smoothing or SmoothingConfig()
        rw = scfg.size_walk_scale * (tcfg.sigma_length_rw**2 * np.outer(gl, gl)
                                     + tcfg.sigma_width_rw**2 * np.outer(gw, gw))
        gp = contour_gp(tcfg)
        ext = (ExtentSettings(tcfg.sigma_extent, tcfg.extent_min_points, tcfg.extent_min_cover,
                              tcfg.extent_min_incidence) if scfg.extent_rows else None)
        return TrackModel(tcfg, scfg, gp, rw, ConditionalTable(gp), ext)

    def process(self, key0: int, key1: int, dt: float, x_ref: np.ndarray) -> gtsam.CustomFactor:
        """Process factor between ``key0`` and ``key1``, ``dt`` s apart, noise at ``x_ref``."""
        c = self.tracking
        return process_factor(key0, key1, dt, self.gp, c.tau, c.sigma_jerk, c.sigma_yaw_acc,
                              c.sigma_pos, x_ref=x_ref, contour_rw=self.contour_rw)

    def predict(self, x: np.ndarray, dt: float) -> np.ndarray:
        """State (26,) after ``dt`` s of the process model's mean motion from ``x`` (26,)."""
        out = ctra_predict(np.asarray(x, dtype=float), dt)
        out[N_KIN:], _ = self.gp.decay(out[N_KIN:], self.tracking.tau, dt)
        return out

    def measurement(self, key: int, z: np.ndarray, sensor_xy: np.ndarray,
                    trusted: np.ndarray | None = None) -> gtsam.CustomFactor:
        """Contour factor of detections ``z`` (m, 2): normal rows of a regular subsample of
        ``max_detections``, extent rows (``extent_rows``) from all of them, ends only at the
        ``trusted`` (m,) ones (all when None; :func:`extent_trusted`)."""
        c, s = self.tracking, self.smoothing
        z_all = np.asarray(z, dtype=float)
        z = z_all[regular_subsample(len(z_all), s.max_detections)]
        noise = (c.sigma_range, np.deg2rad(c.sigma_azimuth_deg)) if s.radar_noise else (0, 0)
        return contour_measurement_factor(key, z, sensor_xy, self.gp, c.sigma_contour,
                                          s.huber_k, c.n_candidates, *noise,
                                          gp_variance=s.radar_noise, table=self.table,
                                          extent=self.extent, extent_detections=z_all,
                                          extent_trusted=trusted)

    def initial_covariance(self) -> np.ndarray:
        """(26, 26) P0 of a new track from the ``[tracking]`` init sigmas and the GP kernel."""
        c = self.tracking
        P0 = np.zeros((N_STATE, N_STATE))
        P0[:N_KIN, :N_KIN] = np.diag(np.square([
            c.init_sigma_pos, c.init_sigma_pos, c.init_sigma_speed, c.init_sigma_accel,
            np.deg2rad(c.init_sigma_yaw_deg), c.init_sigma_yawrate]))
        P0[N_KIN:, N_KIN:] = self.gp.K
        return P0

    def prior(self, key: int, track: Track, step: int = 0) -> gtsam.PriorFactorVector:
        """Prior on ``key``: the filter's state and covariance of ``track`` at ``step``."""
        P = (track.covariances[step] if track.covariances is not None
             else self.initial_covariance())
        return prior_factor(key, track.states[step], P + _PRIOR_JITTER * np.eye(N_STATE))


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
    int64 array of its state keys, one per step. model: the factor maker used.
    """

    graph: gtsam.NonlinearFactorGraph
    values: gtsam.Values
    keys: list[np.ndarray]
    model: TrackModel


def build_track_graph(tracks: TrackSet, det_xy: np.ndarray, sensor_xy: np.ndarray,
                      smoothing: SmoothingConfig | None = None,
                      tracking: TrackingConfig | None = None,
                      det_trusted: np.ndarray | None = None) -> TrackGraph:
    """Prior, process and measurement factors of every track step, initialised from the
    filter's states (module docstring).

    tracks: in any 2D frame (normally C), each with ``det_index`` into ``det_xy``.
    det_xy (N, 2): all radar rows in the same frame (:func:`placed_detections`).
    sensor_xy (2,): the sensor position in that frame. smoothing / tracking: configs
    (defaults when None). det_trusted (N,) bool: detections that may mark an end in the
    extent rows (``smoothing.extent_rows``; :func:`extent_trusted`; None = all). Raises
    ``ValueError`` on a wrong shape or a track id beyond
    ``factors.gtsam_factors.MAX_TRACK_ID``.
    """
    det_xy = np.asarray(det_xy, dtype=float)
    sensor_xy = np.asarray(sensor_xy, dtype=float)
    if det_xy.ndim != 2 or det_xy.shape[1] != 2:
        raise ValueError(f"det_xy shape {det_xy.shape}, expected (N, 2)")
    if sensor_xy.shape != (2,):
        raise ValueError(f"sensor_xy shape {sensor_xy.shape}, expected (2,)")
    model = TrackModel.of(tracking, smoothing)
    graph, values, keys = gtsam.NonlinearFactorGraph(), gtsam.Values(), []
    for tr in tracks.tracks:
        if tr.states.shape != (len(tr), N_STATE):
            raise ValueError(f"track {tr.id}: states shape {tr.states.shape}, expected "
                             f"({len(tr)}, {N_STATE})")
        if len(tr.det_index) and tr.det_index.max() >= len(det_xy):
            raise ValueError(f"track {tr.id}: det_index beyond the {len(det_xy)} detections")
        k = np.array([track_key(tr.id, s) for s in range(len(tr))], dtype=np.int64)
        keys.append(k)
        for s, idx in enumerate(step_detections(tr)):
            values.insert(int(k[s]), tr.states[s])
            if s == 0:
                graph.add(model.prior(int(k[0]), tr))
            else:
                graph.add(model.process(int(k[s - 1]), int(k[s]), float(tr.t[s] - tr.t[s - 1]),
                                        tr.states[s - 1]))
            if len(idx):
                graph.add(model.measurement(int(k[s]), det_xy[idx], sensor_xy,
                                            None if det_trusted is None else det_trusted[idx]))
    return TrackGraph(graph, values, keys, model)


def tracks_from_values(tracks: TrackSet, values: gtsam.Values, keys: list[np.ndarray],
                       tracking: TrackingConfig | None = None,
                       marginals: gtsam.Marginals | None = None,
                       smoother: str = "smoother") -> TrackSet:
    """The same tracks with the states read from ``values`` (``keys`` as in
    :class:`TrackGraph`), clipped to the tracker's road-vehicle limits (0 <= v <= max_speed,
    |a| <= max_accel, |yaw rate| <= max_yawrate, radii >= min_radius), labels recomputed from
    kappa = yawrate / v (``tracking.eta``, ``label_min_speed``) and covariances from
    ``marginals`` (None without). Same frame, T_frame_to_L, ids, times and detections;
    diagnostics gain ``smoother``."""
    c = tracking or TrackingConfig()
    out = []
    for tr, k in zip(tracks.tracks, keys):
        s = np.array([values.atVector(int(key)) for key in k], dtype=float).reshape(-1, N_STATE)
        s[:, V] = np.clip(s[:, V], 0.0, c.max_speed)
        s[:, A] = np.clip(s[:, A], -c.max_accel, c.max_accel)
        s[:, YAWRATE] = np.clip(s[:, YAWRATE], -c.max_yawrate, c.max_yawrate)
        s[:, N_KIN:] = np.maximum(s[:, N_KIN:], c.min_radius)
        cov = (None if marginals is None
               else np.array([marginals.marginalCovariance(int(key)) for key in k]))
        out.append(dataclasses.replace(
            tr, t=tr.t.copy(), states=s, covariances=cov,
            labels=kappa_labels(s, c.eta, c.label_min_speed),
            det_index=tr.det_index.copy(), det_step=tr.det_step.copy()))
    return dataclasses.replace(tracks, tracks=out,
                               diagnostics={**tracks.diagnostics, "smoother": smoother})
