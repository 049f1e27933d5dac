"""The benchmark report: run the benchmark tables and write docs/benchmarks.md whole.

Each table (``TABLES``) is produced by a function of a bench script; its rows, rendered
markdown and provenance (commit, date, machine, command, duration) are stored as JSON under
``bench/results/<table>.json`` (``bench/results/quick/`` with ``--quick``, which never touches
the full results). After running the requested tables, the markdown is rendered from ALL
stored results of that set and written atomically: docs/benchmarks.md for the full set,
bench/results/quick/benchmarks.md for ``--quick`` (``--out`` overrides). Nothing in the
written file is edited by hand; the paragraph above each table lives in ``TABLES`` below.

    OMP_NUM_THREADS=1 python -m bench.report                     # every table, the full set
    OMP_NUM_THREADS=1 python -m bench.report --only sparse speed # rerun two, render all
    OMP_NUM_THREADS=1 python -m bench.report --quick             # smoke set, < 10 min
    python -m bench.report --render-only                         # render the stored results
    OMP_NUM_THREADS=1 python -m bench.report --only robustness --set robustness.seeds=[1,2,3]

``--set TABLE.PARAM=VALUE`` (VALUE as JSON) changes a table's parameter; a result whose
parameters differ from the table's full set is marked REDUCED in the report, with both.
``--jobs N`` runs the independent runs of the tables without time columns (robustness, the
runs of sparse, real_map, independent) in N processes; their figures are the same as with one
(deterministic per seed), only the wall time and the load in the provenance line differ.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from bench import results
from bench.results import Produced

DOCS = results.ROOT / "docs"


# ------------------------------------------------------------------- producers (wrappers)
def _ordered_map(fn: Callable, items: Iterable[tuple], jobs: int) -> Iterator:
    """``fn(*item)`` for every item, in order; in ``jobs`` worker processes when > 1."""
    if jobs <= 1:
        yield from (fn(*item) for item in items)
        return
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        yield from pool.map(fn, *zip(*items))


def _robustness_run(setting: str, seed: int, duration: float):
    from bench import robustness as rb
    from fgloc.config import Config

    return rb.run_one(setting, seed, duration, Config(), True)


def _sparse_runs(case: str, rate: float, seed: int, duration: float, tol: float):
    from bench import sparse as sp
    from fgloc.config import Config

    return sp.run_one(case, seed, rate, duration, Config(), tol)


def produce_robustness(settings: list[str], seeds: list[int], duration: float,
                       jobs: int = 1) -> Produced:
    """bench/robustness.py's matrix: per setting and seed :func:`bench.robustness.run_one`
    (in ``jobs`` processes)."""
    from bench import robustness as rb

    runs = []
    items = [(setting, seed, duration) for setting in settings for seed in seeds]
    for r in _ordered_map(_robustness_run, items, jobs):
        print(f"robustness {r.line()}", flush=True)
        runs.append(r)
    return Produced([r.row() for r in runs], rb.table(runs, settings),
                    f"settings {', '.join(settings)}; seeds {seeds} (odd: intersection, even: "
                    f"T-junction), {duration:g} s scenarios")


def produce_sparse(cases: list[str], rates: list[float], seeds: list[int], duration: float,
                   height: bool, timing: bool, mode_tolerance: float = 0.5,
                   jobs: int = 1) -> Produced:
    """bench/sparse.py: per case, traffic rate and seed :func:`bench.sparse.run_one` (in
    ``jobs`` processes); the sensor-height and the modes' time parts when asked (after
    them, in this process: the time part measures)."""
    from bench import sparse as sp
    from fgloc.config import Config

    cfg = Config()
    runs = []
    items = [(case, rate, seed, duration, mode_tolerance) for case in cases for rate in rates
             for seed in seeds]
    for item, got in zip(items, _ordered_map(_sparse_runs, items, jobs)):
        runs += got
        print(f"sparse {item[0]} {item[1]:g}/min seed {item[2]} done", flush=True)
    body = [*sp.table(runs), "", *sp.totals(runs)]
    if height:
        body += ["", "Sensor height (coarse stage; 60 s, default traffic, the cases and seeds "
                 "above):", "", *sp.height_rows(cases, seeds, 60.0, cfg)]
    if timing:
        body += ["", "Time of the modes (`--method joint`, one process):", "",
                 *sp.timing_rows(cfg, 2)]
    return Produced([dataclasses.asdict(r) for r in runs], body,
                    f"cases {', '.join(cases)}, {rates} vehicles per minute, seeds {seeds}, "
                    f"{duration:g} s scenarios; an ambiguous run holds the truth when a tied "
                    f"mode lies within {mode_tolerance:g} m")


def produce_real_map(junctions: int, seeds: list[int], duration: float,
                     labels: list[str], traffic: list[str] | None = None,
                     jobs: int = 1) -> Produced:
    """bench/real_map.py: every method at the largest junctions of the Lanelet2 example map,
    on each kind of two-way traffic (``traffic``, default both); the scenarios in ``jobs``
    processes."""
    from bench import real_map as rm

    traffic = traffic or list(rm.TRAFFIC)
    sites, rows = rm.run(rm.DEFAULT_MAP, junctions, seeds, duration, labels, traffic,
                         lambda fn, items: _ordered_map(fn, items, jobs))
    return Produced(rows, rm.table(sites, seeds, labels, rm.errors_of(rows)).splitlines(),
                    f"`{rm.DEFAULT_MAP.name}`, its {junctions} largest junctions, seeds {seeds}, "
                    f"{duration:g} s, labels {', '.join(labels)}, two-way traffic "
                    f"{', '.join(traffic)}")


def produce_independent(groups: list[dict[str, list]], duration: float,
                        jobs: int = 1) -> Produced:
    """bench/independent.py: every method on the independent generator's scenarios of
    ``groups`` (junctions x seeds x settings each); the scenarios in ``jobs`` processes."""
    from bench import independent as ind

    rows = ind.run(groups, duration, pool_map=lambda fn, items: _ordered_map(fn, items, jobs))
    return Produced(rows, ind.table(rows), ind.setting_sentence(groups, duration))


def produce_independent_tracking(groups: list[dict[str, list]], duration: float,
                                 jobs: int = 1) -> Produced:
    """bench/independent_tracking.py: the tracker (true pose) and the batch smoother on the
    independent generator's scenarios of ``groups``; the scenarios in ``jobs`` processes."""
    from bench import independent as ind
    from bench import independent_tracking as it

    runs = it.run(groups, duration, pool_map=lambda fn, items: _ordered_map(fn, items, jobs))
    return Produced([r.row() for r in runs], it.table(runs),
                    ind.setting_sentence(groups, duration))


