"""Cross-check of fgloc's GP-EOT tracker against pyrecest's FullSCGPTracker (issue 4).

Runs both star-convex GP trackers on the same single-vehicle simulator sequences and scores
them with fgloc.evaluate_tracking (centre RMS, yaw error, IoU of the 20-radius contour with the
true rectangle) plus wall time per frame. pyrecest is not a dependency of fgloc: run this in
the separate venv made by ``bench/pyrecest_env.sh``::

    bash bench/pyrecest_env.sh
    PYRECEST_BACKEND=numpy bench/.venv-pyrecest/bin/python -m bench.pyrecest_compare

What each tracker receives (identical detections, oracle pose)
--------------------------------------------------------------
* Sequence: ``simulate_detailed(case, seed, duration, vehicles=1)``; only the detections whose
  simulator source is the vehicle are kept (a perfect clustering: no clutter, no false alarms).
* fgloc: ``track_scenario`` on that vehicle-only scenario with the true sensor pose
  (C == L). It applies its own Doppler filter (|doppler| >= doppler_min), association gate,
  birth/confirmation, Doppler measurements and its cap of ``max_detections_per_update``
  (regular subsample) per update. Two configurations: the default (sensor-aware angles +
  Doppler) and ``plain`` without Doppler (positions only, angle from the centre: the same
  information and measurement model family as pyrecest's).
* pyrecest: the same frames and the same |doppler| >= doppler_min detections (x, y in L), the
  same regular subsample cap, all of them used (no gate: the association is perfect). It is
  started at fgloc's first track's birth time from fgloc's birth state and birth covariance
  (centre, yaw, speed, 20 contour radii; acceleration dropped), then predict + update per frame.
  Its states after the last frame with detections are cut, as fgloc cuts a track's
  unmeasured tail.

pyrecest settings (FullSCGPTracker, 2.4.2, numpy backend)
---------------------------------------------------------
state [x, y, yaw, v, yawrate, f_1..f_20] (velocities=True, CTRV-like Euler transition),
n_base_points = 20 at 2 pi i / 20 (the same angles as fgloc's radii, so f_i are fgloc's
radii), kernel (sigma^2, l) = (mean diag of fgloc's contour prior K, gp_length_rad),
joint initial covariance = fgloc's P0 (reordered), reference_extent = fgloc's prior mean
rectangle, extent_forgetting_rate = tau, process noise per step = white acceleration along the
heading (sigma_accel, no acceleration state) + white yaw acceleration (sigma_yaw_acc) +
position random walk (sigma_pos^2 dt), measurement noise per detection = range/azimuth noise
(sigma_range, sigma_azimuth_deg at the detection's 3D range) + sigma_contour^2 I, contour
measurements (scale_mean = 1, scale_variance = 0), unscented predict with fgloc's
(alpha, beta, kappa); the update is pyrecest's own linearized (EKF-type) batch update.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

os.environ.setdefault("PYRECEST_BACKEND", "numpy")

from factors.gp import ContourGP  # noqa: E402
from fgloc.evaluation.tracking import TrackingMetrics, evaluate_tracks  # noqa: E402
from fgloc.scenario import RadarData, Scenario  # noqa: E402
from fgloc.sim import simulate_detailed  # noqa: E402
from fgloc.tracking import TrackingConfig, kappa_labels, track_scenario  # noqa: E402
from fgloc.tracks import (  # noqa: E402
    N_CONTOUR,
    N_KIN,
    N_STATE,
    YAW,
    YAWRATE,
    A,
    Track,
    TrackSet,
    V,
    X,
    Y,
    contour_angles,
)

#: default sequences: (case, seed, what) -- single-vehicle simulator runs of 40 s
SEQUENCES = (
    ("intersection", 1, "car, straight"),
    ("intersection", 2, "van, straight"),
    ("intersection", 3, "truck 10.9 m, straight"),
    ("intersection", 5, "van, straight"),
    ("intersection", 6, "car, left turn"),
    ("intersection", 11, "truck 10.6 m, right turn"),
    ("curve", 1, "car, 93 deg curve"),
)
#: fgloc state index -> pyrecest kinematic index ([x, y, yaw, v, yawrate])
_PR_KIN = (X, Y, YAW, V, YAWRATE)


@dataclass
class Frames:
    """Vehicle-only dynamic detections per frame in L: times (F,), z/rng per frame."""

    t: np.ndarray
    z: list[np.ndarray]
    rng: list[np.ndarray]


@dataclass
class Result:
    name: str
    metrics: TrackingMetrics
    frames: int
    seconds: float

    @property
    def ms_per_frame(self) -> float:
        return 1e3 * self.seconds / max(self.frames, 1)


def vehicle_scenario(case: str, seed: int, duration: float) -> tuple[Scenario, str, float]:
    """Single-vehicle scenario with only that vehicle's detections; its class and length."""
    sim = simulate_detailed(case, seed, duration=duration, vehicles=1)
    scn = sim.scenario
    assert scn.truth is not None and len(scn.truth.tracks) == 1
    vid = scn.truth.tracks[0].id
    keep = sim.source == vid
    r = scn.radar
    radar = RadarData(r.t[keep], r.xyz[keep], r.doppler[keep],
                      None if r.rcs is None else r.rcs[keep],
                      None if r.frame is None else r.frame[keep])
    return (dataclasses.replace(scn, radar=radar), sim.vehicle_class[vid],
            float(scn.truth.tracks[0].length))


