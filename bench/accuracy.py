"""Localization and tracking accuracy of every method, through the file route a user takes.

For every case and seed: simulate, write the scenario directory, load it back, localize with
each method (with the sensor.toml yaw guess, and with ``--without-guess`` also without it) and
score against the ground truth. The methods of one scenario share their common stages
(:func:`fgloc.pipeline.localize_many`: same poses as separate runs); a method's time is the sum
of its stage times, what a separate run would spend. Prints (and with ``--markdown`` writes)
these tables:

* Table I analogue: per scenario and method |dx|, |dy|, 2D, |dyaw| (deg), |dz|, time;
* Table II analogue: per method and case mean / worst 2D and yaw error, and, for methods that
  report a covariance, the mean normalized estimation error squared (NEES) of (x, y, yaw);
* the straight road (``--straight-seeds``): errors, the along-road standard deviation and the
  weak-direction flag of methods that report a covariance;
* tracking (``--tracking-seeds``, oracle pose): filter, fixed-lag and batch smoother metrics;
* data efficiency (``--efficiency-counts``): 2D and yaw error against the number of
  trajectories used, for ``--efficiency-methods``; ``--plot`` writes it as a PNG.

    OMP_NUM_THREADS=1 python -m bench.accuracy                       # the full set
    OMP_NUM_THREADS=1 python -m bench.accuracy --quick               # under 5 minutes
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.results import Produced
from fgloc.config import Config, load_config
from fgloc.evaluation.pose import pose_error, pose_error_vector
from fgloc.io import load_scenario, write_scenario
from fgloc.pipeline import METHODS, SharedStages, localize_many
from fgloc.result import LocalizationResult
from fgloc.scenario import Scenario
from fgloc.sim import simulate

PAPER = {  # the paper's figures (their data: real recordings + CARLA), for reference only
    "Table I (filter-sicp, S1-S4)": "2D 0.38-0.94 m, |dyaw| 0.16-0.35 deg",
    "Table II (the earlier method [localizationiv], S3 / S4)": "|dx| 0.93 / 0.80 m, "
                                                               "|dy| 0.82 / 0.70 m, "
                                                               "|dyaw| 1.25 / 0.03 deg",
}
#: docs/, where the report's markdown lives (links to figures are relative to it)
DOCS = Path(__file__).resolve().parent.parent / "docs"


@dataclass
class Run:
    """One localization scored against the truth.

    signed: (3,) estimate minus truth in L: x (m), y (m), yaw (rad, wrapped). cov: 3x3 (x, y,
    yaw) covariance of the result or None. along_sd: standard deviation (m) along the road
    direction given by ``road_dir`` (straight road only), weak: the result's weak-direction
    flag, if it reports one; status: the result's status ("resolved" or "ambiguous").
    """

    case: str
    seed: int
    guess: bool
    method: str
    n_trajectories: int | None
    converged: bool
    time_s: float
    err: dict
    signed: np.ndarray
    cov: np.ndarray | None
    weak: bool | None
    status: str

    @property
    def nees(self) -> float:
        if self.cov is None:
            return float("nan")
        return float(self.signed @ np.linalg.solve(self.cov, self.signed))


def weak_flag(res: LocalizationResult) -> bool | None:
    """The result's weak-direction flag (diagnostics ``<stage>.degeneracy.weakly_observed``,
    reported by the joint method), or None when the method reports none."""
    for block in res.diagnostics.values():
        if isinstance(block, dict) and isinstance(block.get("degeneracy"), dict):
            deg = block["degeneracy"]
            if "weakly_observed" in deg:
                return bool(deg["weakly_observed"])
    return None


def score(scn: Scenario, res: LocalizationResult, method: str, guess: bool, dt: float,
          n_traj: int | None, case: str, seed: int) -> Run:
    assert scn.truth is not None
    signed = pose_error_vector(res.T_local, scn.truth.sensor_pose)
    cov = None if res.covariance is None else np.asarray(res.covariance, float)[:3, :3]
    return Run(case, seed, guess, method, n_traj, bool(res.converged), dt,
               pose_error(res.T_local, scn.truth.sensor_pose).to_json(), signed, cov,
               weak_flag(res), res.status)


def localize_scored(scn: Scenario, methods: list[str], cfg: Config, guess: bool, case: str,
                    seed: int, n_traj: int | None = None,
                    stages: SharedStages | None = None) -> list[Run]:
    """``methods`` on ``scn`` (shared stages computed once, :func:`localize_many`), scored;
    a run's time is the sum of its stage times, what a separate run would spend."""
    if n_traj is not None:
        cfg = dataclasses.replace(cfg, fine=dataclasses.replace(cfg.fine, n_trajectories=n_traj))
    res = localize_many(scn, methods, cfg, stages)
    return [score(scn, r, m, guess, sum(r.timings.values()), n_traj, case, seed)
            for m, r in res.items()]


