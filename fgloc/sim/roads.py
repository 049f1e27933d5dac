"""Road layouts -> lane pieces (one per lane per movement) -> Lanelet2 lanelets.

Layouts are built in a site frame with the junction (or the road's reference point) at the
origin and then translated into L. Right-hand traffic. A lane piece is a path (see
:mod:`fgloc.sim.paths`) of constant width; its lanelet bounds are the path offset by +- width/2,
so straight pieces are exactly straight and turn pieces are exact circular arcs (with at most
one straight lead-in or lead-out).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from matplotlib.path import Path as MplPath
from scipy.spatial import cKDTree

from fgloc.scenario import Lanelet, LaneletMap
from fgloc.sim.config import RoadSimConfig
from fgloc.sim.paths import Prim, Trace, end_pose, offset_prims, reverse_prims, trace, turn_prims

#: lanelet bound sampling (m)
MAP_DS = 1.0


@dataclass
class LanePiece:
    """One lane of one movement: a path with constant width.

    turn: "left"/"right"/"straight" for junction movements and curve segments (written as the
    lanelet's turn_direction), None for plain approach/exit lanes. curb: the right bound is a
    road edge (outermost lanes and right turns).
    """

    id: int
    start: np.ndarray
    heading: float
    prims: list[Prim]
    width: float
    turn: str | None = None
    curb: bool = False
    successors: list[int] = field(default_factory=list)

    def trace(self, ds: float) -> Trace:
        return trace(self.start, self.heading, self.prims, ds)

    def end(self) -> tuple[np.ndarray, float]:
        return end_pose(self.start, self.heading, self.prims)


@dataclass
class Anchor:
    """Where a sensor may stand: beside ``point`` (on a road centre line running at ``tangent``
    rad, road half width ``half_width`` m) on one of ``sides`` (+1 left, -1 right of the tangent),
    looking at ``target``."""

    point: np.ndarray
    tangent: float
    half_width: float
    target: np.ndarray
    sides: tuple[int, ...] = (1, -1)


@dataclass
class RoadNetwork:
    """Lane pieces plus the paved junction area (polygon, may be empty) and sensor anchors."""

    pieces: list[LanePiece]
    junction: np.ndarray
    anchors: list[Anchor]

    def translate(self, d: np.ndarray) -> None:
        """Shift everything by the 2D vector ``d`` (site frame -> L)."""
        for p in self.pieces:
            p.start = p.start + d
        self.junction = self.junction + d
        for a in self.anchors:
            a.point = a.point + d
            a.target = a.target + d

    def routes(self) -> list[list[int]]:
        """Every sequence of piece indices from an entry piece to an exit piece."""
        preds = {s for p in self.pieces for s in p.successors}
        stack = [[i] for i, p in enumerate(self.pieces) if p.id not in preds]
        index = {p.id: i for i, p in enumerate(self.pieces)}
        out = []
        while stack:
            r = stack.pop()
            succ = self.pieces[r[-1]].successors
            if not succ:
                out.append(r)
            stack.extend(r + [index[s]] for s in succ)
        return sorted(out)

    def curb_line(self, ds: float) -> tuple[np.ndarray, np.ndarray]:
        """(n, 2) points on the road edges (curbs) and (n, 2) unit normals pointing off-road."""
        curbs = [(p.trace(ds), p.width) for p in self.pieces if p.curb]
        edge = np.vstack([t.offset(-0.5 * w) for t, w in curbs])
        return edge, np.vstack([-t.normal() for t, _ in curbs])

    def centre_samples(self, ds: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
        """(n, 2) points on all lane centre lines and (n,) the lane half width at each."""
        traces = [(p.trace(ds), p.width) for p in self.pieces]
        xy = np.vstack([t.xy for t, _ in traces])
        hw = np.concatenate([np.full(len(t.s), 0.5 * w) for t, w in traces])
        return xy, hw


def _unit(angle: float) -> np.ndarray:
    return np.array([np.cos(angle), np.sin(angle)])


class _Builder:
    """Allocates piece ids and links pieces."""

    def __init__(self, width: float) -> None:
        self.width = width
        self.pieces: list[LanePiece] = []

    def add(self, start: np.ndarray, heading: float, prims: list[Prim], turn: str | None = None,
            curb: bool = False) -> LanePiece:
        piece = LanePiece(1000 + len(self.pieces), np.asarray(start, float), heading, prims,
                          self.width, turn, curb)
        self.pieces.append(piece)
        return piece


def _junction(angles: list[float], lanes: list[int], cfg: RoadSimConfig,
              distance: float) -> RoadNetwork:
    """A junction of arms leaving the origin at ``angles`` (rad) with ``lanes`` per direction.

    Opposite arms (exactly pi apart) are one straight road; every other arm pair is a turn.
    Per arm: approach lanes (inbound), exit lanes (outbound); per movement one piece per lane:
    straight i -> i, left turns from the innermost lane, right turns from the outermost lane.
    """
    w = cfg.lane_width
    b = _Builder(w)
    hw = [n * w for n in lanes]
    gaps = np.diff(np.sort(np.concatenate([angles, [min(angles) + 2 * np.pi]])))
    stop = max(hw) / np.sin(min(np.min(gaps), np.pi / 2)) + cfg.junction_margin
    approach: list[list[LanePiece]] = []
    exits: list[list[LanePiece]] = []
    for ang, n in zip(angles, lanes):
        u, nrm = _unit(ang), _unit(ang + np.pi / 2)
        length = cfg.arm_length - stop
        approach.append([
            b.add(u * cfg.arm_length + nrm * (i + 0.5) * w, ang + np.pi, [(length, 0.0)],
                  curb=i == n - 1) for i in range(n)])
        exits.append([
            b.add(u * stop - nrm * (i + 0.5) * w, ang, [(length, 0.0)], curb=i == n - 1)
            for i in range(n)])
    for a, ang_a in enumerate(angles):
        for c, ang_c in enumerate(angles):
            if a == c:
                continue
            phi = (ang_c - ang_a + 2 * np.pi) % (2 * np.pi) - np.pi
            if abs(phi) < 1e-9:
                pairs, turn = [(i, i) for i in range(min(lanes[a], lanes[c]))], "straight"
            elif phi > 0:
                pairs, turn = [(0, 0)], "left"
            else:
                pairs, turn = [(lanes[a] - 1, lanes[c] - 1)], "right"
            for i, j in pairs:
                src, dst = approach[a][i], exits[c][j]
                p0, h0 = src.end()
                prims = ([(float(np.linalg.norm(dst.start - p0)), 0.0)] if turn == "straight"
                         else turn_prims(p0, h0, dst.start, dst.heading))
                mv = b.add(p0, h0, prims, turn=turn, curb=turn == "right")
                src.successors.append(mv.id)
                mv.successors.append(dst.id)
    corners = np.vstack([[_unit(t) * stop + s * _unit(t + np.pi / 2) * h for s in (1, -1)]
                         for t, h in zip(angles, hw)])
    order = np.argsort(np.arctan2(corners[:, 1], corners[:, 0]))
    anchors = [Anchor(_unit(t) * max(distance, stop + 3.0), t, h, np.zeros(2))
               for t, h in zip(angles, hw)]
    return RoadNetwork(b.pieces, corners[order], anchors)


def _two_way_road(start: np.ndarray, heading: float, segments: list[list[Prim]], lanes: int,
                  w: float) -> list[LanePiece]:
    """Both directions of a road given by its centre line split into lanelet segments.

    Segments with curvature carry turn_direction left/right in their driving direction.
    """
    b = _Builder(w)
    end, end_heading = end_pose(start, heading, [p for seg in segments for p in seg])
    reverse = [reverse_prims(seg) for seg in reversed(segments)]
    for p0, h0, segs in ((start, heading, segments), (end, end_heading + np.pi, reverse)):
        for i in range(lanes):
            off = -(i + 0.5) * w
            pos, hd = np.asarray(p0) + off * _unit(h0 + np.pi / 2), h0
            prev: LanePiece | None = None
            for seg in segs:
                prims = offset_prims(seg, off)
                k = sum(kap * length for length, kap in seg)
                turn = None if k == 0 else ("left" if k > 0 else "right")
                piece = b.add(pos, hd, prims, turn=turn, curb=i == lanes - 1)
                if prev is not None:
                    prev.successors.append(piece.id)
                prev = piece
                pos, hd = piece.end()
    return b.pieces


def build_network(case: str, rng: np.random.Generator, cfg: RoadSimConfig,
                  sensor_distance: tuple[float, float]) -> RoadNetwork:
    """The road layout of ``case`` in the site frame (junction / road reference at the origin).

    sensor_distance: range of the distance (m) of junction anchors from the junction centre.
    """
    def lanes() -> int:
        return int(rng.choice(cfg.lanes_per_direction))

    rot = rng.uniform(-np.pi, np.pi)
    jitter = np.deg2rad(rng.uniform(-1, 1) * cfg.crossing_angle_jitter_deg)
    distance = rng.uniform(*sensor_distance)
    if cfg.crossing_angle_deg is not None and case in ("intersection", "tjunction"):
        jitter = np.deg2rad(rng.uniform(*cfg.crossing_angle_deg)) - np.pi / 2
    if case == "intersection":
        alpha = np.pi / 2 + jitter
        n1, n2 = lanes(), lanes()
        angles = [rot, rot + alpha, rot + np.pi, rot + np.pi + alpha]
        return _junction(angles, [n1, n2, n1, n2], cfg, distance)
    if case == "tjunction":
        side = rng.choice([-1.0, 1.0]) * (np.pi / 2 + jitter)
        n1, n2 = lanes(), lanes()
        return _junction([rot, rot + side, rot + np.pi], [n1, n2, n1], cfg, distance)
    n = lanes()
    w = cfg.lane_width
    if case == "straight":
        half = cfg.arm_length
        start = -half * _unit(rot)
        pieces = _two_way_road(start, rot, [[(2 * half, 0.0)]], n, w)
        target = 60.0 * _unit(rot) * rng.choice([-1.0, 1.0])
        return RoadNetwork(pieces, np.zeros((0, 2)), [Anchor(np.zeros(2), rot, n * w, target)])
    if case == "curve":
        radius = rng.uniform(*cfg.curve_radius)
        turn = np.deg2rad(rng.uniform(*cfg.curve_angle_deg)) * rng.choice([-1.0, 1.0])
        kappa = np.sign(turn) / radius
        arc = radius * abs(turn)
        segments = [[(cfg.arm_length, 0.0)], [(arc, kappa)], [(cfg.arm_length, 0.0)]]
        # place the arc's midpoint (apex) at the origin
        apex, apex_heading = end_pose(np.zeros(2), 0.0, [segments[0][0], (arc / 2, kappa)])
        heading = rot - apex_heading
        c, s = np.cos(heading), np.sin(heading)
        start = -np.array([[c, -s], [s, c]]) @ apex
        pieces = _two_way_road(start, heading, segments, n, w)
        centre = np.sign(turn) * radius * _unit(rot + np.pi / 2)
        outer = -int(np.sign(turn))
        return RoadNetwork(pieces, np.zeros((0, 2)),
                           [Anchor(np.zeros(2), rot, n * w, centre, (outer,))])
    raise ValueError(f"unknown case {case!r}")


def to_lanelets(net: RoadNetwork, height: Callable[[np.ndarray], np.ndarray]) -> LaneletMap:
    """Lanelet per piece; bounds sampled every MAP_DS m, z = road height there."""
    out = []
    for p in net.pieces:
        tr = p.trace(MAP_DS)
        bounds = [tr.offset(sign * 0.5 * p.width) for sign in (1.0, -1.0)]
        left, right = (np.column_stack([b, height(b)]) for b in bounds)
        attrs = {"type": "lanelet", "subtype": "road", "location": "urban", "one_way": "yes"}
        if p.turn is not None:
            attrs["turn_direction"] = p.turn
        out.append(Lanelet(p.id, left, right, attrs))
    return LaneletMap(out)


class RoadArea:
    """The paved area: every lane (centre line +- half width) plus the junction polygon."""

    def __init__(self, net: RoadNetwork, ds: float = 0.25) -> None:
        xy, hw = net.centre_samples(ds)
        self._tree = cKDTree(xy)
        self._half_width = float(hw.max())
        self._junction = MplPath(net.junction) if len(net.junction) >= 3 else None

    def clearance(self, xy: np.ndarray, upper: float = np.inf) -> np.ndarray:
        """Distance (m) of (n, 2) points from the road edge, <= 0 on the road; values above
        ``upper`` are reported as ``upper`` (faster queries)."""
        xy = np.asarray(xy, dtype=float)[:, :2]
        bound = upper + self._half_width if np.isfinite(upper) else np.inf
        d, _ = self._tree.query(xy, distance_upper_bound=bound, workers=-1)
        out = np.minimum(d - self._half_width, upper)
        if self._junction is not None:
            out[self._junction.contains_points(xy)] = -1.0
        return out
