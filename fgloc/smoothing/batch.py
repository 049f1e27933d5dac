"""Batch (offline) GP-EOT smoother: Levenberg-Marquardt over every whole track.

The factors are those of :func:`fgloc.smoothing.graph.build_track_graph` (prior on each
track's first step, process factors between all steps, a stacked contour factor per step with
detections), initialised from the filter's states. Tracks share no variable (the filter's
association fixes which detections belong to which track), so each track is optimized as its
own problem: its own damping, step acceptance and stopping test, so one hard track does not
set the damping of all others. The work is vectorized over all tracks
(:func:`fgloc.smoothing.graph.stack_tracks` evaluates every factor of every step in batched
numpy calls; :func:`fgloc.smoothing.banded_lm.levenberg_marquardt` solves all tracks'
block-tridiagonal systems in one banded Cholesky), which gives the same optimum as gtsam's
Levenberg-Marquardt on each track's graph at a fraction of the Python-callback cost (tests
compare the two). Because every step sees the whole track, shape learned late (e.g. a truck's
length once its side is in view) corrects the early centre estimates, and the measurement
association is re-done at each linearization around the smoothed states. On long recordings
the tracks are optimized in groups of at most ``smoothing.batch_steps`` steps, one after the
other (:func:`step_groups`), so the optimizer's memory does not grow with the recording.
"""

from __future__ import annotations

import dataclasses
import time

import gtsam
import numpy as np

from fgloc.smoothing.banded_lm import levenberg_marquardt
from fgloc.smoothing.config import SmoothingConfig
from fgloc.smoothing.graph import (
    build_track_graph,
    stack_tracks,
    tracks_from_states,
    tracks_from_values,
)
from fgloc.tracking.config import TrackingConfig
from fgloc.tracks import TrackSet


def smooth_batch(tracks: TrackSet, det_xy: np.ndarray, sensor_xy: np.ndarray,
                 smoothing: SmoothingConfig | None = None,
                 tracking: TrackingConfig | None = None,
                 det_trusted: np.ndarray | None = None,
                 det_range_rate: np.ndarray | None = None) -> TrackSet:
    """Smooth every track of ``tracks`` (frame C, the filter's output) as a whole.

    det_xy (N, 2) m: all radar rows in the tracks' frame; sensor_xy (2,) m: the sensor there
    (:func:`fgloc.smoothing.graph.placed_detections`); det_trusted (N,): possible ends of
    the extent rows (:func:`fgloc.smoothing.graph.extent_trusted`, None = all);
    det_range_rate (N, 2): Doppler and 3D range of every row for the range-rate rows
    (:func:`fgloc.smoothing.graph.detection_range_rates`, None = none). Returns the
    same tracks (ids, times, detections, frame) with smoothed states, labels from kappa and --
    with ``smoothing.marginals`` -- marginal covariances (``gtsam.Marginals`` of each track's
    graph at the smoothed states); diagnostics gain ``smoother_seconds``,
    ``smoother_iterations`` (optimizer passes; the most of any group of tracks) and the
    summed graph cost (``0.5 |whitened residual|^2``) before/after.
    """
    scfg = smoothing or SmoothingConfig()
    t0 = time.perf_counter()
    states: list[np.ndarray] = []
    iterations, cost_initial, cost_final = 0, 0.0, 0.0
    for group in step_groups([len(tr) for tr in tracks.tracks], scfg.batch_steps):
        part = dataclasses.replace(tracks, tracks=[tracks.tracks[i] for i in group])
        system = stack_tracks(part, det_xy, sensor_xy, scfg, tracking, det_trusted,
                              det_range_rate)
        x0 = np.concatenate([tr.states for tr in part.tracks])
        res = levenberg_marquardt(system, x0, scfg.max_iterations, scfg.relative_tolerance)
        states += np.split(res.states, system.start[1:-1])
        iterations = max(iterations, res.iterations)
        cost_initial += float(res.cost_initial.sum())
        cost_final += float(res.cost_final.sum())
    out = tracks_from_states(tracks, states, tracking, smoother="batch")
    if scfg.marginals:
        smoothed = []
        for filtered, tr in zip(tracks.tracks, out.tracks):
            tg = build_track_graph(TrackSet([filtered]), det_xy, sensor_xy, scfg, tracking,
                                   det_trusted, det_range_rate)
            for key, x in zip(tg.keys[0], tr.states):
                tg.values.update(int(key), x)
            marg = gtsam.Marginals(tg.graph, tg.values)
            smoothed += tracks_from_values(TrackSet([tr]), tg.values, tg.keys, tracking,
                                           marg).tracks
        out = TrackSet(smoothed, out.frame, out.T_frame_to_L, out.diagnostics)
    out.diagnostics.update(smoother="batch", smoother_seconds=time.perf_counter() - t0,
                           smoother_iterations=iterations,
                           smoother_error_initial=cost_initial,
                           smoother_error_final=cost_final)
    return out


def step_groups(lengths: list[int], budget: int) -> list[list[int]]:
    """Consecutive groups of the track indices whose ``lengths`` (steps) sum to at most
    ``budget`` each (a track longer than it alone); every index once, in order."""
    groups: list[list[int]] = []
    total = 0
    for i, n in enumerate(lengths):
        if not groups or total + n > budget:
            groups.append([])
            total = 0
        groups[-1].append(i)
        total += n
    return groups
