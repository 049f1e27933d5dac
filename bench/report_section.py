"""Where and when a bench script measured: the provenance line its printed table carries
(docs/benchmarks.md itself is written whole by ``python -m bench.report``)."""

from __future__ import annotations

import os
import platform
import subprocess
import time
from pathlib import Path


def provenance() -> str:
    """"Commit <short hash>, <UTC date>, <machine>, <n> CPUs, OMP_NUM_THREADS=<v>": where and
    when a generated table was measured."""
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                                text=True, check=True,
                                cwd=Path(__file__).resolve().parent).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    return (f"Commit {commit}, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
            f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
            f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}")

