"""fgloc batch: local and dask engines, failure recording, resume after a kill, summary."""

from __future__ import annotations

import csv
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fgloc.batch import DaskEngine, read_manifest, run_batch
from fgloc.batch.job import JOB_FILE, is_finished, job_dir, remove_leftovers
from fgloc.cli import main
from fgloc.config import to_dict
from fgloc.errors import InputError
from fgloc.evaluation.pose import pose_error
from fgloc.geo import LocalFrame
from fgloc.io import read_ground_truth, write_scenario
from fgloc.result import read_result_json
from fgloc.sim import SimConfig, simulate

REPO = Path(__file__).resolve().parent.parent
#: a small scene (260 m of ALS, 110 m range) so that one icp job takes seconds
SMALL_SIM = {"als": {"extent": 260.0, "density": 1.5, "buildings": 2, "trees": 8, "poles": 2},
             "road": {"arm_length": 100.0},
             "radar": {"max_range": 110.0, "clutter_per_frame": 40.0, "rate_hz": 10.0}}
#: a cheaper coarse search for the tests (the batch mechanics are under test, not accuracy)
FAST_OVERRIDES = """
[overrides.coarse]
position_search_radius = 3.0
position_search_step = 1.5
search_candidates = 2
search_points = 300
refine_points = 3000
alternations = 1
"""


@pytest.fixture(scope="module")
def scenarios(tmp_path_factory) -> Path:
    """scn/a, scn/b: two copies of one small simulated scenario; scn/bad: text in doppler."""
    from fgloc.config import from_dict

    root = tmp_path_factory.mktemp("batch") / "scn"
    cfg = from_dict(SimConfig, SMALL_SIM, None)
    write_scenario(simulate("straight", 1, duration=10.0, vehicles=3, config=cfg), root / "a")
    shutil.copytree(root / "a", root / "b")
    shutil.copytree(root / "a", root / "bad")
    lines = (root / "bad" / "radar.csv").read_text().splitlines()
    cells = lines[3].split(",")
    cells[4] = "fast"
    lines[3] = ",".join(cells)
    (root / "bad" / "radar.csv").write_text("\n".join(lines) + "\n")
    return root


def _manifest(path: Path, scenarios: list[str]) -> Path:
    body = f"scenarios = {json.dumps(scenarios)}\nmethods = [\"icp\"]\n{FAST_OVERRIDES}"
    path.write_text(body)
    return path


def _summary(out: Path) -> list[dict[str, str]]:
    with (out / "summary.csv").open() as fh:
        return list(csv.DictReader(fh))


def test_local_batch_records_failure_and_resumes(scenarios, tmp_path, capsys):
    manifest = _manifest(tmp_path / "m.toml", [str(scenarios / "*")])
    out = tmp_path / "out"
    assert main(["-q", "batch", str(manifest), "--out", str(out), "--workers", "2"]) == 1
    text = capsys.readouterr().out
    assert "FAILED bad/icp" in text and "radar.csv, row 4, field 'doppler'" in text
    rows = {r["job"]: r for r in _summary(out)}
    assert sorted(rows) == ["a/icp", "b/icp", "bad/icp"]
    assert rows["bad/icp"]["status"] == "failed"
    assert "not a number: 'fast'" in rows["bad/icp"]["error"]
    bad_dir = out / "jobs" / "bad" / "icp"
    assert "InputError" in (bad_dir / "traceback.txt").read_text()
    assert not (bad_dir / "result.json").exists()
    # the good jobs: outputs complete, errors in the summary = evaluate's on result.json
    for key in ("a", "b"):
        r = rows[f"{key}/icp"]
        assert r["status"] == "ok" and float(r["time_s"]) > 0 and float(r["peak_rss_mb"]) > 50
        d = out / "jobs" / key / "icp"
        for name in ("result.json", "target.ply", "source.ply", "sensor.geojson", "job.json"):
            assert (d / name).stat().st_size > 0
        saved = read_result_json(d / "result.json")
        frame = LocalFrame.around(float(r["x"]), float(r["y"]), 0.0, saved.crs)
        truth = read_ground_truth(scenarios / key / "ground_truth.json", frame)
        err = pose_error(frame.pose_to_local(saved.T_utm), truth.sensor_pose)
        assert float(r["d2d"]) == pytest.approx(err.d2d, abs=1e-4)
        assert float(r["dyaw_deg"]) == pytest.approx(err.dyaw_deg, abs=1e-4)
        assert err.d2d < 15.0  # a localization, not noise (the cheap test search is coarse)
    assert rows["a/icp"]["x"] == rows["b/icp"]["x"]  # same data, same result
    with (out / "aggregate.csv").open() as fh:
        (agg,) = list(csv.DictReader(fh))
    d2d = [float(rows[k]["d2d"]) for k in ("a/icp", "b/icp")]
    assert (int(agg["jobs"]), int(agg["ok"]), int(agg["failed"])) == (3, 2, 1)
    assert float(agg["worst_2d_m"]) == pytest.approx(max(d2d), rel=1e-5)
    assert float(agg["mean_2d_m"]) == pytest.approx(sum(d2d) / 2, rel=1e-5)

    # resume: finished jobs are skipped (their directories untouched), the failed one re-runs
    stamp = (out / "jobs" / "a" / "icp" / JOB_FILE).stat().st_mtime_ns
    m = read_manifest(manifest)
    log = io.StringIO()
    report = run_batch(m, out, DaskEngine(1, processes=False), progress=log)
    assert (report.skipped, report.ran, report.failed) == (2, 1, 1)
    lines = log.getvalue().splitlines()  # not a terminal: one line per event
    assert lines[0].startswith("[fgloc batch] [") and "2/3 jobs (2 already done), 0 failed" in (
        lines[0])
    assert "3/3 jobs (2 already done), 1 failed" in lines[-1] and "ETA 0s" in lines[-1]
    assert re.search(r"bad/icp failed in \d+\.\d s$", lines[-1]), lines[-1]
    assert (out / "jobs" / "a" / "icp" / JOB_FILE).stat().st_mtime_ns == stamp
    assert sorted(r["job"] for r in _summary(out)) == ["a/icp", "b/icp", "bad/icp"]


