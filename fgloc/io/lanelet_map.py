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
import xml.etree.ElementTree as ET
from pathlib import Path
from xml.sax.saxutils import quoteattr

import lanelet2
import numpy as np
from lanelet2.io import Origin
from lanelet2.projection import UtmProjector

from fgloc.errors import InputError
from fgloc.geo import LocalFrame, horizontal_crs, natural_utm_zone, transformer, utm_zone
from fgloc.io.atomic import write_text_atomic
from fgloc.scenario import Lanelet, LaneletMap

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


# --------------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------------
def read_lanelet_map(
    path: str | Path,
    crs: str,
    frame: LocalFrame,
    *,
    overlap_bbox: tuple[float, float, float, float] | None = None,
) -> LaneletMap:
    """Read a Lanelet2 map into L.

    crs: the world CRS the lat/lon nodes are projected to. Bounds are (n, 3) in L: z is the
    node's ``ele`` tag (same vertical datum as the ALS) minus Z0, or 0 without ``ele``.
    overlap_bbox: (xmin, ymin, xmax, ymax) in L of the ALS; when given, a map that does not
    overlap it grown by :data:`OVERLAP_MARGIN` raises :class:`InputError` (typically a map in
    another UTM zone). Relation tags go to :attr:`Lanelet.attributes`; non-lanelet relations
    are ignored.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(p, "Lanelet2 map not found")
    nodes, lanelet_ids = _parse_osm(p)
    if not lanelet_ids:
        raise InputError(p, "the map holds no lanelet (no relation tagged type=lanelet)")
    lanelets = _load_with_lanelet2(p, nodes, lanelet_ids)

    all_ids = np.concatenate([np.concatenate([lft, rgt]) for _, lft, rgt, _ in lanelets])
    index = {nid: k for k, nid in enumerate(nodes)}
    try:
        rows = np.array([index[i] for i in all_ids.tolist()], dtype=np.int64)
    except KeyError as exc:
        raise InputError(p, f"a lanelet bound references the missing node {exc.args[0]}") from None
    table = np.array(list(nodes.values()), dtype=np.float64)  # (n, 3) lat, lon, ele
    lat, lon, ele = table[rows, 0], table[rows, 1], table[rows, 2]
    east, north = transformer(WGS84, horizontal_crs(crs).to_string()).transform(lon, lat)
    local = np.column_stack(
        [
            np.asarray(east) - frame.origin[0],
            np.asarray(north) - frame.origin[1],
            np.where(np.isnan(ele), 0.0, ele - frame.origin[2]),
        ]
    )
    if not np.isfinite(local).all():
        raise InputError(p, f"some nodes cannot be projected to {crs}")
    if overlap_bbox is not None:
        _check_overlap(p, local, lon, crs, overlap_bbox)

    out: list[Lanelet] = []
    k = 0
    for lid, left_ids, right_ids, attrs in lanelets:
        nl, nr = len(left_ids), len(right_ids)
        left, right = local[k : k + nl].copy(), local[k + nl : k + nl + nr].copy()
        out.append(Lanelet(lid, left, right, attrs))
        k += nl + nr
    return LaneletMap(out)


def _parse_osm(path: Path) -> tuple[dict[int, tuple[float, float, float]], set[int]]:
    """Nodes {id: (lat, lon, ele or NaN)} and the ids of relations tagged type=lanelet."""
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise InputError(path, f"not valid XML: {exc}", row=exc.position[0]) from None
    nodes: dict[int, tuple[float, float, float]] = {}
    for node in root.iter("node"):
        try:
            nid = int(node.attrib["id"])
            lat, lon = float(node.attrib["lat"]), float(node.attrib["lon"])
            ele_tags = [t.get("v") for t in node.iter("tag") if t.get("k") == "ele"]
            ele = float(ele_tags[0]) if ele_tags else float("nan")
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(
                path, f"node needs integer id, numeric lat/lon (and ele): {exc}",
                field=f"node {node.get('id')}",
            ) from None
        if not (abs(lat) <= 90.0 and abs(lon) <= 180.0 and not np.isinf(ele)):
            raise InputError(
                path, f"expected WGS84 lat in [-90, 90], lon in [-180, 180] and a finite ele, "
                f"got lat={lat!r} lon={lon!r} ele={ele!r}", field=f"node {nid}",
            )
        nodes[nid] = (lat, lon, ele)
    lanelet_ids: set[int] = set()
    bound_ways: set[str] = set()
    for rel in root.iter("relation"):
        if any(t.get("k") == "type" and t.get("v") == "lanelet" for t in rel.iter("tag")):
            try:
                lanelet_ids.add(int(rel.attrib["id"]))
            except (KeyError, ValueError):
                raise InputError(path, "a lanelet relation needs an integer id",
                                 field=f"relation {rel.get('id')}") from None
            bound_ways.update(m.get("ref", "") for m in rel.iter("member")
                              if m.get("type") == "way" and m.get("role") in ("left", "right"))
    known = {str(nid) for nid in nodes}
    for way in root.iter("way"):
        if way.get("id") in bound_ways:
            missing = [nd.get("ref") for nd in way.iter("nd") if nd.get("ref") not in known]
            if missing:
                raise InputError(path, f"the lanelet bound references the node {missing[0]}, "
                                 "which the map does not define", field=f"way {way.get('id')}")
    return nodes, lanelet_ids


def _load_with_lanelet2(
    path: Path, nodes: dict[int, tuple[float, float, float]], lanelet_ids: set[int]
) -> list[tuple[int, np.ndarray, np.ndarray, dict[str, str]]]:
    """(id, left node ids, right node ids, tags) per lanelet, validated by lanelet2.

    lanelet2 errors about lanelet relations are fatal; errors about other primitives (areas,
    regulatory elements fgloc ignores) are logged.
    """
    if not nodes:
        raise InputError(path, "the map holds no nodes")
    lat0, lon0, _ = next(iter(nodes.values()))
    projector = UtmProjector(Origin(lat0, lon0))  # any projector: coordinates come from the XML
    try:
        lmap, errors = lanelet2.io.loadRobust(str(path), projector)
    except RuntimeError as exc:
        raise InputError(path, f"lanelet2 cannot read the map: {exc}") from None
    for msg in errors:
        m = _PRIMITIVE_ID.search(msg)
        if m and int(m.group(1)) in lanelet_ids:
            raise InputError(path, f"invalid lanelet: {msg.strip()}", field=f"relation {m[1]}")
        if m:
            log.warning("%s: lanelet2 (ignored, not a lanelet): %s", path, msg.strip())
    out = []
    for ll in sorted(lmap.laneletLayer, key=lambda x: x.id):
        left = np.array([pt.id for pt in ll.leftBound], dtype=np.int64)
        right = np.array([pt.id for pt in ll.rightBound], dtype=np.int64)
        if len(left) < 2 or len(right) < 2:
            raise InputError(path, "a lanelet bound needs >= 2 nodes", field=f"relation {ll.id}")
        out.append((int(ll.id), left, right, {k: str(v) for k, v in ll.attributes.items()}))
    if not out:
        raise InputError(path, "lanelet2 found no valid lanelet in the map")
    return out


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
    """Write a Lanelet2 OSM file atomically.

    Bounds (L) go to world (``frame``) and to WGS84 lat/lon with 10 decimals (~0.01 mm); the
    world height goes to the ``ele`` tag (mm). Each bound is its own way (type=line_thin,
    subtype=solid); relations keep the lanelet ids and carry type=lanelet, the defaults of
    :data:`DEFAULT_LANELET_TAGS` and the lanelet's attributes. Node and way ids count up from
    the largest |lanelet id| + 1.
    """
    lls = lanelet_map.lanelets
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
