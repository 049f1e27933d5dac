"""simulate_on_map(): a scenario with ground truth on any real Lanelet2 map.

The sensor stands on a mast beside a junction of the map's routing graph (the one nearest to
``site``, else a random one of the largest; on a map without one, beside a road), vehicles
drive the junction's routes (each movement with its lead-in and lead-out along the routing
graph per driving direction: two-way lanelets both ways, on their centre line or keeping
right, ``config.real_map``), the ALS is
made from the drivable lanelets' polygons (road surface, class 11), the rest of the ground
(class 2; walkways raised by a curb height), the map's buildings (class 6) and trees in its
vegetation areas (class 5) over a gently sloped terrain. The radar model, traffic, ALS
synthesis and sensor distributions are the synthetic simulator's (:mod:`fgloc.sim`).

The scenario's map is the real map cropped around the junction (``crop_radius``), its
``ele`` tags removed (the heights come from the simulated ALS when the scenario is read back);
:attr:`MapSimulation.map_osm` holds that text and :attr:`MapSimulation.notices` the licence
files found beside the map (``LICENSE*``), to be written next to it.
"""

from __future__ import annotations

import dataclasses
import logging
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fgloc.geo import LocalFrame, natural_utm_zone, transformer, utm_zone, wrap_angle
from fgloc.io.lanelet_map import WGS84, crop_lanelet_osm, read_lanelet_map
from fgloc.map import points_in_polygon
from fgloc.progress import quiet
from fgloc.scenario import BUILDING_CLASS, Lanelet, LaneletMap, Scenario
from fgloc.sim.als import GROUND, synthesize_als
from fgloc.sim.config import SimConfig
from fgloc.sim.core import SimResult, drive_and_observe
from fgloc.sim.map_paths import map_users
from fgloc.sim.mounting import Mounting
from fgloc.sim.real_roads import (
    DrivableArea,
    Junction,
    PathSmoothing,
    Roof,
    build_map_network,
    directed_lanelets,
    every_metre,
    find_junctions,
    junction_routes,
    lanelet2_centre_lines,
    map_scenery,
    road_site,
)
from fgloc.sim.roads import RoadArea, RoadNetwork
from fgloc.sim.scenery import place_scenery
from fgloc.sim.terrain import Terrain

_STAGES = ("junction", "sensor", "site", "scenery", "als", "traffic", "radar")
#: a --site farther than this (m) from every junction is an error
SITE_RADIUS = 500.0
#: height (m) of walkways above the ground around them
SIDEWALK_RAISE = 0.12
#: mast places compared by the mapped road they see, and the share of the radar's max_range
#: counted as seen
MAST_CANDIDATES = 12
VIEW_RANGE_FRACTION = 0.75
#: random road sites tried (a map without junctions, no --site) before giving up on a mast
ROAD_SITE_ATTEMPTS = 5
#: the radar may turn away from the junction until the junction is this far (deg) inside the
#: field of view's edge ...
JUNCTION_IN_VIEW_MARGIN_DEG = 15.0
#: ... and turns when that sees at least this many times the mapped road aiming at it does
TURN_GAIN = 2.0


@dataclass
class MapSimulation:
    """A simulated scenario on a real map plus what its directory needs besides: the cropped
    map's OSM text and the licence notices (file name -> text). junction: the site's centre
    (2,) m in L; site: "junction", or "road" on a map (or near a ``site``) without one."""

    result: SimResult
    map_osm: str
    junction: np.ndarray
    notices: dict[str, str] = field(default_factory=dict)
    site: str = "junction"

    @property
    def scenario(self) -> Scenario:
        return self.result.scenario


def map_crs(lat: float, lon: float, preferred: str) -> str:
    """``preferred`` when it is the UTM zone of (lat, lon), else WGS 84 / UTM of that zone."""
    zone = natural_utm_zone(lon)
    if utm_zone(preferred) == zone:
        return preferred
    return f"EPSG:{(32600 if lat >= 0 else 32700) + zone}"


def map_junctions(map_path: str | Path, crs: str = "EPSG:25832") -> tuple[list[Junction], str]:
    """Junctions of a map (:func:`find_junctions`) with their centres as (lat, lon) in
    ``Junction.centre``, and the CRS used; for choosing sites."""
    lmap, frame, crs = _read_map(map_path, crs)
    return _junctions_in(lmap, frame), crs


