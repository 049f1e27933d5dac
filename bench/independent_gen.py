"""A scenario generator written independently of fgloc, to check fgloc on data its own
simulator did not make.

fgloc's simulator (``fgloc.sim``) is a test instrument written alongside the method: it shares
the method's conventions, and whatever it gets wrong the method may get wrong the same way.
This generator was written from fgloc's input contract only (the scenario directory,
docs/formats.md), without its code, and must never import ``fgloc``
(tests/test_independent_gen.py checks its imports): numpy, scipy, pyproj, laspy, lanelet2 and
matplotlib's polygon test are all it uses.

At a junction ``site`` (lat, lon) of a Lanelet2 map it draws, from one seed:

* a ground plane (height 107-113 m, slope up to 2 %);
* the sensor 10-25 m from the site, off the drivable lanelets and at least 2 m from their edges,
  on a 5-7 m mast, facing the site (+-8 deg), pitched down 4-12 deg, rolled +-1 deg;
* up to 12 routes through the routing graph (German traffic rules, vehicles): from a lane
  within 40 m of the site, random successors for 120 m ahead and predecessors for 120 m back,
  on the lanelet centre lines (a two-way lanelet: the line a quarter of its width from its
  right bound, each way), smoothed through the joins (Gaussian, sigma 2 m);
* vehicles arriving as a Poisson process (``vehicles_per_minute``; the roads filled before
  t = 0) on a random route: cars 4.5 x 1.8 x 1.5 m (75 %), vans 5.5 x 2.0 x 2.2 m (15 %),
  trucks 10-16 x 2.5 x 3.5 m (10 %); desired speed 7-13 m/s, at most 2.5 m/s^2 lateral,
  1.5 m/s^2 acceleration, 2.5 m/s^2 braking (6 m/s^2 at most); all vehicles driven together
  in steps of a frame: where routes share a lane or cross (conflict zones found for a 5.5 x
  2.2 m box at the paths' angle, head-on meetings on two-way streets excepted) a vehicle
  keeps 2 m plus 1.5 s of its speed behind a vehicle ahead, stops before a crossing another
  vehicle is in or that it could not leave with room behind it, and yields to one that
  reaches a zone sooner (within 6 s; one that can no longer stop goes first); a vehicle
  standing still for 15 s drives through (a deadlock broken); in the benchmark's 24 static
  runs 13 pairs of true boxes still touch, 4 of them for 1-6 s (a truck's corners on a
  turn, deadlocks broken; the generator before, blind to other routes, had 55 pairs, 29 for
  1-15 s), and 77 of 397 vehicles wait somewhere (8 s on average);
* a 20 Hz radar (120 x 30 deg field of view, 150 m): per vehicle and frame a Poisson number of
  returns (mean 12 within 30 m, falling as 1 / range, at least 2) on the faces of its box that
  face the sensor at 0.2-0.9 of its height, one in ten on its roof; rigid-body Doppler plus
  0.1 m/s noise; range, azimuth and elevation noise 0.15 m, 0.4 deg, 0.6 deg; no occlusion
  unless asked (``occlusion``: a return whose sight line passes through another vehicle's
  box below its roof is dropped); multipath ghosts if asked (``ghosts``: up to 3 facades
  30-60 m long, 8 m high, 2-5 m beyond a road edge in view, each mirroring a quarter of the
  vehicles' returns it can: a ghost at the return's mirror image, moving mirrored);
* clutter, ``clutter``: "static" (default) 40 kerb scatterers 0.1-0.2 m above the ground on
  the lanelet bounds in view that only one drivable lanelet uses (the road's edges; inside a
  junction also the bounds of the lanelets crossing it) and 15 poles 0-3 m high, 10-140 m away
  within +-55 deg of the boresight and more than 1 m off the drivable lanelets, each seen in
  30 % of the frames with Doppler noise 0.05 m/s; "uniform" 15 false alarms a frame anywhere
  in the field of view, 0-2 m above the ground, Doppler uniform +-15 m/s; "none";
* an ALS tile of the ground plane (1 point per m^2 over 400 x 400 m, 3 cm noise; class 11 on the
  drivable lanelets, 2 elsewhere).

It writes ``out/``: radar.csv, als/tile.las, map.osm (a copy, with the map's LICENSE* files),
sensor.toml (the position off by 3 m per axis, the yaw guess by 3 deg, both 1 sigma; the mast
height rounded to whole metres) and ground_truth.json; besides the contract ``out/_gen/``:
labels.npz (per detection its true world point, vehicle id or scatterer, as the radar.csv rows)
and meta.json (the drawn terrain, routes, vehicle classes and heights).

Frames: W is the world CRS EPSG:25832 (easting, northing, height; m); S the sensor's (x
boresight, y left, z up), ``p_w = R p_s + t`` with ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (pitch > 0
looks down); a vehicle's frame V has x along its heading, y to its left, z up from the ground
below its centre.

    python -m bench.independent_gen --map MAP --site LAT,LON --seed N --out DIR \\
        [--vehicles-per-minute R] [--duration S] [--clutter static|none|uniform] [--occlusion]
        [--ghosts]
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field, replace
from pathlib import Path

import lanelet2
import laspy
import numpy as np
import pyproj
from matplotlib.path import Path as Polygon
from scipy.ndimage import gaussian_filter1d
from scipy.spatial import cKDTree

CRS = "EPSG:25832"
#: radar frame rate (Hz)
FRAME_RATE = 20.0
#: field of view (deg) and range (m) of the radar, written to sensor.toml
HFOV_DEG, VFOV_DEG, MAX_RANGE = 120.0, 30.0, 150.0
#: measurement noise (1 sigma): range m, azimuth and elevation rad, Doppler m/s
SIGMA_RANGE, SIGMA_AZ, SIGMA_EL = 0.15, math.radians(0.4), math.radians(0.6)
SIGMA_DOPPLER = 0.1
#: Doppler noise (m/s, 1 sigma) of the static scatterers
SIGMA_STATIC_DOPPLER = 0.05
#: vertex step (m) of the lanelets' centre lines and of a route's path
LANE_STEP, PATH_STEP = 0.5, 0.2
#: Gaussian sigma (m) smoothing a route through its lanelet joins, and its curvature
PATH_SIGMA, CURVATURE_SIGMA = 2.0, 1.0
#: lateral acceleration, acceleration and braking bounds of the speed profile (m/s^2)
LATERAL_ACC, ACCELERATION, BRAKING = 2.5, 1.5, 2.5
#: slowest speed of the profile (m/s)
MIN_SPEED = 1.0
#: time (s) a vehicle keeps behind an obstacle at its speed, the gap (m) it keeps at a
#: standstill, and its hardest braking (m/s^2; the speed profile's BRAKING is its usual)
HEADWAY, STANDSTILL_GAP, HARD_BRAKING = 1.5, 2.0, 6.0
#: the box (length, width; m) two routes' conflict zones are found for (a van; a truck's
#: corners may still touch a vehicle beside its path on a turn), and the heading difference
#: (deg) above which vehicles meet head on
CONFLICT_BOX, ONCOMING_DEG = (5.5, 2.2), 150.0
#: a conflict zone whose paths meet at this angle (deg) or more is a crossing; conflict points
#: closer than ZONE_GAP (m) along a route are one zone; a vehicle standing still MAX_WAIT s
#: ignores crossings and priorities for its length and DEADLOCK_REACH m (a deadlock broken)
CROSSING_DEG, ZONE_GAP, MAX_WAIT, DEADLOCK_REACH = 30.0, 5.5, 15.0, 20.0
#: a vehicle yields at a zone to one that reaches it sooner, within this many seconds; only
#: vehicles closer than NEAR (m) to it are looked at
YIELD_HORIZON, NEAR = 6.0, 80.0
#: at most this many routes, from this many tries
MAX_ROUTES, ROUTE_TRIES = 12, 40
#: static clutter: kerb scatterers, poles and the share of frames each is seen in
N_KERBS, N_POLES, STATIC_DETECTION_PROB = 40, 15, 0.3
#: uniform clutter: false alarms per frame
UNIFORM_PER_FRAME = 15
#: label of a uniform false alarm in labels.npz (vehicles: their id; static scatterer k: -1-k)
FALSE_ALARM = -1000
#: multipath: facades drawn, their length range (m), offset beyond the road's edge (m) and
#: height (m), the share of a vehicle's returns a facade mirrors, and a ghost's label
N_WALLS, WALL_LENGTH, WALL_OFFSET, WALL_HEIGHT = 3, (30.0, 60.0), (2.0, 5.0), 8.0
GHOST_PROB, GHOST = 0.25, -2000
#: half the side (m) of the square ALS tile around the site, and its grid step (m)
ALS_HALF_SIDE, ALS_STEP = 200.0, 1.0
ROAD, GROUND = 11, 2


# ------------------------------------------------------------------------------- geometry
def pose_rotation(yaw_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """``Rz(yaw) Ry(pitch) Rx(roll)`` (3x3, S -> W); angles in degrees."""
    def rot(a: float, i: int, j: int) -> np.ndarray:
        R = np.eye(3)
        c, s = math.cos(math.radians(a)), math.sin(math.radians(a))
        R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
        return R

    return rot(yaw_deg, 0, 1) @ rot(pitch_deg, 2, 0) @ rot(roll_deg, 1, 2)


def wrap_deg(a: float) -> float:
    """``a`` (deg) wrapped to [-180, 180)."""
    return (a + 180.0) % 360.0 - 180.0


def arc_length(p: np.ndarray) -> np.ndarray:
    """(n,) cumulated length (m) along the polyline ``p`` (n, 2)."""
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))])


def path_length(p: np.ndarray) -> float:
    """Length (m) of the polyline ``p`` (n, 2)."""
    return float(np.sum(np.hypot(*np.diff(p, axis=0).T)))


def resample(p: np.ndarray, n: int) -> np.ndarray:
    """``n`` points evenly spaced by arc length along the polyline ``p`` (m, 2)."""
    d = arc_length(p)
    if d[-1] <= 0:
        return np.repeat(p[:1], n, axis=0)
    u = np.linspace(0.0, d[-1], n)
    return np.column_stack([np.interp(u, d, p[:, 0]), np.interp(u, d, p[:, 1])])


def resample_step(p: np.ndarray, step: float) -> np.ndarray:
    """The polyline ``p`` (m, 2) resampled at about ``step`` m (at least 2 points)."""
    return resample(p, max(2, math.ceil(path_length(p) / step) + 1))


def segment_distance(pts: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(m,) distance of each point ``pts`` (m, 2) to the nearest of the segments a -> b
    (k, 2 each)."""
    ab = b - a
    den = np.maximum(np.sum(ab * ab, axis=1), 1e-12)
    ap = pts[:, None, :] - a[None, :, :]
    t = np.clip(np.sum(ap * ab[None], axis=2) / den[None], 0, 1)
    q = a[None] + t[..., None] * ab[None]
    return np.min(np.hypot(*(pts[:, None, :] - q).transpose(2, 0, 1)), axis=1)