def vehicle_frames(scn: Scenario, doppler_min: float) -> Frames:
    """Per-frame detections in L exactly as fgloc's tracker sees them (frame grouping by
    RadarData.frame_ids, oracle pose, |doppler| >= doppler_min)."""
    T = scn.truth.sensor_pose
    r = scn.radar
    fid = r.frame_ids()
    order = np.argsort(fid, kind="stable")
    first = np.flatnonzero(np.concatenate([[True], np.diff(fid[order]) != 0]))
    bounds = np.append(first, len(order))
    p = r.xyz @ T[:3, :3].T + T[:3, 3]
    rng = np.linalg.norm(p - T[:3, 3], axis=1)
    dyn = np.abs(r.doppler) >= doppler_min
    z, rr = [], []
    for a, b in zip(bounds[:-1], bounds[1:]):
        idx = order[a:b]
        idx = idx[dyn[idx]]
        z.append(p[idx, :2])
        rr.append(rng[idx])
    return Frames(r.t[order[first]], z, rr)


def subsample(n: int, cap: int) -> np.ndarray:
    """fgloc's regular subsample of n detections down to at most cap."""
    if n <= cap:
        return np.arange(n)
    return np.linspace(0, n - 1, cap).round().astype(np.int64)


def run_fgloc(scn: Scenario, cfg: TrackingConfig, name: str) -> tuple[Result, TrackSet]:
    t0 = time.perf_counter()
    ts = track_scenario(scn, scn.truth.sensor_pose, cfg)
    sec = time.perf_counter() - t0
    frames = int(ts.diagnostics.get("frames", 0))
    return Result(name, score(ts, scn), frames, sec), ts


#: evaluate_tracks gate (m), set from --gate
_GATE = 10.0


def score(ts: TrackSet, scn: Scenario) -> TrackingMetrics:
    return evaluate_tracks(ts, scn.truth, gate=_GATE, sensor_pose=scn.truth.sensor_pose,
                           hfov_deg=scn.sensor.hfov_deg, max_range=scn.sensor.max_range)


def polar_noise(z: np.ndarray, rng: np.ndarray, sensor: np.ndarray, cfg: TrackingConfig
                ) -> np.ndarray:
    """(n, 2, 2) per-detection covariance: range / azimuth noise + isotropic contour scatter."""
    d = z - sensor
    u = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
    n = np.column_stack([-u[:, 1], u[:, 0]])
    s_az = rng * np.deg2rad(cfg.sigma_azimuth_deg)
    R = (cfg.sigma_range**2 * u[:, :, None] * u[:, None, :]
         + (s_az**2)[:, None, None] * n[:, :, None] * n[:, None, :])
    return R + cfg.sigma_contour**2 * np.eye(2)


def ctrv_noise(k: np.ndarray, dt: float, sigma_accel: float, sigma_yaw_acc: float,
               sigma_pos: float) -> np.ndarray:
    """5x5 process noise of pyrecest's [x, y, yaw, v, yawrate] over dt: white acceleration
    along the heading, white yaw acceleration, position random walk."""
    c, s = math.cos(k[2]), math.sin(k[2])
    t2 = dt * dt / 2.0
    g_a = np.array([c * t2, s * t2, 0.0, dt, 0.0])
    g_w = np.array([-s * k[3] * dt**3 / 6.0, c * k[3] * dt**3 / 6.0, t2, 0.0, dt])
    Q = sigma_accel**2 * np.outer(g_a, g_a) + sigma_yaw_acc**2 * np.outer(g_w, g_w)
    Q[0, 0] += sigma_pos**2 * dt
    Q[1, 1] += sigma_pos**2 * dt
    return Q