def _junctions_in(lmap: LaneletMap, frame: LocalFrame) -> list[Junction]:
    """:func:`find_junctions` of a map read in ``frame``, centres as (lat, lon)."""
    out = []
    for j in find_junctions(directed_lanelets(lmap).map):
        w = frame.to_world(j.centre[None])[0]
        jlon, jlat = transformer(frame.crs, WGS84).transform(w[0], w[1])
        out.append(Junction(np.array([jlat, jlon]), j.movements))
    return out


def _read_map(map_path: str | Path, crs: str) -> tuple[LaneletMap, LocalFrame, str]:
    """The map read in a local frame around its first node, that frame and the CRS used
    (:func:`map_crs`)."""
    lat, lon = _first_latlon(Path(map_path).read_text(encoding="utf-8"))
    crs = map_crs(lat, lon, crs)
    e, n = transformer(WGS84, crs).transform(lon, lat)
    frame = LocalFrame.around(e, n, 0.0, crs)
    return read_lanelet_map(map_path, crs, frame), frame, crs


def _road_point(lmap: LaneletMap, frame: LocalFrame, site: tuple[float, float] | None,
                rng: np.random.Generator) -> tuple[float, float] | None:
    """(lat, lon) of a road site on a map without junction there: the point of the drivable
    lanelets' centre lines nearest to ``site`` (None beyond :data:`SITE_RADIUS`), or without a
    site a random one of them (from ``rng``; every metre of road alike, so a short lanelet,
    a stub cut off by its neighbours, is seldom drawn)."""
    to_ll = transformer(frame.crs, WGS84)
    pts = np.vstack([every_metre(ll.centerline(20)) for ll in lmap.lanelets])
    if site is None:
        xy = pts[int(rng.integers(len(pts)))]
    else:
        e, n = transformer(WGS84, frame.crs).transform(site[1], site[0])
        at = np.array([e, n]) - np.asarray(frame.origin[:2])
        d = np.hypot(*(pts - at).T)
        if d.min() > SITE_RADIUS:
            return None
        xy = pts[int(np.argmin(d))]
    w = frame.to_world(xy[None])[0]
    lon, lat = to_ll.transform(w[0], w[1])
    return float(lat), float(lon)


def _first_latlon(text: str) -> tuple[float, float]:
    import re

    m = re.search(r"""lat=['"]([-\d.]+)['"]\s+lon=['"]([-\d.]+)['"]""", text)
    if m is None:
        raise ValueError("the map has no node with lat/lon")
    return float(m.group(1)), float(m.group(2))


def _read_text_map(text: str, crs: str, frame: LocalFrame) -> LaneletMap:
    """The map of the OSM ``text`` (a crop of the map read before: its warnings, given then,
    are not repeated)."""
    with tempfile.TemporaryDirectory() as tmp, quiet("fgloc.io.lanelet_map", logging.ERROR):
        path = Path(tmp) / "map.osm"
        path.write_text(text, encoding="utf-8")
        return read_lanelet_map(path, crs, frame)


def _aim(xy: np.ndarray, aim: float, road: np.ndarray, cfg: SimConfig) -> tuple[float, int]:
    """Yaw (rad) of a radar at ``xy`` (2,) that looks towards the junction (``aim``, rad) and
    how many of the road samples ``road`` (n, 2) (one per metre) it sees (inside the
    horizontal field of view, within ``VIEW_RANGE_FRACTION`` x ``max_range``). The junction
    stays ``JUNCTION_IN_VIEW_MARGIN_DEG`` inside the view; the radar turns (steps of 5 deg,
    the most road, the least turn on a tie) only when that sees ``TURN_GAIN`` times the road
    the aim does: a junction at the map's edge, where the aim looks at unmapped land."""
    half = np.deg2rad(cfg.radar.hfov_deg) / 2.0
    limit = max(0.0, cfg.radar.hfov_deg / 2.0 - JUNCTION_IN_VIEW_MARGIN_DEG)
    turns = np.deg2rad(np.arange(-np.floor(limit / 5.0), np.floor(limit / 5.0) + 1) * 5.0)
    rel = road - xy
    near = np.hypot(rel[:, 0], rel[:, 1]) <= VIEW_RANGE_FRACTION * cfg.radar.max_range
    bearing = np.arctan2(rel[near, 1], rel[near, 0])
    seen = (np.abs(wrap_angle(bearing[None, :] - aim - turns[:, None])) <= half).sum(axis=1)
    zero = int(np.argmin(np.abs(turns)))
    best = int(max(range(len(turns)), key=lambda k: (seen[k], -abs(turns[k]))))
    k = best if seen[best] >= TURN_GAIN * seen[zero] else zero
    return float(aim + turns[k]), int(seen[k])


