"""ROS 2 bags (MCAP or sqlite3) -> radar detections, via the pure-Python ``rosbags`` package.

Supported message types on the chosen topic (``pip install 'fgloc[ros]'``):

1. ``sensor_msgs/msg/PointCloud2`` with float fields ``x``, ``y``, ``z`` (m, sensor frame:
   x boresight, y left, z up) and a range-rate field named one of :data:`DOPPLER_FIELDS`
   (or given with ``doppler_field``); an RCS field of :data:`RCS_FIELDS` is kept.
2. Detection lists (ARS548-style): any message with an array of detections whose fields give
   range (m), azimuth (rad, CCW from boresight), elevation (rad, up) and range rate (m/s), by
   the names of :data:`LIST_FIELDS`, e.g. ``radar_msgs/msg/RadarScan`` (range, azimuth,
   elevation, doppler_velocity) or the Continental ARS548 drivers' ``DetectionList``
   (f_range / f_azimuthangle / f_elevationangle / f_rangerate, s_rcs). Points are
   ``x = r cos(el) cos(az)``, ``y = r cos(el) sin(az)``, ``z = r sin(el)``.

Message definitions come from the bag (ROS 2 Iron and later and every MCAP bag store them),
from the built-in ROS 2 types, or from ``.msg`` files given as ``msg_defs`` (path
``.../<package>/msg/<Name>.msg``). Each message is one radar frame: t = ``header.stamp`` (the
bag's receive time when the stamp is zero), frame = message index. Detections with a
non-finite value are dropped (with a warning); rows are ordered by t.
"""

from __future__ import annotations

import dataclasses
import logging
import shutil
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fgloc.errors import InputError
from fgloc.scenario import RadarData

log = logging.getLogger(__name__)

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
#: PointCloud2 range-rate field names accepted (case-insensitive), in order of preference.
DOPPLER_FIELDS: tuple[str, ...] = (
    "doppler", "doppler_velocity", "range_rate", "rangerate", "radial_velocity",
    "radial_speed", "v_r", "vr", "vel_r", "v_doppler", "f_rangerate", "f_range_rate", "velocity",
)
RCS_FIELDS: tuple[str, ...] = ("rcs", "rcs_dbsm", "s_rcs", "radar_cross_section")
#: Detection-list element fields: quantity -> accepted names (lower case, '_' removed).
LIST_FIELDS: dict[str, tuple[str, ...]] = {
    "range": ("range", "frange", "distance", "radialdistance"),
    "azimuth": ("azimuth", "azimuthangle", "fazimuthangle", "azimuthrad"),
    "elevation": ("elevation", "elevationangle", "felevationangle", "elevationrad"),
    "range_rate": ("rangerate", "frangerate", "dopplervelocity", "doppler", "radialvelocity",
                   "vr"),
    "rcs": ("rcs", "srcs", "frcs"),
}
#: sensor_msgs/PointField datatype -> numpy type.
_POINTFIELD_TYPES: dict[int, str] = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4",
                                     7: "f4", 8: "f8"}


def _rosbags():
    try:
        from rosbags.rosbag2 import Reader
        from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
    except ImportError:
        raise InputError(None, "reading ROS 2 bags needs rosbags: pip install 'fgloc[ros]'") \
            from None
    return Reader, Stores, get_types_from_idl, get_types_from_msg, get_typestore