def test_dask_local_cluster_runs_jobs(scenarios, tmp_path):
    manifest = _manifest(tmp_path / "m.toml", [str(scenarios / "a"), str(scenarios / "bad")])
    out = tmp_path / "out"
    t0 = time.monotonic()
    report = run_batch(read_manifest(manifest), out, DaskEngine(2, processes=False, timeout=30))
    assert time.monotonic() - t0 < 120
    status = {r["job"]: r["status"] for r in report.records}
    assert status == {"a/icp": "ok", "bad/icp": "failed"}
    assert (out / "jobs" / "a" / "icp" / "result.json").is_file()


def test_partial_state_is_never_taken_as_finished(scenarios, tmp_path):
    manifest = _manifest(tmp_path / "m.toml", [str(scenarios / "a")])
    (job,) = read_manifest(manifest).jobs()
    out = tmp_path / "out"
    d = job_dir(out, job)
    d.mkdir(parents=True)
    (d / "result.json").write_text("{}")  # outputs without job.json
    assert not is_finished(out, job)
    (d / JOB_FILE).write_text('{"status": "ok", "fingerp')  # truncated record
    assert not is_finished(out, job)
    rec = {"status": "ok", "fingerprint": job.fingerprint}
    (d / JOB_FILE).write_text(json.dumps(rec))
    assert is_finished(out, job)
    (d / JOB_FILE).write_text(json.dumps({**rec, "status": "failed"}))
    assert not is_finished(out, job)
    other = read_manifest(manifest)
    other.config.coarse.doppler_min = 0.7  # another config: another fingerprint, run again
    (job2,) = other.jobs()
    (d / JOB_FILE).write_text(json.dumps(rec))
    assert job2.fingerprint != job.fingerprint and not is_finished(out, job2)
    leftover = d.parent / ".tmp-abc123"
    leftover.mkdir()
    (leftover / "result.json").write_text("{}")
    assert remove_leftovers(out) == 1 and not leftover.exists()


def test_manifest_errors(scenarios, tmp_path):
    m = tmp_path / "m.toml"
    cases = [
        ('scenarios = ["nothing/*"]\nmethods = ["icp"]\n', "scenarios[0]", "matches no directory"),
        (f'scenarios = ["{scenarios}/a"]\nmethods = ["icp", "nope"]\n', "methods[1]",
         "unknown method"),
        (f'scenarios = ["{scenarios}/a"]\nmethods = []\n', "methods", "non-empty"),
        (f'scenarios = ["{scenarios}/a"]\nmethods = ["icp"]\n[overrides.coarse]\nbogus = 1\n',
         "overrides.coarse.bogus", "unknown key"),
        (f'scenarios = ["{scenarios}/a"]\nmethods = ["icp"]\nworkers = 3\n', "workers",
         "unknown key"),
    ]
    for text, field, words in cases:
        m.write_text(text)
        with pytest.raises(InputError) as info:
            read_manifest(m)
        assert info.value.field == field and words in str(info.value), text
    m.write_text(f'scenarios = ["{scenarios}/a"]\nmethods = ["icp"]\n')
    assert main(["-q", "batch", str(m), "--out", str(tmp_path / "o"), "--scheduler", "x"]) == 2