@dataclass
class PyrecestSettings:
    """Free settings of the pyrecest run (everything else mirrors TrackingConfig)."""

    sigma_accel: float = 1.5
    """White acceleration std. dev. (m/s^2) along the heading (no acceleration state)."""
    cap: int = 24
    """At most this many detections (regular subsample) per update."""
    kernel_width: float | None = None
    """Periodic-kernel width l (rad); None: fgloc's gp_length_rad."""
    fgloc_shape_prior: bool = True
    """Initial contour covariance = fgloc's prior K (with its common-offset, symmetry and size
    modes); False: pyrecest's own K_uu."""
    radial_noise_variance: float = 0.0
    """pyrecest's extra radial measurement noise (m^2)."""


def run_pyrecest(scn: Scenario, fr: Frames, birth: Track, cfg: TrackingConfig,
                 ps: PyrecestSettings, name: str = "pyrecest FullSCGP") -> Result:
    from pyrecest.filters import FullSCGPTracker

    gp = ContourGP(contour_angles(), cfg.gp_sf, cfg.gp_length_rad, cfg.gp_sr, cfg.gp_symmetry,
                   cfg.mean_length, cfg.mean_width, cfg.gp_sl, cfg.gp_sw)
    x0 = birth.states[0]
    P0 = birth.covariances[0]          # track_scenario keeps them (store_covariances)
    idx = list(_PR_KIN) + list(range(N_KIN, N_STATE))
    kin0 = x0[list(_PR_KIN)]
    joint = P0[np.ix_(idx, idx)]
    width = cfg.gp_length_rad if ps.kernel_width is None else ps.kernel_width
    kernel = (float(np.mean(np.diag(gp.K))), width)
    if not ps.fgloc_shape_prior:
        from pyrecest.filters import FullSCGPTracker as _F
        k_uu = _F(N_CONTOUR, velocities=True, kernel_params=kernel)._k_uu
        joint[5:, 5:] = np.asarray(k_uu)
        joint[:5, 5:] = 0.0
        joint[5:, :5] = 0.0
    sensor = scn.truth.sensor_pose[:2, 3]
    k0 = int(np.argmin(np.abs(fr.t - birth.t[0])))

    t_start = time.perf_counter()
    trk = FullSCGPTracker(
        N_CONTOUR,
        kinematic_state=kin0,
        shape_state=x0[N_KIN:].copy(),
        joint_covariance=joint,
        velocities=True,
        kernel_params=kernel,
        extent_forgetting_rate=cfg.tau,
        reference_extent=gp.mu.copy(),
        radial_noise_variance=ps.radial_noise_variance,
        scale_mean=1.0,
        scale_variance=0.0,
        alpha=cfg.ukf_alpha,
        beta=cfg.ukf_beta,
        kappa=cfg.ukf_kappa,
    )
    t_list = [float(fr.t[k0])]
    states = [_to_fgloc(trk)]
    last_upd = 0
    for k in range(k0 + 1, len(fr.t)):
        dt = float(fr.t[k] - fr.t[k - 1])
        Q = ctrv_noise(np.asarray(trk.kinematic_state), dt, ps.sigma_accel, cfg.sigma_yaw_acc,
                       cfg.sigma_pos)
        trk.predict(dt=dt, sys_noise=Q)
        z = fr.z[k]
        if len(z):
            sel = subsample(len(z), ps.cap)
            zs = z[sel]
            trk.update(zs, R=polar_noise(zs, fr.rng[k][sel], sensor, cfg))
            last_upd = len(t_list)
        t_list.append(float(fr.t[k]))
        states.append(_to_fgloc(trk))
    sec = time.perf_counter() - t_start
    n = last_upd + 1
    s = np.asarray(states[:n])
    tr = Track(0, np.asarray(t_list[:n]), s, kappa_labels(s, cfg.eta, cfg.label_min_speed))
    ts = TrackSet([tr], frame="L")
    return Result(name, score(ts, scn), n, sec)


