"""Running a batch: skip finished jobs, run the rest on an engine, write the summary.

Output directory layout::

    OUT/jobs/<label>/<method>/   one directory per job (result.json ..., job.json; failed jobs:
                                 job.json, error.txt, traceback.txt)
    OUT/summary.csv              one row per job of the manifest
    OUT/aggregate.csv            one row per method
    OUT/.fgloc-batch.lock        held while a batch writes into OUT

A second run with the same manifest and OUT resumes: jobs finished with the same fingerprint
are skipped, failed and unfinished ones run again.
"""

from __future__ import annotations

import fcntl
import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from fgloc.batch.engines import Engine
from fgloc.batch.job import base_record, is_finished, read_record, remove_leftovers
from fgloc.batch.manifest import Manifest
from fgloc.batch.progress import ProgressBar
from fgloc.batch.summary import write_summary
from fgloc.errors import FglocError

LOCK_FILE = ".fgloc-batch.lock"


@dataclass
class BatchReport:
    """records: one per job of the manifest (in manifest order); skipped: jobs finished by an
    earlier run; ran: jobs run now; aggregate: per-method rows of aggregate.csv."""

    records: list[dict[str, Any]]
    skipped: int
    ran: int
    aggregate: list[dict[str, Any]]

    @property
    def failed(self) -> int:
        return sum(r.get("status") != "ok" for r in self.records)


@contextmanager
def batch_lock(out: Path) -> Iterator[None]:
    """An exclusive lock on ``out``: two batches never write into the same directory."""
    out.mkdir(parents=True, exist_ok=True)
    fd = os.open(out / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise FglocError(f"{out}: another fgloc batch is writing into this directory") from None
        yield
    finally:
        os.close(fd)


def run_batch(manifest: Manifest, out: str | Path, engine: Engine, *,
              progress: TextIO | None = None) -> BatchReport:
    """Run every job of ``manifest`` not yet finished in ``out``; write the summary.

    progress: stream for the progress bar (None: no bar). Returns the report of all jobs.
    """
    out_dir = Path(out).resolve()
    jobs = manifest.jobs()
    with batch_lock(out_dir):
        remove_leftovers(out_dir)
        todo = [j for j in jobs if not is_finished(out_dir, j)]
        bar = ProgressBar(len(jobs), len(jobs) - len(todo), progress) if progress else None
        if bar:
            bar.start()
        try:
            for job, rec in engine.run(todo, str(out_dir)):
                if bar:
                    bar.update(job.key, rec.get("status", "failed"), rec.get("time_s"))
        finally:
            if bar:
                bar.close()
        remove_leftovers(out_dir)  # temporary directories of attempts whose worker died
        records = [read_record(out_dir, j) or {**base_record(j), "status": "missing"}
                   for j in jobs]
        rows = write_summary(out_dir, records, manifest.methods)
    return BatchReport(records, len(jobs) - len(todo), len(todo), rows)
