"""Traffic: routes through the lane pieces and CTRA-consistent vehicle motion along them.

A route (entry lane -> movement -> exit lane) is the concatenated lane centre line whose
curvature is smoothed over ``transition_length`` (clothoid-like ramps, so the yaw rate is
continuous) and re-integrated; vehicles follow it with a speed profile of piecewise constant
acceleration (cruise on straights, turn speed in junction turns, lateral-acceleration cap in
curves). Hence yaw is the path tangent and yawrate = v * curvature exactly.

Vehicles never overlap: each vehicle's entry time is delayed until its occupancy of every
point it shares with an earlier vehicle's route (same lane, merge or crossing) is separated
from that vehicle's occupancy by at least the headway.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from fgloc.geo import wrap_angle
from fgloc.scenario import TrackTruth
from fgloc.sim.config import TrafficSimConfig
from fgloc.sim.roads import RoadNetwork

#: route sampling (m)
ROUTE_DS = 0.25
#: route sub-sampling for conflict search (every n-th sample)
CONFLICT_STRIDE = 4
#: widest centre distance (m) at which two route points can conflict
CONFLICT_DIST = 3.2
#: lateral clearance (m) added to the half widths of two vehicles
LATERAL_MARGIN = 0.6


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
)


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
    s grid, its speed v (m/s) and the time tau (s) since entry."""

    kind: int
    length: float
    width: float
    route: int
    t0: float
    v: np.ndarray
    tau: np.ndarray


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
    """Route along the given piece indices with curvature ramps of length ``transition`` m."""
    prims = [p for i in pieces for p in net.pieces[i].prims]
    bounds = np.cumsum([0.0] + [length for length, _ in prims])
    n = int(np.ceil(bounds[-1] / ROUTE_DS))
    s = np.arange(n + 1) * ROUTE_DS
    kappa = np.array([k for _, k in prims])[
        np.clip(np.searchsorted(bounds, s, side="right") - 1, 0, len(prims) - 1)]
    win = max(1, int(round(transition / ROUTE_DS)) | 1)
    kappa = np.convolve(np.pad(kappa, win // 2, mode="edge"), np.ones(win) / win, mode="valid")
    first = net.pieces[pieces[0]]
    heading = first.heading + _cumtrapz(kappa, ROUTE_DS)
    xy = first.start + _cumtrapz(np.column_stack([np.cos(heading), np.sin(heading)]), ROUTE_DS)
    return Route(pieces, s, xy, heading, kappa)


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


def _time_at(veh: Vehicle, route: Route, s: np.ndarray) -> np.ndarray:
    """Time since entry (s) when the vehicle centre is at arc length s (clamped at the ends)."""
    return np.interp(s, route.s, veh.tau)


def _forbidden(f: Vehicle, rf: Route, lead: Vehicle, rl: Route,
               pairs: tuple[np.ndarray, np.ndarray, np.ndarray],
               headway: float) -> tuple[float, float] | None:
    """Interval of entry times of ``f`` whose occupancy would overlap ``lead``'s."""
    sf, sl, dist = pairs
    m = dist < 0.5 * (f.width + lead.width) + LATERAL_MARGIN
    if not m.any():
        return None
    sf, sl = sf[m], sl[m]
    lead_in = lead.t0 + _time_at(lead, rl, sl - lead.length / 2) - headway
    lead_out = lead.t0 + _time_at(lead, rl, sl + lead.length / 2) + headway
    lo = lead_in - _time_at(f, rf, sf + f.length / 2)
    hi = lead_out - _time_at(f, rf, sf - f.length / 2)
    return float(lo.min()), float(hi.max())


def _earliest(t: float, intervals: list[tuple[float, float]]) -> float:
    """Smallest time >= t outside every open interval."""
    for lo, hi in sorted(intervals):
        if lo < t < hi:
            t = hi
    return t


def _new_vehicle(rng: np.random.Generator, cfg: TrafficSimConfig, routes: list[Route],
                 t_nominal: float) -> Vehicle:
    kind = int(rng.choice(len(VEHICLE_CLASSES), p=np.asarray(cfg.class_mix) / sum(cfg.class_mix)))
    vc = VEHICLE_CLASSES[kind]
    lo, hi = cfg.speed_straight
    v_cruise = rng.uniform(lo, hi if vc.name != "truck" else lo + 0.6 * (hi - lo))
    r = int(rng.integers(len(routes)))
    v = speed_profile(routes[r], v_cruise, rng.uniform(*cfg.speed_turn), cfg)
    return Vehicle(kind, rng.normal(*vc.length), rng.normal(*vc.width), r, t_nominal, v,
                   _cumtrapz(1.0 / v, ROUTE_DS))


def _arrivals(rng: np.random.Generator, cfg: TrafficSimConfig, start: float, end: float,
              count: int | None) -> np.ndarray:
    """Nominal entry times: Poisson with the mean interval, or ``count`` uniform ones."""
    if count is not None:
        return np.sort(rng.uniform(start, end, count))
    n_max = int((end - start) / cfg.arrival_interval * 2 + 20)
    t = start + np.cumsum(rng.exponential(cfg.arrival_interval, n_max))
    return t[t < end]


def _states(veh: Vehicle, route: Route, times: np.ndarray) -> np.ndarray:
    """(n, 6) [t, x, y, yaw, v, yawrate] at the given times within the vehicle's life."""
    t = times[(times >= veh.t0) & (times <= veh.t0 + veh.tau[-1])]
    s = np.interp(t - veh.t0, veh.tau, route.s)
    v = np.interp(s, route.s, veh.v)
    x = np.interp(s, route.s, route.xy[:, 0])
    y = np.interp(s, route.s, route.xy[:, 1])
    yaw = wrap_angle(np.interp(s, route.s, route.heading))
    yawrate = v * np.interp(s, route.s, route.kappa)
    return np.column_stack([t, x, y, np.atleast_1d(yaw), v, yawrate])


def simulate_traffic(rng: np.random.Generator, cfg: TrafficSimConfig, net: RoadNetwork,
                     times: np.ndarray, count: int | None) -> Traffic:
    """Vehicles on random routes, sampled at ``times`` (s); tracks with < 2 samples dropped.

    count: vehicles generated in total (None: Poisson arrivals every ``arrival_interval`` s on
    average). Arrivals start before times[0] so the scene is already filled at the start.
    """
    routes = [build_route(net, r, cfg.transition_length) for r in net.routes()]
    v_mean = float(np.mean(cfg.speed_straight))
    warm = 0.8 * float(np.median([r.s[-1] for r in routes])) / v_mean
    duration = float(times[-1] - times[0]) if len(times) else 0.0
    cache: dict[tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    vehicles: list[Vehicle] = []
    for t_nom in _arrivals(rng, cfg, times[0] - warm, times[0] + duration, count):
        f = _new_vehicle(rng, cfg, routes, float(t_nom))
        intervals = []
        for lead in vehicles:
            key = (f.route, lead.route)
            if key not in cache:
                cache[key] = _conflicts(routes[f.route], routes[lead.route])
            iv = _forbidden(f, routes[f.route], lead, routes[lead.route], cache[key],
                            cfg.headway)
            if iv is not None:
                intervals.append(iv)
        f.t0 = _earliest(f.t0, intervals)
        vehicles.append(f)
    tracks, kinds = [], []
    for veh in vehicles:
        states = _states(veh, routes[veh.route], times)
        if len(states) >= 2:
            tracks.append(TrackTruth(len(tracks), veh.length, veh.width, states))
            kinds.append(veh.kind)
    return Traffic(tracks, np.asarray(kinds, dtype=np.int64))
