"""A scenario directory (DESIGN.md "Scenario directory") <-> :class:`Scenario`.

Layout: ``radar.csv`` (or ``radar.npz`` / ``radar.parquet``), ``als/*.las|*.laz``,
``map.osm``, ``sensor.toml`` and the optional ``ground_truth.json``.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from fgloc.errors import InputError
from fgloc.geo import LocalFrame
from fgloc.io.als import ALS_SUFFIXES, find_als_tiles, read_als, write_als
from fgloc.io.atomic import current_umask, write_text_atomic
from fgloc.io.ground_truth import read_ground_truth, write_ground_truth
from fgloc.io.lanelet_map import als_ground, read_lanelet_map, write_lanelet_map
from fgloc.io.radar import read_radar, write_radar
from fgloc.io.sensor_file import read_sensor_toml, write_sensor_toml
from fgloc.scenario import Scenario, SensorConfig

SENSOR_FILE = "sensor.toml"
MAP_FILE = "map.osm"
ALS_DIR = "als"
GROUND_TRUTH_FILE = "ground_truth.json"
#: Radar file names in order of preference.
RADAR_FILES: tuple[str, ...] = ("radar.csv", "radar.npz", "radar.parquet")
#: Edge (m) of the square ALS tiles written by :func:`write_scenario`, aligned to the grid.
ALS_TILE_SIZE = 1000.0


def find_radar_file(scenario_dir: str | Path) -> Path:
    """The scenario's radar file: ``radar.csv``, else ``radar.npz``, else ``radar.parquet``."""
    d = Path(scenario_dir)
    for name in RADAR_FILES:
        if (d / name).is_file():
            return d / name
    raise InputError(d / RADAR_FILES[0], "radar file not found (also looked for "
                     f"{', '.join(RADAR_FILES[1:])})")


