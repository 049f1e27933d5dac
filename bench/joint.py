"""``--method joint`` against ``--method filter-sicp`` on the same runs (issue 7 figures).

Per case and seed the scenario is simulated, the coarse pose and the filter's tracks are
computed once, and both fine stages run on them: filter-sicp (``register_tracks``) and joint
(``joint_from_tracks``, started from that filter-sicp result). Printed per run: 2D and yaw
error of both, joint's NEES of (x, y, yaw) against its 3x3 covariance, its standard
deviations, weak-direction flag and time; then the means.

    OMP_NUM_THREADS=1 python bench/joint.py accuracy --seeds 1 2 3 4 5
    OMP_NUM_THREADS=1 python bench/joint.py straight --seeds 1 2 3
    OMP_NUM_THREADS=1 python bench/joint.py timing --duration 120
    OMP_NUM_THREADS=1 python bench/joint.py decompose --seeds 1 2 3 4 5
    OMP_NUM_THREADS=1 python bench/joint.py accuracy --seeds 1 2 3 \
        --sim "radar.sigma_azimuth_deg=0.4;radar.corner_fraction=0.1"

``--sim`` changes the simulator's settings (``section.field=value`` of
:class:`fgloc.sim.config.SimConfig`, numbers or comma-separated tuples of numbers, ``;``
between them): the robustness runs of docs/benchmarks.md (the methods' settings are not
tuned to the simulator's). "accuracy" and "straight" use the sensor.toml yaw guess; "timing"
reports the joint stage's split into Python callbacks and the rest. "decompose" splits the
joint's error into what the filter's tracks bring and what remains with exact tracks: besides
filter-sicp and the joint it runs the joint with the track states held (``refine_tracks =
false``) on the filter's tracks, on them with each step's centre error across the vehicle
removed ("truth_lateral"; "truth_lateral_mean": only its mean over the steps of one track that
measured one vehicle; "truth_lateral_within": only the deviations about that mean), and with
each step's centre, yaw, speed and yaw rate replaced by the simulator's truth
("truth_kinematics"; the contours stay the filter's), a step's truth being that of the vehicle
most of its detections came from (the simulator's source); the truth enters in the tracks'
frame C, mapped with the coarse pose as the detections are (so the coarse pose's own error
stays in every variant). The data-efficiency
sweep (error against the number of trajectories, every method) is bench/accuracy.py's
``--efficiency-*`` part.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from fgloc.coarse import target_and_coarse
from fgloc.config import Config, from_dict, load_config, to_dict, tomllib  # tomllib / tomli
from fgloc.evaluation.pose import pose_error_vector
from fgloc.geo import wrap_angle
from fgloc.progress import Timer
from fgloc.registration.fine import register_tracks
from fgloc.registration.joint import joint_from_tracks
from fgloc.result import LocalizationResult
from fgloc.scenario import TrackTruth
from fgloc.sim import simulate, simulate_detailed
from fgloc.sim.config import SimConfig
from fgloc.smoothing.run import smooth_tracks
from fgloc.tracking import track_scenario
from fgloc.tracks import YAW, YAWRATE, TrackSet, V, X, Y


def score(res: LocalizationResult, truth: np.ndarray, seconds: float) -> dict:
    e = pose_error_vector(res.T_local, truth)
    row = {"d2d": float(np.hypot(e[0], e[1])), "dyaw_deg": float(np.rad2deg(abs(e[2]))),
           "time_s": seconds, "converged": bool(res.converged), "nees": None}
    if res.covariance is not None:
        cov = np.asarray(res.covariance)
        row["nees"] = float(e @ np.linalg.solve(cov, e))
        row["sd_x"], row["sd_y"] = float(np.sqrt(cov[0, 0])), float(np.sqrt(cov[1, 1]))
        row["sd_yaw_deg"] = float(np.rad2deg(np.sqrt(cov[2, 2])))
    if res.covariance is not None and "joint" in res.diagnostics:  # no report from filter-sicp
        deg = res.diagnostics["joint"]["degeneracy"]
        row["weak"] = bool(deg["weakly_observed"])
        row["weak_std_m"] = max([d["std_m"] for d in deg["weak_directions"]], default=0.0)
        row["joint_timing"] = res.diagnostics["joint"]["timing_s"]
    return row


def sim_config(spec: str | None) -> SimConfig:
    """The default SimConfig with the ``section.field=value;...`` changes of ``spec`` (values:
    a TOML value, comma-separated ones for a tuple field), checked like a config file
    (:func:`fgloc.config.from_dict`: an unknown field or a wrong type is an InputError naming
    it); ValueError names an item that is not ``section.field=value`` or not a TOML value."""
    data = to_dict(SimConfig())
    for item in filter(None, (spec or "").split(";")):
        key, _, value = item.partition("=")
        section, _, name = key.strip().partition(".")
        table = data.get(section)
        if not isinstance(table, dict) or not name:
            raise ValueError(f"--sim {item!r}: expected section.field=value of a simulator "
                             f"section ({', '.join(data)})")
        text = f"[{value}]" if isinstance(table.get(name), list) else value
        try:
            table[name] = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError as exc:
            raise ValueError(f"--sim {item!r}: {value.strip()!r} is not a value") from exc
    return from_dict(SimConfig, data, None)


def prepared(case: str, seed: int, duration: float, cfg: Config, sim: SimConfig | None = None):
    return stages_of(simulate(case, seed, duration=duration, config=sim), cfg)


def stages_of(scn, cfg: Config):
    """``(scn, target, coarse, tracks)``: the scenario with its target cloud, coarse pose and
    the filter's tracks."""
    target, coarse = target_and_coarse(scn, cfg, Timer())
    return scn, target, coarse, track_scenario(scn, coarse.T_coarse, cfg.tracking)