def read_rosbag_radar(
    bag: str | Path,
    topic: str,
    *,
    doppler_field: str | None = None,
    negate_doppler: bool = False,
    msg_defs: Sequence[str | Path] = (),
) -> RadarData:
    """Read the radar detections of ``topic`` in a ROS 2 bag (directory, ``.mcap`` or
    ``.db3``) into :class:`RadarData` in the sensor frame.

    negate_doppler: flip the sign for drivers whose range rate is positive towards the
    sensor (fgloc's doppler is positive away from it). Raises :class:`InputError` naming the
    bag and the topic for an unknown topic (listing the topics), an unsupported message type,
    a PointCloud2 without a range-rate field (listing its fields) or no detections.
    """
    Reader, Stores, from_idl, from_msg, get_typestore = _rosbags()
    p = Path(bag)
    if not p.exists():
        raise InputError(p, "bag not found")
    frames_t: list[float] = []
    parts: list[np.ndarray] = []  # (n, 5) x, y, z, doppler, rcs per message
    try:
        with Reader(p) as reader:
            conns = [c for c in reader.connections if c.topic == topic]
            if not conns:
                topics = ", ".join(f"{c.topic} ({c.msgtype})" for c in reader.connections)
                raise InputError(p, f"no topic {topic!r} in the bag; topics: {topics or 'none'}",
                                 field="--topic")
            store = get_typestore(Stores.LATEST)
            types: dict[str, Any] = {}
            for c in conns:
                types.update(_bag_definitions(c, from_msg, from_idl))
            for path in msg_defs:
                types.update(_msg_file_types(Path(path), from_msg))
            store.register(types)
            for conn, stamp_ns, raw in reader.messages(connections=conns):
                try:
                    msg = store.deserialize_cdr(raw, conn.msgtype)
                except Exception as exc:  # rosbags raises KeyError/SerdeError for unknown types
                    raise InputError(
                        p, f"cannot decode {conn.msgtype} ({type(exc).__name__}: {exc}); give "
                        "its definition with --msg-def .../<package>/msg/<Name>.msg",
                        field=topic) from None
                parts.append(_detections(p, topic, conn.msgtype, msg, doppler_field))
                frames_t.append(_stamp(msg, stamp_ns))
    except InputError:
        raise
    except Exception as exc:  # rosbags ReaderError, sqlite3/mcap errors, YAML errors...
        raise InputError(p, f"not a readable ROS 2 bag: {type(exc).__name__}: {exc}") from None
    return _radar_data(p, topic, frames_t, parts, negate_doppler)


def _bag_definitions(conn: Any, from_msg, from_idl) -> dict[str, Any]:
    fmt = getattr(conn.msgdef.format, "name", "NONE")
    text = conn.msgdef.data
    if fmt == "MSG" and text:
        return from_msg(text, conn.msgtype)
    if fmt == "IDL" and text:
        return from_idl(text)
    return {}


def _msg_file_types(path: Path, from_msg) -> dict[str, Any]:
    """Types of one ``.msg`` file; its name is ``<package>/msg/<Name>`` from the path."""
    if path.suffix != ".msg" or len(path.parts) < 3 or path.parent.name != "msg":
        raise InputError(path, "expected a .msg file at .../<package>/msg/<Name>.msg",
                         field="--msg-def")
    name = f"{path.parent.parent.name}/msg/{path.stem}"
    try:
        return from_msg(path.read_text(encoding="utf-8"), name)
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc}", field="--msg-def") from None
    except Exception as exc:  # rosbags TypesysError on a bad definition
        raise InputError(path, f"not a valid message definition: {exc}",
                         field="--msg-def") from None


def _stamp(msg: Any, bag_ns: int) -> float:
    """header.stamp in s, or the bag receive time when the message has no (or a zero) stamp."""
    stamp = getattr(getattr(msg, "header", None), "stamp", None)
    if stamp is not None and (stamp.sec or stamp.nanosec):
        return stamp.sec + stamp.nanosec * 1e-9
    return bag_ns * 1e-9