def produce_scenarios(**kw) -> Produced:
    from bench.accuracy import produce_scenarios as f
    return f(**kw)


def produce_straight(**kw) -> Produced:
    from bench.accuracy import produce_straight as f
    return f(**kw)


def produce_efficiency(quick: bool = False, **kw) -> Produced:
    """bench/accuracy.py's data efficiency; the plot beside the markdown (docs/figures/, or
    the quick results' folder)."""
    from bench.accuracy import produce_efficiency as f
    if quick:
        base = results.RESULTS / "quick"
        return f(plot=base / "data_efficiency.png", link_base=base, **kw)
    return f(plot=DOCS / "figures" / "data_efficiency.png", link_base=DOCS, **kw)


def produce_tracking(**kw) -> Produced:
    from bench.accuracy import produce_tracking as f
    return f(**kw)


def produce_speed(**kw) -> Produced:
    from bench.speed import produce
    return produce(**kw)


def produce_sicp_open3d(**kw) -> Produced:
    from bench.sicp_vs_open3d import produce
    return produce(**kw)


def produce_tracking_speed(**kw) -> Produced:
    from bench.tracking_speed import produce
    return produce(**kw)


def produce_pyrecest(**kw) -> Produced:
    from bench.pyrecest_compare import produce_in_venv
    return produce_in_venv(**kw)


# ------------------------------------------------------------------------------ the tables
@dataclass(frozen=True)
class Table:
    """One table of the report: ``full`` / ``quick`` are the producer's parameters of the two
    sets; ``about`` is the paragraph printed above it (what it shows, no figures)."""

    name: str
    title: str
    script: str
    about: str
    produce: Callable[..., Produced]
    full: dict
    quick: dict
    parallel: bool = False
    """Its producer takes ``jobs`` (independent runs, no time columns among them)."""


