"""Tracking on junctions of a real Lanelet2 map with the true sensor pose (issues 20, 22).

For each of the map's largest junctions (``--junctions``), each kind of traffic on two-way
lanelets (``--two-way-traffic``) and each seed, the scenario of ``bench.real_map`` is tracked
by the filter with the true pose and smoothed by the batch smoother on its tracks; the
figures are those of the robustness matrix (``bench.robustness.tracking_figures``: tracks
per vehicle, tracks covering two vehicles, truck length, per-track centre RMS, yaw and IoU
of the filter and the batch). One line per run, then per traffic kind the mean over its
junctions and seeds and the worst run. It checks a tracker or smoother change against the
real map's geometry (two-way streets, junction boxes, curved approaches) without the
localization methods' cost.

    OMP_NUM_THREADS=1 python -m bench.real_map_tracking                 # 3 junctions, seeds 1-6
    OMP_NUM_THREADS=1 python -m bench.real_map_tracking --two-way-traffic centre --json out.json
    OMP_NUM_THREADS=1 python -m bench.real_map_tracking --config variant.toml
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.real_map import DEFAULT_MAP, TRAFFIC, junction_sites, scenario  # noqa: E402
from bench.report_section import provenance  # noqa: E402
from bench.robustness import RunResult, table, tracking_figures  # noqa: E402
from fgloc.config import load_config  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--map", type=Path, default=DEFAULT_MAP)
    ap.add_argument("--junctions", type=int, default=3)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5, 6])
    ap.add_argument("--duration", type=float, default=60.0, help="scenario length (s)")
    ap.add_argument("--two-way-traffic", choices=list(TRAFFIC), nargs="+",
                    default=list(TRAFFIC))
    ap.add_argument("--config", default=None, help="fgloc config TOML (default: all defaults)")
    ap.add_argument("--json", default=None, help="also write every run's figures here")
    args = ap.parse_args()
    cfg = load_config(args.config)
    sites = junction_sites(args.map, args.junctions)
    t0 = time.perf_counter()
    results: list[RunResult] = []
    for kind in args.two_way_traffic:
        for k, site in enumerate(sites):
            for seed in args.seeds:
                scn = scenario(args.map, kind, site, seed, args.duration)
                assert scn.truth is not None
                r = RunResult(kind, seed, f"junction {k + 1}", len(scn.truth.tracks),
                              tracking_figures(scn, cfg))
                results.append(r)
                print(r.line(), flush=True)
                if args.json:
                    Path(args.json).write_text(json.dumps([x.row() for x in results],
                                                          indent=1))
    elapsed = time.perf_counter() - t0
    print(f"\n{provenance()}, `{args.map.name}`, junctions {len(sites)}, seeds {args.seeds}, "
          f"{args.duration:g} s, {elapsed:.0f} s in total. Cells: mean over junctions and "
          "seeds / worst run (the setting column is the two-way traffic kind).\n")
    print("\n".join(table(results, args.two_way_traffic)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
