"""The batch summary: one CSV row per job and an aggregate table per method.

``summary.csv``: job, scenario, method, status (of the job: ok / failed), converged,
pose_status (result.json's ``status``: resolved / ambiguous), n_modes, x, y, z (world CRS, m),
yaw_deg, dx, dy, d2d (m), dyaw_deg (errors against ground truth, empty without it), time_s,
peak_rss_mb, error. ``aggregate.csv`` and the printed table: per method the job counts (and
how many ended ambiguous), the mean and worst 2D and yaw errors over the successful jobs with
ground truth, and the mean and total wall time.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Any

from fgloc.io.atomic import write_text_atomic

SUMMARY_COLUMNS: tuple[str, ...] = (
    "job", "scenario", "method", "status", "converged", "pose_status", "n_modes",
    "x", "y", "z", "yaw_deg",
    "dx", "dy", "d2d", "dyaw_deg", "time_s", "peak_rss_mb", "error",
)
AGGREGATE_COLUMNS: tuple[str, ...] = (
    "method", "jobs", "ok", "failed", "ambiguous", "with_truth", "mean_2d_m", "worst_2d_m",
    "mean_dyaw_deg", "worst_dyaw_deg", "mean_time_s", "total_time_s",
)


def _csv_text(columns: tuple[str, ...], rows: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: _cell(r.get(k)) for k in columns})
    return buf.getvalue()


def _cell(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.6g}" if abs(v) < 1e5 else f"{v:.3f}"
    return str(v)


def aggregate(records: list[dict[str, Any]], methods: list[str]) -> list[dict[str, Any]]:
    """Per method (in ``methods`` order): counts, mean/worst 2D and yaw error, times."""
    rows = []
    for m in methods:
        mine = [r for r in records if r["method"] == m]
        ok = [r for r in mine if r.get("status") == "ok"]
        truth = [r for r in ok if r.get("d2d") is not None]
        times = [r["time_s"] for r in mine if r.get("time_s") is not None]
        d2d = [r["d2d"] for r in truth]
        dyaw = [r["dyaw_deg"] for r in truth]
        rows.append({
            "method": m, "jobs": len(mine), "ok": len(ok), "failed": len(mine) - len(ok),
            "ambiguous": sum(r.get("pose_status") == "ambiguous" for r in ok),
            "with_truth": len(truth),
            "mean_2d_m": sum(d2d) / len(d2d) if d2d else None,
            "worst_2d_m": max(d2d) if d2d else None,
            "mean_dyaw_deg": sum(dyaw) / len(dyaw) if dyaw else None,
            "worst_dyaw_deg": max(dyaw) if dyaw else None,
            "mean_time_s": sum(times) / len(times) if times else None,
            "total_time_s": sum(times) if times else None,
        })
    return rows


def aggregate_table(rows: list[dict[str, Any]]) -> str:
    """The aggregate rows as an aligned text table."""
    head = ("method", "jobs", "ok", "failed", "ambiguous", "mean 2D m", "worst 2D m",
            "mean |dyaw| deg", "worst |dyaw| deg", "mean time s")
    keys = ("method", "jobs", "ok", "failed", "ambiguous", "mean_2d_m", "worst_2d_m",
            "mean_dyaw_deg", "worst_dyaw_deg", "mean_time_s")

    def fmt(v: Any) -> str:
        if v is None or (isinstance(v, float) and math.isnan(v)):
            return "-"
        return f"{v:.3f}" if isinstance(v, float) else str(v)

    table = [head] + [tuple(fmt(r[k]) for k in keys) for r in rows]
    widths = [max(len(row[i]) for row in table) for i in range(len(head))]
    return "\n".join(
        "  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(row, widths)))
        for row in table
    )


def write_summary(out: Path, records: list[dict[str, Any]], methods: list[str]) -> list[dict]:
    """Write ``summary.csv`` and ``aggregate.csv`` atomically; return the aggregate rows."""
    rows = aggregate(records, methods)
    write_text_atomic(out / "summary.csv", _csv_text(SUMMARY_COLUMNS, records))
    write_text_atomic(out / "aggregate.csv", _csv_text(AGGREGATE_COLUMNS, rows))
    return rows
