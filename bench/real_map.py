"""Every method on junctions of a real Lanelet2 map (issue 22).

For each of the map's largest junctions (``--junctions``, ranked by the number of movements of
the routing graph per driving direction), each kind of traffic on two-way lanelets
(``--two-way-traffic``: ``[real_map] two_way_traffic`` of the simulator, "keep-right" and
"centre", keep-right on the lane lines as mapped, "keep-right-mapped", lanelet2's centre
lines as mapped, "centre-lanelet2", and keep-right with pedestrians and cyclists on the map's
own ways and trams on its rails, "keep-right-users"; :data:`TRAFFIC`)
and each seed, ``fgloc.sim.real_map.simulate_on_map`` builds a scenario at that
junction (``--duration`` s of traffic) and ``fgloc.localize_many`` runs every method on it; once
per label source of the lane samples (:data:`LABELS`: their lane's path, the default, or their
lanelet's label from the routing graph or from Menger curvature); the 2D, yaw and height errors
against the simulated truth are printed per run, then the mean and the worst seed per
traffic, labels, junction and method. docs/benchmarks.md's table comes from
``python -m bench.report --only real_map``.

    OMP_NUM_THREADS=1 python -m bench.real_map --seeds 1 2 3
    OMP_NUM_THREADS=1 python -m bench.real_map --seeds 1 --two-way-traffic centre --labels path
    OMP_NUM_THREADS=1 python -m bench.real_map --config variant.toml   # not the defaults
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from fgloc.config import load_config  # noqa: E402
from fgloc.evaluation.pose import pose_error  # noqa: E402
from fgloc.pipeline import localize_many  # noqa: E402
from fgloc.scenario import Scenario  # noqa: E402
from fgloc.sim.config import SimConfig  # noqa: E402
from fgloc.sim.real_map import map_junctions, simulate_on_map  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_MAP = ROOT.parent / "shared" / "data" / "maps" / "lanelet2_mapping_example.osm"
METHODS = ["icp", "filter-sicp", "smoother-sicp", "joint"]
#: Kinds of traffic, one row group each: name -> the simulator's ``[real_map]`` settings.
#: "keep-right" / "centre": where vehicles drive on two-way lanelets (``two_way_traffic``), on
#: paths smoothed through the lanelet joins (the default 5 m moving average);
#: "keep-right-mapped": keep-right on the lane lines as mapped (``path_smoothing = "none"``, a
#: kink where lanelets meet becomes a 1 m arc), as a generator that drives the map's centre
#: lines makes them; "centre-lanelet2": the centre line both ways, lanelet2's own
#: (``centre_line = "lanelet2"``, up to 2 m from fgloc's resampled one on hand-mapped turns),
#: as mapped, as a generator that routes with lanelet2 and drives its ``centerline`` makes them;
#: "keep-right-users": keep-right with pedestrians (10 per minute) and cyclists (6 per minute)
#: on the map's crosswalks, walkways and cycle ways and trams (2 per minute) on its rails
#: (:mod:`fgloc.sim.map_paths`; of the six largest junctions only the third has rails in view).
TRAFFIC: dict[str, dict[str, str | float]] = {
    "keep-right": {"two_way_traffic": "keep-right"},
    "centre": {"two_way_traffic": "centre"},
    "keep-right-mapped": {"two_way_traffic": "keep-right", "path_smoothing": "none"},
    "centre-lanelet2": {"two_way_traffic": "centre", "centre_line": "lanelet2",
                        "path_smoothing": "none"},
    "keep-right-users": {"two_way_traffic": "keep-right", "pedestrians_per_minute": 10.0,
                         "path_cyclists_per_minute": 6.0, "trams_per_minute": 2.0},
}


#: Label sources of the lane samples compared: name -> ``[map]`` (lane_labels, labels).
LABELS: dict[str, tuple[str, str]] = {
    "path": ("path", "routing"),
    "routing": ("lanelet", "routing"),
    "curvature": ("lanelet", "curvature"),
}


#: (traffic, labels, junction index, method) -> (2D m, yaw deg, ambiguous 0/1, dz m) of every
#: seed (dz signed: the result's height minus the truth's)
Errors = dict[tuple[str, str, int, str], list[tuple[float, float, float, float]]]


def junction_sites(map_path: Path, n: int) -> list[tuple[float, float]]:
    """(lat, lon) of the map's ``n`` largest junctions (``map_junctions``' order)."""
    junctions, _ = map_junctions(map_path)
    return [(float(j.centre[0]), float(j.centre[1])) for j in junctions[:n]]


def scenario(map_path: Path, kind: str, site: tuple[float, float], seed: int,
             duration: float) -> Scenario:
    """The simulated scenario with ground truth at the junction ``site`` (lat, lon):
    ``duration`` s of traffic of the kind ``kind`` (:data:`TRAFFIC`), ``seed``."""
    sim_cfg = SimConfig()
    for name, value in TRAFFIC[kind].items():
        setattr(sim_cfg.real_map, name, value)
    return simulate_on_map(map_path, seed, site=site, duration=duration, config=sim_cfg).scenario


def run_one(map_path: Path, kind: str, k: int, site: tuple[float, float], seed: int,
            duration: float, labels: list[str], config: Path | None = None
            ) -> list[dict[str, object]]:
    """One scenario (two-way traffic ``kind``, junction index ``k`` at ``site``, ``seed``),
    localized by every method once per label source (:data:`LABELS`) with the fgloc config TOML
    ``config`` (None: the defaults): one row per (labels, method) with the 2D, yaw and
    height errors and the result's status."""
    scn = scenario(map_path, kind, site, seed, duration)
    rows: list[dict[str, object]] = []
    for mode in labels:
        t0 = time.perf_counter()
        cfg = load_config(config)
        cfg.map.lane_labels, cfg.map.labels = LABELS[mode]
        res = localize_many(scn, METHODS, cfg)
        line = [f"traffic {kind} junction {k + 1} seed {seed} labels {mode}:"]
        for m, r in res.items():
            e = pose_error(r.T_local, scn.truth.sensor_pose)
            rows.append({"traffic": kind, "labels": mode, "junction": k + 1, "method": m,
                         "seed": seed, "d2d": e.d2d, "dyaw_deg": e.dyaw_deg,
                         "dz": float(r.T_local[2, 3] - scn.truth.sensor_pose[2, 3]),
                         "status": r.status})
            line.append(f"{m} {e.d2d:.3f} m {e.dyaw_deg:.3f} deg dz {rows[-1]['dz']:+.3f} m"
                        + ("" if r.status == "resolved" else f" ({r.status})")
                        + ("" if r.converged else " (not converged)"))
        print(" ".join(line) + f"  [{time.perf_counter() - t0:.0f} s]", flush=True)
    return rows


