"""The ``fgloc`` command line: a thin layer that parses, calls the library and prints.

Every :class:`fgloc.errors.FglocError` (bad input, impossible localization) ends the command with
a one-line message on stderr and exit code 2. ``localize`` ends with :data:`EXIT_AMBIGUOUS` (3)
when the result is ``ambiguous`` (outputs written, a warning on stderr).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from fgloc.errors import FglocError

if TYPE_CHECKING:
    from fgloc.geo import LocalFrame
    from fgloc.scenario import AlsCloud, SensorConfig

#: exit code of ``fgloc localize`` when the pose is ambiguous (several modes fit alike)
EXIT_AMBIGUOUS = 3

EXAMPLE_DIR = Path(__file__).resolve().parent.parent / "data" / "example"


# --------------------------------------------------------------------------------------------
# commands
# --------------------------------------------------------------------------------------------
def cmd_simulate(args: argparse.Namespace) -> int:
    from fgloc.config import from_dict, read_toml
    from fgloc.io import write_scenario
    from fgloc.sim import SimConfig, simulate

    sim_cfg = None
    if args.sim_config is not None:
        sim_cfg = from_dict(SimConfig, read_toml(args.sim_config), args.sim_config)
    if args.map is not None:
        return _simulate_on_map(args, sim_cfg)
    if args.site is not None:
        raise FglocError("--site needs --map")
    scn = simulate(
        args.case, args.seed, duration=args.duration, vehicles=args.vehicles, config=sim_cfg
    )
    write_scenario(scn, args.out, radar_format=args.radar_format)
    print(
        f"wrote {args.case} scenario (seed {args.seed}, {len(scn.radar)} detections) to {args.out}"
    )
    return 0


def _parse_site(text: str) -> tuple[float, float]:
    """'LAT,LON' in degrees (WGS84)."""
    from fgloc.errors import InputError

    try:
        lat, lon = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError("--site", f"expected LAT,LON in degrees, got {text!r}") from None
    if not (abs(lat) <= 90.0 and abs(lon) <= 180.0):
        raise InputError("--site", f"lat must be in [-90, 90] and lon in [-180, 180], got {text}")
    return lat, lon


def _simulate_on_map(args: argparse.Namespace, sim_cfg) -> int:
    from fgloc.errors import InputError
    from fgloc.io import write_scenario
    from fgloc.sim.real_map import simulate_on_map

    if not Path(args.map).is_file():
        raise InputError(args.map, "Lanelet2 map not found")
    site = None if args.site is None else _parse_site(args.site)
    try:
        sim = simulate_on_map(args.map, args.seed, site=site, duration=args.duration,
                              vehicles=args.vehicles, config=sim_cfg)
    except (ValueError, RuntimeError) as exc:
        raise InputError(args.map, str(exc)) from None
    write_scenario(sim.scenario, args.out, radar_format=args.radar_format, map_osm=sim.map_osm,
                   extra_files=sim.notices)
    w = sim.scenario.frame.to_world(sim.junction[None])[0]
    print(f"wrote a scenario on {args.map} ({sim.site} at E {w[0]:.1f} N {w[1]:.1f}, seed "
          f"{args.seed}, {len(sim.scenario.radar)} detections, "
          f"{_road_users(sim.result.vehicle_class)}) to {args.out}")
    return 0


def _road_users(classes: list[str]) -> str:
    """'N vehicles', or with pedestrians, cyclists or trams among ``classes`` (the simulator's
    class name per true track) how many of each."""
    others = {name: classes.count(kind) for kind, name in
              (("pedestrian", "pedestrians"), ("bicycle", "cyclists"), ("tram", "trams"))}
    if not any(others.values()):
        return f"{len(classes)} vehicles"
    return (f"{len(classes)} road users: {len(classes) - sum(others.values())} motor vehicles, "
            + ", ".join(f"{n} {name}" for name, n in others.items()))


def scenario_summary(path: str | Path) -> str:
    """One-screen text summary of a scenario directory (loads and validates it)."""
    from fgloc.config import CoarseConfig, MapConfig
    from fgloc.io import load_scenario
    from fgloc.labels import NAMES
    from fgloc.map import map_labels
    from fgloc.scenario import ASPRS_CLASSES, RAGGED_END_GAP, lanelet_kind, ragged

    scn = load_scenario(path)
    r, s = scn.radar, scn.sensor
    lam = CoarseConfig().doppler_min
    dyn = float(np.mean(np.abs(r.doppler) >= lam)) if len(r) else 0.0
    n_frames = len(np.unique(r.frame_ids()))
    classes, counts = np.unique(scn.als.classification, return_counts=True)
    cls_txt = ", ".join(
        f"{ASPRS_CLASSES.get(int(c), f'class {int(c)}')} ({int(c)}): {n:,}"
        for c, n in zip(classes, counts)
    )
    map_cfg = MapConfig()
    labels = map_labels(scn.lanelets, map_cfg)
    codes = list(labels.code.values())
    by_label = ", ".join(f"{NAMES[k]} {codes.count(k)}" for k in sorted(NAMES))
    n_routed = list(labels.source.values()).count("routing")
    lmap = scn.lanelets
    rag = ragged(lmap.lanelets)
    drivable_kinds = [lanelet_kind(ll) for ll in lmap.lanelets]
    by_kind = ", ".join(f"{k} {drivable_kinds.count(k)}" for k in sorted(set(drivable_kinds)))

    # how far apart the two constructions of each lanelet's centre line lie (formats.md)
    apart = np.array([np.linalg.norm(ll.centre(ll.samples(0.5))[1], axis=1).max()
                      for ll in lmap.lanelets])

    def counts(d: dict[str, int]) -> str:
        return ", ".join(f"{k} {v}" for k, v in d.items()) or "none"
    rate = len(r) / r.duration if r.duration > 0 else float("nan")
    guess = (
        "absent (global yaw search)" if s.yaw_guess_deg is None else f"{s.yaw_guess_deg:.2f} deg"
    )
    height = "absent" if s.approx_height is None else f"{s.approx_height:.2f} m"
    lines = [
        f"scenario      {scn.path}",
        f"CRS           {scn.crs}",
        f"approx pos    E {s.approx_position[0]:.2f}  N {s.approx_position[1]:.2f}"
        f"  height {height}",
        f"yaw guess     {guess}",
        f"field of view {s.hfov_deg:g} x {s.vfov_deg:g} deg, max range {s.max_range:g} m",
        f"radar         {len(r):,} detections in {n_frames:,} frames over {r.duration:.1f} s "
        f"({rate:,.0f} /s); dynamic (|doppler| >= {lam:g} m/s): {100 * dyn:.1f} %",
        f"ALS           {len(scn.als):,} points in {len(scn.als.source_files)} tile(s); {cls_txt}",
        f"lanelets      {len(lmap)} drivable ({by_kind}; {lmap.rules})",
        f"  labels      {by_label} ({n_routed} from the routing graph's junction movements, "
        f"the rest by Menger curvature, gamma {map_cfg.gamma:g} 1/m)",
        f"  centre line {map_cfg.centre_line!r}; arc-length and lanelet2's construction "
        f"apart by median {np.median(apart):.2f} m, max {apart.max():.2f} m, "
        f"over 0.3 m on {int((apart > 0.3).sum())} lanelets",
        f"  ignored     {sum(lmap.ignored_by_kind().values())} not drivable "
        f"({counts(lmap.ignored_by_kind())})",
        f"  skipped     {len(lmap.skipped)} roads lanelet2 rejected"
        + (f" (relation {', '.join(str(i) for i in lmap.skipped)})" if lmap.skipped else ""),
        f"  ragged      {len(rag)} drivable with bounds ending more than {RAGGED_END_GAP:g} m "
        "apart" + (f" (relation {', '.join(map(str, rag))})" if rag else ""),
        f"map areas     {len(lmap.areas)} ({counts(lmap.areas_by_kind())})",
        f"regulatory    {sum(lmap.regulatory.values())} ({counts(lmap.regulatory)})",
        f"ground truth  {'yes' if scn.truth is not None else 'no'}"
        + (f" ({len(scn.truth.tracks)} vehicles)" if scn.truth is not None else ""),
    ]
    return "\n".join(lines)


def cmd_info(args: argparse.Namespace) -> int:
    print(scenario_summary(args.scenario))
    return 0


def _load_for_localize(path: str | Path, ignore_yaw_guess: bool):
    from fgloc.io import load_scenario

    scn = load_scenario(path)
    if ignore_yaw_guess:
        scn.sensor.yaw_guess_deg = None
    return scn


def _print_result(res) -> None:
    doc = res.to_json()
    s = doc["sensor"]
    print(f"method {res.method}: {'converged' if res.converged else 'NOT CONVERGED'}, "
          f"{res.status} ({len(res.modes)} mode(s))")
    print(f"  E {s['x']:.3f}  N {s['y']:.3f}  z {s['z']:.3f}  ({res.crs})")
    print(
        f"  yaw {s['yaw_deg']:.3f} deg (true heading {doc['true_heading_deg']:.3f} deg)  "
        f"pitch {s['pitch_deg']:.3f}  roll {s['roll_deg']:.3f}"
    )
    print("  stage times: " + ", ".join(f"{k} {v:.2f} s" for k, v in res.timings.items()))
    for w in res.warnings:
        print(f"  warning: {w}")
    if not res.converged:
        print(
            "  WARNING: registration did not converge; see result.json diagnostics", file=sys.stderr
        )


def cmd_localize(args: argparse.Namespace) -> int:
    from fgloc.config import load_config
    from fgloc.outputs import write_localization
    from fgloc.pipeline import localize

    cfg = load_config(args.config)
    scn = _load_for_localize(args.scenario, args.ignore_yaw_guess)
    res = localize(scn, method=args.method, config=cfg)
    written = write_localization(args.out, scn, res)
    _print_result(res)
    print("wrote " + ", ".join(str(p) for p in written))
    if res.status == "ambiguous":
        tied = sum(bool(m["tied"]) for m in res.modes)
        why = next((w for w in res.warnings if "ambiguous pose" in w), None)
        if tied > 1 or why is None:
            why = (f"ambiguous pose: {tied} modes could not be told apart (result.json 'modes'; "
                   "the covariance covers them)")
        print(f"fgloc: warning: {why}", file=sys.stderr)   # one mode: not pinned (its reason)
        return EXIT_AMBIGUOUS
    return 0


def _truth_frame(gt_path: Path):
    """A local frame at the true sensor position of a ground_truth.json (its values are
    validated again by read_ground_truth)."""
    from fgloc.geo import LocalFrame

    try:
        doc = json.loads(gt_path.read_text(encoding="utf-8"))
        s = doc["sensor"]
        return LocalFrame.around(float(s["x"]), float(s["y"]), float(s["z"]), str(doc["crs"]))
    except (OSError, ValueError, KeyError, TypeError):
        return LocalFrame.around(0.0, 0.0)


def _scenario_als(scenario_dir: Path, sensor: SensorConfig, frame: LocalFrame
                  ) -> tuple[AlsCloud | None, LocalFrame]:
    """(ALS, its frame L) of the scenario directory that holds a ground truth, read as
    :func:`fgloc.load_scenario` reads it; (None, ``frame``) without ALS tiles there."""
    from fgloc.io.als import find_als_tiles, read_als
    from fgloc.io.scenario_dir import ALS_DIR, SENSOR_FILE

    als_dir = scenario_dir / ALS_DIR
    if not als_dir.is_dir():
        return None, frame
    return read_als(find_als_tiles(als_dir), sensor.approx_position, sensor.crs,
                    config_path=scenario_dir / SENSOR_FILE)


def evaluation_inputs(path: Path) -> tuple[Path | None, Path | None]:
    """(result.json, tracks.csv) to evaluate: a file of either kind, or an output directory."""
    if path.is_dir():
        res, trk = path / "result.json", path / "tracks.csv"
        found = (res if res.is_file() else None, trk if trk.is_file() else None)
        if found == (None, None):
            raise FglocError(f"{path}: neither result.json nor tracks.csv in this directory")
        return found
    if path.suffix.lower() == ".csv":
        return None, path
    return path, None


def cmd_track(args: argparse.Namespace) -> int:
    from fgloc.config import load_config
    from fgloc.io import load_scenario, write_tracks_csv
    from fgloc.outputs import staged_dir
    from fgloc.pipeline import track

    cfg = load_config(args.config)
    scn = load_scenario(args.scenario)
    run = track(scn, cfg, oracle_pose=args.oracle_pose, smoother=args.smoother)
    with staged_dir(args.out) as tmp:
        write_tracks_csv(tmp / "tracks.csv", run.tracks, scn.frame)
    n_states = sum(len(t) for t in run.tracks.tracks)
    placed = "ground-truth pose (oracle)" if args.oracle_pose else "T_coarse"
    smoothed = "" if args.smoother == "none" else f", {args.smoother} smoother"
    relinked = len(run.tracks.diagnostics.get("relinked", []))
    others, why = run.tracks.left_out()
    print(f"{len(run.tracks)} tracks ({relinked} joined to a lost track), {n_states} states; "
          f"detections placed with {placed}{smoothed}; {others} tracks of other road users "
          f"left out {why}")
    print("  stage times: " + ", ".join(f"{k} {v:.2f} s" for k, v in run.timings.items()))
    print(f"wrote {Path(args.out) / 'tracks.csv'}")
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    from fgloc.evaluation.pose import pose_error
    from fgloc.evaluation.tracking import evaluate_tracks, visible_states
    from fgloc.geo import same_crs
    from fgloc.io import read_ground_truth, read_sensor_toml, read_tracks_csv
    from fgloc.result import read_result_json
    from fgloc.scenario import SensorConfig

    gt_path = Path(args.ground_truth)
    result_path, tracks_path = evaluation_inputs(Path(args.result))
    frame = _truth_frame(gt_path)
    truth = read_ground_truth(gt_path, frame)
    out: dict = {}
    if result_path is not None:
        saved = read_result_json(result_path)
        if not same_crs(truth.crs, saved.crs):
            raise FglocError(f"{gt_path}: CRS {truth.crs} differs from the result's {saved.crs}")
        err = pose_error(frame.pose_to_local(saved.T_utm), truth.sensor_pose)
        out.update(method=saved.method, converged=saved.converged, status=saved.status,
                   pose=err.to_json())
        if not args.json:
            print(f"method {saved.method}: {saved.status}"
                  f"{'' if saved.converged else ' (NOT CONVERGED)'}")
            print(err.table())
    if tracks_path is not None:
        toml = gt_path.parent / "sensor.toml"
        sensor = read_sensor_toml(toml) if toml.is_file() else SensorConfig((0.0, 0.0))
        als, frame = _scenario_als(gt_path.parent, sensor, frame) if toml.is_file() else (
            None, frame)
        truth = read_ground_truth(gt_path, frame)
        metrics = evaluate_tracks(
            read_tracks_csv(tracks_path, frame), truth,
            visible=visible_states(truth, sensor.hfov_deg, sensor.max_range, als))
        out["tracking"] = metrics.to_json()
        if not args.json:
            print(("\n" if result_path is not None else "") + metrics.table())
    if args.json:
        print(json.dumps(out))
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from fgloc.evaluation.pose import pose_error
    from fgloc.io import load_scenario, write_scenario
    from fgloc.outputs import write_localization
    from fgloc.pipeline import localize
    from fgloc.sim import simulate

    if EXAMPLE_DIR.is_dir():
        src = EXAMPLE_DIR
    else:  # installed without the repository's data/: make the same scenario
        src = Path(tempfile.mkdtemp(prefix="fgloc-demo-")) / "example"
        write_scenario(simulate("intersection", 1, duration=30.0), src)
    print(scenario_summary(src))
    scn = load_scenario(src)
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="fgloc-demo-out-"))
    print()
    res = localize(scn, method=args.method)
    write_localization(out, scn, res)
    _print_result(res)
    if scn.truth is not None:
        print("\nerror against ground truth (paper Table I row + vertical):")
        print(pose_error(res.T_local, scn.truth.sensor_pose).table())
    print(f"\noutputs in {out}")
    return 0


def cmd_import_rosbag(args: argparse.Namespace) -> int:
    from fgloc.io.rosbag import import_rosbag

    radar, written = import_rosbag(
        args.bag, args.topic, args.out, als=args.als or (), map_file=args.map,
        sensor=args.sensor, ground_truth=args.ground_truth, doppler_field=args.doppler_field,
        negate_doppler=args.negate_doppler, msg_defs=args.msg_def or (),
    )
    n_frames = len(np.unique(radar.frame_ids()))
    print(f"{len(radar):,} detections in {n_frames:,} frames over {radar.duration:.1f} s from "
          f"{args.topic}")
    print(f"wrote {', '.join(str(Path(args.out) / n) for n in written)}")
    missing = [n for n, flag in (("als/", "--als"), ("map.osm", "--map"),
                                 ("sensor.toml", "--sensor"))
               if not any(w.startswith(n) for w in written)
               and not (Path(args.out) / n).exists()]
    if missing:
        print(f"still needed for a scenario: {', '.join(missing)} (copy them into {args.out} "
              "or pass --als / --map / --sensor); then check it with `fgloc info`")
    return 0


def cmd_batch(args: argparse.Namespace) -> int:
    from fgloc.batch import aggregate_table, make_engine, read_manifest, run_batch

    manifest = read_manifest(args.manifest)
    engine = make_engine(args.engine, args.workers, args.scheduler)
    try:
        report = run_batch(manifest, args.out, engine, progress=None if args.quiet else sys.stderr)
    except KeyboardInterrupt:
        print("fgloc: batch interrupted; run the same command again to resume", file=sys.stderr)
        return 130
    print(aggregate_table(report.aggregate))
    print(f"{len(report.records)} jobs: {report.skipped} already done, {report.ran} run now, "
          f"{report.failed} failed")
    for r in report.records:
        if r.get("status") != "ok":
            print(f"  FAILED {r['job']}: {r.get('error', '')}")
    print(f"wrote {Path(args.out) / 'summary.csv'}, {Path(args.out) / 'aggregate.csv'}")
    return 1 if report.failed else 0


def cmd_config(args: argparse.Namespace) -> int:
    from fgloc.config import dump_config, load_config

    print(dump_config(load_config(args.config)), end="")
    return 0


# --------------------------------------------------------------------------------------------
# parser
# --------------------------------------------------------------------------------------------
def _scenario_command(sub, name: str, help_text: str) -> argparse.ArgumentParser:
    """A subcommand that reads SCENARIO, writes into --out DIR and takes --config."""
    s = sub.add_parser(name, help=help_text)
    s.add_argument("scenario")
    s.add_argument("--out", required=True, help="output directory")
    s.add_argument("--config", default=None, help="fgloc config TOML (default: built-in defaults)")
    return s


def build_parser() -> argparse.ArgumentParser:
    from fgloc.pipeline import METHODS
    from fgloc.smoothing import SMOOTHERS

    p = argparse.ArgumentParser(prog="fgloc", description=__doc__.split("\n")[0])
    p.add_argument("-q", "--quiet", action="store_true", help="no progress messages")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("simulate", help="write a simulated scenario with ground truth")
    where = s.add_mutually_exclusive_group(required=True)
    where.add_argument("--case", choices=["intersection", "tjunction", "curve", "straight"],
                       help="a synthetic layout")
    where.add_argument("--map", default=None,
                       help="a real Lanelet2 map (.osm): the sensor beside one of its junctions")
    s.add_argument("--site", default=None, metavar="LAT,LON",
                   help="with --map: take the junction nearest to this WGS84 point "
                   "(default: a random one of the largest, from --seed)")
    s.add_argument("--seed", type=int, default=1)
    s.add_argument("--duration", type=float, default=60.0, help="seconds (default 60)")
    s.add_argument(
        "--vehicles", type=int, default=None, help="vehicle count (default: from duration)"
    )
    s.add_argument("--radar-format", choices=["csv", "npz"], default="csv")
    s.add_argument(
        "--sim-config", default=None, help="simulator settings TOML (fgloc.sim.SimConfig)"
    )
    s.add_argument("--out", required=True)
    s.set_defaults(fn=cmd_simulate)

    s = sub.add_parser("info", help="summarize and validate a scenario directory")
    s.add_argument("scenario")
    s.set_defaults(fn=cmd_info)

    s = _scenario_command(sub, "localize", "localize the sensor of a scenario")
    s.add_argument("--method", choices=sorted(METHODS), default="icp")
    s.add_argument(
        "--ignore-yaw-guess",
        action="store_true",
        help="ignore sensor.toml's yaw_guess_deg (global yaw search)",
    )
    s.set_defaults(fn=cmd_localize)

    s = _scenario_command(sub, "track", "track the vehicles (GP-EOT filter), write tracks.csv")
    s.add_argument(
        "--oracle-pose",
        action="store_true",
        help="place detections with the ground-truth pose (tracking alone, paper V-A)",
    )
    s.add_argument(
        "--smoother",
        choices=SMOOTHERS,
        default="none",
        help="refine the filter's tracks: fixed-lag (online, [smoothing] lag) or batch "
        "(offline, whole tracks); default none",
    )
    s.set_defaults(fn=cmd_track)

    s = sub.add_parser(
        "evaluate", help="compare a result.json and/or tracks.csv with a ground_truth.json"
    )
    s.add_argument("result", help="result.json, tracks.csv, or an output directory with them")
    s.add_argument("ground_truth")
    s.add_argument("--json", action="store_true", help="machine-readable output")
    s.set_defaults(fn=cmd_evaluate)

    s = sub.add_parser("demo", help="run the pipeline on the built-in example and print errors")
    s.add_argument("--out", default=None, help="output directory (default: a temporary one)")
    s.add_argument("--method", choices=sorted(METHODS), default="filter-sicp")
    s.set_defaults(fn=cmd_demo)

    s = sub.add_parser("config", help="print the configuration with every default")
    s.add_argument("--dump", action="store_true", help="(default action) print the full config")
    s.add_argument("--config", default=None, help="a config TOML to validate and print merged")
    s.set_defaults(fn=cmd_config)

    s = sub.add_parser(
        "batch", help="localize many scenarios with several methods (resumable; docs/batch.md)"
    )
    s.add_argument("manifest", help="batch manifest TOML (scenarios, methods, config)")
    s.add_argument("--out", required=True, help="output directory (re-run to resume)")
    s.add_argument("--workers", type=int, default=max(1, (os.cpu_count() or 2) // 2),
                   help="parallel jobs (default: half the CPU cores)")
    s.add_argument("--engine", choices=["local", "dask"], default="local",
                   help="local process pool (default) or dask.distributed")
    s.add_argument("--scheduler", default=None,
                   help="dask scheduler address (default: a local dask cluster)")
    s.set_defaults(fn=cmd_batch)

    s = sub.add_parser("import", help="make a scenario from recorded data (docs/cli.md)")
    kinds = s.add_subparsers(dest="kind", required=True)
    s = kinds.add_parser("rosbag", help="radar detections from a ROS 2 bag (MCAP or sqlite3)")
    s.add_argument("bag", help="bag directory (with metadata.yaml), .mcap or .db3 file")
    s.add_argument("--topic", required=True, help="PointCloud2 or detection-list topic")
    s.add_argument("--out", required=True, help="scenario directory to write")
    s.add_argument("--als", nargs="+", default=None, metavar="PATH",
                   help="ALS tiles (.las/.laz files or directories) copied into OUT/als/")
    s.add_argument("--map", default=None, help="Lanelet2 map copied to OUT/map.osm")
    s.add_argument("--sensor", default=None, help="sensor.toml copied (validated) into OUT")
    s.add_argument("--ground-truth", default=None, help="ground_truth.json copied into OUT")
    s.add_argument("--doppler-field", default=None,
                   help="PointCloud2 range-rate field name (default: found by name)")
    s.add_argument("--negate-doppler", action="store_true",
                   help="the driver's range rate is positive towards the sensor")
    s.add_argument("--msg-def", nargs="+", default=None, metavar="MSG",
                   help="message definitions .../<package>/msg/<Name>.msg for bags without them")
    s.set_defaults(fn=cmd_import_rosbag)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.WARNING if args.quiet else logging.INFO,
        format="[fgloc] %(message)s",
        stream=sys.stderr,
    )
    fn: Callable[[argparse.Namespace], int] = args.fn
    try:
        return fn(args)
    except FglocError as exc:
        print(f"fgloc: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
