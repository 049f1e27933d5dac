"""``--method joint`` against ``--method filter-sicp`` on the same runs (issue 7 figures).

Per case and seed the scenario is simulated, the coarse pose and the filter's tracks are
computed once, and both fine stages run on them: filter-sicp (``register_tracks``) and joint
(``joint_from_tracks``, started from that filter-sicp result). Printed per run: 2D and yaw
error of both, joint's NEES of (x, y, yaw) against its 3x3 covariance, its standard
deviations, weak-direction flag and time; then the means.

    OMP_NUM_THREADS=1 python bench/joint.py accuracy --seeds 1 2 3 4 5
    OMP_NUM_THREADS=1 python bench/joint.py straight --seeds 1 2 3
    OMP_NUM_THREADS=1 python bench/joint.py timing --duration 120
    OMP_NUM_THREADS=1 python bench/joint.py accuracy --seeds 1 2 3 \
        --sim "radar.sigma_azimuth_deg=0.4;radar.corner_fraction=0.1"

``--sim`` changes the simulator's settings (``section.field=value`` of
:class:`fgloc.sim.config.SimConfig`, numbers or comma-separated tuples of numbers, ``;``
between them): the robustness runs of docs/benchmarks.md (the methods' settings are not
tuned to the simulator's). "accuracy" and "straight" use the sensor.toml yaw guess; "timing"
reports the joint stage's split into Python callbacks and the rest. The data-efficiency
sweep (error against the number of trajectories, every method) is bench/accuracy.py's
``--efficiency-*`` part.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from fgloc.coarse import target_and_coarse
from fgloc.config import Config, from_dict, load_config, to_dict, tomllib  # tomllib / tomli
from fgloc.evaluate import pose_error_vector
from fgloc.fine import register_tracks
from fgloc.progress import Timer
from fgloc.registration.joint import joint_from_tracks
from fgloc.result import LocalizationResult
from fgloc.sim import simulate
from fgloc.sim.config import SimConfig
from fgloc.tracking import track_scenario


def score(res: LocalizationResult, truth: np.ndarray, seconds: float) -> dict:
    e = pose_error_vector(res.T_local, truth)
    row = {"d2d": float(np.hypot(e[0], e[1])), "dyaw_deg": float(np.rad2deg(abs(e[2]))),
           "time_s": seconds, "converged": bool(res.converged), "nees": None}
    if res.covariance is not None:
        cov = np.asarray(res.covariance)
        row["nees"] = float(e @ np.linalg.solve(cov, e))
        row["sd_x"], row["sd_y"] = float(np.sqrt(cov[0, 0])), float(np.sqrt(cov[1, 1]))
        row["sd_yaw_deg"] = float(np.rad2deg(np.sqrt(cov[2, 2])))
        deg = res.diagnostics["joint"]["degeneracy"]
        row["weak"] = bool(deg["weakly_observed"])
        row["weak_std_m"] = max([d["std_m"] for d in deg["weak_directions"]], default=0.0)
        row["joint_timing"] = res.diagnostics["joint"]["timing_s"]
    return row


def sim_config(spec: str | None) -> SimConfig:
    """The default SimConfig with the ``section.field=value;...`` changes of ``spec`` (values:
    a TOML value, comma-separated ones for a tuple field), checked like a config file
    (:func:`fgloc.config.from_dict`: an unknown field or a wrong type is an InputError naming
    it); ValueError names an item that is not ``section.field=value`` or not a TOML value."""
    data = to_dict(SimConfig())
    for item in filter(None, (spec or "").split(";")):
        key, _, value = item.partition("=")
        section, _, name = key.strip().partition(".")
        table = data.get(section)
        if not isinstance(table, dict) or not name:
            raise ValueError(f"--sim {item!r}: expected section.field=value of a simulator "
                             f"section ({', '.join(data)})")
        text = f"[{value}]" if isinstance(table.get(name), list) else value
        try:
            table[name] = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError as exc:
            raise ValueError(f"--sim {item!r}: {value.strip()!r} is not a value") from exc
    return from_dict(SimConfig, data, None)


def prepared(case: str, seed: int, duration: float, cfg: Config, sim: SimConfig | None = None):
    scn = simulate(case, seed, duration=duration, config=sim)
    timer = Timer()
    target, coarse = target_and_coarse(scn, cfg, timer)
    tracks = track_scenario(scn, coarse.T_coarse, cfg.tracking)
    return scn, target, coarse, tracks


def both(scn, target, coarse, tracks, cfg: Config) -> tuple[dict, dict]:
    truth = scn.truth.sensor_pose
    t0 = time.perf_counter()
    fs = register_tracks(scn, cfg, target, coarse, tracks, Timer(), method="filter-sicp")
    t1 = time.perf_counter()
    jt = joint_from_tracks(scn, cfg, target, coarse, tracks, Timer(), start=fs)
    t2 = time.perf_counter()
    return score(fs, truth, t1 - t0), score(jt, truth, t2 - t1)


def accuracy(args, cfg: Config) -> list[dict]:
    rows = []
    print(f"{'case':<13}{'seed':>4}{'tracks':>7} | {'f-sicp 2D':>9}{'yaw':>7} | {'joint 2D':>9}"
          f"{'yaw':>7}{'sd x':>7}{'sd y':>7}{'sd yaw':>7}{'NEES':>7}{'weak':>5}{'t s':>6}")
    for case in args.cases:
        for seed in args.seeds:
            scn, target, coarse, tracks = prepared(case, seed, args.duration, cfg, args.sim)
            f, j = both(scn, target, coarse, tracks, cfg)
            rows.append({"case": case, "seed": seed, "tracks": len(tracks), "filter_sicp": f,
                         "joint": j})
            print(f"{case:<13}{seed:>4}{len(tracks):>7} | {f['d2d']:9.3f}{f['dyaw_deg']:7.3f} | "
                  f"{j['d2d']:9.3f}{j['dyaw_deg']:7.3f}{j.get('sd_x', np.nan):7.3f}"
                  f"{j.get('sd_y', np.nan):7.3f}{j.get('sd_yaw_deg', np.nan):7.3f}"
                  f"{j['nees'] if j['nees'] is not None else np.nan:7.2f}"
                  f"{'yes' if j.get('weak') else 'no':>5}{j['time_s']:6.1f}", flush=True)
    for key in ("filter_sicp", "joint"):
        d2d = np.mean([r[key]["d2d"] for r in rows])
        yaw = np.mean([r[key]["dyaw_deg"] for r in rows])
        print(f"mean {key:<12} 2D {d2d:.3f} m  |dyaw| {yaw:.3f} deg")
    nees = [r["joint"]["nees"] for r in rows if r["joint"]["nees"] is not None]
    print(f"joint NEES mean {np.mean(nees):.2f} (median {np.median(nees):.2f}, n={len(nees)})")
    return rows


def straight(args, cfg: Config) -> list[dict]:
    rows = []
    for seed in args.seeds:
        scn, target, coarse, tracks = prepared("straight", seed, args.duration, cfg, args.sim)
        f, j = both(scn, target, coarse, tracks, cfg)
        rows.append({"case": "straight", "seed": seed, "filter_sicp": f, "joint": j})
        print(f"straight {seed}: f-sicp 2D {f['d2d']:.3f} | joint 2D {j['d2d']:.3f} yaw "
              f"{j['dyaw_deg']:.3f} weak {j.get('weak')} weakest std {j.get('weak_std_m', 0):.2f} m"
              f" sd x/y {j.get('sd_x', np.nan):.2f}/{j.get('sd_y', np.nan):.2f} NEES "
              f"{j['nees'] if j['nees'] is not None else np.nan:.2f}", flush=True)
    return rows


def timing(args, cfg: Config) -> list[dict]:
    scn, target, coarse, tracks = prepared("intersection", args.seeds[0], args.duration, cfg,
                                           args.sim)
    f, j = both(scn, target, coarse, tracks, cfg)
    print(f"intersection seed {args.seeds[0]}, {args.duration:.0f} s, {len(tracks)} tracks: "
          f"joint stage {j['time_s']:.1f} s (incl. LaneLines and the result), 2D {j['d2d']:.3f} m")
    print(json.dumps(j.get("joint_timing"), indent=1))
    return [{"tracks": len(tracks), "filter_sicp": f, "joint": j}]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("part", choices=["accuracy", "straight", "timing"])
    ap.add_argument("--cases", nargs="+", default=["intersection", "tjunction"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3, 4, 5])
    ap.add_argument("--duration", type=float, default=None,
                    help="scenario length in s (default 60; timing: 120)")
    ap.add_argument("--json", default=None, help="also write all rows to this JSON file")
    ap.add_argument("--config", default=None, help="fgloc config TOML (default: all defaults)")
    ap.add_argument("--sim", default=None,
                    help='simulator changes, e.g. "radar.sigma_azimuth_deg=0.4;'
                         'traffic.class_mix=0.4,0.5,0.1"')
    args = ap.parse_args()
    args.sim = sim_config(args.sim)          # checked before anything runs
    if args.duration is None:
        args.duration = 120.0 if args.part == "timing" else 60.0
    cfg = load_config(args.config)
    rows = {"accuracy": accuracy, "straight": straight, "timing": timing}[args.part](args, cfg)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