# ------------------------------------------------------------------------------------ map
@dataclass
class Lane:
    """One driving direction of a lanelet: its centre ``line`` (n, 2) in W, ``length`` m."""

    line: np.ndarray
    length: float
    lanelet: lanelet2.core.ConstLanelet


#: a lane's key: (lanelet id, driven against its drawn direction)
LaneKey = tuple[int, bool]


def lane_key(ll: lanelet2.core.ConstLanelet) -> LaneKey:
    """The key of the lane ``ll`` (a lanelet, possibly inverted) in :attr:`RoadMap.lanes`."""
    return (ll.id, ll.inverted())


class RoadMap:
    """The drivable lanelets of a Lanelet2 map in W (node positions projected with pyproj from
    the OSM file's lat / lon; lanelet2 gives the lanelets, traffic rules and routing graph)."""

    def __init__(self, path: Path, site: tuple[float, float]) -> None:
        self.to_world = pyproj.Transformer.from_crs("EPSG:4326", CRS, always_xy=True)
        self.node = self._project_nodes(path)
        origin = lanelet2.io.Origin(*site)
        # robust: a map with a primitive lanelet2 cannot build (a bound drawn as several ways,
        # an area without one outer ring) is driven on the lanelets it can; the routing graph
        # over a map that still holds a rejected lanelet (bounds missing) crashes the process
        lmap, _ = lanelet2.io.loadRobust(str(path), lanelet2.projection.UtmProjector(origin))
        valid = [ll for ll in lmap.laneletLayer
                 if len(ll.leftBound) > 1 and len(ll.rightBound) > 1]
        if len(valid) < len(lmap.laneletLayer):
            lmap = lanelet2.core.createSubmapFromLanelets(valid)
        rules = lanelet2.traffic_rules.create(lanelet2.traffic_rules.Locations.Germany,
                                              lanelet2.traffic_rules.Participants.Vehicle)
        self.graph = lanelet2.routing.RoutingGraph(lmap, rules)
        self.lanes: dict[LaneKey, Lane] = {}
        polygons, bound_use = [], {}
        for ll in lmap.laneletLayer:
            if not rules.canPass(ll):
                continue
            polygons.append(np.vstack([self.xy(ll.leftBound), self.xy(ll.rightBound)[::-1]]))
            for b in (ll.leftBound, ll.rightBound):
                bound_use.setdefault(b.id, [0, b])[0] += 1
            two_way = rules.canPass(ll.invert())
            for v in [ll, ll.invert()] if two_way else [ll]:
                line = self._centre_line(v, two_way)
                self.lanes[lane_key(v)] = Lane(line, path_length(line), v)
        #: the kerbs: bounds of only one drivable lanelet, (n, 2) polylines
        self.outer = [self.xy(b) for count, b in bound_use.values() if count == 1]
        #: the drivable lanelets' outlines as (k, 2, 2) segments
        self.edges = np.concatenate([np.stack([p[:-1], p[1:]], 1) for p in polygons])
        self._polygons = [Polygon(p) for p in polygons]
        self._boxes = np.array([[*p.min(axis=0), *p.max(axis=0)] for p in polygons])

    def _project_nodes(self, path: Path) -> dict[int, tuple[float, float]]:
        """OSM node id -> (easting, northing) in W of every node of the map file."""
        nodes = list(ET.parse(path).getroot().iter("node"))
        lat = np.array([float(n.get("lat")) for n in nodes])
        lon = np.array([float(n.get("lon")) for n in nodes])
        east, north = self.to_world.transform(lon, lat)
        return {int(n.get("id")): (e, nn) for n, e, nn in zip(nodes, east, north)}

    def xy(self, ls: lanelet2.core.ConstLineString3d) -> np.ndarray:
        """(n, 2) the line string's nodes in W."""
        return np.array([self.node[p.id] for p in ls], dtype=float)

    def _centre_line(self, ll: lanelet2.core.ConstLanelet, two_way: bool) -> np.ndarray:
        """Where vehicles drive ``ll`` (in its direction): midway between its bounds, or a
        quarter of the width from its right bound when both directions share it."""
        left, right = self.xy(ll.leftBound), self.xy(ll.rightBound)
        longest = max(path_length(left), path_length(right))
        n = max(2, math.ceil(longest / LANE_STEP) + 1)
        left, right = resample(left, n), resample(right, n)
        return 0.25 * left + 0.75 * right if two_way else 0.5 * (left + right)

    def inside(self, pts: np.ndarray) -> np.ndarray:
        """(m,) bool: the points (m, 2) of W on a drivable lanelet."""
        pts = np.atleast_2d(pts)
        ins = np.zeros(len(pts), bool)
        for poly, (x0, y0, x1, y1) in zip(self._polygons, self._boxes):
            m = ((pts[:, 0] >= x0 - 1) & (pts[:, 0] <= x1 + 1) & (pts[:, 1] >= y0 - 1)
                 & (pts[:, 1] <= y1 + 1) & ~ins)
            if m.any():
                ins[m] |= poly.contains_points(pts[m])
        return ins

    def edge_distance(self, pts: np.ndarray) -> np.ndarray:
        """(m,) distance (m) of the points (m, 2) of W to the nearest drivable lanelet edge."""
        return segment_distance(np.atleast_2d(pts), self.edges[:, 0], self.edges[:, 1])


