"""Tests of the smoothers: the fixed-lag smoother's bounded memory over a long sequence and
its accuracy, and the batch smoother against the filter on a simulated car (known truth)."""

from __future__ import annotations

import copy
import dataclasses

import gtsam
import numpy as np
import pytest
from test_smoothing_graph import DT, make_track

from factors.gtsam_factors import track_key
from fgloc.config import Config
from fgloc.evaluation.tracking import evaluate_tracks
from fgloc.pipeline import track
from fgloc.sim import SimConfig, simulate
from fgloc.smoothing import SmoothingConfig
from fgloc.smoothing.batch import smooth_batch, step_groups
from fgloc.smoothing.fixed_lag import smooth_fixed_lag
from fgloc.smoothing.graph import TrackModel
from fgloc.smoothing.run import smooth_tracks
from fgloc.tracks import N_STATE, YAW, Track, TrackSet


def centre_and_yaw_error(states: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    rms = float(np.sqrt(np.mean(np.sum((states[:, :2] - truth[:, :2]) ** 2, axis=1))))
    return rms, float(np.mean(np.abs(states[:, YAW] - truth[:, YAW])))


def test_fixed_lag_long_sequence_bounded_factor_slots() -> None:
    rng = np.random.default_rng(4)
    n = 500                                                    # 25 s at 20 Hz
    tr, det, sensor, truth = make_track(rng, n=n)
    lag = 1.0
    out = smooth_fixed_lag(TrackSet([tr]), det, sensor, SmoothingConfig(lag=lag))
    window = int(lag / DT) + 1
    d = out.diagnostics
    # one variable per step in the window, two factors per step (+ marginals): without
    # reused slots the smoother would hold ~2 n = 1000 of them
    assert d["window_variables_max"] <= window + 2
    assert d["factor_slots_max"] < 4 * window, d
    (r0, y0), (r1, y1) = (centre_and_yaw_error(s, truth)
                          for s in (tr.states, out.tracks[0].states))
    assert r1 < 0.6 * r0 and y1 < 0.6 * y0, (r0, r1, y0, y1)


def test_fixed_lag_tracks_smoothed_together_equal_each_alone() -> None:
    # one smoother per track: tracks overlapping in time (the second starts 1 s later, a
    # shorter lag than its life) must not change each other's estimates
    rng = np.random.default_rng(11)
    a, det_a, sensor, _ = make_track(rng, n=80, track_id=3)
    b, det_b, _, _ = make_track(rng, n=60, track_id=4)
    b = Track(b.id, b.t + 1.0, b.states, b.labels, None, b.det_index + len(det_a), b.det_step)
    det = np.vstack([det_a, det_b])
    cfg = SmoothingConfig(lag=0.5)
    both = smooth_fixed_lag(TrackSet([a, b]), det, sensor, cfg)
    for i, tr in enumerate((a, b)):
        alone = smooth_fixed_lag(TrackSet([tr]), det, sensor, cfg)
        np.testing.assert_allclose(both.tracks[i].states, alone.tracks[0].states, atol=1e-9)
        assert not np.allclose(alone.tracks[0].states, tr.states)          # it did smooth
    # both tracks' windows at once (0.5 s at 20 Hz: 11 steps each) while they overlap
    assert 20 <= both.diagnostics["window_variables_max"] <= 2 * 12


def test_step_groups_bound_the_steps_and_keep_the_order() -> None:
    assert step_groups([5, 4, 3, 9, 1], 9) == [[0, 1], [2], [3], [4]]
    assert step_groups([12, 2], 9) == [[0], [1]]           # a longer track is a group alone
    assert step_groups([0, 3], 3) == [[0, 1]]
    assert step_groups([], 5) == []


def test_batch_smoother_in_groups_equals_all_tracks_at_once(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # tracks share no variable: grouping them (the memory bound on long recordings) gives each
    # the same optimum up to rounding, with the same iterations and summed cost
    import fgloc.smoothing.batch as batch

    systems: list[list[int]] = []                  # the track ids of each system optimized
    stack = batch.stack_tracks

    def recorded(tracks: TrackSet, *args: object) -> object:
        systems.append([tr.id for tr in tracks.tracks])
        return stack(tracks, *args)

    monkeypatch.setattr(batch, "stack_tracks", recorded)
    rng = np.random.default_rng(21)
    parts = [make_track(rng, n=n, track_id=k) for k, n in ((3, 70), (4, 50), (5, 90))]
    offset, tracks = 0, []
    for tr, det, _, _ in parts:
        tracks.append(dataclasses.replace(tr, det_index=tr.det_index + offset))
        offset += len(det)
    det, sensor = np.vstack([p[1] for p in parts]), parts[0][2]
    runs = {b: smooth_batch(TrackSet(tracks), det, sensor, SmoothingConfig(batch_steps=b))
            for b in (10**6, 130, 60)}
    assert systems == [[3, 4, 5], [3, 4], [5], [3], [4], [5]]
    ref = runs[10**6]
    for out in runs.values():
        for got, want, filt in zip(out.tracks, ref.tracks, tracks):
            np.testing.assert_allclose(got.states, want.states, rtol=0, atol=1e-9)
            assert not np.allclose(got.states, filt.states)             # it did smooth
        assert out.diagnostics["smoother_iterations"] == ref.diagnostics["smoother_iterations"]
        assert np.isclose(out.diagnostics["smoother_error_final"],
                          ref.diagnostics["smoother_error_final"], rtol=1e-12)
        assert out.diagnostics["smoother_error_final"] < out.diagnostics["smoother_error_initial"]


def test_factor_callbacks_repeated_at_the_same_state_match_fresh_factors() -> None:
    # the callbacks serve a repeated linearization at the same state from the last
    # evaluation: it must equal a fresh factor's at every point of a sequence that returns
    rng = np.random.default_rng(5)
    tr, det, sensor, _ = make_track(rng, n=3)
    model = TrackModel.of()
    k0, k1 = track_key(tr.id, 0), track_key(tr.id, 1)
    idx = tr.det_index[tr.det_step == 1]

    def make() -> list:
        return [model.process(k0, k1, 0.05, tr.states[0]),
                model.measurement(k1, det[idx], sensor)]

    used = make()
    points = [tr.states[:2], tr.states[:2] + rng.normal(0, 0.05, (2, N_STATE))]
    for x in (points[0], points[0], points[1], points[1], points[0]):
        v = gtsam.Values()
        v.insert(k0, x[0])
        v.insert(k1, x[1])
        for f_used, f_new in zip(used, make()):
            assert f_used.error(v) == pytest.approx(f_new.error(v), rel=1e-12)
            ja, jb = f_used.linearize(v).jacobian(), f_new.linearize(v).jacobian()
            np.testing.assert_array_equal(ja[0], jb[0])
            np.testing.assert_array_equal(ja[1], jb[1])


@pytest.mark.slow
def test_fixed_lag_between_filter_and_batch_on_a_busy_intersection() -> None:
    # intersection seed 1, 60 s, 30 vehicles (11k detections/s): a track born 3.9 m off with
    # 7 detections made the fixed-lag smoother diverge (heading flipped, 19 m contour) when
    # ISAM2 checked relinearization only every 3rd update (pooled centre RMS 0.81 m against
    # the filter's 0.43 m, yaw error 5.2 deg); measured at c62332d: 0.433 m, 0.61 deg
    # (docs/experiments.md, "Fixed-lag smoother speed")
    scn = simulate("intersection", 1, duration=60.0, vehicles=30)
    cfg = Config()
    run = track(scn, cfg, oracle_pose=True)
    fixed = smooth_tracks(scn, run.tracks, run.T_placement, "fixed-lag", cfg)
    pose = scn.truth.sensor_pose
    m0, m1 = (evaluate_tracks(ts, scn.truth, eta=cfg.tracking.eta, sensor_pose=pose,
                              hfov_deg=scn.sensor.hfov_deg, max_range=scn.sensor.max_range)
              for ts in (run.tracks, fixed))
    assert m1.n_matched == m0.n_matched
    assert m1.centre_rms < 1.05 * m0.centre_rms, (m0.centre_rms, m1.centre_rms)
    assert m1.yaw_error_deg < 0.8 * m0.yaw_error_deg, (m0.yaw_error_deg, m1.yaw_error_deg)


# one passenger car per scenario (class mix: cars only). Measured on other seeds
# (docs/experiments.md): the batch smoother lowers the yaw error on every one, but its centre
# RMS is worse on some (a contour too long or short where no side is seen at enough incidence
# to measure the length), so these are cases where it wins, not a claim that it always does.
CASES = [("intersection", 6)]
SLOW_CASES = [("curve", 3)]


def one_car(case: str, seed: int) -> None:
    sim = SimConfig()
    sim.traffic = dataclasses.replace(sim.traffic, class_mix=(1.0, 0.0, 0.0))
    scn = simulate(case, seed, duration=15.0, vehicles=1, config=sim)
    cfg = Config()
    run = track(scn, cfg, oracle_pose=True)
    assert len(run.tracks) >= 1
    smoothed = smooth_tracks(scn, run.tracks, run.T_placement, "batch", cfg)
    pose = scn.truth.sensor_pose
    m0, m1 = (evaluate_tracks(ts, scn.truth, sensor_pose=pose, hfov_deg=scn.sensor.hfov_deg,
                              max_range=scn.sensor.max_range)
              for ts in (run.tracks, smoothed))
    print(f"{case} {seed}: RMS {m0.centre_rms:.3f} -> {m1.centre_rms:.3f} m, yaw "
          f"{m0.yaw_error_deg:.2f} -> {m1.yaw_error_deg:.2f} deg, IoU {m0.iou:.3f} -> "
          f"{m1.iou:.3f}")
    assert m1.n_states == m0.n_states > 20
    assert m1.centre_rms < m0.centre_rms and m1.yaw_error_deg < m0.yaw_error_deg
    # IoU: the aggregate rises (docs/experiments.md, the robustness matrix); a single car may
    # lose a little (filter -> batch, intersection 6: 0.831 -> 0.800 since the filter's
    # ``visible_slack``, 0.721 -> 0.784 before; curve 3: 0.726 -> 0.753)
    assert m1.iou > m0.iou - 0.04, (m0.iou, m1.iou)


@pytest.mark.parametrize(("case", "seed"), CASES)
def test_batch_beats_the_filter_on_a_simulated_car(case: str, seed: int) -> None:
    one_car(case, seed)


@pytest.mark.slow
@pytest.mark.parametrize(("case", "seed"), SLOW_CASES)
def test_batch_beats_the_filter_on_more_cars(case: str, seed: int) -> None:
    one_car(case, seed)


# one truck per scenario (class mix: trucks only), its length unobservable for a while: the
# filter promotes it to the long-vehicle contour; with the smoothers' long-vehicle model
# (docs/method.md 5) its centre error drops well below the car model's. Measured on
# intersection 1-6 and T-junction 1-6 (15 s): batch long below batch car by 23-85 % on 8 of the
# 11 seeds with a scored track, equal or within 1 % on the rest (intersection 5, 6: the truck
# split into two tracks; T-junction 3: its contour never reached 9 m)
TRUCK_CASES = [("tjunction", 4), ("intersection", 1)]
SLOW_TRUCK_CASES = [("tjunction", 6)]


def one_truck(case: str, seed: int) -> None:
    sim = SimConfig()
    sim.traffic = dataclasses.replace(sim.traffic, class_mix=(0.0, 0.0, 1.0))
    scn = simulate(case, seed, duration=15.0, vehicles=1, config=sim)
    cfg = Config()
    # the causal filter's tracks: its length retrodiction (fgloc.tracking.retrodict) fixes the
    # head-on truck's centre in the filter's own output, which this test does not isolate
    cfg.tracking.retrodict_window = 0
    car = copy.deepcopy(cfg)
    car.smoothing.long_vehicle_length = 0.0
    run = track(scn, cfg, oracle_pose=True)
    sets = [run.tracks] + [smooth_tracks(scn, run.tracks, run.T_placement, name, c)
                           for name in ("batch", "fixed-lag") for c in (car, cfg)]
    pose = scn.truth.sensor_pose
    m = [evaluate_tracks(ts, scn.truth, sensor_pose=pose, hfov_deg=scn.sensor.hfov_deg,
                         max_range=scn.sensor.max_range) for ts in sets]
    rms = [x.centre_rms for x in m]
    print(f"{case} {seed}: centre RMS filter / batch car / batch long / fixed-lag car / "
          f"fixed-lag long: {' / '.join(f'{r:.3f}' for r in rms)} m")
    assert m[0].n_states > 100 and all(x.n_states == m[0].n_states for x in m)
    assert rms[2] < 0.7 * rms[1] and rms[2] < 0.5 * rms[0]
    assert rms[4] < rms[3]


@pytest.mark.parametrize(("case", "seed"), TRUCK_CASES)
def test_long_vehicle_model_on_a_simulated_truck(case: str, seed: int) -> None:
    one_truck(case, seed)


@pytest.mark.slow
@pytest.mark.parametrize(("case", "seed"), SLOW_TRUCK_CASES)
def test_long_vehicle_model_on_more_trucks(case: str, seed: int) -> None:
    one_truck(case, seed)
