"""Stage timing and progress messages.

Library code records each stage's wall time in a :class:`Timer`; the CLI turns on INFO logging
so the user sees a line when a stage starts and ends (steps of more than a few seconds).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

log = logging.getLogger("fgloc")


@dataclass
class Timer:
    """Wall-clock seconds per named stage, in the order the stages ran."""

    seconds: dict[str, float] = field(default_factory=dict)

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        log.info("%s ...", name)
        t0 = time.perf_counter()
        try:
            yield
        finally:
            dt = time.perf_counter() - t0
            self.seconds[name] = self.seconds.get(name, 0.0) + dt
            log.info("%s done in %.2f s", name, dt)


@contextmanager
def quiet(logger_name: str, level: int = logging.CRITICAL) -> Iterator[None]:
    """Silence the log lines of ``logger_name`` below ``level`` inside the ``with`` block (a
    library whose failures become one error of ours; a file read again whose warnings were
    given once)."""
    logger = logging.getLogger(logger_name)
    before = logger.level
    logger.setLevel(level)
    try:
        yield
    finally:
        logger.setLevel(before)