def _to_fgloc(trk) -> np.ndarray:
    """pyrecest state -> fgloc state row [x, y, v, a=0, yaw, yawrate, r_0..r_19]."""
    k = np.asarray(trk.kinematic_state, dtype=float)
    s = np.zeros(N_STATE)
    s[X], s[Y], s[YAW], s[V], s[YAWRATE] = k
    s[A] = 0.0
    s[N_KIN:] = np.asarray(trk.shape_state, dtype=float)
    return s


def pooled(results: list[Result]) -> tuple[float, float, float, int, float]:
    """State-weighted pooled centre RMS, yaw error, IoU, states, ms/frame over sequences."""
    n = np.array([r.metrics.n_states for r in results], dtype=float)
    ok = n > 0
    ms = 1e3 * sum(r.seconds for r in results) / max(sum(r.frames for r in results), 1)
    if not ok.any():
        return math.nan, math.nan, math.nan, 0, ms
    m = [r.metrics for r, o in zip(results, ok) if o]
    w = n[ok]
    rms = math.sqrt(float(np.sum(w * np.array([x.centre_rms for x in m]) ** 2) / w.sum()))
    yaw = float(np.sum(w * np.array([x.yaw_error_deg for x in m])) / w.sum())
    iou = float(np.sum(w * np.array([x.iou for x in m])) / w.sum())
    return rms, yaw, iou, int(w.sum()), ms


#: extra pyrecest settings run with --variants (name suffix, settings changes)
VARIANTS = (
    ("l=pi/4", {"kernel_width": math.pi / 4}),
    ("own K_uu prior", {"fgloc_shape_prior": False}),
    ("all detections", {"cap": 10_000}),
    ("sigma_a=0.5", {"sigma_accel": 0.5}),
    ("radial var 0.1", {"radial_noise_variance": 0.1}),
)


#: the separate venv made by bench/pyrecest_env.sh
VENV_PYTHON = Path(__file__).resolve().parent / ".venv-pyrecest" / "bin" / "python"