def _detections(bag: Path, topic: str, msgtype: str, msg: Any,
                doppler_field: str | None) -> np.ndarray:
    """(n, 5) x, y, z, doppler, rcs (NaN when absent) of one message."""
    if msgtype == POINTCLOUD2:
        return _pointcloud2(bag, topic, msg, doppler_field)
    found = _detection_array(msg)
    if found is None:
        raise InputError(
            bag, f"unsupported message type {msgtype}: expected {POINTCLOUD2} or a detection "
            "list (an array of detections with range, azimuth, elevation and range rate)",
            field=topic)
    items, fields = found
    if not items:
        return np.zeros((0, 5))
    cols = {q: np.array([getattr(it, f) for it in items], dtype=np.float64)
            for q, f in fields.items()}
    r, az, el = cols["range"], cols["azimuth"], cols["elevation"]
    return np.column_stack([
        r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el),
        cols["range_rate"], cols.get("rcs", np.full(len(r), np.nan)),
    ])


def _detection_array(msg: Any) -> tuple[list, dict[str, str]] | None:
    """(detections, quantity -> attribute) of the first array field of ``msg`` whose elements
    carry range, azimuth, elevation and range rate; ([], {}) when every array of the message
    is empty; None when it has no such array."""
    if not dataclasses.is_dataclass(msg):
        return None
    empty = False
    for f in dataclasses.fields(msg):
        value = getattr(msg, f.name)
        if not isinstance(value, list):
            continue
        if not value:
            empty = True
            continue
        if not dataclasses.is_dataclass(value[0]):
            continue
        names = {g.name.lower().replace("_", ""): g.name for g in dataclasses.fields(value[0])}
        chosen = {q: next((names[a] for a in alts if a in names), None)
                  for q, alts in LIST_FIELDS.items()}
        if all(chosen[q] for q in ("range", "azimuth", "elevation", "range_rate")):
            return value, {q: a for q, a in chosen.items() if a}
    return ([], {}) if empty else None


def _pointcloud2(bag: Path, topic: str, msg: Any, doppler_field: str | None) -> np.ndarray:
    fields = {f.name: f for f in msg.fields}
    lower = {n.lower(): n for n in fields}

    def pick(alts: Iterable[str]) -> str | None:
        return next((lower[a] for a in alts if a in lower), None)

    wanted = (doppler_field.lower(),) if doppler_field else DOPPLER_FIELDS
    dop = pick(wanted)
    missing = [a for a in ("x", "y", "z") if a not in lower]
    if dop is None or missing:
        need = (f"the field {doppler_field!r}" if doppler_field else
                "a range-rate field (one of " + ", ".join(DOPPLER_FIELDS) + ")")
        need = need if not missing else "fields " + ", ".join(missing)
        raise InputError(
            bag, f"PointCloud2 has fields {', '.join(fields) or 'none'}; expected x, y, z and "
            f"{need}" + ("" if doppler_field or missing else "; name it with --doppler-field"),
            field=topic)
    rcs = pick(RCS_FIELDS)
    order = ">" if msg.is_bigendian else "<"
    names = [lower["x"], lower["y"], lower["z"], dop] + ([rcs] if rcs else [])
    for n in names:
        if fields[n].datatype not in _POINTFIELD_TYPES or fields[n].count != 1:
            raise InputError(bag, f"PointCloud2 field {n!r} has datatype {fields[n].datatype} "
                             f"x{fields[n].count}; expected one number", field=topic)
    dtype = np.dtype({
        "names": names,
        "formats": [order + _POINTFIELD_TYPES[fields[n].datatype] for n in names],
        "offsets": [fields[n].offset for n in names],
        "itemsize": msg.point_step,
    })
    n_points = msg.width * msg.height
    data = np.asarray(msg.data, dtype=np.uint8)
    if msg.height > 1 and msg.row_step != msg.width * msg.point_step:
        data = data.reshape(msg.height, msg.row_step)[:, : msg.width * msg.point_step]
    if data.size < n_points * msg.point_step:
        raise InputError(bag, f"PointCloud2 holds {data.size} bytes, expected "
                         f"{n_points} points x {msg.point_step}", field=topic)
    pts = np.frombuffer(np.ascontiguousarray(data).tobytes()[: n_points * msg.point_step],
                        dtype=dtype, count=n_points)
    cols = [pts[n].astype(np.float64) for n in names]
    if not rcs:
        cols.append(np.full(n_points, np.nan))
    return np.column_stack(cols) if n_points else np.zeros((0, 5))


