"""The filter and the two smoothers on one scenario, scored against its ground truth: tracking
metrics (:mod:`fgloc.evaluation.tracking`) and CPU time of each."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

from fgloc.config import Config
from fgloc.errors import FglocError
from fgloc.evaluation.tracking import TrackingMetrics, evaluate_tracks, visible_states
from fgloc.pipeline import track
from fgloc.scenario import Scenario
from fgloc.smoothing.run import smooth_tracks


@dataclass(frozen=True)
class TrackerComparison:
    """Tracking metrics of the filter and the smoothers on one scenario.

    names: ("filter", "fixed-lag", "batch"); metrics: one
    :class:`fgloc.evaluation.tracking.TrackingMetrics` each; cpu_seconds: CPU time of each
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
    three against ``scenario.truth`` with :func:`fgloc.evaluation.tracking.evaluate_tracks`
    (visibility from the true pose, the sensor's FOV and the ALS's buildings:
    :func:`~fgloc.evaluation.tracking.visible_states`). ``oracle_pose`` places the
    detections with the true pose (tracking alone); otherwise with T_coarse, and the tracks
    are scored in frame C as if it were L (the coarse error adds to every metric)."""
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
    visible = visible_states(truth, sensor.hfov_deg, sensor.max_range, scenario.als)
    metrics = tuple(evaluate_tracks(ts, truth, eta=cfg.tracking.eta, visible=visible)
                    for ts in sets)
    minutes = sum(float(tr.t[-1] - tr.t[0]) for tr in run.tracks.tracks) / 60.0
    return TrackerComparison(("filter", "fixed-lag", "batch"), metrics, tuple(cpu),
                             scenario.radar.duration, len(scenario.radar), minutes)
