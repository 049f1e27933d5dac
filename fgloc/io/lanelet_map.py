"""Lanelet2 ``map.osm`` <-> :class:`LaneletMap` in the local frame L.

The file is standard Lanelet2 OSM XML with WGS84 lat/lon nodes. Reading validates it with
lanelet2 (which also resolves inverted bounds) and takes each bound point's lat/lon/``ele``
from the XML node of the same id; pyproj projects lat/lon to the world CRS. lanelet2's own
projection is never used for coordinates (its UTM zone follows its origin, see
docs/formats.md).
"""

from __future__ import annotations

import logging
import re
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

import lanelet2
import numpy as np
from lanelet2.io import Origin
from lanelet2.projection import UtmProjector
from scipy.spatial import cKDTree

from fgloc.errors import InputError
from fgloc.geo import LocalFrame, horizontal_crs, natural_utm_zone, transformer, utm_zone
from fgloc.io.atomic import write_text_atomic
from fgloc.scenario import (
    GROUND_CLASSES,
    AlsCloud,
    Lanelet,
    LaneletMap,
    MapArea,
    MapSettings,
    is_two_way,
)

log = logging.getLogger(__name__)

WGS84 = "EPSG:4326"
#: Relation tags written for every lanelet unless its attributes say otherwise.
DEFAULT_LANELET_TAGS: dict[str, str] = {
    "subtype": "road",
    "location": "urban",
    "one_way": "yes",
}
#: Distance (m) by which the ALS bounding box is grown before testing overlap with the map.
OVERLAP_MARGIN = 100.0
_PRIMITIVE_ID = re.compile(r"primitive (-?\d+)")
#: the line lanelet2 puts before its list of parse errors (no error itself)
_ERRORS_HEADER = re.compile(r"errors? oc+ur+ed while parsing", re.IGNORECASE)
_FAILED_ID = re.compile(r"Failed to get id (-?\d+)")


# --------------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------------
#: Fallback when lanelet2 has no traffic rules for the location/participant: subtypes open to
#: each participant class (the part before ":"), as lanelet2's German rules have them.
PASSABLE_SUBTYPES: dict[str, frozenset[str]] = {
    "vehicle": frozenset({"road", "highway", "play_street"}),
    "bicycle": frozenset({"road", "bicycle_lane", "play_street"}),
    "pedestrian": frozenset({"crosswalk", "walkway", "play_street"}),
    "train": frozenset({"rail"}),
}

#: At most about this many ALS points build the ground-height KD-tree (a regular subsample).
GROUND_MAX_POINTS = 2_000_000
#: Ground height callback: (n, 2) xy in L (m) -> (n,) height in L (m).
GroundFn = Callable[[np.ndarray], np.ndarray]
#: A driving direction of a lanelet: (lanelet id, inverted = against its bounds' direction).
Directed = tuple[int, bool]


@dataclass
class _Nodes:
    """Every XML node: ids (n,), lat, lon, ele (NaN when absent), local_x/local_y (NaN)."""

    ids: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    ele: np.ndarray
    local: np.ndarray


@dataclass
class _Raw:
    """What lanelet2 made of the file: per lanelet (id, left ids, right ids, tags, drivable),
    areas (id, subtype, outline ids), successors among drivable lanelets (in their own
    direction, and per driving direction), regulatory counts, how drivability was decided and
    the lanelets lanelet2 rejected that are roads by their tags (id -> what is wrong)."""

    lanelets: list[tuple[int, np.ndarray, np.ndarray, dict[str, str], bool]]
    areas: list[tuple[int, str, np.ndarray]]
    successors: dict[int, tuple[int, ...]]
    directed_successors: dict[Directed, tuple[Directed, ...]]
    regulatory: dict[str, int]
    rules: str
    skipped: dict[int, str]