_ALL_METHODS = ["filter-sicp", "icp", "joint", "smoother-sicp"]
#: the quick set leaves out smoother-sicp (the batch smoother is the slowest stage)
_QUICK_METHODS = ["filter-sicp", "icp", "joint"]
TABLES: list[Table] = [
    Table("scenarios", "Localization per scenario and per method", "bench/accuracy.py",
          "Every method localizes simulated scenarios through the file route a user takes "
          "(scenario written and loaded back), with the sensor.toml yaw guess; errors against "
          "the simulated truth. The first table lists every run, the second the mean and worst "
          "run per method and case and, for methods that report a covariance, the mean NEES "
          "of (x, y, yaw) over every run (3 degrees of freedom: 3 is consistent; an "
          "ambiguous run's covariance covers its modes) and the runs whose result says it is "
          "ambiguous (marked in the first table). A method's time is the sum of its stage "
          "times, what a separate run spends.",
          produce_scenarios,
          {"cases": ["intersection", "tjunction", "curve"], "seeds": [1, 2, 3, 4, 5],
           "duration": 60.0, "methods": _ALL_METHODS},
          {"cases": ["intersection", "tjunction", "curve"], "seeds": [1], "duration": 30.0,
           "methods": _QUICK_METHODS}),
    Table("robustness", "Robustness matrix", "bench/robustness.py",
          "Tracking (true pose; filter and batch smoother) and localization (filter-sicp, "
          "joint) under simulator settings the defaults do not make: platoons, trucks, low "
          "returns, far and sparse returns, an oblique junction, light traffic, wheel returns "
          "with their micro-Doppler, cyclists at the lanes' edges (4 per minute; the tracking "
          "figures count the motor vehicles, a kept cyclist track is a false one), a tenth of "
          "the returns on the roofs (inside the footprints, not on the outlines), multipath "
          "ghosts (16 buildings 2 m or more from the road, each facade facing the sensor "
          "mirroring 30 % of the vehicles' returns it can; a kept ghost track is a false one), "
          "pairs of vehicles side by side in adjacent lanes (0-0.5 s apart, two 3 m lanes per "
          "direction), a third of the vehicles standing 3-15 s short of the junction (their "
          "returns static, their tracks ended) with queues behind them, and all of these but "
          "the micro-Doppler, the "
          "cyclists, the roof returns, the ghosts, the pairs abreast and the stops at once. "
          "A vehicle counts where the sensor sees it "
          "(field of view, not behind the ALS's buildings). Cells: "
          "mean over the seeds / worst seed. cover 2 = tracks covering two "
          "vehicles at once; truck figures over the tracks following a truck (> 8 m). "
          "flagged = runs whose result says it is not sure (status ambiguous, or a weakly "
          "observed direction with its covariance): their errors are honest misses, the "
          "unflagged column is what a user would take as a pose.",
          produce_robustness,
          {"settings": ["default", "platoons", "trucks", "low-returns", "far-sparse", "oblique",
                        "10-per-min", "wheel-doppler", "cyclists", "roof-returns", "ghosts",
                        "abreast", "stops", "combined"],
           "seeds": [1, 2, 3, 4, 5],
           "duration": 60.0},
          {"settings": ["combined"], "seeds": [1], "duration": 30.0}, parallel=True),
    Table("sparse", "Sparse traffic", "bench/sparse.py",
          "Few vehicles per minute: a run must be resolved within 0.3 m or report itself "
          "ambiguous with the truth among its tied modes, never confidently wrong. Per case, "
          "traffic rate (down to 2 vehicles per minute) and method: share resolved, 2D error of "
          "the resolved runs, NEES against the reported covariance, |dz| and the runs with no "
          "pose (the method found too little: LocalizationError); then the sensor height of "
          "the coarse stage under three vehicle return-height models, two curb heights (the static "
          "ground returns) and no static scatterers at all, and the time the mode search "
          "costs.",
          produce_sparse,
          {"cases": ["intersection", "tjunction"], "rates": [2.0, 5.0, 10.0, 20.0],
           "seeds": [1, 2, 3, 4, 5], "duration": 60.0, "height": True, "timing": True},
          {"cases": ["intersection", "tjunction"], "rates": [5.0], "seeds": [1],
           "duration": 60.0, "height": False, "timing": False}, parallel=True),
    Table("real_map", "Real Lanelet2 map", "bench/real_map.py",
          "Scenarios simulated on the Lanelet2 example map (Karlsruhe, BSD-3-Clause, FZI) at "
          "its six largest junctions of the routing graph; vehicles drive its two-way lanelets "
          "(two-way streets drawn as one lanelet) both ways, keeping to the right half of "
          "their direction (keep-right) or on the centre line (centre), on paths smoothed "
          "through the lanelet joins; keep-right-mapped: keep-right on the lane lines as "
          "mapped, a kink where lanelets meet turned within 1 m (as a generator that drives "
          "the map's centre lines makes them); centre-lanelet2: the centre line both ways, "
          "lanelet2's own (Lanelet.centerline, up to 2 m from the arc-length one on "
          "hand-mapped turns), as mapped (as a generator that drives lanelet2's centre lines "
          "makes them); keep-right-users: keep-right with pedestrians (10 per minute) and "
          "cyclists (6 per minute) on the map's crosswalks, walkways and cycle ways and "
          "trams (2 per minute) on its rails (in view at junction 3 only); "
          "one row group each; "
          "every method, mean and worst seed per junction (the height error dz: its signed "
          "mean and largest magnitude) and the runs whose result was "
          "ambiguous (the pose given is the best mode's; [map] two_way_lanes = auto: the "
          "lane models of two-way streets are modes); each scenario localized with the lane "
          "samples labelled by their lane's path (labels path, the default [map] lane_labels) "
          "and by their lanelet's routing-graph label (labels routing, lane_labels = "
          "\"lanelet\").",
          produce_real_map,
          {"junctions": 6, "seeds": [1, 2, 3], "duration": 60.0,
           "labels": ["path", "routing"],
           "traffic": ["keep-right", "centre", "keep-right-mapped", "centre-lanelet2",
                       "keep-right-users"]},
          {"junctions": 1, "seeds": [1], "duration": 30.0, "labels": ["path"],
           "traffic": ["keep-right", "centre"]}, parallel=True),
    Table("independent", "Scenarios of an independent generator", "bench/independent.py",
          "Scenarios written by bench/independent_gen.py, a generator written without fgloc's "
          "code, from the scenario directory contract only (it imports nothing of fgloc; a test "
          "checks). fgloc's own simulator is a test instrument written alongside the method, "
          "sharing its conventions: a mistake both make alike would not show on its scenarios, and "
          "it is not the data fgloc is for. On the Lanelet2 example map (Karlsruhe, BSD-3-Clause, "
          "FZI) at the junctions of the real-map table (1-6, the routing graph's six largest) "
          "and, held out (never tuned on), its next six (7-12: smaller junctions, where the "
          "generator's mast, facing the junction's centre, may see only a short stretch of "
          "road or a few lanes a lane apart): cars, vans and trucks (boxes up to 16 m) "
          "drive the lanelet centre lines of the routing graph (on a two-way lanelet a quarter of "
          "its width from the right bound), smoothed through the joins, at 7-13 m/s with bounded "
          "lateral acceleration, arriving as a Poisson process (12 per minute; 3-per-min: 3), "
          "driven together: where routes share a lane or cross they follow, yield and wait "
          "before a busy crossing (in the 24 static runs a fifth of them stop for a while; 13 "
          "pairs of boxes still touch, 4 of them for 1-6 s); a 20 "
          "Hz radar on a 5-7 m mast 10-25 m from the junction, pitched 4-12 deg, returns a Poisson "
          "number of points per vehicle and frame on the box faces that face it, at 0.2-0.9 of the "
          "vehicle's height, one in ten on the roof, with rigid-body Doppler, no occlusion ("
          "occluded: the static setting with the returns whose sight line passes through "
          "another vehicle's box below its roof dropped: 5-16 % of the returns; ghosts: "
          "the static setting plus multipath ghosts: up to 3 facades 30-60 m long, 8 m high, "
          "2-5 m beyond a road edge in view, each mirroring a quarter of the vehicles' "
          "returns it can, at the return's mirror image, moving mirrored (seed 1: 2-13 % "
          "as many as the vehicles' returns); "
          "clutter (static): 40 kerb scatterers 0.1-0.2 m high on the lanelet bounds no other "
          "lanelet shares and 15 poles 0-3 m high more than 1 m off the road, each in 30 % of the "
          "frames; none: no clutter; uniform: 15 false alarms a frame anywhere in view, 0-2 m "
          "high, random Doppler; the ALS a ground plane (slope up to 2 %), sensor.toml 3 m and 3 "
          "deg off (1 sigma). Every method through the library (load_scenario, localize_many, the "
          "defaults); per setting and method the runs, how many resolved, the 2D error (runs "
          "with a pose, then the resolved ones alone), the yaw error, the mean NEES of (x, y, "
          "yaw) over the resolved runs (3 is consistent), the height error dz (signed mean, "
          "worst magnitude) and the runs without a pose (LocalizationError).",
          produce_independent,
          {"groups": [{"junctions": [1, 2, 3, 4, 5, 6], "seeds": [1, 2],
                       "settings": ["static"]},
                      {"junctions": [1, 3], "seeds": [1],
                       "settings": ["none", "3-per-min"]},
                      {"junctions": [1, 2, 3, 4, 5, 6], "seeds": [1],
                       "settings": ["uniform"]},
                      {"junctions": [1, 2, 3, 4, 5, 6], "seeds": [1, 2],
                       "settings": ["occluded", "ghosts"]},
                      {"junctions": [7, 8, 9, 10, 11, 12], "seeds": [1, 2],
                       "settings": ["static"]}],
           "duration": 60.0},
          {"groups": [{"junctions": [1], "seeds": [1], "settings": ["static"]}],
           "duration": 60.0}, parallel=True),
    Table("independent_tracking", "Tracking on the independent generator's scenarios",
          "bench/independent_tracking.py",
          "The tracker on scenarios fgloc's simulator did not make: the independent "
          "generator's scenarios of the table above (the same junctions, seeds and settings "
          "give the same scenarios), each tracked by the filter with the true sensor pose and "
          "smoothed by the batch smoother on its tracks; the figures and cells of the "
          "robustness matrix (mean over the runs / worst run; truck figures over the tracks "
          "following a truck, > 8 m), with the track counts per run beside tracks per vehicle: "
          "false tracks (following no vehicle, or a vehicle another track follows at the "
          "same time), fragments (a vehicle's later tracks: a track break; a vehicle that "
          "stands has static returns, dropped, and gets a new track when it moves off unless "
          "the re-linking joins the two across the stand, [tracking] stand_time) and missed "
          "vehicles. A vehicle counts where the sensor sees it.",
          produce_independent_tracking,
          {"groups": [{"junctions": [1, 2, 3, 4, 5, 6], "seeds": [1, 2],
                       "settings": ["static"]},
                      {"junctions": [7, 8, 9, 10, 11, 12], "seeds": [1, 2],
                       "settings": ["static"]},
                      {"junctions": [1, 2, 3, 4, 5, 6], "seeds": [1, 2],
                       "settings": ["occluded", "ghosts"]}],
           "duration": 60.0},
          {"groups": [{"junctions": [1], "seeds": [1], "settings": ["static"]}],
           "duration": 30.0}, parallel=True),
    Table("straight", "Straight road without a junction", "bench/accuracy.py",
          "On a straight road nothing observes the position along the road: every method "
          "is off along it. The table shows how far, and whether a method that reports a "
          "covariance says so (its along-road standard deviation, the joint's weak-direction "
          "flag, and the result's status).",
          produce_straight,
          {"seeds": [1, 2, 3], "duration": 60.0, "methods": _ALL_METHODS},
          {"seeds": [1], "duration": 30.0, "methods": _QUICK_METHODS}),
    Table("efficiency", "Data efficiency", "bench/accuracy.py",
          "2D and yaw error against the number of trajectories the fine stage uses "
          "(`[fine] n_trajectories`), on the intersection and the T-junction: how many "
          "vehicles a site needs.",
          produce_efficiency,
          {"seeds": [1, 2, 3], "counts": [5, 10, 20, 50], "duration": 60.0,
           "methods": ["filter-sicp", "joint"]},
          {"seeds": [1], "counts": [5, 20], "duration": 30.0,
           "methods": ["filter-sicp", "joint"], "quick": True}),
    Table("tracking", "Tracking: filter, fixed-lag and batch smoother", "bench/accuracy.py",
          "GP-EOT tracking with the true sensor pose: the filter, the fixed-lag smoother and "
          "the batch smoother on the same tracks. trkRMS is the paper's average RMS (mean of "
          "the per-track centre RMS); RTF = recording s / CPU s on one core.",
          produce_tracking,
          {"seeds": [1, 2, 3, 4, 5], "duration": 60.0, "vehicles": 50},
          {"seeds": [1], "duration": 30.0, "vehicles": 30}),
    Table("pyrecest", "GP-EOT against pyrecest's FullSCGPTracker", "bench/pyrecest_compare.py",
          "fgloc's GP-EOT tracker against pyrecest's FullSCGPTracker (numpy backend, its own "
          "venv bench/.venv-pyrecest from bench/pyrecest_env.sh; pyrecest is not a dependency "
          "of fgloc) on the same single-vehicle frames with the true pose.",
          produce_pyrecest,
          {"duration": 40.0, "sequences": None},
          {"duration": 20.0, "sequences": ["intersection:1", "intersection:6"]}),
    Table("speed", "Speed per stage, peak memory and scaling", "bench/speed.py",
          "Every localization runs as its own `fgloc localize` child process, the way a user "
          "runs it: stage times from its result.json, peak resident memory (VmHWM) its own. "
          "Then how the stages grow with the recording length (vehicle arrivals "
          "proportional) and with the vehicle count. Times depend on the machine's load, "
          "given in the provenance line.",
          produce_speed,
          {"duration": 120.0, "vehicles": 60, "durations": [30.0, 60.0, 120.0, 300.0, 900.0],
           "vehicle_counts": [20, 50, 100], "methods": _ALL_METHODS},
          {"duration": 30.0, "vehicles": 20, "durations": [], "vehicle_counts": [],
           "methods": _ALL_METHODS}),
    Table("sicp_open3d", "SICP against Open3D ICP", "bench/sicp_vs_open3d.py",
          "fgloc's SE(2) SICP and plain ICP against Open3D's point-to-point "
          "`registration_icp` on the same clouds (road points of the target cloud; dynamic "
          "radar points placed with the true pose, oracle labels, moved by a known offset); "
          "median wall time over the repeats, iterations, and the errors against the offset.",
          produce_sicp_open3d,
          {"repeats": 7}, {"repeats": 2}),
    Table("tracking_speed", "Tracker real-time factor and measurement models",
          "bench/tracking_speed.py",
          "The filter's real-time factor on one core (recording s / CPU s; target >= 5 at "
          "~10,000 detections/s) and its metrics with the sensor-aware and the plain "
          "measurement model, true pose.",
          produce_tracking_speed,
          {"seeds": [1, 2, 3], "duration": 60.0, "vehicles": 50},
          {"seeds": [1], "duration": 30.0, "vehicles": 30}),
]
BY_NAME = {t.name: t for t in TABLES}


