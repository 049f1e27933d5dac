"""Batch (offline) GP-EOT smoother: Levenberg-Marquardt over every whole track.

Each track is one graph of :func:`fgloc.smoothing.graph.build_track_graph` (prior on the
first step, process factors between all steps, a stacked contour factor per step with
detections), initialised from the filter's states and optimized on its own: tracks share no
variable (the filter's association fixes which detections belong to which track), and a
separate optimizer per track keeps one hard track from setting the damping of all others.
Because every step sees the whole track, shape learned late (e.g. a truck's length once its
side is in view) corrects the early centre estimates, and the measurement association is
re-done at each linearization around the smoothed states.
"""

from __future__ import annotations

import time

import gtsam
import numpy as np

from fgloc.smoothing.config import SmoothingConfig
from fgloc.smoothing.graph import build_track_graph, tracks_from_values
from fgloc.tracking.config import TrackingConfig
from fgloc.tracks import TrackSet


def lm_params(cfg: SmoothingConfig) -> gtsam.LevenbergMarquardtParams:
    """Levenberg-Marquardt settings of the batch smoother (``max_iterations``,
    ``relative_tolerance``)."""
    p = gtsam.LevenbergMarquardtParams()
    p.setMaxIterations(cfg.max_iterations)
    p.setRelativeErrorTol(cfg.relative_tolerance)
    p.setAbsoluteErrorTol(0.0)
    return p


def smooth_batch(tracks: TrackSet, det_xy: np.ndarray, sensor_xy: np.ndarray,
                 smoothing: SmoothingConfig | None = None,
                 tracking: TrackingConfig | None = None,
                 det_trusted: np.ndarray | None = None) -> TrackSet:
    """Smooth every track of ``tracks`` (frame C, the filter's output) as a whole.

    det_xy (N, 2) m: all radar rows in the tracks' frame; sensor_xy (2,) m: the sensor there
    (:func:`fgloc.smoothing.graph.placed_detections`); det_trusted (N,): possible ends of
    the extent rows (:func:`fgloc.smoothing.graph.extent_trusted`, None = all). Returns the
    same tracks (ids, times, detections, frame) with smoothed states, labels from kappa and --
    with
    ``smoothing.marginals`` -- marginal covariances; diagnostics gain ``smoother_seconds``,
    ``smoother_iterations`` (summed over tracks) and the summed graph error before/after.
    """
    scfg = smoothing or SmoothingConfig()
    t0 = time.perf_counter()
    out, iters, err0, err1 = [], 0, 0.0, 0.0
    params = lm_params(scfg)
    for tr in tracks.tracks:
        one = TrackSet([tr], tracks.frame, tracks.T_frame_to_L, {})
        tg = build_track_graph(one, det_xy, sensor_xy, scfg, tracking, det_trusted)
        opt = gtsam.LevenbergMarquardtOptimizer(tg.graph, tg.values, params)
        result = opt.optimize()
        iters += int(opt.iterations())
        err0 += tg.graph.error(tg.values)
        err1 += tg.graph.error(result)
        marg = gtsam.Marginals(tg.graph, result) if scfg.marginals else None
        out += tracks_from_values(one, result, tg.keys, tracking, marg).tracks
    diag = {**tracks.diagnostics, "smoother": "batch",
            "smoother_seconds": time.perf_counter() - t0, "smoother_iterations": iters,
            "smoother_error_initial": err0, "smoother_error_final": err1}
    return TrackSet(out, tracks.frame, tracks.T_frame_to_L, diag)
