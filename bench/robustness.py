"""Robustness matrix: tracking (oracle pose; filter and batch smoother) and localization
(filter-sicp, joint) under simulator settings our defaults do not make (issue 20).

Settings (``SETTINGS``; each a change of :class:`fgloc.sim.config.SimConfig`): default;
platoons of 2-4 vehicles at 0.8-1.2 s headway; 15 % trucks 9-12 m long; low returns (0.2-1.5 m
above the road); far and sparse returns (25 per vehicle and frame at 20 m falling to 4 at
150 m); an oblique 70-80 deg junction with a large junction box; 10 vehicles per minute;
30 % of the returns at the wheels with their micro-Doppler (0 to twice the body's speed along
the heading: "wheel-doppler"); 4 cyclists per minute riding 1.4 m right of the lane centres
besides the motor vehicles ("cyclists": the tracking figures count the motor vehicles only, a
cyclist's track that fgloc keeps is a false track); a tenth of the returns on the roofs,
inside the footprints ("roof-returns"; the independent generator's share); multipath ghosts
(16 buildings 2 m or more from the road edge, each facade that faces the sensor mirroring 30 %
of the vehicles' returns it can: "ghosts", 1-37 % as many ghosts as vehicle returns over the
first four seeds, the intersections most); pairs of vehicles side by side in adjacent lanes,
0-0.5 s apart, on roads of two 3 m lanes per direction ("abreast"); a third of the vehicles
standing 3-15 s short of the junction, their returns static, and the vehicles that come up
behind them queueing ("stops"); and all of these but
the micro-Doppler, the cyclists, the roof returns, the ghosts, the pairs abreast and the stops
at once ("combined", with returns at every visible corner and at the wheels and more
clutter).
Seeds: odd ones simulate an intersection, even ones a T-junction.

Per run: tracks per eligible true vehicle (all tracks, false ones included), tracks covering
two vehicles (a track whose contour covers at least half of the footprints of two true
vehicles at once for 10 steps or more), truck length error (|median contour extent along the
heading - true length| of the tracks following a truck, m) and centre bias towards the sensor
(m, > 0: towards it), per-track centre RMS (the paper's average RMS), yaw error and IoU of the
filter and the batch smoother (:func:`fgloc.evaluation.tracking.evaluate_tracks`, visibility
from the true pose, the FOV and the ALS's buildings:
:func:`fgloc.evaluation.tracking.visible_states`), and the 2D / yaw
error of filter-sicp and joint (:func:`fgloc.localize_many`), whether each flagged itself
(ambiguous or a weakly observed direction) and the 2D error of the runs that did not. The
table gives per setting the mean over the seeds and the worst seed (the number of flagged
runs).

    OMP_NUM_THREADS=1 python -m bench.robustness            # seeds 1-5, the full matrix
    OMP_NUM_THREADS=1 python -m bench.robustness --quick    # seeds 1-2, 30 s, a smoke set

docs/benchmarks.md's table comes from ``python -m bench.report --only robustness``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from bench.accuracy import weak_flag
from bench.report_section import provenance
from bench.sparse import truth_distance
from fgloc import localize_many, track
from fgloc.config import Config, from_dict, load_config
from fgloc.evaluation.pose import pose_error
from fgloc.evaluation.tracking import (
    TrackingMetrics,
    box_intersection_area,
    contour_polygons,
    evaluate_tracks,
    visible_states,
)
from fgloc.scenario import Scenario
from fgloc.sim import simulate_detailed
from fgloc.sim.config import SimConfig
from fgloc.smoothing.run import smooth_tracks
from fgloc.tracks import N_KIN, YAW, TrackSet

_PLATOONS = {"platoon_size": [2, 4], "platoon_headway": [0.8, 1.2], "headway": 0.3}
_TRUCKS = {"class_mix": [0.65, 0.2, 0.15], "truck_length": [9.0, 12.0]}
_SPARSE = {"returns_at_reference": 25.0, "reference_range": 20.0, "returns_exponent": 0.91,
           "range_half_detection": 0.95}
_OBLIQUE = {"crossing_angle_deg": [70.0, 80.0], "junction_margin": 16.0}
SETTINGS: dict[str, dict] = {
    "default": {},
    "platoons": {"traffic": _PLATOONS},
    "trucks": {"traffic": _TRUCKS},
    "low-returns": {"radar": {"return_height": [0.2, 1.5]}},
    "far-sparse": {"radar": _SPARSE},
    "oblique": {"road": _OBLIQUE},
    "10-per-min": {"traffic": {"arrival_interval": 6.0}},
    "wheel-doppler": {"radar": {"wheel_fraction": 0.3, "wheel_radius": 0.35}},
    "cyclists": {"traffic": {"cyclists_per_minute": 4.0}},
    "roof-returns": {"radar": {"roof_fraction": 0.1}},
    "ghosts": {"radar": {"ghost_fraction": 0.3},
               "als": {"buildings": 16, "building_clearance": 2.0}},
    "abreast": {"road": {"lane_width": 3.0, "lanes_per_direction": [2]},
                "traffic": {"platoon_size": [2, 2], "platoon_headway": [0.0, 0.5],
                            "platoon_abreast": True}},
    "stops": {"traffic": {"stop_share": 0.3}},
    "combined": {
        "traffic": {**_PLATOONS, **_TRUCKS, "class_mix": [0.75, 0.15, 0.1]},
        "radar": {**_SPARSE, "return_height": [0.2, 1.5], "corners": "visible",
                  "corner_fraction": 0.35, "wheel_fraction": 0.25, "clutter_per_frame": 400.0},
        "road": _OBLIQUE,
    },
}
METHODS = ("filter-sicp", "joint")
#: a true vehicle counts as a truck above this length (m)
TRUCK_LENGTH = 8.0
#: share of a vehicle's footprint a track contour must cover to count as covering it
COVER_SHARE = 0.5
#: steps a track must cover two vehicles at once to count as covering two
COVER_STEPS = 10
#: a flagged run holds the truth when a tied mode or its valley lies this close (m)
MODE_TOLERANCE = 0.5


@dataclass
class RunResult:
    """One (setting, seed): the figures of the module docstring (NaN where not defined)."""

    setting: str
    seed: int
    case: str
    vehicles: int
    figures: dict[str, float] = field(default_factory=dict)

    def row(self) -> dict:
        """The run as a JSON row: setting, seed, case, vehicles and every figure."""
        return {"setting": self.setting, "seed": self.seed, "case": self.case,
                "vehicles": self.vehicles, **self.figures}

    def line(self) -> str:
        """One progress line: setting, seed, case and every figure."""
        return f"{self.setting:<11} {self.seed:>2} {self.case:<12} " + " ".join(
            f"{k}={v:.3f}" for k, v in self.figures.items())


def sim_config(setting: str) -> SimConfig:
    return from_dict(SimConfig, SETTINGS[setting], None)


def _truth_at(tr, t: np.ndarray) -> np.ndarray:
    """(k, 3) x, y, yaw of a true vehicle at times t (inside its span)."""
    s = tr.states
    return np.column_stack([np.interp(t, s[:, 0], s[:, 1]), np.interp(t, s[:, 0], s[:, 2]),
                            np.interp(t, s[:, 0], np.unwrap(s[:, 3]))])


def covered_share(poly: np.ndarray, pose: np.ndarray, length: float,
                  width: float) -> np.ndarray:
    """(k,) share of a length x width footprint at poses (k, 3) [x, y, yaw] covered by the
    polygons (k, m, 2) (all in L)."""
    c, s = np.cos(pose[:, 2])[:, None], np.sin(pose[:, 2])[:, None]
    d = poly - pose[:, None, :2]
    local = np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)
    k = len(pose)
    inter = np.abs(box_intersection_area(local, np.full(k, length / 2), np.full(k, width / 2)))
    return inter / (length * width)


def tracks_covering_two(tracks: TrackSet, scn: Scenario) -> int:
    """Tracks whose contour covers >= COVER_SHARE of two true footprints at once for at least
    COVER_STEPS steps."""
    assert scn.truth is not None
    out = 0
    for tr in tracks.in_local().tracks:
        poly = contour_polygons(tr.states)
        reach = float(np.max(tr.states[:, N_KIN:]))
        covers = np.zeros(len(tr), dtype=int)
        for gt in scn.truth.tracks:
            m = (tr.t >= gt.states[0, 0]) & (tr.t <= gt.states[-1, 0])
            if not m.any():
                continue
            pose = _truth_at(gt, tr.t[m])
            near = np.hypot(*(pose[:, :2] - tr.states[m, :2]).T) < reach + gt.length / 2
            if not near.any():
                continue
            idx = np.flatnonzero(m)[near]
            share = covered_share(poly[idx], pose[near], gt.length, gt.width)
            covers[idx] += share >= COVER_SHARE
        out += int(np.sum(covers >= 2) >= COVER_STEPS)
    return out


def truck_figures(tracks: TrackSet, metrics: TrackingMetrics, scn: Scenario,
                  ) -> tuple[float, float]:
    """Mean |length error| (m) over the tracks following a truck (median contour extent
    along the heading against the true length) and their mean centre offset towards the
    sensor (m); NaN without trucks."""
    assert scn.truth is not None
    truth = {gt.id: gt for gt in scn.truth.tracks}
    by_id = {tr.id: tr for tr in tracks.in_local().tracks}
    sensor = scn.truth.sensor_pose[:2, 3]
    err, bias = [], []
    for row in metrics.rows:
        gt = truth.get(row.truth_id) if row.truth_id is not None else None
        if gt is None or gt.length < TRUCK_LENGTH:
            continue
        tr = by_id[row.track_id]
        poly = contour_polygons(tr.states)
        h = np.column_stack([np.cos(tr.states[:, YAW]), np.sin(tr.states[:, YAW])])
        proj = np.einsum("kmd,kd->km", poly, h)
        err.append(abs(float(np.median(np.ptp(proj, axis=1))) - gt.length))
        m = (tr.t >= gt.states[0, 0]) & (tr.t <= gt.states[-1, 0])
        pose = _truth_at(gt, tr.t[m])
        to_sensor = sensor - pose[:, :2]
        to_sensor /= np.linalg.norm(to_sensor, axis=1, keepdims=True)
        bias.append(float(np.mean(np.sum((tr.states[m, :2] - pose[:, :2]) * to_sensor,
                                         axis=1))))
    return (float(np.mean(err)) if err else math.nan, float(np.mean(bias)) if bias
            else math.nan)


def tracking_figures(scn: Scenario, cfg: Config) -> dict[str, float]:
    """The tracking figures of the module docstring for ``scn`` (with ground truth): the
    filter with the true pose and the batch smoother on its tracks, config ``cfg``."""
    assert scn.truth is not None
    run = track(scn, cfg, oracle_pose=True)
    smoothed = smooth_tracks(scn, run.tracks, run.T_placement, "batch", cfg)
    f: dict[str, float] = {}
    visible = visible_states(scn.truth, scn.sensor.hfov_deg, scn.sensor.max_range, scn.als)
    for name, ts in (("filter", run.tracks), ("batch", smoothed)):
        m = evaluate_tracks(ts, scn.truth, eta=cfg.tracking.eta, visible=visible)
        f[f"{name}.rms"] = m.centre_rms_track_mean
        f[f"{name}.yaw"] = m.yaw_error_deg
        f[f"{name}.iou"] = m.iou
        f[f"{name}.truck_len"], f[f"{name}.truck_bias"] = truck_figures(ts, m, scn)
        if name == "filter":
            f["tracks_per_vehicle"] = m.n_tracks / max(m.n_true, 1)
            f["false"] = m.false_tracks
            f["fragments"] = m.fragments
            f["missed"] = m.missed
            f["covering_two"] = tracks_covering_two(ts, scn)
    return f


def run_one(setting: str, seed: int, duration: float, cfg: Config,
            localization: bool) -> RunResult:
    case = "intersection" if seed % 2 else "tjunction"
    sim = simulate_detailed(case, seed, duration, config=sim_config(setting))
    scn = sim.scenario
    assert scn.truth is not None
    # the tracking figures are about the motor vehicles (a cyclist's track counts as false)
    motor = replace(scn.truth, tracks=[gt for gt, kind in zip(scn.truth.tracks,
                                                               sim.vehicle_class)
                                       if kind != "bicycle"])
    out = RunResult(setting, seed, case, len(motor.tracks),
                    tracking_figures(replace(scn, truth=motor), cfg))
    f = out.figures
    if localization:
        for meth, r in localize_many(scn, list(METHODS), cfg).items():
            e = pose_error(r.T_local, scn.truth.sensor_pose)
            f[f"{meth}.2d"], f[f"{meth}.yaw"] = e.d2d, e.dyaw_deg
            flagged = r.status == "ambiguous" or bool(weak_flag(r))
            f[f"{meth}.flagged"] = float(flagged)
            f[f"{meth}.2d_unflagged"] = math.nan if flagged else e.d2d
            f[f"{meth}.flagged_held"] = (float(truth_distance(r, scn.truth.sensor_pose)
                                               <= MODE_TOLERANCE) if flagged else math.nan)
    return out


#: table columns: (header, figure key, worst = max or min, format)
COLUMNS: list[tuple[str, str, Callable, str]] = [
    ("tracks/veh", "tracks_per_vehicle", max, "{:.2f}"),
    ("cover 2", "covering_two", max, "{:.1f}"),
    ("truck len err m", "filter.truck_len", max, "{:.2f}"),
    ("truck bias m", "filter.truck_bias", max, "{:.2f}"),
    ("filter RMS m", "filter.rms", max, "{:.3f}"),
    ("filter yaw deg", "filter.yaw", max, "{:.2f}"),
    ("filter IoU", "filter.iou", min, "{:.3f}"),
    ("batch len err m", "batch.truck_len", max, "{:.2f}"),
    ("batch RMS m", "batch.rms", max, "{:.3f}"),
    ("batch yaw deg", "batch.yaw", max, "{:.2f}"),
    ("batch IoU", "batch.iou", min, "{:.3f}"),
    ("filter-sicp 2D m", "filter-sicp.2d", max, "{:.3f}"),
    ("filter-sicp yaw deg", "filter-sicp.yaw", max, "{:.3f}"),
    ("filter-sicp flagged", "filter-sicp.flagged", sum, "{:.0f}"),
    ("filter-sicp flagged, truth held", "filter-sicp.flagged_held", sum, "{:.0f}"),
    ("filter-sicp 2D unflagged m", "filter-sicp.2d_unflagged", max, "{:.3f}"),
    ("joint 2D m", "joint.2d", max, "{:.3f}"),
    ("joint yaw deg", "joint.yaw", max, "{:.3f}"),
    ("joint flagged", "joint.flagged", sum, "{:.0f}"),
    ("joint flagged, truth held", "joint.flagged_held", sum, "{:.0f}"),
    ("joint 2D unflagged m", "joint.2d_unflagged", max, "{:.3f}"),
]
"""Columns: (header, figure, aggregate of the worst seed -- ``sum``: the cell is the count
over the seeds alone --, format). flagged = runs whose result says it is not sure: status
ambiguous or a weakly observed direction (``weak_flag``); truth held = flagged runs whose truth
lies within MODE_TOLERANCE of a place the result says the sensor may be (a tied mode or its
valley, :func:`bench.sparse.truth_distance`): honest, not confidently wrong; unflagged = the
2D error of the others."""


#: the track counts per run beside tracks per vehicle (bench/independent_tracking.py's table)
COUNT_COLUMNS: list[tuple[str, str, Callable, str]] = [
    ("false", "false", max, "{:.1f}"),
    ("fragments", "fragments", max, "{:.1f}"),
    ("missed", "missed", max, "{:.1f}"),
]


def table(results: list[RunResult], settings: list[str],
          columns: list[tuple[str, str, Callable, str]] = COLUMNS) -> list[str]:
    """Markdown table: per setting ``mean / worst seed`` of every column of ``columns`` that
    the results have (:data:`COLUMNS`)."""
    cols = [c for c in columns if any(c[1] in r.figures for r in results)]
    lines = ["| setting | runs | vehicles | " + " | ".join(c[0] for c in cols) + " |",
             "|---|---|---|" + "---|" * len(cols)]
    for s in settings:
        rs = [r for r in results if r.setting == s]
        if not rs:
            continue
        cells = []
        for _, key, worst, fmt in cols:
            v = np.array([r.figures.get(key, math.nan) for r in rs], dtype=float)
            v = v[np.isfinite(v)]
            if worst is sum:
                cells.append("-" if v.size == 0 else fmt.format(np.sum(v)))
            else:
                cells.append("-" if v.size == 0 else
                             f"{fmt.format(np.mean(v))} / {fmt.format(worst(v))}")
        n_veh = np.mean([r.vehicles for r in rs])
        lines.append(f"| {s} | {len(rs)} | {n_veh:.0f} | " + " | ".join(cells) + " |")
    return lines



def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="seeds 1-2, 30 s scenarios")
    ap.add_argument("--settings", nargs="+", default=list(SETTINGS), choices=list(SETTINGS))
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3, 4, 5])
    ap.add_argument("--duration", type=float, default=60.0, help="scenario length (s)")
    ap.add_argument("--no-localization", action="store_true",
                    help="tracking only (faster, while iterating on the tracker)")
    ap.add_argument("--config", default=None, help="fgloc config TOML (default: all defaults)")
    ap.add_argument("--json", default=None, help="also write every run's figures here")
    args = ap.parse_args()
    if args.quick:
        args.seeds, args.duration = [1, 2], 30.0
    cfg = load_config(args.config)
    t0 = time.perf_counter()
    results: list[RunResult] = []
    for setting in args.settings:
        for seed in args.seeds:
            r = run_one(setting, seed, args.duration, cfg, not args.no_localization)
            results.append(r)
            print(r.line(), flush=True)
            if args.json:
                Path(args.json).write_text(json.dumps([x.row() for x in results], indent=1))
    elapsed = time.perf_counter() - t0
    quick = " --quick" if args.quick else ""
    command = "OMP_NUM_THREADS=1 python -m bench.robustness" + quick
    extra = [a for a in sys.argv[1:] if a not in ("--quick",)]
    if extra:
        command += " " + " ".join(extra)
    head = [f"### Robustness matrix (`python -m bench.robustness{quick}`)",
            "", f"Command: `{command}`", "",
            f"{provenance()}, {args.duration:g} s scenarios, seeds {args.seeds} (odd: "
            f"intersection, even: T-junction), {elapsed:.0f} s in total. Cells: mean over the "
            "seeds / worst seed. "
            "Tracking with the true pose; truck figures over the tracks following a truck "
            "(> 8 m); cover 2 = tracks covering two vehicles at once."]
    text = "\n".join(head + [""] + table(results, args.settings))
    print("\n" + text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
