"""``ground_truth.json`` (world frame) <-> :class:`GroundTruth` (local frame L).

File layout::

    {"crs": "EPSG:25832",
     "sensor": {"x": E, "y": N, "z": h, "yaw_deg": .., "pitch_deg": .., "roll_deg": ..},
     "tracks": [{"id": 1, "length": 4.5, "width": 1.8,
                 "states": [[t, x, y, yaw, v, yawrate], ...]}]}

x/y/z in m in the world CRS; yaw_deg CCW from grid east, pitch_deg > 0 = boresight down,
``R = Rz(yaw) Ry(pitch) Rx(roll)``; track yaw in rad CCW from grid east, v in m/s, yawrate
in rad/s, t in s. ``tracks`` is required (the true vehicles; an empty list when there were
none) and every track needs at least one state.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from fgloc.errors import InputError
from fgloc.geo import LocalFrame, parse_crs, pose_from_se3, same_crs, se3_from_pose
from fgloc.io.atomic import write_text_atomic
from fgloc.io.json_file import read_json
from fgloc.scenario import GroundTruth, TrackTruth

SENSOR_KEYS: tuple[str, ...] = ("x", "y", "z", "yaw_deg", "pitch_deg", "roll_deg")
TRACK_KEYS: tuple[str, ...] = ("id", "length", "width", "states")
#: Largest distance (m) of a ground-truth position from the local origin (the approximate
#: sensor position): farther means another site, CRS or unit.
MAX_DISTANCE = 10_000.0


def read_ground_truth(path: str | Path, frame: LocalFrame) -> GroundTruth:
    """Read ground truth and convert it to L of ``frame``.

    Its ``crs`` must describe the same horizontal CRS as ``frame.crs``. Raises
    :class:`InputError` (with the line for JSON syntax errors, the dotted field otherwise) for
    bad JSON, missing keys, wrong types, non-finite numbers or states not shaped (n, 6).
    """
    p = Path(path)
    data = read_json(p)
    _require_keys(p, data, ("crs", "sensor", "tracks"), "")
    crs = data["crs"]
    if not isinstance(crs, str):
        raise InputError(p, f"expected a string, got {crs!r}", field="crs")
    try:
        parse_crs(crs)
    except ValueError as exc:
        raise InputError(p, str(exc), field="crs") from None
    if not same_crs(crs, frame.crs):
        raise InputError(
            p, f"ground truth CRS {crs} differs from the scenario's world CRS {frame.crs}",
            field="crs",
        )
    sensor = data["sensor"]
    _require_keys(p, sensor, SENSOR_KEYS, "sensor.")
    x, y, z, yaw, pitch, roll = (_number(p, sensor[k], f"sensor.{k}") for k in SENSOR_KEYS)
    for key, value, origin in (("x", x, frame.origin[0]), ("y", y, frame.origin[1])):
        _check_near(p, np.array([value]), origin, f"sensor.{key}")
    pose_w = se3_from_pose(x, y, z, math.radians(yaw), math.radians(pitch), math.radians(roll))
    tracks_raw = data["tracks"]
    if not isinstance(tracks_raw, list):
        raise InputError(p, "expected a list of tracks", field="tracks")
    tracks = [_read_track(p, tr, frame, f"tracks[{k}].") for k, tr in enumerate(tracks_raw)]
    seen: dict[int, int] = {}
    for k, tr in enumerate(tracks):
        if tr.id in seen:
            raise InputError(p, f"track id {tr.id} appears twice (also tracks[{seen[tr.id]}])",
                             field=f"tracks[{k}].id")
        seen[tr.id] = k
    return GroundTruth(crs=crs, sensor_pose=frame.pose_to_local(pose_w), tracks=tracks)


def _read_track(path: Path, tr: Any, frame: LocalFrame, prefix: str) -> TrackTruth:
    _require_keys(path, tr, TRACK_KEYS, prefix)
    tid = tr["id"]
    if isinstance(tid, bool) or not isinstance(tid, int):
        raise InputError(path, f"expected an integer, got {tid!r}", field=f"{prefix}id")
    length = _number(path, tr["length"], f"{prefix}length")
    width = _number(path, tr["width"], f"{prefix}width")
    for key, value in (("length", length), ("width", width)):
        if not value > 0.0:
            raise InputError(path, f"a vehicle {key} must be > 0 m, got {value!r}",
                             field=f"{prefix}{key}")
    rows = tr["states"]
    ok = isinstance(rows, list) and all(
        isinstance(r, list) and len(r) == 6
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in r)
        for r in rows
    )
    if not ok or not rows:
        raise InputError(
            path, "expected a non-empty list of [t, x, y, yaw, v, yawrate] number rows (n, 6)",
            field=f"{prefix}states",
        )
    states = np.array(rows, dtype=np.float64).reshape(-1, 6)
    bad = ~np.isfinite(states).all(axis=1)
    if bad.any():
        raise InputError(path, "non-finite value", field=f"{prefix}states[{int(np.argmax(bad))}]")
    back = np.diff(states[:, 0]) <= 0
    if back.any():
        i = int(np.argmax(back)) + 1
        raise InputError(path, f"t must increase along a track ({states[i, 0]!r} after "
                         f"{states[i - 1, 0]!r})", field=f"{prefix}states[{i}]")
    _check_near(path, states[:, 1], frame.origin[0], f"{prefix}states", "x")
    _check_near(path, states[:, 2], frame.origin[1], f"{prefix}states", "y")
    states[:, 1:3] -= np.asarray(frame.origin[:2])
    return TrackTruth(id=tid, length=length, width=width, states=states)


def _check_near(path: Path, values: np.ndarray, origin: float, field: str, what: str = "") -> None:
    """World coordinates must lie within :data:`MAX_DISTANCE` m of the scenario's origin."""
    far = np.abs(values - origin) > MAX_DISTANCE
    if far.any():
        i = int(np.argmax(far))
        where = f"{field}[{i}]" if what else field
        raise InputError(
            path, f"{what + ' ' if what else ''}{float(values[i])!r} lies more than "
            f"{MAX_DISTANCE:g} m from the sensor's approx_position: another site or CRS?",
            field=where,
        )


