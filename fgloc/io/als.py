"""ALS tiles: ``als/*.las|*.laz`` <-> :class:`AlsCloud` in the local frame L.

Reading resolves the world CRS (sensor.toml `crs`, else the tiles' CRS), fixes the local origin
(E0, N0 from the approximate sensor position, Z0 from the ALS road heights) and streams the
points chunk by chunk into preallocated float32 arrays in L: the float64 world coordinates
exist for one chunk at a time only.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import laspy
import numpy as np

from fgloc.errors import InputError
from fgloc.geo import LocalFrame, parse_crs, same_crs
from fgloc.io._crs import canonical_world_crs
from fgloc.io.atomic import atomic_path
from fgloc.order_stats import median_inplace
from fgloc.progress import quiet
from fgloc.scenario import GROUND_CLASSES, AlsCloud

log = logging.getLogger(__name__)

ALS_SUFFIXES: tuple[str, ...] = (".las", ".laz")
#: Radius (m) around the approximate position whose ground/road points define Z0.
Z0_RADIUS = 100.0
#: Points per chunk when streaming a tile.
CHUNK_POINTS = 1_000_000
#: Single-threaded LAZ decompression (as fast per chunk here, and the memory of one chunk
#: instead of one per decompression thread); None lets laspy choose when lazrs is missing.
_LAZ_BACKEND = laspy.LazBackend.Lazrs if laspy.LazBackend.Lazrs.is_available() else None


@dataclass(frozen=True)
class _Tile:
    path: Path
    point_count: int
    crs: str | None
    """The tile's CRS as WKT, None when the file has none (or an unreadable one)."""


def find_als_tiles(als_dir: str | Path) -> list[Path]:
    """Every ``*.las`` / ``*.laz`` (any case) directly in ``als_dir``, sorted by name.

    Hidden files (leading dot, e.g. temporaries of an interrupted write) are skipped.
    """
    d = Path(als_dir)
    if not d.is_dir():
        raise InputError(d, "ALS directory not found (expected als/ with .las/.laz tiles)")
    tiles = sorted(
        p
        for p in d.iterdir()
        if p.is_file() and p.suffix.lower() in ALS_SUFFIXES and not p.name.startswith(".")
    )
    if not tiles:
        raise InputError(d, "no ALS tiles (*.las or *.laz) in this directory")
    return tiles


def _open_tile(path: Path) -> _Tile:
    try:
        with quiet("laspy"), laspy.open(path) as reader:
            header = reader.header
            count = int(header.point_count)
            try:
                crs = header.parse_crs()
            except Exception as exc:  # laspy/pyproj raise various types for odd GeoTIFF keys
                log.warning("%s: ignoring an unreadable CRS record (%s)", path, exc)
                crs = None
    except Exception as exc:  # laspy/lazrs: LaspyException, OSError, LazrsError...
        raise InputError(path, f"not a readable LAS/LAZ file: {exc}") from None
    return _Tile(path, count, None if crs is None else crs.to_wkt())


def _resolve_world_crs(
    tiles: Sequence[_Tile], configured: str | None, config_path: str | Path = "sensor.toml"
) -> str:
    """The world CRS: ``configured`` (sensor.toml ``crs``) if given, else the tiles' CRS.

    Every tile's horizontal CRS must equal it (compound CRS such as ``EPSG:25832+7837`` match
    ``EPSG:25832``); a tile without CRS needs ``configured``. Returns the canonical string of
    the horizontal CRS (``"EPSG:25832"``).
    """
    reference: tuple[str, str | Path] | None = None  # (crs, where it came from)
    if configured is not None:
        reference = (configured, config_path)
    for tile in tiles:
        if tile.crs is None:
            if configured is None:
                raise InputError(
                    tile.path,
                    f"the tile has no CRS and {config_path} sets no `crs`: add "
                    f'crs = "EPSG:25832" (or the right one) to {config_path}',
                )
            continue
        if reference is None:
            reference = (tile.crs, tile.path)
        elif not same_crs(tile.crs, reference[0]):
            raise InputError(
                tile.path,
                f"the tile's CRS {parse_crs(tile.crs).name!r} differs from the CRS "
                f"{parse_crs(reference[0]).name!r} of {reference[1]}",
            )
    assert reference is not None  # tiles is non-empty and each has a CRS or configured is set
    return canonical_world_crs(reference[0], reference[1], "crs" if configured else None)


