"""Traffic: routes through the lane pieces and CTRA-consistent vehicle motion along them.

A route (entry lane -> movement -> exit lane) follows the concatenated lane centre line: its
curvature, smoothed over ``transition_length`` (clothoid-like ramps, so the yaw rate is
continuous), steers a path follower that keeps to the centre line (a junction turn's corner is
cut by a few decimetres, the exit lane's centre regained within ~30 m); vehicles follow it
with a speed profile of piecewise constant acceleration (cruise on straights, turn speed in
junction turns, lateral-acceleration cap in curves). Hence yaw is the path tangent and
yawrate = v * curvature.

Vehicles arrive singly or in platoons (``platoon_size``): a platoon's followers drive the
leader's route at the leader's speed profile, ``platoon_headway`` s (front to front) behind
their predecessor. Vehicles never overlap: each vehicle's entry time is delayed until its
occupancy of every point it shares with an earlier vehicle's route (same lane, merge or
crossing) is separated from that vehicle's occupancy by at least the headway. With
``stop_share`` that share of the vehicles stops once short of its route's first crossing
(:func:`stop_lines`) and stands ``stop_time`` s, v 0 (a red light, a yield); a vehicle that
would come up behind a standing one on its lane before it has moved off queues behind it and
moves off ``queue_discharge`` s after it; the stand is part of its occupancy, so the other
vehicles whose paths it blocks enter later.

Cyclists (``cyclists_per_minute``; none by default) ride the same routes ``cyclist_offset`` m
right of the lane centre line, at the lane's edge: road users that are not motor vehicles,
whose detections and tracks a localizer must not take for vehicles on the lane centres.
Other users on ways of their own (:class:`PathUsers`: a real map's footpaths, cycle ways and
rails, :mod:`fgloc.sim.map_paths`) arrive the same way on their own routes.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from fgloc.geo import wrap_angle
from fgloc.scenario import TrackTruth
from fgloc.sim.config import TrafficSimConfig
from fgloc.sim.paths import Trace, trace
from fgloc.sim.roads import RoadNetwork

#: route sampling (m)
ROUTE_DS = 0.25
#: route sub-sampling for conflict search (every n-th sample)
CONFLICT_STRIDE = 4
#: widest centre distance (m) at which two route points can conflict
CONFLICT_DIST = 3.2
#: lateral clearance (m) added to the half widths of two vehicles
LATERAL_MARGIN = 0.6
#: path follower's wavenumber (1/m): critically damped return to the lane centre line, the
#: lateral error decaying as exp(-FOLLOW_WAVENUMBER * distance)
FOLLOW_WAVENUMBER = 0.1

#: two routes cross (:func:`stop_lines`) where their headings differ by more than this and
#: less than its supplement (deg): not a lane followed or shared, not the opposite lane
CROSSING_DEG = 30.0
#: how often a queue is looked for again from a later entry time (:func:`_join_queue`)
QUEUE_TRIES = 3
#: conflicts (:func:`_conflicts`) per pair of route indices, computed once
_ConflictCache = dict[tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class VehicleClass:
    """Vehicle class: length and width as (mean, std) m, roof height m, mean RCS dBsm."""

    name: str
    length: tuple[float, float]
    width: tuple[float, float]
    height: float
    rcs: float


VEHICLE_CLASSES: tuple[VehicleClass, ...] = (
    VehicleClass("car", (4.5, 0.25), (1.8, 0.06), 1.5, 10.0),
    VehicleClass("van", (5.5, 0.3), (2.0, 0.05), 2.2, 13.0),
    VehicleClass("truck", (11.0, 0.6), (2.5, 0.03), 3.6, 20.0),
    VehicleClass("bicycle", (1.8, 0.1), (0.6, 0.05), 1.7, 0.0),
    VehicleClass("pedestrian", (0.5, 0.05), (0.5, 0.05), 1.7, -5.0),
    VehicleClass("tram", (35.0, 2.0), (2.65, 0.02), 3.5, 25.0),
)
#: index of the bicycle class in VEHICLE_CLASSES (``class_mix`` draws from the classes before it)
BICYCLE = 3
#: index of the pedestrian class in VEHICLE_CLASSES
PEDESTRIAN = 4
#: index of the tram class in VEHICLE_CLASSES
TRAM = 5


@dataclass
class Route:
    """A smoothed path through lane pieces, sampled every ROUTE_DS m (L frame)."""

    pieces: list[int]
    s: np.ndarray
    xy: np.ndarray
    heading: np.ndarray
    kappa: np.ndarray


@dataclass
class Vehicle:
    """One vehicle: class index, size (m), route index, entry time t0 (s) and, on the route's
    s grid, its speed v (m/s) and the time tau (s) since entry, not counting a stop; a
    vehicle that stops stands ``dwell`` s at arc length ``stop_s`` (m; inf: no stop), where
    its v is 0."""

    kind: int
    length: float
    width: float
    route: int
    t0: float
    v: np.ndarray
    tau: np.ndarray
    stop_s: float = math.inf
    dwell: float = 0.0

    def time_at(self, route: Route, s: np.ndarray) -> np.ndarray:
        """Time since entry (s) when the vehicle centre is at arc length s (clamped at the
        ends; after a stop's standing time where the stop is reached)."""
        return np.interp(s, route.s, self.tau) + np.where(s > self.stop_s, self.dwell, 0.0)

    def stop_reached(self, route: Route) -> float:
        """Time since entry (s) when the vehicle reaches its stop; inf when it has none."""
        return (float(np.interp(self.stop_s, route.s, self.tau)) if math.isfinite(self.stop_s)
                else math.inf)

    def arc_at(self, route: Route, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Arc length (m) of the centre at times t since entry, and whether it stands."""
        t_stop = self.stop_reached(route)
        standing = (t >= t_stop) & (t <= t_stop + self.dwell)
        t = np.where(t > t_stop + self.dwell, t - self.dwell, np.minimum(t, t_stop))
        return np.interp(t, self.tau, route.s), standing


@dataclass
class PathUsers:
    """Road users other than the lanes' motor vehicles (cyclists, pedestrians, trams) on
    routes of their own: class index ``kind`` (into VEHICLE_CLASSES), Poisson arrivals
    ``per_minute`` on average on a random one of ``routes``, cruise speeds (m/s) drawn from
    ``speed`` (70 % of it in junction turns)."""

    routes: list[Route]
    kind: int
    per_minute: float
    speed: tuple[float, float]


@dataclass
class Traffic:
    """Ground-truth tracks in L and the class index of each (into VEHICLE_CLASSES)."""

    tracks: list[TrackTruth]
    kinds: np.ndarray


def _cumtrapz(y: np.ndarray, ds: float) -> np.ndarray:
    """Cumulative trapezoid integral along axis 0 (starting at 0) of samples spaced ds."""
    steps = np.cumsum(0.5 * (y[1:] + y[:-1]) * ds, axis=0)
    return np.concatenate([np.zeros_like(y[:1]), steps])


def build_route(net: RoadNetwork, pieces: list[int], transition: float) -> Route:
    """Route along the given piece indices with curvature ramps of length ``transition`` m.

    The lane centre line's curvature, smoothed over ``transition`` m, is the feed-forward of a
    path follower that steers back onto the centre line (``FOLLOW_WAVENUMBER``): integrating the
    smoothed curvature alone leaves the vehicle off the exit lane's centre after every turn (the
    smoothing cuts the corner; 0.2-0.7 m measured on junction turns), so the follower closes
    that gap within ~30 m. Curvature is continuous; each ROUTE_DS step is an arc of the mean
    of its two ends' curvatures (Heun), so yaw rate = speed * curvature holds along the route.
    """
    prims = [p for i in pieces for p in net.pieces[i].prims]
    first = net.pieces[pieces[0]]
    ref = trace(first.start, first.heading, prims, ROUTE_DS)
    n = int(np.ceil(ref.s[-1] / ROUTE_DS))
    s = np.arange(n + 1) * ROUTE_DS
    kappa_ref = ref.kappa[np.clip(np.searchsorted(ref.s, s, side="right"), 1, len(ref.s) - 1)]
    win = max(1, int(round(transition / ROUTE_DS)) | 1)
    kappa_ff = np.convolve(np.pad(kappa_ref, win // 2, mode="edge"), np.ones(win) / win,
                           mode="valid")
    follow = _Follower(ref, kappa_ff)
    xy = np.empty((n + 1, 2))
    heading = np.empty(n + 1)
    kappa = np.empty(n + 1)
    x, y, h = float(first.start[0]), float(first.start[1]), float(first.heading)
    for i in range(n + 1):
        xy[i], heading[i] = (x, y), h
        kappa[i] = k0 = follow.curvature(x, y, h)
        if i < n:  # Heun step: constant curvature, the mean of this node's and the predicted next
            k = 0.5 * (k0 + follow.curvature(*_arc(x, y, h, k0), peek=True))
            x, y, h = _arc(x, y, h, k)
    return Route(pieces, s, xy, heading, kappa)


class _Follower:
    """Curvature command of the path follower: feed-forward plus critically damped feedback on
    the lateral and heading error to the reference (plain floats: called twice per step)."""

    def __init__(self, ref: Trace, kappa_ff: np.ndarray) -> None:
        self.x, self.y = ref.xy[:, 0].tolist(), ref.xy[:, 1].tolist()
        self.h, self.s = ref.heading.tolist(), ref.s.tolist()
        self.k = ref.kappa.tolist()
        self.ff = kappa_ff.tolist()
        self.j = 0

    def curvature(self, x: float, y: float, h: float, peek: bool = False) -> float:
        """Commanded curvature (1/m) at pose (x, y, h) in L; peek: do not move the cursor."""
        j, last = self.j, len(self.s) - 1
        while j < last and ((x - self.x[j + 1]) ** 2 + (y - self.y[j + 1]) ** 2
                            <= (x - self.x[j]) ** 2 + (y - self.y[j]) ** 2):
            j += 1
        if not peek:
            self.j = j
        dx, dy = x - self.x[j], y - self.y[j]
        c, s = math.cos(self.h[j]), math.sin(self.h[j])
        ahead = dx * c + dy * s
        k_ref = self.k[min(j + 1, last)] if ahead > 0 else self.k[j]
        lateral = -dx * s + dy * c - 0.5 * k_ref * ahead**2
        dh = (h - self.h[j] - k_ref * ahead + math.pi) % (2 * math.pi) - math.pi
        u = min(max((self.s[j] + ahead) / ROUTE_DS, 0.0), len(self.ff) - 1.0)
        i0 = min(int(u), len(self.ff) - 2)
        ff = self.ff[i0] + (u - i0) * (self.ff[i0 + 1] - self.ff[i0])
        return ff - FOLLOW_WAVENUMBER**2 * lateral - 2.0 * FOLLOW_WAVENUMBER * dh


def _arc(x: float, y: float, h: float, k: float) -> tuple[float, float, float]:
    """Pose after ROUTE_DS m of constant curvature k from (x, y, h): the chord formula of
    :func:`fgloc.sim.paths._advance` on plain floats (it runs twice per step of every route;
    the array version costs ~30x more per call: 25 against 0.8 us)."""
    half = 0.5 * k * ROUTE_DS
    chord = ROUTE_DS * (math.sin(half) / half if abs(half) > 1e-12 else 1.0)
    return x + chord * math.cos(h + half), y + chord * math.sin(h + half), h + 2.0 * half


def speed_profile(route: Route, v_cruise: float, v_turn: float,
                  cfg: TrafficSimConfig) -> np.ndarray:
    """Speed (m/s) on the route grid: limits, then acceleration/deceleration passes."""
    k = np.abs(route.kappa)
    v_lim = np.minimum(v_cruise, np.sqrt(cfg.lateral_accel / np.maximum(k, 1e-9)))
    v_lim = np.where(k > cfg.turn_curvature, np.minimum(v_lim, v_turn), v_lim)
    s = route.s
    v2 = np.minimum.accumulate(v_lim**2 - 2 * cfg.accel * s) + 2 * cfg.accel * s
    v2 = np.minimum.accumulate((v2 + 2 * cfg.decel * s)[::-1])[::-1] - 2 * cfg.decel * s
    return np.sqrt(np.maximum(v2, 1.0))


def _conflicts(a: Route, b: Route) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Arc lengths on a and b and centre distances of route points closer than CONFLICT_DIST."""
    pa, pb = a.xy[::CONFLICT_STRIDE], b.xy[::CONFLICT_STRIDE]
    pairs = cKDTree(pa).sparse_distance_matrix(cKDTree(pb), CONFLICT_DIST, output_type="ndarray")
    return (a.s[::CONFLICT_STRIDE][pairs["i"]], b.s[::CONFLICT_STRIDE][pairs["j"]],
            pairs["v"])


def stop_lines(routes: list[Route], gap: float) -> np.ndarray:
    """(n,) arc length (m) on each route of ``gap`` m before its first crossing with another
    route (a point within CONFLICT_DIST of the other's whose heading differs by
    CROSSING_DEG to 180 - CROSSING_DEG), where a stopping vehicle's front stands; inf where
    the route crosses none."""
    pts = [r.xy[::CONFLICT_STRIDE] for r in routes]
    heads = [r.heading[::CONFLICT_STRIDE] for r in routes]
    owner = np.concatenate([np.full(len(p), i) for i, p in enumerate(pts)])
    head = np.concatenate(heads)
    tree = cKDTree(np.vstack(pts))
    lo, hi = np.deg2rad(CROSSING_DEG), np.deg2rad(180.0 - CROSSING_DEG)
    out = np.full(len(routes), np.inf)
    for i, route in enumerate(routes):
        for k, near in enumerate(tree.query_ball_point(pts[i], CONFLICT_DIST)):
            near = np.asarray(near, dtype=np.int64)
            turn = np.abs(wrap_angle(head[near] - heads[i][k]))
            if np.any((owner[near] != i) & (turn > lo) & (turn < hi)):
                out[i] = route.s[::CONFLICT_STRIDE][k] - gap
                break
    return out


def _with_stop(veh: Vehicle, route: Route, line: float, dwell: float,
               cfg: TrafficSimConfig) -> Vehicle:
    """``veh`` stopping with its front at arc length ``line`` (m) for ``dwell`` s: braking at
    ``cfg.decel`` to it and accelerating at ``cfg.accel`` from it (a new Vehicle); ``veh``
    itself when the line leaves no room to brake from the entry speed."""
    stop = line - 0.5 * veh.length
    if not np.isfinite(stop) or stop < veh.v[0] ** 2 / (2.0 * cfg.decel):
        return veh
    stop = float(route.s[np.searchsorted(route.s, stop, side="right") - 1])   # a grid node: v 0
    d = route.s - stop
    v = np.minimum(veh.v, np.sqrt(2.0 * np.where(d < 0.0, cfg.decel, cfg.accel) * np.abs(d)))
    # constant acceleration between grid nodes (v^2 linear in s): dt = 2 ds / (v0 + v1), finite
    # where v is 0 at the stop (the trapezoid of 1 / v is not)
    tau = np.concatenate([[0.0], np.cumsum(2.0 * ROUTE_DS / (v[1:] + v[:-1]))])
    return dataclasses.replace(veh, v=v, tau=tau, stop_s=stop, dwell=float(dwell))


def _same_lane(a: Route, b: Route, s: float) -> bool:
    """Whether routes a and b pass within 0.5 m of each other at arc length s (m)."""
    pa = [np.interp(s, a.s, a.xy[:, k]) for k in range(2)]
    pb = [np.interp(s, b.s, b.xy[:, k]) for k in range(2)]
    return math.hypot(pa[0] - pb[0], pa[1] - pb[1]) < 0.5


def _queued(f: Vehicle, route: Route, earlier: list[Vehicle], routes: list[Route],
            cfg: TrafficSimConfig) -> Vehicle | None:
    """``f`` standing in the queue behind the last of the ``earlier`` vehicles that stand on
    its lane (its route and theirs together from the start to their front), when, braking
    for it, it comes up behind that one before it moves off: its front ``queue_gap`` m
    behind that one's rear, moving off ``queue_discharge`` s after it; None when there is no
    such queue (or no room to brake for it)."""
    tail: tuple[float, Vehicle] | None = None
    for lead in earlier:
        rl = routes[lead.route]
        front = lead.stop_s + 0.5 * lead.length
        if (lead.dwell <= 0 or front > min(route.s[-1], rl.s[-1])
                or not (_same_lane(route, rl, 0.0) and _same_lane(route, rl, front))):
            continue
        line = lead.stop_s - 0.5 * lead.length - cfg.queue_gap
        queued = _with_stop(f, route, line, 0.0, cfg)
        if queued is f or (tail is not None and queued.stop_s >= tail[1].stop_s):
            continue
        arrive = queued.t0 + queued.stop_reached(route)
        off = lead.t0 + lead.stop_reached(rl) + lead.dwell
        if arrive < off:
            tail = (off + cfg.queue_discharge - arrive, queued)
    return None if tail is None else dataclasses.replace(tail[1], dwell=tail[0])


def _forbidden(f: Vehicle, rf: Route, lead: Vehicle, rl: Route,
               pairs: tuple[np.ndarray, np.ndarray, np.ndarray],
               headway: float) -> tuple[float, float] | None:
    """Interval of entry times of ``f`` whose occupancy would overlap ``lead``'s."""
    sf, sl, dist = pairs
    m = dist < 0.5 * (f.width + lead.width) + LATERAL_MARGIN
    if not m.any():
        return None
    sf, sl = sf[m], sl[m]
    lead_in = lead.t0 + lead.time_at(rl, sl - lead.length / 2) - headway
    lead_out = lead.t0 + lead.time_at(rl, sl + lead.length / 2) + headway
    lo = lead_in - f.time_at(rf, sf + f.length / 2)
    hi = lead_out - f.time_at(rf, sf - f.length / 2)
    return float(lo.min()), float(hi.max())


def _earliest(t: float, intervals: list[tuple[float, float]]) -> float:
    """Smallest time >= t outside every open interval."""
    for lo, hi in sorted(intervals):
        if lo < t < hi:
            t = hi
    return t


def _beside(routes: list[Route], r: int) -> list[int]:
    """Indices of the routes whose start lies 2-4.5 m to the side of route ``r``'s start
    (at most 2 m ahead or behind it) with a heading within 15 deg of its: the adjacent lanes
    of its road, in its direction."""
    p0, h0 = routes[r].xy[0], routes[r].heading[0]
    u = np.array([np.cos(h0), np.sin(h0)])
    out = []
    for j, route in enumerate(routes):
        d = route.xy[0] - p0
        side, along = abs(d[0] * u[1] - d[1] * u[0]), abs(float(d @ u))
        if (2.0 <= side <= 4.5 and along <= 2.0
                and abs(wrap_angle(route.heading[0] - h0)) <= np.deg2rad(15.0)):
            out.append(j)
    return out


def _new_vehicle(rng: np.random.Generator, cfg: TrafficSimConfig, routes: list[Route],
                 t_nominal: float, leader: Vehicle | None = None) -> Vehicle:
    """A random vehicle entering at ``t_nominal``; a platoon follower (``leader`` given) takes
    the leader's route and speed profile (with ``platoon_abreast`` a route beside it, at its
    cruise speed) and enters one platoon headway (front to front) behind it."""
    kind = int(rng.choice(len(cfg.class_mix), p=np.asarray(cfg.class_mix) / sum(cfg.class_mix)))
    vc = VEHICLE_CLASSES[kind]
    if leader is None:
        lo, hi = cfg.speed_straight
        v_cruise = rng.uniform(lo, hi if vc.name != "truck" else lo + 0.6 * (hi - lo))
        r = int(rng.integers(len(routes)))
        v = speed_profile(routes[r], v_cruise, rng.uniform(*cfg.speed_turn), cfg)
    else:
        r, v = leader.route, leader.v
        beside = _beside(routes, r) if cfg.platoon_abreast else []
        if beside:
            r = beside[int(rng.integers(len(beside)))]
            v = speed_profile(routes[r], float(leader.v[0]), rng.uniform(*cfg.speed_turn), cfg)
    if vc.name == "truck" and cfg.truck_length is not None:
        length = rng.uniform(*cfg.truck_length)
    else:
        length = rng.normal(*vc.length)
    veh = Vehicle(kind, length, rng.normal(*vc.width), r, t_nominal, v,
                  _cumtrapz(1.0 / v, ROUTE_DS))
    if leader is not None:
        veh.t0 = (leader.t0 + rng.uniform(*cfg.platoon_headway)
                  + 0.5 * (veh.length - leader.length) / v[0])
    return veh


def _arrivals(rng: np.random.Generator, cfg: TrafficSimConfig, start: float, end: float,
              count: int | None) -> list[tuple[float, int]]:
    """Nominal entry times and sizes of the platoons (size 1: a single vehicle): Poisson with
    the mean interval x the mean platoon size, or uniform ones until ``count`` vehicles."""
    lo, hi = cfg.platoon_size
    if count is not None:
        t = np.sort(rng.uniform(start, end, count))
    else:
        interval = cfg.arrival_interval * 0.5 * (lo + hi)
        n_max = int((end - start) / interval * 2 + 20)
        t = start + np.cumsum(rng.exponential(interval, n_max))
        t = t[t < end]
    sizes = np.ones(len(t), dtype=np.int64) if lo == hi == 1 else rng.integers(lo, hi + 1, len(t))
    if count is not None:   # platoons until count vehicles in total
        keep = np.cumsum(sizes) - sizes < count
        t, sizes = t[keep], sizes[keep]
        sizes[-1:] -= max(int(sizes.sum()) - count, 0)
    return [(float(a), int(b)) for a, b in zip(t, sizes)]


def _states(veh: Vehicle, route: Route, times: np.ndarray) -> np.ndarray:
    """(n, 6) [t, x, y, yaw, v, yawrate] at the given times within the vehicle's life."""
    t = times[(times >= veh.t0) & (times <= veh.t0 + veh.tau[-1] + veh.dwell)]
    s, standing = veh.arc_at(route, t - veh.t0)
    v = np.where(standing, 0.0, np.interp(s, route.s, veh.v))
    x = np.interp(s, route.s, route.xy[:, 0])
    y = np.interp(s, route.s, route.xy[:, 1])
    yaw = wrap_angle(np.interp(s, route.s, route.heading))
    yawrate = v * np.interp(s, route.s, route.kappa)
    return np.column_stack([t, x, y, np.atleast_1d(yaw), v, yawrate])


def simulate_traffic(rng: np.random.Generator, cfg: TrafficSimConfig, net: RoadNetwork,
                     times: np.ndarray, count: int | None,
                     others: tuple[PathUsers, ...] = ()) -> Traffic:
    """Vehicles on random routes, sampled at ``times`` (s); tracks with < 2 samples dropped.

    count: motor vehicles generated in total (None: Poisson arrivals every ``arrival_interval``
    s on average). Arrivals start before times[0] so the scene is already filled at the start.
    Cyclists (``cyclists_per_minute``, none by default) and then ``others`` (users of ways of
    their own, e.g. a real map's footpaths) come after the motor vehicles, so adding them
    leaves those unchanged.
    """
    routes = [build_route(net, r, cfg.transition_length) for r in net.routes()]
    warm = _warm_up(routes, cfg.speed_straight)
    duration = float(times[-1] - times[0]) if len(times) else 0.0
    cache: _ConflictCache = {}
    vehicles: list[Vehicle] = []
    lines = stop_lines(routes, cfg.stop_gap) if cfg.stop_share > 0 else None
    for t_nom, size in _arrivals(rng, cfg, times[0] - warm, times[0] + duration, count):
        leader = None
        for _ in range(size):
            f = _new_vehicle(rng, cfg, routes, t_nom, leader)
            driven = f
            if lines is not None:
                dwell = rng.uniform(*cfg.stop_time) if rng.random() < cfg.stop_share else 0.0
                queued = _join_queue(f, vehicles, routes, cache, cfg)
                if queued is not None:
                    driven = queued
                elif dwell > 0:
                    driven = _with_stop(f, routes[f.route], lines[f.route], dwell, cfg)
            _enter(driven, vehicles, routes, cache, cfg.headway)
            f.t0 = driven.t0      # a platoon's followers take the profile without the stop
            leader = f
    rides = [(veh, routes[veh.route]) for veh in vehicles]
    groups = list(others)
    if cfg.cyclists_per_minute > 0:
        groups.insert(0, PathUsers([offset_route(r, cfg.cyclist_offset) for r in routes],
                                   BICYCLE, cfg.cyclists_per_minute, cfg.cyclist_speed))
    for group in groups:
        if group.per_minute > 0 and group.routes:
            rides += _riders(rng, cfg, group, times[0], duration)
    tracks, kinds = [], []
    for veh, route in rides:
        states = _states(veh, route, times)
        if len(states) >= 2:
            tracks.append(TrackTruth(len(tracks), veh.length, veh.width, states))
            kinds.append(veh.kind)
    return Traffic(tracks, np.asarray(kinds, dtype=np.int64))


def _warm_up(routes: list[Route], speed: tuple[float, float]) -> float:
    """How long (s) before the recording arrivals start so the scene is already filled: 0.8
    of the median route length at the mean of the cruise ``speed`` range (m/s)."""
    return 0.8 * float(np.median([r.s[-1] for r in routes])) / float(np.mean(speed))


def _entry(f: Vehicle, earlier: list[Vehicle], routes: list[Route], cache: _ConflictCache,
           headway: float) -> float:
    """The earliest entry time (s) from ``f.t0`` on at which ``f`` overlaps none of the
    ``earlier`` vehicles (on ``routes``; ``cache`` keeps the conflicts per route pair)."""
    intervals = []
    for lead in earlier:
        key = (f.route, lead.route)
        if key not in cache:
            cache[key] = _conflicts(routes[f.route], routes[lead.route])
        iv = _forbidden(f, routes[f.route], lead, routes[lead.route], cache[key], headway)
        if iv is not None:
            intervals.append(iv)
    return _earliest(f.t0, intervals)


def _enter(f: Vehicle, earlier: list[Vehicle], routes: list[Route],
           cache: _ConflictCache,
           headway: float) -> None:
    """Delay ``f``'s entry until it overlaps none of the ``earlier`` vehicles (:func:`_entry`),
    then append it to them."""
    f.t0 = _entry(f, earlier, routes, cache, headway)
    earlier.append(f)


def _join_queue(f: Vehicle, earlier: list[Vehicle], routes: list[Route],
                cache: _ConflictCache, cfg: TrafficSimConfig) -> Vehicle | None:
    """``f`` queued (:func:`_queued`) at an entry time at which it overlaps none of the
    ``earlier`` vehicles, or None: when the queue's profile must enter later (it would come
    too close to another vehicle after moving off), the queue is looked for again from that
    later time, up to QUEUE_TRIES times."""
    t0 = f.t0
    for _ in range(QUEUE_TRIES):
        queued = _queued(dataclasses.replace(f, t0=t0), routes[f.route], earlier, routes, cfg)
        if queued is None:
            return None
        t0 = _entry(queued, earlier, routes, cache, cfg.headway)
        if t0 <= queued.t0:
            return queued
    return None


def _every_route_step(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The polyline ``xy`` (n, 2) resampled every ROUTE_DS m by arc length: its vertices' arc
    lengths (n,), the new stations (m,) and the points there (m, 2)."""
    s_old = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    s = np.arange(int(s_old[-1] / ROUTE_DS) + 1) * ROUTE_DS
    return s_old, s, np.column_stack([np.interp(s, s_old, xy[:, 0]),
                                      np.interp(s, s_old, xy[:, 1])])


def offset_route(route: Route, right: float) -> Route:
    """The route moved ``right`` m to the right of its direction of travel (left: negative),
    resampled every ROUTE_DS m. Its heading is the original's at the same station; its
    curvature kappa / (1 + kappa right) (a left turn's radius grows by ``right``)."""
    normal = np.column_stack([np.sin(route.heading), -np.cos(route.heading)])
    s_old, s, xy = _every_route_step(route.xy + right * normal)
    kappa = route.kappa / np.maximum(1.0 + route.kappa * right, 0.2)
    return Route(route.pieces, s, xy, np.interp(s, s_old, np.unwrap(route.heading)),
                 np.interp(s, s_old, kappa))


def polyline_route(xy: np.ndarray) -> Route:
    """A route along the polyline ``xy`` (n, 2) in L (no lane pieces), resampled every
    ROUTE_DS m by arc length; heading the tangent, curvature its derivative along the route."""
    _, s, pts = _every_route_step(xy)
    d = np.gradient(pts, axis=0)
    heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    return Route([], s, pts, heading, np.gradient(heading) / ROUTE_DS)


def _riders(rng: np.random.Generator, cfg: TrafficSimConfig, users: PathUsers,
            start: float, duration: float) -> list[tuple[Vehicle, Route]]:
    """The road users of ``users`` over the recording from ``start`` (s) lasting ``duration``
    s, with their routes. They keep their headway to each other, not to the motor vehicles
    (which pass cyclists in the same lane)."""
    warm = _warm_up(users.routes, users.speed)
    n = int(rng.poisson(users.per_minute * (duration + warm) / 60.0))
    vc = VEHICLE_CLASSES[users.kind]
    cache: _ConflictCache = {}
    riders: list[Vehicle] = []
    for t0 in np.sort(rng.uniform(start - warm, start + duration, n)):
        r = int(rng.integers(len(users.routes)))
        v_cruise = rng.uniform(*users.speed)
        v = speed_profile(users.routes[r], v_cruise, 0.7 * v_cruise, cfg)
        f = Vehicle(users.kind, rng.normal(*vc.length), rng.normal(*vc.width), r, float(t0), v,
                    _cumtrapz(1.0 / v, ROUTE_DS))
        _enter(f, riders, users.routes, cache, cfg.headway)
    return [(f, users.routes[f.route]) for f in riders]
