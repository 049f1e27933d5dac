"""Which tracks are motor vehicles.

The lanes fgloc registers tracks to are where motor vehicles drive. Other road users the radar
tracks do not drive there: cyclists ride at the lane's edge or on a bicycle lane beside it,
pedestrians walk on sidewalks and crosswalks. Registered to the nearest lane centre they pull
the pose across the lane: simulated cyclists 1.4 m right of the lane centres, 4 per minute,
took the mean 2D error over the three synthetic layouts (seeds 1-3) from 0.114 to 0.179 m
(filter-sicp) and from 0.079 to 0.191 m (smoother-sicp); without their tracks 0.122 and
0.104 m (docs/experiments.md).

A cyclist's track is short and narrow where the radar saw enough of it; a motor vehicle's is
neither (cars are 3.5-5 m long and 1.6-2 m wide). A track counts as a motor vehicle unless the
shorter of its contour's median length and width (over its steps) is below
``min_vehicle_width``, or the longer is below ``min_vehicle_length`` while the shorter is
below ``wide_vehicle_width`` (:class:`fgloc.tracking.config.TrackingConfig`). A sparsely
seen cyclist keeps a contour near the car-sized prior and passes as a vehicle: the rule drops
what it can tell (79 % of the cyclists' tracked detections over the robustness settings with
cyclists) and few vehicles' tracks (5 of 1003 there, 0.04 % of their detections).

A pedestrian is rarely seen well enough to shrink its contour (on the example map's junctions
with 10 pedestrians per minute on its crosswalks and walkways, their kept tracks had the
prior's 4.4 x 1.9 m), but it walks: a track whose speed stays below ``walking_speed`` for 90 %
of its steps is not a motor vehicle either (static returns are not tracked: a vehicle waiting
at a stop line leaves no track there, its track is its moving part; the rows at which a
re-linked track stood do not count).

A tram is as long, wide and fast as a truck, but it runs on rails: where the map has them
(lanelets no motor vehicle may drive: rails, bicycle lanes, walkways, crosswalks; the
``ignored`` ones of :class:`fgloc.scenario.LaneletMap`), a track that keeps at least
``off_lane_margin`` m nearer one of those than any drivable lanelet (the median over its steps
of the difference of its two distances) is not a motor vehicle either. A distance is to the
nearest part of a lanelet's area whose axis lies along the track's heading (within
:data:`ALONG_DEG`, either way): a car on a lane is 0 m from the drivable area wherever it
drives on it, a crosswalk across the road is not along the cars crossing it, a rail laid in a
lane shares that lane's area (a tram there counts as a vehicle and drives the lane's line),
and a tram crossing the junction's lanes on its rail is far from every lane along it. The
tracks are in the coarse frame: a coarse pose a lane off would put a lane's vehicles on the
sidewalk or the rail bed beside it; when the rule would take more than :data:`DOUBT_SHARE` of
the detections of the tracks it judges, it doubts the placement and drops none (a warning says
so).

Nor is a track that keeps more than ``off_road_margin`` m from every drivable lanelet's area,
whatever the direction (the median over its steps of its centre's distance): a multipath
ghost, which a roadside radar sees mirrored behind a facade or a barrier beside the road (on
the independent generator's ghosts setting, junctions 1-6 seeds 1-2, 33 of the 39 ghost
tracks lay 7.6-42 m off the drivable area, the other 6 on or beside a road, and every
vehicle's track within 1.0 m with the true pose), or a vehicle on a road the map lacks (a car
park, a driveway), which has no lane to register to.
Nor is a track whose centre lies behind a building of the ALS, as seen from the sensor, at
more than ``hidden_share`` of its steps (:mod:`fgloc.tracking.sightlines`): the radar has no
line of sight there, so its returns bounced off a facade; this catches the ghosts a facade
mirrors onto another road, which lie on the road.
The doubt guard above counts the three rules' detections together.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from fgloc.geo import wrap_angle
from fgloc.scenario import Lanelet, LaneletMap, lanelets_near
from fgloc.tracking.config import TrackingConfig
from fgloc.tracking.sightlines import Buildings
from fgloc.tracks import YAW, Track, V, X, Y, contour_length_width

log = logging.getLogger(__name__)

#: Spacing (m) of the samples of a lanelet's area (along and across it): a point inside reads
#: at most half the diagonal, 0.35 m, from the area.
AREA_STEP = 0.5
#: A lanelet's area counts for a track where its axis lies within this (deg, either direction)
#: of the track's heading (up to ALONG_DEG + SECTOR_DEG, see :class:`DirectedAreas`).
ALONG_DEG = 30.0
#: Width (deg) of the heading sectors of :class:`DirectedAreas`.
SECTOR_DEG = 15.0
#: The off-lane rule doubts the placement when it would drop more than this share of the
#: detections of the tracks it judges (those the size and speed rules kept).
DOUBT_SHARE = 0.5


def is_motor_vehicle(track: Track, cfg: TrackingConfig) -> bool:
    """Whether ``track``'s contour (median length and width over its steps, m) has a shorter
    side of at least ``cfg.min_vehicle_width`` and either a longer one of at least
    ``cfg.min_vehicle_length`` or a shorter one of at least ``cfg.wide_vehicle_width``, and
    its speed (90th percentile of |v| over its steps but those it stood at,
    ``Track.standing``, m/s) reaches ``cfg.walking_speed``. The
    footprint's sides, whichever axis the tracker took for the heading (a car whose contour
    came out turned by 90 deg, 2.7 m long and 3.2 m wide, is a car); and a wide one is a
    vehicle however short (a car seen end-on, 2.9 m long and 2.5 m wide)."""
    moving = np.ones(len(track), dtype=bool)
    moving[track.standing_steps()] = False
    if np.quantile(np.abs(track.states[moving, V]), 0.9) < cfg.walking_speed:
        return False
    length, width = contour_length_width(track.states)
    short, long = sorted((float(np.median(length)), float(np.median(width))))
    return short >= cfg.min_vehicle_width and (long >= cfg.min_vehicle_length
                                               or short >= cfg.wide_vehicle_width)


def area_samples(lanelets: list[Lanelet], step: float = AREA_STEP
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Points (n, 2) about ``step`` m apart along and across every lanelet of ``lanelets``,
    covering its area (bounds included), in the lanelets' frame, and (n,) the lanelet's axis
    there (rad in [0, pi): the direction of the line through the point, either way)."""
    xy, axis = [np.zeros((0, 2))], [np.zeros(0)]
    for ll in lanelets:
        n = ll.samples(step)
        for share in np.linspace(0.0, 1.0, max(2, int(np.ceil(ll.width() / step)) + 1)):
            line = ll.line_at(share, n)
            d = np.gradient(line, axis=0)
            xy.append(line)
            axis.append(np.arctan2(d[:, 1], d[:, 0]) % np.pi)
    return np.vstack(xy), np.concatenate(axis)


