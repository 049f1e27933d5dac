"""Smoothers as pipeline stages: smooth a filter run's tracks, the ``smoother-sicp`` method
and the filter / fixed-lag / batch comparison on one scenario."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from fgloc.errors import FglocError
from fgloc.scenario import Scenario
from fgloc.smoothing.config import SMOOTHERS
from fgloc.tracks import TrackSet

if TYPE_CHECKING:
    from fgloc.config import Config
    from fgloc.evaluate_tracking import TrackingMetrics
    from fgloc.progress import Timer
    from fgloc.result import LocalizationResult


def smooth_tracks(scn: Scenario, tracks: TrackSet, T_placement: np.ndarray, smoother: str,
                  config: Config) -> TrackSet:
    """``tracks`` (the filter's, frame C of ``T_placement``: 4x4 S -> L that placed the
    detections) smoothed by ``smoother`` ("none", "fixed-lag" or "batch") with
    ``config.smoothing`` and the tracker's models ``config.tracking``."""
    from fgloc.smoothing.batch import smooth_batch
    from fgloc.smoothing.fixed_lag import smooth_fixed_lag
    from fgloc.smoothing.graph import detection_range_rates, extent_trusted, placed_detections

    if smoother not in SMOOTHERS:
        raise FglocError(f"unknown smoother {smoother!r}; available: {', '.join(SMOOTHERS)}")
    if smoother == "none":
        return tracks
    det_xy, sensor_xy = placed_detections(scn, T_placement)
    trusted = extent_trusted(scn, T_placement, det_xy, config.tracking)
    fn = smooth_batch if smoother == "batch" else smooth_fixed_lag
    return fn(tracks, det_xy, sensor_xy, config.smoothing, config.tracking, trusted,
              detection_range_rates(scn))


def run_smoother_sicp(scn: Scenario, cfg: Config, timer: Timer) -> LocalizationResult:
    """Localize like filter-sicp, with the filter's tracks replaced by the smoother's
    (``cfg.smoothing.smoother``, batch by default) before the source cloud and SICP."""
    from fgloc.coarse import target_and_coarse
    from fgloc.fine import register_tracks
    from fgloc.tracking import track_scenario

    target, coarse = target_and_coarse(scn, cfg, timer)
    with timer.stage("tracking"):
        tracks = track_scenario(scn, coarse.T_coarse, cfg.tracking)
    with timer.stage(f"smoothing ({cfg.smoothing.smoother})"):
        tracks = smooth_tracks(scn, tracks, coarse.T_coarse, cfg.smoothing.smoother, cfg)
    return register_tracks(scn, cfg, target, coarse, tracks, timer, method="smoother-sicp")


@dataclass(frozen=True)
class TrackerComparison:
    """Tracking metrics of the filter and the smoothers on one scenario.

    names: ("filter", "fixed-lag", "batch"); metrics: one
    :class:`fgloc.evaluate_tracking.TrackingMetrics` each; cpu_seconds: CPU time of each
    (the smoothers' own time, without the filter they start from); recording_s: duration of
    the recording (s); detections: radar rows; track_minutes: summed duration of the
    filter's tracks (min), the batch smoother's unit of work.
    """

    names: tuple[str, ...]
    metrics: tuple[TrackingMetrics, ...]
    cpu_seconds: tuple[float, ...]
    recording_s: float
    detections: int
    track_minutes: float

    def table(self) -> str:
        """One line per tracker: the :meth:`TrackingMetrics.table` columns, CPU seconds and
        the real-time factor (recording s / CPU s)."""
        lines = []
        for i, (name, m, cpu) in enumerate(zip(self.names, self.metrics, self.cpu_seconds)):
            head, row = m.table().splitlines()[:2]
            rtf = self.recording_s / cpu if cpu > 0 else math.inf
            if i == 0:
                lines.append(f"{'tracker':>9} {head} {'CPU s':>7} {'RTF':>6}")
            lines.append(f"{name:>9} {row} {cpu:7.1f} {rtf:6.2f}")
        return "\n".join(lines)


def compare_trackers(scenario: Scenario, config: Config | None = None,
                     oracle_pose: bool = True) -> TrackerComparison:
    """Run the filter, then the fixed-lag and the batch smoother on its tracks, and score all
    three against ``scenario.truth`` with :func:`fgloc.evaluate_tracking.evaluate_tracks`
    (visibility from the true pose and the sensor's FOV). ``oracle_pose`` places the
    detections with the true pose (tracking alone); otherwise with T_coarse, and the tracks
    are scored in frame C as if it were L (the coarse error adds to every metric)."""
    from fgloc.config import Config
    from fgloc.evaluate_tracking import evaluate_tracks
    from fgloc.pipeline import track

    if scenario.truth is None:
        raise FglocError("compare_trackers needs the scenario's ground truth")
    cfg = config or Config()
    c0 = time.process_time()
    run = track(scenario, cfg, oracle_pose=oracle_pose)
    sets, cpu = [run.tracks], [time.process_time() - c0]
    for name in ("fixed-lag", "batch"):
        c0 = time.process_time()
        sets.append(smooth_tracks(scenario, run.tracks, run.T_placement, name, cfg))
        cpu.append(time.process_time() - c0)
    truth, sensor = scenario.truth, scenario.sensor
    metrics = tuple(evaluate_tracks(ts, truth, eta=cfg.tracking.eta,
                                    sensor_pose=truth.sensor_pose, hfov_deg=sensor.hfov_deg,
                                    max_range=sensor.max_range) for ts in sets)
    minutes = sum(float(tr.t[-1] - tr.t[0]) for tr in run.tracks.tracks) / 60.0
    return TrackerComparison(("filter", "fixed-lag", "batch"), metrics, tuple(cpu),
                             scenario.radar.duration, len(scenario.radar), minutes)
