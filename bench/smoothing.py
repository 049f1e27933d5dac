"""Filter vs fixed-lag vs batch smoother on simulated scenarios, all three on the same data.

Per seed: simulate, run :func:`fgloc.smoothing.run.compare_trackers` (the filter, then both
smoothers on the filter's tracks and association; oracle pose) and print its table: tracking
metrics (pooled centre RMS, per-track mean "trkRMS", yaw error, IoU, label accuracy), CPU
seconds and the real-time factor (recording s / CPU s; the fixed-lag target is >= 1 at
~10,000 detections/s), the batch smoother's CPU seconds per track-minute, then the mean over
seeds. With ``--localize``, also filter-sicp and smoother-sicp on the same scenario
(coarse stage included) with their 2D and yaw errors::

    OMP_NUM_THREADS=1 python -m bench.smoothing --case intersection --seeds 1 2 3 4 5 \\
        --duration 60 --vehicles 50 [--localize] [--no-tracking] [--config C.toml]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from fgloc.config import load_config
from fgloc.evaluation.pose import pose_error
from fgloc.evaluation.trackers import compare_trackers
from fgloc.pipeline import localize
from fgloc.sim import CASES, simulate

METRICS = ("centre_rms", "centre_rms_track_mean", "yaw_error_deg", "iou", "label_accuracy")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default="intersection", choices=CASES)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--vehicles", type=int, default=50)
    ap.add_argument("--localize", action="store_true",
                    help="also localize with filter-sicp and smoother-sicp")
    ap.add_argument("--config", default=None, help="fgloc config TOML (default: all defaults)")
    ap.add_argument("--no-tracking", action="store_true",
                    help="skip the tracker comparison (with --localize: localization only)")
    args = ap.parse_args()
    cfg = load_config(args.config)
    rows: dict[str, list[list[float]]] = {}
    for seed in args.seeds:
        scn = simulate(args.case, seed, duration=args.duration, vehicles=args.vehicles)
        rec = scn.radar.duration
        print(f"\n== {args.case} seed {seed}: {rec:.0f} s, {len(scn.radar)} detections "
              f"({len(scn.radar) / rec:.0f}/s), {len(scn.truth.tracks)} vehicles; "
              f"load {os.getloadavg()[0]:.1f}")
        if not args.no_tracking:
            cmp = compare_trackers(scn, cfg, oracle_pose=True)
            print(cmp.table())
            for name, m, cpu in zip(cmp.names, cmp.metrics, cmp.cpu_seconds):
                rows.setdefault(name, []).append([getattr(m, k) for k in METRICS] + [cpu])
            print(f"batch: {cmp.cpu_seconds[2] / cmp.track_minutes:.1f} CPU s per "
                  f"track-minute ({cmp.track_minutes:.1f} track-minutes)")
        if args.localize:
            truth = scn.truth.sensor_pose
            for method in ("filter-sicp", "smoother-sicp"):
                w0 = time.perf_counter()
                res = localize(scn, method, cfg)
                err = pose_error(res.T_local, truth)
                print(f"[{method}] 2D {err.d2d:.3f} m, yaw {err.dyaw_deg:.3f} deg, "
                      f"{time.perf_counter() - w0:.0f} s wall")
                rows.setdefault(method, []).append([err.d2d, err.dyaw_deg])
    print(f"\n== mean over seeds {args.seeds}")
    if rows.get("filter"):
        print(f"{'tracker':>9} " + " ".join(f"{k:>22}" for k in (*METRICS, "cpu_s")))
    for name in ("filter", "fixed-lag", "batch") if rows.get("filter") else ():
        mean = np.nanmean(np.array(rows[name], dtype=float), axis=0)
        print(f"{name:>9} " + " ".join(f"{v:22.3f}" for v in mean))
    for method in ("filter-sicp", "smoother-sicp"):
        if method in rows:
            d2d, dyaw = np.mean(np.array(rows[method]), axis=0)
            print(f"{method}: mean 2D {d2d:.3f} m, mean |dyaw| {dyaw:.3f} deg")


if __name__ == "__main__":
    main()
