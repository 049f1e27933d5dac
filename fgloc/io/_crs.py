"""World-CRS validation shared by the readers."""

from __future__ import annotations

from pathlib import Path

from pyproj import CRS

from fgloc.errors import InputError
from fgloc.geo import horizontal_crs, parse_crs


def canonical_world_crs(crs: str | CRS, path: str | Path | None, field: str | None = None) -> str:
    """Validate a world CRS and return its horizontal part as a string (``"EPSG:25832"``).

    The world CRS must be projected with metre axes; a compound CRS (e.g. ``EPSG:25832+7837``)
    is reduced to its horizontal part. Falls back to WKT when the CRS has no EPSG code.
    Raises :class:`InputError` naming ``path`` / ``field`` otherwise.
    """
    try:
        parsed = crs if isinstance(crs, CRS) else parse_crs(crs)
    except ValueError as exc:
        raise InputError(path, str(exc), field=field) from None
    h = horizontal_crs(parsed)
    units = {a.unit_name.lower() for a in h.axis_info}
    if not h.is_projected or not units <= {"metre", "meter"}:
        raise InputError(
            path,
            f"the world CRS must be projected with metre axes (e.g. EPSG:25832), got {h.name!r}",
            field=field,
        )
    epsg = h.to_epsg(min_confidence=90)
    return f"EPSG:{epsg}" if epsg is not None else h.to_wkt()