# --------------------------------------------------------------------- terrain and sensor
@dataclass(frozen=True)
class Terrain:
    """The ground plane: height (m) ``z0 + grad . (xy - origin)`` over W."""

    origin: np.ndarray
    z0: float
    grad: np.ndarray

    def __call__(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        return (self.z0 + self.grad[0] * (np.asarray(x) - self.origin[0])
                + self.grad[1] * (np.asarray(y) - self.origin[1]))


def draw_terrain(rng: np.random.Generator, origin: np.ndarray) -> Terrain:
    """Height 107-113 m at ``origin``, slope 0-2 % in a random direction."""
    z0 = 110.0 + rng.uniform(-3, 3)
    slope = rng.uniform(0, 0.02)
    direction = rng.uniform(0, 2 * math.pi)
    return Terrain(origin, z0, slope * np.array([math.cos(direction), math.sin(direction)]))


@dataclass(frozen=True)
class Sensor:
    """The true sensor pose: ``position`` (3,) in W, angles in degrees; ``mast`` (m) its
    height above the ground."""

    position: np.ndarray
    yaw_deg: float
    pitch_deg: float
    roll_deg: float
    mast: float

    @property
    def R(self) -> np.ndarray:
        """3x3 rotation S -> W."""
        return pose_rotation(self.yaw_deg, self.pitch_deg, self.roll_deg)

    def to_sensor(self, p_w: np.ndarray) -> np.ndarray:
        """(n, 3) points of W in S."""
        return (p_w - self.position) @ self.R


def place_sensor(road: RoadMap, site: np.ndarray, terrain: Terrain,
                 rng: np.random.Generator) -> Sensor:
    """The sensor 10-25 m from ``site`` (W), off the drivable lanelets and at least 2 m from
    their edges, on a 5-7 m mast, facing the site +-8 deg, pitched 4-12 deg, rolled +-1 deg."""
    for _ in range(5000):
        r, phi = rng.uniform(10, 25), rng.uniform(0, 2 * math.pi)
        p = site + r * np.array([math.cos(phi), math.sin(phi)])
        if not road.inside(p)[0] and road.edge_distance(p)[0] >= 2.0:
            break
    else:
        raise RuntimeError("no place for the sensor off the road near the site")
    mast = rng.uniform(5, 7)
    to_site = site - p
    yaw = wrap_deg(math.degrees(math.atan2(to_site[1], to_site[0])) + rng.uniform(-8, 8))
    pitch, roll = rng.uniform(4, 12), rng.uniform(-1, 1)
    return Sensor(np.array([p[0], p[1], float(terrain(*p)) + mast]), yaw, pitch, roll, mast)


# ---------------------------------------------------------------------------- routes
@dataclass
class Route:
    """A path through the routing graph: its lanes, the smoothed path ``xy`` (n, 2) in W,
    arc length ``s`` (m), heading ``heading`` (rad, unwrapped, CCW from grid east) and
    smoothed curvature ``curvature`` (1/m) at its vertices."""

    lanes: list[LaneKey]
    xy: np.ndarray
    s: np.ndarray
    heading: np.ndarray
    curvature: np.ndarray


def _extend(road: RoadMap, rng: np.random.Generator, start: lanelet2.core.ConstLanelet,
            seen: set[LaneKey], forward: bool, reach: float) -> list[LaneKey]:
    """Lanes from ``start`` on, a random successor (predecessor) at a time, until ``reach`` m
    or a dead end; in driving order away from ``start``."""
    out, cur, length = [], start, 0.0
    step = road.graph.following if forward else road.graph.previous
    while length < reach:
        nxt = [f for f in step(cur) if lane_key(f) in road.lanes and lane_key(f) not in seen]
        if not nxt:
            break
        cur = nxt[rng.integers(len(nxt))]
        out.append(lane_key(cur))
        seen.add(out[-1])
        length += road.lanes[out[-1]].length
    return out


def build_route(road: RoadMap, rng: np.random.Generator, start: lanelet2.core.ConstLanelet,
                reach: float = 120.0) -> Route:
    """A route through ``start``: ``reach`` m of lanes ahead and behind, its path smoothed
    through the joins (Gaussian, :data:`PATH_SIGMA`, end points kept)."""
    seen = {lane_key(start)}
    ahead = _extend(road, rng, start, seen, True, reach)
    behind = _extend(road, rng, start, seen, False, reach)
    lanes = [*behind[::-1], lane_key(start), *ahead]
    pts = np.concatenate([road.lanes[k].line for k in lanes])
    keep = np.concatenate([[True], np.hypot(*np.diff(pts, axis=0).T) > 1e-3])
    pts = resample_step(pts[keep], PATH_STEP)
    smooth = np.column_stack([gaussian_filter1d(pts[:, i], PATH_SIGMA / PATH_STEP,
                                                mode="nearest") for i in range(2)])
    pts = resample_step(smooth, PATH_STEP)
    s = arc_length(pts)
    d = np.gradient(pts, s, axis=0)
    heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    curvature = gaussian_filter1d(np.gradient(heading, s), CURVATURE_SIGMA / PATH_STEP,
                                  mode="nearest")
    return Route(lanes, pts, s, heading, curvature)


def pick_routes(road: RoadMap, site: np.ndarray, rng: np.random.Generator) -> list[Route]:
    """Up to :data:`MAX_ROUTES` distinct routes at least 30 m long, each through a lane that
    comes within 40 m of ``site``."""
    near = [k for k, lane in road.lanes.items()
            if np.min(np.hypot(*(lane.line - site).T)) <= 40.0]
    routes: list[Route] = []
    for _ in range(ROUTE_TRIES):
        route = build_route(road, rng, road.lanes[near[rng.integers(len(near))]].lanelet)
        if route.s[-1] < 30 or any(route.lanes == r.lanes for r in routes):
            continue
        routes.append(route)
        if len(routes) >= MAX_ROUTES:
            break
    return routes


def speed_profile(route: Route, v_desired: float) -> np.ndarray:
    """(n,) speed (m/s) at the route's vertices: ``v_desired`` bounded by the lateral
    acceleration on its curvature, reached and left within the acceleration and braking
    bounds, at least :data:`MIN_SPEED`."""
    v = np.minimum(v_desired, np.sqrt(LATERAL_ACC / np.maximum(np.abs(route.curvature), 1e-6)))
    ds = np.diff(route.s)
    for i in range(len(v) - 1):
        v[i + 1] = min(v[i + 1], math.sqrt(v[i] ** 2 + 2 * ACCELERATION * ds[i]))
    for i in range(len(v) - 2, -1, -1):
        v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2 * BRAKING * ds[i]))
    return np.maximum(v, MIN_SPEED)


# ---------------------------------------------------------------------------- vehicles
@dataclass
class Vehicle:
    """A vehicle of the recording: its box (m), route index, ``states`` (n, 6) [t s, x m, y m,
    yaw rad, v m/s, yaw rate rad/s] in W at the radar ``frames`` (n,) it is on its route."""

    id: int
    kind: str
    length: float
    width: float
    height: float
    route: int
    states: np.ndarray
    frames: np.ndarray


def draw_box(rng: np.random.Generator) -> tuple[str, float, float, float]:
    """A vehicle class and its length, width, height (m): car 75 %, van 15 %, truck 10 %."""
    u = rng.random()
    if u < 0.75:
        return "car", 4.5, 1.8, 1.5
    if u < 0.90:
        return "van", 5.5, 2.0, 2.2
    return "truck", float(rng.uniform(10, 16)), 2.5, 3.5


def arrival_times(rng: np.random.Generator, start: float, end: float, rate: float
                  ) -> list[float]:
    """Poisson arrivals (``rate`` per s) in (``start``, ``end``] s."""
    out, t = [], start
    while (t := t + rng.exponential(1.0 / rate)) <= end:
        out.append(t)
    return out


@dataclass
class Zone:
    """Where two routes come close enough for vehicles on them to touch (one of
    :func:`conflict_zones`): the conflict points' arc lengths ``s_a`` (m,) on the first
    route, in order, and ``s_b`` (m,) the nearest points' on the second; a ``crossing``
    (the paths' median angle there :data:`CROSSING_DEG` or more) or a shared stretch."""

    s_a: np.ndarray
    s_b: np.ndarray
    crossing: bool


def conflict_zones(a: Route, b: Route) -> list[Zone]:
    """The :class:`Zone` s of route ``a`` with route ``b`` (``a`` with itself: one, every
    vertex): vertices of ``a`` closer to ``b``'s path than two boxes of :data:`CONFLICT_BOX`
    (length, width) at the paths' angle theta need beside each other, half of ``length |sin
    theta| + width |cos theta|`` plus half a width (``width`` for parallel paths: adjacent
    lanes, 3 m or more apart, do not conflict), not head on (heading difference above
    :data:`ONCOMING_DEG`: vehicles meeting on a two-way street pass each other); split where
    consecutive ones lie more than :data:`ZONE_GAP` apart along ``a``."""
    length, width = CONFLICT_BOX
    d, j = cKDTree(b.xy).query(a.xy, distance_upper_bound=0.5 * (length + 2 * width))
    i = np.flatnonzero(np.isfinite(d))
    j = j[i]
    turn = np.abs((a.heading[i] - b.heading[j] + math.pi) % (2 * math.pi) - math.pi)
    reach = 0.5 * (length * np.sin(turn) + width * np.abs(np.cos(turn)) + width)
    keep = (d[i] < reach) & (turn < math.radians(ONCOMING_DEG))
    s_a, s_b, turn = a.s[i[keep]], b.s[j[keep]], turn[keep]
    cuts = np.flatnonzero(np.diff(s_a) > ZONE_GAP) + 1
    return [Zone(x, y, bool(np.median(u) >= math.radians(CROSSING_DEG)))
            for x, y, u in zip(*(np.split(q, cuts) for q in (s_a, s_b, turn))) if len(x)]