def reduced(table: Table, params: dict, quick: bool = False) -> dict:
    """{param: [set value, used value]} where ``params`` differ from the table's full set
    (its quick set with ``quick``)."""
    ref = table.quick if quick else table.full
    return {k: [v, params.get(k)] for k, v in ref.items() if params.get(k) != v}


def run_table(table: Table, quick: bool, overrides: dict, command: str,
              root: Path = results.RESULTS, jobs: int = 1) -> Path | None:
    """Produce one table and store it (its runs in ``jobs`` processes when the table is
    ``parallel``); returns the JSON path (None when the table is
    :class:`bench.results.Unavailable` here)."""
    params = {**(table.quick if quick else table.full), **overrides}
    print(f"== {table.name}: {params}", flush=True)
    commit, started, t0 = results.git_commit(), results.utc_now(), time.perf_counter()
    try:
        produced = table.produce(**params, **({"jobs": jobs} if table.parallel else {}))
    except results.Unavailable as e:
        print(f"== {table.name}: not measured ({e}); the stored result stays", flush=True)
        return None
    dt = time.perf_counter() - t0
    path = results.save(table.name, produced, command, started, dt, quick, params,
                        reduced(table, params, quick), commit, root)
    print(f"== {table.name}: {dt:.0f} s -> {path}", flush=True)
    return path


