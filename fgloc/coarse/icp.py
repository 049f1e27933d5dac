"""The coarse stage's planar registration: the road and lane-centre targets in L, the robust
road score and its raster, the planar point-to-point ICP and the exhaustive hypothesis search
(steps 2-4 of :mod:`fgloc.coarse.localize`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import distance_transform_edt
from scipy.spatial import cKDTree

from fgloc.geo import wrap_angle
from fgloc.map import TargetCloud
from fgloc.scenario import TWO_WAY_MIN_WIDTH, Lanelet, lane_lines


@dataclass
class PlanarTarget:
    """Points (M, 2) in L with their KD-tree, the target of a planar ICP."""

    xy: np.ndarray
    tree: cKDTree

    @classmethod
    def of(cls, xy: np.ndarray) -> PlanarTarget:
        return cls(xy=xy, tree=cKDTree(xy))


@dataclass
class ScoreRaster:
    """float32 raster (nx, ny) of ``clip(1 - d / tau, 0, 1)``, d the distance (m) from the cell
    centre to the nearest occupied cell; origin (2,) is the centre of cell (0, 0), cell (m).
    The raster extends ``pad`` m beyond the points, so its outer ``pad - tau`` m score 0."""

    score: np.ndarray
    origin: np.ndarray
    cell: float

    @classmethod
    def build(cls, xy: np.ndarray, cell: float, pad: float, tau: float) -> ScoreRaster:
        """The raster of points (M, 2) in L."""
        origin = xy.min(axis=0) - pad
        shape = np.ceil((xy.max(axis=0) + pad - origin) / cell).astype(int) + 1
        occ = np.zeros(shape, dtype=bool)
        ij = np.round((xy - origin) / cell).astype(int)
        occ[ij[:, 0], ij[:, 1]] = True
        dist = distance_transform_edt(~occ) * cell
        return cls(np.clip(1.0 - dist / tau, 0.0, 1.0).astype(np.float32), origin, cell)


@dataclass
class RoadModel:
    """Planar view of the road points: a 2D KD-tree with heights, and a score raster.

    planar: unique road points in L (2D) and their tree; z: (M,) their heights (m). score:
    float32 raster (nx, ny) of ``clip(1 - d / tau, 0, 1)``, d being the distance (m) from the
    cell centre to the nearest occupied road cell; origin (2,) is the centre of cell (0, 0). The
    raster extends ``pad`` m beyond the road, so its outer ``pad - tau`` m score 0.
    """

    planar: PlanarTarget
    z: np.ndarray
    score: np.ndarray
    origin: np.ndarray
    cell: float

    @classmethod
    def build(cls, target: TargetCloud, cell: float, pad: float, tau: float) -> RoadModel:
        xyz = target.unique_xyz()
        raster = ScoreRaster.build(xyz[:, :2], cell, pad, tau)
        return cls(PlanarTarget.of(xyz[:, :2]), z=xyz[:, 2], score=raster.score,
                   origin=raster.origin, cell=cell)

    def distance(self, xy: np.ndarray, upper: float = np.inf) -> np.ndarray:
        """2D distance (m) of points (N, 2) to the nearest road point (inf beyond ``upper``)."""
        return self.planar.tree.query(xy, distance_upper_bound=upper)[0]

    def road_height(self, xy: np.ndarray, k: int = 4) -> tuple[np.ndarray, np.ndarray]:
        """Mean height of the k nearest road points under each xy and the nearest distance (m)."""
        d, i = self.planar.tree.query(xy, k=k)
        return self.z[i].mean(axis=1), d[:, 0]


@dataclass
class LaneCentres:
    """Lane centre lines sampled in L: points (K, 2), unit left normals (K, 2) of the driving
    direction, whether each sample's lane runs against its lanelet's direction (K,) (the left
    half of a two-way street, or its centre line driven backwards), the index (K,) of its
    lanelet in the list it was built from and the index (K,) of its lane
    (:func:`fgloc.scenario.lane_lines`)."""

    xy: np.ndarray
    normal: np.ndarray
    against: np.ndarray
    lanelet: np.ndarray
    lane: np.ndarray

    @classmethod
    def build(cls, lanelets: list[Lanelet], step: float,
              two_way_min_width: float = TWO_WAY_MIN_WIDTH) -> LaneCentres:
        """Every lane of the lanelets (:func:`fgloc.scenario.lane_lines` with
        ``two_way_min_width``, which sets the lane model of two-way lanelets), samples about
        ``step`` m apart."""
        index = {id(ll): k for k, ll in enumerate(lanelets)}
        xy, normal, against, which, lane = [], [], [], [], []
        for k, (ll, c, back) in enumerate(lane_lines(lanelets, step, two_way_min_width)):
            d = np.gradient(c, axis=0)
            d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
            xy.append(c)
            normal.append(np.column_stack([-d[:, 1], d[:, 0]]))
            against.append(np.full(len(c), back))
            which.append(np.full(len(c), index[id(ll)], dtype=np.int64))
            lane.append(np.full(len(c), k, dtype=np.int64))
        return cls(np.vstack(xy), np.vstack(normal), np.concatenate(against),
                   np.concatenate(which), np.concatenate(lane))

    def towards(self, sensor_xy: np.ndarray, offset: float) -> PlanarTarget:
        """The centre lines shifted ``offset`` m sideways towards ``sensor_xy`` (2,)."""
        side = np.sign(np.einsum("ij,ij->i", sensor_xy - self.xy, self.normal))
        return PlanarTarget.of(self.xy + (offset * side)[:, None] * self.normal)


def robust_score(d: np.ndarray, tau: float) -> float:
    """Mean of clip(1 - d / tau, 0, 1): 1 for a cloud entirely on the road, 0 for one off it."""
    return float(np.clip(1.0 - np.asarray(d) / tau, 0.0, 1.0).mean()) if np.size(d) else 0.0


def apply_planar(xy: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Apply a planar pose (x, y, yaw) to (N, 2) points."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return xy @ np.array([[c, s], [-s, c]]) + pose[:2]


def _kabsch_2d(p: np.ndarray, q: np.ndarray) -> tuple[float, np.ndarray]:
    """Rotation angle and translation (2,) best mapping points p onto q (both (N, 2))."""
    pc, qc = p.mean(axis=0), q.mean(axis=0)
    h = (p - pc).T @ (q - qc)
    ang = float(np.arctan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1]))
    c, s = np.cos(ang), np.sin(ang)
    return ang, qc - np.array([[c, -s], [s, c]]) @ pc


@dataclass
class IcpOutcome:
    """Planar ICP result: pose (x, y, yaw), whether the last stage converged, iterations run."""

    pose: np.ndarray
    converged: bool
    iterations: int


def icp_planar(
    src: np.ndarray, target: PlanarTarget, pose0: np.ndarray, ranges: list[float],
    iterations: int, tol: float = 1e-3,
) -> IcpOutcome:
    """Point-to-point planar ICP of source points (N, 2) (sensor-centred, levelled) against a
    planar target, one stage per correspondence range (m); returns the pose mapping src to L.

    A stage ends when the update moves the source by less than ``tol`` m (translation plus
    rotation times the source radius) or after ``iterations`` steps.
    """
    pose = np.asarray(pose0, dtype=float).copy()
    radius = float(np.sqrt((src**2).sum(axis=1).max())) if len(src) else 0.0
    converged, total = False, 0
    for rng in ranges:
        converged = False
        for _ in range(iterations):
            total += 1
            cur = apply_planar(src, pose)
            d, idx = target.tree.query(cur, distance_upper_bound=rng)
            ok = np.isfinite(d)
            if ok.sum() < 3:
                break
            ang, t = _kabsch_2d(cur[ok], target.xy[idx[ok]])
            c, s = np.cos(ang), np.sin(ang)
            pose[:2] = np.array([[c, -s], [s, c]]) @ pose[:2] + t
            pose[2] = wrap_angle(pose[2] + ang)
            if np.hypot(*t) + abs(ang) * radius < tol:
                converged = True
                break
    return IcpOutcome(pose=pose, converged=converged, iterations=total)




# --------------------------------------------------------------------------------------------
# global hypothesis search
# --------------------------------------------------------------------------------------------
def search_grid(
    src: np.ndarray, road: RoadModel | ScoreRaster, centre: np.ndarray, yaws: np.ndarray,
    offs: np.ndarray,
) -> np.ndarray:
    """Robust score (nyaw, n, n) of every (yaw, start position ``centre + (offs[i], offs[j])``)
    hypothesis for source points (N, 2), read from the score raster.

    offs must be multiples of the raster cell. Points off the raster are clamped into its
    zero-score border (which needs the raster padded by at least 2 max|offs| + tau).
    """
    nx, ny = road.score.shape
    flat = road.score.ravel()
    k = np.round(offs / road.cell).astype(np.int64)
    shift = (k[:, None] * ny + k[None, :]).ravel()
    m = int(np.abs(k).max())
    out = np.empty((len(yaws), shift.size), dtype=np.float32)
    for a, yaw in enumerate(yaws):
        ij = np.round((apply_planar(src, np.array([*centre, yaw])) - road.origin) / road.cell)
        i = np.clip(ij[:, 0].astype(np.int64), m, nx - 1 - m)
        j = np.clip(ij[:, 1].astype(np.int64), m, ny - 1 - m)
        out[a] = np.take(flat, (i * ny + j)[:, None] + shift[None, :]).mean(axis=0)
    return out.reshape(len(yaws), len(offs), len(offs))


def distinct_peaks(
    scores: np.ndarray, yaws: np.ndarray, offs: np.ndarray, k: int, yaw_sep: float,
    pos_sep: float,
) -> list[tuple[float, float, float, float]]:
    """Up to k best hypotheses (score, yaw, dx, dy) at least yaw_sep rad or pos_sep m apart."""
    order = np.argsort(scores, axis=None)[::-1]
    picked: list[tuple[float, float, float, float]] = []
    for flat in order:
        a, i, j = np.unravel_index(flat, scores.shape)
        yaw, dx, dy = float(yaws[a]), float(offs[i]), float(offs[j])
        if all(
            abs(wrap_angle(yaw - p[1])) >= yaw_sep or np.hypot(dx - p[2], dy - p[3]) >= pos_sep
            for p in picked
        ):
            picked.append((float(scores[a, i, j]), yaw, dx, dy))
            if len(picked) == k:
                break
    return picked