@dataclass(eq=False)
class Driver:
    """A vehicle on its route during the simulation (:func:`drive`): its ``box`` (class,
    length, width, height; :func:`draw_box`), route index, speed profile ``v_des`` (m/s at
    the route's vertices), arc position ``s`` (m, its centre), speed ``v`` (m/s), how long
    (s) it has stood still, ``waited``, and up to which arc position (m) it drives through a
    deadlock, ``through``; ``s_hist``, ``v_hist``, ``frames``: its samples. Equal only to
    itself."""

    id: int
    box: tuple[str, float, float, float]
    route: int
    v_des: np.ndarray
    s: float = 0.0
    v: float = 0.0
    waited: float = 0.0
    through: float = -math.inf
    s_hist: list = field(default_factory=list)
    v_hist: list = field(default_factory=list)
    frames: list = field(default_factory=list)

    @property
    def length(self) -> float:
        """Its box's length (m)."""
        return self.box[1]

    def stops_within(self, distance: float) -> bool:
        """Whether it can still stop within ``distance`` (m) braking at :data:`BRAKING` (with
        0.5 m to spare)."""
        return distance >= self.v ** 2 / (2.0 * BRAKING) + 0.5


def crossing_spans(k: int, zones: dict[tuple[int, int], list[Zone]], n_routes: int
                   ) -> np.ndarray:
    """(m, 2) arc-length spans (m) of route ``k`` inside a crossing with any other route, the
    overlapping ones merged, in order."""
    spans = sorted((float(z.s_a[0]), float(z.s_a[-1])) for b in range(n_routes) if b != k
                   for z in zones[k, b] if z.crossing)
    merged: list[list[float]] = []
    for lo, hi in spans:
        if merged and lo <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], hi)
        else:
            merged.append([lo, hi])
    return np.array(merged).reshape(-1, 2)


def _obstacle(me: Driver, others: list[Driver], zones: dict[tuple[int, int], list[Zone]],
              crossings: np.ndarray) -> float:
    """Distance (m) from ``me``'s front to where it must stop behind: the nearest point of
    its route ahead that a box of ``others`` covers on a shared stretch (a vehicle ahead),
    the entry of a crossing another vehicle is in (no waiting inside it), or the entry of a
    zone that another vehicle reaches first. Priority at a zone both still approach: one
    that can no longer stop before it (its braking distance at :data:`BRAKING`) over one
    that can, else the one that reaches it sooner (within :data:`YIELD_HORIZON` s), ties to
    the lower id. It does not stop inside a crossing with any route (``crossings``, its
    :func:`crossing_spans`): with the obstacle beyond one closer than its length and
    :data:`STANDSTILL_GAP` past the crossing's end, it stops before the crossing (queues
    spilling into a junction would lock it). A vehicle that has stood still for
    :data:`MAX_WAIT` s ignores crossings and priorities for its length and
    :data:`DEADLOCK_REACH` m (a deadlock of vehicles waiting for each other in a circle
    broken: it drives through the one in its way). inf: nothing ahead."""
    front = me.s + 0.5 * me.length
    stuck = me.s < me.through                          # a deadlock broken: it drives through
    best = math.inf
    for o in others:
        o_half = 0.5 * o.length
        for z in zones[me.route, o.route]:
            ahead = z.s_a > front
            if not ahead.any():
                continue
            if z.crossing and stuck:
                continue
            mine = float(z.s_a[0]) - front
            covered = ahead & (np.abs(z.s_b - o.s) <= o_half)
            if covered.any():
                # behind it on a shared stretch; before a crossing it is in, not into it
                best = min(best, mine if z.crossing and mine > 0.0
                           else float(z.s_a[covered][0]) - front)
                continue
            theirs = float(z.s_b.min()) - (o.s + o_half)
            if mine <= 0.0 or theirs <= 0.0 or me.route == o.route or stuck:
                continue               # inside it already, or it is behind on its own stretch
            t_me, t_o = mine / max(me.v, 0.5), theirs / max(o.v, 0.5)
            if t_o >= YIELD_HORIZON:
                continue
            committed = (not me.stops_within(mine), not o.stops_within(theirs))
            o_first = (committed[1] and not committed[0]) or (
                committed[0] == committed[1] and (t_o < t_me or (t_o == t_me and o.id < me.id)))
            if o_first:
                best = min(best, mine)
    if not stuck:
        # no stop inside a crossing: before one it cannot leave with room behind it
        for lo, hi in crossings:
            if front < lo < front + best and best - (hi - front) < me.length + STANDSTILL_GAP:
                return lo - front
    return best


def drive(routes: list[Route], rng: np.random.Generator, duration: float,
          vehicles_per_minute: float) -> list[Vehicle]:
    """The vehicles on their route during at least two of the ``duration`` s of radar frames
    (ids in order from 0), simulated together in steps of one frame: arrivals from L / 3 s
    before t = 0 on (L the longest route's length in m), so the roads are filled at t = 0;
    each on a random route at 7-13 m/s desired (:func:`speed_profile`), entering when its
    route's start is free, and keeping :data:`STANDSTILL_GAP` m plus :data:`HEADWAY` s of its
    speed behind the obstacle :func:`_obstacle` finds (a vehicle ahead on a shared stretch,
    one in a crossing, a zone another reaches first), braking at most at
    :data:`HARD_BRAKING`."""
    dt = 1.0 / FRAME_RATE
    n_frames = int(round(duration * FRAME_RATE))
    start = -max(r.s[-1] for r in routes) / 3.0
    zones = {(a, b): conflict_zones(routes[a], routes[b])
             for a in range(len(routes)) for b in range(len(routes))}
    crossings = [crossing_spans(k, zones, len(routes)) for k in range(len(routes))]
    waiting: list[tuple[float, Driver]] = []
    for t0 in arrival_times(rng, start, duration, vehicles_per_minute / 60.0):
        k = int(rng.integers(len(routes)))
        box = draw_box(rng)
        v_des = speed_profile(routes[k], rng.uniform(7, 13))
        waiting.append((t0, Driver(len(waiting), box, k, v_des)))
    active: list[Driver] = []
    done: list[Driver] = []
    for step in range(int(math.floor(start / dt)), n_frames):
        t = step * dt
        for t0, d in [w for w in waiting if w[0] <= t]:
            # its box and the gaps before and behind it on its route's start free
            d.s, d.v = -0.5 * d.length - STANDSTILL_GAP, 0.0
            gap = _obstacle(d, active, zones, crossings[d.route]) - d.length - 2.0 * STANDSTILL_GAP
            if gap < 0.0:
                continue                                     # its start is not free yet
            d.s = 0.0
            d.v = float(min(d.v_des[0], math.sqrt(2.0 * BRAKING * gap)))
            waiting.remove((t0, d))
            active.append(d)
        xy = np.array([[np.interp(d.s, routes[d.route].s, routes[d.route].xy[:, i])
                        for i in (0, 1)] for d in active]).reshape(-1, 2)
        near = np.linalg.norm(xy[:, None] - xy[None], axis=2) < NEAR
        gaps = [_obstacle(d, [o for j, o in enumerate(active) if near[i, j] and j != i], zones,
                          crossings[d.route]) for i, d in enumerate(active)]
        for d, gap in zip(active, gaps):
            room = max(gap - STANDSTILL_GAP, 0.0)
            target = min(float(np.interp(d.s, routes[d.route].s, d.v_des)), room / HEADWAY,
                         math.sqrt(2.0 * BRAKING * room))
            d.v = max(0.0, d.v + float(np.clip(target - d.v, -HARD_BRAKING * dt,
                                                ACCELERATION * dt)))
            d.s += d.v * dt
            d.waited = d.waited + dt if d.v < 0.1 else 0.0
            if d.waited > MAX_WAIT:
                d.through, d.waited = d.s + d.length + DEADLOCK_REACH, 0.0
            if step >= 0:
                d.frames.append(step)
                d.s_hist.append(d.s)
                d.v_hist.append(d.v)
        done += [d for d in active if d.s >= routes[d.route].s[-1]]
        active = [d for d in active if d.s < routes[d.route].s[-1]]
    vehicles: list[Vehicle] = []
    for d in sorted(done + active, key=lambda d: d.id):
        frames = np.asarray(d.frames, dtype=np.int64)
        on = np.asarray(d.s_hist) <= routes[d.route].s[-1]
        if on.sum() < 2:
            continue
        states = route_states(routes[d.route], frames[on] * dt, np.asarray(d.s_hist)[on],
                              np.asarray(d.v_hist)[on])
        vehicles.append(Vehicle(len(vehicles), *d.box, d.route, states, frames[on]))
    return vehicles


