"""Single-linkage clustering of 2D detections (DBSCAN with min_samples = 1, then a size cut)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def _components(n: int, pairs: np.ndarray) -> np.ndarray:
    """Connected components of the graph on n nodes with edges pairs (e, 2): per node the
    smallest node index of its component (min-label propagation with pointer jumping; a
    few numpy passes instead of a sparse-graph build per frame)."""
    root = np.arange(n)
    if not len(pairs):
        return root
    a, b = pairs[:, 0], pairs[:, 1]
    while True:
        m = np.minimum(root[a], root[b])
        np.minimum.at(root, a, m)
        np.minimum.at(root, b, m)
        while True:                                   # pointer jumping to the roots
            nxt = root[root]
            if np.array_equal(nxt, root):
                break
            root = nxt
        if np.array_equal(root[a], root[b]):
            return root


def cluster_labels(p: np.ndarray, eps: float, min_points: int) -> np.ndarray:
    """Cluster index per point (n, 2): connected components of the eps-neighbourhood graph
    (m); points in components smaller than min_points get -1. Labels are 0..k-1, ordered by
    each component's first point."""
    n = len(p)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    pairs = cKDTree(p).query_pairs(eps, output_type="ndarray")
    _, lab = np.unique(_components(n, pairs), return_inverse=True)
    counts = np.bincount(lab)
    keep = counts >= min_points
    remap = np.full(len(counts), -1, dtype=np.int64)
    remap[keep] = np.arange(int(keep.sum()))
    return remap[lab]
