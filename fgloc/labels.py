"""Driving-behaviour labels shared by the target cloud (lanelets) and the source cloud (tracks)."""

from __future__ import annotations

import numpy as np

STRAIGHT: int = 0
LEFT: int = 1
RIGHT: int = 2
#: label code -> name as written in files (tracks.csv, PLY comments, result.json)
NAMES: dict[int, str] = {STRAIGHT: "straight", LEFT: "left", RIGHT: "right"}
CODES: dict[str, int] = {v: k for k, v in NAMES.items()}


def label_names(codes: np.ndarray) -> np.ndarray:
    """Array of label names for an array of label codes."""
    lut = np.array([NAMES[k] for k in sorted(NAMES)], dtype=object)
    return lut[np.asarray(codes, dtype=np.int64)]
