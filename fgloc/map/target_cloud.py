"""Target cloud (paper IV-A): ALS road points cropped to the lanelets, downsampled and labelled.

Every road point inside a lanelet's polygon inherits that lanelet's label
(:mod:`fgloc.map.lanelet_labels`) and id. Only the map's drivable lanelets
(:attr:`LaneletMap.lanelets`, decided when the map is read) hold target points.

Rules chosen here (documented because the paper leaves them open):

* Overlapping lanelets (inside intersections, merges): a road point inside several polygons is
  kept once per lanelet, each copy with that lanelet's label and id. SICP can then match a
  turning vehicle to the turn lane and a straight one to the straight lane over the same
  asphalt; users who need unique positions take ``np.unique(xyz, axis=0)``.
* Downsampling: one voxel grid anchored at the origin of ``L``; points are averaged per
  (lanelet, voxel) pair (the centroid, as Open3D's ``voxel_down_sample`` does) so labels stay
  pure. Implemented with one ``np.unique`` over packed integer keys instead of one Open3D call
  per lanelet.
* Points exactly on a polygon edge count as inside.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from matplotlib.path import Path as MplPath
from scipy.spatial import cKDTree

from fgloc.config import MapConfig
from fgloc.errors import InputError, LocalizationError
from fgloc.labels import NAMES
from fgloc.map.lanelet_labels import map_labels
from fgloc.scenario import (
    RAGGED_END_GAP,
    AlsCloud,
    Lanelet,
    LaneletMap,
    Scenario,
    lanelets_near,
    nearest_on_segments,
    ragged,
)

#: ASPRS codes that mean "not classified"; an ALS holding only these has no class information.
UNCLASSIFIED_CODES: tuple[int, ...] = (0, 1)
#: Upper bound on the number of point-edge pairs evaluated at once by the boundary test.
_PAIR_CHUNK = 4_000_000


@dataclass
class TargetCloud:
    """Labelled road points in the local frame ``L``.

    xyz: (N, 3) float64 m in L. label: (N,) int8 codes of :mod:`fgloc.labels`. lanelet_id: (N,)
    int64 id of the lanelet each point lies in. lanelet_labels / lanelet_curvature: label and
    signed Menger curvature (1/m, positive = counter-clockwise = left) of every lanelet of the map.
    warnings: what the construction had to work around (e.g. an unclassified ALS, road
    lanelets lanelet2 rejected: :meth:`LaneletMap.warnings`).
    label_source: "routing" or "curvature" per lanelet id (see :func:`map_labels`).
    ignored_lanelets: lanelets of the map not drivable by the configured participant, counted
    per kind (they hold no target point).
    memo: what later stages derive from this cloud, built once and shared, by key
    (:meth:`fgloc.coarse.icp.LaneCentres.of_target`); not an input.
    """

    xyz: np.ndarray
    label: np.ndarray
    lanelet_id: np.ndarray
    lanelet_labels: dict[int, int] = field(default_factory=dict)
    lanelet_curvature: dict[int, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    label_source: dict[int, str] = field(default_factory=dict)
    ignored_lanelets: dict[str, int] = field(default_factory=dict)
    memo: dict[tuple, object] = field(default_factory=dict, init=False, repr=False,
                                      compare=False)

    def __len__(self) -> int:
        return int(self.xyz.shape[0])

    def lanelets(self, lanelet_map: LaneletMap) -> list[Lanelet]:
        """The lanelets of ``lanelet_map`` that hold points of this cloud, in map order."""
        used = set(np.unique(self.lanelet_id).tolist())
        return [ll for ll in lanelet_map.lanelets if ll.id in used]

    def of_label(self, code: int) -> np.ndarray:
        """(M, 3) points carrying label ``code``."""
        return self.xyz[self.label == code]

    def unique_xyz(self) -> np.ndarray:
        """(M, 3) points with the per-lanelet copies of overlapping lanelets merged."""
        return np.unique(self.xyz, axis=0)

    def summary(self) -> dict[str, object]:
        """JSON-ready counts: points in total and per label name, lanelets per label name and
        per label source, ignored (not drivable) lanelets per kind."""
        sources = list(self.label_source.values())
        return {
            "n_points": len(self),
            "points_per_label": {NAMES[k]: int((self.label == k).sum()) for k in NAMES},
            "lanelets_per_label": {
                NAMES[k]: sum(v == k for v in self.lanelet_labels.values()) for k in NAMES
            },
            "lanelets_per_label_source": {k: sources.count(k) for k in sorted(set(sources))},
            "ignored_lanelets": dict(self.ignored_lanelets),
        }


# --------------------------------------------------------------------------------------------
# vectorized point-in-polygon
# --------------------------------------------------------------------------------------------
def _edges(poly: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end points (E, 2) of the closed polygon's edges."""
    p = np.asarray(poly, dtype=float)[:, :2]
    return p, np.roll(p, -1, axis=0)