def produce_in_venv(duration: float = 40.0, sequences: list[str] | None = None):
    """Run this script in the pyrecest venv (``--json``) and return its rows, table and
    pooled figures as a :class:`bench.results.Produced`; ``sequences``: "case:seed" items
    (default: ``SEQUENCES``); :class:`bench.results.Unavailable` without the venv (the report
    then keeps the stored result)."""
    import subprocess
    import sys
    import tempfile

    from bench.results import ROOT, Produced, Unavailable

    if not VENV_PYTHON.exists():
        raise Unavailable(f"{VENV_PYTHON} not found: run `bash bench/pyrecest_env.sh`")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "pyrecest.json"
        env = {**os.environ, "PYRECEST_BACKEND": "numpy", "PYTHONPATH": str(ROOT)}
        cmd = [str(VENV_PYTHON), "-m", "bench.pyrecest_compare", "--duration", f"{duration:g}",
               "--json", str(out)] + (["--sequences", *sequences] if sequences else [])
        subprocess.run(cmd, check=True, env=env, cwd=ROOT, stdout=sys.stdout, stderr=sys.stderr)
        doc = json.loads(out.read_text())
    return Produced(doc["rows"], doc["body"], doc["setting"], doc["summary"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=40.0)
    ap.add_argument("--sequences", nargs="*", default=None,
                    help="case:seed pairs (default: the built-in list)")
    ap.add_argument("--sigma-accel", type=float, default=1.5,
                    help="pyrecest white acceleration std. dev. (m/s^2) along the heading "
                         "(it has no acceleration state)")
    ap.add_argument("--cap", type=int, default=None,
                    help="detections per pyrecest update (default: fgloc's "
                         "max_detections_per_update)")
    ap.add_argument("--gate", type=float, default=10.0,
                    help="evaluate_tracks gate (m): one vehicle per sequence, so a loose gate "
                         "scores a poor track instead of calling it false")
    ap.add_argument("--variants", action="store_true",
                    help="also run the pyrecest setting variants (VARIANTS)")
    ap.add_argument("--json", default=None,
                    help="also write the rows, the printed table and the pooled figures here "
                         "(read by bench.report)")
    args = ap.parse_args()
    lines: list[str] = []
    rows: list[dict] = []

    def emit(line: str = "") -> None:
        lines.append(line)
        print(line, flush=True)

    global _GATE
    _GATE = args.gate

    import pyrecest

    seqs = ([(s.split(":")[0], int(s.split(":")[1]), "") for s in args.sequences]
            if args.sequences else SEQUENCES)
    base = TrackingConfig()
    plain = dataclasses.replace(base, measurement_model="plain", use_doppler=False)
    ps = PyrecestSettings(args.sigma_accel, args.cap or base.max_detections_per_update)
    setting = (f"pyrecest {getattr(pyrecest, '__version__', '?')} backend "
               f"{os.environ.get('PYRECEST_BACKEND')}; duration {args.duration:.0f} s; "
               f"evaluate gate {args.gate} m; pyrecest {ps}")
    print(setting + "\n")
    head = (f"{'sequence':<30} {'tracker':<32} {'trk':>3} {'false':>5} {'states':>6} "
            f"{'RMS m':>6} {'yaw deg':>7} {'IoU':>5} {'ms/frame':>8}")
    emit(head)
    emit("-" * len(head))
    by_tracker: dict[str, list[Result]] = {}
    for case, seed, what in seqs:
        scn, cls, length = vehicle_scenario(case, seed, args.duration)
        label = f"{case}:{seed} {what or cls}"
        fr = vehicle_frames(scn, base.doppler_min)
        res = []
        r_def, ts = run_fgloc(scn, base, "fgloc sensor-aware+Doppler")
        res.append(r_def)
        r_pl, _ = run_fgloc(scn, plain, "fgloc plain, no Doppler")
        res.append(r_pl)
        if ts.tracks:
            birth = min(ts.tracks, key=lambda tr: tr.t[0])
            res.append(run_pyrecest(scn, fr, birth, base, ps))
            if args.variants:
                for suffix, change in VARIANTS:
                    res.append(run_pyrecest(scn, fr, birth, base,
                                            dataclasses.replace(ps, **change),
                                            f"pyrecest {suffix}"))
        else:
            emit(f"{label}: fgloc started no track, pyrecest has no shared initialization")
        for r in res:
            m = r.metrics
            emit(f"{label:<30} {r.name:<32} {m.n_tracks:3d} {m.false_tracks:5d} "
                 f"{m.n_states:6d} {m.centre_rms:6.3f} {m.yaw_error_deg:7.2f} {m.iou:5.3f} "
                 f"{r.ms_per_frame:8.2f}")
            rows.append({"sequence": label, "tracker": r.name, "tracks": m.n_tracks,
                         "false": m.false_tracks, "states": m.n_states, "rms": m.centre_rms,
                         "yaw_deg": m.yaw_error_deg, "iou": m.iou, "ms_per_frame":
                         r.ms_per_frame})
            by_tracker.setdefault(r.name, []).append(r)
        emit()
    emit("pooled over sequences (state-weighted; ms/frame = total time / total frames):")
    for name, rs in by_tracker.items():
        rms, yaw, iou, n, ms = pooled(rs)
        emit(f"{'ALL':<30} {name:<32} {'':>3} {sum(r.metrics.false_tracks for r in rs):5d} "
             f"{n:6d} {rms:6.3f} {yaw:7.2f} {iou:5.3f} {ms:8.2f}")
    ref = by_tracker.get("fgloc sensor-aware+Doppler")
    pl = by_tracker.get("fgloc plain, no Doppler")
    pr = by_tracker.get("pyrecest FullSCGP")
    summary = {}
    if ref and pl and pr:
        emit()
        emit(f"speed ratio (ms per frame) pyrecest / fgloc sensor-aware: "
             f"{pooled(pr)[4] / pooled(ref)[4]:.1f}, pyrecest / fgloc plain: "
             f"{pooled(pr)[4] / pooled(pl)[4]:.1f}")
        for name, rs in (("fgloc", ref), ("pyrecest", pr)):
            rms, yaw, iou, n, ms = pooled(rs)
            summary[name] = {"rms": rms, "yaw_deg": yaw, "iou": iou, "states": n,
                             "ms_per_frame": ms}
        summary["sequences"] = len(seqs)
    if args.json:
        Path(args.json).write_text(json.dumps({
            "rows": rows, "body": ["```", *lines, "```"], "setting": setting,
            "summary": summary}, indent=1, default=float))


if __name__ == "__main__":
    main()