def route_states(route: Route, t: np.ndarray, s: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(n, 6) states [t, x, y, yaw, v, yaw rate] of a vehicle at arc positions ``s`` (m) of
    ``route`` with speeds ``v`` (m/s) at the times ``t`` (s): yaw rate = v x the path's
    heading change per metre."""
    heading = np.interp(s, route.s, route.heading)
    turn = np.interp(s, route.s, np.gradient(route.heading, route.s))
    return np.column_stack([t, np.interp(s, route.s, route.xy[:, 0]),
                            np.interp(s, route.s, route.xy[:, 1]),
                            (heading + math.pi) % (2 * math.pi) - math.pi, v, v * turn])


# ----------------------------------------------------------------------------- radar
@dataclass
class Returns:
    """Radar returns before the measurement: ``frame`` (n,), true point ``p_w`` (n, 3) in W,
    measured and true Doppler (m/s), ``label`` (vehicle id, -1-k static scatterer k,
    :data:`FALSE_ALARM`), ``roof`` (bool), ``rcs`` (dBsm); ``noisy``: the position gets the
    range / angle noise (false alarms are drawn where they are seen)."""

    frame: np.ndarray
    p_w: np.ndarray
    doppler: np.ndarray
    doppler_true: np.ndarray
    label: np.ndarray
    roof: np.ndarray
    rcs: np.ndarray
    noisy: bool = True

    #: the per-return fields
    ARRAYS = ("frame", "p_w", "doppler", "doppler_true", "label", "roof", "rcs")

    def take(self, idx: np.ndarray) -> Returns:
        """The returns ``idx`` (indices or a mask)."""
        return replace(self, **{k: getattr(self, k)[idx] for k in self.ARRAYS})

    @classmethod
    def concat(cls, parts: list[Returns]) -> Returns:
        """``parts`` one after the other (``noisy`` no longer says anything)."""
        return cls(*(np.concatenate([getattr(p, k) for p in parts]) for k in cls.ARRAYS))

    @classmethod
    def static(cls, frame: np.ndarray, p_w: np.ndarray, doppler: np.ndarray,
               doppler_true: np.ndarray, label: np.ndarray, noisy: bool = True) -> Returns:
        """Returns of things that are not vehicles (no roof, RCS 0)."""
        n = len(frame)
        return cls(frame, p_w, doppler, doppler_true, label, np.zeros(n, bool), np.zeros(n),
                   noisy)


@dataclass
class BoxSamples:
    """Every (vehicle, frame) of the vehicles, stacked: frame, vehicle id, states (n, 6) and
    box size length, width, height (m)."""

    frame: np.ndarray
    vid: np.ndarray
    states: np.ndarray
    size: np.ndarray

    @classmethod
    def of(cls, vehicles: list[Vehicle]) -> BoxSamples:
        def cat(parts: list[np.ndarray], shape: tuple[int, ...]) -> np.ndarray:
            return np.concatenate(parts) if parts else np.zeros(shape)

        n = [len(v.frames) for v in vehicles]
        return cls(cat([v.frames for v in vehicles], (0,)).astype(int),
                   cat([np.full(k, v.id) for k, v in zip(n, vehicles)], (0,)).astype(int),
                   cat([v.states for v in vehicles], (0, 6)),
                   cat([np.tile([v.length, v.width, v.height], (k, 1))
                        for k, v in zip(n, vehicles)], (0, 3)))


def returns_per_box(boxes: BoxSamples, sensor: Sensor, terrain: Terrain,
                    rng: np.random.Generator) -> np.ndarray:
    """(n,) number of returns of each box: Poisson with mean ``max(2, 12 * 30 m / range)``
    (12 within 30 m), none when its centre is out of the horizontal field of view or range."""
    x, y = boxes.states[:, 1], boxes.states[:, 2]
    d = np.column_stack([x, y, terrain(x, y) + boxes.size[:, 2] / 2]) - sensor.position
    d_s = d @ sensor.R
    az = np.degrees(np.arctan2(d_s[:, 1], d_s[:, 0]))
    seen = (np.hypot(d[:, 0], d[:, 1]) <= MAX_RANGE) & (np.abs(az) <= HFOV_DEG / 2)
    mean = np.maximum(2.0, 12.0 * 30.0 / np.maximum(np.linalg.norm(d, axis=1), 30.0))
    return np.where(seen, rng.poisson(mean), 0)


def box_face_points(rng: np.random.Generator, sensor_v: np.ndarray, size: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Points on the boxes of ``size`` (n, 3: length, width, height, m) in V, seen from the
    sensor at ``sensor_v`` (n, 2, in V): uniform along the perimeter of the vertical faces that
    face the sensor, at 0.2-0.9 of the height; one in ten instead uniform on the roof. Returns
    (n, 3) points and the (n,) roof flags."""
    n = len(size)
    length, width, height = size.T
    hl, hw = length / 2, width / 2
    # faces front, left, rear, right; each from corner (sx, sy) to corner (ex, ey)
    faces = np.column_stack([sensor_v[:, 0] > hl, sensor_v[:, 1] > hw,
                             sensor_v[:, 0] < -hl, sensor_v[:, 1] < -hw])
    lens = np.column_stack([width, length, width, length]) * faces
    cum = np.cumsum(lens, axis=1)
    u = rng.random(n) * cum[:, -1]
    e = np.minimum(np.sum(cum <= u[:, None], axis=1), 3)
    rows = np.arange(n)
    before = np.where(e > 0, cum[rows, np.maximum(e - 1, 0)], 0.0)
    f = (u - before) / np.maximum(lens[rows, e], 1e-9)
    sx, ex = (hl * c for c in np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]])[e].T)
    sy, ey = (hw * c for c in np.array([[-1, 1], [1, 1], [1, -1], [-1, -1]])[e].T)
    x, y = sx + f * (ex - sx), sy + f * (ey - sy)
    z = rng.uniform(0.2, 0.9, n) * height
    roof = rng.random(n) < 0.10
    x = np.where(roof, rng.uniform(-0.5, 0.5, n) * length, x)
    y = np.where(roof, rng.uniform(-0.5, 0.5, n) * width, y)
    return np.column_stack([x, y, np.where(roof, height, z)]), roof


def rigid_velocity(states: np.ndarray, rx: np.ndarray, ry: np.ndarray, terrain: Terrain
                   ) -> np.ndarray:
    """(n, 3) velocity (m/s, W) of the points ``(rx, ry)`` (m, W axes) from the centres of
    vehicles in the states (n, 6) [t, x, y, yaw, v, yaw rate]: moving along the ground plane,
    turning at the yaw rate."""
    _, _, _, yaw, v, w = states.T
    vx, vy = v * np.cos(yaw), v * np.sin(yaw)
    return np.column_stack([vx - w * ry, vy + w * rx,
                            terrain.grad[0] * vx + terrain.grad[1] * vy])


def vehicle_returns(boxes: BoxSamples, sensor: Sensor, terrain: Terrain,
                    rng: np.random.Generator) -> Returns:
    """The vehicles' returns (:func:`returns_per_box`, :func:`box_face_points`) with their
    rigid-body Doppler (the vehicle moving along the ground plane, turning at its yaw rate)
    plus :data:`SIGMA_DOPPLER` noise; RCS 10 dBsm. ``boxes``: every (vehicle, frame)."""
    i = np.repeat(np.arange(len(boxes.frame)), returns_per_box(boxes, sensor, terrain, rng))
    _, x, y, yaw = boxes.states[i, :4].T
    c, s = np.cos(yaw), np.sin(yaw)
    dx, dy = sensor.position[0] - x, sensor.position[1] - y
    local, roof = box_face_points(rng, np.column_stack([c * dx + s * dy, -s * dx + c * dy]),
                                  boxes.size[i])
    rx, ry = c * local[:, 0] - s * local[:, 1], s * local[:, 0] + c * local[:, 1]
    p_w = np.column_stack([x + rx, y + ry, terrain(x, y) + local[:, 2]])
    vel = rigid_velocity(boxes.states[i], rx, ry, terrain)
    ray = p_w - sensor.position
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    doppler = vel[:, 0] * ray[:, 0] + vel[:, 1] * ray[:, 1] + vel[:, 2] * ray[:, 2]
    return Returns(boxes.frame[i], p_w, doppler + rng.normal(0, SIGMA_DOPPLER, len(i)), doppler,
                   boxes.vid[i], roof, np.full(len(i), 10.0))