# ------------------------------------------------------------------------------ rendering
def provenance_line(doc: dict, table: Table) -> str:
    m = doc["machine"]
    dirty = " (with uncommitted changes)" if doc["dirty"] else ""
    line = (f"Measured at commit `{doc['commit']}`{dirty}, {doc['started']} - {doc['finished']}, "
            f"{doc['duration_s']:.0f} s; {m['processor']}, "
            f"{m['cpus']} CPUs, load {m['load']}, Python {m['python']}, OMP_NUM_THREADS="
            f"{m['omp_num_threads']}. Command: `{doc['command']}` (producer: {table.script}). "
            f"Setting: {doc['setting']}.")
    if doc.get("imported_from"):
        line += f" Imported: {doc['imported_from']}."
    if doc["reduced"]:
        which = "quick" if doc["quick"] else "full"
        line += f" **REDUCED against the {which} set:** " + "; ".join(
            f"{k} {json.dumps(used)} instead of {json.dumps(full)}"
            for k, (full, used) in doc["reduced"].items()) + "."
    return line


def _f(v, fmt: str = "{:.3f}") -> str:
    return "-" if v is None else fmt.format(v)


def _mean_of(rows: list[dict], key: str, fmt: str) -> str:
    """The mean of ``key`` over the rows that have a finite value of it, formatted; "-" when
    none has."""
    values = [r[key] for r in rows if math.isfinite(r.get(key, math.nan))]
    return fmt.format(sum(values) / len(values)) if values else "-"


