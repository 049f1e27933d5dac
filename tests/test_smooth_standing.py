"""Standing steps held still in the smoothers (fgloc.smoothing.standing): the stacked rows
against the gtsam graph, and vehicles that stop at a junction keeping one track whose stand
the batch smoother holds where the simulator's truth stood."""

from __future__ import annotations

import dataclasses

import numpy as np
from test_track_system import assert_equals_graph, three_tracks

from fgloc.config import Config, from_dict
from fgloc.evaluation.tracking import evaluate_tracks
from fgloc.pipeline import track
from fgloc.sim import SimConfig, simulate_detailed
from fgloc.smoothing import SmoothingConfig
from fgloc.smoothing.fixed_lag import smooth_fixed_lag
from fgloc.smoothing.graph import build_track_graph, placed_detections, stack_tracks
from fgloc.smoothing.run import smooth_tracks
from fgloc.tracks import YAWRATE, V


def test_stacked_standing_rows_equal_the_gtsam_graph() -> None:
    tracks, det, sensor = three_tracks(1)
    tr = tracks.tracks[2]
    tr.standing = np.zeros(len(tr), dtype=bool)
    tr.standing[2:7] = True
    cfg = SmoothingConfig(max_detections=6)
    tg = build_track_graph(tracks, det, sensor, cfg)
    st = stack_tracks(tracks, det, sensor, cfg)
    offset = sum(len(t) for t in tracks.tracks[:2])
    np.testing.assert_array_equal(st.stand_step, offset + np.arange(2, 7))
    x = np.concatenate([t.states for t in tracks.tracks])
    rng = np.random.default_rng(3)
    x[st.stand_step, V] = rng.uniform(0.0, 2.0, 5)
    x[st.stand_step, YAWRATE] = rng.uniform(-0.2, 0.2, 5)
    assert_equals_graph(st, tg, x)
    # the standing rows cost 0.5 (v / sigma_v)^2 + 0.5 (yaw rate / sigma_w)^2 each
    bare = dataclasses.replace(tr, standing=None)
    plain = stack_tracks(dataclasses.replace(tracks, tracks=[*tracks.tracks[:2], bare]),
                         det, sensor, cfg)
    extra = np.sum(st.evaluate(x).cost) - np.sum(plain.evaluate(x).cost)
    expect = 0.5 * np.sum((x[st.stand_step, V] / cfg.stand_sigma_speed) ** 2
                          + (x[st.stand_step, YAWRATE] / cfg.stand_sigma_yawrate) ** 2)
    np.testing.assert_allclose(extra, expect, rtol=1e-8)


def _stand_errors(tracks, truth, eta: float) -> list[float]:
    """Per joined track with standing rows, the largest distance (m) of those rows' centres
    from its vehicle's true centre."""
    m = evaluate_tracks(tracks, truth, eta=eta)
    vehicle = {r.track_id: r.truth_id for r in m.rows}
    states = {gt.id: gt.states for gt in truth.tracks}
    out = []
    for tr in tracks.in_local().tracks:
        if tr.standing is None or vehicle.get(tr.id) is None:
            continue
        st, k = states[vehicle[tr.id]], tr.standing_steps()
        dx = tr.states[k, 0] - np.interp(tr.t[k], st[:, 0], st[:, 1])
        dy = tr.states[k, 1] - np.interp(tr.t[k], st[:, 0], st[:, 2])
        out.append(float(np.max(np.hypot(dx, dy))))
    return out


def _near(errors: list[float]) -> bool:
    """Stands held near the truth: every one within 1 m, on average within 0.4 m."""
    return max(errors) < 1.0 and float(np.mean(errors)) < 0.4


def test_vehicles_that_stop_keep_one_track_and_stand_still() -> None:
    """Intersection, seed 2, 40 s: every vehicle stops once for 3-15 s before the junction (its
    returns static, dropped). Without the link across a stand its track breaks; with it the
    fragments go and the stands' rows stay near where the vehicles stood (:func:`_near`: the
    largest distance per stand), filtered and smoothed (batch and fixed-lag); the batch
    smoother without the standing rows drives them further off."""
    sim = from_dict(SimConfig, {"traffic": {"stop_share": 1.0}}, None)
    scn = simulate_detailed("intersection", 2, 40.0, config=sim).scenario
    assert scn.truth is not None
    cfg = Config()
    off = dataclasses.replace(cfg, tracking=dataclasses.replace(cfg.tracking, stand_time=0.0))
    broken = evaluate_tracks(track(scn, off, oracle_pose=True).tracks, scn.truth)
    run = track(scn, cfg, oracle_pose=True)
    joined = evaluate_tracks(run.tracks, scn.truth)
    assert broken.fragments >= 3 and joined.fragments <= broken.fragments - 3
    assert joined.missed <= broken.missed and joined.false_tracks <= broken.false_tracks
    eta = cfg.tracking.eta
    assert len(run.tracks.diagnostics["relinked_stands"]) >= 3
    assert _near(_stand_errors(run.tracks, scn.truth, eta))
    batch = smooth_tracks(scn, run.tracks, run.T_placement, "batch", cfg)
    assert _near(_stand_errors(batch, scn.truth, eta))
    det_xy, sensor_xy = placed_detections(scn, run.T_placement)
    lagged = smooth_fixed_lag(run.tracks, det_xy, sensor_xy, cfg.smoothing, cfg.tracking)
    assert _near(_stand_errors(lagged, scn.truth, eta))
    loose = dataclasses.replace(cfg, smoothing=dataclasses.replace(
        cfg.smoothing, stand_sigma_speed=1e3, stand_sigma_yawrate=1e3))
    free = smooth_tracks(scn, run.tracks, run.T_placement, "batch", loose)
    assert max(_stand_errors(free, scn.truth, eta)) > max(_stand_errors(batch, scn.truth, eta))