def read_lanelet_map(
    path: str | Path,
    crs: str,
    frame: LocalFrame,
    *,
    overlap_bbox: tuple[float, float, float, float] | None = None,
    settings: MapSettings | None = None,
    ground: GroundFn | None = None,
) -> LaneletMap:
    """Read a Lanelet2 map into L.

    crs: the world CRS the nodes are projected to (from lat/lon, or from ``local_x`` /
    ``local_y`` in ``settings.local_crs`` plus ``settings.local_offset``). Bounds are (n, 3)
    in L: z is the node's ``ele`` tag (same vertical datum as the ALS) minus Z0; nodes without
    ``ele`` get ``ground(xy)`` (the ALS ground under them), or 0 when ``ground`` is None.
    overlap_bbox: (xmin, ymin, xmax, ymax) in L of the ALS; when given, a map that does not
    overlap it grown by :data:`OVERLAP_MARGIN` raises :class:`InputError` (typically a map in
    another UTM zone). Only lanelets the traffic rules of ``settings`` (location,
    participant) let pass go to :attr:`LaneletMap.lanelets`; the others to ``ignored``. Areas
    are kept with their subtype; regulatory elements are only counted. Relation tags go to
    :attr:`Lanelet.attributes`.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(p, "Lanelet2 map not found")
    settings = settings or MapSettings()
    nodes, lanelet_ids = _parse_osm(p)
    if not lanelet_ids:
        raise InputError(p, "the map holds no lanelet (no relation tagged type=lanelet)")
    local = _node_coordinates(p, nodes, crs, frame, settings, ground)
    if settings.local_crs is not None and np.isfinite(nodes.local).all(axis=1).any():
        # lanelet2 orients bounds and builds areas from lat/lon: give it the local_x/local_y
        lon, lat = transformer(horizontal_crs(crs).to_string(), WGS84).transform(
            local[:, 0] + frame.origin[0], local[:, 1] + frame.origin[1])
        with tempfile.TemporaryDirectory() as tmp:
            patched = Path(tmp) / p.name
            _write_latlon(p, patched, nodes.ids, np.asarray(lat), np.asarray(lon))
            raw = _load_with_lanelet2(patched, nodes, lanelet_ids, settings,
                                      (float(lat[0]), float(lon[0])))
    else:
        raw = _load_with_lanelet2(p, nodes, lanelet_ids, settings,
                                  (float(nodes.lat[0]), float(nodes.lon[0])))
    index = {int(nid): k for k, nid in enumerate(nodes.ids.tolist())}
    used = np.concatenate([np.concatenate([lft, rgt]) for _, lft, rgt, _, _ in raw.lanelets])
    try:
        rows = np.array([index[i] for i in used.tolist()], dtype=np.int64)
    except KeyError as exc:
        raise InputError(p, f"a lanelet bound references the missing node {exc.args[0]}") from None
    if overlap_bbox is not None:
        _check_overlap(p, local[rows], nodes.lon[rows], crs, overlap_bbox)

    def xyz(ids: np.ndarray) -> np.ndarray:
        return local[[index[int(i)] for i in ids]].copy()

    drivable: list[Lanelet] = []
    ignored: list[Lanelet] = []
    for lid, left_ids, right_ids, attrs, ok in raw.lanelets:
        (drivable if ok else ignored).append(Lanelet(lid, xyz(left_ids), xyz(right_ids), attrs))
    areas = [MapArea(aid, sub, xyz(ring)[:, :2]) for aid, sub, ring in raw.areas
             if all(int(i) in index for i in ring)]
    if not drivable:
        raise InputError(p, f"no lanelet of the map is drivable under {raw.rules} (kinds: "
                         f"{LaneletMap([], ignored).ignored_by_kind()})")
    out = LaneletMap(drivable, ignored, areas, raw.successors, raw.regulatory, raw.rules,
                     directed_successors=raw.directed_successors, skipped=raw.skipped)
    if ignored:
        log.debug("%s: %d drivable lanelets; ignored %s", p, len(drivable), out.ignored_by_kind())
    return out


def als_ground(als: AlsCloud, classes: tuple[int, ...] = GROUND_CLASSES, k: int = 8) -> GroundFn:
    """Ground height callback over an ALS in L: the median height (m, L) of the ``k`` nearest
    points of ``classes`` (ASPRS ground, road surface; all points when it has none) in 2D. The
    KD-tree is built on the first call only, from at most about :data:`GROUND_MAX_POINTS`
    points (every n-th)."""
    cache: list[tuple[cKDTree, np.ndarray]] = []

    def height(xy: np.ndarray) -> np.ndarray:
        if not cache:
            sel = np.flatnonzero(np.isin(np.asarray(als.classification), classes))
            if not len(sel):
                sel = np.arange(len(als.xyz))
            sel = sel[:: max(1, len(sel) // GROUND_MAX_POINTS)]  # bounded KD-tree (big tiles)
            pts = np.asarray(als.xyz[sel], dtype=np.float64)
            if not len(pts):
                return np.zeros(len(xy))
            cache.append((cKDTree(pts[:, :2]), pts[:, 2]))
        tree, z = cache[0]
        _, idx = tree.query(np.asarray(xy, dtype=np.float64)[:, :2], k=min(k, len(z)))
        return np.median(z[np.asarray(idx).reshape(len(xy), -1)], axis=1)

    return height


def _node_coordinates(
    path: Path, nodes: _Nodes, crs: str, frame: LocalFrame, settings: MapSettings,
    ground: GroundFn | None,
) -> np.ndarray:
    """(n, 3) coordinates in L of every node (see :func:`read_lanelet_map`)."""
    world_crs = horizontal_crs(crs).to_string()
    has_local = np.isfinite(nodes.local).all(axis=1)
    if has_local.any() and settings.local_crs is None and not np.any(
        (nodes.lat != 0.0) | (nodes.lon != 0.0)
    ):
        raise InputError(path, "the nodes carry local_x/local_y but no lat/lon: declare their "
                         "CRS and origin in sensor.toml ([map] local_crs, local_offset)")
    east, north = (np.asarray(v, dtype=np.float64) for v in
                   transformer(WGS84, world_crs).transform(nodes.lon, nodes.lat))
    if settings.local_crs is not None and has_local.any():
        lx = nodes.local[has_local, 0] + settings.local_offset[0]
        ly = nodes.local[has_local, 1] + settings.local_offset[1]
        src = horizontal_crs(settings.local_crs).to_string()
        le, ln = transformer(src, world_crs).transform(lx, ly) if src != world_crs else (lx, ly)
        east[has_local], north[has_local] = le, ln
    xy = np.column_stack([east - frame.origin[0], north - frame.origin[1]])
    if not np.isfinite(xy).all():
        raise InputError(path, f"some nodes cannot be projected to {crs}")
    z = nodes.ele - frame.origin[2]
    missing = np.isnan(z)
    if missing.any():
        z[missing] = ground(xy[missing]) if ground is not None else 0.0
    return np.column_stack([xy, z])


def _write_latlon(src: Path, dst: Path, ids: np.ndarray, lat: np.ndarray, lon: np.ndarray
                  ) -> None:
    """Copy of the OSM file ``src`` with every node's lat/lon replaced (nodes by id)."""
    root = ET.parse(src).getroot()
    where = {int(i): k for k, i in enumerate(ids.tolist())}
    for node in root.iter("node"):
        k = where[int(node.attrib["id"])]
        node.set("lat", f"{lat[k]:.11f}")
        node.set("lon", f"{lon[k]:.11f}")
    ET.ElementTree(root).write(dst, encoding="utf-8", xml_declaration=True)


