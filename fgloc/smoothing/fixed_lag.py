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

Long vehicles (trucks, buses) switch to the long-vehicle contour model online: once the
filter's contour of a track has been at least ``[smoothing] long_vehicle_length`` long for
``LONG_HOLD_S`` without a break (the filter has promoted it or sees it long), the track's
window starts afresh from the filter's state and covariance there, and its later factors use
the long model (:class:`fgloc.smoothing.graph.TrackModels`; the batch smoother decides with
hindsight instead and uses it for the whole track).

The tracks share no variable (the sensor pose is fixed here), so their joint posterior
factorizes: every track gets its own smoother, created at its first step and dropped after
its last. Same estimates as one smoother over all tracks, but each ISAM2 update and
marginalization works on one short chain: one smoother holding every track re-eliminated
large parts of all the chains at each frame (~2x the CPU time on 30 vehicles).

Memory stays bounded: marginalized variables and factors leave the smoother and the ISAM2
parameters set ``findUnusedFactorSlots`` (a custom ``ISAM2Params`` drops it otherwise), so
the factor slots are reused (``factor_slots_max`` in the diagnostics).
"""

from __future__ import annotations

import time
from collections import defaultdict, deque
from dataclasses import dataclass, field

import gtsam
import numpy as np

from factors.gtsam_factors import track_key
from fgloc.errors import FglocError
from fgloc.smoothing.config import SmoothingConfig
from fgloc.smoothing.graph import TrackModel, TrackModels, step_detections, tracks_from_states
from fgloc.tracking.config import TrackingConfig
from fgloc.tracks import Track, TrackSet

#: s a filtered contour must stay long before the fixed-lag smoother takes a track for a long
#: vehicle (a car's contour grows past the threshold for a few frames now and then)
LONG_HOLD_S = 1.0


def isam2_params(cfg: SmoothingConfig) -> gtsam.ISAM2Params:
    """ISAM2 settings of the fixed-lag smoother (relinearization threshold / skip) with
    ``findUnusedFactorSlots`` on."""
    p = gtsam.ISAM2Params()
    p.setRelinearizeThreshold(cfg.relinearize_threshold)
    p.relinearizeSkip = cfg.relinearize_skip
    p.findUnusedFactorSlots = True
    p.setFactorization("QR")
    return p


@dataclass
class _TrackWindow:
    """The smoother of one track and its steps still in the window (oldest first)."""

    smoother: gtsam.IncrementalFixedLagSmoother
    steps: deque[int] = field(default_factory=deque)


def smooth_fixed_lag(tracks: TrackSet, det_xy: np.ndarray, sensor_xy: np.ndarray,
                     smoothing: SmoothingConfig | None = None,
                     tracking: TrackingConfig | None = None,
                     det_trusted: np.ndarray | None = None,
                     det_range_rate: np.ndarray | None = None) -> TrackSet:
    """Run the fixed-lag smoother over ``tracks`` (frame C, the filter's output and
    association) in time order; returns the same tracks with the lagged smoothed states and
    labels from kappa (no covariances).

    det_xy (N, 2) m: all radar rows in the tracks' frame; sensor_xy (2,) m: the sensor there;
    det_trusted (N,): possible ends of the extent rows (None = all); det_range_rate (N, 2):
    Doppler and 3D range of every row for the range-rate rows (None = none).
    Diagnostics gain ``smoother_seconds``, ``frames``, ``factor_slots_max`` (largest number
    of factor slots one track's smoother held) and ``window_variables_max`` (largest number
    of state variables in all windows at once).
    """
    scfg = smoothing or SmoothingConfig()
    models = TrackModels.of(tracking, scfg)
    long_from = [models.long_from(tr, LONG_HOLD_S) for tr in tracks.tracks]
    sensor_xy = np.asarray(sensor_xy, dtype=float)
    t0 = time.perf_counter()
    params = isam2_params(scfg)
    frames: dict[float, list[tuple[int, int]]] = defaultdict(list)
    for i, tr in enumerate(tracks.tracks):
        for s, t in enumerate(tr.t):
            frames[float(t)].append((i, s))
    dets = [step_detections(tr) for tr in tracks.tracks]
    states = [tr.states.copy() for tr in tracks.tracks]
    open_: dict[int, _TrackWindow] = {}
    slots_max = window_max = n_window = 0

    def close(i: int) -> None:
        """Read the final estimates of track i's window and drop its smoother."""
        nonlocal n_window
        w = open_.pop(i)
        tid = tracks.tracks[i].id
        for s in w.steps:
            states[i][s] = w.smoother.calculateEstimateVector(track_key(tid, s))
        n_window -= len(w.steps)

    for t in sorted(frames):
        for i, s in frames[t]:
            tr = tracks.tracks[i]
            if i in open_ and (t - tr.t[open_[i].steps[-1]] >= scfg.lag or s == long_from[i]):
                close(i)            # a gap as long as the lag, or now a long vehicle: afresh
            model = models.long if s >= long_from[i] else models.car
            w = open_.get(i)
            if w is None:
                w = open_[i] = _TrackWindow(gtsam.IncrementalFixedLagSmoother(scfg.lag, params))
            graph, values, key = _step_factors(model, tr, s, w, states[i], det_xy, sensor_xy,
                                               dets[i][s], det_trusted, det_range_rate)
            # the steps this update marginalizes (IFLS: stamp < newest stamp - lag): their
            # output is the estimate just before they leave
            while w.steps and tr.t[w.steps[0]] < t - scfg.lag:
                s_old = w.steps.popleft()
                states[i][s_old] = w.smoother.calculateEstimateVector(track_key(tr.id, s_old))
                n_window -= 1
            try:
                w.smoother.update(graph, values, {key: t})
            except RuntimeError as exc:          # the smoother is unusable afterwards
                raise FglocError(f"fixed-lag smoother failed on track {tr.id} at t = "
                                 f"{t:.3f} s: {exc}") from exc
            w.steps.append(s)
            n_window += 1
            states[i][s] = w.smoother.calculateEstimateVector(key)
            slots_max = max(slots_max, int(w.smoother.getFactors().size()))
            if s == len(tr) - 1:
                close(i)
        window_max = max(window_max, n_window)
    out = tracks_from_states(tracks, states, tracking, smoother="fixed-lag")
    out.diagnostics.update(smoother_seconds=time.perf_counter() - t0, frames=len(frames),
                           factor_slots_max=slots_max, window_variables_max=window_max)
    return out