def both(scn, target, coarse, tracks, cfg: Config) -> tuple[dict, dict, LocalizationResult]:
    """Scores of filter-sicp and of the joint started from it (its time includes the
    ``[joint] smoother`` smoothing), and the filter-sicp result."""
    truth = scn.truth.sensor_pose
    t0 = time.perf_counter()
    fs = register_tracks(scn, cfg, target, coarse, tracks, Timer(), method="filter-sicp")
    t1 = time.perf_counter()
    smoothed = (None if cfg.joint.smoother == "none" else
                smooth_tracks(scn, tracks, coarse.T_coarse, cfg.joint.smoother, cfg))
    jt = joint_from_tracks(scn, cfg, target, coarse, tracks, Timer(), start=fs,
                           smoothed=smoothed)
    t2 = time.perf_counter()
    return score(fs, truth, t1 - t0), score(jt, truth, t2 - t1), fs


def accuracy(args, cfg: Config) -> list[dict]:
    rows = []
    print(f"{'case':<13}{'seed':>4}{'tracks':>7} | {'f-sicp 2D':>9}{'yaw':>7} | {'joint 2D':>9}"
          f"{'yaw':>7}{'sd x':>7}{'sd y':>7}{'sd yaw':>7}{'NEES':>7}{'weak':>5}{'t s':>6}")
    for case in args.cases:
        for seed in args.seeds:
            scn, target, coarse, tracks = prepared(case, seed, args.duration, cfg, args.sim)
            f, j, _ = both(scn, target, coarse, tracks, cfg)
            rows.append({"case": case, "seed": seed, "tracks": len(tracks), "filter_sicp": f,
                         "joint": j})
            print(f"{case:<13}{seed:>4}{len(tracks):>7} | {f['d2d']:9.3f}{f['dyaw_deg']:7.3f} | "
                  f"{j['d2d']:9.3f}{j['dyaw_deg']:7.3f}{j.get('sd_x', np.nan):7.3f}"
                  f"{j.get('sd_y', np.nan):7.3f}{j.get('sd_yaw_deg', np.nan):7.3f}"
                  f"{j['nees'] if j['nees'] is not None else np.nan:7.2f}"
                  f"{'yes' if j.get('weak') else 'no':>5}{j['time_s']:6.1f}", flush=True)
    for key in ("filter_sicp", "joint"):
        d2d = np.mean([r[key]["d2d"] for r in rows])
        yaw = np.mean([r[key]["dyaw_deg"] for r in rows])
        print(f"mean {key:<12} 2D {d2d:.3f} m  |dyaw| {yaw:.3f} deg")
    nees = [r["joint"]["nees"] for r in rows if r["joint"]["nees"] is not None]
    print(f"joint NEES mean {np.mean(nees):.2f} (median {np.median(nees):.2f}, n={len(nees)})")
    return rows


