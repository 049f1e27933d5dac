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
from fgloc.scenario import TWO_WAY_MIN_WIDTH, Lanelet, LaneletMap, lane_ambiguity, lane_lines


@dataclass
class PlanarTarget:
    """Points (M, 2) in L with their KD-tree, the target of a planar ICP."""

    xy: np.ndarray
    tree: cKDTree

    @classmethod
    def of(cls, xy: np.ndarray) -> PlanarTarget:
        return cls(xy=xy, tree=cKDTree(xy))

    def query(self, xy: np.ndarray, receding: np.ndarray | None, upper: float
              ) -> tuple[np.ndarray, np.ndarray]:
        """Distance (N,) (m; inf beyond ``upper``) and nearest target point (N, 2) of points
        ``xy`` (N, 2) in L (where the distance is inf: the point itself). ``receding`` (the
        points' Doppler signs) is not read: any point may match any target point."""
        if not len(self.xy):
            return np.full(len(xy), np.inf), np.array(xy, dtype=float)
        d, i = self.tree.query(xy, distance_upper_bound=upper)
        near = self.xy[np.minimum(i, len(self.xy) - 1)]
        return d, np.where(np.isfinite(d)[:, None], near, xy)


@dataclass
class SignedLanes:
    """Lane lines seen from one sensor position, split by the Doppler sign of the vehicles
    that may drive them: ``receding`` holds the samples a point moving away from the sensor
    (Doppler > 0) may match, ``approaching`` those a point moving towards it may match. A lane
    is in both where it runs within the gate angle of square to the line of sight (its
    vehicles' Doppler sign says nothing there)."""

    receding: PlanarTarget
    approaching: PlanarTarget

    def query(self, xy: np.ndarray, receding: np.ndarray | None, upper: float
              ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`PlanarTarget.query` of points ``xy`` (N, 2) each against the lanes of its
        Doppler sign (``receding`` (N,) bool)."""
        if receding is None:
            raise ValueError("SignedLanes.query needs the points' Doppler signs (receding)")
        d, near = np.empty(len(xy)), np.empty((len(xy), 2))
        for target, sel in ((self.receding, receding), (self.approaching, ~receding)):
            d[sel], near[sel] = target.query(xy[sel], None, upper)
        return d, near


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
    lanelet in the list it was built from, the index (K,) of its lane
    (:func:`fgloc.scenario.lane_lines`), the offset (K, 2) (m) between the two
    constructions of its lanelet's centre line there (:meth:`fgloc.scenario.Lanelet.centre`;
    None: not computed, 0) and the bend (K,) (m): how far the lane lies from its lanelet's
    own centre line where it bends into a lane of the lanelet before or after it (a lanelet
    that leads into or out of a two-way street's right half, :func:`fgloc.scenario.lane_lines`;
    0 elsewhere, also on the halves of a two-way street; None: not computed, 0)."""

    xy: np.ndarray
    normal: np.ndarray
    against: np.ndarray
    lanelet: np.ndarray
    lane: np.ndarray
    centre_offset: np.ndarray | None = None
    bend: np.ndarray | None = None

    @classmethod
    def build(cls, lanelets: list[Lanelet], step: float,
              two_way_min_width: float = TWO_WAY_MIN_WIDTH,
              centre: str = "resampled") -> LaneCentres:
        """Every lane of the lanelets (:func:`fgloc.scenario.lane_lines` with
        ``two_way_min_width``, which sets the lane model of two-way lanelets), samples about
        ``step`` m apart, each lane moved as its lanelet's centre line of kind ``centre``
        (:data:`fgloc.scenario.CENTRE_LINES`; ``[map] centre_line``) lies from the arc-length
        one (the lanes of :func:`~fgloc.scenario.lane_lines` are built on that)."""
        index = {id(ll): k for k, ll in enumerate(lanelets)}
        xy, normal, against, which, lane, offsets, bends = [], [], [], [], [], [], []
        for k, (ll, c, back) in enumerate(lane_lines(lanelets, step, two_way_min_width)):
            own = ll.centerline(len(c))
            # the halves of a two-way street keep right by the model: no bend
            bend = np.zeros_like(c) if ll.keeps_right(two_way_min_width) else (
                c - (own[::-1] if back else own))
            line, off = ll.centre(len(c), centre)
            shift = line - own
            c = c + (shift[::-1] if back else shift)
            offsets.append(off[::-1] if back else off)
            d = np.gradient(c, axis=0)
            d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
            n = np.column_stack([-d[:, 1], d[:, 0]])
            bends.append(np.abs(np.einsum("ij,ij->i", bend, n)))     # sideways part
            xy.append(c)
            normal.append(n)
            against.append(np.full(len(c), back))
            which.append(np.full(len(c), index[id(ll)], dtype=np.int64))
            lane.append(np.full(len(c), k, dtype=np.int64))
        return cls(np.vstack(xy), np.vstack(normal), np.concatenate(against),
                   np.concatenate(which), np.concatenate(lane), np.vstack(offsets),
                   np.concatenate(bends))

    @classmethod
    def of_target(cls, target: TargetCloud, lanelet_map: LaneletMap, step: float,
                  two_way_min_width: float, centre: str) -> LaneCentres:
        """:meth:`build` on the lanelets of ``lanelet_map`` that hold points of ``target``
        (:meth:`TargetCloud.lanelets`), built once per argument set and kept in
        ``target.memo``, its arrays read-only: the coarse stage, every mode's fine and joint
        targets and each probe of a valley ask for the same lanes (a valley's 60 probes
        rebuilt them each time)."""
        # the entry holds the map, so its id cannot be reused while the entry lives
        key = ("lane centres", id(lanelet_map), step, two_way_min_width, centre)
        hit = target.memo.get(key)
        if hit is not None:
            return hit[1]
        lanes = cls.build(target.lanelets(lanelet_map), step, two_way_min_width, centre)
        for value in vars(lanes).values():
            if isinstance(value, np.ndarray):
                value.setflags(write=False)
        target.memo[key] = (lanelet_map, lanes)
        return lanes

    @property
    def direction(self) -> np.ndarray:
        """(K, 2) unit driving direction of each sample (its left normal turned clockwise)."""
        return np.column_stack([self.normal[:, 1], -self.normal[:, 0]])

    def ambiguity(self) -> np.ndarray:
        """(K,) where vehicles drive is this uncertain (m) at each sample
        (:func:`fgloc.scenario.lane_ambiguity` of the centre offset and the bend)."""
        return lane_ambiguity(len(self.xy), self.centre_offset, self.bend)

    def aspect(self, sensor_xy: np.ndarray) -> np.ndarray:
        """(K,) |sin| of the angle between each sample's driving direction and the line of
        sight from ``sensor_xy`` (2,) to it: 0 head-on, 1 broadside."""
        los = self.xy - np.asarray(sensor_xy, dtype=float)
        dist = np.maximum(np.linalg.norm(los, axis=1), 1e-9)
        return np.abs(np.einsum("ij,ij->i", los, self.normal)) / dist

    def towards(self, sensor_xy: np.ndarray, offset: float | np.ndarray) -> PlanarTarget:
        """The centre lines shifted ``offset`` m (one for all, or (K,) per sample) sideways
        towards ``sensor_xy`` (2,)."""
        return PlanarTarget.of(self._shifted(sensor_xy, offset))

    def seen_from(self, sensor_xy: np.ndarray, offset: float | np.ndarray, gate_deg: float
                  ) -> SignedLanes:
        """:meth:`towards` (``offset`` m, one for all or (K,) per sample), split by Doppler
        sign (:class:`SignedLanes`): a sample whose driving direction ``d`` has ``d . u >
        -sin(gate_deg)`` (``u`` the unit line of sight from ``sensor_xy`` to it) may be driven
        away from the sensor, one with ``d . u < sin(gate_deg)`` towards it; 90 deg admits
        every sample for both signs."""
        xy = self._shifted(sensor_xy, offset)
        los = xy - np.asarray(sensor_xy, dtype=float)
        los /= np.maximum(np.linalg.norm(los, axis=1, keepdims=True), 1e-9)
        away = los[:, 0] * self.normal[:, 1] - los[:, 1] * self.normal[:, 0]   # d . u
        tol = np.sin(np.deg2rad(gate_deg))
        return SignedLanes(PlanarTarget.of(xy[away >= -tol]), PlanarTarget.of(xy[away <= tol]))

    def _shifted(self, sensor_xy: np.ndarray, offset: float | np.ndarray) -> np.ndarray:
        side = np.sign(np.einsum("ij,ij->i", sensor_xy - self.xy, self.normal))
        return self.xy + (offset * side)[:, None] * self.normal


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
    src: np.ndarray, target: PlanarTarget | SignedLanes, pose0: np.ndarray, ranges: list[float],
    iterations: int, tol: float = 1e-3, receding: np.ndarray | None = None,
) -> IcpOutcome:
    """Point-to-point planar ICP of source points (N, 2) (sensor-centred, levelled) against a
    planar target, one stage per correspondence range (m); returns the pose mapping src to L.
    ``receding`` (N,) bool: the points' Doppler signs, needed by a :class:`SignedLanes` target
    (each point matched only to the lanes its sign may drive).

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
            d, near = target.query(cur, receding, rng)
            ok = np.isfinite(d)
            if ok.sum() < 3:
                break
            ang, t = _kabsch_2d(cur[ok], near[ok])
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