def _step_factors(model: TrackModel, tr: Track, s: int, w: _TrackWindow, states: np.ndarray,
                  det_xy: np.ndarray, sensor_xy: np.ndarray, idx: np.ndarray,
                  det_trusted: np.ndarray | None, det_range_rate: np.ndarray | None
                  ) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, int]:
    """New factors, initial value and key of step ``s`` of ``tr``: the process factor from the
    previous step (initialised by the process model from its current estimate in
    ``states``) when that step is in the window, else the filter's prior; the standing rows
    of a standing step; the contour factor of the step's detections ``idx``."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    key = track_key(tr.id, s)
    if w.steps and w.steps[-1] == s - 1:
        dt = float(tr.t[s] - tr.t[s - 1])
        x_prev = states[s - 1]                           # its current smoothed estimate
        graph.add(model.process(track_key(tr.id, s - 1), key, dt, x_prev))
        values.insert(key, model.predict(x_prev, dt))
    else:       # first step, or the previous one already left the window
        graph.add(model.prior(key, tr, s))
        values.insert(key, tr.states[s])
    if tr.standing is not None and tr.standing[s]:
        graph.add(model.standing(key))
    if len(idx):
        graph.add(model.measurement(key, det_xy[idx], sensor_xy,
                                    None if det_trusted is None else det_trusted[idx],
                                    None if det_range_rate is None else det_range_rate[idx]))
    return graph, values, key
