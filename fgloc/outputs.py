"""Writing a localization's artifacts into an output directory, all or nothing."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from fgloc.labels import STRAIGHT
from fgloc.report import plot_overview, sensor_geojson
from fgloc.result import LocalizationResult
from fgloc.scenario import Scenario


@contextmanager
def staged_dir(out_dir: str | Path) -> Iterator[Path]:
    """Yield a temporary directory beside ``out_dir``; on success move its files into
    ``out_dir`` (each with an atomic ``os.replace``), on error delete it and leave ``out_dir``
    untouched."""
    out = Path(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    try:
        yield tmp
        out.mkdir(exist_ok=True)
        for p in sorted(tmp.rglob("*")):
            dest = out / p.relative_to(tmp)
            if p.is_dir():
                dest.mkdir(exist_ok=True)
            else:
                os.replace(p, dest)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def write_json(path: Path, doc: object) -> None:
    path.write_text(json.dumps(doc, indent=2, allow_nan=False) + "\n", encoding="utf-8")


def write_localization(out_dir: str | Path, scn: Scenario, res: LocalizationResult) -> list[Path]:
    """Write result.json, target.ply, source.ply, sensor.geojson, overview.png and, when the
    method tracked vehicles, tracks.csv; returns the written paths (in ``out_dir``)."""
    from fgloc.io.ply import write_labelled_ply
    from fgloc.io.tracks_csv import write_tracks_csv

    names: list[str] = []
    with staged_dir(out_dir) as tmp:
        write_json(tmp / "result.json", res.to_json())
        names.append("result.json")
        if res.target is not None:
            t = res.target
            write_labelled_ply(tmp / "target.ply", scn.frame.to_world(t.xyz), t.label, t.lanelet_id)
            names.append("target.ply")
        if res.source_xyz is not None:
            lab = res.source_label
            if lab is None:
                lab = np.full(len(res.source_xyz), STRAIGHT, dtype=np.int8)
            write_labelled_ply(tmp / "source.ply", scn.frame.to_world(res.source_xyz), lab)
            names.append("source.ply")
        if res.tracks is not None:
            write_tracks_csv(tmp / "tracks.csv", res.tracks, scn.frame)
            names.append("tracks.csv")
        s = scn.sensor
        write_json(tmp / "sensor.geojson", sensor_geojson(res, s.hfov_deg, s.max_range))
        names.append("sensor.geojson")
        if res.target is not None:
            truth = scn.truth.sensor_pose if scn.truth is not None else None
            plot_overview(
                str(tmp / "overview.png"),
                res,
                res.target.xyz,
                res.target.label,
                s.hfov_deg,
                s.max_range,
                true_T_local=truth,
            )
            names.append("overview.png")
    return [Path(out_dir) / n for n in names]
