"""Where batch jobs run: a local process pool (stdlib) or a dask.distributed cluster.

Both engines take the jobs to run and yield ``(job, record)`` as jobs finish, in completion
order. Jobs record their own failures (:func:`fgloc.batch.job.run_job`); an engine only
handles workers that die (segfault, out-of-memory kill): a job whose worker died is retried on
a fresh worker until it has died :data:`MAX_ATTEMPTS` times, then recorded as failed; jobs
only queued in the broken pool are retried without counting.
"""

from __future__ import annotations

import ctypes
import logging
import multiprocessing
import os
import signal
import sys
from collections.abc import Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any, Protocol

from fgloc.batch.job import died_attempts, record_crash, run_job
from fgloc.batch.manifest import Job
from fgloc.errors import FglocError

#: Thread-count variables set to 1 in every worker (one job per core; BLAS/OpenMP threads
#: on top of worker processes oversubscribe the cores).
THREAD_ENV: tuple[str, ...] = (
    "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS",
)
MAX_ATTEMPTS = 2
Outcome = tuple[Job, dict[str, Any]]


class Engine(Protocol):
    def run(self, jobs: Sequence[Job], out: str) -> Iterator[Outcome]: ...


def single_thread_env() -> dict[str, str]:
    """The environment for worker processes: the thread variables set to 1 unless the user
    set them."""
    return {k: os.environ.get(k, "1") for k in THREAD_ENV}


def _init_worker() -> None:
    """Worker start-up: die with the parent (Linux), so that killing a batch stops its jobs;
    the environment (thread counts) is inherited from the parent at spawn time."""
    if sys.platform.startswith("linux"):
        try:
            ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass


class LocalEngine:
    """A pool of ``workers`` spawned processes on this machine (stdlib concurrent.futures).

    Workers are started with the ``spawn`` method and single-threaded numerics
    (:func:`single_thread_env`); a worker runs jobs one after the other.
    """

    def __init__(self, workers: int) -> None:
        if workers < 1:
            raise FglocError(f"--workers must be >= 1, got {workers}")
        self.workers = workers

    def run(self, jobs: Sequence[Job], out: str) -> Iterator[Outcome]:
        todo = list(jobs)
        root = Path(out)
        while todo:
            started = sum(died_attempts(root, j) for j in todo)
            died: list[Job] = []
            yield from self._run_pool(todo, out, died)
            if died and sum(died_attempts(root, j) for j in todo) == started:
                raise FglocError("the batch's worker processes die before running a job "
                                 "(see the messages above)")
            todo = []
            for job in died:  # queued jobs of a broken pool are retried without counting
                n = died_attempts(root, job)
                if n >= MAX_ATTEMPTS:
                    msg = (f"WorkerDied: the worker process died {n} times while running "
                           "this job (killed by the OS, out of memory, or a crash)")
                    yield job, record_crash(out, job, msg)
                else:
                    todo.append(job)

    def _run_pool(self, jobs: list[Job], out: str, died: list[Job]) -> Iterator[Outcome]:
        saved = {k: os.environ.get(k) for k in THREAD_ENV}
        os.environ.update(single_thread_env())  # inherited by the spawned workers
        try:
            pool = ProcessPoolExecutor(
                max_workers=min(self.workers, len(jobs)),
                mp_context=multiprocessing.get_context("spawn"),
                initializer=_init_worker,
            )
            pending = {pool.submit(run_job, job, out): job for job in jobs}
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
        try:
            while pending:
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for fut in done:
                    job = pending.pop(fut)
                    try:
                        yield job, fut.result()
                    except BrokenProcessPool:
                        died.append(job)
        finally:
            pool.shutdown(wait=not pending, cancel_futures=True)


class DaskEngine:
    """Jobs as tasks of a dask.distributed cluster (``pip install 'fgloc[batch]'``).

    scheduler: address of a running scheduler (``tcp://host:8786``); None starts a
    LocalCluster of ``workers`` single-threaded workers (processes, or threads with
    ``processes=False``). Scenario and output paths must be the same on every worker (a
    shared file system). dask's nannies start workers with OMP_NUM_THREADS=1 and friends.
    """

    def __init__(self, workers: int, scheduler: str | None = None, *, processes: bool = True,
                 timeout: float = 60.0) -> None:
        if workers < 1:
            raise FglocError(f"--workers must be >= 1, got {workers}")
        self.workers = workers
        self.scheduler = scheduler
        self.processes = processes
        self.timeout = timeout

    def run(self, jobs: Sequence[Job], out: str) -> Iterator[Outcome]:
        try:
            from dask.distributed import Client, LocalCluster, as_completed
        except ImportError:
            raise FglocError(
                "the dask engine needs dask.distributed: pip install 'fgloc[batch]'") from None
        logging.getLogger("distributed").setLevel(logging.WARNING)  # not the CLI's INFO level
        cluster = None
        if self.scheduler is None:
            extra = {"env": single_thread_env()} if self.processes else {}
            cluster = LocalCluster(
                n_workers=self.workers, threads_per_worker=1, processes=self.processes,
                dashboard_address=None, scheduler_kwargs={"dashboard": False}, **extra,
            )
        try:
            client = Client(cluster if cluster is not None else self.scheduler,
                            timeout=self.timeout)
        except (OSError, TimeoutError) as exc:
            if cluster is not None:
                cluster.close()
            raise FglocError(f"cannot reach the dask scheduler {self.scheduler}: {exc}") from None
        try:
            futures = {
                client.submit(run_job, job, out, key=f"fgloc-{job.key}-{os.getpid()}",
                              pure=False): job
                for job in jobs
            }
            for fut in as_completed(futures):
                job = futures[fut]
                try:
                    yield job, fut.result()
                except Exception as exc:  # noqa: BLE001 - KilledWorker, lost worker...
                    msg = f"WorkerDied: {type(exc).__name__}: {' '.join(str(exc).split())}"
                    yield job, record_crash(out, job, msg)
        finally:
            client.close()
            if cluster is not None:
                cluster.close()


def make_engine(name: str, workers: int, scheduler: str | None = None) -> Engine:
    if name == "local":
        if scheduler is not None:
            raise FglocError("--scheduler needs --engine dask")
        return LocalEngine(workers)
    if name == "dask":
        return DaskEngine(workers, scheduler)
    raise FglocError(f"unknown engine {name!r} (local or dask)")
