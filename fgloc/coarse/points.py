"""The coarse stage's source: the accumulated dynamic radar points, voxel-averaged and filtered
by DBSCAN (Open3D), in the sensor frame S (step 1 of :mod:`fgloc.coarse.localize`)."""

from __future__ import annotations

import numpy as np

from fgloc._open3d import open3d
from fgloc.config import CoarseConfig
from fgloc.map import voxel_centroids
from fgloc.scenario import RadarData


def dynamic_points(radar: RadarData, cfg: CoarseConfig) -> tuple[np.ndarray, int]:
    """Filtered dynamic cloud (M, 3) in S and the number of dynamic detections before filtering.

    Keeps ``|doppler| >= cfg.doppler_min``, averages per ``cfg.voxel_size`` voxel and drops the
    points DBSCAN (``dbscan_eps`` m, ``dbscan_min_points``) labels as noise.
    """
    dyn = np.asarray(radar.xyz, dtype=float)[np.abs(radar.doppler) >= cfg.doppler_min]
    if dyn.shape[0] == 0:
        return np.zeros((0, 3)), 0
    pts, _ = voxel_centroids(dyn, np.zeros(dyn.shape[0], dtype=np.int64), cfg.voxel_size)
    o3d = open3d()
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    lab = np.asarray(pcd.cluster_dbscan(cfg.dbscan_eps, cfg.dbscan_min_points, False))
    return pts[lab >= 0], int(dyn.shape[0])