def _when(doc: dict) -> str:
    return f"commit `{doc['commit']}`, {doc['started']}"


def first_screen(docs: dict[str, dict]) -> list[str]:
    """The current figures per method next to the paper's and the peers'."""
    out = ["## At a glance", "", "### Localization", ""]
    sc, sp = docs.get("scenarios"), docs.get("speed")
    if sc is None:
        out += ["No stored per-scenario result yet: run `python -m bench.report --only "
                "scenarios`.", ""]
    else:
        mem = sp["summary"].get("peak_rss_mib", {}) if sp else {}
        out += [f"fgloc on simulated scenarios ({sc['setting']}; {_when(sc)}): mean over the "
                "runs, worst run in brackets; time = the method's stage times (load average "
                f"{sc['machine']['load']} on {sc['machine']['cpus']} CPUs at the end of the "
                "run: times scale with it); peak memory "
                + (f"of a separate `fgloc localize` process in the speed table ({sp['setting']}; "
                   f"{_when(sp)})." if sp else "not measured yet."), "",
                "| method | runs | 2D m | \\|dyaw\\| deg | \\|dz\\| m | NEES (x, y, yaw) | "
                "time s | peak memory MiB |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
        for m, s in sc["summary"]["methods"].items():
            n_cov = sum(r["method"] == m and r.get("cov") is not None for r in sc["rows"])
            nees = _f(s["nees_mean"], "{:.2f}")
            if s["nees_mean"] is not None and n_cov < s["runs"]:
                nees += f" ({n_cov} of {s['runs']} runs)"
            out.append(f"| {m} | {s['runs']} | {s['d2d_mean']:.3f} ({s['d2d_worst']:.3f}) | "
                       f"{s['dyaw_mean']:.3f} | {s['dz_mean']:.3f} | {nees} | "
                       f"{s['time_mean']:.1f} | {_f(mem.get(m), '{:.0f}')} |")
    out += ["| paper, SICP (Table I: S1, S2 CARLA; S3, S4 real) | 4 sensors | 0.66, 0.94, 0.38, "
            "0.55 | 0.20, 0.22, 0.35, 0.16 | - | - | - | - |",
            "| paper, earlier method [localizationiv] (Table II: S3, S4) | 2 sensors | \\|dx\\| "
            "0.93, 0.80; \\|dy\\| 0.82, 0.70 | 1.25, 0.03 | - | - | - | - |", "",
            "The paper's rows are its own figures (section V, Tables I and II; mean 2D per "
            "sensor as its text gives them) on its own data: quoted for orientation, not the "
            "same runs. It reports no height, NEES, time or memory.", ""]
    so = docs.get("sicp_open3d")
    if so is not None:
        s = so["summary"]
        out += ["### Registration against Open3D ICP", "",
                f"The same clouds, from a {s['offset']} offset ({_when(so)}; table below):", "",
                "| registration | time ms | 2D m | \\|dyaw\\| deg |", "|---|---:|---:|---:|",
                f"| fgloc SICP (hard, 50 -> 1.5 m) | {s['sicp_ms']:.1f} | {s['sicp_2d']:.3f} | "
                f"{s['sicp_yaw']:.3f} |",
                f"| Open3D point-to-point ICP (50 m) | {s['open3d_ms']:.1f} | "
                f"{s['open3d_2d']:.3f} | {s['open3d_yaw']:.3f} |", ""]
    tr, py, it = docs.get("tracking"), docs.get("pyrecest"), docs.get("independent_tracking")
    if tr is not None or py is not None or it is not None:
        out += ["### Tracking (true pose)", "",
                "| tracker | data | centre RMS m | yaw deg | IoU |", "|---|---|---:|---:|---:|"]
        if tr is not None:
            for name in ("filter", "batch"):
                t = tr["summary"][name]
                out.append(f"| fgloc {name} (per-track mean RMS) | {tr['setting']} ({_when(tr)})"
                           f" | {t['centre_rms_track_mean']:.3f} | {t['yaw_error_deg']:.2f} | "
                           f"{t['iou']:.3f} |")
        if it is not None:
            for name in ("filter", "batch"):
                out.append(f"| fgloc {name} (per-track mean RMS) | the independent generator's "
                           f"scenarios, {len(it['rows'])} runs, oracle pose ({_when(it)}) | "
                           + " | ".join(_mean_of(it["rows"], f"{name}.{k}", fmt)
                                        for k, fmt in (("rms", "{:.3f}"), ("yaw", "{:.2f}"),
                                                       ("iou", "{:.3f}"))) + " |")
        if py is not None and "pyrecest" in py["summary"]:
            for name in ("fgloc", "pyrecest"):
                t = py["summary"][name]
                label = "fgloc filter" if name == "fgloc" else "pyrecest FullSCGPTracker"
                out.append(f"| {label} (pooled RMS, {t['ms_per_frame']:.1f} ms per frame) | "
                           f"{py['summary']['sequences']} single-vehicle sequences ({_when(py)})"
                           f" | {t['rms']:.3f} | {t['yaw_deg']:.2f} | {t['iou']:.3f} |")
        out += ["| paper, GP-EOT (section V-A) | CARLA S1, 60 trajectories | 0.49 | 3.8 | "
                "0.59 |", ""]
    return out


def render(docs: dict[str, dict], quick: bool) -> str:
    """The whole markdown report from the stored results ``docs`` (table name -> JSON)."""
    out = ["# fgloc benchmarks" + (" (quick smoke set)" if quick else ""), "",
           "Generated by `OMP_NUM_THREADS=1 python -m bench.report"
           + (" --quick" if quick else "") + "` from the stored results in "
           + ("`bench/results/quick/`" if quick else "`bench/results/`")
           + "; do not edit by hand. Each table says the commit, date, machine and command it "
           "ran with; rerun one with `--only TABLE`. Accuracy figures are deterministic for a "
           "commit (same seeds, same numbers); times vary with the machine's load. The history "
           "of experiments and decisions is in [experiments.md](experiments.md).", "",
           *first_screen(docs)]
    out += ["## Tables", ""] + [f"- [{t.title}](#{t.name})" for t in TABLES] + [""]
    for t in TABLES:
        out += [f'<a id="{t.name}"></a>', "", f"## {t.title}", "", t.about, ""]
        doc = docs.get(t.name)
        if doc is None:
            out += [f"Not measured yet: `python -m bench.report --only {t.name}"
                    + (" --quick" if quick else "") + "`.", ""]
            continue
        out += [provenance_line(doc, t), "", *doc["body"], ""]
    return "\n".join(out).rstrip("\n") + "\n"


def write_report(quick: bool, out: Path | None, root: Path = results.RESULTS) -> Path:
    from fgloc.io.atomic import write_text_atomic

    docs = {t.name: d for t in TABLES if (d := results.load(t.name, quick, root)) is not None}
    path = out or (root / "quick" / "benchmarks.md" if quick else DOCS / "benchmarks.md")
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, render(docs, quick))
    return path