def run(map_path: Path, n_junctions: int, seeds: list[int], duration: float,
        labels: list[str], traffic: list[str] | None = None,
        pool_map: Callable[..., Iterable[list[dict[str, object]]]] | None = None,
        config: Path | None = None) -> tuple[list[tuple[float, float]], list[dict[str, object]]]:
    """Junction sites (lat, lon) and the rows of :func:`run_one` (with ``config``) for every
    traffic kind, junction and seed (in that order). ``pool_map(fn, items)`` runs
    ``fn(*item)`` per item in order (e.g. in worker processes; default: here, one after the
    other)."""
    sites = junction_sites(map_path, n_junctions)
    items = [(map_path, kind, k, site, seed, duration, labels, config)
             for kind in traffic or list(TRAFFIC) for k, site in enumerate(sites) for seed in seeds]
    done = (pool_map or (lambda fn, its: (fn(*it) for it in its)))(run_one, items)
    return sites, [row for rows in done for row in rows]


def errors_of(rows: list[dict[str, object]]) -> Errors:
    """The rows grouped per (traffic, labels, junction index, method), seeds in order."""
    errors: Errors = {}
    for r in rows:
        errors.setdefault((r["traffic"], r["labels"], int(r["junction"]) - 1, r["method"]),
                          []).append((r["d2d"], r["dyaw_deg"], float(r["status"] != "resolved"),
                                      r["dz"]))
    return errors


def table(sites: list[tuple[float, float]], seeds: list[int], labels: list[str],
          errors: Errors) -> str:
    """Markdown table: per two-way traffic kind and label source, every junction's and all runs'
    mean and worst per method (the height error: its signed mean and worst magnitude), and
    how many of the runs were ambiguous."""
    rows = ["| two-way traffic | junction (lat, lon) | labels | method | 2D mean (m) "
            "| 2D worst (m) | yaw mean (deg) | yaw worst (deg) | dz mean (m) | abs dz worst (m) "
            "| ambiguous |",
            "|---|---|---|---|---|---|---|---|---|---|---|"]

    def row(kind: str, name: str, mode: str, m: str, e: np.ndarray) -> str:
        return (f"| {kind} | {name} | {mode} | {m} | {e[:, 0].mean():.3f} | "
                f"{e[:, 0].max():.3f} | {e[:, 1].mean():.3f} | {e[:, 1].max():.3f} | "
                f"{e[:, 3].mean():+.3f} | {np.abs(e[:, 3]).max():.3f} | "
                f"{int(e[:, 2].sum())}/{len(e)} |")

    kinds = list(dict.fromkeys(kind for kind, *_ in errors))
    for kind in kinds:
        for mode in labels:
            for k, (lat, lon) in enumerate(sites):
                rows += [row(kind, f"{k + 1} ({lat:.5f}, {lon:.5f})", mode, m,
                             np.array(errors[(kind, mode, k, m)])) for m in METHODS]
            rows += [row(kind, f"all {len(sites)} x {len(seeds)} runs", mode, m,
                         np.vstack([errors[(kind, mode, k, m)] for k in range(len(sites))]))
                     for m in METHODS]
    return "\n".join(rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--map", type=Path, default=DEFAULT_MAP)
    ap.add_argument("--junctions", type=int, default=3)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--labels", choices=list(LABELS), nargs="+",
                    default=["path", "routing"], help="label sources of the lane samples "
                    "compared (LABELS)")
    ap.add_argument("--two-way-traffic", choices=list(TRAFFIC), nargs="+",
                    default=list(TRAFFIC),
                    help="the kinds of simulated traffic (TRAFFIC): where vehicles drive on "
                    "two-way lanelets ([real_map] two_way_traffic), whether on the lane lines "
                    "as mapped (keep-right-mapped) and on lanelet2's centre lines "
                    "(centre-lanelet2); one row group per kind")
    ap.add_argument("--config", type=Path, default=None,
                    help="fgloc config TOML (default: all defaults; [map] lane_labels and "
                    "labels are set per label source)")
    args = ap.parse_args()
    sites, rows = run(args.map, args.junctions, args.seeds, args.duration, args.labels,
                      args.two_way_traffic, config=args.config)
    print(table(sites, args.seeds, args.labels, errors_of(rows)))


if __name__ == "__main__":
    main()
