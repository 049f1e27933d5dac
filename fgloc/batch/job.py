"""Running one batch job and keeping its state on disk.

A job's outputs live in ``<out>/jobs/<label>/<method>/``. That directory is written as a
hidden sibling (``.tmp-*``) and renamed into place in one step, with ``job.json`` (the job's
record) inside, so it either does not exist or is complete: an interrupted job leaves only a
hidden temporary directory, which the next run deletes. A job is *finished* when its directory
holds a ``job.json`` with status ``ok`` and the job's current fingerprint.

Record (``job.json``): ``job``, ``scenario``, ``label``, ``method``, ``fingerprint``,
``status`` (ok / failed), ``error`` (one line, failed only), ``converged``, the pose
(``x``, ``y``, ``z`` in the world CRS, ``yaw_deg``, ``crs``), the errors against
``ground_truth.json`` when the scenario has one (``dx``, ``dy``, ``d2d`` m, ``dyaw_deg``),
``time_s`` (wall time of load + localize + write) and ``peak_rss_mb`` (peak resident memory of
the worker process during the job; Linux).
"""

from __future__ import annotations

import json
import math
import os
import resource
import shutil
import sys
import tempfile
import time
import traceback
import uuid
from pathlib import Path
from typing import Any

from fgloc.batch.manifest import Job
from fgloc.io.atomic import current_umask

JOB_FILE = "job.json"
ERROR_FILE = "error.txt"
TRACEBACK_FILE = "traceback.txt"
JOBS_DIR = "jobs"
_TMP_PREFIX = ".tmp-"
_TRASH_PREFIX = ".trash-"


def _make_tmp(final: Path) -> Path:
    """A hidden temporary directory ``.tmp-<method>-*`` beside ``final`` (mode per umask, not
    mkdtemp's 0700). One is left behind by every attempt whose process died."""
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f"{_TMP_PREFIX}{final.name}-", dir=final.parent))
    os.chmod(tmp, 0o777 & ~current_umask())
    return tmp


def job_dir(out: Path, job: Job) -> Path:
    return out / JOBS_DIR / job.label / job.method


def base_record(job: Job) -> dict[str, Any]:
    return {"job": job.key, "scenario": job.scenario, "label": job.label,
            "method": job.method, "fingerprint": job.fingerprint}


def read_record(out: Path, job: Job) -> dict[str, Any] | None:
    """The job's saved record, or None when it has none or an unreadable one."""
    try:
        doc = json.loads((job_dir(out, job) / JOB_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) else None


def is_finished(out: Path, job: Job) -> bool:
    rec = read_record(out, job)
    return rec is not None and rec.get("status") == "ok" and (
        rec.get("fingerprint") == job.fingerprint)


def died_attempts(out: Path, job: Job) -> int:
    """Attempts at ``job`` whose process died in this run (their temporary directories are
    left; :func:`remove_leftovers` deletes them when a run starts and ends)."""
    return len(list(job_dir(out, job).parent.glob(f"{_TMP_PREFIX}{job.method}-*")))


def remove_leftovers(out: Path) -> int:
    """Delete hidden temporary job directories of interrupted runs; return how many."""
    root = out / JOBS_DIR
    if not root.is_dir():
        return 0
    n = 0
    for d in root.glob("**/.*"):
        if d.is_dir() and d.name.startswith((_TMP_PREFIX, _TRASH_PREFIX)):
            shutil.rmtree(d, ignore_errors=True)
            n += 1
    return n


def run_job(job: Job, out: str) -> dict[str, Any]:
    """Run ``job`` and publish its directory under ``out``; return its record.

    Runs in a worker process. Any exception of the job (bad input, failed localization, a
    bug) is caught: the job is recorded as failed with ``error.txt`` (one line) and
    ``traceback.txt``; only interrupts (KeyboardInterrupt, SystemExit) propagate.
    """
    from fgloc.config import Config, from_dict
    from fgloc.evaluation.pose import pose_error
    from fgloc.geo import pose_from_se3
    from fgloc.io import load_scenario
    from fgloc.outputs import write_localization
    from fgloc.pipeline import localize

    final = job_dir(Path(out), job)
    tmp = _make_tmp(final)
    _reset_peak_rss()
    t0 = time.perf_counter()
    rec = base_record(job)
    try:
        cfg = from_dict(Config, job.config, None)
        scn = load_scenario(job.scenario)
        if job.ignore_yaw_guess:
            scn.sensor.yaw_guess_deg = None
        res = localize(scn, job.method, cfg)
        write_localization(tmp / "out", scn, res)
        for p in (tmp / "out").iterdir():
            os.replace(p, tmp / p.name)
        (tmp / "out").rmdir()
        x, y, z, yaw, _, _ = pose_from_se3(res.T_utm)
        rec.update(status="ok", converged=bool(res.converged), pose_status=res.status,
                   n_modes=len(res.modes), crs=res.crs, x=x, y=y, z=z,
                   yaw_deg=math.degrees(yaw))
        if scn.truth is not None:
            err = pose_error(res.T_local, scn.truth.sensor_pose)
            rec.update(dx=err.dx, dy=err.dy, d2d=err.d2d, dyaw_deg=err.dyaw_deg)
    except Exception as exc:  # noqa: BLE001 - every job failure is recorded, the batch goes on
        rec.update(status="failed", error=_one_line(exc))
        shutil.rmtree(tmp / "out", ignore_errors=True)  # no partial outputs in a failed job
        (tmp / ERROR_FILE).write_text(rec["error"] + "\n", encoding="utf-8")
        (tmp / TRACEBACK_FILE).write_text(traceback.format_exc(), encoding="utf-8")
    rec.update(time_s=time.perf_counter() - t0, peak_rss_mb=_peak_rss_mb())
    publish(tmp, final, rec)
    return rec


def record_crash(out: str, job: Job, message: str) -> dict[str, Any]:
    """Record ``job`` as failed when its worker died (the worker could not write it)."""
    final = job_dir(Path(out), job)
    tmp = _make_tmp(final)
    rec = {**base_record(job), "status": "failed", "error": message}
    (tmp / ERROR_FILE).write_text(message + "\n", encoding="utf-8")
    publish(tmp, final, rec)
    return rec


def publish(tmp: Path, final: Path, rec: dict[str, Any]) -> None:
    """Write ``job.json`` into ``tmp`` and rename ``tmp`` to ``final`` (replacing an older
    ``final``): readers see either no directory, the old one or the complete new one."""
    (tmp / JOB_FILE).write_text(json.dumps(rec, indent=2) + "\n", encoding="utf-8")
    for _ in range(5):  # another process may publish the same job concurrently
        if final.exists():
            trash = final.with_name(f"{_TRASH_PREFIX}{final.name}-{uuid.uuid4().hex[:8]}")
            try:
                os.rename(final, trash)
            except FileNotFoundError:
                pass
            else:
                shutil.rmtree(trash, ignore_errors=True)
        try:
            os.rename(tmp, final)
            return
        except OSError:  # final re-appeared (ENOTEMPTY / EEXIST): swap again
            continue
    shutil.rmtree(tmp, ignore_errors=True)
    raise OSError(f"cannot publish {final}: it keeps being replaced")


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or "(no message)"
    return f"{type(exc).__name__}: {text}"


def _reset_peak_rss() -> None:
    """Reset the process's peak-RSS counter (Linux ``clear_refs``) so it measures one job."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass


def _peak_rss_mb() -> float:
    """Peak resident set size (MB) since the last reset (VmHWM), else since process start."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / (1024.0 * 1024.0 if sys.platform == "darwin" else 1024.0)
