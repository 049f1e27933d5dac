"""Lane lines through lanelet joins the way a vehicle drives them.

Hand-mapped lanelets meet at kinks: each lanelet's centre line is a polyline of its own, and
the next lanelet of a lane starts in a slightly different direction. A vehicle cannot turn its
heading at a point; it drives a smooth path through the join, 0.1-0.3 m beside the kinked
centre lines there, and a target line that keeps the kink biases a registration that matches
vehicles to it (docs/experiments.md, issue 22).

:func:`smooth_lane_joins` chains every lane with the lane that follows it (and the one before
it) and replaces its samples by a smoothing spline of the chain that penalizes the rate of
change of the path's curvature, the quantity a vehicle's steering rate bounds:

    minimize  sum_i |p_i - c_i|^2 + (length / step)^6 sum_i |(D3 p)_i|^2

(``D3`` the third difference, ``p_{i+1} - 3 p_i + 3 p_{i-1} - p_{i-2}``)

over the chain's samples ``c_i`` (``step`` m apart). It is a linear low-pass filter whose
cut-off wavelength is ``2 pi length``: a kink is spread over a few ``length`` m (a clothoid-like
transition), a straight line and (to first order) a circular arc stay where they are, since
their curvature does not change. ``length`` is a vehicle's steering length: the distance it
drives while it changes its curvature (about its speed times its steering time constant;
``[joint] join_smoothing_length``, 1.5 m by default). The next lane is the routing graph's
successor (per driving direction, :attr:`fgloc.scenario.LaneletMap.directed_successors`)
whose start meets the lane's end,
or, where the map has no routing graph for the lane, any lane whose start meets it; of
several, the one that continues straightest (a fork's other branches keep their own join).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from fgloc.scenario import Lanelet, LaneletMap

#: ends of two lanes closer than this (m) meet
JOIN_TOLERANCE = 0.5
#: two lanes whose directions at the join differ by more than this (deg) are not chained
JOIN_MAX_TURN_DEG = 60.0


def lane_ends(lane: np.ndarray, n_lanes: int) -> tuple[np.ndarray, np.ndarray]:
    """(first, last) sample index (n_lanes,) of every lane of the grouped, ascending lane
    indices ``lane`` (a lane without samples: ``last == first - 1``)."""
    k = np.arange(n_lanes)
    return (np.searchsorted(lane, k, side="left"), np.searchsorted(lane, k, side="right") - 1)


def lane_neighbours(xy: np.ndarray, lane: np.ndarray, keys: list[tuple[int, bool]],
                    lmap: LaneletMap | None = None, tol: float = JOIN_TOLERANCE,
                    max_turn_deg: float = JOIN_MAX_TURN_DEG) -> tuple[np.ndarray, np.ndarray]:
    """(predecessor, successor) lane index (K,) of every lane, -1 where none: lane ``k`` is
    the samples ``xy[lane == k]`` (in driving order, ``lane`` grouped and numbered 0..K-1),
    ``keys[k]`` its (lanelet id, driven against the lanelet). A successor starts within
    ``tol`` m of the lane's end, its first direction within ``max_turn_deg`` of the lane's
    last, and is a routing-graph successor of the lane when ``lmap`` has one for it (any
    lane otherwise); of several, the best aligned. Predecessors the same way backwards."""
    xy = np.asarray(xy, dtype=float)
    lane = np.asarray(lane)
    n_lanes = len(keys)
    first, last = lane_ends(lane, n_lanes)
    ok = last > first
    nxt = np.minimum(first + 1, len(xy) - 1)
    prv = np.maximum(last - 1, 0)
    d_start = xy[nxt] - xy[first]
    d_end = xy[last] - xy[prv]
    d_start /= np.maximum(np.linalg.norm(d_start, axis=1, keepdims=True), 1e-12)
    d_end /= np.maximum(np.linalg.norm(d_end, axis=1, keepdims=True), 1e-12)
    # [a, b]: does lane b start where lane a ends, in about its direction?
    gap = np.linalg.norm(xy[last][:, None, :] - xy[first][None, :, :], axis=2)
    align = d_end @ d_start.T
    meet = (gap <= tol) & (align >= np.cos(np.deg2rad(max_turn_deg))) & ok[:, None] & ok[None]
    np.fill_diagonal(meet, False)
    graph = _directed_graph(lmap)
    if graph:
        index = {key: k for k, key in enumerate(keys)}
        routed = np.zeros_like(meet)
        for a, key in enumerate(keys):
            routed[a, [index[b] for b in graph.get(key, ()) if b in index]] = True
        # a lane the graph gives a successor (predecessor) among these lanes is chained
        # along the graph only; the others by geometry
        succ_ok = np.where(routed.any(axis=1)[:, None], meet & routed, meet)
        pred_ok = np.where(routed.any(axis=0)[None, :], meet & routed, meet)
    else:
        succ_ok = pred_ok = meet
    score = np.where(succ_ok, align, -np.inf)
    succ = np.where(np.isfinite(score.max(axis=1)), score.argmax(axis=1), -1)
    score = np.where(pred_ok, align, -np.inf)
    pred = np.where(np.isfinite(score.max(axis=0)), score.argmax(axis=0), -1)
    return pred, succ


Graph = dict[tuple[int, bool], tuple[tuple[int, bool], ...]]


def _directed_graph(lmap: LaneletMap | None) -> Graph:
    """The routing graph per driving direction of ``lmap`` (empty: none)."""
    if lmap is None:
        return {}
    if lmap.directed_successors:
        return dict(lmap.directed_successors)
    return {(a, False): tuple((b, False) for b in v) for a, v in lmap.successors.items()}


def smooth_lane_joins(xy: np.ndarray, lane: np.ndarray, keys: list[tuple[int, bool]],
                      length: float, step: float, lmap: LaneletMap | None = None,
                      order: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Lane samples (M, 2) and unit left normals (M, 2) smoothed through the joins (module
    docstring): each lane chained with up to ``3 * length`` m of its predecessor and
    successor (:func:`lane_neighbours`) and smoothed with steering length ``length`` m
    (samples about ``step`` m apart); ``length <= 0`` smooths nothing (the normals are then
    those of the lines as given). ``order``: the difference order of the penalty (3; 2 is a
    cubic smoothing spline, compared in docs/experiments.md)."""
    xy = np.asarray(xy, dtype=float)
    lane = np.asarray(lane)
    if np.any(np.diff(lane) < 0):
        raise ValueError("smooth_lane_joins: the samples must be grouped by lane in order")
    n_lanes = len(keys)
    first, last = lane_ends(lane, n_lanes)
    if length <= 0.0 or not len(xy):
        return xy.copy(), _normals(xy, first, last)
    pred, succ = lane_neighbours(xy, lane, keys, lmap)
    reach = int(np.ceil(3.0 * length / step))
    chains, own = [], []
    pos = 0
    for k in range(n_lanes):
        idx = [np.arange(first[k], last[k] + 1)]
        head = tail = 0
        if pred[k] >= 0:
            p = np.arange(max(first[pred[k]], last[pred[k]] - reach), last[pred[k]])
            idx.insert(0, p)
            head = len(p)
        if succ[k] >= 0:
            s = np.arange(first[succ[k]] + 1, min(last[succ[k]], first[succ[k]] + reach) + 1)
            idx.append(s)
            tail = len(s)
        chain = np.concatenate(idx)
        chains.append(chain)
        own.append(pos + head + np.arange(len(chain) - head - tail))
        pos += len(chain)
    chain_idx = np.concatenate(chains)
    sizes = np.array([len(c) for c in chains])
    smooth = _whittaker(xy[chain_idx], sizes, (length / step) ** (2 * order), order)
    start = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    normal_all = _normals(smooth, start, start + sizes - 1)
    own_idx = np.concatenate(own)
    return smooth[own_idx], normal_all[own_idx]