def _place_mast(rng: np.random.Generator, cfg: SimConfig, net: RoadNetwork, area: RoadArea,
                lmap: LaneletMap, target: np.ndarray) -> Mounting:
    """Mast ``setback`` m off a road edge ``junction_distance`` m from the junction centre
    ``target``, clear of the lanes, the drivable lanelets and the map's buildings, looking at
    the junction (yaw jitter, height, pitch and roll as the synthetic simulator's).

    Of up to MAST_CANDIDATES such places the one that sees the most mapped road is taken (the
    drivable lanelets' centre lines, sampled every metre, inside the radar's horizontal field of
    view and within ``VIEW_RANGE_FRACTION`` x ``max_range``), as an installer would aim the
    radar at the traffic: on a real map a junction near the map's edge otherwise gets a radar
    staring at the few metres of road the map has beyond it. Where every such place aims at
    unmapped land, the radar turns from the junction towards the road (:func:`_aim`)."""
    s = cfg.sensor
    edge, normal = net.curb_line(1.0)
    dist = np.linalg.norm(edge - target, axis=1)
    blocked = [ll.polygon() for ll in lmap.lanelets]
    blocked += [a.outline for a in lmap.areas if a.subtype == "building"]
    road = np.vstack([every_metre(ll.centerline(50)) for ll in lmap.lanelets])
    places: list[tuple[np.ndarray, float, int]] = []
    for _ in range(400):
        cand = np.flatnonzero(np.abs(dist - rng.uniform(*s.junction_distance)) < 2.0)
        if not len(cand):
            continue
        i = int(rng.choice(cand))
        xy = edge[i] + rng.uniform(*s.setback) * normal[i]
        if area.clearance(xy[None])[0] < 0.9 * s.setback[0]:
            continue
        if any(points_in_polygon(xy[None], poly, 0.5)[0] for poly in blocked):
            continue
        look = target - xy
        yaw, seen = _aim(xy, float(np.arctan2(look[1], look[0])), road, cfg)
        places.append((xy, yaw, seen))
        if len(places) == MAST_CANDIDATES:
            break
    if not places:
        raise RuntimeError(
            f"no roadside position for the sensor {s.junction_distance[0]:g}-"
            f"{s.junction_distance[1]:g} m from the site (a road edge there clear of the "
            "lanelets and buildings); give --site LAT,LON near another junction or road, or "
            "another --seed")
    xy, yaw, _ = max(places, key=lambda p: p[2])
    yaw += np.deg2rad(rng.uniform(-1, 1) * s.yaw_jitter_deg)
    return Mounting(xy, float(rng.uniform(*s.mast_height)), float(wrap_angle(yaw)),
                    float(np.deg2rad(rng.uniform(*s.pitch_deg))),
                    float(np.deg2rad(rng.uniform(-1, 1) * s.roll_deg)))


def _with_heights(lmap: LaneletMap, terrain: Terrain) -> LaneletMap:
    """The map with every bound's z on the simulated road surface."""
    def lift(ll: Lanelet) -> Lanelet:
        left, right = ll.left.copy(), ll.right.copy()
        left[:, 2], right[:, 2] = terrain.road(left[:, :2]), terrain.road(right[:, :2])
        return dataclasses.replace(ll, left=left, right=right)
    return dataclasses.replace(lmap, lanelets=[lift(ll) for ll in lmap.lanelets],
                               ignored=[lift(ll) for ll in lmap.ignored])


def _sidewalks_and_roofs(als_xyz: np.ndarray, cls: np.ndarray, lmap: LaneletMap,
                         roofs: list[Roof], terrain: Terrain) -> None:
    """In place: ground points on walkways (lanelets and areas) raised by SIDEWALK_RAISE;
    ground points inside a building's outline on its flat roof (class 6)."""
    walks = [ll.polygon() for ll in lmap.ignored if ll.attributes.get("subtype") == "walkway"]
    walks += [a.outline for a in lmap.areas if a.subtype == "walkway"]
    xy = als_xyz[:, :2].astype(float)
    for poly, roof in [*((w, None) for w in walks), *((r.outline, r) for r in roofs)]:
        lo, hi = poly.min(axis=0), poly.max(axis=0)
        box = np.flatnonzero(np.all((xy >= lo) & (xy <= hi), axis=1) & (cls == GROUND))
        hit = box[points_in_polygon(xy[box], poly)]
        if roof is None:
            als_xyz[hit, 2] += SIDEWALK_RAISE
        else:
            als_xyz[hit, 2] = terrain.ground(poly.mean(axis=0)) + roof.height
            cls[hit] = BUILDING_CLASS