def _parse_osm(path: Path) -> tuple[_Nodes, dict[int, dict[str, str]]]:
    """Every node and the tags of the relations tagged type=lanelet, by id."""
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise InputError(path, f"not valid XML: {exc}", row=exc.position[0]) from None
    rows: list[tuple[int, float, float, float, float, float]] = []
    for node in root.iter("node"):
        tags = {t.get("k"): t.get("v") for t in node.iter("tag")}
        try:
            nid = int(node.attrib["id"])
            if "local_x" in tags and "local_y" in tags:
                # lat/lon optional; Vector Map Builder writes them empty (lat="" lon="")
                lat, lon = (float(node.get(k) or "0") for k in ("lat", "lon"))
            else:
                lat, lon = float(node.attrib["lat"]), float(node.attrib["lon"])
            ele, lx, ly = (float(tags[k]) if k in tags else float("nan")
                           for k in ("ele", "local_x", "local_y"))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(
                path, f"node needs integer id, numeric lat/lon (and ele, local_x/local_y): {exc}",
                field=f"node {node.get('id')}",
            ) from None
        if not (abs(lat) <= 90.0 and abs(lon) <= 180.0 and not np.isinf([ele, lx, ly]).any()):
            raise InputError(
                path, f"expected WGS84 lat in [-90, 90], lon in [-180, 180] and a finite ele, "
                f"got lat={lat!r} lon={lon!r} ele={ele!r}", field=f"node {nid}",
            )
        rows.append((nid, lat, lon, ele, lx, ly))
    table = np.array([r[1:] for r in rows], dtype=np.float64).reshape(-1, 5)
    nodes = _Nodes(np.array([r[0] for r in rows], dtype=np.int64), table[:, 0], table[:, 1],
                   table[:, 2], table[:, 3:5])
    lanelet_ids: dict[int, dict[str, str]] = {}
    bound_ways: set[str] = set()
    for rel in root.iter("relation"):
        if any(t.get("k") == "type" and t.get("v") == "lanelet" for t in rel.iter("tag")):
            try:
                lanelet_ids[int(rel.attrib["id"])] = {
                    t.get("k", ""): t.get("v", "") for t in rel.iter("tag")}
            except (KeyError, ValueError):
                raise InputError(path, "a lanelet relation needs an integer id",
                                 field=f"relation {rel.get('id')}") from None
            bound_ways.update(m.get("ref", "") for m in rel.iter("member")
                              if m.get("type") == "way" and m.get("role") in ("left", "right"))
    known = {str(nid) for nid in nodes.ids.tolist()}
    for way in root.iter("way"):
        if way.get("id") in bound_ways:
            missing = [nd.get("ref") for nd in way.iter("nd") if nd.get("ref") not in known]
            if missing:
                raise InputError(path, f"the lanelet bound references the node {missing[0]}, "
                                 "which the map does not define", field=f"way {way.get('id')}")
    return nodes, lanelet_ids


