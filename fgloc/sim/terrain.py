"""Ground and road surface heights: a gently sloped plane, roads slightly above it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Terrain:
    """Heights in L (m). ``ground(xy) = z0 + grad . xy``; the road is ``road_raise`` higher."""

    z0: float
    grad: np.ndarray
    road_raise: float

    def ground(self, xy: np.ndarray) -> np.ndarray:
        """Ground height (m, L) at (n, 2) points."""
        return self.z0 + np.asarray(xy)[..., :2] @ self.grad

    def road(self, xy: np.ndarray) -> np.ndarray:
        """Road surface height (m, L) at (n, 2) points."""
        return self.ground(xy) + self.road_raise
