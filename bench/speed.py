"""Speed of fgloc: per-stage time and peak memory per method, SICP against Open3D, tracker
real-time factors, and how each stage grows with recording length and vehicle count.

Every localization runs as its own child process through the CLI (``fgloc localize SCENARIO
--method M --out DIR``), the way a user runs it, so its peak resident memory (``VmHWM``) is
that run's alone; stage times come from the run's result.json (``timings_s``). Simulation and
writing the scenario are not timed.

    OMP_NUM_THREADS=1 python -m bench.speed [--quick] [--methods icp filter-sicp ...]

Sections: (1) stages + peak memory on one 120 s intersection with 60 vehicles (--quick: 60 s,
30 vehicles); (2) SICP vs Open3D ``registration_icp`` on the same clouds (bench.sicp_vs_open3d);
(3) tracker real-time factors on one core with the oracle pose (recording s / CPU s) of the
filter, the fixed-lag and the batch smoother (``fgloc.smoothing.run.compare_trackers``; a smoother's
time excludes the filter it starts from); (4) scaling: recording length 30, 60, 120, 300, 900 s
(vehicle arrivals proportional to length) and vehicle count 20, 50, 100 in 60 s (--quick:
30, 60 s; 20, 50).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.results import Produced
from fgloc.io import write_scenario
from fgloc.pipeline import METHODS
from fgloc.scenario import Scenario
from fgloc.sim import simulate


def peak_rss_mib() -> float:
    """This process's peak resident memory (MiB): ``VmHWM`` of /proc/self/status, which exec
    resets (``ru_maxrss`` keeps the forking parent's peak when that was larger)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return float(line.split()[1]) / 1024.0
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def child_main(method: str, scenario: str, out: str) -> int:
    """Run ``fgloc localize`` in this process and print one JSON line with the stage times,
    wall time and peak RSS (MiB)."""
    from fgloc.cli import main as cli_main

    t0 = time.perf_counter()
    rc = cli_main(["-q", "localize", scenario, "--method", method, "--out", out])
    wall = time.perf_counter() - t0
    doc = json.loads((Path(out) / "result.json").read_text()) if rc == 0 else {}
    print(json.dumps({
        "rc": rc,
        "wall_s": wall,
        "peak_rss_mib": peak_rss_mib(),
        "timings_s": doc.get("timings_s", {}),
    }))
    return 0


def run_child(method: str, scenario: Path, work: Path) -> dict:
    """One localization in a fresh interpreter; its JSON report (rc != 0 on failure)."""
    out = work / f"out-{method}-{scenario.name}"
    cmd = [sys.executable, "-m", "bench.speed", "--child", method, str(scenario), str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode != 0 or not lines:
        return {"rc": proc.returncode or 1, "error": proc.stderr.strip().splitlines()[-1:]}
    return json.loads(lines[-1])


def make_scenario(work: Path, case: str, seed: int, duration: float,
                  vehicles: int | None) -> tuple[Path, Scenario]:
    scn = simulate(case, seed, duration=duration, vehicles=vehicles)
    d = work / f"{case}-{seed}-{duration:g}s-{vehicles}v"
    write_scenario(scn, d)
    return d, scn


def describe(scn: Scenario) -> str:
    n = len(scn.radar)
    rec = scn.radar.duration
    nv = len(scn.truth.tracks) if scn.truth is not None else 0
    return f"{rec:.0f} s, {n} detections ({n / rec:.0f}/s), {nv} vehicles, {len(scn.als)} ALS pts"


def stage_table(reports: dict[str, dict]) -> list[str]:
    """Markdown: per method the stage times (s), total wall time and peak RSS."""
    stages: list[str] = []
    for r in reports.values():
        stages += [s for s in r.get("timings_s", {}) if s not in stages]
    out = ["| method | " + " | ".join(stages) + " | total wall s | peak RSS MiB |",
           "|---|" + "---:|" * (len(stages) + 2)]
    for m, r in reports.items():
        if r["rc"] != 0:
            out.append(f"| {m} | failed: {r.get('error')} |")
            continue
        cells = [f"{r['timings_s'][s]:.2f}" if s in r["timings_s"] else "" for s in stages]
        out.append(f"| {m} | " + " | ".join(cells) + f" | {r['wall_s']:.1f} | "
                   f"{r['peak_rss_mib']:.0f} |")
    return out


def measured(work: Path, label: str, methods: list[str], case: str, seed: int, duration: float,
             vehicles: int | None, rows: list[dict]) -> list[str]:
    """Every method on one scenario in its own process: a heading, the stage table; one row
    per method appended to ``rows``."""
    d, scn = make_scenario(work, case, seed, duration, vehicles)
    reports = {m: run_child(m, d, work) for m in methods}
    rows += [{"part": label, "case": case, "seed": seed, "duration": duration,
              "vehicles": vehicles, "method": m, **r} for m, r in reports.items()]
    return ["", f"{label}: {case} seed {seed}, {describe(scn)}", "", *stage_table(reports)]


def section_stages(work: Path, methods: list[str], duration: float, vehicles: int,
                   rows: list[dict]) -> list[str]:
    return measured(work, "stages and peak memory", methods, "intersection", 1, duration,
                    vehicles, rows)


def section_sicp(repeats: int) -> list[str]:
    from bench import sicp_vs_open3d as so
    from fgloc.registration.config import SicpConfig

    c = so.make_clouds("intersection", 1, 60.0, 1.0, 1.5, 30.0, 1.5)
    cfg = SicpConfig()
    out = ["", f"## (2) SICP vs Open3D registration_icp: {len(c.source_xy)} source, "
           f"{len(c.target_xy)} target points, offset 1.5 m / 1.5 deg, median of {repeats}", "",
           "| method | time ms | ratio to Open3D | 2D error m | yaw error deg |",
           "|---|---:|---:|---:|---:|"]
    t_s, (T_s, it_s) = so.timed(lambda: so.run_fgloc(c, cfg), repeats)
    t_o, T_o = so.timed(lambda: so.open3d_icp(c, cfg.max_correspondence, cfg.max_iterations),
                        repeats)
    for name, t, T in (("fgloc SICP (hard, 50 -> 1.5 m)", t_s, T_s),
                       (f"Open3D p2p ICP ({cfg.max_correspondence:g} m)", t_o, T_o)):
        e2d, eyaw = so.errors(T, c)
        out.append(f"| {name} | {1e3 * t:.1f} | {t / t_o:.2f} | {e2d:.3f} | {eyaw:.3f} |")
    return [*out, f"(SICP iterations: {it_s})"]


def section_realtime(scn: Scenario) -> list[str]:
    from fgloc.evaluation.trackers import compare_trackers

    cmp = compare_trackers(scn, oracle_pose=True)
    i = cmp.names.index("batch")
    return ["", f"## (3) tracker real-time factors, oracle pose, one core: {describe(scn)}", "",
            "```", cmp.table(), "```",
            f"batch smoother: {cmp.cpu_seconds[i] / max(cmp.track_minutes, 1e-9):.2f} CPU s per "
            f"track-minute ({cmp.track_minutes:.1f} track-minutes)"]


def section_scaling(work: Path, methods: list[str], durations: list[float],
                    vehicle_counts: list[int], rows: list[dict]) -> list[str]:
    out = ["", "#### Scaling with recording length (vehicle arrivals proportional)"] \
        if durations else []
    for dur in durations:
        out += measured(work, f"{dur:g} s", methods, "intersection", 2, dur, None, rows)
    if vehicle_counts:
        out += ["", "#### Scaling with vehicle count (60 s)"]
    for nv in vehicle_counts:
        out += measured(work, f"{nv} vehicles", methods, "intersection", 3, 60.0, nv, rows)
    return out


def produce(duration: float, vehicles: int, durations: list[float], vehicle_counts: list[int],
            methods: list[str]) -> Produced:
    """The report's speed table: stages and peak memory on one intersection of ``duration``
    s with ``vehicles`` vehicles, then the scaling runs; summary: peak RSS (MiB) and wall
    time (s) per method of the first part."""
    rows: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        body = ["#### Stages and peak memory", *section_stages(Path(tmp), methods, duration,
                                                              vehicles, rows)]
        body += section_scaling(Path(tmp), methods, durations, vehicle_counts, rows)
    first = [r for r in rows if r["part"] == "stages and peak memory" and r["rc"] == 0]
    summary = {"peak_rss_mib": {r["method"]: r["peak_rss_mib"] for r in first},
               "wall_s": {r["method"]: r["wall_s"] for r in first}}
    return Produced(rows, body, f"intersection seed 1, {duration:g} s, {vehicles} vehicles; "
                    f"scaling: {durations} s (seed 2), {vehicle_counts} vehicles in 60 s "
                    "(seed 3)", summary)


def main() -> int:
    if len(sys.argv) == 5 and sys.argv[1] == "--child":
        return child_main(*sys.argv[2:])
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="smaller scenarios, fewer points")
    ap.add_argument("--methods", nargs="+", default=sorted(METHODS), choices=sorted(METHODS))
    ap.add_argument("--sections", nargs="+", default=["stages", "sicp", "realtime", "scaling"],
                    choices=["stages", "sicp", "realtime", "scaling"])
    args = ap.parse_args()
    quick = args.quick
    print(f"# fgloc speed: {os.cpu_count()} CPUs, load {os.getloadavg()[0]:.2f}, "
          f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}, "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        dur, nveh = (60.0, 30) if quick else (120.0, 60)
        rows: list[dict] = []
        if "stages" in args.sections:
            print("\n".join(section_stages(work, args.methods, dur, nveh, rows)), flush=True)
        if "sicp" in args.sections:
            print("\n".join(section_sicp(3 if quick else 7)), flush=True)
        if "realtime" in args.sections:
            print("\n".join(section_realtime(simulate("intersection", 1, duration=dur,
                                                       vehicles=nveh))), flush=True)
        if "scaling" in args.sections:
            print("\n".join(section_scaling(work, args.methods,
                                             [30.0, 60.0] if quick
                                             else [30.0, 60.0, 120.0, 300.0, 900.0],
                                             [20, 50] if quick else [20, 50, 100], rows)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