def passable_by_tags(attributes: dict[str, str], participant: str) -> bool:
    """Fallback drivability from tags: explicit ``participant:<p>`` tags decide (the most
    specific of ``participant:vehicle:car``, ``participant:vehicle``; any participant tag
    present but none matching means closed), else the subtype (:data:`PASSABLE_SUBTYPES`)."""
    explicit = {k.split(":", 1)[1]: v for k, v in attributes.items()
                if k.startswith("participant:")}
    parts = participant.split(":")
    if explicit:
        for n in range(len(parts), 0, -1):
            key = ":".join(parts[:n])
            if key in explicit:
                return explicit[key] == "yes"
        return False
    return attributes.get("subtype", "road") in PASSABLE_SUBTYPES.get(parts[0], frozenset())


def _traffic_rules(path: Path, settings: MapSettings) -> tuple[object | None, str]:
    """lanelet2 traffic rules for the settings, or None (tags decide) when it has none."""
    try:
        rules = lanelet2.traffic_rules.create(settings.location, settings.participant)
    except RuntimeError as exc:
        log.warning("%s: %s; drivable lanelets are decided by subtype/participant tags",
                    path, exc)
        return None, f"subtype/participant tags ({settings.location}/{settings.participant})"
    return rules, f"lanelet2 traffic rules {settings.location}/{settings.participant}"


def _directed_successors(lmap: object, rules: object | None, drivable: set[int]) -> dict[
        Directed, tuple[Directed, ...]]:
    """Routing graph among the drivable lanelets per driving direction: lanelet2's
    ``RoutingGraph.following`` with the rules from every lanelet and, where the rules let a
    vehicle drive it against its direction (a two-way lanelet), from its inverted lanelet;
    else lanelets whose bounds (as driven) start at the points where another's end (lanelet2's
    ``follows``), two-way lanelets (tag ``one_way`` = no) both ways."""
    lanelets = [ll for ll in lmap.laneletLayer if ll.id in drivable]
    if rules is not None:
        # on the drivable lanelets only: lanelet2's graph over a map that holds lanelets it
        # rejected (a bound missing) crashes the process
        graph = lanelet2.routing.RoutingGraph(
            lanelet2.core.createSubmapFromLanelets(lanelets), rules)
        succ = {(ll.id, d.inverted()): [(f.id, f.inverted()) for f in graph.following(d)]
                for ll in lanelets
                for d in ((ll, ll.invert()) if rules.canPass(ll.invert()) else (ll,))}
    else:
        ends: dict[Directed, tuple[tuple[int, int], tuple[int, int]]] = {}
        for ll in lanelets:
            left, right = ll.leftBound, ll.rightBound
            ends[(ll.id, False)] = ((left[0].id, right[0].id), (left[-1].id, right[-1].id))
            if is_two_way({k: str(v) for k, v in ll.attributes.items()}):
                ends[(ll.id, True)] = ((right[-1].id, left[-1].id), (right[0].id, left[0].id))
        starts: dict[tuple[int, int], list[Directed]] = {}
        for key, (start, _) in ends.items():
            starts.setdefault(start, []).append(key)
        succ = {key: starts.get(end, []) for key, (_, end) in ends.items()}
    return {k: tuple(sorted(x for x in set(v) if x[0] in drivable)) for k, v in succ.items()
            if v}


def _successors(directed: dict[Directed, tuple[Directed, ...]]) -> dict[int, tuple[int, ...]]:
    """The routing graph in the lanelets' own direction (:attr:`LaneletMap.successors`): the
    directed graph's forward lanelets to forward lanelets."""
    succ = {k[0]: tuple(i for i, inv in v if not inv) for k, v in directed.items() if not k[1]}
    return {k: v for k, v in succ.items() if v}