def read_als(
    paths: Sequence[str | Path],
    approx_position: tuple[float, float],
    configured_crs: str | None = None,
    *,
    config_path: str | Path = "sensor.toml",
    z0: float | None = None,
    chunk_points: int = CHUNK_POINTS,
) -> tuple[AlsCloud, LocalFrame]:
    """Read ALS tiles into one cloud in the local frame L and return it with that frame.

    approx_position: (E, N) in the world CRS (sensor.toml). configured_crs: sensor.toml's
    ``crs`` or None; the world CRS follows :func:`_resolve_world_crs`. The frame's origin is
    ``(round(E), round(N), Z0)`` with Z0 = ``z0`` if given, else the rounded median height of
    the class 2/11 points within :data:`Z0_RADIUS` m of ``approx_position`` (all points when
    there are none). The frame's ``crs`` is the resolved world CRS string.
    """
    tiles = [_open_tile(Path(p)) for p in paths]
    if not tiles:
        raise InputError(None, "no ALS tiles given")
    crs = _resolve_world_crs(tiles, configured_crs, config_path)
    e0, n0 = float(round(approx_position[0])), float(round(approx_position[1]))
    total = sum(t.point_count for t in tiles)
    if total == 0:
        raise InputError(tiles[0].path, "the ALS tiles hold no points")
    xyz = np.empty((total, 3), dtype=np.float32)
    cls = np.empty(total, dtype=np.uint8)
    z_ref: float | None = None  # provisional integer height offset, fixed by the first chunk
    road_z: list[np.ndarray] = []  # heights - z_ref (float32) of ground/road points near E, N
    start = 0
    for tile in tiles:
        end = start + tile.point_count
        i = start
        try:
            with quiet("laspy"), laspy.open(tile.path, laz_backend=_LAZ_BACKEND) as reader:
                for chunk in reader.chunk_iterator(chunk_points):
                    m = len(chunk)
                    if i + m > end:
                        raise InputError(
                            tile.path, f"holds more points than its header's {tile.point_count}"
                        )
                    x, y, z = np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z)
                    c = np.asarray(chunk.classification, dtype=np.uint8)
                    if z_ref is None:
                        z_ref = float(round(float(np.median(z))))
                    xyz[i : i + m, 0] = x - e0
                    xyz[i : i + m, 1] = y - n0
                    xyz[i : i + m, 2] = z - z_ref
                    cls[i : i + m] = c
                    if z0 is None:
                        near = np.isin(c, GROUND_CLASSES) & (
                            (x - approx_position[0]) ** 2 + (y - approx_position[1]) ** 2
                            <= Z0_RADIUS**2
                        )
                        road_z.append((z[near] - z_ref).astype(np.float32))
                    i += m
        except InputError:
            raise
        except Exception as exc:  # corrupt LAZ stream, truncated file...
            raise InputError(
                tile.path, f"cannot read the points (truncated or corrupt LAS/LAZ file?): {exc}"
            ) from None
        if i != end:
            raise InputError(
                tile.path, f"holds {i - start} points, its header says {tile.point_count}"
            )
        start = end
    assert z_ref is not None
    if z0 is None:
        near_z = np.concatenate(road_z) if road_z else np.zeros(0, dtype=np.float32)
        del road_z[:]
        z0 = z_ref + median_inplace(near_z if near_z.size else xyz[:, 2].copy())
    z0 = float(round(z0))
    xyz[:, 2] -= np.float32(z0 - z_ref)
    frame = LocalFrame((e0, n0, z0), crs)
    return AlsCloud(xyz=xyz, classification=cls, source_files=[t.path for t in tiles]), frame


def write_als(
    path: str | Path, xyz_world: np.ndarray, classification: np.ndarray, crs: str
) -> None:
    """Write one LAS 1.4 / point format 6 tile atomically (``.laz`` compressed via lazrs).

    xyz_world: (N, 3) float64 world coordinates in ``crs`` (m); classification: (N,) ASPRS
    codes. Scale 0.001 m; offsets at the floor of the tile's minimum corner; CRS as a WKT VLR.
    """
    xyz = np.asarray(xyz_world, dtype=np.float64).reshape(-1, 3)
    cls = np.asarray(classification).reshape(-1)
    if cls.shape[0] != xyz.shape[0]:
        raise ValueError(f"{cls.shape[0]} classifications for {xyz.shape[0]} points")
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.full(3, 0.001)
    header.offsets = np.floor(xyz.min(axis=0)) if len(xyz) else np.zeros(3)
    header.add_crs(parse_crs(crs))
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.classification = cls.astype(np.uint8)
    with atomic_path(path) as tmp:
        las.write(tmp)
