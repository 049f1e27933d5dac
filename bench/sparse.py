"""Sparse traffic: resolved or honestly ambiguous, never confidently wrong (issue 21).

Per case (the 4-arm junction "intersection" and the T-junction "tjunction"), traffic density
(vehicles per minute: the simulator's Poisson ``[traffic] arrival_interval = 60 / rate`` s) and
seed, a scenario of ``--duration`` s is simulated and localized by icp, filter-sicp and joint
(``localize_many``: the shared stages once). Per run and method: the result's status
(resolved / ambiguous; "no pose" when the method raised LocalizationError, as with too few
vehicles for a track), the 2D, yaw and height errors, the NEES of (x, y, yaw) against the
reported covariance (every method reports one: icp its lane-score tie's, the others their fit's
per track, docs/method.md 2.1), the reported std. dev. of z, and for ambiguous runs whether the
truth lies at one of the tied modes, on the valley they are samples of or within 2 std. devs.
along the weak direction (within ``--mode-tolerance`` m; :func:`truth_distance`). Goals: every
resolved run within 0.3 m, every ambiguous run with the truth among its modes, the joint's
mean NEES over its resolved runs at most 6; the share resolved as reported.

Second part, the sensor height (``--height``, on by default; ``--no-height`` skips it): the
coarse stage (which gives every method its z, pitch and roll) on 60 s scenarios of default
traffic, both cases, the same seeds, with the simulator's vehicle return heights as by default,
uniform 0.2-1.5 m, and uniform 0.9-1.5 m (centred at 1.2 m), and with its curbs (the static
ground returns) 0.05 m and 0.25 m high instead of 0.15 m, and without static scatterers
(no kerbs, poles or facades: the static detections are false alarms and vehicles standing in
queues); per setting the mean and worst |dz| and tilt error and the mean of (dz / z_std)^2,
for the defaults and for the former model (a fixed 1.2 m reflection height, no static ground
returns). Goal: |dz| <= 0.15 m in every setting with static scatterers, the tilt as good as
the former model's; without them, (dz / z_std)^2 about 1 or less (z rests on the moving
returns' height prior, and says so).

    OMP_NUM_THREADS=1 python -m bench.sparse
    OMP_NUM_THREADS=1 python -m bench.sparse --quick

docs/benchmarks.md's table comes from ``python -m bench.report --only sparse``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from bench.report_section import provenance
from fgloc.coarse import coarse_localize
from fgloc.config import Config, load_config
from fgloc.errors import LocalizationError
from fgloc.evaluation.pose import pose_error, pose_error_vector
from fgloc.map import build_target_cloud
from fgloc.pipeline import localize_many
from fgloc.result import LocalizationResult
from fgloc.sim import SimConfig, simulate

METHODS = ("icp", "filter-sicp", "smoother-sicp", "joint")
CASES = ("intersection", "tjunction")
RATES = (2.0, 5.0, 10.0, 20.0)
#: the status of a run whose method raised LocalizationError (no track to register, ...)
NO_POSE = "no pose"
#: the goal of a resolved run's 2D error (m)
RESOLVED_BAR = 0.3


@dataclasses.dataclass
class Run:
    """One method on one scenario."""

    case: str
    rate: float
    seed: int
    method: str
    vehicles: int
    status: str
    n_modes: int
    n_tied: int
    err_2d: float
    err_yaw_deg: float
    err_z: float
    z_std: float | None
    nees: float | None
    truth_in_modes: bool
    seconds: float


def scenario(case: str, seed: int, rate: float, duration: float):
    sc = SimConfig()
    sc = dataclasses.replace(sc, traffic=dataclasses.replace(sc.traffic,
                                                             arrival_interval=60.0 / rate))
    return simulate(case, seed, duration=duration, config=sc)


def truth_distance(res: LocalizationResult, truth: np.ndarray) -> float:
    """Distance (m, in the plane) from the true sensor position (``truth`` 4x4 S -> L) to the
    nearest place the result says the sensor may be: its tied modes (every mode when none is
    flagged tied) and, when it reports one, the segment of its valley or of its weak direction
    (the reported position +-2 std. devs. along it)."""
    tied = [f for f, d in zip(res.mode_fits, res.modes) if d["tied"]] or res.mode_fits
    xy = truth[:2, 3]
    near = [float(np.hypot(*(f.T_local[:2, 3] - xy))) for f in tied]
    for seg in (res.valley, res.weak_direction):
        if seg is None:
            continue
        a, b = (res.frame.to_local(np.array([[seg[k]["x"], seg[k]["y"]]]))[0]
                for k in ("from", "to"))
        t = float(np.clip((xy - a) @ (b - a) / max(float((b - a) @ (b - a)), 1e-12), 0.0, 1.0))
        near.append(float(np.hypot(*(a + t * (b - a) - xy))))
    return min(near) if near else float(np.hypot(*(res.T_local[:2, 3] - xy)))


def localize_each(scn, cfg) -> dict[str, LocalizationResult | None]:
    """Every method's result on ``scn``; None for a method that raised
    :class:`LocalizationError` (too little traffic for it: no track, too few points)."""
    try:
        return localize_many(scn, list(METHODS), cfg)
    except LocalizationError:
        out: dict[str, LocalizationResult | None] = {}
        for m in METHODS:
            try:
                out[m] = localize_many(scn, [m], cfg)[m]
            except LocalizationError:
                out[m] = None
        return out


def run_one(case: str, seed: int, rate: float, duration: float, cfg, tol: float) -> list[Run]:
    scn = scenario(case, seed, rate, duration)
    truth = scn.truth.sensor_pose
    t0 = time.perf_counter()
    out = localize_each(scn, cfg)
    seconds = time.perf_counter() - t0
    runs = []
    for m, res in out.items():
        if res is None:
            runs.append(Run(case, rate, seed, m, len(scn.truth.tracks), NO_POSE, 0, 0, np.nan,
                            np.nan, np.nan, None, None, False, seconds))
            continue
        err = pose_error(res.T_local, truth)
        e = pose_error_vector(res.T_local, truth)
        nees = None if res.covariance is None else float(e @ np.linalg.solve(res.covariance, e))
        n_tied = sum(bool(d["tied"]) for d in res.modes) or len(res.modes)
        runs.append(Run(case, rate, seed, m, len(scn.truth.tracks), res.status, len(res.modes),
                        n_tied, err.d2d, err.dyaw_deg, float(res.T_local[2, 3] - truth[2, 3]),
                        res.z_std, nees, truth_distance(res, truth) <= tol, seconds))
    return runs


#: simulated heights (m above the road): the simulator's ``[radar]`` settings per row name
#: (vehicle returns ``return_height``, None = the simulator's default; curb scatterers
#: ``curb_height``, 0.15 m by default, against fgloc's static-return prior 0.1 +- 0.05 m)
HEIGHT_SETTINGS: dict[str, dict[str, object]] = {
    "default": {}, "returns uniform 0.2-1.5 m": {"return_height": (0.2, 1.5)},
    "returns uniform 0.9-1.5 m": {"return_height": (0.9, 1.5)},
    "curbs 0.05 m": {"curb_height": 0.05}, "curbs 0.25 m": {"curb_height": 0.25},
    "no static scatterers": {"clutter_per_frame": 0.0}}


def former_height_model(cfg: Config) -> Config:
    """``cfg`` with the vertical fit as before issue 21: a fixed 1.2 m reflection height and
    no static ground returns."""
    coarse = dataclasses.replace(cfg.coarse, reflection_height=1.2, reflection_height_sigma=0.0,
                                 static_min_points=10**9)
    return dataclasses.replace(cfg, coarse=coarse)


def height_rows(cases: list[str], seeds: list[int], duration: float, cfg: Config
                ) -> list[str]:
    """The height table: per height setting (:data:`HEIGHT_SETTINGS`) and model, over cases x
    seeds, the mean / worst |dz| (m) and tilt error (deg) of the coarse pose and the mean
    (dz / z_std)^2."""
    lines = ["| simulated heights | model | runs | abs dz m (mean / worst) | tilt error deg "
             "(mean / worst) | mean (dz / z_std)^2 |", "|---|---|---|---|---|---|"]
    for name, radar in HEIGHT_SETTINGS.items():
        sims = []
        for case in cases:
            for seed in seeds:
                sc = SimConfig()
                sc = dataclasses.replace(sc, radar=dataclasses.replace(sc.radar, **radar))
                sims.append(simulate(case, seed, duration=duration, config=sc))
        for model, mc in (("defaults", cfg), ("former: fixed 1.2 m", former_height_model(cfg))):
            dz, tilt, nz = [], [], []
            for scn in sims:
                res = coarse_localize(scn, build_target_cloud(scn, mc.map), mc.coarse)
                truth = scn.truth.sensor_pose
                E = truth[:3, :3] @ res.T_coarse[:3, :3].T
                w = 0.5 * np.array([E[2, 1] - E[1, 2], E[0, 2] - E[2, 0]])
                dz.append(float(res.T_coarse[2, 3] - truth[2, 3]))
                tilt.append(float(np.rad2deg(np.linalg.norm(w))))
                if res.z_std:
                    nz.append((dz[-1] / res.z_std) ** 2)
                print(f"height {name:<18} {model:<20} dz {dz[-1]:+.3f} z_std "
                      f"{_fmt(res.z_std, '{:.3f}')} tilt {tilt[-1]:.3f} deg "
                      f"static {res.n_static_ground}", flush=True)
            a = np.abs(dz)
            lines.append(f"| {name} | {model} | {len(dz)} | {a.mean():.3f} / {a.max():.3f} | "
                         f"{np.mean(tilt):.3f} / {max(tilt):.3f} | "
                         f"{_fmt(np.mean(nz) if nz else None)} |")
    return lines


def timing_rows(cfg: Config, repeats: int = 2) -> list[str]:
    """Wall time of ``localize(..., "joint")`` with the modes (the defaults) against one mode
    (``max_modes = 1``: no mode search) on the 120 s intersection (seed 1, default traffic)
    and on the 60 s 4-arm junction at 5 vehicles per minute (seed 1); best of ``repeats``."""
    from fgloc.pipeline import localize

    lines = ["| scenario | max_modes | modes kept | status | wall s (best of "
             f"{repeats}) | ratio |", "|---|---|---|---|---|---|"]
    for name, scn in (("intersection 120 s, seed 1", simulate("intersection", 1,
                                                               duration=120.0)),
                      ("intersection 60 s, 5 veh/min, seed 1",
                       scenario("intersection", 1, 5.0, 60.0))):
        base = None
        for modes in (1, cfg.coarse.max_modes):
            mc = dataclasses.replace(cfg, coarse=dataclasses.replace(cfg.coarse,
                                                                     max_modes=modes))
            best, res = np.inf, None
            for _ in range(repeats):
                t0 = time.perf_counter()
                res = localize(scn, "joint", mc)
                best = min(best, time.perf_counter() - t0)
            base = base or best
            lines.append(f"| {name} | {modes} | {len(res.diagnostics['coarse']['modes'])} | "
                         f"{res.status} | {best:.1f} | {best / base:.2f} |")
            print(lines[-1], flush=True)
    return lines


def retrack_rows(cases: list[str], seeds: list[int], rates: list[float], duration: float,
                 cfg: Config) -> list[str]:
    """Rigid reuse against re-tracking: on every run whose joint picks a mode other than the
    one the tracker's detections were placed by, the tracker is run again with that mode's
    placement (its births and field of view then come from the map as seen from it) and the
    joint (from its own filter-sicp) refined on those tracks; the 2D errors of both and the
    distance between the two poses."""
    from fgloc.geo import se2_to_se3
    from fgloc.pipeline import SharedStages
    from fgloc.progress import Timer
    from fgloc.registration.fine import register_tracks
    from fgloc.registration.joint import joint_from_tracks
    from fgloc.tracking import track_scenario

    lines = ["| run | mode | tracks rigid / re-tracked | joint 2D m rigid | joint 2D m "
             "re-tracked | poses apart m |", "|---|---|---|---|---|---|"]
    for case in cases:
        for rate in rates:
            for seed in seeds:
                scn = scenario(case, seed, rate, duration)
                st = SharedStages(scn, cfg)
                res = localize_many(scn, ["joint"], cfg, st)["joint"]
                target, coarse = st.coarse()
                k = next(i for i, m in enumerate(coarse.modes)
                         if np.allclose(m.start, res.mode_fits[0].start))
                if k == 0:
                    continue
                mode = coarse.modes[k]
                T = mode.placed(se2_to_se3(mode.start) @ coarse.T_coarse)
                placed = dataclasses.replace(coarse, T_coarse=T, modes=[
                    dataclasses.replace(mode, start=np.eye(3))])
                tracks = track_scenario(scn, T, cfg.tracking)
                fine = register_tracks(scn, cfg, target, placed, tracks, Timer(), "filter-sicp")
                again = joint_from_tracks(scn, cfg, target, placed, tracks, Timer(), start=fine)
                truth = scn.truth.sensor_pose[:2, 3]
                lines.append(
                    f"| {case} {rate:g}/min s{seed} | {k} | {len(st.tracks())} / {len(tracks)} | "
                    f"{np.hypot(*(res.T_local[:2, 3] - truth)):.3f} | "
                    f"{np.hypot(*(again.T_local[:2, 3] - truth)):.3f} | "
                    f"{np.hypot(*(res.T_local[:2, 3] - again.T_local[:2, 3])):.3f} |")
                print(lines[-1], flush=True)
    return lines


def _fmt(v: float | None, f: str = "{:.2f}") -> str:
    return "-" if v is None or not np.isfinite(v) else f.format(v)


def table(runs: list[Run]) -> list[str]:
    """Per (case, rate, method): runs, share resolved, 2D error of the resolved runs (mean /
    worst seed), resolved runs beyond the bar, ambiguous runs with the truth among the modes,
    the NEES of the ambiguous runs against their covering covariance and of the resolved runs
    (mean / worst), |dz| (mean / worst)."""
    lines = ["| case | veh/min | method | runs | resolved | 2D m resolved (mean / worst) | "
             f"resolved > {RESOLVED_BAR} m | ambiguous: truth in modes | NEES ambiguous "
             "(mean / worst) | NEES resolved (mean / worst) | abs dz m (mean / worst) | "
             "no pose |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    keys = sorted({(r.case, r.rate, r.method) for r in runs},
                  key=lambda k: (CASES.index(k[0]), k[1], METHODS.index(k[2])))
    for case, rate, method in keys:
        rs = [r for r in runs if (r.case, r.rate, r.method) == (case, rate, method)]
        res = [r for r in rs if r.status == "resolved"]
        amb = [r for r in rs if r.status not in ("resolved", NO_POSE)]
        e2 = [r.err_2d for r in res]
        nees = [r.nees for r in res if r.nees is not None]
        nees_amb = [r.nees for r in amb if r.nees is not None]
        dz = [abs(r.err_z) for r in rs if r.status != NO_POSE]
        lines.append(
            f"| {case} | {rate:g} | {method} | {len(rs)} | {len(res)}/{len(rs)} | "
            f"{_fmt(np.mean(e2) if e2 else None)} / {_fmt(max(e2) if e2 else None)} | "
            f"{sum(x > RESOLVED_BAR for x in e2)} | "
            f"{sum(r.truth_in_modes for r in amb)}/{len(amb)} | "
            f"{_fmt(np.mean(nees_amb) if nees_amb else None)} / "
            f"{_fmt(max(nees_amb) if nees_amb else None)} | "
            f"{_fmt(np.mean(nees) if nees else None)} / {_fmt(max(nees) if nees else None)} | "
            f"{_fmt(np.mean(dz) if dz else None)} / {_fmt(max(dz) if dz else None)} | "
            f"{len(rs) - len(res) - len(amb)} |")
    return lines


def totals(runs: list[Run]) -> list[str]:
    """Per method over every run: share resolved, resolved beyond the bar, ambiguous runs with
    the truth among the modes, mean NEES over the resolved runs and over every run."""
    out = []
    for m in METHODS:
        rs = [r for r in runs if r.method == m]
        if not rs:
            continue
        res = [r for r in rs if r.status == "resolved"]
        amb = [r for r in rs if r.status not in ("resolved", NO_POSE)]
        nees = [r.nees for r in res if r.nees is not None]
        every = [r.nees for r in rs if r.nees is not None]
        out.append(f"- {m}: resolved {len(res)}/{len(rs)} ({100 * len(res) / len(rs):.0f} %), "
                   f"resolved beyond {RESOLVED_BAR} m: {sum(r.err_2d > RESOLVED_BAR for r in res)}"
                   f" (worst {_fmt(max((r.err_2d for r in res), default=None))} m), ambiguous "
                   f"with the truth among the tied modes: {sum(r.truth_in_modes for r in amb)}/"
                   f"{len(amb)}, mean NEES over the resolved runs: "
                   f"{_fmt(np.mean(nees) if nees else None)}, over every run: "
                   f"{_fmt(np.mean(every) if every else None)}, no pose (LocalizationError): "
                   f"{len(rs) - len(res) - len(amb)}")
    return out



def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="smoke set: seed 1, 5 and 10 vehicles per minute, both cases")
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    ap.add_argument("--rates", nargs="+", type=float, default=list(RATES),
                    help="vehicles per minute")
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3, 4, 5])
    ap.add_argument("--duration", type=float, default=60.0, help="scenario length (s)")
    ap.add_argument("--mode-tolerance", type=float, default=0.5,
                    help="an ambiguous run holds the truth when a tied mode is this close (m)")
    ap.add_argument("--no-height", action="store_true", help="skip the sensor-height part")
    ap.add_argument("--no-timing", action="store_true", help="skip the modes' time part")
    ap.add_argument("--retrack", action="store_true",
                    help="only compare rigid reuse of the tracks with re-tracking per mode "
                         "(printed, not written)")
    ap.add_argument("--config", default=None, help="fgloc config TOML (default: all defaults)")
    ap.add_argument("--json", default=None, help="also write every run's figures here")
    args = ap.parse_args()
    if args.quick:
        args.seeds, args.rates = [1], [5.0, 10.0]
    cfg = load_config(args.config)
    if args.retrack:
        print("\n".join(retrack_rows(args.cases, args.seeds, args.rates, args.duration, cfg)))
        return 0
    t0 = time.perf_counter()
    runs: list[Run] = []
    for case in args.cases:
        for rate in args.rates:
            for seed in args.seeds:
                for r in run_one(case, seed, rate, args.duration, cfg, args.mode_tolerance):
                    runs.append(r)
                    print(f"{case:<12} {rate:>4g} {seed:>2} {r.method:<11} {r.status:<9} "
                          f"modes {r.n_tied}/{r.n_modes} 2d {r.err_2d:.2f} yaw "
                          f"{r.err_yaw_deg:.2f} dz {r.err_z:+.2f} z_std {_fmt(r.z_std)} "
                          f"nees {_fmt(r.nees)} truth_in_modes {r.truth_in_modes} "
                          f"{r.seconds:.1f} s", flush=True)
                if args.json:
                    Path(args.json).write_text(json.dumps([dataclasses.asdict(x) for x in runs],
                                                          indent=1))
    height = [] if args.no_height else ["", "Sensor height (coarse stage; 60 s, default "
                                        "traffic, the cases and seeds above):", "",
                                        *height_rows(args.cases, args.seeds, 60.0, cfg)]
    timing = [] if args.no_timing else ["", "Time of the modes (`--method joint`, one "
                                        "process, OMP_NUM_THREADS=1):", "",
                                        *timing_rows(cfg, 1 if args.quick else 2)]
    elapsed = time.perf_counter() - t0
    command = "OMP_NUM_THREADS=1 python -m bench.sparse" + (" " if len(sys.argv) > 1 else "") \
        + " ".join(sys.argv[1:])
    head = [f"### Sparse traffic (`python -m bench.sparse{' --quick' if args.quick else ''}`)", "",
            f"Command: `{command}`", "",
            f"{provenance()}, {args.duration:g} s scenarios, seeds {args.seeds}, "
            f"{elapsed:.0f} s in total. "
            "Cells over the seeds: mean / worst seed. NEES of (x, y, yaw) against the "
            "reported covariance (3 degrees of freedom). An ambiguous run holds the truth when "
            f"one of its tied modes, its valley or its weak direction's +-2 std. devs. lies "
            f"within {args.mode_tolerance:g} m of it.", ""]
    text = "\n".join(head + table(runs) + [""] + totals(runs) + height + timing)
    print("\n" + text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