def occluded(ret: Returns, boxes: BoxSamples, sensor: Sensor, terrain: Terrain
             ) -> np.ndarray:
    """(n,) bool: the line of sight from the sensor to each true return point passes through
    the box of another vehicle of the same frame below its roof (the box from the ground to its
    height; the vehicle's own box never hides its returns). Each return is tested against
    every box of its frame: the sight line's parameter interval inside the box's footprint
    (slabs along its length and width), and the line's height where it leaves the footprint
    or enters it, whichever is lower."""
    n = len(ret.frame)
    order = np.argsort(boxes.frame, kind="stable")
    frames = boxes.frame[order]
    lo = np.searchsorted(frames, ret.frame, "left")
    cnt = np.searchsorted(frames, ret.frame, "right") - lo
    ri = np.repeat(np.arange(n), cnt)
    bi = order[np.repeat(lo - np.cumsum(cnt) + cnt, cnt) + np.arange(int(cnt.sum()))]
    other = ret.label[ri] != boxes.vid[bi]
    ri, bi = ri[other], bi[other]
    _, x, y, yaw = boxes.states[bi, :4].T
    c, s = np.cos(yaw), np.sin(yaw)
    a = np.column_stack([sensor.position[0] - x, sensor.position[1] - y])
    b = ret.p_w[ri, :2] - np.column_stack([x, y])
    # sight line in the box's frame: start (the sensor) a_l, direction d_l, t in [0, 1]
    a_l = np.column_stack([c * a[:, 0] + s * a[:, 1], -s * a[:, 0] + c * a[:, 1]])
    d_l = np.column_stack([c * b[:, 0] + s * b[:, 1], -s * b[:, 0] + c * b[:, 1]]) - a_l
    half = boxes.size[bi, :2] / 2
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (-half - a_l) / d_l, (half - a_l) / d_l
    parallel = np.abs(d_l) < 1e-12
    inside = np.abs(a_l) <= half
    t_lo = np.where(parallel, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2))
    t_hi = np.where(parallel, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2))
    enter = np.maximum(t_lo.max(axis=1), 0.0)
    leave = np.minimum(t_hi.min(axis=1), 1.0)
    crosses = enter < leave
    z0, z1 = sensor.position[2], ret.p_w[ri, 2]
    low = np.minimum(z0 + enter * (z1 - z0), z0 + leave * (z1 - z0))
    hidden = crosses & (low < terrain(x, y) + boxes.size[bi, 2])
    out = np.zeros(n, bool)
    out[ri[hidden]] = True
    return out


@dataclass
class Scatterers:
    """The static scatterers in W: kerbs (k, 3) and poles (m, 3)."""

    kerbs: np.ndarray
    poles: np.ndarray


def in_view(sensor: Sensor, q: np.ndarray) -> np.ndarray:
    """(n,) bool: the points ``q`` (n, 2) of W 10 to 145 m from the sensor and 2 deg inside
    its horizontal field of view (by its yaw alone)."""
    d = q - sensor.position[:2]
    r = np.hypot(d[:, 0], d[:, 1])
    az = (np.degrees(np.arctan2(d[:, 1], d[:, 0])) - sensor.yaw_deg + 180) % 360 - 180
    return (r <= MAX_RANGE - 5) & (r >= 10) & (np.abs(az) <= HFOV_DEG / 2 - 2.0)


def edges_in_view(road: RoadMap, sensor: Sensor) -> np.ndarray:
    """(k, 2, 2) segments of the road's edges in view (:func:`in_view`): the bounds only one
    drivable lanelet uses (:attr:`RoadMap.outer`), any lanelet edge when none of those is."""
    segs = np.concatenate([np.stack([b[:-1], b[1:]], 1) for b in road.outer if len(b) > 1])
    segs = segs[in_view(sensor, segs.mean(axis=1))]
    if len(segs) == 0:
        segs = road.edges[in_view(sensor, road.edges.mean(axis=1))]
    return segs


def draw_scatterers(road: RoadMap, sensor: Sensor, terrain: Terrain,
                    rng: np.random.Generator) -> Scatterers:
    """:data:`N_KERBS` kerb points 0.1-0.2 m above the ground, uniform by length along the
    bounds in view that only one drivable lanelet uses (:attr:`RoadMap.outer`; any lanelet
    edge in view when none of those is),
    and :data:`N_POLES` pole points 0-3 m above the ground, 10-140 m away within +-55 deg of
    the boresight and more than 1 m off the drivable lanelets."""
    segs = edges_in_view(road, sensor)
    seg_len = np.hypot(*(segs[:, 1] - segs[:, 0]).T)
    k = rng.choice(len(segs), N_KERBS, p=seg_len / seg_len.sum())
    kxy = segs[k, 0] + rng.random(N_KERBS)[:, None] * (segs[k, 1] - segs[k, 0])
    kerbs = np.column_stack([kxy, terrain(kxy[:, 0], kxy[:, 1])
                             + rng.uniform(0.1, 0.2, N_KERBS)])
    yaw, pts = math.radians(sensor.yaw_deg), []
    while len(pts) < N_POLES:
        r, az = rng.uniform(10, 140), yaw + math.radians(rng.uniform(-55, 55))
        q = sensor.position[:2] + r * np.array([math.cos(az), math.sin(az)])
        if not road.inside(q)[0] and road.edge_distance(q)[0] > 1.0:
            pts.append(q)
    pxy = np.array(pts)
    poles = np.column_stack([pxy, terrain(pxy[:, 0], pxy[:, 1]) + rng.uniform(0, 3, N_POLES)])
    return Scatterers(kerbs, poles)


def static_returns(scat: Scatterers, n_frames: int, rng: np.random.Generator) -> Returns:
    """Each scatterer seen in a frame with probability :data:`STATIC_DETECTION_PROB`; Doppler
    noise :data:`SIGMA_STATIC_DOPPLER`."""
    points = np.vstack([scat.kerbs, scat.poles])
    fi, si = np.nonzero(rng.random((n_frames, len(points))) < STATIC_DETECTION_PROB)
    return Returns.static(fi, points[si], rng.normal(0, SIGMA_STATIC_DOPPLER, len(fi)),
                          np.zeros(len(fi)), -1 - si)


def uniform_returns(sensor: Sensor, terrain: Terrain, n_frames: int,
                    rng: np.random.Generator) -> Returns:
    """:data:`UNIFORM_PER_FRAME` false alarms a frame, uniform in range (5-150 m) and azimuth
    over the field of view, 0-2 m above the ground, Doppler uniform +-15 m/s (true Doppler
    NaN: there is nothing there)."""
    m = UNIFORM_PER_FRAME * n_frames
    r = rng.uniform(5, MAX_RANGE, m)
    az = math.radians(sensor.yaw_deg) + np.radians(rng.uniform(-HFOV_DEG / 2, HFOV_DEG / 2, m))
    qx, qy = sensor.position[0] + r * np.cos(az), sensor.position[1] + r * np.sin(az)
    qz = terrain(qx, qy) + rng.uniform(0, 2, m)
    return Returns.static(np.repeat(np.arange(n_frames), UNIFORM_PER_FRAME),
                          np.column_stack([qx, qy, qz]), rng.uniform(-15, 15, m),
                          np.full(m, np.nan), np.full(m, FALSE_ALARM), noisy=False)


@dataclass
class Walls:
    """Vertical reflecting facades: ``start`` and unit ``direction`` (k, 2) in W, ``length``
    (k,) m, ``top`` (k,) height of the top in W (m)."""

    start: np.ndarray
    direction: np.ndarray
    length: np.ndarray
    top: np.ndarray


