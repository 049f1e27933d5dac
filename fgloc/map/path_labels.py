"""Lane samples labelled by what a vehicle driving them shows (``[map] lane_labels = "path"``).

The tracks' points are labelled by their yaw rate over speed (:func:`fgloc.labels.kappa_labels`,
threshold ``tracking.eta``); the lanelets by three points of a bound or by the routing graph's
movement (:mod:`fgloc.map.lanelet_labels`). On hand-mapped maps the two disagree: a roundabout
drawn as short straight lanelets is "straight" by both lanelet rules while the vehicles on it
turn all the way round, and a kink where two lanelets join makes every vehicle turn for a few
metres (docs/experiments.md, "Labels that disagree with the map").

Here each lane sample takes the label of the curvature of its lane's path: the lane's line
continued through its joins into the lanes before and after it, its heading smoothed along
the arc length by a Gaussian of ``sigma`` m (a vehicle takes a kink over a few metres), the
curvature the heading's rate of change per metre; above ``gamma`` (1/m) LEFT, below
``-gamma`` RIGHT.
The lanes before and after are those of :func:`fgloc.map.lane_joins.lane_neighbours` (the
routing graph's, the straightest of several), followed over as many lanes as ``3 sigma`` m
need (a roundabout's lanelets can be 4 m long).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d

from fgloc.map.lane_joins import lane_ends, lane_neighbours
from fgloc.map.lanelet_labels import labels_from_curvature
from fgloc.scenario import LaneletMap


def path_curvature(xy: np.ndarray, heading: np.ndarray, lane: np.ndarray,
                   keys: list[tuple[int, bool]], sigma: float, lmap: LaneletMap | None = None
                   ) -> np.ndarray:
    """(K,) signed curvature (1/m, counter-clockwise positive) of the lanes' paths at their
    samples ``xy`` (K, 2) in L, ordered along each lane in its driving direction, with unit
    driving directions ``heading`` (K, 2), lane indices ``lane`` (K,) (grouped, 0..L-1) and
    ``keys`` (lanelet id, driven against it) per lane; see the module docstring."""
    xy, heading, lane = np.asarray(xy, float), np.asarray(heading, float), np.asarray(lane)
    if len(xy) == 0:
        return np.zeros(0)
    first, last = lane_ends(lane, len(keys))
    prv, nxt = lane_neighbours(xy, lane, keys, lmap)
    reach = 3.0 * sigma
    out = np.zeros(len(xy))
    for k in range(len(keys)):
        if last[k] < first[k]:
            continue
        own = np.arange(first[k], last[k] + 1)
        before = _walk(k, prv, first, last, reach, xy, backwards=True)
        after = _walk(k, nxt, first, last, reach, xy, backwards=False)
        idx = np.concatenate([before, own, after]).astype(np.int64)
        seg = np.linalg.norm(np.diff(xy[idx], axis=0), axis=1)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        theta = np.unwrap(np.arctan2(heading[idx, 1], heading[idx, 0]))
        keep = np.concatenate([[True], seg > 1e-6])    # joined lanes share their end points
        out[own] = _curvature(s[keep], theta[keep], sigma, s[len(before):len(before) + len(own)])
    return out


def _curvature(s: np.ndarray, theta: np.ndarray, sigma: float, at: np.ndarray) -> np.ndarray:
    """d theta / d s (1/m) at arc lengths ``at`` of the heading ``theta`` (rad, unwrapped) given
    at increasing arc lengths ``s`` (m), smoothed by a Gaussian of ``sigma`` m."""
    if len(s) < 2 or s[-1] <= 0.0:
        return np.zeros(len(at))
    step = min(0.25, sigma / 4.0) if sigma > 0 else 0.25
    grid = np.arange(0.0, s[-1] + step, step)
    th = np.interp(grid, s, theta)
    if sigma > 0:
        th = gaussian_filter1d(th, sigma / step, mode="nearest")
    return np.interp(at, grid, np.gradient(th, step))


def _walk(k: int, link: np.ndarray, first: np.ndarray, last: np.ndarray, reach: float,
          xy: np.ndarray, backwards: bool) -> np.ndarray:
    """Sample indices of the lanes chained from lane ``k`` along ``link`` (the next or the
    previous lane, -1: none), about ``reach`` m of them, in driving order."""
    parts: list[np.ndarray] = []
    got, j, seen = 0.0, int(link[k]), {k}
    while j >= 0 and got < reach and j not in seen:
        seen.add(j)
        idx = np.arange(first[j], last[j] + 1)
        seg = np.linalg.norm(np.diff(xy[idx], axis=0), axis=1)
        cum = np.concatenate([[0.0], np.cumsum(seg[::-1] if backwards else seg)])
        take = idx[::-1][cum <= reach - got][::-1] if backwards else idx[cum <= reach - got]
        parts.append(take)
        got += float(cum[len(take) - 1]) if len(take) else reach
        j = int(link[j])
    if backwards:
        parts = parts[::-1]
    return np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)


def path_labels(xy: np.ndarray, heading: np.ndarray, lane: np.ndarray,
                keys: list[tuple[int, bool]], sigma: float, gamma: float,
                lmap: LaneletMap | None = None) -> np.ndarray:
    """(K,) int8 label codes of lane samples by their path's curvature
    (:func:`path_curvature`; threshold ``gamma`` 1/m)."""
    return labels_from_curvature(path_curvature(xy, heading, lane, keys, sigma, lmap), gamma)
