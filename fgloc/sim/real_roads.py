"""A real Lanelet2 map as the simulator's road network: junctions, routes, curbs and scenery.

The synthetic simulator drives vehicles along lane pieces made of constant-curvature primitives
(:mod:`fgloc.sim.paths`). Here every route of the routing graph through a junction becomes one
such piece: its lanelets' centre lines are concatenated, smoothed a little (maps draw kinks at
lanelet joins) and turned into 1 m primitives whose curvature reproduces the polyline's headings,
so :func:`fgloc.sim.traffic.simulate_traffic` drives them unchanged. Routes follow the routing
graph per driving direction (:attr:`fgloc.scenario.LaneletMap.directed_successors`): a
two-way lanelet is driven both ways, on its centre line or each direction on its right half
(``SimConfig.real_map.two_way_traffic``). Road edges (lanelet bounds
with no drivable lanelet beside them) become curb pieces for the radar's static clutter;
buildings and vegetation come from the map's areas.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.cluster.hierarchy import fcluster, linkage

from fgloc.labels import junction_movements
from fgloc.map import crop_to_lanelets, points_in_polygon
from fgloc.map.lane_models import min_width
from fgloc.scenario import (
    TWO_WAY_MIN_WIDTH,
    Lanelet,
    LaneletMap,
    MapArea,
    lane_lines,
    resample_polyline,
)
from fgloc.sim.config import AlsSimConfig
from fgloc.sim.paths import Prim
from fgloc.sim.roads import LanePiece, RoadNetwork
from fgloc.sim.scenery import Scenery

#: spacing (m) of the primitives a route is made of
ROUTE_STEP = 1.0
#: default half window (samples at ROUTE_STEP) of the moving average that smooths a route's
#: kinks (``SimConfig.real_map.path_half_window``)
SMOOTH_HALF_WINDOW = 2
#: how far (m) beside a bound the curb test looks for another drivable lanelet
CURB_PROBE = 1.0


@dataclass
class Junction:
    """A junction of the routing graph: its centre (2,) in L (m) and its movements (chains of
    lanelet ids, :func:`fgloc.labels.junction_movements`)."""

    centre: np.ndarray
    movements: list[list[int]]


@dataclass
class DirectedLanelets:
    """The drivable lanelets of a map once per driving direction, as a map of its own.

    ``map.lanelets``: every drivable lanelet in its own direction (its own id) and every one the
    routing graph drives against its direction (a two-way lanelet) inverted: bounds swapped and
    reversed (so its right half is the right half of that direction), attributes kept, under a
    new id (larger than any lanelet id of the map); ``map.successors``: the routing graph per
    direction (:attr:`LaneletMap.directed_successors`) over these ids. ``source``: id ->
    (lanelet id of the map, inverted)."""

    map: LaneletMap
    source: dict[int, tuple[int, bool]]


def directed_lanelets(lmap: LaneletMap) -> DirectedLanelets:
    """The map's lanelets per driving direction (:class:`DirectedLanelets`). A map without
    :attr:`LaneletMap.directed_successors` (built in memory) is driven in the lanelets' own
    direction along :attr:`LaneletMap.successors`."""
    directed = lmap.directed_successors or {
        (a, False): tuple((b, False) for b in succ) for a, succ in lmap.successors.items()}
    by_id = {ll.id: ll for ll in lmap.lanelets}
    inverted = sorted({k for k in (*directed, *(x for v in directed.values() for x in v))
                       if k[1] and k[0] in by_id})
    offset = 1 + max((abs(i) for i in by_id), default=0)
    ids = {(i, False): i for i in by_id}
    ids.update({key: offset + k for k, key in enumerate(inverted)})
    lanelets = list(lmap.lanelets)
    for i, _ in inverted:
        ll = by_id[i]
        lanelets.append(Lanelet(ids[(i, True)], ll.right[::-1].copy(), ll.left[::-1].copy(),
                                dict(ll.attributes)))
    succ = {ids[a]: tuple(ids[b] for b in v if b in ids) for a, v in directed.items()
            if a in ids}
    return DirectedLanelets(LaneletMap(lanelets, successors={k: v for k, v in succ.items() if v}),
                            {v: k for k, v in ids.items()})


def find_junctions(lmap: LaneletMap, link_distance: float = 25.0) -> list[Junction]:
    """Junctions of the map: movements whose first lanelets lie within ``link_distance`` m of
    each other (single linkage) form one; sorted by number of movements (most first). Give it
    the map of :func:`directed_lanelets` for the movements in both directions of two-way
    lanelets."""
    moves = junction_movements(lmap)
    if not moves:
        return []
    by_id = {ll.id: ll for ll in lmap.lanelets}
    centres = np.array([by_id[m[0]].centerline(5).mean(axis=0) for m in moves])
    groups = (np.ones(1, dtype=int) if len(moves) == 1 else
              fcluster(linkage(centres, "single"), link_distance, "distance"))
    out = [Junction(centres[groups == g].mean(axis=0), [m for m, k in zip(moves, groups)
                                                        if k == g])
           for g in np.unique(groups)]
    return sorted(out, key=lambda j: (-len(j.movements), float(j.centre[0])))


def _heading_change(a: Lanelet, b: Lanelet) -> float:
    """|heading change| (rad) from the end of ``a`` to the end of ``b``."""
    da, db = np.diff(a.centerline(6)[-2:], axis=0)[0], np.diff(b.centerline(6)[-2:], axis=0)[0]
    return abs(float(np.arctan2(da[0] * db[1] - da[1] * db[0], da @ db)))


def _extend(start: int, graph: dict[int, tuple[int, ...]], by_id: dict[int, Lanelet],
            reach: float, seen: set[int]) -> list[int]:
    """Lanelet ids from ``start`` along ``graph`` (successors or predecessors) for about
    ``reach`` m, taking the straightest branch at every fork and never a lanelet twice."""
    out: list[int] = []
    length, cur = 0.0, start
    while length < reach:
        nxt = [i for i in graph.get(cur, ()) if i in by_id and i not in seen]
        if not nxt:
            break
        cur = min(nxt, key=lambda i: _heading_change(by_id[cur], by_id[i]))
        seen.add(cur)
        out.append(cur)
        c = by_id[cur].centerline(10)
        length += float(np.linalg.norm(np.diff(c, axis=0), axis=1).sum())
    return out


def road_site(lmap: LaneletMap, centre: np.ndarray, radius: float = 10.0) -> Junction | None:
    """A site on a road where the map has no junction: ``centre`` (2,) m in L and, as its
    movements, every lanelet of ``lmap`` whose centre line passes within ``radius`` m of it,
    each alone (:func:`junction_routes` extends them along the routing graph). Give it the map
    of :func:`directed_lanelets` for both directions of two-way lanelets. None when no lanelet
    passes there."""
    near = [ll.id for ll in lmap.lanelets
            if np.hypot(*(every_metre(ll.centerline(20)) - centre).T).min() <= radius]
    return Junction(np.asarray(centre, dtype=float), [[i] for i in sorted(near)]) if near \
        else None


def every_metre(xy: np.ndarray) -> np.ndarray:
    """The polyline (n, 2) resampled about every metre (m, L)."""
    length = float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum())
    return resample_polyline(xy, max(2, int(length) + 1))


def junction_routes(lmap: LaneletMap, junction: Junction, reach: float) -> list[list[int]]:
    """One route (lanelet ids in driving order) per movement of the junction: the movement
    plus about ``reach`` m of its predecessors and successors (straightest at forks)."""
    by_id = {ll.id: ll for ll in lmap.lanelets}
    pred = lmap.predecessors()
    routes = []
    for move in junction.movements:
        seen = set(move)
        back = _extend(move[0], pred, by_id, reach, seen)
        ahead = _extend(move[-1], lmap.successors, by_id, reach, seen)
        routes.append([*back[::-1], *move, *ahead])
    return routes


@dataclass(frozen=True)
class PathSmoothing:
    """How a route's lane line becomes the path driven (``SimConfig.real_map.path_smoothing``):
    ``kind`` "moving-average" (over ``2 * half_window + 1`` samples, ROUTE_STEP m apart),
    "spline" (a cubic smoothing spline against arc length, penalty ``spline_length ** 4``) or
    "none"."""

    kind: str = "moving-average"
    half_window: int = SMOOTH_HALF_WINDOW
    spline_length: float = 3.0


def smooth_path(xy: np.ndarray, smoothing: PathSmoothing = PathSmoothing()) -> np.ndarray:
    """The path (n, 2) vehicles drive along a route's line ``xy`` (n, 2), ROUTE_STEP m
    sampled, as ``smoothing`` says; the first and last samples stay in place (a moving
    average keeps its first and last ``half_window + 1``)."""
    xy = np.asarray(xy, dtype=float)
    if smoothing.kind == "moving-average":
        h = smoothing.half_window
        if h < 1 or len(xy) <= 2 * h + 2:
            return xy
        padded = np.vstack([np.repeat(xy[:1], h, 0), xy, np.repeat(xy[-1:], h, 0)])
        kernel = np.ones(2 * h + 1) / (2 * h + 1)
        smooth = np.column_stack([np.convolve(padded[:, k], kernel, "valid") for k in (0, 1)])
        smooth[:h + 1], smooth[-h - 1:] = xy[:h + 1], xy[-h - 1:]
        return smooth
    if smoothing.kind == "spline":
        from scipy.interpolate import make_smoothing_spline

        if len(xy) < 5:
            return xy
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
        keep = np.concatenate([[True], np.diff(s) > 1e-9])
        s, xy = s[keep], xy[keep]
        lam = float(smoothing.spline_length) ** 4
        out = np.column_stack([make_smoothing_spline(s, xy[:, k], lam=lam)(s) for k in (0, 1)])
        out[0], out[-1] = xy[0], xy[-1]
        return out
    if smoothing.kind == "none":
        return xy
    raise ValueError(f"unknown path smoothing {smoothing.kind!r}")


def lanelet2_centre_lines(directed: DirectedLanelets) -> dict[int, np.ndarray]:
    """lanelet2's own centre line (:meth:`fgloc.scenario.Lanelet.lanelet2_centerline`) of
    every lanelet of ``directed`` ((n, 2) m in L, in the lanelet's driving direction): an
    inverted lanelet's is its map lanelet's reversed, as ``lanelet2.core.Lanelet.invert``
    gives it (lanelet2's construction of the swapped bounds is another line)."""
    by_id = {ll.id: ll for ll in directed.map.lanelets}   # a map lanelet keeps its id
    return {lid: by_id[orig].lanelet2_centerline()[::-1 if inverted else 1]
            for lid, (orig, inverted) in directed.source.items()}


def _polyline(lanelets: list[Lanelet], attr: str,
              two_way_min_width: float = TWO_WAY_MIN_WIDTH,
              smoothing: PathSmoothing = PathSmoothing(),
              centre_lines: dict[int, np.ndarray] | None = None) -> np.ndarray:
    """(n, 2) concatenation of the lanelets' lanes in their direction (``attr="centre"``: the
    centre line, the right half's on a two-way lanelet at least ``two_way_min_width`` m wide,
    :func:`fgloc.scenario.lane_lines`) or bounds, resampled every ROUTE_STEP m, kinks at the
    joins smoothed as ``smoothing`` says (:func:`smooth_path`). ``centre_lines``: lanelet id
    -> (m, 2) line that replaces a lanelet's own centre line where its lane is that centre
    line (e.g. :func:`lanelet2_centre_lines`; the right half of a two-way street and a line
    bending into one stay)."""
    if attr == "centre":
        given = centre_lines or {}
        lines = [resample_polyline(given[ll.id], len(c))
                 if ll.id in given and np.allclose(c, ll.line_at(0.5, len(c))) else c
                 for ll, c, back in lane_lines(lanelets, ROUTE_STEP / 2, two_way_min_width)
                 if not back]
    else:
        lines = [getattr(ll, attr)[:, :2] for ll in lanelets]
    parts = []
    for p in lines:
        parts.append(p if not parts else p[1:])
    xy = np.vstack(parts)
    length = float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum())
    xy = resample_polyline(xy, max(3, int(np.ceil(length / ROUTE_STEP)) + 1))
    return smooth_path(xy, smoothing)


def piece_from_polyline(pid: int, xy: np.ndarray, width: float, curb: bool = False) -> LanePiece:
    """A lane piece following the polyline (n, 2): one primitive per segment whose curvature
    turns the heading from one vertex's to the next's (vertex heading = mean of the adjacent
    segments'), so the traced path stays within millimetres of the polyline."""
    seg = np.diff(xy, axis=0)
    length = np.linalg.norm(seg, axis=1)
    keep = length > 1e-6
    seg, length = seg[keep], length[keep]
    th = np.unwrap(np.arctan2(seg[:, 1], seg[:, 0]))
    phi = np.concatenate([[th[0]], 0.5 * (th[:-1] + th[1:]), [th[-1]]])
    prims: list[Prim] = [(float(s), float(k)) for s, k in zip(length, np.diff(phi) / length)]
    return LanePiece(pid, np.asarray(xy[0], dtype=float), float(phi[0]), prims, width, curb=curb)


def _mean_width(lanelets: list[Lanelet], two_way_min_width: float) -> float:
    """Mean width (m) of the lanes a route drives (half a two-way street's when its traffic
    keeps right, :func:`_polyline`)."""
    return float(np.mean([ll.width() / (2 if ll.keeps_right(two_way_min_width) else 1)
                          for ll in lanelets]))


def curb_polylines(lanelets: list[Lanelet]) -> list[np.ndarray]:
    """Road edges: each bound (n, 2) with no drivable lanelet within CURB_PROBE m beyond it,
    oriented so that off-road lies to its right."""
    out = []
    for ll in lanelets:
        for bound, side in ((ll.right[:, :2], -1.0), (ll.left[:, :2], 1.0)):
            mid = resample_polyline(bound, 3)
            d = mid[2] - mid[0]
            if not np.linalg.norm(d):
                continue
            normal = np.array([-d[1], d[0]]) / np.linalg.norm(d)  # left of the driving direction
            probe = mid[1] + side * CURB_PROBE * normal
            if not any(points_in_polygon(probe[None], o.polygon())[0] for o in lanelets):
                out.append(bound if side < 0 else bound[::-1])
    return out


@dataclass
class MapRoadNetwork(RoadNetwork):
    """Road network of a real map: the first ``n_routes`` pieces are whole routes (each its own
    route), the rest curb pieces (zero width, only for the radar's curb clutter)."""

    n_routes: int = 0

    def routes(self) -> list[list[int]]:
        return [[i] for i in range(self.n_routes)]

    def centre_samples(self, ds: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        """Centre lines of the routes only (curb pieces are no road)."""
        traces = [(p.trace(ds), p.width) for p in self.pieces[: self.n_routes]]
        return (np.vstack([t.xy for t, _ in traces]),
                np.concatenate([np.full(len(t.s), 0.5 * w) for t, w in traces]))


def build_map_network(lmap: LaneletMap, routes: list[list[Lanelet]], centre: np.ndarray,
                      radius: float, two_way_traffic: str = "keep-right",
                      smoothing: PathSmoothing = PathSmoothing(),
                      centre_lines: dict[int, np.ndarray] | None = None) -> MapRoadNetwork:
    """Route pieces for ``routes`` (lanelets in driving order, inverted ones as
    :func:`directed_lanelets` makes them) driven as ``two_way_traffic`` says
    (:func:`fgloc.map.lane_models.min_width`: a two-way lanelet at least
    :data:`fgloc.scenario.TWO_WAY_MIN_WIDTH` wide keeps right), plus curb pieces of the
    drivable lanelets of ``lmap`` within ``radius`` m of ``centre`` (2,). ``smoothing``: how
    a route's line becomes the path driven (:func:`smooth_path`); ``centre_lines``: lanelet id
    -> the centre line driven instead of the lanelet's own (:func:`_polyline`)."""
    width = min_width(two_way_traffic)
    pieces = [piece_from_polyline(k, _polyline(r, "centre", width, smoothing, centre_lines),
                                  _mean_width(r, width))
              for k, r in enumerate(routes)]
    near = [ll for ll in lmap.lanelets
            if np.min(np.linalg.norm(ll.polygon() - centre, axis=1)) <= radius]
    for curb in curb_polylines(near):
        if len(curb) >= 2 and np.linalg.norm(curb[-1] - curb[0]) > 0.5:
            xy = resample_polyline(curb, max(2, int(np.linalg.norm(np.diff(curb, axis=0),
                                                                   axis=1).sum()) + 1))
            pieces.append(piece_from_polyline(len(pieces), xy, 0.0, curb=True))
    return MapRoadNetwork(pieces, np.zeros((0, 2)), [], n_routes=len(routes))


@dataclass
class DrivableArea:
    """Road surface of the ALS: the drivable lanelets' polygons (duck-types
    :class:`fgloc.sim.roads.RoadArea` for :func:`fgloc.sim.als.synthesize_als`)."""

    lanelets: list[Lanelet]
    cache: dict[int, np.ndarray] = field(default_factory=dict)

    def clearance(self, xy: np.ndarray, upper: float = np.inf) -> np.ndarray:
        """-1 inside a drivable lanelet, ``upper`` elsewhere (only the sign is used)."""
        xy = np.asarray(xy, dtype=float)[:, :2]
        out = np.full(len(xy), float(upper) if np.isfinite(upper) else 1.0)
        idx, _ = crop_to_lanelets(xy, self.lanelets)
        out[idx] = -1.0
        return out


def _oriented_box(outline: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Centre (2,), size (length, width) and yaw of the principal-axes box around a polygon."""
    c = outline.mean(axis=0)
    _, _, vt = np.linalg.svd(outline - c, full_matrices=False)
    u = (outline - c) @ vt.T
    lo, hi = u.min(axis=0), u.max(axis=0)
    return c + ((lo + hi) / 2) @ vt, hi - lo, float(np.arctan2(vt[0, 1], vt[0, 0]))


@dataclass
class Roof:
    """A building of the map: its outline (m, 2) in L and its height (m) above the ground."""

    outline: np.ndarray
    height: float


def map_scenery(rng: np.random.Generator, cfg: AlsSimConfig, areas: list[MapArea],
                poles: Scenery, road: DrivableArea, centre: np.ndarray
                ) -> tuple[Scenery, list[Roof]]:
    """Scenery for the radar and the roofs for the ALS from the map's areas within the tile
    around ``centre``: every building area is a roof of random height; those close to a
    rectangle (their principal-axes box at most 25 % larger) are also boxes for the radar's
    occlusion and facade clutter (a box around an L- or U-shaped building would cover the
    street). Trees inside the vegetation areas (about one per 60 m², at most ``cfg.trees``, off
    the road) and the poles of ``poles``."""
    half = cfg.extent / 2.0
    inside = [a for a in areas if np.max(np.abs(a.outline.mean(axis=0) - centre)) < half]
    roofs = [Roof(a.outline, float(rng.uniform(*cfg.building_height)))
             for a in inside if a.subtype == "building"]
    boxes = []
    for roof in roofs:
        c, size, yaw = _oriented_box(roof.outline)
        x, y = roof.outline[:, 0], roof.outline[:, 1]
        area = 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
        if np.prod(size) <= 1.25 * area:
            boxes.append((c, size, yaw, roof.height))
    cand = []
    for a in inside:
        if a.subtype != "vegetation":
            continue
        lo, hi = a.outline.min(axis=0), a.outline.max(axis=0)
        n = int(np.ceil(np.prod(hi - lo) / 60.0))
        pts = rng.uniform(lo, hi, (n, 2))
        cand.append(pts[points_in_polygon(pts, a.outline)])
    trees = np.vstack(cand) if cand else np.zeros((0, 2))
    trees = trees[rng.permutation(len(trees))][: cfg.trees]
    radius = rng.uniform(*cfg.crown_radius, len(trees))
    clear = np.ones(len(trees), dtype=bool)
    for k in range(8):  # the whole crown off the road
        ang = 2 * np.pi * k / 8
        ring = trees + radius[:, None] * np.array([np.cos(ang), np.sin(ang)])
        clear &= road.clearance(ring, 1.0) > 0
    trees, radius = trees[clear], radius[clear]
    b = np.array([x[0] for x in boxes]).reshape(-1, 2)
    scenery = Scenery(b, np.array([x[1] for x in boxes]).reshape(-1, 2),
                      np.array([x[2] for x in boxes]), np.array([x[3] for x in boxes]),
                      trees, radius, rng.uniform(*cfg.tree_height, len(trees)),
                      poles.pole_xy, poles.pole_height)
    return scenery, roofs