def test_manifest_globs_labels_and_config(scenarios, tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text("[coarse]\ndoppler_min = 0.8\n")
    m = tmp_path / "m.toml"
    m.write_text(
        f'scenarios = ["{scenarios}/[ab]", "{scenarios}/a"]\nmethods = ["icp", "filter-sicp"]\n'
        'config = "c.toml"\n[overrides.coarse]\nvoxel_size = 0.7\n'
    )
    man = read_manifest(m)
    assert [j.key for j in man.jobs()] == ["a/icp", "a/filter-sicp", "b/icp", "b/filter-sicp"]
    c = to_dict(man.config)["coarse"]
    assert c["doppler_min"] == 0.8 and c["voxel_size"] == 0.7


@pytest.mark.slow
def test_kill_and_resume(scenarios, tmp_path):
    """A real interruption: SIGKILL the batch process while a job runs (its worker dies with
    it), then resume.
    Nothing finished is lost or re-run, nothing half-written is taken as finished, every job
    appears exactly once in the summary."""
    for k in "cd":
        shutil.copytree(scenarios / "a", scenarios.parent / "kill" / k)
    shutil.copytree(scenarios / "a", scenarios.parent / "kill" / "e")
    manifest = _manifest(tmp_path / "m.toml", [str(scenarios.parent / "kill" / "*")])
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    cmd = [sys.executable, "-m", "fgloc", "-q", "batch", str(manifest), "--out", str(out),
           "--workers", "1"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    jobs = out / "jobs"
    deadline = time.monotonic() + 120
    try:
        while not list(jobs.glob("*/icp/job.json")):  # first job published
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.1)
        while not list(jobs.glob("*/.tmp-*")):  # the second job is writing or running
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.05)
    finally:
        os.kill(proc.pid, signal.SIGKILL)  # the parent only: workers must not outlive it
        proc.wait(timeout=30)
    done = sorted(p.parent.parent.name for p in jobs.glob("*/icp/job.json"))
    assert len(done) == 1
    stamp = {k: (jobs / k / "icp" / JOB_FILE).stat().st_mtime_ns for k in done}
    man = read_manifest(manifest)
    finished = [j.label for j in man.jobs() if is_finished(out, j)]
    assert finished == done  # the interrupted job is not finished
    res = subprocess.run(cmd[:-1] + ["2"], env=env, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "3 jobs: 1 already done, 2 run now, 0 failed" in res.stdout
    rows = _summary(out)
    assert sorted(r["job"] for r in rows) == ["c/icp", "d/icp", "e/icp"]
    assert all(r["status"] == "ok" for r in rows)
    assert {k: (jobs / k / "icp" / JOB_FILE).stat().st_mtime_ns for k in done} == stamp
    assert not list(jobs.glob("**/.tmp-*")) and not list(jobs.glob("**/.trash-*"))


@pytest.mark.slow
def test_worker_death_is_retried_then_recorded(scenarios, tmp_path):
    """SIGKILL the worker (as the OOM killer would) each time it runs job c: c is retried once,
    then recorded as failed (WorkerDied); job d, queued behind it, still runs."""
    psutil = pytest.importorskip("psutil")
    for k in "cd":
        shutil.copytree(scenarios / "a", tmp_path / "scn" / k)
    manifest = _manifest(tmp_path / "m.toml", [str(tmp_path / "scn" / "*")])
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-m", "fgloc", "-q", "batch", str(manifest),
                             "--out", str(out), "--workers", "1"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    kills = 0
    seen: set[str] = set()
    deadline = time.monotonic() + 240
    while proc.poll() is None and time.monotonic() < deadline:
        tmp = {p.name for p in (out / "jobs" / "c").glob(".tmp-*")} - seen
        if tmp and kills < 2:
            seen |= tmp
            for child in psutil.Process(proc.pid).children(recursive=True):
                if "spawn_main" in " ".join(child.cmdline()):  # not the resource tracker
                    child.kill()
            kills += 1
        time.sleep(0.05)
    stdout, _ = proc.communicate(timeout=60)
    assert kills == 2 and proc.returncode == 1, stdout
    rows = {r["job"]: r for r in _summary(out)}
    assert rows["d/icp"]["status"] == "ok"
    assert rows["c/icp"]["status"] == "failed" and "WorkerDied" in rows["c/icp"]["error"]
    assert "died 2 times" in (out / "jobs" / "c" / "icp" / "error.txt").read_text()
