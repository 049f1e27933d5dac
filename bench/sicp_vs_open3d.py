"""Speed and accuracy of fgloc's SE(2) SICP / plain ICP against Open3D's point-to-point ICP.

Clouds (both in the local frame L, 2D):

* target: the labelled road points of the simulated scenario's TargetCloud;
* source: the dynamic radar detections (|doppler| >= 0.5 m/s), voxel-downsampled and
  DBSCAN-filtered as in the coarse stage (``fgloc.coarse.dynamic_points``, default settings;
  without DBSCAN the isolated false alarms would outnumber the voxels on vehicles), placed with
  the TRUE sensor pose, projected to 2D, voxel-downsampled again (``--voxel``), each labelled
  with the label of its nearest target point (an oracle label: this benchmarks registration
  alone, not the tracker's labelling), then moved by the inverse of a known SE(2) offset D.
  Every method starts at the identity and should return D.

Methods: fgloc SICP (hard, soft), fgloc plain ICP (mode "none"; shrinking range 50 m -> 1.5 m,
and fixed ranges), Open3D ``registration_icp`` point-to-point on the same points with z = 0
(one fixed range: 50 m and a small one). All stop after 100 iterations or an RMSE change below
1e-4 m (Open3D: and a fitness change below 1e-6). Times are medians over ``--repeats`` runs and
include building the KD-trees (fgloc: SemanticTargets; Open3D builds its tree inside the call).
Errors: the 2D position error (m) the estimate gives for the sensor and the yaw error (deg),
both against D. Open3D reports no iteration count; it is found afterwards as the smallest
``max_iteration`` that reproduces the converged transform.

    python -m bench.sicp_vs_open3d --case intersection --seed 1
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import time
from collections.abc import Callable

import numpy as np
from scipy.spatial import cKDTree

from bench.results import Produced
from fgloc._open3d import open3d
from fgloc.coarse import dynamic_points
from fgloc.config import CoarseConfig, MapConfig
from fgloc.geo import se2, se2_inv, se2_params, transform_points
from fgloc.map import build_target_cloud, voxel_centroids
from fgloc.registration.config import SicpConfig
from fgloc.registration.sicp import SemanticTargets, sicp
from fgloc.sim import simulate


@dataclasses.dataclass
class Clouds:
    """Benchmark input: target (M, 2) + labels, perturbed source (N, 2) + labels, offset D,
    true sensor position (2,) in L."""

    target_xy: np.ndarray
    target_label: np.ndarray
    source_xy: np.ndarray
    source_label: np.ndarray
    D: np.ndarray
    sensor_xy: np.ndarray


def make_clouds(case: str, seed: int, duration: float, voxel: float, offset: float,
                direction_deg: float, yaw_deg: float) -> Clouds:
    scn = simulate(case, seed, duration)
    tc = build_target_cloud(scn, MapConfig())
    dyn = dynamic_points(scn.radar, CoarseConfig()).xyz
    flat = transform_points(scn.truth.sensor_pose, dyn) * np.array([1.0, 1.0, 0.0])
    xy = voxel_centroids(flat, np.zeros(len(flat), dtype=np.int64), voxel)[0][:, :2]
    txy = tc.xyz[:, :2]
    label = tc.label[cKDTree(txy).query(xy)[1]].astype(np.int64)
    a = np.deg2rad(direction_deg)
    D = se2(offset * np.cos(a), offset * np.sin(a), np.deg2rad(yaw_deg))
    return Clouds(txy, tc.label.astype(np.int64), transform_points(se2_inv(D), xy), label, D,
                  scn.truth.sensor_pose[:2, 3].copy())


def errors(T: np.ndarray, c: Clouds) -> tuple[float, float]:
    """2D sensor position error (m) and |yaw error| (deg) of an estimate T against D."""
    sensor_in_source = transform_points(se2_inv(c.D), c.sensor_xy[None])
    pos = transform_points(T, sensor_in_source)[0]
    yaw = se2_params(se2_inv(c.D) @ T)[2]
    return float(np.linalg.norm(pos - c.sensor_xy)), abs(float(np.rad2deg(yaw)))


def run_fgloc(c: Clouds, cfg: SicpConfig) -> tuple[np.ndarray, int]:
    targets = SemanticTargets.build(c.target_xy, c.target_label)
    res = sicp(c.source_xy, c.source_label, targets, None, np.eye(3), cfg)
    return res.T, res.iterations


def open3d_icp(c: Clouds, max_dist: float, max_iteration: int) -> np.ndarray:
    o3d = open3d()
    reg = o3d.pipelines.registration

    def cloud(xy: np.ndarray):
        return o3d.geometry.PointCloud(
            o3d.utility.Vector3dVector(np.column_stack([xy, np.zeros(len(xy))])))

    res = reg.registration_icp(
        cloud(c.source_xy), cloud(c.target_xy), max_dist, np.eye(4),
        reg.TransformationEstimationPointToPoint(),
        reg.ICPConvergenceCriteria(relative_fitness=1e-6, relative_rmse=1e-4,
                                   max_iteration=max_iteration))
    T4 = np.asarray(res.transformation)
    return se2(T4[0, 3], T4[1, 3], float(np.arctan2(T4[1, 0], T4[0, 0])))


def open3d_iterations(c: Clouds, max_dist: float, cap: int) -> int:
    """Smallest max_iteration that reproduces the converged transform (binary search)."""
    final = open3d_icp(c, max_dist, cap)
    lo, hi = 1, cap
    while lo < hi:
        mid = (lo + hi) // 2
        if np.array_equal(open3d_icp(c, max_dist, mid), final):
            hi = mid
        else:
            lo = mid + 1
    return lo


def timed(fn: Callable[[], object], repeats: int) -> tuple[float, object]:
    """Median wall time (s) over repeats and the last return value."""
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def compare(c: Clouds, repeats: int, small_range: float) -> list[dict]:
    """Every method of the module docstring on the clouds ``c``: one row each (name, time s,
    iterations, 2D error m, yaw error deg, ratio of the time to Open3D's at 50 m)."""
    base = SicpConfig()
    fixed = dataclasses.replace(base, range_decay=1.0)
    small = dataclasses.replace(fixed, max_correspondence=small_range,
                                min_correspondence=small_range)
    fg: dict[str, SicpConfig] = {
        "fgloc SICP hard, 50->1.5 m": base,
        "fgloc SICP soft, 50->1.5 m": dataclasses.replace(base, mode="soft"),
        "fgloc plain ICP, 50->1.5 m": dataclasses.replace(base, mode="none"),
        "fgloc plain ICP, 50 m fixed": dataclasses.replace(fixed, mode="none"),
        f"fgloc plain ICP, {small_range:g} m fixed": dataclasses.replace(small, mode="none"),
    }
    rows = []
    for name, cfg in fg.items():
        t, (T, it) = timed(lambda cfg=cfg: run_fgloc(c, cfg), repeats)
        rows.append({"method": name, "time_s": t, "iterations": it,
                     **dict(zip(("d2d", "dyaw_deg"), errors(T, c)))})
    for dist in (base.max_correspondence, small_range):
        t, T = timed(lambda dist=dist: open3d_icp(c, dist, base.max_iterations), repeats)
        rows.append({"method": f"Open3D p2p ICP, {dist:g} m", "time_s": t,
                     "iterations": open3d_iterations(c, dist, base.max_iterations),
                     **dict(zip(("d2d", "dyaw_deg"), errors(T, c)))})
    t_ref = next(r["time_s"] for r in rows
                 if r["method"] == f"Open3D p2p ICP, {base.max_correspondence:g} m")
    for r in rows:
        r["ratio"] = r["time_s"] / t_ref
    return rows


def table(rows: list[dict]) -> list[str]:
    out = ["| method | time (ms) | vs Open3D 50 m | iterations | ms / iteration | 2D error (m) "
           "| yaw error (deg) |", "|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        out.append(f"| {r['method']} | {1e3 * r['time_s']:.1f} | {r['ratio']:.2f} | "
                   f"{r['iterations']} | {1e3 * r['time_s'] / max(r['iterations'], 1):.2f} | "
                   f"{r['d2d']:.3f} | {r['dyaw_deg']:.3f} |")
    return out


def produce(repeats: int = 7, case: str = "intersection", seed: int = 1,
            duration: float = 60.0, voxel: float = 1.0, offset: float = 1.5,
            direction: float = 30.0, yaw: float = 1.5, small_range: float = 3.0) -> Produced:
    """The report's table; summary: SICP (hard) and Open3D at 50 m, time (ms) and errors."""
    c = make_clouds(case, seed, duration, voxel, offset, direction, yaw)
    rows = compare(c, repeats, small_range)
    sicp_row, o3d_row = rows[0], next(r for r in rows if r["method"].startswith("Open3D"))
    summary = {"sicp_ms": 1e3 * sicp_row["time_s"], "sicp_2d": sicp_row["d2d"],
               "sicp_yaw": sicp_row["dyaw_deg"], "open3d_ms": 1e3 * o3d_row["time_s"],
               "open3d_2d": o3d_row["d2d"], "open3d_yaw": o3d_row["dyaw_deg"],
               "offset": f"{offset:g} m / {yaw:g} deg"}
    counts = np.bincount(c.source_label, minlength=3)
    return Produced(rows, table(rows),
                    f"{case} seed {seed}, {duration:g} s: target {len(c.target_xy)} points, "
                    f"source {len(c.source_xy)} points (straight/left/right {counts.tolist()}), "
                    f"offset {offset:g} m at {direction:g} deg and {yaw:g} deg, median of "
                    f"{repeats}", summary)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--case", default="intersection")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--voxel", type=float, default=1.0, help="2D source voxel (m)")
    ap.add_argument("--offset", type=float, default=1.5, help="offset translation (m)")
    ap.add_argument("--direction", type=float, default=30.0, help="its direction (deg)")
    ap.add_argument("--yaw", type=float, default=1.5, help="offset yaw (deg)")
    ap.add_argument("--small-range", type=float, default=3.0, help="small fixed range (m)")
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    p = produce(args.repeats, args.case, args.seed, args.duration, args.voxel, args.offset,
                args.direction, args.yaw, args.small_range)
    print(f"{p.setting}; {os.cpu_count()} CPUs")
    print("\n".join(p.body))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