def _load_with_lanelet2(
    path: Path, nodes: _Nodes, lanelet_ids: dict[int, dict[str, str]], settings: MapSettings,
    origin: tuple[float, float],
) -> _Raw:
    """Lanelets, areas and routing graph, validated by lanelet2 (its projector's origin: a
    node's (lat, lon) as the file ``path`` has them, so that every node lies in or near the
    origin's UTM zone; fgloc takes the coordinates from the XML).

    A lanelet that references a regulatory element lanelet2 cannot build (a type it does not
    implement, e.g. Autoware's ``detection_area``; lanelet2 then rejects the lanelet) is read
    without that reference (logged; fgloc uses no regulatory element). A lanelet lanelet2
    rejects (or with a bound of fewer than 2 nodes) is skipped with a warning; when its tags
    make it drivable (:func:`passable_by_tags`) it is listed in ``_Raw.skipped`` (the
    result's warnings say so); no drivable lanelet left is fatal. Errors about other
    primitives (areas, regulatory elements) are logged.
    """
    if not len(nodes.ids):
        raise InputError(path, "the map holds no nodes")
    projector = UtmProjector(Origin(*origin))
    with tempfile.TemporaryDirectory() as tmp:
        joined = Path(tmp) / path.name
        split = _join_split_bounds(path, joined)
        source = joined if split else path
        if split:
            log.info("%s: %d lanelet(s) with a bound drawn as several ways, read with the ways "
                     "joined (relation %s)", path, len(split), ", ".join(map(str, split)))
        lmap, errors = _load_robust(source, projector, path)
        dangling = _regulatory_failures(errors, lanelet_ids)
        if dangling:
            patched = Path(tmp) / f"patched-{path.name}"
            _drop_regulatory_members(source, patched, dangling)
            lmap, errors = _load_robust(patched, projector, path)
        for lid, refs in sorted(dangling.items()):
            log.warning("%s: relation %d read without its reference(s) to %s: lanelet2 cannot "
                        "build them (fgloc uses no regulatory element)", path, lid,
                        ", ".join(f"relation {r}" for r in sorted(refs)))
    broken: dict[int, str] = {}  # lanelet id -> what is wrong with it
    for msg in errors:
        m = _PRIMITIVE_ID.search(msg)
        if m and int(m.group(1)) in lanelet_ids:
            broken.setdefault(int(m.group(1)), f"invalid lanelet: {msg.strip()}")
        elif m:
            log.warning("%s: primitive %s ignored (not a lanelet; fgloc does not need it), "
                        "lanelet2 says: %s", path, m.group(1),
                        msg[m.end():].lstrip(": ").strip() or msg.strip())
        elif not _ERRORS_HEADER.match(msg.strip()):
            log.warning("%s: lanelet2 (ignored, not about a lanelet): %s", path, msg.strip())
    rules, how = _traffic_rules(path, settings)
    lanelets = []
    for ll in sorted(lmap.laneletLayer, key=lambda x: x.id):
        left = np.array([pt.id for pt in ll.leftBound], dtype=np.int64)
        right = np.array([pt.id for pt in ll.rightBound], dtype=np.int64)
        if len(left) < 2 or len(right) < 2:
            broken.setdefault(ll.id, "a lanelet bound needs >= 2 nodes")
        if ll.id in broken:
            continue
        attrs = {k: str(v) for k, v in ll.attributes.items()}
        ok = (bool(rules.canPass(ll)) if rules is not None
              else passable_by_tags(attrs, settings.participant))
        lanelets.append((int(ll.id), left, right, attrs, ok))
    if broken and not any(ok for *_, ok in lanelets):
        lid = min(broken)
        raise InputError(path, broken[lid], field=f"relation {lid}")
    skipped = {lid: msg for lid, msg in sorted(broken.items())
               if passable_by_tags(lanelet_ids.get(lid, {}), settings.participant)}
    for lid, msg in sorted(broken.items()):
        kind = "a road by its tags" if lid in skipped else "not drivable"
        log.warning("%s: relation %d skipped (%s): %s", path, lid, kind, msg)
    if not lanelets:
        raise InputError(path, "lanelet2 found no valid lanelet in the map")
    areas = []
    for area in sorted(lmap.areaLayer, key=lambda x: x.id):
        ring = np.array([pt.id for pt in area.outerBoundPolygon()], dtype=np.int64)
        sub = str(area.attributes["subtype"]) if "subtype" in area.attributes else "unknown"
        if len(ring) >= 3:
            areas.append((int(area.id), sub, ring))
    regulatory: dict[str, int] = {}
    for reg in lmap.regulatoryElementLayer:
        sub = str(reg.attributes["subtype"]) if "subtype" in reg.attributes else "unknown"
        regulatory[sub] = regulatory.get(sub, 0) + 1
    drivable = {lid for lid, *_, ok in lanelets if ok}
    directed = _directed_successors(lmap, rules, drivable)
    return _Raw(lanelets, areas, _successors(directed), directed,
                dict(sorted(regulatory.items())), how, skipped)


