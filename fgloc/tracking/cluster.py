"""Single-linkage clustering of 2D detections (DBSCAN with min_samples = 1, then a size cut)."""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree


def cluster_labels(p: np.ndarray, eps: float, min_points: int) -> np.ndarray:
    """Cluster index per point (n, 2): connected components of the eps-neighbourhood graph
    (m); points in components smaller than min_points get -1. Labels are 0..k-1."""
    n = len(p)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    pairs = cKDTree(p).query_pairs(eps, output_type="ndarray")
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, lab = connected_components(g, directed=False)
    counts = np.bincount(lab)
    keep = counts >= min_points
    remap = np.full(len(counts), -1, dtype=np.int64)
    remap[keep] = np.arange(int(keep.sum()))
    return remap[lab]