def parse_sets(items: list[str]) -> dict[str, dict]:
    """``TABLE.PARAM=JSON`` items -> {table: {param: value}}."""
    out: dict[str, dict] = {}
    for item in items:
        key, sep, value = item.partition("=")
        table, dot, param = key.partition(".")
        if not sep or not dot or table not in BY_NAME:
            raise SystemExit(f"--set {item!r}: expected TABLE.PARAM=JSON with TABLE one of "
                             f"{', '.join(BY_NAME)}")
        if param not in BY_NAME[table].full:
            raise SystemExit(f"--set {item!r}: {table} has the parameters "
                             f"{', '.join(BY_NAME[table].full)}")
        try:
            out.setdefault(table, {})[param] = json.loads(value)
        except json.JSONDecodeError as e:
            raise SystemExit(f"--set {item!r}: the value is not JSON ({e})") from e
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="the smoke set (< 10 minutes)")
    ap.add_argument("--only", nargs="+", choices=list(BY_NAME), default=None,
                    help="run these tables only (the others are rendered from storage)")
    ap.add_argument("--render-only", action="store_true", help="run nothing, render only")
    ap.add_argument("--set", nargs="+", default=[], metavar="TABLE.PARAM=JSON",
                    help="change a table's parameter (marked REDUCED in the report)")
    ap.add_argument("--out", type=Path, default=None, help="write the markdown here instead")
    ap.add_argument("--jobs", type=int, default=1,
                    help="processes for the runs of the tables " + ", ".join(
                        t.name for t in TABLES if t.parallel))
    args = ap.parse_args(argv)
    sets = parse_sets(args.set)
    argv = sys.argv[1:] if argv is None else argv
    command = "OMP_NUM_THREADS=1 python -m bench.report" + "".join(f" {a}" for a in argv)
    if not args.render_only:
        for t in TABLES:
            if args.only is None or t.name in args.only:
                run_table(t, args.quick, sets.get(t.name, {}), command, jobs=args.jobs)
    print(f"wrote {write_report(args.quick, args.out)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
