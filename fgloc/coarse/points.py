"""The coarse stage's source: the accumulated dynamic radar points, voxel-averaged and filtered
by DBSCAN (Open3D), in the sensor frame S (step 1 of :mod:`fgloc.coarse.localize`)."""

from __future__ import annotations

import numpy as np

from fgloc._open3d import open3d
from fgloc.config import CoarseConfig
from fgloc.map import voxel_centroids
from fgloc.scenario import RadarData


def dynamic_points(radar: RadarData, cfg: CoarseConfig) -> tuple[np.ndarray, np.ndarray, int]:
    """Filtered dynamic cloud (M, 3) in S, whether each point moves away from the sensor (M,)
    bool (Doppler > 0) and the number of dynamic detections before filtering.

    Keeps ``|doppler| >= cfg.doppler_min``, averages per ``cfg.voxel_size`` voxel and Doppler
    sign (where vehicles of both directions pass, a voxel gives one point per direction) and
    drops the points DBSCAN (``dbscan_eps`` m, ``dbscan_min_points``) labels as noise.
    """
    moving = np.abs(radar.doppler) >= cfg.doppler_min
    dyn = np.asarray(radar.xyz, dtype=float)[moving]
    if dyn.shape[0] == 0:
        return np.zeros((0, 3)), np.zeros(0, dtype=bool), 0
    sign = (np.asarray(radar.doppler)[moving] > 0).astype(np.int64)
    pts, sign = voxel_centroids(dyn, sign, cfg.voxel_size)
    o3d = open3d()
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    keep = np.asarray(pcd.cluster_dbscan(cfg.dbscan_eps, cfg.dbscan_min_points, False)) >= 0
    return pts[keep], sign[keep] == 1, int(dyn.shape[0])
