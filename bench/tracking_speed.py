"""Tracking speed and accuracy on a simulated scenario with the oracle sensor pose.

Prints recording seconds / processing seconds (the real-time factor; the target is >= 5 on one
core at ~10,000 detections/s) and the tracking metrics of fgloc.evaluate_tracking for each
measurement model::

    python -m bench.tracking_speed --case intersection --seed 5 --duration 150 --vehicles 60
"""

from __future__ import annotations

import argparse
import dataclasses
import time

from fgloc.evaluate_tracking import evaluate_tracks
from fgloc.sim import CASES, simulate
from fgloc.tracking import TrackingConfig, track_scenario


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default="intersection", choices=CASES)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--duration", type=float, default=150.0)
    ap.add_argument("--vehicles", type=int, default=60)
    ap.add_argument("--models", nargs="+", default=["sensor-aware", "plain"])
    args = ap.parse_args()

    scn = simulate(args.case, args.seed, duration=args.duration, vehicles=args.vehicles)
    assert scn.truth is not None
    pose = scn.truth.sensor_pose
    rec = scn.radar.duration
    print(f"{args.case} seed {args.seed}: {rec:.0f} s, {len(scn.radar)} detections "
          f"({len(scn.radar) / rec:.0f}/s), {len(scn.truth.tracks)} vehicles")
    for model in args.models:
        cfg = dataclasses.replace(TrackingConfig(), measurement_model=model)
        t0 = time.perf_counter()
        tracks = track_scenario(scn, pose, cfg)
        sec = time.perf_counter() - t0
        m = evaluate_tracks(tracks, scn.truth, sensor_pose=pose, hfov_deg=scn.sensor.hfov_deg,
                            max_range=scn.sensor.max_range)
        print(f"\n[{model}] processing {sec:.1f} s, real-time factor {rec / sec:.1f}")
        print(m.table())


if __name__ == "__main__":
    main()
