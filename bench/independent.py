"""Every method on scenarios of the independent generator (bench/independent_gen.py).

fgloc's own simulator is a test instrument written alongside the method; this benchmark
localizes scenarios it did not make. Per (junction, seed, setting) the generator writes a
scenario directory (into a temporary directory) on the Lanelet2 example map (BSD-3-Clause,
FZI; its licence file is copied with it; ``--map`` another), at one of the map's twelve largest
junctions of its routing graph (:func:`junctions`; 7-12 held out, :data:`LOOKED_AT`), fgloc
loads it like any user's
(:func:`fgloc.io.load_scenario`) and localizes it with every method
(:func:`bench.sparse.localize_each`: :func:`fgloc.pipeline.localize_many` with the defaults; a
method that raises :class:`fgloc.errors.LocalizationError` is a "no pose" run). Per run and
method: the status, the 2D and yaw errors against the file's ground truth, the NEES of
(x, y, yaw) against the reported covariance and the signed height error dz; then per setting
and method the table :func:`table`.

The settings (:data:`SETTINGS`): "static" the generator's defaults (static clutter: kerbs and
poles, 12 vehicles per minute), "none" no clutter, "uniform" uniform false alarms instead,
"3-per-min" the defaults at 3 vehicles per minute, "occluded" the defaults with vehicles
hiding the returns behind them, "ghosts" the defaults with multipath ghosts of facades beside
the road.

    OMP_NUM_THREADS=1 python -m bench.independent                    # the report's full set
    OMP_NUM_THREADS=1 python -m bench.independent --junctions 1 --seeds 1 --settings static
    OMP_NUM_THREADS=1 python -m bench.independent --map MY_MAP.osm --junctions 1 2 --seeds 1 2

docs/benchmarks.md's table comes from ``python -m bench.report --only independent``.
"""

from __future__ import annotations

import argparse
import functools
import json
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from bench.independent_gen import generate
from bench.real_map import DEFAULT_MAP, junction_sites
from bench.sparse import METHODS, NO_POSE, localize_each
from fgloc.config import load_config
from fgloc.evaluation.pose import pose_error, pose_error_vector
from fgloc.io import load_scenario
from fgloc.result import LocalizationResult
from fgloc.scenario import Scenario

#: how many of a map's largest junctions the benchmark may run
N_JUNCTIONS = 12
#: junctions 1 to this one are the sites fgloc's development looked at (the real-map table's);
#: the rest are held out: measured, never tuned on (:func:`site_group`)
LOOKED_AT = 6
#: the row label of the held-out junctions' runs besides their setting (:func:`site_group`)
HELD_OUT = "held-out junctions"
#: setting name -> the generator's keyword arguments (:func:`bench.independent_gen.generate`)
SETTINGS: dict[str, dict[str, object]] = {
    "static": {}, "none": {"clutter": "none"}, "uniform": {"clutter": "uniform"},
    "3-per-min": {"vehicles_per_minute": 3.0}, "occluded": {"occlusion": True},
    "ghosts": {"ghosts": True}}

#: one run's figures (see :func:`rows_of`)
Row = dict[str, object]


@functools.lru_cache(maxsize=4)
def junctions(map_path: Path = DEFAULT_MAP, n: int = N_JUNCTIONS
              ) -> dict[int, tuple[float, float]]:
    """Junction number (1 = the largest) -> site (lat, lon, deg) of the ``n`` largest junctions
    of ``map_path``'s routing graph (:func:`bench.real_map.junction_sites`, its order), to 1e-5
    deg (the generator draws its seed from the site at that resolution)."""
    return {k: (round(lat, 5), round(lon, 5))
            for k, (lat, lon) in enumerate(junction_sites(map_path, n), start=1)}


def runs_of(groups: list[dict[str, list]]) -> list[tuple[int, int, str]]:
    """(junction, seed, setting) of every run of ``groups`` (each {"junctions", "seeds",
    "settings"}: their product), in order: group, setting, junction, seed."""
    return [(j, s, setting) for g in groups for setting in g["settings"]
            for j in g["junctions"] for s in g["seeds"]]


