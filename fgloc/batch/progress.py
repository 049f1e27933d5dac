"""A progress bar for batch runs on stderr: jobs done, failed, elapsed time and ETA.

On a terminal the bar redraws one line; otherwise (logs, CI) it prints one line per finished
job. The ETA is the mean wall time per job finished in this run times the jobs left.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO


def format_seconds(s: float) -> str:
    s = max(0, int(round(s)))
    h, rem = divmod(s, 3600)
    m, sec = divmod(rem, 60)
    return f"{h}h{m:02d}m{sec:02d}s" if h else (f"{m}m{sec:02d}s" if m else f"{sec}s")


class ProgressBar:
    """Counts finished jobs of ``total`` (``skipped`` of them were finished before)."""

    def __init__(self, total: int, skipped: int = 0, stream: TextIO | None = None,
                 width: int = 30) -> None:
        self.total = total
        self.skipped = skipped
        self.done = skipped
        self.failed = 0
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.width = width
        self.t0 = time.monotonic()

    def line(self) -> str:
        frac = self.done / self.total if self.total else 1.0
        fill = int(round(frac * self.width))
        bar = "#" * fill + "." * (self.width - fill)
        elapsed = time.monotonic() - self.t0
        ran = self.done - self.skipped
        left = self.total - self.done
        eta = format_seconds(elapsed / ran * left) if ran and left else ("0s" if not left else "?")
        skipped = f" ({self.skipped} already done)" if self.skipped else ""
        return (f"[{bar}] {self.done}/{self.total} jobs{skipped}, {self.failed} failed, "
                f"elapsed {format_seconds(elapsed)}, ETA {eta}")

    def start(self) -> None:
        self._emit("")

    def update(self, key: str, status: str, seconds: float | None) -> None:
        self.done += 1
        self.failed += status != "ok"
        took = f" in {seconds:.1f} s" if seconds is not None else ""
        self._emit(f"{key} {status}{took}")

    def close(self) -> None:
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()

    def _emit(self, event: str) -> None:
        if self.tty:
            self.stream.write("\r\x1b[2K" + self.line())
        else:
            self.stream.write(f"[fgloc batch] {self.line()}" + (f"  {event}" if event else "")
                              + "\n")
        self.stream.flush()
