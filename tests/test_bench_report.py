"""bench.report: stored results, provenance, reduced sets and the rendered markdown."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bench import report, results
from bench.results import Produced, Unavailable


def square_rows(n: int, scale: float) -> Produced:
    """A small real producer: squares of 0..n-1 times ``scale``, one row each."""
    rows = [{"i": i, "value": scale * i * i} for i in range(n)]
    body = ["| i | value |", "|---|---|"] + [f"| {r['i']} | {r['value']:g} |" for r in rows]
    return Produced(rows, body, f"{n} squares x {scale:g}",
                    {"total": sum(r["value"] for r in rows), "nan": math.nan})


TOY = report.Table("toy", "Toy table", "tests/test_bench_report.py", "What the toy shows.",
                   square_rows, {"n": 4, "scale": 1.0}, {"n": 2, "scale": 1.0})


def test_run_table_stores_rows_provenance_and_reduction(tmp_path):
    path = report.run_table(TOY, False, {"n": 3}, "python -m bench.report --only toy", tmp_path)
    doc = json.loads(path.read_text())
    assert path == tmp_path / "toy.json"
    assert [r["value"] for r in doc["rows"]] == [0.0, 1.0, 4.0]
    assert doc["summary"] == {"total": 5.0, "nan": None}  # NaN stored as null
    assert doc["reduced"] == {"n": [4, 3]}
    assert doc["params"] == {"n": 3, "scale": 1.0}
    assert doc["command"] == "python -m bench.report --only toy"
    assert len(doc["commit"]) >= 7 and doc["machine"]["cpus"] >= 1
    assert doc["duration_s"] >= 0 and not doc["quick"]
    # the full set itself is not reduced; quick results go to their own directory
    full = json.loads(report.run_table(TOY, False, {}, "c", tmp_path).read_text())
    assert full["reduced"] == {}
    quick = report.run_table(TOY, True, {}, "c", tmp_path)
    assert quick == tmp_path / "quick" / "toy.json"
    assert json.loads(quick.read_text())["reduced"] == {}
    assert json.loads((tmp_path / "toy.json").read_text())["params"]["n"] == 4


def pid_square_rows(n: int, scale: float, jobs: int = 1) -> Produced:
    """A parallel producer: the squares computed in ``jobs`` processes, with the worker pids."""
    got = list(report._ordered_map(_square_with_pid, [(i, scale) for i in range(n)], jobs))
    rows = [{"i": i, "value": v, "pid": pid} for i, (v, pid) in enumerate(got)]
    return Produced(rows, [f"| {r['i']} | {r['value']:g} |" for r in rows], f"{n} squares")


def _square_with_pid(i: int, scale: float) -> tuple[float, int]:
    import os

    return scale * i * i, os.getpid()


def test_parallel_table_gets_the_same_rows_in_worker_processes(tmp_path):
    import os

    par = report.Table("par", "Parallel toy", "tests/test_bench_report.py", "Squares.",
                       pid_square_rows, {"n": 6, "scale": 0.5}, {"n": 2, "scale": 0.5},
                       parallel=True)
    one = json.loads(report.run_table(par, False, {}, "c", tmp_path, jobs=1).read_text())
    two = json.loads(report.run_table(par, False, {}, "c", tmp_path, jobs=2).read_text())
    assert [r["value"] for r in two["rows"]] == [r["value"] for r in one["rows"]] == [
        0.5 * i * i for i in range(6)]
    assert {r["pid"] for r in one["rows"]} == {os.getpid()}
    assert os.getpid() not in {r["pid"] for r in two["rows"]}
    assert two["reduced"] == {}                 # jobs is not a parameter of the set
    # a table that is not parallel never gets jobs
    assert report.run_table(TOY, False, {}, "c", tmp_path, jobs=2) is not None


def test_unavailable_table_keeps_the_stored_result(tmp_path):
    report.run_table(TOY, False, {}, "first", tmp_path)

    def missing(**_):
        raise Unavailable("peer venv absent")

    gone = report.Table("toy", "Toy", "x", "y", missing, {}, {})
    assert report.run_table(gone, False, {}, "second", tmp_path) is None
    assert results.load("toy", False, tmp_path)["command"] == "first"


def test_render_marks_reduced_and_missing_tables(tmp_path, monkeypatch):
    monkeypatch.setattr(report, "TABLES", [TOY, report.Table(
        "other", "Other table", "x", "Never run.", square_rows, {"n": 1, "scale": 1.0}, {})])
    report.run_table(TOY, False, {"n": 2, "scale": 2.0}, "cmd --set toy.n=2", tmp_path)
    docs = {"toy": results.load("toy", False, tmp_path)}
    text = report.render(docs, quick=False)
    assert text.startswith("# fgloc benchmarks\n")
    assert "## Toy table" in text and "What the toy shows." in text
    assert "| 1 | 2 |" in text  # the producer's body, verbatim
    assert "**REDUCED against the full set:** n 2 instead of 4; scale 2.0 instead of 1.0." \
        in text
    assert "`cmd --set toy.n=2`" in text
    assert "Not measured yet: `python -m bench.report --only other`" in text
    # rendering is a pure function of the stored results
    assert report.render(docs, quick=False) == text


def test_first_screen_quotes_stored_summaries():
    summary = {"methods": {"joint": {"runs": 2, "d2d_mean": 0.1234, "d2d_worst": 0.2,
                                     "dyaw_mean": 0.03, "dz_mean": 0.1, "nees_mean": 2.5,
                                     "time_mean": 10.0},
                           "icp": {"runs": 2, "d2d_mean": 0.3, "d2d_worst": 0.4,
                                   "dyaw_mean": 0.05, "dz_mean": 0.1, "nees_mean": None,
                                   "time_mean": 5.0}}}
    rows = [{"method": "joint", "cov": [[1.0]]}, {"method": "joint", "cov": [[1.0]]},
            {"method": "icp", "cov": None}, {"method": "icp", "cov": [[1.0]]}]
    summary["methods"]["icp"]["nees_mean"] = 0.25
    doc = {"setting": "s", "commit": "abc1234", "started": "d", "summary": summary,
           "machine": {"load": 1.5, "cpus": 2}, "rows": rows}
    speed = {"setting": "t", "commit": "def5678", "started": "f",
             "summary": {"peak_rss_mib": {"joint": 900.4}}}
    py = {"commit": "0123abc", "started": "e", "summary": {
        "sequences": 7, "fgloc": {"rms": 0.64, "yaw_deg": 1.01, "iou": 0.781, "states": 10,
                                  "ms_per_frame": 3.05},
        "pyrecest": {"rms": 1.462, "yaw_deg": 2.01, "iou": 0.574, "states": 10,
                     "ms_per_frame": 10.2}}}
    independent = {"commit": "4567def", "started": "g", "rows": [
        {"filter.rms": 0.5, "filter.yaw": 2.0, "filter.iou": 0.7, "batch.rms": 0.4,
         "batch.yaw": 1.0, "batch.iou": float("nan")},
        {"filter.rms": 0.7, "filter.yaw": 3.0, "filter.iou": 0.8, "batch.rms": 0.2,
         "batch.yaw": 2.0, "batch.iou": 0.75}]}
    lines = report.first_screen({"scenarios": doc, "speed": speed, "pyrecest": py,
                                 "independent_tracking": independent})
    assert "| joint | 2 | 0.123 (0.200) | 0.030 | 0.100 | 2.50 | 10.0 | 900 |" in lines
    assert "| icp | 2 | 0.300 (0.400) | 0.050 | 0.100 | 0.25 (1 of 2 runs) | 5.0 | - |" in lines
    assert any(ln.startswith("| paper, SICP") and "0.66, 0.94, 0.38, 0.55" in ln
               for ln in lines)
    assert ("| pyrecest FullSCGPTracker (pooled RMS, 10.2 ms per frame) | 7 single-vehicle "
            "sequences (commit `0123abc`, e) | 1.462 | 2.01 | 0.574 |") in lines
    assert ("| fgloc batch (per-track mean RMS) | the independent generator's scenarios, 2 "
            "runs, oracle pose (commit `4567def`, g) | 0.300 | 1.50 | 0.750 |") in lines
    # no stored result: no invented numbers, a pointer to the command instead
    empty = report.first_screen({})
    assert any("--only scenarios" in ln for ln in empty)
    assert not any("pyrecest" in ln for ln in empty)


@pytest.mark.parametrize("item, message", [
    ("nosuch.seeds=[1]", "TABLE one of"),
    ("robustness.nosuch=[1]", "has the parameters"),
    ("robustness.seeds=[1,", "not JSON"),
    ("robustness.seeds", "TABLE.PARAM=JSON"),
])
def test_parse_sets_rejects_bad_items(item, message):
    with pytest.raises(SystemExit, match=message.replace("[", r"\[")):
        report.parse_sets([item])


def test_parse_sets_reads_json_values():
    assert report.parse_sets(["robustness.seeds=[1,2,3]", "sparse.height=false"]) == {
        "robustness": {"seeds": [1, 2, 3]}, "sparse": {"height": False}}


def test_every_table_has_a_paragraph_and_matching_sets():
    names = [t.name for t in report.TABLES]
    assert len(set(names)) == len(names)
    for t in report.TABLES:
        assert t.about and t.title
        assert set(t.quick) - {"quick"} <= set(t.full), t.name


def test_the_robustness_table_runs_every_setting_of_the_matrix() -> None:
    from bench.robustness import SETTINGS

    table = next(t for t in report.TABLES if t.name == "robustness")
    assert table.full["settings"] == list(SETTINGS)


def test_sicp_against_open3d_builds_its_clouds_from_the_coarse_source() -> None:
    """bench/sicp_vs_open3d.py's clouds: the coarse source's points (its DynamicSource) on the
    road, displaced by D (2 m at 30 deg, 3 deg); D itself scores 0, the identity D's yaw."""
    from bench.sicp_vs_open3d import errors, make_clouds

    c = make_clouds("intersection", 1, 6.0, 1.0, 2.0, 30.0, 3.0)
    assert len(c.source_xy) > 50 and c.source_label.shape == (len(c.source_xy),)
    assert errors(c.D, c) == pytest.approx((0.0, 0.0), abs=1e-9)
    assert errors(np.eye(3), c)[1] == pytest.approx(3.0)
