"""Smoothers as pipeline stages: smooth a filter run's tracks and the ``smoother-sicp`` method
(the filter / fixed-lag / batch comparison is :mod:`fgloc.evaluation.trackers`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from fgloc.errors import FglocError
from fgloc.scenario import Scenario
from fgloc.smoothing.config import SMOOTHERS
from fgloc.tracks import TrackSet

if TYPE_CHECKING:
    from fgloc.config import Config
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
    from fgloc.registration.fine import register_tracks
    from fgloc.tracking import track_scenario

    target, coarse = target_and_coarse(scn, cfg, timer)
    with timer.stage("tracking"):
        tracks = track_scenario(scn, coarse.T_coarse, cfg.tracking)
    with timer.stage(f"smoothing ({cfg.smoothing.smoother})"):
        tracks = smooth_tracks(scn, tracks, coarse.T_coarse, cfg.smoothing.smoother, cfg)
    return register_tracks(scn, cfg, target, coarse, tracks, timer, method="smoother-sicp")