def _load_robust(path: Path, projector: UtmProjector, shown: Path) -> tuple[object, list[str]]:
    """lanelet2's map of the file ``path`` and its error messages (errors name ``shown``, the
    user's file that ``path`` is a repaired copy of, or ``path`` itself)."""
    try:
        return lanelet2.io.loadRobust(str(path), projector)
    except RuntimeError as exc:
        raise InputError(shown, f"lanelet2 cannot read the map: {exc}") from None


def _join_split_bounds(src: Path, dst: Path) -> list[int]:
    """Lanelet2 wants one way per bound; hand-made maps (INTERACTION, rounD) draw a bound as
    several ways end to end, and lanelet2 then rejects the lanelet ("Lanelet has not exactly
    one left border"). Each such bound whose ways chain (consecutive ways share an end node,
    in any order and direction) becomes one new way (the first way's tags; a fresh id above
    every id of the file), written with the rest of ``src`` to ``dst``. Elements JOSM marks
    ``action="delete"`` are left out, as lanelet2 leaves them. Returns the ids of the lanelets
    so joined; empty (and nothing written) when there are none."""
    root = ET.parse(src).getroot()
    ways = {w.get("id"): w for w in root.iter("way") if w.get("action") != "delete"}
    ids = [int(e.get("id", "0")) for e in root if e.get("id", "").lstrip("-").isdigit()]
    fresh = max(map(abs, ids), default=0)
    joined: list[int] = []
    for rel in root.iter("relation"):
        if rel.get("action") == "delete" or not any(
                t.get("k") == "type" and t.get("v") == "lanelet" for t in rel.iter("tag")):
            continue
        done = False
        for role in ("left", "right"):
            members = [m for m in rel.iter("member") if m.get("role") == role
                       and m.get("type") == "way"]
            if len(members) < 2 or any(m.get("ref") not in ways for m in members):
                continue
            chain = _chain([[nd.get("ref", "") for nd in ways[m.get("ref")].iter("nd")]
                            for m in members])
            if chain is None:
                continue
            fresh += 1
            first = ways[members[0].get("ref")]
            way = ET.SubElement(root, "way", {"id": str(fresh), "visible": "true",
                                              "version": "1"})
            way.extend(ET.Element("nd", {"ref": r}) for r in chain)
            way.extend(ET.Element("tag", dict(t.attrib)) for t in first.iter("tag"))
            for m in members[1:]:
                rel.remove(m)
            members[0].set("ref", str(fresh))
            done = True
        if done:
            joined.append(int(rel.get("id", "0")))
    if joined:
        ET.ElementTree(root).write(dst, encoding="utf-8", xml_declaration=True)
    return joined


def _chain(parts: list[list[str]]) -> list[str] | None:
    """The node ids of the ways ``parts`` joined end to end into one line (each used once,
    reversed where needed), None when they do not form one."""
    line, rest = list(parts[0]), [list(p) for p in parts[1:]]
    while rest:
        for k, part in enumerate(rest):
            if len(part) < 2:
                return None
            if part[0] == line[-1] or part[-1] == line[-1]:
                line += (part if part[0] == line[-1] else part[::-1])[1:]
            elif part[-1] == line[0] or part[0] == line[0]:
                line = (part if part[-1] == line[0] else part[::-1])[:-1] + line
            else:
                continue
            del rest[k]
            break
        else:
            return None
    return line


def _regulatory_failures(errors: list[str], lanelet_ids: dict[int, dict[str, str]]
                         ) -> dict[int, set[int]]:
    """Lanelet id -> the ids of non-lanelet relations it failed to get (lanelet2's "Error
    parsing primitive L: Failed to get id R from map": R is a regulatory element lanelet2
    could not build; a reference to a relation the map lacks lanelet2 only logs)."""
    out: dict[int, set[int]] = {}
    for msg in errors:
        m = _PRIMITIVE_ID.search(msg)
        if m is None or int(m.group(1)) not in lanelet_ids:
            continue
        refs = {int(r) for r in _FAILED_ID.findall(msg)} - lanelet_ids.keys()
        if refs:
            out.setdefault(int(m.group(1)), set()).update(refs)
    return out