def draw_walls(road: RoadMap, sensor: Sensor, terrain: Terrain, rng: np.random.Generator
               ) -> Walls:
    """Up to :data:`N_WALLS` facades (a building front, a noise barrier): each along a road
    edge in view (:func:`edges_in_view`, chosen by length), :data:`WALL_OFFSET` m beyond it
    off the road, :data:`WALL_LENGTH` m long, :data:`WALL_HEIGHT` m high; only where none of
    it lies on a drivable lanelet, the sensor is on the road's side and at least 30 m away
    (a facade beside the mast would hide the road) and no facade drawn before is within 10 m
    of its ends or middle."""
    segs = edges_in_view(road, sensor)
    seg_len = np.hypot(*(segs[:, 1] - segs[:, 0]).T)
    sensor_xy = sensor.position[:2]
    walls: list[tuple[np.ndarray, np.ndarray, float]] = []
    for _ in range(200):
        if len(walls) == N_WALLS:
            break
        a, b = segs[rng.choice(len(segs), p=seg_len / seg_len.sum())]
        u = (b - a) / max(float(np.hypot(*(b - a))), 1e-9)
        n = np.array([-u[1], u[0]])
        mid = a + rng.random() * (b - a)
        if road.inside(mid + n)[0]:
            n = -n
        centre = mid + rng.uniform(*WALL_OFFSET) * n
        length = rng.uniform(*WALL_LENGTH)
        start = centre - u * length / 2
        line = start + np.linspace(0, length, 25)[:, None] * u
        if (road.inside(line).any() or np.dot(sensor_xy - centre, n) >= 0
                or segment_distance(sensor_xy[None], start[None], line[-1][None])[0] < 30.0
                or (walls and segment_distance(line[[0, 12, -1]], np.array([w[0] for w in walls]),
                                               np.array([w[0] + w[2] * w[1] for w in walls])
                                               ).min() < 10.0)):
            continue
        walls.append((start, u, length))
    start = np.array([w[0] for w in walls]).reshape(-1, 2)
    return Walls(start, np.array([w[1] for w in walls]).reshape(-1, 2),
                 np.array([w[2] for w in walls]),
                 terrain(start[:, 0], start[:, 1]) + WALL_HEIGHT)


def ghost_returns(vret: Returns, boxes: BoxSamples, walls: Walls, sensor: Sensor,
                  terrain: Terrain, rng: np.random.Generator) -> Returns:
    """Multipath ghosts of the vehicles' returns ``vret`` in the facades ``walls``: the path
    sensor - facade - vehicle - facade - sensor appears at the point's mirror image in the
    facade, moving with the mirrored velocity (its Doppler the image's radial speed, plus
    :data:`SIGMA_DOPPLER` noise). Per return and facade with probability :data:`GHOST_PROB`,
    where the point lies on the sensor's side and the sight line to the image meets the
    facade within its length and below its top. RCS 0 dBsm, label :data:`GHOST`."""
    stride = int(boxes.frame.max(initial=0)) + 1        # (vehicle, frame) -> one key
    key = boxes.vid.astype(np.int64) * stride + boxes.frame
    order = np.argsort(key)
    row = order[np.searchsorted(key[order], vret.label.astype(np.int64) * stride + vret.frame)]
    states = boxes.states[row]
    vel = rigid_velocity(states, vret.p_w[:, 0] - states[:, 1], vret.p_w[:, 1] - states[:, 2],
                         terrain)
    s_xy, parts = sensor.position[:2], []
    for a, u, length, top in zip(walls.start, walls.direction, walls.length, walls.top):
        n = np.array([-u[1], u[0]])
        side = np.sign(np.dot(s_xy - a, n))
        d = vret.p_w[:, :2] - a
        image = a + 2 * (d @ u)[:, None] * u - d
        to = image - s_xy
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.dot(a - s_xy, n) / (to @ n)
        along = (s_xy + t[:, None] * to - a) @ u
        ray_z = sensor.position[2] + t * (vret.p_w[:, 2] - sensor.position[2])
        seen = ((np.sign(d @ n) == side) & (t > 0) & (t < 1) & (along >= 0)
                & (along <= length) & (ray_z <= top) & (rng.random(len(t)) < GHOST_PROB))
        if not seen.any():
            continue
        p_w = np.column_stack([image[seen], vret.p_w[seen, 2]])
        v = vel[seen]
        v_xy = 2 * (v[:, :2] @ u)[:, None] * u - v[:, :2]
        ray = p_w - sensor.position
        ray /= np.linalg.norm(ray, axis=1, keepdims=True)
        doppler = v_xy[:, 0] * ray[:, 0] + v_xy[:, 1] * ray[:, 1] + v[:, 2] * ray[:, 2]
        m = len(p_w)
        parts.append(Returns(vret.frame[seen], p_w,
                             doppler + rng.normal(0, SIGMA_DOPPLER, m), doppler,
                             np.full(m, GHOST), np.zeros(m, bool), np.zeros(m)))
    return Returns.concat(parts) if parts else vret.take(np.zeros(0, dtype=int))


@dataclass
class Detections:
    """What the radar reports, sorted by frame: the points ``p_s`` (n, 3) in S, and the
    ``returns`` they measure (the same rows: frame, true point, Doppler, label, ...)."""

    p_s: np.ndarray
    returns: Returns