def load_scenario(path: str | Path) -> Scenario:
    """Load a scenario directory into the local frame L (see docs/formats.md).

    The world CRS is sensor.toml's ``crs`` if present, else the ALS tiles' CRS. The local
    origin is (round(E), round(N), Z0) of sensor.toml's approx_position, Z0 the rounded median
    ALS height of classes 2/11 within 100 m (else of all points). Every problem is an
    :class:`InputError` naming the file.
    """
    d = Path(path)
    if not d.is_dir():
        raise InputError(d, "scenario directory not found")
    sensor = read_sensor_toml(d / SENSOR_FILE)
    radar = read_radar(find_radar_file(d))
    if not (d / MAP_FILE).is_file():
        raise InputError(d / MAP_FILE, "Lanelet2 map not found")
    als, frame = read_als(
        find_als_tiles(d / ALS_DIR), sensor.approx_position, sensor.crs,
        config_path=d / SENSOR_FILE,
    )
    lo, hi = als.xyz[:, :2].min(axis=0), als.xyz[:, :2].max(axis=0)
    bbox = (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
    _check_sensor_near_als(d / SENSOR_FILE, sensor, frame, bbox)
    lanelets = read_lanelet_map(d / MAP_FILE, frame.crs, frame, overlap_bbox=bbox,
                                settings=sensor.map, ground=als_ground(als))
    gt_path = d / GROUND_TRUTH_FILE
    truth = read_ground_truth(gt_path, frame) if gt_path.is_file() else None
    return Scenario(frame=frame, sensor=sensor, radar=radar, als=als, lanelets=lanelets,
                    truth=truth, path=d)


def _check_sensor_near_als(
    path: Path, sensor: SensorConfig, frame: LocalFrame, bbox: tuple[float, float, float, float]
) -> None:
    """The approximate position must lie within ``max_range`` of the ALS bounding box (bbox in
    L): otherwise the sensor cannot see the scanned road (wrong position, CRS or tiles)."""
    e, n = (float(v) for v in sensor.approx_position)
    x, y = e - frame.origin[0], n - frame.origin[1]
    dx = max(bbox[0] - x, 0.0, x - bbox[2])
    dy = max(bbox[1] - y, 0.0, y - bbox[3])
    gap = float(np.hypot(dx, dy))
    if gap > sensor.max_range:
        (e0, n0), (e1, n1) = frame.to_world(np.array([bbox[:2], bbox[2:]]))[:, :2].tolist()
        raise InputError(
            path,
            f"approx_position ({e:.1f}, {n:.1f}) lies {gap:.0f} m from the ALS tiles "
            f"(E {e0:.0f}..{e1:.0f}, N {n0:.0f}..{n1:.0f} in {frame.crs}), farther than "
            f"max_range {sensor.max_range:g} m: wrong position, CRS or tiles?",
            field="sensor.approx_position",
        )


def write_scenario(scn: Scenario, out_dir: str | Path, *, radar_format: str = "csv",
                   map_osm: str | None = None, extra_files: dict[str, str] | None = None) -> None:
    """Write ``scn`` as a scenario directory.

    radar_format: "csv", "npz" or "parquet". The ALS goes to ``als/<E_km>_<N_km>.laz`` tiles of
    :data:`ALS_TILE_SIZE` m aligned to the world grid. A new ``out_dir`` is written as a
    hidden sibling directory and renamed into place; in an existing one every file is replaced
    atomically, then stale scenario files (other radar formats, ALS tiles not written now, a
    ground truth when ``scn.truth`` is None) are removed. ``map_osm``: the text to write as
    map.osm instead of serializing ``scn.lanelets`` (e.g. a real map's crop, which must hold the
    same lanelets); ``extra_files``: further text files (name -> text), e.g. a map's licence.
    """
    if radar_format not in ("csv", "npz", "parquet"):
        raise ValueError(f"radar_format must be csv, npz or parquet, got {radar_format!r}")
    out = Path(out_dir)
    if out.exists():
        if not out.is_dir():
            raise InputError(out, "exists and is not a directory")
        written = _write_files(scn, out, radar_format, map_osm, extra_files or {})
        _remove_stale(out, written)
        return
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    os.chmod(tmp, 0o777 & ~current_umask())  # mkdtemp makes 0700; give the usual mode
    try:
        _write_files(scn, tmp, radar_format, map_osm, extra_files or {})
        os.rename(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _write_files(scn: Scenario, d: Path, radar_format: str, map_osm: str | None,
                 extra_files: dict[str, str]) -> set[Path]:
    """Write every file of ``scn`` into ``d``; return the paths written."""
    frame = scn.frame
    written = {d / SENSOR_FILE, d / f"radar.{radar_format}", d / MAP_FILE}
    write_sensor_toml(d / SENSOR_FILE, scn.sensor)
    write_radar(d / f"radar.{radar_format}", scn.radar)
    if map_osm is None:
        write_lanelet_map(d / MAP_FILE, scn.lanelets, frame)
    else:
        write_text_atomic(d / MAP_FILE, map_osm)
    for name, text in extra_files.items():
        if Path(name).name != name or name.startswith("."):
            raise ValueError(f"extra file names must be plain file names, got {name!r}")
        write_text_atomic(d / name, text)
        written.add(d / name)
    world = frame.to_world(scn.als.xyz)
    keys = np.floor(world[:, :2] / ALS_TILE_SIZE).astype(np.int64)
    tiles, inverse = np.unique(keys, axis=0, return_inverse=True)
    order = np.argsort(inverse.reshape(-1), kind="stable")
    bounds = np.searchsorted(inverse.reshape(-1)[order], np.arange(len(tiles) + 1))
    for k, (ke, kn) in enumerate(tiles.tolist()):
        sel = order[bounds[k] : bounds[k + 1]]
        name = f"{int(ke * ALS_TILE_SIZE) // 1000}_{int(kn * ALS_TILE_SIZE) // 1000}.laz"
        path = d / ALS_DIR / name
        write_als(path, world[sel], scn.als.classification[sel], frame.crs)
        written.add(path)
    if scn.truth is not None:
        write_ground_truth(d / GROUND_TRUTH_FILE, scn.truth, frame)
        written.add(d / GROUND_TRUTH_FILE)
    return written


def _remove_stale(d: Path, written: set[Path]) -> None:
    stale = [d / name for name in RADAR_FILES] + [d / GROUND_TRUTH_FILE]
    als_dir = d / ALS_DIR
    if als_dir.is_dir():
        stale += [p for p in als_dir.iterdir() if p.suffix.lower() in ALS_SUFFIXES]
    for p in stale:
        if p not in written and p.is_file():
            p.unlink()
