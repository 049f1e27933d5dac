"""Replace (or append) a generated section of docs/benchmarks.md between the markers
``<!-- BEGIN <name> -->`` and ``<!-- END <name> -->``; written atomically."""

from __future__ import annotations

import os
import platform
import subprocess
import time
from pathlib import Path

from fgloc.io.atomic import write_text_atomic


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


def replace_section(path: str | Path, name: str, body: str) -> None:
    """Put ``body`` between the ``name`` markers of ``path``: replaces the block if present,
    appends it at the end of the file otherwise."""
    p = Path(path)
    begin, end = f"<!-- BEGIN {name} -->", f"<!-- END {name} -->"
    text = p.read_text() if p.exists() else ""
    block = f"{begin}\n{body.strip()}\n{end}"
    if begin in text and end in text:
        head, rest = text.split(begin, 1)
        tail = rest.split(end, 1)[1]
        new = head + block + tail
    else:
        new = text.rstrip("\n") + ("\n\n" if text else "") + block + "\n"
    write_text_atomic(p, new)