def _drop_regulatory_members(src: Path, dst: Path, refs: dict[int, set[int]]) -> None:
    """Copy of the OSM file ``src`` without the ``regulatory_element`` members of the lanelet
    relations in ``refs`` (lanelet id -> relation ids) that point to those relations."""
    root = ET.parse(src).getroot()
    for rel in root.iter("relation"):
        drop = refs.get(int(rel.get("id", "0")), set())
        for member in [m for m in rel.iter("member") if m.get("role") == "regulatory_element"
                       and int(m.get("ref", "0")) in drop]:
            rel.remove(member)
    ET.ElementTree(root).write(dst, encoding="utf-8", xml_declaration=True)


def _check_overlap(
    path: Path,
    local: np.ndarray,
    lon: np.ndarray,
    crs: str,
    bbox: tuple[float, float, float, float],
) -> None:
    xmin, ymin, xmax, ymax = bbox
    lo, hi = local[:, :2].min(axis=0), local[:, :2].max(axis=0)
    g = OVERLAP_MARGIN
    if lo[0] <= xmax + g and hi[0] >= xmin - g and lo[1] <= ymax + g and hi[1] >= ymin - g:
        return
    lon_c = float(np.median(lon))
    zone = utm_zone(horizontal_crs(crs))
    zone_text = f" (zone {zone})" if zone is not None else ""
    raise InputError(
        path,
        f"map lies in UTM zone {natural_utm_zone(lon_c)} (lon {lon_c:.2f}), but the ALS/sensor "
        f"CRS is {crs}{zone_text}; map and ALS do not overlap (map bbox in L "
        f"[{lo[0]:.0f}, {lo[1]:.0f}, {hi[0]:.0f}, {hi[1]:.0f}] m, ALS bbox "
        f"[{xmin:.0f}, {ymin:.0f}, {xmax:.0f}, {ymax:.0f}] m)",
    )


# --------------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------------
def write_lanelet_map(path: str | Path, lanelet_map: LaneletMap, frame: LocalFrame) -> None:
    """Write a Lanelet2 OSM file atomically (the drivable and the ignored lanelets; areas and
    regulatory elements are not written).

    Bounds (L) go to world (``frame``) and to WGS84 lat/lon with 10 decimals (~0.01 mm); the
    world height goes to the ``ele`` tag (mm). Each bound is its own way (type=line_thin,
    subtype=solid); relations keep the lanelet ids and carry type=lanelet, the defaults of
    :data:`DEFAULT_LANELET_TAGS` and the lanelet's attributes. Node and way ids count up from
    the largest |lanelet id| + 1.
    """
    lls = [*lanelet_map.lanelets, *lanelet_map.ignored]
    ids = [ll.id for ll in lls]
    if len(set(ids)) != len(ids) or 0 in ids:
        raise ValueError("lanelet ids must be unique and non-zero")
    bounds = [b for ll in lls for b in (ll.left, ll.right)]
    world = frame.to_world(np.vstack([np.asarray(b, dtype=np.float64) for b in bounds]))
    lon, lat = transformer(horizontal_crs(frame.crs).to_string(), WGS84).transform(
        world[:, 0], world[:, 1]
    )
    next_id = max((abs(i) for i in ids), default=0) + 1
    node_ids = np.arange(next_id, next_id + len(world))
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', '<osm version="0.6" generator="fgloc">']
    node_fmt = '  <node id="%d" visible="true" version="1" lat="%.10f" lon="%.10f">' \
        '<tag k="ele" v="%.4f"/></node>'
    lines.extend(map(node_fmt.__mod__, zip(node_ids.tolist(), lat.tolist(), lon.tolist(),
                                           world[:, 2].tolist())))
    way_id = int(node_ids[-1]) + 1 if len(node_ids) else next_id
    k = 0
    relations = []
    for ll in lls:
        members = []
        for role, bound in (("left", ll.left), ("right", ll.right)):
            refs = "".join(f'<nd ref="{i}"/>' for i in node_ids[k : k + len(bound)].tolist())
            lines.append(
                f'  <way id="{way_id}" visible="true" version="1">{refs}'
                '<tag k="type" v="line_thin"/><tag k="subtype" v="solid"/></way>'
            )
            members.append(f'<member type="way" ref="{way_id}" role="{role}"/>')
            k += len(bound)
            way_id += 1
        tags = {**DEFAULT_LANELET_TAGS, **ll.attributes, "type": "lanelet"}
        tag_xml = "".join(f"<tag k={quoteattr(str(a))} v={quoteattr(str(v))}/>"
                          for a, v in tags.items())
        relations.append(
            f'  <relation id="{ll.id}" visible="true" version="1">{"".join(members)}{tag_xml}'
            "</relation>"
        )
    lines.extend(relations)
    lines.append("</osm>")
    write_text_atomic(path, "\n".join(lines) + "\n")


