"""The batch smoother's length floor (fgloc.smoothing.length_floor): its rows against numerical
derivatives and the gtsam graph, and a 12 m truck seen end-on with sparse returns against the
simulator's truth."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from test_track_system import assert_equals_graph, three_tracks
from test_tracking_robustness import SPARSE, TRUCK_12M

from factors.gp import rectangle_radius
from fgloc.config import Config, from_dict
from fgloc.evaluation.tracking import contour_polygons
from fgloc.pipeline import track
from fgloc.sim import SimConfig, simulate_detailed
from fgloc.smoothing import SmoothingConfig
from fgloc.smoothing.graph import TrackModels, build_track_graph, stack_tracks
from fgloc.smoothing.length_floor import floor_rows
from fgloc.smoothing.run import smooth_tracks
from fgloc.tracking.config import TrackingConfig
from fgloc.tracks import N_KIN, N_STATE, YAW, contour_angles, contour_length_width


def test_floor_rows_one_sided_with_numerical_jacobian() -> None:
    rng = np.random.default_rng(4)
    x = rng.normal(0.0, 1.0, (6, N_STATE))
    x[:, N_KIN:] = rectangle_radius(contour_angles(), 10.0, 2.5)
    x[:, N_KIN] += np.array([-1.0, -0.3, 0.05, 0.2, 1.0, -2.0])   # lengths 9 ... 11, 8
    floor = np.full(6, 10.0)
    r, J = floor_rows(x, floor, 0.5)
    length = contour_length_width(x)[0]
    np.testing.assert_allclose(r, np.minimum(length - 10.0, 0.0) / 0.5)
    assert np.all(r[length >= 10.0] == 0.0) and np.all(r[length < 10.0] < 0.0)
    eps = 1e-6
    for k in range(N_STATE):
        d = np.zeros(N_STATE)
        d[k] = eps
        num = (floor_rows(x + d, floor, 0.5)[0] - floor_rows(x - d, floor, 0.5)[0]) / (2 * eps)
        np.testing.assert_allclose(J[:, k], num, atol=1e-6)


def test_stacked_floor_rows_equal_the_gtsam_graph() -> None:
    tracks, det, sensor = three_tracks(1)
    tr = tracks.tracks[1]               # a 10.5 m truck in every filtered step: long model
    tr.states[:, N_KIN:] = rectangle_radius(contour_angles(), 10.5, 2.5)
    tr.length_floor = 10.5              # measured behind its seen end by the tracker
    cfg = SmoothingConfig(max_detections=6)
    tg = build_track_graph(tracks, det, sensor, cfg)
    st = stack_tracks(tracks, det, sensor, cfg)
    # less twice the range noise (the occupied length ends at a detection)
    assert len(st.floor_step) == len(tr)
    np.testing.assert_allclose(st.floor, 10.5 - 2.0 * TrackingConfig().sigma_range)
    x = np.concatenate([t.states for t in tracks.tracks])
    rng = np.random.default_rng(5)
    x[st.floor_step, N_KIN] -= rng.uniform(-0.3, 1.5, len(st.floor_step))   # most too short
    assert_equals_graph(st, tg, x)
    # without the floor (or for the car tracks) no such rows
    off = stack_tracks(tracks, det, sensor, SmoothingConfig(max_detections=6,
                                                           length_floor_sigma=0.0))
    assert len(off.floor_step) == 0


def _truck_length(ts) -> float:
    """Median contour extent along the heading (m) of the longest track."""
    tr = max(ts.in_local().tracks, key=len)
    h = np.column_stack([np.cos(tr.states[:, YAW]), np.sin(tr.states[:, YAW])])
    return float(np.median(np.ptp(np.einsum("kmd,kd->km", contour_polygons(tr.states), h),
                                  axis=1)))


# straight road, sparse returns (bench/robustness.py's far-sparse), the truck seen end-on for
# most of it. Measured on seeds 1-8: batch median length 11.3-12.1 m with the floor on all but
# seed 3 (whose filter track stays 6.3 m, no occupied length), 7.9-11.9 m without it (seeds
# 6 / 8: 7.9 / 10.7 m against 11.3 / 11.3 m; centre RMS 2.03 / 0.65 m against 0.45 / 0.39 m).
# Since the extent rows need 12 detections on their face (``extent_face_min_points``) the
# smoother alone shortens less: without the floor seeds 6 / 8 9.4 / 11.2 m (with it 11.3 /
# 11.4 m), so the cause is checked on seed 6 only. Since ``tracking.visible_slack`` the
# smoother keeps seed 6's length without the floor too (11.4 m)
@pytest.mark.parametrize("seed", [6, pytest.param(8, marks=pytest.mark.slow)])
def test_batch_keeps_the_length_of_a_truck_seen_end_on(seed: int) -> None:
    table = {**TRUCK_12M, "radar": SPARSE}
    scn = simulate_detailed("straight", seed, 25.0, vehicles=1,
                            config=from_dict(SimConfig, table, None)).scenario
    cfg = Config()
    run = track(scn, cfg, oracle_pose=True)
    assert abs(_truck_length(run.tracks) - 12.0) <= 1.0
    batch = smooth_tracks(scn, run.tracks, run.T_placement, "batch", cfg)
    assert abs(_truck_length(batch) - 12.0) <= 1.5, _truck_length(batch)
    off = copy.deepcopy(cfg)
    off.smoothing.length_floor_sigma = 0.0
    free = smooth_tracks(scn, run.tracks, run.T_placement, "batch", off)
    assert abs(_truck_length(free) - 12.0) <= 1.5, _truck_length(free)
    # the cause: its grazing side returns, matched to the front face (the contour's heading
    # a little off hides that side), shortened the truck without the floor (seed 6: 9.8 m);
    # matched to the side they lie on (``tracking.visible_slack``) they do not (11.4 m)
    off.tracking.visible_slack = np.inf
    hidden = smooth_tracks(scn, run.tracks, run.T_placement, "batch", off)
    assert seed != 6 or _truck_length(hidden) < _truck_length(batch) - 0.5


def test_a_track_with_an_occupied_length_gets_the_long_model() -> None:
    """Seen end-on from behind, a 10.8 m truck's filter contour may stay 8.3 m (below
    long_vehicle_length) while the tracker measured 6.9 m occupied behind its seen end
    (far-sparse intersection seed 5): with the car model the smoother's GP prior pulled it to
    the floor (6.9 m, centre 2.4 m towards the sensor), with the long model 8.4 m, 1.1 m."""
    tracks, _, _ = three_tracks(2)
    tr = tracks.tracks[0]
    tr.states[:, N_KIN:] = rectangle_radius(contour_angles(), 8.3, 2.0)
    models = TrackModels.of(TrackingConfig(), SmoothingConfig())
    assert not models.is_long(tr)
    tr.length_floor = 6.9
    assert models.is_long(tr) and models.for_track(tr) is models.long
    off = TrackModels.of(TrackingConfig(), SmoothingConfig(long_vehicle_length=0.0))
    assert not off.is_long(tr)