@dataclass(frozen=True)
class DirectedAreas:
    """Lanelet areas by direction: one KD-tree of :func:`area_samples` per heading sector
    (``SECTOR_DEG`` wide over [0, 180) deg), holding the samples whose axis lies within
    ``ALONG_DEG + SECTOR_DEG / 2`` of the sector's centre (None where none does)."""

    trees: tuple[cKDTree | None, ...]

    @classmethod
    def of(cls, xy: np.ndarray, axis: np.ndarray) -> DirectedAreas:
        """The sector trees of area samples ``xy`` (n, 2) with their axes ``axis`` (n,) rad
        (:func:`area_samples`)."""
        sector = np.deg2rad(SECTOR_DEG)
        reach = np.deg2rad(ALONG_DEG) + sector / 2
        trees = []
        for centre in (np.arange(round(180.0 / SECTOR_DEG)) + 0.5) * sector:
            off = np.abs(wrap_angle(2.0 * (axis - centre))) / 2.0     # axes: modulo pi
            near = off <= reach
            trees.append(cKDTree(xy[near]) if near.any() else None)
        return cls(tuple(trees))

    def distance(self, xy: np.ndarray, heading: np.ndarray) -> np.ndarray:
        """(n,) distance (m) of each point (n, 2) to the nearest area sample whose axis lies
        along ``heading`` (n,) rad (within ALONG_DEG to ALONG_DEG + SECTOR_DEG); inf where
        there is none."""
        sector = (np.asarray(heading) % np.pi // np.deg2rad(SECTOR_DEG)).astype(int)
        sector = np.minimum(sector, len(self.trees) - 1)
        out = np.full(len(xy), np.inf)
        for k in np.unique(sector):
            tree = self.trees[k]
            if tree is not None:
                rows = sector == k
                out[rows] = tree.query(xy[rows])[0]
        return out


@dataclass(frozen=True)
class MapWays:
    """The area of the lanelets a motor vehicle may drive, whatever the direction (``road``),
    and by direction, with the other ways of the map by direction (``drivable``, ``other``:
    None both on a map without other ways, where only :func:`is_off_road` has a use) (frame
    L)."""

    road: cKDTree
    drivable: DirectedAreas | None
    other: DirectedAreas | None

    @classmethod
    def of(cls, lanelet_map: LaneletMap, centre: np.ndarray | None = None,
           reach: float = np.inf) -> MapWays | None:
        """The ways of ``lanelet_map``: its drivable lanelets and its ``ignored`` ones whose
        bounding box comes within ``reach`` m of ``centre`` (2,) in L (every lanelet without
        ``centre``); None when no drivable lanelet does (nothing to tell a track's way by)."""
        def near(lanelets: list[Lanelet]) -> list[Lanelet]:
            return lanelets if centre is None else lanelets_near(lanelets, centre, reach)
        drivable, other = near(lanelet_map.lanelets), near(lanelet_map.ignored)
        if not drivable:
            return None
        xy, axis = area_samples(drivable)
        if not other:
            return cls(cKDTree(xy), None, None)
        return cls(cKDTree(xy), DirectedAreas.of(xy, axis), DirectedAreas.of(*area_samples(other)))

    def nearer_other(self, xy: np.ndarray, heading: np.ndarray) -> np.ndarray:
        """(n,) how much nearer (m) each point (n, 2) heading ``heading`` (n,) rad lies to
        another way's area than to the drivable area, both along the heading: the distance to
        the drivable area minus that to the other ways' (-inf where no other way runs along
        the heading, +inf where only other ways do)."""
        if self.drivable is None or self.other is None:
            return np.full(len(xy), -np.inf)
        xy, heading = np.asarray(xy, dtype=float), np.asarray(heading, dtype=float)
        other = self.other.distance(xy, heading)
        out = np.full(len(xy), -np.inf)
        near = np.isfinite(other)
        out[near] = self.drivable.distance(xy[near], heading[near]) - other[near]
        return out

    def off_road(self, xy: np.ndarray) -> np.ndarray:
        """(n,) distance (m) of each point (n, 2) from the drivable area, whatever its
        direction (0 inside, up to the samples' half diagonal, 0.35 m)."""
        return self.road.query(xy)[0]


def is_off_lane(track: Track, ways: MapWays, cfg: TrackingConfig) -> bool:
    """Whether ``track`` keeps at least ``cfg.off_lane_margin`` m nearer a way no motor
    vehicle may use than any drivable lanelet, both along its heading (median over its steps;
    its centres in the frame of ``ways``)."""
    nearer = ways.nearer_other(track.states[:, [X, Y]], track.states[:, YAW])
    return bool(np.median(nearer) >= cfg.off_lane_margin)


def is_off_road(track: Track, ways: MapWays, cfg: TrackingConfig) -> bool:
    """Whether ``track``'s centre keeps more than ``cfg.off_road_margin`` m from every drivable
    lanelet's area (median over its steps; its centres in the frame of ``ways``)."""
    return bool(np.median(ways.off_road(track.states[:, [X, Y]])) > cfg.off_road_margin)


#: at most this many steps of a track are tested for a line of sight (evenly spaced)
SIGHT_STEPS = 25


def is_hidden(track: Track, sight: Sight, cfg: TrackingConfig) -> bool:
    """Whether ``track``'s centre lies behind a building, as seen from the sensor, at more
    than ``cfg.hidden_share`` of its steps (at most :data:`SIGHT_STEPS` of them tested;
    centres in the frame of ``sight``)."""
    k = np.unique(np.linspace(0, len(track.states) - 1, SIGHT_STEPS).round().astype(int))
    hidden = sight.buildings.hidden(sight.sensor, track.states[k][:, [X, Y]])
    return bool(hidden.mean() > cfg.hidden_share)


@dataclass
class Sight:
    """The sensor's position ``sensor`` (3,) m and the buildings that block its view, in the
    frame the tracks are placed in (L as the placement puts it)."""

    sensor: np.ndarray
    buildings: Buildings


@dataclass
class RoadUsers:
    """Tracks split by :func:`split_road_users`, each list in input order.

    vehicles: the motor vehicles'; others: the rest; off_lane: ids among ``others`` that the
    map's other ways told (:func:`is_off_lane`); off_road: those off every drivable lanelet
    (:func:`is_off_road`, and not off lane); hidden: those behind a building (:func:`is_hidden`,
    and neither of the others); doubted: ids the three rules would have told but that were
    kept, the placement doubted (:data:`DOUBT_SHARE`)."""

    vehicles: list[Track]
    others: list[Track]
    off_lane: list[int] = field(default_factory=list)
    off_road: list[int] = field(default_factory=list)
    hidden: list[int] = field(default_factory=list)
    doubted: list[int] = field(default_factory=list)


def split_road_users(tracks: list[Track], cfg: TrackingConfig,
                     ways: MapWays | None = None, sight: Sight | None = None) -> RoadUsers:
    """The motor vehicles' tracks and the others: by size and speed (:func:`is_motor_vehicle`),
    then, with ``ways``, by where they run (:func:`is_off_lane`, :func:`is_off_road`) and, with
    ``sight``, whether the sensor can see them (:func:`is_hidden`), unless the three would drop
    more than :data:`DOUBT_SHARE` of the detections of the tracks left."""
    vehicle = [is_motor_vehicle(tr, cfg) for tr in tracks]
    lane = [v and ways is not None and is_off_lane(tr, ways, cfg)
            for tr, v in zip(tracks, vehicle)]
    road = [v and not o and ways is not None and is_off_road(tr, ways, cfg)
            for tr, v, o in zip(tracks, vehicle, lane)]
    hidden = [v and not o and not r and sight is not None and is_hidden(tr, sight, cfg)
              for tr, v, o, r in zip(tracks, vehicle, lane, road)]
    off = [a or b or c for a, b, c in zip(lane, road, hidden)]
    judged = sum(len(tr.det_index) for tr, v in zip(tracks, vehicle) if v)
    off_dets = sum(len(tr.det_index) for tr, o in zip(tracks, off) if o)
    off_ids = [tr.id for tr, o in zip(tracks, off) if o]
    doubted = off_dets > DOUBT_SHARE * judged
    if doubted:
        log.warning("%d of %d motor-vehicle tracks (%d of %d detections) run off every "
                    "drivable lanelet or behind buildings: the coarse placement is doubted "
                    "and they are kept",
                    len(off_ids), sum(vehicle), off_dets, judged)
    keep = [v and (doubted or not o) for v, o in zip(vehicle, off)]

    def ids(told: list[bool]) -> list[int]:
        return [] if doubted else [tr.id for tr, t in zip(tracks, told) if t]
    return RoadUsers([tr for tr, k in zip(tracks, keep) if k],
                     [tr for tr, k in zip(tracks, keep) if not k],
                     off_lane=ids(lane), off_road=ids(road), hidden=ids(hidden),
                     doubted=off_ids if doubted else [])
