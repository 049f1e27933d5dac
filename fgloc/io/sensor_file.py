"""``sensor.toml`` <-> :class:`SensorConfig`.

Top level: optional ``crs`` (the world CRS). Table ``[sensor]``: ``approx_position = [E, N]``
(required, world CRS, m), optional ``approx_height`` (m above the road), ``yaw_guess_deg``
(degrees CCW from grid east), ``hfov_deg`` / ``vfov_deg`` (degrees), ``max_range`` (m).
Optional table ``[map]``: how map.osm is read (:class:`fgloc.scenario.MapSettings`):
``location`` / ``participant`` of lanelet2's traffic rules, ``local_crs`` / ``local_offset`` for
maps with ``local_x`` / ``local_y`` node tags.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

from fgloc.config import dumps_toml, from_dict, read_toml
from fgloc.errors import InputError
from fgloc.io._crs import canonical_world_crs
from fgloc.io.atomic import write_text_atomic
from fgloc.scenario import MapSettings, SensorConfig

#: Largest |E| or |N| (m) accepted for approx_position (projected CRS coordinates, including
#: zone-prefixed eastings such as EPSG:4647's 32 500 000 m, stay far below it).
MAX_COORDINATE = 1e8


@dataclass
class _SensorTable:
    """The ``[sensor]`` table as written in the file (validated by fgloc.config.from_dict)."""

    approx_position: tuple[float, float] | None = None
    approx_height: float | None = None
    yaw_guess_deg: float | None = None
    hfov_deg: float = SensorConfig.hfov_deg
    vfov_deg: float = SensorConfig.vfov_deg
    max_range: float = SensorConfig.max_range


@dataclass
class _MapTable:
    """The optional ``[map]`` table (see :class:`fgloc.scenario.MapSettings`)."""

    location: str = MapSettings.location
    participant: str = MapSettings.participant
    local_crs: str | None = None
    local_offset: tuple[float, float] = MapSettings.local_offset


@dataclass
class _SensorFile:
    crs: str | None = None
    sensor: _SensorTable = field(default_factory=_SensorTable)
    map: _MapTable = field(default_factory=_MapTable)


def read_sensor_toml(path: str | Path) -> SensorConfig:
    """Read and validate ``sensor.toml``.

    Raises :class:`InputError` naming the dotted key for unknown keys, wrong types, a missing
    ``[sensor] approx_position``, non-finite numbers, out-of-range values (|E|, |N| <=
    :data:`MAX_COORDINATE`, 0 < hfov_deg <= 360, 0 < vfov_deg <= 180, max_range > 0) and an
    invalid or non-projected ``crs``. ``crs`` stays as written (None when absent).
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(p, "sensor file not found")
    raw = from_dict(_SensorFile, read_toml(p), p)
    s = raw.sensor
    if s.approx_position is None:
        raise InputError(p, "missing required key ([sensor] approx_position = [E, N])",
                         field="sensor.approx_position")
    if raw.crs is not None:
        canonical_world_crs(raw.crs, p, "crs")
    numbers = asdict(s)
    for key, value in numbers.items():
        values = value if isinstance(value, tuple) else (value,)
        if not all(v is None or math.isfinite(v) for v in values):
            raise InputError(p, f"must be finite, got {value!r}", field=f"sensor.{key}")
    ranges = {
        "approx_position": (
            all(abs(v) <= MAX_COORDINATE for v in s.approx_position),
            f"projected coordinates within +-{MAX_COORDINATE:g} m (E, N in the world CRS)",
        ),
        "hfov_deg": (0.0 < s.hfov_deg <= 360.0, "in (0, 360]"),
        "vfov_deg": (0.0 < s.vfov_deg <= 180.0, "in (0, 180]"),
        "max_range": (s.max_range > 0.0, "> 0"),
    }
    for key, (ok, expected) in ranges.items():
        if not ok:
            raise InputError(p, f"must be {expected}, got {numbers[key]!r}", field=f"sensor.{key}")
    m = raw.map
    if m.local_crs is not None:
        canonical_world_crs(m.local_crs, p, "map.local_crs")
    if not all(math.isfinite(v) and abs(v) <= MAX_COORDINATE for v in m.local_offset):
        raise InputError(p, f"must be finite coordinates within +-{MAX_COORDINATE:g} m, got "
                         f"{m.local_offset!r}", field="map.local_offset")
    for key in ("location", "participant"):
        if not getattr(m, key).strip():
            raise InputError(p, "must not be empty", field=f"map.{key}")
    settings = MapSettings(m.location, m.participant, m.local_crs,
                           tuple(float(v) for v in m.local_offset))
    return SensorConfig(crs=raw.crs, **numbers, map=settings)


def write_sensor_toml(path: str | Path, sensor: SensorConfig) -> None:
    """Write ``sensor.toml`` atomically (optional fields that are None are left out)."""
    table = {k: v for k, v in asdict(sensor).items() if k not in ("crs", "map")}
    table["approx_position"] = [float(v) for v in sensor.approx_position]
    data: dict[str, object] = {} if sensor.crs is None else {"crs": sensor.crs}
    # float(): numpy scalars would otherwise be written as "np.float64(...)"
    data["sensor"] = {
        k: (v if isinstance(v, list) else float(v)) for k, v in table.items() if v is not None
    }
    if sensor.map != MapSettings():
        data["map"] = {k: (list(v) if isinstance(v, tuple) else v)
                       for k, v in asdict(sensor.map).items() if v is not None}
    write_text_atomic(path, dumps_toml(data))