@dataclass
class _Layout:
    """Where a simulated site stands (:func:`_site_layout`): the map crop's OSM text, the
    junction frame (the site's centre at ground height ``centre_h``, m), the site, the road
    network driven there and the radar's mounting (both in that frame)."""

    text: str
    frame0: LocalFrame
    centre_h: float
    junction: Junction
    net: RoadNetwork
    mount: Mounting


def _site_layout(map_path: Path, at: tuple[float, float], kind: str, crs: str,
                 crop_radius: float, route_reach: float, licensed: bool, cfg: SimConfig,
                 site_rng: np.random.Generator, sensor_rng: np.random.Generator) -> _Layout:
    """The crop of the map ``crop_radius`` m around ``at`` (lat, lon; its notice names the
    LICENSE files when ``licensed``), the ``kind`` of site there ("junction" or "road"), its
    routes (``route_reach`` m before and after), their road network and the mast beside it.
    Raises RuntimeError when the site falls apart in the crop or has no mast place."""
    jlat, jlon = at
    notice = ("Crop of " + map_path.name + f" ({crop_radius:g} m around lat {jlat:.6f}, lon "
              f"{jlon:.6f}; ele tags removed) written by the fgloc map simulator; " + (
                  "see the LICENSE files beside this map for its copyright and licence."
                  if licensed else "the original map's copyright and licence apply."))
    text = crop_lanelet_osm(map_path, jlat, jlon, crop_radius, drop_ele=True)
    text = text.replace("?>", f"?>\n<!-- {notice} -->", 1)

    # junction frame: the junction centre at ground height; the final frame follows the mast
    je, jn = transformer(WGS84, crs).transform(jlon, jlat)
    centre_h = site_rng.uniform(*cfg.site.ground_height)
    frame0 = LocalFrame.around(je, jn, centre_h, crs)
    lmap0 = _read_text_map(text, crs, frame0)
    directed_all = directed_lanelets(lmap0)
    directed = directed_all.map
    centre0 = np.array([je, jn]) - np.asarray(frame0.origin[:2])
    junction = road_site(directed, centre0) if kind == "road" else next(
        (j for j in find_junctions(directed) if np.linalg.norm(j.centre - centre0) < 30.0), None)
    if junction is None:
        raise RuntimeError(f"the {kind} site at lat {jlat:.6f}, lon {jlon:.6f} fell apart in the "
                           "crop")
    by_id = {ll.id: ll for ll in directed.lanelets}
    routes = [[by_id[i] for i in r] for r in junction_routes(directed, junction, route_reach)]
    rm = cfg.real_map
    net = build_map_network(lmap0, routes, junction.centre, cfg.als.extent, rm.two_way_traffic,
                            PathSmoothing(rm.path_smoothing, rm.path_half_window,
                                          rm.path_spline_length),
                            lanelet2_centre_lines(directed_all) if rm.centre_line == "lanelet2"
                            else None)
    mount = _place_mast(sensor_rng, cfg, net, RoadArea(net), lmap0, junction.centre)
    return _Layout(text, frame0, centre_h, junction, net, mount)