def straight(args, cfg: Config) -> list[dict]:
    rows = []
    for seed in args.seeds:
        scn, target, coarse, tracks = prepared("straight", seed, args.duration, cfg, args.sim)
        f, j, _ = both(scn, target, coarse, tracks, cfg)
        rows.append({"case": "straight", "seed": seed, "filter_sicp": f, "joint": j})
        print(f"straight {seed}: f-sicp 2D {f['d2d']:.3f} | joint 2D {j['d2d']:.3f} yaw "
              f"{j['dyaw_deg']:.3f} weak {j.get('weak')} weakest std {j.get('weak_std_m', 0):.2f} m"
              f" sd x/y {j.get('sd_x', np.nan):.2f}/{j.get('sd_y', np.nan):.2f} NEES "
              f"{j['nees'] if j['nees'] is not None else np.nan:.2f}", flush=True)
    return rows


def timing(args, cfg: Config) -> list[dict]:
    scn, target, coarse, tracks = prepared("intersection", args.seeds[0], args.duration, cfg,
                                           args.sim)
    f, j, _ = both(scn, target, coarse, tracks, cfg)
    print(f"intersection seed {args.seeds[0]}, {args.duration:.0f} s, {len(tracks)} tracks: "
          f"joint stage {j['time_s']:.1f} s (incl. LaneLines and the result), 2D {j['d2d']:.3f} m")
    print(json.dumps(j.get("joint_timing"), indent=1))
    return [{"tracks": len(tracks), "filter_sicp": f, "joint": j}]


def truth_in_track_frame(scn, coarse, tracks: TrackSet) -> list[TrackTruth]:
    """The true vehicles mapped from L into the tracks' frame C by ``T_coarse T_true^-1`` at
    the median height (in L) of the tracked detections: they carry the coarse pose's error,
    its tilt's sideways shift included, as the detections placed with it do."""
    T_true = scn.truth.sensor_pose
    M = coarse.T_coarse @ np.linalg.inv(T_true)
    used = np.concatenate([tr.det_index for tr in tracks.tracks])
    z = float(np.median(scn.radar.xyz[used] @ T_true[2, :3] + T_true[2, 3]))
    yaw = np.arctan2(M[1, 0], M[0, 0])
    out = []
    for tr in scn.truth.tracks:
        s = np.array(tr.states, dtype=float)
        xyz1 = np.column_stack([s[:, 1:3], np.full(len(s), z), np.ones(len(s))])
        s[:, 1:3] = (xyz1 @ M.T)[:, :2]
        s[:, 3] += yaw
        out.append(dataclasses.replace(tr, states=s))
    return out


def step_vehicles(tracks: TrackSet, source: np.ndarray) -> list[np.ndarray]:
    """Per track, the true vehicle id (-1 none) each step measured: the most common simulator
    source among the step's detections, carried over (forward, then backward) to steps without
    vehicle detections."""
    out = []
    for tr in tracks.tracks:
        vid = np.full(len(tr), -1, np.int64)
        src = source[tr.det_index]
        ok = src >= 0
        pairs, counts = np.unique(np.column_stack([tr.det_step[ok], src[ok]]), axis=0,
                                  return_counts=True)
        # per step the most common source (ties: the smaller id)
        order = np.lexsort((pairs[:, 1], -counts, pairs[:, 0]))
        best = order[np.r_[True, np.diff(pairs[order, 0]) != 0]] if len(order) else order
        vid[pairs[best, 0]] = pairs[best, 1]
        have = np.flatnonzero(vid >= 0)
        if have.size:
            fill = np.maximum.accumulate(np.where(vid >= 0, np.arange(len(tr)), -1))
            vid = np.where(fill >= 0, vid[np.maximum(fill, 0)], vid[have[0]])
        out.append(vid)
    return out


def with_truth(tracks: TrackSet, truth: list[TrackTruth], vehicles: list[np.ndarray],
               part: str) -> tuple[TrackSet, float]:
    """The tracks (frame of ``truth``) with every step inside its measured vehicle's truth
    span (``vehicles``: :func:`step_vehicles`) corrected: "lateral" removes the centre error's
    component across the track's heading, "lateral_mean" only its mean over the steps that
    measured one vehicle, "lateral_within" only the deviations about that mean; "kinematics"
    replaces centre, yaw, speed and yaw rate by the truth. Returns them and the share of steps
    corrected."""
    by_id = {tr.id: np.asarray(tr.states, dtype=float) for tr in truth}
    out, n = [], 0
    for tr, vid in zip(tracks.tracks, vehicles):
        st = tr.states.copy()
        for v in np.unique(vid[vid >= 0]):
            s = by_id[int(v)]
            k = np.flatnonzero((vid == v) & (tr.t >= s[0, 0]) & (tr.t <= s[-1, 0]))
            x, y, yaw, speed, yawrate = (np.interp(tr.t[k], s[:, 0], c) for c in (
                s[:, 1], s[:, 2], np.unwrap(s[:, 3]), s[:, 4], s[:, 5]))
            if part.startswith("lateral"):
                left = np.column_stack([-np.sin(st[k, YAW]), np.cos(st[k, YAW])])
                across = np.einsum("ki,ki->k", st[k][:, [X, Y]] - np.column_stack([x, y]), left)
                if part == "lateral_mean":
                    across = np.full_like(across, across.mean())
                elif part == "lateral_within":
                    across = across - across.mean()
                st[k, X] -= across * left[:, 0]
                st[k, Y] -= across * left[:, 1]
            else:
                st[k, X], st[k, Y], st[k, V], st[k, YAWRATE] = x, y, speed, yawrate
                st[k, YAW] += wrap_angle(yaw - st[k, YAW])
            n += len(k)
        out.append(dataclasses.replace(tr, states=st))
    total = sum(len(tr) for tr in tracks.tracks)
    return dataclasses.replace(tracks, tracks=out), n / max(total, 1)