def scenario_file_route(case: str, seed: int, duration: float, work: Path) -> Path:
    d = work / f"{case}-{seed}"
    write_scenario(simulate(case, seed, duration=duration), d)
    return d


def localization_runs(case: str, seed: int, duration: float, methods: list[str], work: Path,
                      cfg: Config, guesses: tuple[bool, ...],
                      shared: dict[tuple[str, int], SharedStages | None]) -> list[Run]:
    """Every method on one simulated scenario (written and loaded back); when ``shared`` has
    the key ``(case, seed)``, the shared stages of the run with the yaw guess are kept there
    (for the data-efficiency sweep)."""
    d = scenario_file_route(case, seed, duration, work)
    runs = []
    for guess in guesses:
        scn = load_scenario(d)
        if not guess:
            scn.sensor = dataclasses.replace(scn.sensor, yaw_guess_deg=None)
        stages = SharedStages(scn, cfg)
        if guess and (case, seed) in shared:
            shared[(case, seed)] = stages
        for r in localize_scored(scn, methods, cfg, guess, case, seed, stages=stages):
            print(f"  {case:<13}{seed:>3} {'guess' if guess else 'none ':<6}{r.method:<14}"
                  f"2D {r.err['d2d']:6.3f} m  |dyaw| {r.err['dyaw_deg']:6.3f} deg  "
                  f"{r.time_s:5.1f} s{'' if r.converged else '  NOT CONVERGED'}", flush=True)
            runs.append(r)
    return runs


# ---------------------------------------------------------------------------------- tables
def run_label(r: Run) -> str:
    """The method's name with what the run says about itself: not converged, ambiguous."""
    notes = [n for n, on in (("not converged", not r.converged),
                             (r.status, r.status != "resolved")) if on]
    return r.method + (f" ({', '.join(notes)})" if notes else "")


def table_one(runs: list[Run]) -> list[str]:
    out = ["| case | seed | yaw guess | method | \\|dx\\| m | \\|dy\\| m | 2D m | \\|dyaw\\| deg "
           "| \\|dz\\| m | time s |", "|---|---:|---|---|---:|---:|---:|---:|---:|---:|"]
    for r in runs:
        e = r.err
        out.append(f"| {r.case} | {r.seed} | {'yes' if r.guess else 'no'} | {run_label(r)}"
                   f" | {e['dx']:.3f} | "
                   f"{e['dy']:.3f} | {e['d2d']:.3f} | {e['dyaw_deg']:.3f} | {e['dz']:.3f} | "
                   f"{r.time_s:.1f} |")
    return out


