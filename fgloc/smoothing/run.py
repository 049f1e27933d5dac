"""The smoothing stage: a filter run's tracks smoothed by the fixed-lag or the batch smoother
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
