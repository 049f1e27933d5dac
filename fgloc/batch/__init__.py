"""Batch localization: many scenarios x methods from a TOML manifest, on a local process pool
or a dask.distributed cluster, resumable after an interruption (docs/batch.md)."""

from fgloc.batch.engines import DaskEngine, LocalEngine, make_engine
from fgloc.batch.manifest import Job, Manifest, read_manifest
from fgloc.batch.runner import BatchReport, run_batch
from fgloc.batch.summary import aggregate_table

__all__ = [
    "BatchReport",
    "DaskEngine",
    "Job",
    "LocalEngine",
    "Manifest",
    "aggregate_table",
    "make_engine",
    "read_manifest",
    "run_batch",
]
