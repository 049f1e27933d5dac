"""GP-EOT smoothers in GTSAM on the tracker's models: the track graph builder
(:mod:`fgloc.smoothing.graph`), the batch and fixed-lag smoothers and the tracker comparison.

Only the configuration is imported eagerly (``fgloc.config`` needs it without gtsam); the rest
loads on first use.
"""

from __future__ import annotations

import importlib
from typing import Any

from fgloc.smoothing.config import SMOOTHERS, SmoothingConfig

_LAZY = {
    "TrackGraph": "fgloc.smoothing.graph",
    "TrackModel": "fgloc.smoothing.graph",
    "build_track_graph": "fgloc.smoothing.graph",
    "placed_detections": "fgloc.smoothing.graph",
    "tracks_from_values": "fgloc.smoothing.graph",
}

__all__ = ["SMOOTHERS", "SmoothingConfig", *_LAZY]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