def _whittaker(c: np.ndarray, sizes: np.ndarray, mu: float, order: int = 3) -> np.ndarray:
    """Whittaker smoothing of ``order`` (module docstring: 3) of the stacked chains ``c``
    (N, 2) of lengths ``sizes``: one sparse banded solve; a chain of at most ``order``
    samples stays."""
    n = len(c)
    coef = np.diff(np.eye(order + 1), order, axis=0)[0] * (-1) ** order
    d = sp.diags(list(coef), list(range(order + 1)), shape=(max(n - order, 0), n), format="csr")
    start = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    row_ok = np.zeros(max(n - order, 0), dtype=bool)
    for s, m in zip(start, sizes):      # rows whose samples lie in one chain
        row_ok[s:s + max(m - order, 0)] = True
    d = d[row_ok]
    a = (sp.identity(n, format="csc") + mu * (d.T @ d)).tocsc()
    return splu(a).solve(np.ascontiguousarray(c))


def _normals(xy: np.ndarray, first: np.ndarray, last: np.ndarray) -> np.ndarray:
    """Unit left normals (M, 2) of polylines ``xy[first[k]:last[k] + 1]`` (central differences
    inside each, one-sided at its ends)."""
    d = np.zeros_like(xy)
    if len(xy) > 1:
        d[1:-1] = xy[2:] - xy[:-2]
        d[0], d[-1] = xy[1] - xy[0], xy[-1] - xy[-2]
        one = last > first
        d[first[one]] = xy[first[one] + 1] - xy[first[one]]
        d[last[one]] = xy[last[one]] - xy[last[one] - 1]
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    return np.column_stack([-d[:, 1], d[:, 0]])


def lane_keys(lanelets: list[Lanelet], lanelet_index: np.ndarray, against: np.ndarray,
              lane: np.ndarray) -> list[tuple[int, bool]]:
    """(lanelet id, driven against it) of every lane (index 0..K-1) from the per-sample
    lanelet index (into ``lanelets``), direction flag and lane index
    (:class:`fgloc.coarse.LaneCentres`)."""
    n_lanes = int(lane.max()) + 1 if len(lane) else 0
    first, _ = lane_ends(lane, n_lanes)
    return [(lanelets[int(lanelet_index[i])].id, bool(against[i])) for i in first]