def rows_of(res: dict[str, LocalizationResult | None], truth: np.ndarray, key: Row
            ) -> list[Row]:
    """One row per method of ``res`` (None: no pose) against the true pose ``truth`` (4x4,
    S -> L): ``key`` plus status, modes, 2D error (m), |yaw error| (deg), NEES of (x, y,
    yaw) against the result's covariance (None without one), dz = estimated minus true
    height (m)."""
    rows = []
    for m, r in res.items():
        row: Row = {**key, "method": m, "status": NO_POSE, "n_modes": 0, "d2d": None,
                    "dyaw_deg": None, "nees": None, "dz": None}
        if r is not None:
            err, e = pose_error(r.T_local, truth), pose_error_vector(r.T_local, truth)
            nees = None if r.covariance is None else float(e @ np.linalg.solve(r.covariance, e))
            row.update(status=r.status, n_modes=len(r.modes), d2d=err.d2d,
                       dyaw_deg=err.dyaw_deg, nees=nees, dz=float(r.T_local[2, 3] - truth[2, 3]))
        rows.append(row)
    return rows


@contextmanager
def generated(junction: int, seed: int, setting: str, duration: float,
              map_path: Path = DEFAULT_MAP) -> Iterator[Scenario]:
    """The generator's scenario (``duration`` s at junction ``junction`` of ``map_path``,
    ``seed``, ``setting``) written to a temporary directory and loaded as a user's would be
    (:func:`fgloc.io.load_scenario`); the directory is removed on exit. ``ValueError`` for
    a junction the map does not have."""
    sites = junctions(map_path)
    if junction not in sites:
        raise ValueError(f"{map_path}: {len(sites)} junctions in its routing graph, "
                         f"no junction {junction}")
    with tempfile.TemporaryDirectory(prefix="fgloc-independent-") as tmp:
        yield load_scenario(generate(map_path, sites[junction], seed, Path(tmp) / "scenario",
                                     duration=duration, **SETTINGS[setting]))


def run_one(junction: int, seed: int, setting: str, duration: float,
            config: Path | None = None, map_path: Path = DEFAULT_MAP) -> list[Row]:
    """Generate the scenario (``duration`` s at junction ``junction``, ``seed``, ``setting``),
    localize it with every method (fgloc config TOML ``config``, None: the defaults) and
    score it: :func:`rows_of` with the vehicle count and the wall time of all methods
    together (s)."""
    with generated(junction, seed, setting, duration, map_path) as scn:
        t0 = time.perf_counter()
        res = localize_each(scn, load_config(config))
        seconds = time.perf_counter() - t0
    key: Row = {"setting": setting, "junction": junction, "seed": seed,
                "vehicles": len(scn.truth.tracks), "seconds": round(seconds, 1)}
    rows = rows_of(res, scn.truth.sensor_pose, key)
    print(f"independent junction {junction} seed {seed} {setting}: " + "; ".join(
        f"{r['method']} {r['status']}" + ("" if r["d2d"] is None else
                                         f" {r['d2d']:.3f} m {r['dyaw_deg']:.3f} deg")
        for r in rows) + f"  [{seconds:.0f} s]", flush=True)
    return rows


def run(groups: list[dict[str, list]], duration: float, config: Path | None = None,
        pool_map: Callable[..., Iterable[list[Row]]] | None = None,
        map_path: Path = DEFAULT_MAP) -> list[Row]:
    """The rows of :func:`run_one` for every run of ``groups`` (:func:`runs_of`) on the
    Lanelet2 map ``map_path``. ``pool_map(fn, items)`` runs ``fn(*item)`` per item in order
    (e.g. in worker processes; default: here, one after the other)."""
    items = [(j, s, setting, duration, config, map_path) for j, s, setting in runs_of(groups)]
    done = (pool_map or (lambda fn, its: (fn(*it) for it in its)))(run_one, items)
    return [row for rows in done for row in rows]


def _mean_worst(values: list[float], fmt: str = "{:.3f}") -> str:
    return (f"{fmt.format(np.mean(values))} / {fmt.format(max(values))}" if values
            else "- / -")


def site_group(junction: int) -> str:
    """The row label of a junction's runs besides their setting: "" for the sites development
    looked at (1 to :data:`LOOKED_AT`), :data:`HELD_OUT` for the others."""
    return "" if junction <= LOOKED_AT else HELD_OUT


def group_label(setting: str, junction: int) -> str:
    """The row label of a run: its setting, with :data:`HELD_OUT` for a held-out junction."""
    group = site_group(junction)
    return f"{setting}, {group}" if group else setting


