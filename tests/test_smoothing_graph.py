"""Tests of fgloc.smoothing.graph: the track graph's structure, keys and read-back, and that
optimizing it brings noisy filter-like states back to a known true trajectory."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from factors.ctra import ctra_predict
from factors.gp import rectangle_radius
from factors.gtsam_factors import decode_track_key
from fgloc.evaluation.tracking import contour_polygons
from fgloc.smoothing import SmoothingConfig
from fgloc.smoothing.graph import (
    TrackModel,
    build_track_graph,
    regular_subsample,
    step_detections,
    tracks_from_values,
    turn_round,
)
from fgloc.tracking import TrackingConfig
from fgloc.tracks import N_KIN, N_STATE, YAW, Track, TrackSet, contour_angles

DT = 0.05


def truth_run(n: int, rng: np.random.Generator, length: float, width: float) -> np.ndarray:
    """(n, 26) true states: a car at 8-14 m/s whose yaw rate ramps (0.4 rad/s^2) to a random
    turn rate half-way."""
    model = TrackModel.of()
    x = np.zeros(N_STATE)
    x[:2] = rng.uniform(-5, 5, 2) + [-20.0, 15.0]
    x[2] = rng.uniform(8, 14)
    x[YAW] = rng.uniform(-0.3, 0.3)
    x[N_KIN:] = rectangle_radius(model.gp.angles, length, width)
    out = [x]
    turn = rng.choice([-1.0, 1.0]) * rng.uniform(0.1, 0.3)
    for k in range(1, n):
        x = ctra_predict(out[-1], DT)
        if k >= n // 2:
            x[5] = np.clip(x[5] + 0.4 * DT * np.sign(turn), -abs(turn), abs(turn))
        out.append(x)
    return np.array(out)


def box_points(x: np.ndarray, sensor: np.ndarray, length: float, width: float,
               rng: np.random.Generator, sigma: float) -> np.ndarray:
    """Noisy detections (k, 2) on the faces of the true box that face the sensor."""
    h = np.array([np.cos(x[YAW]), np.sin(x[YAW])])
    lat = np.array([-h[1], h[0]])
    pts = []
    for axis, half, other, ohalf in ((h, length / 2, lat, width / 2),
                                     (lat, width / 2, h, length / 2)):
        for sgn in (1.0, -1.0):
            mid = x[:2] + sgn * axis * half
            if np.dot(sensor - mid, sgn * axis) > 0:
                s = rng.uniform(-0.95, 0.95, 8)
                pts.append(mid + np.outer(s * ohalf, other))
    z = np.vstack(pts)
    return z + rng.normal(0, sigma, z.shape)


def make_track(rng: np.random.Generator, n: int = 60, track_id: int = 7
               ) -> tuple[Track, np.ndarray, np.ndarray, np.ndarray]:
    """A filter-like track (true states + correlated errors) with its detections; returns
    (track, all detections (N, 2), sensor (2,), true states (n, 26))."""
    length, width = rng.uniform(4.0, 5.2), rng.uniform(1.7, 2.0)
    truth = truth_run(n, rng, length, width)
    sensor = np.array([0.0, -10.0])
    dets, det_index, det_step = [], [], []
    for k, x in enumerate(truth):
        z = box_points(x, sensor, length, width, rng, 0.1)
        det_index.append(np.arange(len(z)) + sum(len(d) for d in dets))
        det_step.append(np.full(len(z), k))
        dets.append(z)
    est = truth.copy()
    drift = np.cumsum(rng.normal(0, 0.08, (n, 2)), axis=0)
    est[:, :2] += drift + rng.normal(0, 0.2, (n, 2))
    est[:, YAW] += rng.normal(0, 0.04, n)
    est[:, N_KIN:] = TrackModel.of().gp.mu
    t = np.arange(n) * DT
    tr = Track(track_id, t, est, np.zeros(n, dtype=np.int8), None,
               np.concatenate(det_index), np.concatenate(det_step))
    return tr, np.vstack(dets), sensor, truth


def test_graph_structure_keys_and_readback() -> None:
    rng = np.random.default_rng(3)
    tr, det, sensor, _ = make_track(rng, n=12)
    tr.det_step = np.where(tr.det_step == 5, 4, tr.det_step)        # step 5 has no detections
    tg = build_track_graph(TrackSet([tr]), det, sensor, SmoothingConfig(max_detections=5))
    assert tg.graph.size() == 1 + 11 + 11                          # prior, process, measurement
    assert [decode_track_key(int(k)) for k in tg.keys[0]] == [(7, s) for s in range(12)]
    sizes = sorted(tg.graph.at(i).dim() for i in range(tg.graph.size()))
    assert max(sizes) == N_STATE and min(sizes) == 5 + 4     # 5 detections + 4 extent rows
    back = tracks_from_values(TrackSet([tr]), tg.values, tg.keys, TrackingConfig())
    np.testing.assert_allclose(back.tracks[0].states, tr.states)          # within the limits
    assert back.diagnostics["smoother"] == "smoother" and back.tracks[0].covariances is None
    assert len(step_detections(tr)[5]) == 0


def test_step_detections_and_subsample() -> None:
    tr = Track(1, np.arange(4.0), np.zeros((4, N_STATE)), np.zeros(4, dtype=np.int8), None,
               np.array([10, 11, 12, 13]), np.array([2, 0, 2, 3]))
    assert [list(i) for i in step_detections(tr)] == [[11], [], [10, 12], [13]]
    np.testing.assert_array_equal(regular_subsample(10, 4), [0, 3, 6, 9])
    np.testing.assert_array_equal(regular_subsample(3, 0), [0, 1, 2])


def test_bad_shapes_raise() -> None:
    rng = np.random.default_rng(0)
    tr, det, sensor, _ = make_track(rng, n=5)
    with pytest.raises(ValueError, match="det_xy"):
        build_track_graph(TrackSet([tr]), det[:, :1], sensor)
    with pytest.raises(ValueError, match="sensor_xy"):
        build_track_graph(TrackSet([tr]), det, np.zeros(3))
    with pytest.raises(ValueError, match="det_index"):
        build_track_graph(TrackSet([tr]), det[:10], sensor)


@pytest.mark.parametrize("seed", [1, 2])
def test_optimized_graph_beats_the_noisy_states(seed: int) -> None:
    rng = np.random.default_rng(seed)
    tr, det, sensor, truth = make_track(rng)
    tg = build_track_graph(TrackSet([tr]), det, sensor)
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(10)
    res = gtsam.LevenbergMarquardtOptimizer(tg.graph, tg.values, params).optimize()
    out = tracks_from_values(TrackSet([tr]), res, tg.keys).tracks[0].states

    def errors(s: np.ndarray) -> tuple[float, float]:
        rms = float(np.sqrt(np.mean(np.sum((s[:, :2] - truth[:, :2]) ** 2, axis=1))))
        return rms, float(np.mean(np.abs(s[:, YAW] - truth[:, YAW])))

    (r0, y0), (r1, y1) = errors(tr.states), errors(out)
    assert r1 < 0.5 * r0 and y1 < 0.5 * y0, (r0, r1, y0, y1)
    assert r1 < 0.35          # a contour offset remains where only two faces are seen


def test_turn_round_keeps_the_motion_and_the_contour() -> None:
    rng = np.random.default_rng(11)
    x = np.zeros((4, N_STATE))
    x[:, :2] = rng.normal(0, 20, (4, 2))
    x[:, 2] = [-6.0, -0.3, 4.0, -12.0]                               # speed
    x[:, 3] = rng.normal(0, 1, 4)                                    # acceleration
    x[:, YAW] = rng.uniform(-np.pi, np.pi, 4)
    x[:, 5] = rng.normal(0, 0.2, 4)                                  # yaw rate
    x[:, N_KIN:] = rectangle_radius(contour_angles(), 4.6, 1.9) + rng.normal(0, 0.2, (4, 20))
    mask = x[:, 2] < -1.0
    y = turn_round(x, mask)
    np.testing.assert_array_equal(y[~mask], x[~mask])
    assert np.all(y[mask, 2] > 0)
    # same contour polygon (as a point set), same positions after any motion
    px, py = contour_polygons(x), contour_polygons(y)
    for k in range(4):
        d = np.linalg.norm(px[k][:, None] - py[k][None], axis=-1)
        assert d.min(axis=1).max() < 1e-9
    for dt in (0.05, 1.0):
        np.testing.assert_allclose(ctra_predict(y[:, :N_KIN], dt)[:, :2],
                                   ctra_predict(x[:, :N_KIN], dt)[:, :2], atol=1e-9)