def simulate_on_map(map_path: str | Path, seed: int, *, site: tuple[float, float] | None = None,
                    duration: float = 60.0, vehicles: int | None = None,
                    config: SimConfig | None = None, crop_radius: float = 300.0,
                    route_reach: float = 150.0) -> MapSimulation:
    """Simulate a recording at a junction of the Lanelet2 map ``map_path``.

    site: (lat, lon) near which the junction is taken (the nearest one, within
    :data:`SITE_RADIUS` m); None: a random one (from ``seed``) of those with the most
    movements. Where the map has no junction (a race track, a campus road), or none within
    :data:`SITE_RADIUS` m of ``site``, the sensor watches a road instead: the point of the
    drivable lanelets nearest to ``site`` (none within :data:`SITE_RADIUS`: ValueError), or a
    random point of their centre lines, whose lanelets there are driven along the routing
    graph (:func:`fgloc.sim.real_roads.road_site`). The world CRS is ``config.site.crs`` when
    the map lies in its UTM zone, else WGS 84 / UTM of the map's zone. ``crop_radius`` (m): the
    part of the map kept around the junction; ``route_reach`` (m): lead-in and lead-out of every
    route. Deterministic in (map, seed, site, duration, vehicles, config).
    """
    if duration <= 0:
        raise ValueError(f"duration must be positive, got {duration}")
    cfg = config or SimConfig()
    rng = dict(zip(_STAGES, (np.random.default_rng(s)
                             for s in np.random.SeedSequence(seed).spawn(len(_STAGES)))))
    map_path = Path(map_path)
    whole, whole_frame, crs = _read_map(map_path, cfg.site.crs)
    junctions = _junctions_in(whole, whole_frame)
    kind = "junction"
    if site is not None:
        d = [np.hypot(j.centre[0] - site[0], (j.centre[1] - site[1]) * np.cos(np.radians(
            site[0]))) * 111_195.0 for j in junctions]
        if junctions and min(d) <= SITE_RADIUS:
            jlat, jlon = (float(v) for v in junctions[int(np.argmin(d))].centre)
        else:
            point = _road_point(whole, whole_frame, site, rng["junction"])
            if point is None:
                raise ValueError(f"no junction of the routing graph and no drivable lanelet "
                                 f"within {SITE_RADIUS:g} m of the site ({site[0]:.6f}, "
                                 f"{site[1]:.6f})" + (f"; the nearest junction is "
                                                      f"{min(d):.0f} m away" if d else ""))
            (jlat, jlon), kind = point, "road"
    elif junctions:
        top = [j for j in junctions if len(j.movements) == len(junctions[0].movements)]
        jlat, jlon = (float(v) for v in top[int(rng["junction"].integers(len(top)))].centre)
    else:
        (jlat, jlon), kind = _road_point(whole, whole_frame, None, rng["junction"]), "road"
    notices = {p.name: p.read_text(encoding="utf-8")
               for p in sorted(map_path.parent.glob("LICENSE*")) if p.is_file()}
    site_rng = rng["site"]
    attempts = ROAD_SITE_ATTEMPTS if kind == "road" and site is None else 1
    for attempt in range(attempts):
        if attempt:       # another random metre of road: the last one had no mast place
            jlat, jlon = _road_point(whole, whole_frame, None, rng["junction"])
        try:
            lay = _site_layout(map_path, (jlat, jlon), kind, crs, crop_radius, route_reach,
                               bool(notices), cfg, site_rng, rng["sensor"])
            break
        except RuntimeError:
            if attempt == attempts - 1:
                raise
    text, frame0, centre_h, junction, net, mount = (
        lay.text, lay.frame0, lay.centre_h, lay.junction, lay.net, lay.mount)

    slope = site_rng.uniform(*cfg.als.slope)
    downhill = site_rng.uniform(-np.pi, np.pi)
    grad = slope * np.array([np.cos(downhill), np.sin(downhill)])
    mast_en = mount.xy + np.asarray(frame0.origin[:2])
    approx_en = mast_en + site_rng.normal(0.0, cfg.sensor.approx_position_sigma, 2)
    ground_at_mast = centre_h + float(grad @ (mount.xy - junction.centre))
    frame = LocalFrame.around(approx_en[0], approx_en[1], ground_at_mast, crs)
    offset = np.asarray(frame0.origin[:2]) - np.asarray(frame.origin[:2])
    net.translate(offset)
    mount.xy = mount.xy + offset
    centre = junction.centre + offset
    terrain = Terrain(centre_h - frame.origin[2] - float(grad @ centre), grad,
                      cfg.als.road_raise)
    lmap = _with_heights(_read_text_map(text, crs, frame), terrain)
    area = RoadArea(net)
    road = DrivableArea(lmap.lanelets)

    poles = place_scenery(rng["scenery"], dataclasses.replace(cfg.als, buildings=0, trees=0),
                          net, area, mount.xy)
    scenery, roofs = map_scenery(rng["scenery"], cfg.als, lmap.areas, poles, road, mount.xy)
    no_boxes = dataclasses.replace(scenery, building_centre=np.zeros((0, 2)),
                                   building_size=np.zeros((0, 2)), building_yaw=np.zeros(0),
                                   building_height=np.zeros(0))
    als = synthesize_als(rng["als"], cfg.als, terrain, road, no_boxes, mount.xy)
    _sidewalks_and_roofs(als.xyz, als.classification, lmap, roofs, terrain)
    result = drive_and_observe(rng["traffic"], rng["radar"], site_rng, cfg, net, mount, terrain,
                               scenery, frame, approx_en, als, lmap, duration, vehicles,
                               map_users(lmap, centre, route_reach, cfg))
    return MapSimulation(result, text, centre, notices, kind)
