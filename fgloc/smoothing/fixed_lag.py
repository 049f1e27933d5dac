"""Fixed-lag (online) GP-EOT smoother: ``gtsam.IncrementalFixedLagSmoother`` (ISAM2) fed
frame by frame beside the filter.

At each radar frame time, every track alive then gets its new state variable (initialised
from the filter's state at that step, which an online filter has at that moment), the
process factor from its previous step and the stacked contour factor of the detections the
filter associated to it in that frame (``Track.det_index`` / ``det_step``); a track's first
step gets the filter's birth prior. Variables older than ``lag`` seconds are marginalized.
The output state of a step is its estimate just before it left the window (a fixed-lag
smoothed estimate, ``lag`` s of future data), or the final estimate for the steps still in
the window at the end.

Memory stays bounded: marginalized variables and factors leave the smoother and the ISAM2
parameters set ``findUnusedFactorSlots`` (a custom ``ISAM2Params`` drops it otherwise), so
the factor slots are reused (``factor_slots_max`` in the diagnostics).
"""

from __future__ import annotations

import time
from collections import defaultdict

import gtsam
import numpy as np

from factors.gtsam_factors import track_key
from fgloc.errors import FglocError
from fgloc.smoothing.config import SmoothingConfig
from fgloc.smoothing.graph import TrackModel, step_detections, tracks_from_values
from fgloc.tracking.config import TrackingConfig
from fgloc.tracks import TrackSet


def isam2_params(cfg: SmoothingConfig) -> gtsam.ISAM2Params:
    """ISAM2 settings of the fixed-lag smoother (relinearization threshold / skip) with
    ``findUnusedFactorSlots`` on."""
    p = gtsam.ISAM2Params()
    p.setRelinearizeThreshold(cfg.relinearize_threshold)
    p.relinearizeSkip = cfg.relinearize_skip
    p.findUnusedFactorSlots = True
    p.setFactorization("QR")
    return p


def smooth_fixed_lag(tracks: TrackSet, det_xy: np.ndarray, sensor_xy: np.ndarray,
                     smoothing: SmoothingConfig | None = None,
                     tracking: TrackingConfig | None = None,
                     det_trusted: np.ndarray | None = None) -> TrackSet:
    """Run the fixed-lag smoother over ``tracks`` (frame C, the filter's output and
    association) in time order; returns the same tracks with the lagged smoothed states and
    labels from kappa (no covariances).

    det_xy (N, 2) m: all radar rows in the tracks' frame; sensor_xy (2,) m: the sensor there;
    det_trusted (N,): possible ends of the extent rows (None = all).
    Diagnostics gain ``smoother_seconds``, ``frames``, ``factor_slots_max`` (largest number
    of factor slots the smoother held) and ``window_variables_max``.
    """
    scfg = smoothing or SmoothingConfig()
    model = TrackModel.of(tracking, scfg)
    sensor_xy = np.asarray(sensor_xy, dtype=float)
    t0 = time.perf_counter()
    smoother = gtsam.IncrementalFixedLagSmoother(scfg.lag, isam2_params(scfg))
    frames: dict[float, list[tuple[int, int]]] = defaultdict(list)
    for i, tr in enumerate(tracks.tracks):
        for s, t in enumerate(tr.t):
            frames[float(t)].append((i, s))
    dets = [step_detections(tr) for tr in tracks.tracks]
    states = [tr.states.copy() for tr in tracks.tracks]
    window: dict[int, tuple[int, int]] = {}
    slots_max = window_max = 0
    for t in sorted(frames):
        graph, values, stamps = gtsam.NonlinearFactorGraph(), gtsam.Values(), {}
        for i, s in frames[t]:
            tr = tracks.tracks[i]
            key = track_key(tr.id, s)
            stamps[key] = t
            prev = track_key(tr.id, s - 1) if s else None
            if prev is not None and prev in window:
                dt = float(tr.t[s] - tr.t[s - 1])
                x_prev = states[i][s - 1]                    # its current smoothed estimate
                graph.add(model.process(prev, key, dt, x_prev))
                values.insert(key, model.predict(x_prev, dt))
            else:       # first step, or the previous one already left the window
                graph.add(model.prior(key, tr, s))
                values.insert(key, tr.states[s])
            if len(dets[i][s]):
                idx = dets[i][s]
                graph.add(model.measurement(key, det_xy[idx], sensor_xy,
                                            None if det_trusted is None else det_trusted[idx]))
            window[key] = (i, s)
        try:
            smoother.update(graph, values, stamps)
        except RuntimeError as exc:          # the smoother is unusable afterwards
            raise FglocError(f"fixed-lag smoother failed at t = {t:.3f} s: {exc}") from exc
        est = smoother.calculateEstimate()
        for key in list(window):
            if est.exists(key):
                i, s = window[key]
                states[i][s] = est.atVector(key)
            else:
                del window[key]
        slots_max = max(slots_max, int(smoother.getFactors().size()))
        window_max = max(window_max, len(window))
    values = gtsam.Values()
    keys = []
    for tr, st in zip(tracks.tracks, states):
        k = np.array([track_key(tr.id, s) for s in range(len(tr))], dtype=np.int64)
        for key, x in zip(k, st):
            values.insert(int(key), x)
        keys.append(k)
    out = tracks_from_values(tracks, values, keys, tracking, smoother="fixed-lag")
    out.diagnostics.update(smoother_seconds=time.perf_counter() - t0, frames=len(frames),
                           factor_slots_max=slots_max, window_variables_max=window_max)
    return out