def table_two(runs: list[Run], methods: list[str]) -> list[str]:
    out = ["| method | case | runs | mean 2D m | worst 2D m | mean \\|dyaw\\| deg | worst "
           "\\|dyaw\\| deg | ambiguous | mean NEES (x, y, yaw) | mean time s |",
           "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    cases = sorted({r.case for r in runs})
    for m in methods:
        for case in [*cases, "all"]:
            sel = [r for r in runs if r.method == m and case in (r.case, "all")]
            if not sel:
                continue
            d2 = np.array([r.err["d2d"] for r in sel])
            dy = np.array([r.err["dyaw_deg"] for r in sel])
            nees = np.array([r.nees for r in sel])
            ntxt = f"{np.nanmean(nees):.2f}" if np.isfinite(nees).any() else "-"
            out.append(f"| {m} | {case} | {len(sel)} | {d2.mean():.3f} | {d2.max():.3f} | "
                       f"{dy.mean():.3f} | {dy.max():.3f} | "
                       f"{sum(r.status != 'resolved' for r in sel)}/{len(sel)} | {ntxt} | "
                       f"{np.mean([r.time_s for r in sel]):.1f} |")
    return out


def table_straight(runs: list[Run], road_dirs: dict[int, np.ndarray]) -> list[str]:
    out = ["| seed | method | 2D m | along-road error m | \\|dyaw\\| deg | along-road sd m "
           "| weak direction flagged | status |", "|---:|---|---:|---:|---:|---:|---|---|"]
    for r in runs:
        u = road_dirs[r.seed]
        along = abs(float(r.signed[:2] @ u))
        sd = "-" if r.cov is None else f"{np.sqrt(u @ r.cov[:2, :2] @ u):.3f}"
        flag = "-" if r.weak is None else ("yes" if r.weak else "no")
        out.append(f"| {r.seed} | {r.method} | {r.err['d2d']:.3f} | {along:.3f} | "
                   f"{r.err['dyaw_deg']:.3f} | {sd} | {flag} | {r.status} |")
    return out


def road_direction(scn: Scenario) -> np.ndarray:
    """Unit vector (L) of the straight road: the principal axis of the true vehicle centres."""
    assert scn.truth is not None
    xy = np.concatenate([tr.states[:, 1:3] for tr in scn.truth.tracks])
    xy = xy - xy.mean(axis=0)
    return np.linalg.eigh(xy.T @ xy)[1][:, -1]


def table_efficiency(runs: list[Run], counts: list[int], methods: list[str]) -> list[str]:
    out = ["| method | trajectories | runs | mean 2D m | worst 2D m | mean \\|dyaw\\| deg | "
           "worst \\|dyaw\\| deg |", "|---|---:|---:|---:|---:|---:|---:|"]
    for m in methods:
        for n in counts:
            sel = [r for r in runs if r.method == m and r.n_trajectories == n]
            if sel:
                d2 = np.array([r.err["d2d"] for r in sel])
                dy = np.array([r.err["dyaw_deg"] for r in sel])
                out.append(f"| {m} | {n} | {len(sel)} | {d2.mean():.3f} | {d2.max():.3f} | "
                           f"{dy.mean():.3f} | {dy.max():.3f} |")
    return out


def plot_efficiency(runs: list[Run], counts: list[int], methods: list[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    for m in methods:
        for ax, key in zip(axes, ("d2d", "dyaw_deg")):
            mean = [np.mean([r.err[key] for r in runs if r.method == m and r.n_trajectories == n])
                    for n in counts]
            ax.plot(counts, mean, marker="o", label=m)
    axes[0].set_ylabel("mean 2D error (m)")
    axes[1].set_ylabel("mean |yaw error| (deg)")
    for ax in axes:
        ax.set_xlabel("trajectories used")
        ax.set_xscale("log")
        ax.minorticks_off()
        ax.set_xticks(counts, [str(n) for n in counts])
        ax.grid(alpha=0.3)
        ax.set_ylim(bottom=0)
    axes[0].legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)


# ------------------------------------------------------------------------------ producers
def run_row(r: Run) -> dict:
    """A Run as a JSON-serializable dict (the stored row)."""
    return dict(dataclasses.asdict(r), signed=r.signed.tolist(),
                cov=None if r.cov is None else r.cov.tolist())


def method_summary(runs: list[Run]) -> dict[str, dict[str, float | None]]:
    """Per method over all runs: runs, mean / worst 2D (m), mean |dyaw| (deg), mean |dz| (m),
    mean NEES of (x, y, yaw) (None without covariance) and mean time (s)."""
    out: dict[str, dict[str, float | None]] = {}
    for m in sorted({r.method for r in runs}):
        sel = [r for r in runs if r.method == m]
        nees = np.array([r.nees for r in sel])
        out[m] = {"runs": len(sel),
                  "d2d_mean": float(np.mean([r.err["d2d"] for r in sel])),
                  "d2d_worst": float(np.max([r.err["d2d"] for r in sel])),
                  "dyaw_mean": float(np.mean([r.err["dyaw_deg"] for r in sel])),
                  "dz_mean": float(np.mean([r.err["dz"] for r in sel])),
                  "nees_mean": float(np.nanmean(nees)) if np.isfinite(nees).any() else None,
                  "time_mean": float(np.mean([r.time_s for r in sel]))}
    return out


def produce_scenarios(cases: list[str], seeds: list[int], duration: float, methods: list[str],
                      cfg: Config | None = None, without_guess: bool = False) -> Produced:
    """Table I and II analogues: every method on cases x seeds (file route)."""
    cfg = cfg or Config()
    runs: list[Run] = []
    with tempfile.TemporaryDirectory() as tmp:
        for case in cases:
            for seed in seeds:
                runs += localization_runs(case, seed, duration, methods, Path(tmp), cfg,
                                          (True, False) if without_guess else (True,), {})
    body = ["#### Per scenario (Table I analogue)", "", *table_one(runs), "",
            "#### Per method (Table II analogue)", "", *table_two(runs, methods)]
    return Produced([run_row(r) for r in runs], body,
                    f"cases {', '.join(cases)}, seeds {seeds}, {duration:g} s scenarios, "
                    "sensor.toml yaw guess" + (" and without it" if without_guess else ""),
                    {"methods": method_summary(runs)})


def produce_straight(seeds: list[int], duration: float, methods: list[str],
                     cfg: Config | None = None) -> Produced:
    """The straight road: errors, along-road error and standard deviation, weak flag."""
    cfg = cfg or Config()
    runs: list[Run] = []
    road_dirs: dict[int, np.ndarray] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            runs += localization_runs("straight", seed, duration, methods, Path(tmp), cfg,
                                      (True,), {})
            road_dirs[seed] = road_direction(load_scenario(Path(tmp) / f"straight-{seed}"))
    return Produced([run_row(r) for r in runs], table_straight(runs, road_dirs),
                    f"straight road, seeds {seeds}, {duration:g} s scenarios")


def produce_efficiency(seeds: list[int], counts: list[int], duration: float,
                       methods: list[str], plot: Path | None = None,
                       cfg: Config | None = None, link_base: Path = DOCS) -> Produced:
    """2D and yaw error against the number of trajectories used (intersection + T-junction);
    ``plot`` also writes the PNG, linked relative to ``link_base`` (the markdown's folder)."""
    cfg = cfg or Config()
    runs: list[Run] = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            for case in ("intersection", "tjunction"):
                stages = SharedStages(load_scenario(
                    scenario_file_route(case, seed, duration, Path(tmp))), cfg)
                for n in counts:
                    for r in localize_scored(stages.scenario, methods, cfg, True, case, seed, n,
                                             stages):
                        print(f"  {case:<13}{seed:>3} {n:>3} trajectories {r.method:<14}"
                              f"2D {r.err['d2d']:6.3f} m  |dyaw| {r.err['dyaw_deg']:6.3f} deg",
                              flush=True)
                        runs.append(r)
    body = table_efficiency(runs, counts, methods)
    if plot is not None:
        plot_efficiency(runs, counts, methods, plot)
        link = os.path.relpath(plot.resolve(), link_base.resolve())
        body += ["", f"![data efficiency]({link})"]
    return Produced([run_row(r) for r in runs], body,
                    f"intersection and T-junction, seeds {seeds}, {duration:g} s scenarios, "
                    f"{counts} trajectories")


def produce_tracking(seeds: list[int], duration: float, vehicles: int,
                     cfg: Config | None = None) -> Produced:
    """Filter, fixed-lag and batch smoother on the same scenarios, oracle pose."""
    from fgloc.evaluation.trackers import compare_trackers

    cfg = cfg or Config()
    rows: list[dict] = []
    body: list[str] = []
    for seed in seeds:
        scn = simulate("intersection", seed, duration=duration, vehicles=vehicles)
        cmp = compare_trackers(scn, cfg, oracle_pose=True)
        rate = len(scn.radar) / scn.radar.duration
        for name, m, cpu in zip(cmp.names, cmp.metrics, cmp.cpu_seconds):
            rows.append({"seed": seed, "tracker": name, "detections_per_s": rate,
                         "cpu_s": cpu, "rtf": cmp.recording_s / cpu if cpu > 0 else None,
                         **{k: v for k, v in dataclasses.asdict(m).items()
                            if k not in ("rows", "missed_ids")}})
        body += ["", f"intersection seed {seed} ({rate:.0f} detections/s, {vehicles} "
                 f"vehicles, {duration:g} s):", "", "```", cmp.table(), "```"]
    summary = {}
    for name in ("filter", "fixed-lag", "batch"):
        sel = [r for r in rows if r["tracker"] == name]
        summary[name] = {k: float(np.mean([r[k] for r in sel]))
                         for k in ("centre_rms_track_mean", "yaw_error_deg", "iou", "rtf")}
    return Produced(rows, body[1:], f"intersection, seeds {seeds}, {duration:g} s, "
                    f"{vehicles} vehicles, oracle pose", summary)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="seed 1 of each case, 30 s, yaw guess only, small efficiency sweep")
    ap.add_argument("--cases", nargs="+", default=["intersection", "tjunction", "curve"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3, 4, 5])
    ap.add_argument("--methods", nargs="+", default=sorted(METHODS), choices=sorted(METHODS))
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--without-guess", action="store_true",
                    help="also localize every scenario without the sensor.toml yaw guess")
    ap.add_argument("--straight-seeds", nargs="*", type=int, default=[1, 2, 3])
    ap.add_argument("--tracking-seeds", nargs="*", type=int, default=[1, 2, 3, 4, 5])
    ap.add_argument("--efficiency-counts", nargs="*", type=int, default=[5, 10, 20, 50])
    ap.add_argument("--efficiency-methods", nargs="*", default=["filter-sicp", "joint"])
    ap.add_argument("--efficiency-seeds", nargs="*", type=int, default=[1, 2, 3])
    ap.add_argument("--plot", default=None, help="write the data-efficiency plot to this PNG")
    ap.add_argument("--markdown", default=None, help="also write all tables to this file")
    ap.add_argument("--json", default=None, help="also write all runs to this JSON file")
    ap.add_argument("--config", default=None, help="fgloc config TOML (default: all defaults)")
    args = ap.parse_args()
    if args.quick:
        args.seeds, args.duration = [1], 30.0
        args.straight_seeds, args.tracking_seeds, args.efficiency_seeds = [1], [1], [1]
        args.efficiency_counts = [5, 20]
    cfg = load_config(args.config)
    eff_methods = [m for m in args.efficiency_methods if m in METHODS]
    t_start = time.perf_counter()
    md = [f"fgloc accuracy, {time.strftime('%Y-%m-%d', time.gmtime())}, {os.cpu_count()} CPUs, "
          f"{args.duration:g} s scenarios, seeds {args.seeds}"]
    print("localization runs:")
    parts = [("Table I and II analogues", produce_scenarios(
        args.cases, args.seeds, args.duration, args.methods, cfg, args.without_guess))]
    if args.straight_seeds:
        parts.append(("Straight road without junction (weakly observed along the road)",
                      produce_straight(args.straight_seeds, args.duration, args.methods, cfg)))
    if eff_methods and args.efficiency_counts and args.efficiency_seeds:
        print("data efficiency runs:")
        parts.append(("Data efficiency (intersection + T-junction)", produce_efficiency(
            args.efficiency_seeds, args.efficiency_counts, args.duration, eff_methods,
            Path(args.plot) if args.plot else None, cfg,
            Path(args.markdown).parent if args.markdown else Path.cwd())))
    if args.tracking_seeds:
        print("tracking runs ...", flush=True)
        parts.append(("Tracking: filter, fixed-lag and batch smoother (oracle pose)",
                      produce_tracking(args.tracking_seeds, args.duration,
                                       30 if args.quick else 50, cfg)))
    for title, p in parts:
        md += [f"\n### {title}\n", *p.body]
    md.append("\nThe paper's figures (their data, not ours): "
              + "; ".join(f"{k}: {v}" for k, v in PAPER.items()))
    md.append(f"\nTotal time {time.perf_counter() - t_start:.0f} s.")
    text = "\n".join(md)
    print("\n" + text)
    if args.markdown:
        Path(args.markdown).write_text(text + "\n")
    if args.json:
        Path(args.json).write_text(json.dumps([r for _, p in parts[:3] for r in p.rows],
                                              indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