def ordered_labels(labels: Iterable[str]) -> list[str]:
    """The row labels (:func:`group_label`) among ``labels``, each once, in table order: the
    settings' order in :data:`SETTINGS`, the junctions looked at before the held-out ones."""
    have = set(labels)
    return [label for s in SETTINGS for label in (s, f"{s}, {HELD_OUT}") if label in have]


def table(rows: list[Row]) -> list[str]:
    """Markdown: per setting (and :func:`site_group`) and method the runs, how many resolved,
    the 2D error (mean / worst over the runs with a pose, then over the resolved ones), the
    |yaw| error, the mean NEES over the resolved runs (3 is consistent), dz (signed mean /
    worst magnitude) and the runs without a pose."""
    lines = ["| setting | method | runs | resolved | 2D m (mean / worst) | 2D m resolved (mean / "
             "worst) | abs dyaw deg (mean / worst) | NEES resolved (mean) | dz m (mean / worst "
             "abs) | no pose |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    label_of = [group_label(r["setting"], r["junction"]) for r in rows]
    for label in ordered_labels(label_of):
        for m in METHODS:
            rs = [r for r, g in zip(rows, label_of) if g == label and r["method"] == m]
            posed = [r for r in rs if r["status"] != NO_POSE]
            nees = [r["nees"] for r in rs if r["status"] == "resolved" and r["nees"] is not None]
            dz = [r["dz"] for r in posed]
            lines.append(
                f"| {label} | {m} | {len(rs)} | {sum(r['status'] == 'resolved' for r in rs)} | "
                f"{_mean_worst([r['d2d'] for r in posed])} | "
                f"{_mean_worst([r['d2d'] for r in posed if r['status'] == 'resolved'])} | "
                f"{_mean_worst([r['dyaw_deg'] for r in posed])} | "
                f"{f'{np.mean(nees):.2f}' if nees else '-'} | "
                + (f"{np.mean(dz):+.3f} / {max(abs(d) for d in dz):.3f}" if dz else "- / -")
                + f" | {len(rs) - len(posed)} |")
    return lines


def setting_sentence(groups: list[dict[str, list]], duration: float,
                     map_path: Path = DEFAULT_MAP) -> str:
    """What ``groups`` ran: the map, the runs per group, the scenario length."""
    parts = [f"junctions {g['junctions']} x seeds {g['seeds']} in {', '.join(g['settings'])}"
             for g in groups]
    n = len(runs_of(groups))
    return (f"`{map_path.name}`, {n} scenario{'s' * (n != 1)}: {'; '.join(parts)}; "
            f"{duration:g} s each")


def parser(description: str) -> argparse.ArgumentParser:
    """The options of the benchmarks on the generator's scenarios (this one and
    bench/independent_tracking.py): the map, one group of runs instead of the report's set,
    the scenario length, an fgloc config and a JSON output (:func:`groups_of`)."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--map", type=Path, default=DEFAULT_MAP,
                    help="Lanelet2 map (default: the Lanelet2 example map)")
    ap.add_argument("--junctions", type=int, nargs="+",
                    choices=range(1, N_JUNCTIONS + 1), default=None,
                    help="with --seeds and --settings: one group instead of the report's set "
                         "(1 = the map's largest junction)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1])
    ap.add_argument("--settings", nargs="+", choices=list(SETTINGS), default=["static"])
    ap.add_argument("--duration", type=float, default=60.0, help="scenario length (s)")
    ap.add_argument("--config", type=Path, default=None,
                    help="fgloc config TOML (default: all defaults)")
    ap.add_argument("--json", type=Path, default=None, help="also write every run here")
    return ap


def groups_of(args: argparse.Namespace, table_name: str) -> list[dict[str, list]]:
    """The groups of runs :func:`parser`'s ``args`` ask for: the one group of ``--junctions``,
    ``--seeds`` and ``--settings``, or without ``--junctions`` the report table
    ``table_name``'s full set (bench/report.py)."""
    if args.junctions is not None:
        return [{"junctions": args.junctions, "seeds": args.seeds, "settings": args.settings}]
    from bench.report import BY_NAME

    return BY_NAME[table_name].full["groups"]


def main() -> int:
    args = parser(__doc__.split("\n\n")[0]).parse_args()
    groups = groups_of(args, "independent")
    rows = run(groups, args.duration, args.config, map_path=args.map)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    print(setting_sentence(groups, args.duration, args.map) + "\n\n" + "\n".join(table(rows)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
