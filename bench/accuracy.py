"""Localization accuracy through the file route, the way a user runs fgloc.

For every case and seed: simulate, write the scenario directory, load it back, localize with
each method (with the sensor.toml yaw guess and without it), and score against the ground truth.
Prints one row per run (the paper's Table I columns plus dz and time) and a summary per method.

    python bench/accuracy.py --cases intersection tjunction --seeds 1 2 3 4 5 --methods icp
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from fgloc.config import Config, load_config
from fgloc.evaluate import pose_error
from fgloc.io import load_scenario, write_scenario
from fgloc.pipeline import METHODS, localize
from fgloc.sim import simulate


def run(
    case: str, seed: int, duration: float, methods: list[str], work: Path, cfg: Config
) -> list[dict]:
    d = work / f"{case}-{seed}"
    write_scenario(simulate(case, seed, duration=duration), d)
    rows = []
    for guess in (True, False):
        scn = load_scenario(d)
        if not guess:
            scn.sensor = dataclasses.replace(scn.sensor, yaw_guess_deg=None)
        for method in methods:
            t0 = time.perf_counter()
            res = localize(scn, method=method, config=cfg)
            dt = time.perf_counter() - t0
            err = pose_error(res.T_local, scn.truth.sensor_pose)
            rows.append(
                {
                    "case": case,
                    "seed": seed,
                    "guess": guess,
                    "method": method,
                    "converged": res.converged,
                    "time_s": dt,
                    **err.to_json(),
                    "timings_s": res.timings,
                }
            )
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--cases", nargs="+", default=["intersection", "tjunction"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3, 4, 5])
    ap.add_argument("--methods", nargs="+", default=["icp"], choices=sorted(METHODS))
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--json", default=None, help="also write all rows to this JSON file")
    ap.add_argument("--config", default=None, help="fgloc config TOML (default: all defaults)")
    args = ap.parse_args()
    cfg = load_config(args.config)

    print(
        f"{'case':<13}{'seed':>4} {'guess':<6}{'method':<14}{'|dx|':>7}{'|dy|':>7}{'2D':>7}"
        f"{'|dyaw|':>8}{'|dz|':>7}{'time s':>8}"
    )
    rows: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        for case in args.cases:
            for seed in args.seeds:
                for r in run(case, seed, args.duration, args.methods, Path(tmp), cfg):
                    rows.append(r)
                    print(
                        f"{case:<13}{seed:>4} {'yes' if r['guess'] else 'no':<6}"
                        f"{r['method']:<14}{r['dx']:7.3f}{r['dy']:7.3f}{r['d2d']:7.3f}"
                        f"{r['dyaw_deg']:8.3f}{r['dz']:7.3f}{r['time_s']:8.2f}"
                        f"{'' if r['converged'] else '  NOT CONVERGED'}",
                        flush=True,
                    )
    print("\nsummary (mean / max over runs):")
    for method in args.methods:
        sel = [r for r in rows if r["method"] == method]
        for key in ("dx", "dy", "d2d", "dyaw_deg", "dz", "time_s"):
            v = np.array([r[key] for r in sel])
            print(f"  {method:<14}{key:<9} mean {v.mean():7.3f}  max {v.max():7.3f}")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
