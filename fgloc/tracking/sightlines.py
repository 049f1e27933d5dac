"""Where the radar has no line of sight: behind the buildings of the ALS.

A roadside radar sees a vehicle only along a free line of sight. Returns from behind a building
(as seen from the sensor) travelled a path that bounced off a facade: multipath ghosts, the
mirror image of a vehicle in front of the facade, moving as it does, mirrored. The specular
point lies on the facade, so the sight line to every such ghost passes through its building.
Most ghosts land off the road (the off-road rule of :mod:`fgloc.tracking.road_users`), but a
facade at a junction mirrors one arm onto another: in fgloc's simulator with 16 buildings 2 m
from the road, 13 tracks made of ghosts alone drove within 0.2 m of a drivable lanelet
(intersection seed 3). :class:`Buildings` tells which track positions lie behind a building.

Buildings are the ALS points of class 6 (ASPRS building); an ALS without them has no
buildings here and the rule does nothing (vegetation is left out: a radar sees through
foliage in part). Heights are in L; the grid is built once per tracking run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from fgloc.scenario import BUILDING_CLASS, GROUND_CLASSES, AlsCloud

#: cell (m) of the building-top grid
CELL = 1.0
#: spacing (m) of the samples along a sight line
STEP = 0.5
#: sight-line samples this close (m) to the sensor or to the target are not tested (a mast
#: beside a wall, a vehicle beside a facade, the grid's cells)
END_CLEARANCE = 2.0
#: a building cell blocks a sight line where its top lies this much (m) above the line
TOP_MARGIN = 0.5
#: the sight line ends this high (m) above the ground under a track's centre: a vehicle is
#: seen while any of it up to a van's roof is
TARGET_HEIGHT = 2.0
#: sight lines tested at once (bounds the memory: CHUNK x range / STEP samples)
CHUNK = 1024
#: ground points (a regular subsample of at most this many) give the ground height under a
#: track
GROUND_POINTS = 200_000


@dataclass
class Buildings:
    """The tops of the ALS's buildings on a grid, and the ground height under any point.

    origin: (2,) m in L, the grid's lower-left corner; top: (ny, nx) the highest building
    point per ``CELL`` m cell (m in L; -inf where there is none); ground: a KD-tree over the
    xy of the ALS's ground points (:data:`fgloc.scenario.GROUND_CLASSES`; all points but the
    buildings when it has none: a tree crown would lift the sight line's end) and their
    heights ``ground_z`` (m in L).
    """

    origin: np.ndarray
    top: np.ndarray
    ground: cKDTree
    ground_z: np.ndarray

    @classmethod
    def of(cls, als: AlsCloud, centre: np.ndarray, reach: float) -> Buildings | None:
        """From the ALS points within ``reach`` m of ``centre`` (2,) in L; None without a
        building point there or without a ground point (or, lacking those, any other)."""
        xyz = np.asarray(als.xyz, dtype=float)
        near = np.hypot(*(xyz[:, :2] - centre).T) <= reach
        code = np.asarray(als.classification)
        building = near & (code == BUILDING_CLASS)
        other = near & np.isin(code, GROUND_CLASSES)
        if not other.any():
            other = near & ~building
        if not building.any() or not other.any():
            return None
        b = xyz[building]
        origin = b[:, :2].min(axis=0)
        ij = np.floor((b[:, :2] - origin) / CELL).astype(int)
        top = np.full((ij[:, 1].max() + 1, ij[:, 0].max() + 1), -np.inf)
        np.maximum.at(top, (ij[:, 1], ij[:, 0]), b[:, 2])
        g = xyz[other]
        g = g[:: max(1, len(g) // GROUND_POINTS)]
        return cls(origin, top, cKDTree(g[:, :2]), g[:, 2])

    def hidden(self, sensor: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """(n,) mask of the points ``xy`` (n, 2) m in L that the sensor at ``sensor`` (3,) m in
        L cannot see: the sight line from it to ``TARGET_HEIGHT`` m above the ground there
        passes more than ``TOP_MARGIN`` m below a building's top (samples every ``STEP`` m,
        ``END_CLEARANCE`` m from either end left out; :data:`CHUNK` points at a time)."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        return np.concatenate([self._hidden(sensor, xy[k:k + CHUNK])
                               for k in range(0, len(xy), CHUNK)] or [np.zeros(0, dtype=bool)])

    def _hidden(self, sensor: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """:meth:`hidden` of one chunk of points."""
        z_t = self.ground_z[self.ground.query(xy)[1]] + TARGET_HEIGHT
        length = np.hypot(*(xy - sensor[:2]).T)
        n = int(np.ceil(float(length.max()) / STEP))
        if n == 0:
            return np.zeros(len(xy), dtype=bool)
        s = np.arange(1, n) * STEP                                   # (k,) m from the sensor
        frac = s[None, :] / np.maximum(length[:, None], 1e-9)        # (n, k)
        inside = (s[None, :] >= END_CLEARANCE) & (s[None, :] <= length[:, None] - END_CLEARANCE)
        px = sensor[0] + frac * (xy[:, 0:1] - sensor[0])
        py = sensor[1] + frac * (xy[:, 1:2] - sensor[1])
        h = sensor[2] + frac * (z_t[:, None] - sensor[2])
        i = np.floor((py - self.origin[1]) / CELL).astype(int)
        j = np.floor((px - self.origin[0]) / CELL).astype(int)
        on = inside & (i >= 0) & (j >= 0) & (i < self.top.shape[0]) & (j < self.top.shape[1])
        top = np.full(i.shape, -np.inf)
        top[on] = self.top[i[on], j[on]]
        return np.any(top > h + TOP_MARGIN, axis=1)
