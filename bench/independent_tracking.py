"""Tracking on scenarios of the independent generator (bench/independent_gen.py), true pose.

The robustness matrix (bench/robustness.py) measures the tracker on fgloc's own simulator;
this benchmark measures it on scenarios that simulator did not make: the scenarios of
``bench.independent`` (the same junctions, seeds and settings give the same scenarios), each
tracked by the filter with the true sensor pose and smoothed by the batch smoother on its
tracks. Per run the figures of :func:`bench.robustness.tracking_figures`: tracks per vehicle,
false tracks, fragments (a vehicle's later tracks: a track break, e.g. a vehicle that stood,
its returns static), missed vehicles, tracks covering two vehicles, the truck length error
and centre offset towards the sensor, per-track centre RMS, yaw error and IoU of the filter
and the batch smoother; a vehicle counts where the sensor sees it. Per setting (held-out
junctions on rows of their own) the mean over the runs and the worst run:
:func:`bench.robustness.table`.

    OMP_NUM_THREADS=1 python -m bench.independent_tracking                 # the report's set
    OMP_NUM_THREADS=1 python -m bench.independent_tracking --junctions 1 2 --seeds 1 \\
        --settings static occluded --config variant.toml

docs/benchmarks.md's table comes from ``python -m bench.report --only independent_tracking``.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable
from pathlib import Path

from bench import robustness
from bench.independent import generated, group_label, groups_of, ordered_labels, parser, runs_of
from bench.real_map import DEFAULT_MAP
from bench.robustness import RunResult, tracking_figures
from fgloc.config import load_config


def run_one(junction: int, seed: int, setting: str, duration: float,
            config: Path | None = None, map_path: Path = DEFAULT_MAP) -> RunResult:
    """The tracking figures of the generator's scenario at ``junction``, ``seed``,
    ``setting`` (``duration`` s; fgloc config TOML ``config``, None: the defaults), labelled
    by :func:`bench.independent.group_label`; its case names the junction."""
    with generated(junction, seed, setting, duration, map_path) as scn:
        assert scn.truth is not None
        out = RunResult(group_label(setting, junction), seed, f"junction {junction}",
                        len(scn.truth.tracks), tracking_figures(scn, load_config(config)))
    print(f"independent tracking {out.line()}", flush=True)
    return out


def run(groups: list[dict[str, list]], duration: float, config: Path | None = None,
        pool_map: Callable[..., Iterable[RunResult]] | None = None,
        map_path: Path = DEFAULT_MAP) -> list[RunResult]:
    """:func:`run_one` for every run of ``groups`` (:func:`bench.independent.runs_of`);
    ``pool_map(fn, items)`` runs ``fn(*item)`` per item in order (default: here)."""
    items = [(j, s, setting, duration, config, map_path) for j, s, setting in runs_of(groups)]
    return list((pool_map or (lambda fn, its: (fn(*it) for it in its)))(run_one, items))


def table(results: list[RunResult]) -> list[str]:
    """Markdown: per row label (setting, held-out junctions apart) ``mean / worst run`` of
    every tracking figure, the track counts beside tracks per vehicle
    (:func:`bench.robustness.table`)."""
    cols = robustness.COLUMNS[:1] + robustness.COUNT_COLUMNS + robustness.COLUMNS[1:]
    return robustness.table(results, ordered_labels(r.setting for r in results), cols)


def main() -> int:
    args = parser(__doc__.split("\n\n")[0]).parse_args()
    groups = groups_of(args, "independent_tracking")
    results = run(groups, args.duration, args.config, map_path=args.map)
    print("\n".join(table(results)))
    if args.json:
        args.json.write_text(json.dumps([r.row() for r in results], indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
