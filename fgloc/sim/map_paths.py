"""The ways of a real Lanelet2 map that are not for motor vehicles, as routes for pedestrians,
cyclists and trams (``fgloc simulate --map``, ``[real_map] pedestrians_per_minute``,
``path_cyclists_per_minute`` and ``trams_per_minute``).

A pedestrian way is a lanelet of subtype ``crosswalk`` or ``walkway``, or one tagged
``participant:pedestrian=yes``; a cycle way one of subtype ``bicycle_lane`` or tagged
``participant:bicycle=yes``; a rail one of subtype ``rail``. Only the lanelets the map's
traffic rules close to motor vehicles (``LaneletMap.ignored``) are taken. Pedestrians walk a
way in both directions; cyclists and trams use it in both unless it is tagged
``one_way=yes``. Ways that continue one another (the end of one centre line within
:data:`JOIN_DISTANCE` m of the start of the next, turning by less than
:data:`JOIN_ANGLE_DEG`) are chained into one route, so users do not appear and vanish where
two lanelets of a footpath or a rail meet.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgloc.geo import wrap_angle
from fgloc.scenario import Lanelet, LaneletMap
from fgloc.sim.config import SimConfig
from fgloc.sim.traffic import (
    BICYCLE,
    PEDESTRIAN,
    ROUTE_DS,
    TRAM,
    PathUsers,
    Route,
    polyline_route,
)

#: largest gap (m) between the end of one way's centre line and the start of the next
JOIN_DISTANCE = 1.0
#: largest turn (deg) from one way into the next it continues
JOIN_ANGLE_DEG = 60.0
#: centre line samples per metre of a way
SAMPLES_PER_METRE = 2.0

PEDESTRIAN_SUBTYPES = ("crosswalk", "walkway")
CYCLE_SUBTYPES = ("bicycle_lane",)


@dataclass(frozen=True)
class _Way:
    """One directed way: its centre line (n, 2) in L and the lanelet it comes from."""

    xy: np.ndarray
    lanelet: int

    def heading(self, end: bool) -> float:
        """Direction (rad, CCW from L's x axis) of the line's last segment (``end``) or
        first."""
        d = self.xy[-1] - self.xy[-2] if end else self.xy[1] - self.xy[0]
        return float(np.arctan2(d[1], d[0]))


def is_pedestrian_way(ll: Lanelet) -> bool:
    """Whether pedestrians walk the lanelet ``ll`` (by subtype or participant tag)."""
    return (ll.attributes.get("subtype") in PEDESTRIAN_SUBTYPES
            or ll.attributes.get("participant:pedestrian") == "yes")


def is_cycle_way(ll: Lanelet) -> bool:
    """Whether cyclists ride the lanelet ``ll`` (by subtype or participant tag)."""
    return (ll.attributes.get("subtype") in CYCLE_SUBTYPES
            or ll.attributes.get("participant:bicycle") == "yes")


def is_rail(ll: Lanelet) -> bool:
    """Whether trams run on the lanelet ``ll`` (subtype ``rail``)."""
    return ll.attributes.get("subtype") == "rail"


def _centre(ll: Lanelet) -> np.ndarray:
    """The lanelet's centre line, :data:`SAMPLES_PER_METRE` samples per metre."""
    rough = ll.centerline(50)
    length = float(np.linalg.norm(np.diff(rough, axis=0), axis=1).sum())
    return ll.centerline(max(2, int(np.ceil(length * SAMPLES_PER_METRE)) + 1))


def _directed(lanelets: list[Lanelet], both_ways: bool) -> list[_Way]:
    """Each lanelet's centre line in its direction and, where it is used both ways, reversed."""
    ways = []
    for k, ll in enumerate(lanelets):
        xy = _centre(ll)
        ways.append(_Way(xy, k))
        if both_ways or ll.attributes.get("one_way") != "yes":
            ways.append(_Way(xy[::-1].copy(), k))
    return ways


def _successor(ways: list[_Way], k: int) -> int | None:
    """The way that continues way ``k`` (another lanelet), the closest in heading, or None."""
    end, h = ways[k].xy[-1], ways[k].heading(True)
    best, best_turn = None, np.deg2rad(JOIN_ANGLE_DEG)
    for j, w in enumerate(ways):
        if w.lanelet == ways[k].lanelet or np.hypot(*(w.xy[0] - end)) > JOIN_DISTANCE:
            continue
        turn = abs(wrap_angle(w.heading(False) - h))
        if turn < best_turn:
            best, best_turn = j, turn
    return best


def way_routes(lanelets: list[Lanelet], both_ways: bool) -> list[Route]:
    """Routes along ``lanelets`` (the ways of one kind of user, in L): each maximal chain of
    directed ways (see the module docstring), sampled every ROUTE_DS m; ``both_ways``: every
    way in both directions (pedestrians), else as its ``one_way`` tag says (cyclists)."""
    ways = _directed(lanelets, both_ways)
    succ = [_successor(ways, k) for k in range(len(ways))]
    has_pred = {j for j in succ if j is not None}
    heads = [k for k in range(len(ways)) if k not in has_pred]
    seen: set[int] = set()
    routes = []
    for start in heads + list(range(len(ways))):      # then what is left: closed loops
        if start in seen:
            continue
        chain, k = [], start
        while k is not None and k not in seen:
            seen.add(k)
            chain.append(ways[k].xy if not chain else ways[k].xy[1:])
            k = succ[k]
        xy = np.vstack(chain)
        if np.linalg.norm(np.diff(xy, axis=0), axis=1).sum() >= 2 * ROUTE_DS:
            routes.append(polyline_route(xy))
    return routes


def near(lanelets: list[Lanelet], centre: np.ndarray, reach: float) -> list[Lanelet]:
    """The lanelets whose bounds come within ``reach`` m of ``centre`` (2,) in L."""
    return [ll for ll in lanelets
            if np.hypot(*(np.vstack([ll.left, ll.right])[:, :2] - centre).T).min() <= reach]


def map_users(lmap: LaneletMap, centre: np.ndarray, reach: float,
              cfg: SimConfig) -> tuple[PathUsers, ...]:
    """The pedestrians, cyclists and trams ``cfg.real_map`` asks for, on the ways of ``lmap``
    (in L) within ``reach`` m of the junction ``centre`` (2,); none when every rate is 0."""
    rm = cfg.real_map
    wanted = [(rm.pedestrians_per_minute, is_pedestrian_way, True, PEDESTRIAN,
               rm.pedestrian_speed),
              (rm.path_cyclists_per_minute, is_cycle_way, False, BICYCLE,
               cfg.traffic.cyclist_speed),
              (rm.trams_per_minute, is_rail, False, TRAM, rm.tram_speed)]
    if all(rate <= 0 for rate, *_ in wanted):
        return ()
    ways = near(lmap.ignored, centre, reach)
    return tuple(PathUsers(way_routes([w for w in ways if is_way(w)], both_ways), kind, rate,
                           speed)
                 for rate, is_way, both_ways, kind, speed in wanted if rate > 0)
