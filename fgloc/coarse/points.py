"""The coarse stage's source: the accumulated dynamic radar points, voxel-averaged and filtered
by DBSCAN's noise test (:func:`dbscan_not_noise`), in the sensor frame S (step 1 of
:mod:`fgloc.coarse.localize`).

Before the voxels, each moving detection must lie on a trail (:func:`on_trail`): a vehicle
returns detections frame after frame within a few metres of each other, a false alarm (a
detection with a random Doppler anywhere in view) stands alone. The paper's voxel + DBSCAN
filter cannot tell them apart once false alarms are many: accumulated over a minute, 15 a
frame fill the view with occupied voxels that DBSCAN joins into one cluster. On the
independent generator's "uniform" clutter (15 false alarms a frame, 80 % of the moving
detections where the vehicles return a few points a frame) the coarse fit ended 8.4 m / 1.5
deg off with a confident covariance at one junction (docs/experiments.md, issue 22).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from fgloc.config import CoarseConfig
from fgloc.map import voxel_centroids
from fgloc.scenario import RadarData


def on_trail(xy: np.ndarray, t: np.ndarray, radius: float, window: float,
             min_neighbours: int) -> np.ndarray:
    """(n,) True where at least ``min_neighbours`` other points of ``xy`` (n, 2) m, stamped
    ``t`` (n,) s, lie within ``radius`` m along each horizontal axis and within ``window`` s
    (a box in space and time: one KD-tree over (x, y, t radius / window), whose
    ``min_neighbours + 1`` nearest points in the maximum norm, the point itself among them,
    must lie within ``radius``; counting every neighbour instead took 36 times as long on a
    minute of dense traffic). ``min_neighbours`` 0 keeps every point."""
    if min_neighbours <= 0 or len(t) == 0:
        return np.ones(len(t), dtype=bool)
    t = np.asarray(t, dtype=float)
    pts = np.column_stack([xy, (t - t[0]) * (radius / window)])
    bound = radius * (1.0 + 1e-9)   # inclusive, also for frames exactly ``window`` s apart
    dist, _ = cKDTree(pts).query(pts, k=[min_neighbours + 1], p=np.inf,
                                 distance_upper_bound=bound)
    return dist[:, 0] <= bound


@dataclass
class DynamicSource:
    """The coarse stage's source, in the sensor frame S.

    xyz: (M, 3) m, the moving on-trail detections voxel-averaged per Doppler sign and kept by
    DBSCAN; receding: (M,) True where that point moves away from the sensor (Doppler > 0).
    detections: (K, 3) m, the moving on-trail detections themselves (a regular subsample of at
    most ``vertical_points``), whose heights the vertical fit uses (a voxel's centroid is no
    unbiased sample of the heights it averages). n_dynamic: detections with
    ``|doppler| >= doppler_min``; n_off_trail: how many of them lie on no trail.
    """

    xyz: np.ndarray
    receding: np.ndarray
    detections: np.ndarray
    n_dynamic: int
    n_off_trail: int


def dynamic_points(radar: RadarData, cfg: CoarseConfig) -> DynamicSource:
    """The filtered dynamic cloud and the detections it averages (:class:`DynamicSource`).

    Keeps ``|doppler| >= cfg.doppler_min`` on a trail (:func:`on_trail` with ``trail_radius``,
    ``trail_window``, ``trail_min_neighbours``, horizontal in S), averages per
    ``cfg.voxel_size`` voxel and Doppler sign (where vehicles of both directions pass, a voxel
    gives one point per direction) and drops the points DBSCAN (``dbscan_eps`` m,
    ``dbscan_min_points``) labels as noise.
    """
    moving = np.abs(radar.doppler) >= cfg.doppler_min
    dyn = np.asarray(radar.xyz, dtype=float)[moving]
    if dyn.shape[0] == 0:
        return DynamicSource(np.zeros((0, 3)), np.zeros(0, dtype=bool), np.zeros((0, 3)), 0, 0)
    trail = on_trail(dyn[:, :2], np.asarray(radar.t)[moving], cfg.trail_radius,
                     cfg.trail_window, cfg.trail_min_neighbours)
    on = dyn[trail]
    sign = (np.asarray(radar.doppler)[moving][trail] > 0).astype(np.int64)
    pts, sign = voxel_centroids(on, sign, cfg.voxel_size)
    keep = dbscan_not_noise(pts, cfg.dbscan_eps, cfg.dbscan_min_points)
    return DynamicSource(pts[keep], sign[keep] == 1,
                         on[:: max(1, len(on) // cfg.vertical_points)],
                         int(dyn.shape[0]), int((~trail).sum()))


def dbscan_not_noise(pts: np.ndarray, eps: float, min_points: int) -> np.ndarray:
    """(n,) True where DBSCAN (radius ``eps`` m, ``min_points``) does not label the point
    (n, 3) as noise: a core point (at least ``min_points`` points, itself included, within
    ``eps``) or one within ``eps`` of a core point. Which cluster a point joins does not
    matter here, so no clustering is run; Open3D's ``cluster_dbscan`` labels the same points
    noise (tests/test_coarse_trail.py) but its import alone took 2 s of a run."""
    pts = np.asarray(pts, dtype=float).reshape(-1, 3)
    if not len(pts):
        return np.zeros(0, dtype=bool)
    core = cKDTree(pts).query_ball_point(pts, eps, return_length=True) >= min_points
    if not core.any():
        return core
    dist, _ = cKDTree(pts[core]).query(pts, distance_upper_bound=eps)
    return dist <= eps
