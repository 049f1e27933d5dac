"""Tracking speed and accuracy on simulated scenarios with the oracle sensor pose.

For each seed and measurement model, prints the real-time factor (recording seconds / CPU
seconds of the tracker on one core; the target is >= 5 at ~10,000 detections/s) and the
tracking metrics of fgloc.evaluate_tracking (pooled centre RMS and the paper's per-track mean
"trkRMS", yaw error, IoU, tracked share of the vehicles visible >= 2 s, false tracks,
fragments)::

    OMP_NUM_THREADS=1 python -m bench.tracking_speed --case intersection --seeds 1 2 3 \\
        --duration 60 --vehicles 50 [--variant noisy|sparse|10hz|dense|10k]

Variants change the simulator (fgloc.sim.SimConfig), never the tracker settings ("10k":
10 points per degree, about 10,000 detections/s on the intersection instead of 12-15k).
Ends with the mean over the seeds per model and the load average (timings on a shared
machine are inflated by other jobs).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time

import numpy as np

from bench.results import Produced
from fgloc.evaluation.tracking import evaluate_tracks
from fgloc.sim import CASES, SimConfig, simulate
from fgloc.tracking import TrackingConfig, track_scenario


def variant_config(name: str) -> SimConfig:
    """SimConfig of a named variant ("default", "noisy", "sparse", "10hz", "dense",
    "10k")."""
    cfg = SimConfig()
    r = cfg.radar
    if name == "noisy":
        cfg.radar = dataclasses.replace(r, sigma_range=0.3, sigma_azimuth_deg=0.4,
                                        sigma_elevation_deg=1.0, sigma_doppler=0.15)
    elif name == "sparse":
        cfg.radar = dataclasses.replace(r, points_per_degree=6.0)
    elif name == "10hz":
        cfg.radar = dataclasses.replace(r, rate_hz=10.0)
    elif name == "10k":
        cfg.radar = dataclasses.replace(r, points_per_degree=10.0)
    elif name == "dense":
        cfg.traffic = dataclasses.replace(cfg.traffic, headway=0.7)
    elif name != "default":
        raise ValueError(f"unknown variant {name!r}")
    return cfg


def produce(seeds: list[int], duration: float, vehicles: int, case: str = "intersection",
            variant: str = "default", models: tuple[str, ...] = ("sensor-aware", "plain"),
            ) -> Produced:
    """Per seed and measurement model the tracker's CPU time, real-time factor and metrics
    (one row each); the body ends with the mean over the seeds per model."""
    rows: list[dict] = []
    body: list[str] = []
    for seed in seeds:
        scn = simulate(case, seed, duration=duration, vehicles=vehicles,
                       config=variant_config(variant))
        assert scn.truth is not None
        pose = scn.truth.sensor_pose
        rec = scn.radar.duration
        body += ["", f"{case} seed {seed} variant {variant}: {rec:.0f} s, {len(scn.radar)} "
                 f"detections ({len(scn.radar) / rec:.0f}/s), {len(scn.truth.tracks)} "
                 "vehicles", "", "```"]
        for model in models:
            cfg = dataclasses.replace(TrackingConfig(), measurement_model=model)
            c0, w0 = time.process_time(), time.perf_counter()
            tracks = track_scenario(scn, pose, cfg)
            cpu, wall = time.process_time() - c0, time.perf_counter() - w0
            m = evaluate_tracks(tracks, scn.truth, sensor_pose=pose,
                                hfov_deg=scn.sensor.hfov_deg, max_range=scn.sensor.max_range)
            body += [f"[{model}] CPU {cpu:.1f} s (wall {wall:.1f} s), real-time factor "
                     f"{rec / cpu:.1f} (CPU) / {rec / wall:.1f} (wall), "
                     f"{len(scn.radar) / rec:.0f} det/s", m.table()]
            rows.append({"seed": seed, "model": model, "cpu_s": cpu, "wall_s": wall,
                         "rtf": rec / cpu, "tracked_share": m.tracked_share,
                         "false_tracks": m.false_tracks, "fragments": m.fragments,
                         "centre_rms": m.centre_rms, "trk_rms": m.centre_rms_track_mean,
                         "yaw_error_deg": m.yaw_error_deg, "iou": m.iou})
        body.append("```")
    body += ["", f"Mean over seeds {seeds}:", "", "```",
             f"{'model':>13} {'share':>6} {'false':>5} {'frag':>4} {'RMS m':>6} {'trkRMS':>6} "
             f"{'yaw':>5} {'IoU':>5} {'RT':>5}"]
    keys = ("tracked_share", "false_tracks", "fragments", "centre_rms", "trk_rms",
            "yaw_error_deg", "iou", "rtf")
    for model in models:
        a = np.mean([[r[k] for k in keys] for r in rows if r["model"] == model], axis=0)
        body.append(f"{model:>13} {a[0]:6.3f} {a[1]:5.1f} {a[2]:4.1f} {a[3]:6.3f} {a[4]:6.3f} "
                    f"{a[5]:5.2f} {a[6]:5.3f} {a[7]:5.1f}")
    body.append("```")
    return Produced(rows, body[1:], f"{case}, seeds {seeds}, {duration:g} s, {vehicles} "
                    f"vehicles, variant {variant}, true pose")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default="intersection", choices=CASES)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--vehicles", type=int, default=50)
    ap.add_argument("--variant", default="default",
                    choices=["default", "noisy", "sparse", "10hz", "dense", "10k"])
    ap.add_argument("--models", nargs="+", default=["sensor-aware", "plain"])
    args = ap.parse_args()
    p = produce(args.seeds, args.duration, args.vehicles, args.case, args.variant,
                tuple(args.models))
    print("\n".join(p.body))
    print(f"(load average {os.getloadavg()[0]:.1f})")


if __name__ == "__main__":
    main()
