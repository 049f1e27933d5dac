"""Coarse localization accuracy on simulated scenarios.

For every case and seed the scenario is simulated once and localized four times: with and
without the yaw guess, from the simulator's approximate position and from one moved exactly
``--offset`` m away from the true position (direction drawn from the seed). Errors compare
T_coarse with the true sensor pose (both S -> L): dx, dy, 2D (m), wrapped dyaw (deg), dz (m).

    python bench/coarse_accuracy.py --cases intersection tjunction curve --seeds 1 2 3 4 5
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

from fgloc.coarse import coarse_localize
from fgloc.config import CoarseConfig, MapConfig
from fgloc.geo import pose_from_se3, wrap_angle
from fgloc.map import build_target_cloud
from fgloc.scenario import Scenario
from fgloc.sim import simulate


def variant(scn: Scenario, guess: bool, offset: float | None, seed: int) -> Scenario:
    """The scenario with the yaw guess dropped and/or the approximate position moved."""
    sensor = scn.sensor
    if offset is not None:
        ang = np.random.default_rng(seed).uniform(0.0, 2.0 * np.pi)
        true_xy = scn.frame.to_world(scn.truth.sensor_pose[:2, 3])
        pos = true_xy + offset * np.array([np.cos(ang), np.sin(ang)])
        sensor = dataclasses.replace(sensor, approx_position=(float(pos[0]), float(pos[1])))
    if not guess:
        sensor = dataclasses.replace(sensor, yaw_guess_deg=None)
    return dataclasses.replace(scn, sensor=sensor)


def errors(T: np.ndarray, truth: np.ndarray) -> tuple[float, float, float, float, float]:
    """dx, dy, 2D, dz (m) and wrapped dyaw (deg) of an estimate against the truth (S -> L)."""
    e, g = pose_from_se3(T), pose_from_se3(truth)
    dx, dy, dz = e[0] - g[0], e[1] - g[1], e[2] - g[2]
    return dx, dy, float(np.hypot(dx, dy)), float(np.rad2deg(wrap_angle(e[3] - g[3]))), dz


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--cases", nargs="+", default=["intersection", "tjunction", "curve"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3, 4, 5])
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--offset", type=float, default=10.0)
    ap.add_argument("--max-2d", type=float, default=1.5)
    ap.add_argument("--max-yaw", type=float, default=1.5)
    args = ap.parse_args()

    print(f"{'case':<13}{'seed':>4} {'guess':<5} {'approx':<7}{'dx':>7}{'dy':>7}{'2D':>7}"
          f"{'dyaw':>7}{'dz':>7}{'fit':>6}{'time':>7}  ok")
    fails, times, stages = 0, [], {}
    for case in args.cases:
        for seed in args.seeds:
            base = simulate(case, seed, duration=args.duration)
            for offset in (None, args.offset):
                for guess in (True, False):
                    scn = variant(base, guess, offset, seed)
                    t0 = time.perf_counter()
                    target = build_target_cloud(scn, MapConfig())
                    t_map = time.perf_counter() - t0
                    res = coarse_localize(scn, target, CoarseConfig())
                    dt = time.perf_counter() - t0
                    for name, sec in {"target cloud": t_map, **res.timings}.items():
                        stages.setdefault(name, []).append(sec)
                    times.append(dt)
                    dx, dy, d2, dyaw, dz = errors(res.T_coarse, scn.truth.sensor_pose)
                    ok = d2 < args.max_2d and abs(dyaw) < args.max_yaw
                    fails += not ok
                    where = "sim" if offset is None else f"{offset:.0f}m"
                    print(f"{case:<13}{seed:>4} {'yes' if guess else 'no':<5} {where:<7}"
                          f"{dx:7.2f}{dy:7.2f}{d2:7.2f}{dyaw:7.2f}{dz:7.2f}{res.fitness:6.2f}"
                          f"{dt:7.2f}  {'ok' if ok else 'FAIL'}", flush=True)
    print(f"{len(times)} runs, {fails} outside {args.max_2d} m / {args.max_yaw} deg; "
          f"time per run (target cloud + coarse) median {np.median(times):.2f} s, "
          f"max {np.max(times):.2f} s")
    print("stage seconds (median / max): " + ", ".join(
        f"{k} {np.median(v):.2f}/{np.max(v):.2f}" for k, v in stages.items()))
    return 1 if fails else 0


if __name__ == "__main__":
    raise SystemExit(main())
