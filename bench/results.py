"""Stored benchmark results: one JSON file per report table under ``bench/results/``
(``bench/results/quick/`` for the smoke set), each with the rows a producer measured, its
rendered markdown and where, when and how it was measured (commit, date, machine, command,
duration). ``python -m bench.report`` writes them and renders docs/benchmarks.md from them."""

from __future__ import annotations

import json
import math
import os
import platform
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fgloc.io.atomic import write_text_atomic

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "bench" / "results"


class Unavailable(RuntimeError):
    """A table cannot be measured on this machine (e.g. a peer's separate venv is missing):
    the report keeps its stored result."""


@dataclass
class Produced:
    """What a table producer returns: ``rows`` (JSON-serializable dicts, one per run or table
    row, the raw figures), ``body`` (the rendered markdown lines), ``setting`` (one sentence:
    scenarios, seeds, durations) and ``summary`` (figures the report's first screen quotes)."""

    rows: list[dict]
    body: list[str]
    setting: str
    summary: dict[str, Any] = field(default_factory=dict)


#: what the report itself writes: not counted as uncommitted changes of the measured code
GENERATED = ("docs/benchmarks.md", "docs/figures", "bench/results")


def git_commit() -> tuple[str, bool]:
    """Short hash of HEAD and whether the tracked files other than the report's own outputs
    (``GENERATED``) differ from it ("unknown", False outside a git checkout)."""
    def git(*args: str) -> str:
        return subprocess.run(["git", *args], capture_output=True, text=True, check=True,
                              cwd=ROOT).stdout.strip()
    try:
        return git("rev-parse", "--short", "HEAD"), bool(git(
            "status", "--porcelain", "--untracked-files=no", "--", ".",
            *(f":(exclude){g}" for g in GENERATED)))
    except (OSError, subprocess.CalledProcessError):
        return "unknown", False


def machine() -> dict[str, Any]:
    """The machine a result was measured on: processor, CPUs, Python, OMP_NUM_THREADS and the
    1-minute load average at the time of the call."""
    return {"processor": platform.processor() or platform.machine(),
            "cpus": os.cpu_count(), "python": platform.python_version(),
            "omp_num_threads": os.environ.get("OMP_NUM_THREADS", "unset"),
            "load": round(os.getloadavg()[0], 2)}


def utc_now() -> str:
    return time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())


def _clean(x: Any) -> Any:
    """JSON-safe copy: NaN / inf become None, tuples lists, numpy scalars Python numbers."""
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if hasattr(x, "item") and not isinstance(x, (str, bytes)):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def result_path(table: str, quick: bool, root: Path = RESULTS) -> Path:
    return (root / "quick" if quick else root) / f"{table}.json"


def save(table: str, produced: Produced, command: str, started: str, duration_s: float,
         quick: bool, params: dict, reduced: dict, commit: tuple[str, bool],
         root: Path = RESULTS) -> Path:
    """Write one table's result (atomically) and return its path; ``commit``: the
    :func:`git_commit` taken when the run started."""
    commit, dirty = commit
    doc = {"table": table, "command": command, "commit": commit, "dirty": dirty,
           "started": started, "finished": utc_now(), "duration_s": round(duration_s, 1),
           "machine": machine(), "quick": quick, "params": params, "reduced": reduced,
           "setting": produced.setting, "summary": produced.summary, "body": produced.body,
           "rows": produced.rows}
    path = result_path(table, quick, root)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, json.dumps(_clean(doc), indent=1) + "\n")
    return path


def load(table: str, quick: bool, root: Path = RESULTS) -> dict | None:
    """A stored result, or None when the table was never run into ``root``."""
    path = result_path(table, quick, root)
    return json.loads(path.read_text()) if path.exists() else None