def _require_keys(path: Path, obj: Any, keys: tuple[str, ...], prefix: str) -> None:
    if not isinstance(obj, dict):
        raise InputError(path, f"expected an object, got {type(obj).__name__}",
                         field=prefix.rstrip(".") or None)
    for k in keys:
        if k not in obj:
            raise InputError(path, "missing key", field=f"{prefix}{k}")


def _number(path: Path, value: Any, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InputError(path, f"expected a finite number, got {value!r}", field=key)
    return float(value)


def write_ground_truth(path: str | Path, truth: GroundTruth, frame: LocalFrame) -> None:
    """Write ground truth (given in L of ``frame``) in world coordinates, atomically."""
    x, y, z, yaw, pitch, roll = pose_from_se3(frame.pose_to_world(truth.sensor_pose))
    sensor = {"x": x, "y": y, "z": z, "yaw_deg": math.degrees(yaw),
              "pitch_deg": math.degrees(pitch), "roll_deg": math.degrees(roll)}
    tracks = []
    for tr in truth.tracks:
        states = np.array(tr.states, dtype=np.float64).reshape(-1, 6)
        states[:, 1:3] += np.asarray(frame.origin[:2])
        head = json.dumps({"id": int(tr.id), "length": float(tr.length), "width": float(tr.width)})
        rows = ",\n    ".join(json.dumps(r) for r in states.tolist())
        tracks.append(f'  {head[:-1]}, "states": [\n    {rows}]}}')
    body = ",\n".join(tracks)
    text = (
        f'{{"crs": {json.dumps(truth.crs)},\n "sensor": {json.dumps(sensor)},\n'
        f' "tracks": [\n{body}\n ]}}\n'
    )
    write_text_atomic(path, text)