def _boundary_distance(xy: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance (m) of every point to the nearest polygon edge."""
    return np.linalg.norm(xy - nearest_on_segments(xy, a, b), axis=1)


def _densify(a: np.ndarray, b: np.ndarray, step: float) -> np.ndarray:
    """Points (K, 2) along the edges a -> b, at most ``step`` m apart, ends included."""
    n = np.maximum(1, np.ceil(np.linalg.norm(b - a, axis=1) / step).astype(np.int64))
    edge = np.repeat(np.arange(len(a)), n + 1)
    t = np.concatenate([np.linspace(0.0, 1.0, k + 1) for k in n])
    return a[edge] + t[:, None] * (b - a)[edge]


def points_in_polygon(xy: np.ndarray, poly: np.ndarray, margin: float = 0.0) -> np.ndarray:
    """Boolean mask of points (N, 2) inside a simple polygon (m, 2), concave allowed.

    A point counts as inside when it lies in the polygon's interior or within ``margin`` metres
    of its boundary (``margin = 0`` keeps points exactly on an edge, up to 1e-9 m). The interior
    test is matplotlib's (C speed, undefined exactly on the boundary); points near the boundary,
    found with a KD-tree of boundary samples, are then decided by their exact distance to the
    edges (vectorized over points x edges in bounded chunks).
    """
    xy = np.asarray(xy, dtype=float)[:, :2]
    a, b = _edges(poly)
    tol = max(float(margin), 1e-9)
    inside = MplPath(a).contains_points(xy) if len(xy) else np.zeros(0, dtype=bool)
    step = max(tol, 1.0)
    d, _ = cKDTree(_densify(a, b, step)).query(xy, distance_upper_bound=tol + step / 2 + 1e-9)
    near = np.flatnonzero(np.isfinite(d) & ~inside)
    chunk = max(1, _PAIR_CHUNK // max(1, a.shape[0]))
    for s in range(0, near.size, chunk):
        idx = near[s : s + chunk]
        inside[idx] = _boundary_distance(xy[idx], a, b) <= tol
    return inside


# --------------------------------------------------------------------------------------------
# cropping and downsampling
# --------------------------------------------------------------------------------------------
def select_road_points(als: AlsCloud, road_classes: list[int]) -> tuple[np.ndarray, list[str]]:
    """Mask of ALS points in the road classes, plus warnings.

    An ALS without any classified point (only codes 0/1) falls back to every point.
    """
    cls = np.asarray(als.classification)
    if len(cls) and np.isin(cls, UNCLASSIFIED_CODES).all():
        return np.ones(len(cls), dtype=bool), [
            "ALS has no classified points (only classes 0/1): all points treated as road "
            "candidates, the target cloud may contain vehicles, vegetation and walls"
        ]
    return np.isin(cls, np.asarray(road_classes)), []


def crop_to_lanelets(
    xy: np.ndarray, lanelets: list[Lanelet], margin: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """(point index, lanelet index) pairs of points (N, 2) inside each lanelet polygon.

    A point inside several lanelets yields one pair per lanelet. Each polygon is tested only
    against the points of its bounding box (+ margin), found by binary search on x.
    """
    order = np.argsort(xy[:, 0], kind="stable")
    xs = xy[order, 0]
    pts, lls = [], []
    for j, ll in enumerate(lanelets):
        poly = ll.polygon()
        lo, hi = poly.min(axis=0) - margin, poly.max(axis=0) + margin
        s, e = np.searchsorted(xs, lo[0], "left"), np.searchsorted(xs, hi[0], "right")
        cand = order[s:e]
        cand = cand[(xy[cand, 1] >= lo[1]) & (xy[cand, 1] <= hi[1])]
        hit = cand[points_in_polygon(xy[cand], poly, margin)]
        pts.append(hit)
        lls.append(np.full(hit.shape[0], j, dtype=np.int64))
    if not pts:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    return np.concatenate(pts), np.concatenate(lls)


def voxel_centroids(
    xyz: np.ndarray, group: np.ndarray, voxel: float
) -> tuple[np.ndarray, np.ndarray]:
    """Centroid of the points of each occupied (group, voxel) cell.

    xyz: (N, 3) m; group: (N,) non-negative int; voxel: edge (m) of a grid anchored at the
    origin. Returns (M, 3) centroids and the (M,) group of each.
    """
    if xyz.shape[0] == 0:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    cell = np.floor(xyz / voxel).astype(np.int64)
    cell -= cell.min(axis=0)
    span = cell.max(axis=0) + 1
    key = group.astype(np.int64)
    for k in range(3):
        key = key * span[k] + cell[:, k]
    _, inv = np.unique(key, return_inverse=True)
    inv = inv.reshape(-1)
    n = np.bincount(inv).astype(float)
    cent = np.column_stack([np.bincount(inv, weights=xyz[:, k]) / n for k in range(3)])
    first = np.zeros(n.shape[0], dtype=np.int64)
    first[inv[::-1]] = np.arange(inv.shape[0])[::-1]
    return cent, group[first]


def approx_position_local(scn: Scenario) -> np.ndarray:
    """The sensor's approximate position (2,) in L (m)."""
    return scn.frame.to_local(np.asarray(scn.sensor.approx_position, dtype=float))


def check_inside_als(scn: Scenario) -> None:
    """Raise :class:`InputError` when the approximate position lies outside the ALS extent."""
    if len(scn.als) == 0:
        raise InputError(scn.path, "the ALS point cloud is empty")
    lo = scn.als.xyz[:, :2].min(axis=0).astype(float)
    hi = scn.als.xyz[:, :2].max(axis=0).astype(float)
    c = approx_position_local(scn)
    if np.any(c < lo) or np.any(c > hi):
        w_lo, w_hi = scn.frame.to_world(lo), scn.frame.to_world(hi)
        raise InputError(
            scn.path,
            f"sensor approx_position {tuple(scn.sensor.approx_position)} lies outside the ALS "
            f"extent E [{w_lo[0]:.1f}, {w_hi[0]:.1f}], N [{w_lo[1]:.1f}, {w_hi[1]:.1f}]",
            field="sensor.approx_position",
        )


def _near_sensor(scn: Scenario, xy: np.ndarray, radius: float) -> np.ndarray:
    """Mask of points (N, 2) in L within ``radius`` m of the sensor's approximate position."""
    c = approx_position_local(scn)
    return np.einsum("ij,ij->i", xy - c, xy - c) <= radius * radius


def ragged_warning(lanelets: list[Lanelet]) -> list[str]:
    """A warning naming the ``lanelets`` (those near the sensor) whose bounds end more than
    :data:`~fgloc.scenario.RAGGED_END_GAP` m apart (:func:`~fgloc.scenario.ragged`), or none."""
    ids = ragged(lanelets)
    if not ids:
        return []
    return [f"map: {len(ids)} drivable lanelet(s) near the sensor with bounds whose ends lie "
            f"more than {RAGGED_END_GAP:g} m apart (relation {', '.join(map(str, ids))}): one "
            "bound runs on past the other, so the lane centre there cuts across the road; "
            "vehicles are registered to a line they do not drive (check the map)"]


def build_target_cloud(scn: Scenario, cfg: MapConfig) -> TargetCloud:
    """Target cloud in L from the scenario's ALS and lanelet map (see the module docstring).

    Only ALS points within ``sensor.max_range + cfg.sensor_margin`` metres of the approximate
    sensor position are considered. Raises :class:`InputError` when that position lies outside
    the ALS and :class:`LocalizationError` when no road point lies inside any lanelet there.
    """
    check_inside_als(scn)
    labels = map_labels(scn.lanelets, cfg)
    lanelet_labels = labels.code

    radius = scn.sensor.max_range + cfg.sensor_margin
    road, warnings = select_road_points(scn.als, cfg.road_classes)
    xyz = np.asarray(scn.als.xyz, dtype=np.float64)
    keep = road & _near_sensor(scn, xyz[:, :2], radius)
    xyz = xyz[keep]
    centre = approx_position_local(scn)
    near = lanelets_near(scn.lanelets.lanelets, centre, radius)
    pt, lj = crop_to_lanelets(xyz[:, :2], near, cfg.crop_margin)
    if pt.size == 0:
        classes = "any class" if warnings else f"classes {list(cfg.road_classes)}"
        raise LocalizationError(
            f"no ALS road points ({classes}) inside the {len(near)} lanelet(s) within "
            f"{radius:.0f} m of the approximate sensor position ({int(keep.sum())} road-class "
            f"points there): check that ALS tiles, lanelet map and approx_position overlap"
        )
    cent, lj_v = voxel_centroids(xyz[pt], lj, cfg.voxel_size)
    near_ids = np.array([ll.id for ll in near], dtype=np.int64)
    lid = near_ids[lj_v]
    label = np.array([lanelet_labels[int(i)] for i in near_ids], dtype=np.int8)[lj_v]
    return TargetCloud(
        xyz=cent,
        label=label,
        lanelet_id=lid,
        lanelet_labels=lanelet_labels,
        lanelet_curvature=labels.curvature,
        warnings=[*warnings, *scn.lanelets.warnings(), *ragged_warning(near)],
        label_source=labels.source,
        ignored_lanelets=scn.lanelets.ignored_by_kind(),
    )