def _radar_data(bag: Path, topic: str, frames_t: list[float], parts: list[np.ndarray],
                negate: bool) -> RadarData:
    if not parts:
        raise InputError(bag, "the topic has no messages", field=topic)
    counts = np.array([len(a) for a in parts])
    det = np.vstack(parts)
    t = np.repeat(np.asarray(frames_t), counts)
    frame = np.repeat(np.arange(len(parts)), counts)
    has_rcs = bool(np.isfinite(det[:, 4]).any())
    core = det[:, :4] if not has_rcs else det
    good = np.isfinite(core).all(axis=1)
    if not good.all():
        log.warning("%s: dropped %d detections with non-finite values", bag, int((~good).sum()))
    det, t, frame = det[good], t[good], frame[good]
    if len(det) == 0:
        raise InputError(bag, f"no detections in {len(parts)} messages", field=topic)
    rank = np.empty(len(parts), dtype=np.int64)  # messages renumbered in time order
    rank[np.argsort(np.asarray(frames_t), kind="stable")] = np.arange(len(parts))
    frame = rank[frame]
    order = np.argsort(frame, kind="stable")
    det, t, frame = det[order], t[order], frame[order]
    doppler = -det[:, 3] if negate else det[:, 3]
    return RadarData(t=t, xyz=det[:, :3].copy(), doppler=doppler.copy(),
                     rcs=det[:, 4].copy() if has_rcs else None,
                     frame=frame)


def import_rosbag(
    bag: str | Path,
    topic: str,
    out: str | Path,
    *,
    als: Sequence[str | Path] = (),
    map_file: str | Path | None = None,
    sensor: str | Path | None = None,
    ground_truth: str | Path | None = None,
    **read_options: Any,
) -> tuple[RadarData, list[str]]:
    """Write a scenario directory ``out`` from a bag: ``radar.csv`` from ``topic`` (options of
    :func:`read_rosbag_radar`), plus copies of the files a bag cannot hold: ``als`` (tile
    files or directories of tiles) into ``als/``, ``map_file`` to ``map.osm``, ``sensor`` to
    ``sensor.toml`` (validated), ``ground_truth`` to ``ground_truth.json``.

    Every input is checked before anything is written; the files appear in ``out`` only when
    all are written (each by an atomic rename). Returns the radar data and the written names.
    """
    from fgloc.io.als import find_als_tiles
    from fgloc.io.radar import write_radar
    from fgloc.io.sensor_file import read_sensor_toml
    from fgloc.outputs import staged_dir

    copies: list[tuple[Path, str]] = []
    for src in als:
        sp = Path(src)
        tiles = find_als_tiles(sp) if sp.is_dir() else [sp]
        for tile in tiles:
            if not tile.is_file() or tile.suffix.lower() not in (".las", ".laz"):
                raise InputError(tile, "expected a .las/.laz tile or a directory of them",
                                 field="--als")
            copies.append((tile, f"als/{tile.name}"))
    for src, name, flag in ((map_file, "map.osm", "--map"), (sensor, "sensor.toml", "--sensor"),
                            (ground_truth, "ground_truth.json", "--ground-truth")):
        if src is not None:
            if not Path(src).is_file():
                raise InputError(src, "file not found", field=flag)
            copies.append((Path(src), name))
    if sensor is not None:
        read_sensor_toml(sensor)
    radar = read_rosbag_radar(bag, topic, **read_options)
    with staged_dir(out) as tmp:
        write_radar(tmp / "radar.csv", radar)
        for src, name in copies:
            (tmp / name).parent.mkdir(exist_ok=True)
            shutil.copyfile(src, tmp / name)
    return radar, ["radar.csv"] + [name for _, name in copies]