def add_noise(p_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The points (n, 3) of S with range, azimuth and elevation noise."""
    r = np.linalg.norm(p_s, axis=1)
    az = np.arctan2(p_s[:, 1], p_s[:, 0])
    el = np.arcsin(np.clip(p_s[:, 2] / r, -1, 1))
    r = r + rng.normal(0, SIGMA_RANGE, len(r))
    az = az + rng.normal(0, SIGMA_AZ, len(r))
    el = el + rng.normal(0, SIGMA_EL, len(r))
    return np.column_stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az),
                            r * np.sin(el)])


def measure(parts: list[Returns], sensor: Sensor, rng: np.random.Generator) -> Detections:
    """The returns as measured in S (:func:`add_noise` when ``noisy``), those in the field of
    view and range kept; sorted by frame, in random order within a frame."""
    points, kept = [], []
    for part in parts:
        p_s = sensor.to_sensor(part.p_w)
        if part.noisy:
            p_s = add_noise(p_s, rng)
        az = np.degrees(np.arctan2(p_s[:, 1], p_s[:, 0]))
        el = np.degrees(np.arctan2(p_s[:, 2], np.hypot(p_s[:, 0], p_s[:, 1])))
        keep = ((np.abs(az) <= HFOV_DEG / 2) & (np.abs(el) <= VFOV_DEG / 2)
                & (np.linalg.norm(p_s, axis=1) <= MAX_RANGE + 1))
        points.append(p_s[keep])
        kept.append(part.take(keep))
    p_s, returns = np.concatenate(points), Returns.concat(kept)
    order = np.lexsort((rng.random(len(returns.frame)), returns.frame))
    return Detections(p_s[order], returns.take(order))


# ----------------------------------------------------------------------------- writers
def write_radar(out: Path, det: Detections) -> None:
    """radar.csv: t (s, frame / rate), x, y, z (m, S), doppler (m/s), rcs, frame."""
    r = det.returns
    table = np.column_stack([r.frame / FRAME_RATE, det.p_s, r.doppler, r.rcs, r.frame])
    np.savetxt(out / "radar.csv", table, fmt=["%.3f"] * 5 + ["%.0f", "%d"], delimiter=",",
               header="t,x,y,z,doppler,rcs,frame", comments="")


def write_labels(out: Path, det: Detections, scat: Scatterers | None) -> None:
    """_gen/labels.npz: per radar.csv row its frame, point in S, true point in W, Doppler
    measured and true, label and roof flag; the static scatterers (W)."""
    r, empty = det.returns, np.zeros((0, 3))
    np.savez_compressed(out / "_gen" / "labels.npz", frame=r.frame, p_s=det.p_s,
                        p_w_true=r.p_w, dop=r.doppler, dop_true=r.doppler_true,
                        label=r.label, roof=r.roof,
                        kerbs=empty if scat is None else scat.kerbs,
                        poles=empty if scat is None else scat.poles)


def write_als(out: Path, road: RoadMap, terrain: Terrain, rng: np.random.Generator
              ) -> tuple[int, float]:
    """als/tile.las (LAS 1.4, point format 6, mm resolution, CRS in a WKT VLR): the ground
    plane on a jittered 1 m grid around the site with 3 cm height noise, class 11 on the
    drivable lanelets, 2 elsewhere. Returns the point count and the share on the road."""
    g = np.arange(-ALS_HALF_SIDE, ALS_HALF_SIDE + 1e-9, ALS_STEP)
    gx, gy = np.meshgrid(terrain.origin[0] + g, terrain.origin[1] + g)
    x = gx.ravel() + rng.uniform(-0.1, 0.1, gx.size)
    y = gy.ravel() + rng.uniform(-0.1, 0.1, gx.size)
    z = terrain(x, y) + rng.normal(0, 0.03, x.size)
    road_pts = road.inside(np.column_stack([x, y]))
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([round(terrain.origin[0]), round(terrain.origin[1]),
                               round(terrain.z0)], dtype=float)
    header.add_crs(pyproj.CRS(CRS))
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, z
    las.classification = np.where(road_pts, ROAD, GROUND).astype(np.uint8)
    las.return_number = np.ones(x.size, np.uint8)
    las.number_of_returns = np.ones(x.size, np.uint8)
    las.write(out / "als" / "tile.las")
    return x.size, float(road_pts.mean())


def copy_map(out: Path, map_path: Path) -> None:
    """map.osm, and the LICENSE* files beside the map (its licence travels with it)."""
    shutil.copyfile(map_path, out / "map.osm")
    for lic in map_path.resolve().parent.glob("LICENSE*"):
        shutil.copyfile(lic, out / lic.name)


def write_sensor_toml(out: Path, sensor: Sensor, rng: np.random.Generator) -> None:
    """sensor.toml: the position off by N(0, 3 m) per axis, the yaw guess by N(0, 3 deg), the
    mast height rounded to whole metres, the field of view."""
    approx = sensor.position[:2] + rng.normal(0, 3.0, 2)
    yaw_guess = wrap_deg(sensor.yaw_deg + rng.normal(0, 3.0))
    (out / "sensor.toml").write_text(
        f'crs = "{CRS}"\n\n[sensor]\n'
        f"approx_position = [{approx[0]:.3f}, {approx[1]:.3f}]\n"
        f"approx_height = {float(round(sensor.mast)):.1f}\n"
        f"yaw_guess_deg = {yaw_guess:.3f}\n"
        f"hfov_deg = {HFOV_DEG:g}\nvfov_deg = {VFOV_DEG:g}\nmax_range = {MAX_RANGE:g}\n")


def write_ground_truth(out: Path, sensor: Sensor, vehicles: list[Vehicle]) -> None:
    """ground_truth.json: the sensor pose and every vehicle's states (W, 4 decimals)."""
    p = sensor.position
    gt = {"crs": CRS,
          "sensor": {"x": float(p[0]), "y": float(p[1]), "z": float(p[2]),
                     "yaw_deg": float(sensor.yaw_deg), "pitch_deg": float(sensor.pitch_deg),
                     "roll_deg": float(sensor.roll_deg)},
          "tracks": [{"id": v.id, "length": float(v.length), "width": float(v.width),
                      "states": [[round(float(x), 4) for x in row] for row in v.states]}
                     for v in vehicles]}
    (out / "ground_truth.json").write_text(json.dumps(gt))


# ------------------------------------------------------------------------------ generate
def generate(map_path: str | Path, site: tuple[float, float], seed: int, out: str | Path,
             vehicles_per_minute: float = 12.0, duration: float = 60.0,
             clutter: str = "static", occlusion: bool = False, ghosts: bool = False) -> Path:
    """Write a scenario directory ``out`` at the junction ``site`` (lat, lon, deg) of the
    Lanelet2 map ``map_path``: ``duration`` s of traffic at ``vehicles_per_minute``,
    ``clutter`` "static", "uniform" or "none" (the module's docstring says what each draws);
    ``occlusion``: vehicles hide the returns behind them (:func:`occluded`; false alarms
    excepted), the same draws otherwise; ``ghosts``: facades (:func:`draw_walls`) mirror the
    vehicles' returns (:func:`ghost_returns`; drawn from a generator of their own, the other
    draws the same). Deterministic in (``seed``, ``site``). Returns ``out``."""
    if clutter not in ("static", "none", "uniform"):
        raise ValueError(f"clutter {clutter!r}: expected static, none or uniform")
    map_path, out = Path(map_path), Path(out)
    lat, lon = site
    # the site enters the seed: different sites with the same seed are not correlated
    key = [seed, int(round(lat * 1e5)), int(round(lon * 1e5))]
    rng = np.random.default_rng(key)
    (out / "als").mkdir(parents=True, exist_ok=True)
    (out / "_gen").mkdir(exist_ok=True)
    road = RoadMap(map_path, (lat, lon))
    centre = np.array(road.to_world.transform(lon, lat))
    terrain = draw_terrain(rng, centre)
    sensor = place_sensor(road, centre, terrain, rng)
    routes = pick_routes(road, centre, rng)
    vehicles = drive(routes, rng, duration, vehicles_per_minute)
    if not vehicles:
        warnings.warn(f"{out}: no vehicle in the {duration:g} s", stacklevel=2)
    boxes = BoxSamples.of(vehicles)
    parts = [vehicle_returns(boxes, sensor, terrain, rng)]
    n_frames = int(round(duration * FRAME_RATE))
    scat = draw_scatterers(road, sensor, terrain, rng) if clutter == "static" else None
    if scat is not None:
        parts.append(static_returns(scat, n_frames, rng))
    elif clutter == "uniform":
        parts.append(uniform_returns(sensor, terrain, n_frames, rng))
    walls = None
    if ghosts:
        ghost_rng = np.random.default_rng([*key, 1])
        walls = draw_walls(road, sensor, terrain, ghost_rng)
        parts.append(ghost_returns(parts[0], boxes, walls, sensor, terrain, ghost_rng))
    n_hidden = 0
    if occlusion:
        hidden = [occluded(p, boxes, sensor, terrain) & (p.label != FALSE_ALARM)
                  for p in parts]
        n_hidden = int(sum(h.sum() for h in hidden))
        parts = [p.take(~h) for p, h in zip(parts, hidden)]
    det = measure(parts, sensor, rng)
    write_radar(out, det)
    write_labels(out, det, scat)
    n_als, road_share = write_als(out, road, terrain, rng)
    copy_map(out, map_path)
    write_sensor_toml(out, sensor, rng)
    write_ground_truth(out, sensor, vehicles)
    meta = {"site": centre.tolist(), "site_latlon": [lat, lon], "seed": seed,
            "clutter": clutter, "occlusion": occlusion, "n_hidden": n_hidden,
            "walls": None if walls is None else [
                [*a.tolist(), *(a + w * u).tolist()]
                for a, u, w in zip(walls.start, walls.direction, walls.length)],
            "n_ghost": int((det.returns.label == GHOST).sum()),
            "vpm": vehicles_per_minute, "duration": duration,
            "terrain": {"z0": terrain.z0, "grad": terrain.grad.tolist()}, "mast": sensor.mast,
            "n_routes": len(routes),
            "routes": [[[k, inv] for k, inv in r.lanes] for r in routes],
            "vehicles": [{"id": v.id, "cls": v.kind, "H": v.height, "route": v.route}
                         for v in vehicles],
            "n_det": len(det.p_s), "n_veh_det": int((det.returns.label >= 0).sum()),
            "n_als": n_als, "als_road_share": road_share}
    (out / "_gen" / "meta.json").write_text(json.dumps(meta, indent=1))
    return out


def summary(out: Path) -> str:
    """One line about the scenario ``out``, from its ground truth and _gen/meta.json."""
    s = json.loads((out / "ground_truth.json").read_text())["sensor"]
    m = json.loads((out / "_gen" / "meta.json").read_text())
    return (f"{out}: sensor ({s['x']:.1f},{s['y']:.1f},{s['z']:.1f}) yaw {s['yaw_deg']:.1f} "
            f"pitch {s['pitch_deg']:.1f} mast {m['mast']:.2f}; routes {m['n_routes']}; "
            f"tracks {len(m['vehicles'])}; detections {m['n_det']} (vehicle {m['n_veh_det']}); "
            f"ALS {m['n_als']} pts, road {m['als_road_share']:.2f}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--map", required=True, type=Path, help="Lanelet2 map (.osm)")
    ap.add_argument("--site", required=True, help="the junction: LAT,LON (deg)")
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--out", required=True, type=Path, help="the scenario directory to write")
    ap.add_argument("--vehicles-per-minute", type=float, default=12.0)
    ap.add_argument("--duration", type=float, default=60.0, help="s of radar frames")
    ap.add_argument("--clutter", choices=["static", "none", "uniform"], default="static")
    ap.add_argument("--occlusion", action="store_true",
                    help="vehicles hide the returns behind them")
    ap.add_argument("--ghosts", action="store_true",
                    help="facades beside the road mirror the vehicles' returns (multipath)")
    a = ap.parse_args(argv)
    lat, lon = (float(v) for v in a.site.split(","))
    out = generate(a.map, (lat, lon), a.seed, a.out, a.vehicles_per_minute, a.duration,
                   a.clutter, a.occlusion, a.ghosts)
    print(summary(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