# --------------------------------------------------------------------------------------------
# cropping
# --------------------------------------------------------------------------------------------
def crop_lanelet_osm(
    path: str | Path, lat: float, lon: float, radius: float, *, drop_ele: bool = False
) -> str:
    """OSM XML text of the part of a Lanelet2 map around (lat, lon).

    Keeps every lanelet and area relation with a node within ``radius`` m (whole, with all its
    ways and nodes), every regulatory element whose members are all there that a kept lanelet
    references or that names a kept relation, and drops references to the regulatory elements
    that are not kept. ``drop_ele`` removes the nodes' ``ele`` tags (when
    the heights are to come from another ALS). Distances use a local equirectangular
    approximation (fine for a few hundred metres).
    """
    p = Path(path)
    try:
        root = ET.parse(p).getroot()
    except ET.ParseError as exc:
        raise InputError(p, f"not valid XML: {exc}", row=exc.position[0]) from None
    nodes = {n.get("id"): n for n in root.iter("node")}
    ways = {w.get("id"): w for w in root.iter("way")}
    k_lat = np.deg2rad(1.0) * 6_371_000.0
    k_lon = k_lat * np.cos(np.deg2rad(lat))

    def near(node: ET.Element | None) -> bool:
        if node is None:
            return False
        dy = (float(node.get("lat", "nan")) - lat) * k_lat
        dx = (float(node.get("lon", "nan")) - lon) * k_lon
        return bool(dx * dx + dy * dy <= radius * radius)

    def way_nodes(wid: str | None) -> list[str]:
        w = ways.get(wid or "")
        return [] if w is None else [nd.get("ref", "") for nd in w.iter("nd")]

    keep_rel: set[str] = set()
    keep_way: set[str] = set()
    relations = list(root.iter("relation"))
    for rel in relations:
        tags = {t.get("k"): t.get("v") for t in rel.iter("tag")}
        if tags.get("type") not in ("lanelet", "multipolygon"):
            continue
        members = [m for m in rel.iter("member") if m.get("type") == "way"]
        refs = [r for m in members for r in way_nodes(m.get("ref"))]
        if any(near(nodes.get(r)) for r in refs) and all(r in nodes for r in refs):
            keep_rel.add(rel.get("id", ""))
            keep_way.update(m.get("ref", "") for m in members)
    # regulatory elements whose members are all kept and that a kept lanelet references or
    # that name one (a traffic light or a speed limit names only its ways; a right of way
    # names its lanelets)
    referenced = {m.get("ref") for rel in relations if rel.get("id") in keep_rel
                  for m in rel.iter("member")
                  if m.get("type") == "relation" and m.get("role") == "regulatory_element"}
    for rel in relations:
        tags = {t.get("k"): t.get("v") for t in rel.iter("tag")}
        if tags.get("type") != "regulatory_element":
            continue
        members = list(rel.iter("member"))
        if members and all(
            (m.get("type") == "way" and m.get("ref") in ways)
            or (m.get("type") == "relation" and m.get("ref") in keep_rel)
            or (m.get("type") == "node" and m.get("ref") in nodes)
            for m in members
        ) and (rel.get("id") in referenced or any(
                m.get("ref") in keep_rel for m in members if m.get("type") == "relation")):
            keep_rel.add(rel.get("id", ""))
            keep_way.update(m.get("ref", "") for m in members if m.get("type") == "way")
    keep_node = {r for wid in keep_way for r in way_nodes(wid)}
    keep_node.update(m.get("ref", "") for rel in relations if rel.get("id") in keep_rel
                     for m in rel.iter("member") if m.get("type") == "node")
    out = ET.Element("osm", dict(root.attrib))
    for nid, node in nodes.items():
        if nid in keep_node:
            if drop_ele:
                for t in [t for t in node.findall("tag") if t.get("k") == "ele"]:
                    node.remove(t)
            out.append(node)
    out.extend(w for wid, w in ways.items() if wid in keep_way)
    for rel in relations:
        if rel.get("id") in keep_rel:
            for m in [m for m in rel.findall("member") if m.get("type") == "relation"
                      and m.get("ref") not in keep_rel]:
                rel.remove(m)
            out.append(rel)
    ET.indent(out)
    return ET.tostring(out, encoding="unicode", xml_declaration=True) + "\n"
