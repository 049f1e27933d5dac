"""Fine-registration variants of filter-sicp on the same coarse poses and tracks.

For each case and seed the scenario is simulated, the coarse pose and the GP-EOT tracks are
computed once, and every variant (source kind, target kind, first correspondence range, label
mode, kernel, source voxel) registers the same tracks. The first row is the coarse pose alone
(`--method icp`); "paper" is the paper's literal design (raw detections to ALS road points,
50 m first range). Yaw guess as in sensor.toml.

    python bench/fine_variants.py --cases intersection tjunction --seeds 1 2 3 4 5
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from fgloc.coarse import coarse_localize
from fgloc.config import Config
from fgloc.evaluation.pose import pose_error
from fgloc.map import build_target_cloud
from fgloc.progress import Timer
from fgloc.registration.fine import register_tracks
from fgloc.sim import simulate
from fgloc.tracking import track_scenario

#: name -> ([fine] overrides, [sicp] overrides); start_range 0 means SicpConfig's 50 m
VARIANTS: dict[str, tuple[dict, dict]] = {
    "paper: detections>road-points 50m": (
        {"source": "detections", "target": "road-points", "start_range": 0.0},
        {},
    ),
    "detections>road-points 5m": ({"source": "detections", "target": "road-points"}, {}),
    "detections>road-points 5m cauchy": (
        {"source": "detections", "target": "road-points"},
        {"kernel": "cauchy"},
    ),
    "centres>road-points 5m cauchy": (
        {"source": "centres", "target": "road-points"},
        {"kernel": "cauchy"},
    ),
    "centres>lane-centres 5m": ({"source": "centres", "target": "lane-centres"}, {}),
    "detections>lane-centres 5m": ({"source": "detections", "target": "lane-centres"}, {}),
    "detections>visible-sides 50m": (
        {"source": "detections", "target": "visible-sides", "start_range": 0.0},
        {},
    ),
    "detections>visible-sides 5m (default)": ({}, {}),
    "default, soft labels": ({}, {"mode": "soft"}),
    "default, labels ignored": ({}, {"mode": "none"}),
    "default, cauchy": ({}, {"kernel": "cauchy"}),
    "default, 1 m source voxel": ({"voxel_size": 1.0}, {}),
    "default, constant offset": ({"visible_side": "constant"}, {}),
}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--cases", nargs="+", default=["intersection", "tjunction"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3, 4, 5])
    ap.add_argument("--duration", type=float, default=60.0)
    args = ap.parse_args()

    errs: dict[str, list[tuple[float, float]]] = {"coarse (icp)": []}
    errs.update({name: [] for name in VARIANTS})
    base = Config()
    for case in args.cases:
        for seed in args.seeds:
            scn = simulate(case, seed, duration=args.duration)
            target = build_target_cloud(scn, base.map)
            coarse = coarse_localize(scn, target, base.coarse)
            tracks = track_scenario(scn, coarse.T_coarse, base.tracking)
            e = pose_error(coarse.T_coarse, scn.truth.sensor_pose)
            errs["coarse (icp)"].append((e.d2d, e.dyaw_deg))
            for name, (fine, sicp) in VARIANTS.items():
                cfg = dataclasses.replace(
                    base,
                    fine=dataclasses.replace(base.fine, **fine),
                    sicp=dataclasses.replace(base.sicp, **sicp),
                )
                res = register_tracks(scn, cfg, target, coarse, tracks, Timer(), "filter-sicp")
                e = pose_error(res.T_local, scn.truth.sensor_pose)
                errs[name].append((e.d2d, e.dyaw_deg))
            print(f"{case} {seed} done", flush=True)
    ref = np.array(errs["coarse (icp)"])
    print(
        f"\n{'variant':<40}{'mean 2D':>9}{'max 2D':>8}{'mean yaw':>10}{'max yaw':>9}{'2D<icp':>8}"
    )
    for name, rows in errs.items():
        a = np.array(rows)
        better = int(np.sum(a[:, 0] < ref[:, 0]))
        print(
            f"{name:<40}{a[:, 0].mean():9.3f}{a[:, 0].max():8.3f}{a[:, 1].mean():10.3f}"
            f"{a[:, 1].max():9.3f}{better:>5}/{len(a)}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