def decompose(args, cfg: Config) -> list[dict]:
    held = dataclasses.replace(cfg, joint=dataclasses.replace(cfg.joint, refine_tracks=False))
    parts = ("lateral_mean", "lateral_within", "lateral", "kinematics")
    names = ("filter_sicp", "joint", "held", *(f"truth_{p}" for p in parts))
    print(f"{'case':<13}{'seed':>4} | " + " | ".join(f"{n.replace('truth_', '= '):>16}"
                                                  for n in names)
          + " | steps corrected")
    print(f"{'':17} | " + " | ".join(f"{'2D m / yaw deg':>16}" for _ in names) + " |")
    rows = []
    for case in args.cases:
        for seed in args.seeds:
            sim = simulate_detailed(case, seed, duration=args.duration, config=args.sim)
            scn, target, coarse, tracks = stages_of(sim.scenario, cfg)
            truth = scn.truth.sensor_pose
            row: dict = {"case": case, "seed": seed}
            row["filter_sicp"], row["joint"], fs = both(scn, target, coarse, tracks, cfg)
            truth_c = truth_in_track_frame(scn, coarse, tracks)
            vehicles = step_vehicles(tracks, sim.source)
            variants = {"held": (tracks, 0.0)} | {
                f"truth_{p}": with_truth(tracks, truth_c, vehicles, p) for p in parts}
            for name, (trk, _) in variants.items():
                t0 = time.perf_counter()
                res = joint_from_tracks(scn, held, target, coarse, trk, Timer(), start=fs)
                row[name] = score(res, truth, time.perf_counter() - t0)
            row["corrected_share"] = variants["truth_kinematics"][1]
            rows.append(row)
            print(f"{case:<13}{seed:>4} | " + " | ".join(
                f"{row[n]['d2d']:8.3f} /{row[n]['dyaw_deg']:6.3f}" for n in names)
                + f" | {row['corrected_share']:.0%}", flush=True)
    base = [np.mean([r["filter_sicp"][k] for r in rows]) for k in ("d2d", "dyaw_deg")]
    for n in names:
        m = [np.mean([r[n][k] for r in rows]) for k in ("d2d", "dyaw_deg")]
        print(f"mean {n:<22} 2D {m[0]:.3f} m  |dyaw| {m[1]:.3f} deg  (x filter-sicp: "
              f"{m[0] / base[0]:.2f} / {m[1] / base[1]:.2f})")
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("part", choices=["accuracy", "straight", "timing", "decompose"])
    ap.add_argument("--cases", nargs="+", default=["intersection", "tjunction"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3, 4, 5])
    ap.add_argument("--duration", type=float, default=None,
                    help="scenario length in s (default 60; timing: 120)")
    ap.add_argument("--json", default=None, help="also write all rows to this JSON file")
    ap.add_argument("--config", default=None, help="fgloc config TOML (default: all defaults)")
    ap.add_argument("--sim", default=None,
                    help='simulator changes, e.g. "radar.sigma_azimuth_deg=0.4;'
                         'traffic.class_mix=0.4,0.5,0.1"')
    args = ap.parse_args()
    args.sim = sim_config(args.sim)          # checked before anything runs
    if args.duration is None:
        args.duration = 120.0 if args.part == "timing" else 60.0
    cfg = load_config(args.config)
    parts = {"accuracy": accuracy, "straight": straight, "timing": timing,
             "decompose": decompose}
    rows = parts[args.part](args, cfg)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
