"""``--method filter-sicp``: the labelled source cloud from tracks, the fine stage's warnings,
covariance and tracks, and accuracy end to end on a short simulated scenario."""

from __future__ import annotations

import dataclasses
import json
from types import SimpleNamespace

import numpy as np
import pytest

from fgloc.coarse import CoarseResult, coarse_localize
from fgloc.coarse.icp import _kabsch_2d
from fgloc.coarse.vertical import rodrigues
from fgloc.config import Config, dump_config, load_config
from fgloc.errors import LocalizationError
from fgloc.evaluation.pose import pose_error
from fgloc.geo import rot_from_ypr, rot_z, se2, se3, transform_points
from fgloc.labels import LEFT, RIGHT, STRAIGHT
from fgloc.map import build_target_cloud
from fgloc.pipeline import METHODS, localize
from fgloc.progress import Timer
from fgloc.registration.config import FineConfig
from fgloc.registration.fine import coarse_tilt_covariance, register_tracks, sensor_covariance
from fgloc.registration.source import build_source_cloud, choose_tracks, voxel_per_label
from fgloc.result import json_ready
from fgloc.scenario import RadarData
from fgloc.sim import simulate
from fgloc.tracking import track_scenario
from fgloc.tracks import N_STATE, Track, TrackSet


def _track(tid: int, xy: np.ndarray, labels: list[int], det_index: list[int],
           det_step: list[int]) -> Track:
    states = np.zeros((len(xy), N_STATE))
    states[:, :2] = xy
    states[:, 6:] = 1.0  # unit circle contour
    return Track(tid, np.arange(len(xy), dtype=float), states, np.array(labels, np.int8),
                 det_index=np.array(det_index, np.int64), det_step=np.array(det_step, np.int64))


def _cfg(**fine) -> Config:
    cfg = Config()
    cfg.fine = dataclasses.replace(cfg.fine, **fine)
    return cfg


@pytest.fixture
def constructed() -> tuple[SimpleNamespace, TrackSet, np.ndarray]:
    """Six detections (S) used by two tracks, and T_coarse = 90 deg turn + (100, 0, 5)."""
    xyz = np.array([[0.0, 0, 1], [0.1, 0, 1], [10, 0, 1], [20, 0, 1], [30, 0, 1], [40, 0, 1]])
    radar = RadarData(np.arange(6.0), xyz, np.ones(6))
    a = _track(7, np.array([[0.0, 0], [10, 0], [20, 0]]), [STRAIGHT, LEFT, LEFT],
               [0, 1, 2, 3], [0, 0, 1, 2])
    b = _track(9, np.array([[30.0, 0], [40, 0]]), [RIGHT, RIGHT], [4, 5], [0, 1])
    T = se3(rot_z(np.pi / 2), [100.0, 0.0, 5.0])
    return SimpleNamespace(radar=radar), TrackSet([a, b]), T


def test_detections_in_c_labelled_by_their_state(constructed):
    """The detections where T_coarse places them (the constant visible-side model; "aspect"
    moves them onto their tracks' cross-sections, test_visible_side.py)."""
    scn, tracks, T = constructed
    src = build_source_cloud(scn, tracks, T, _cfg(source="detections", voxel_size=0.5,
                                                  visible_side="constant"))
    expect = transform_points(T, scn.radar.xyz)[:, :2]
    # detections 0 and 1 share a voxel and a label (straight, step 0 of track 7): averaged
    assert len(src) == 5 and src.n_raw == 6
    np.testing.assert_allclose(src.xy[np.argmin(src.xy[:, 1])], expect[:2].mean(axis=0))
    lab = dict(zip(map(tuple, np.round(src.xy, 6)), src.label))
    assert lab[tuple(np.round(expect[2], 6))] == LEFT  # det_step 1 of track 7
    assert lab[tuple(np.round(expect[3], 6))] == LEFT  # det_step 2
    assert lab[tuple(np.round(expect[5], 6))] == RIGHT  # track 9
    assert set(src.track_id.tolist()) == {7, 9}
    assert src.summary()["points_per_label"] == {"straight": 1, "left": 2, "right": 2}


def test_centres_and_contours(constructed):
    scn, tracks, T = constructed
    cen = build_source_cloud(scn, tracks, T, _cfg(source="centres"))
    np.testing.assert_allclose(np.sort(cen.xy[:, 0]), [0, 10, 20, 30, 40])
    assert sorted(cen.label.tolist()) == [STRAIGHT, LEFT, LEFT, RIGHT, RIGHT]
    con = build_source_cloud(scn, tracks, T, _cfg(source="contours", voxel_size=0.01))
    assert len(con) == 5 * 20  # 20 contour points on a unit circle around each centre
    d = np.linalg.norm(con.xy - np.round(con.xy / 10) * 10, axis=1)
    np.testing.assert_allclose(d, 1.0, atol=0.01)


def test_voxels_are_per_label():
    xy = np.array([[0.1, 0.1], [0.2, 0.2], [0.3, 0.3], [1.6, 0.1]])
    cent, lab, first, n = voxel_per_label(xy, np.array([0, 0, 1, 0], np.int8), 1.0)
    assert len(cent) == 3
    np.testing.assert_allclose(cent[(lab == 0) & (cent[:, 0] < 1)], [[0.15, 0.15]])
    np.testing.assert_allclose(cent[lab == 1], [[0.3, 0.3]])
    assert sorted(first.tolist()) == [0, 2, 3]
    assert sorted(n.tolist()) == [1, 1, 2]


def test_voxel_none_is_the_targets(constructed):
    scn, tracks, T = constructed
    cfg = _cfg(source="detections", voxel_size=None)
    cfg.map = dataclasses.replace(cfg.map, voxel_size=100.0)
    src = build_source_cloud(scn, tracks, T, cfg)
    assert len(src) == 3  # one voxel per label


def test_trajectory_subset_is_seeded():
    fine = FineConfig(n_trajectories=20)
    a = choose_tracks(80, fine, np.random.default_rng(4))
    b = choose_tracks(80, fine, np.random.default_rng(4))
    c = choose_tracks(80, fine, np.random.default_rng(5))
    assert len(a) == 20 and len(np.unique(a)) == 20 and np.all(np.diff(a) > 0)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert len(choose_tracks(146, FineConfig(trajectory_share=0.5), np.random.default_rng(0))) == 73
    both = FineConfig(n_trajectories=50, trajectory_share=0.25)
    assert len(choose_tracks(146, both, np.random.default_rng(0))) == 37
    np.testing.assert_array_equal(choose_tracks(5, fine, np.random.default_rng(0)), np.arange(5))


def test_subset_through_config_seed(constructed):
    scn, tracks, T = constructed
    cfg = _cfg(source="centres", n_trajectories=1)
    ids = {int(build_source_cloud(scn, tracks, T, dataclasses.replace(cfg, seed=s)).track_id[0])
           for s in range(20)}
    assert ids == {7, 9}
    again = build_source_cloud(scn, tracks, T, cfg)
    assert build_source_cloud(scn, tracks, T, cfg).n_tracks_used == again.n_tracks_used == 1
    assert again.n_tracks_total == 2


def test_invalid_fine_config(constructed):
    scn, tracks, T = constructed
    for bad in ({"source": "pixels"}, {"target": "roads"}, {"trajectory_share": 0.0},
                {"n_trajectories": 0}, {"voxel_size": -1.0}, {"start_range": -1.0},
                {"visible_side": "sometimes"}, {"model_spread": -0.5}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            build_source_cloud(scn, tracks, T, _cfg(**bad))


def test_fine_config_round_trips_through_toml(tmp_path):
    cfg = _cfg(source="detections", target="road-points", n_trajectories=20, start_range=0.0)
    p = tmp_path / "c.toml"
    p.write_text(dump_config(cfg))
    assert load_config(p).fine == cfg.fine


def test_sensor_covariance_propagates_the_lever_arm():
    cov = np.diag([0.01, 0.04, 1e-4])
    out = sensor_covariance(cov, se2(0.0, 0.0, 0.0), np.array([10.0, 0.0]))
    # turning by dyaw moves a point at (10, 0) by 10 dyaw along y
    np.testing.assert_allclose(out, [[0.01, 0, 0], [0, 0.04 + 100e-4, 1e-3], [0, 1e-3, 1e-4]])
    assert sensor_covariance(None, np.eye(3), np.zeros(2)) is None


def test_coarse_tilt_covariance_is_the_shift_a_real_tilt_error_causes():
    """A coarse pose whose roll / pitch is off by w (about L's x, y), followed by the ideal
    planar registration of the vehicles (Kabsch of their placed to their true positions),
    puts the sensor off sideways; the covariance added for a tilt covariance S must be
    ``K S K^T``, K the central-difference Jacobian of that shift with respect to w."""
    rng = np.random.default_rng(4)
    T_true = se3(rot_from_ypr(0.7, np.deg2rad(4.0), np.deg2rad(-1.0)), [3.0, -2.0, 6.5])
    # vehicles on one road beside the sensor, reflections 0.3-1.4 m above a flat road (z = 0)
    x = np.column_stack([rng.uniform(-60, 120, 3000), rng.uniform(12, 22, 3000),
                         rng.uniform(0.3, 1.4, 3000)])
    p_s = (x - T_true[:3, 3]) @ T_true[:3, :3]

    def sensor_shift(w: np.ndarray) -> np.ndarray:
        T_c = se3(rodrigues(w).T @ T_true[:3, :3], T_true[:3, 3])
        q = p_s @ T_c[:3, :3].T + T_c[:3, 3]
        # the best 2D rigid transform from the placed to the true positions
        ang, t = _kabsch_2d(q[:, :2], x[:, :2])
        return T_true[:2, 3] - (rot_z(ang)[:2, :2] @ T_c[:2, 3] + t)

    h = 1e-4
    K = np.column_stack([(sensor_shift(h * e) - sensor_shift(-h * e)) / (2 * h)
                         for e in np.eye(3)[:2]])
    S = np.array([[4.0, -1.5], [-1.5, 1.0]]) * np.deg2rad(1.0) ** 2
    coarse = CoarseResult(T_true, (0.0,) * 6, 1.0, 0.1, len(p_s), len(p_s), True, "converged",
                          None, source_xyz=p_s, tilt_covariance=S)
    out = coarse_tilt_covariance(coarse)
    np.testing.assert_allclose(out[:2, :2], K @ S @ K.T, rtol=0.05)
    assert np.all(out[2] == 0) and np.all(out[:, 2] == 0)
    # the shift of a real 1 deg error (0.1 m) is the linear one within a few millimetres
    w = np.deg2rad([1.0, -0.5, 0.0])
    np.testing.assert_allclose(sensor_shift(w), K @ w[:2], atol=0.005)
    assert coarse_tilt_covariance(dataclasses.replace(coarse, tilt_covariance=None)) is None


# ---------------------------------------------------------------------------------------------
# end to end on a short simulated scenario (one coarse + tracking run shared by the tests)
# ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def stages():
    scn = simulate("tjunction", 4, duration=20.0)
    cfg = Config()
    target = build_target_cloud(scn, cfg.map)
    coarse = coarse_localize(scn, target, cfg.coarse)
    tracks = track_scenario(scn, coarse.T_coarse, cfg.tracking)
    return scn, cfg, target, coarse, tracks


def test_registered_in_methods():
    assert "filter-sicp" in METHODS


def test_short_scenario_within_bars(stages):
    scn, cfg, target, coarse, tracks = stages
    res = register_tracks(scn, cfg, target, coarse, tracks, Timer(), "filter-sicp")
    err = pose_error(res.T_local, scn.truth.sensor_pose)
    assert err.d2d < 0.7 and err.dyaw_deg < 0.4
    d = res.diagnostics
    # the covariance counts the evidence per track: wider than SICP's per-point one (which
    # treats every point as independent, diagnostics only) along the least determined direction
    cov, per_point = res.covariance, np.asarray(d["sicp"]["sensor_covariance_uncalibrated"])
    assert res.converged and cov.shape == per_point.shape == (3, 3)
    assert np.linalg.eigvalsh(cov[:2, :2])[-1] > 2.0 * np.linalg.eigvalsh(per_point[:2, :2])[-1]
    assert d["sicp"]["stop_reason"] == "rmse_converged" and d["source"]["n_points"] > 100
    assert d["tracking"]["n_tracks"] == len(tracks)
    assert res.source_xyz.shape == (len(res.source_label), 3)
    # the tracks carry T_fine: in L they are the C states moved by T_fine
    T_fine = res.tracks.T_frame_to_L
    assert not np.allclose(T_fine, np.eye(3))
    np.testing.assert_allclose(
        np.vstack([t.states[:, :2] for t in res.tracks.in_local().tracks]),
        transform_points(T_fine, np.vstack([t.states[:, :2] for t in tracks.tracks])),
    )
    np.testing.assert_allclose(res.T_local[:2, :2] @ np.ones(2),
                               T_fine[:2, :2] @ coarse.T_coarse[:2, :2] @ np.ones(2))
    assert res.to_json()["method"] == "filter-sicp"


def test_too_few_points_drop_a_label_with_a_warning(stages):
    scn, cfg, target, coarse, tracks = stages
    counts = build_source_cloud(scn, tracks, coarse.T_coarse, cfg).summary()["points_per_label"]
    n_min = max(counts["left"], counts["right"]) + 1
    assert n_min <= counts["straight"]
    cfg = dataclasses.replace(cfg, sicp=dataclasses.replace(cfg.sicp, min_points_per_label=n_min))
    res = register_tracks(scn, cfg, target, coarse, tracks, Timer(), "filter-sicp")
    assert sorted(res.diagnostics["sicp"]["dropped_labels"]) == ["left", "right"]
    assert sum("dropped" in w for w in res.to_json()["warnings"]) == 2
    assert pose_error(res.T_local, scn.truth.sensor_pose).d2d < 1.0


def test_iteration_limit_is_not_converged(stages):
    scn, cfg, target, coarse, tracks = stages
    cfg = dataclasses.replace(cfg, sicp=dataclasses.replace(cfg.sicp, max_iterations=1))
    res = register_tracks(scn, cfg, target, coarse, tracks, Timer(), "filter-sicp")
    assert not res.converged and res.diagnostics["sicp"]["stop_reason"] == "max_iterations"
    assert any("iteration limit" in w for w in res.warnings)


def test_a_doubted_off_lane_rule_is_a_warning(stages):
    """The tracker kept tracks the map's other ways would have told (the placement doubted,
    :mod:`fgloc.tracking.road_users`): the result says so."""
    scn, cfg, target, coarse, tracks = stages
    res = register_tracks(scn, cfg, target, coarse, tracks, Timer(), "filter-sicp")
    assert not any("lane off" in w for w in res.warnings)
    flagged = dataclasses.replace(tracks, diagnostics={**tracks.diagnostics,
                                                       "off_lane_doubted": [3, 5]})
    res = register_tracks(scn, cfg, target, coarse, flagged, Timer(), "filter-sicp")
    assert any(w.startswith("tracking: 2 tracks ran off") and "lane off" in w
               for w in res.warnings)


def test_no_vehicle_track_is_a_localization_error(stages):
    """Without a vehicle track filter-sicp has nothing of its own to register (before, it
    returned the coarse pose, and the CLI failed writing its NaN RMSE): a LocalizationError
    says how many tracks the tracker found and why it left them out."""
    scn, cfg, target, coarse, _ = stages
    with pytest.raises(LocalizationError, match="found no track"):
        register_tracks(scn, cfg, target, coarse, TrackSet([]), Timer(), "filter-sicp")
    others = TrackSet([], diagnostics={"not_motor_vehicles": [1, 2, 4], "off_lane": [4]})
    with pytest.raises(LocalizationError, match=r"smoother-sicp: .*all 3 of its tracks .*2 "
                       r"smaller or slower .*1 off the drivable lanelets.*walking_speed"):
        register_tracks(scn, cfg, target, coarse, others, Timer(), "smoother-sicp")


def test_json_ready_turns_non_finite_numbers_into_null():
    """A SICP left with too few correspondences has NaN RMSE and sigma; result.json is
    strict JSON (no NaN / Infinity), so they become null."""
    doc = json_ready({"a": np.float64("nan"), "b": [1.0, float("inf")],
                      "c": np.array([np.nan, 2.0]), "d": np.int64(3)})
    assert doc == {"a": None, "b": [1.0, None], "c": [None, 2.0], "d": 3}
    json.dumps(doc, allow_nan=False)


@pytest.mark.slow
def test_localize_end_to_end(stages):
    scn = stages[0]
    res = localize(scn, "filter-sicp")
    assert set(res.timings) >= {"coarse ICP", "tracking", "source cloud", "SICP"}
    assert pose_error(res.T_local, scn.truth.sensor_pose).d2d < 0.7


def test_aspect_visible_side_weights_voxels_by_their_detections(constructed):
    """``[fine] visible_side = "aspect"``: each voxel carries the number of detections it
    averages and the cloud the offsets measured on its tracks; "constant" neither."""
    scn, tracks, T = constructed
    src = build_source_cloud(scn, tracks, T, _cfg(source="detections", voxel_size=0.5,
                                                  visible_side="aspect"))
    assert sorted(src.weight.tolist()) == [1, 1, 1, 1, 2]   # detections 0 and 1 share a voxel
    assert src.visible_side is not None and src.visible_side.count.sum() == 6
    assert "visible_side" in src.summary()
    plain = build_source_cloud(scn, tracks, T, _cfg(source="detections", voxel_size=0.5,
                                                    visible_side="constant"))
    assert plain.weight is None and plain.visible_side is None


def test_model_spread_adds_the_constant_offset_fits_difference(stages):
    """``[fine] model_spread``: the pose is the "aspect" fit's; its covariance grows by
    ``model_spread d d^T``, ``d`` the sensor's difference to the fit with the constant offset,
    which is what a separate ``visible_side = "constant"`` run reports (without slip starts,
    whose fits each model may end on differently)."""
    scn, cfg, target, coarse, tracks = stages

    def run(**fine):
        c = dataclasses.replace(cfg, fine=dataclasses.replace(cfg.fine, slip_tracks=0, **fine))
        return register_tracks(scn, c, target, coarse, tracks, Timer(), "filter-sicp")

    alone, spread, constant = run(model_spread=0.0), run(model_spread=0.5), \
        run(visible_side="constant")
    assert len(alone.mode_fits) == 1                    # one coarse mode: one fit per model
    assert "constant_offset_difference" not in alone.diagnostics["sicp"]
    np.testing.assert_allclose(spread.T_local, alone.T_local)
    diff = spread.diagnostics["sicp"]["constant_offset_difference"]
    d = np.array([diff["dx_m"], diff["dy_m"], np.deg2rad(diff["dyaw_deg"])])
    np.testing.assert_allclose(d[:2], alone.T_local[:2, 3] - constant.T_local[:2, 3],
                               atol=1e-9)
    yaw = [np.arctan2(r.T_local[1, 0], r.T_local[0, 0]) for r in (alone, constant)]
    assert abs(d[2] - (yaw[0] - yaw[1])) < 1e-9
    assert np.hypot(*d[:2]) > 0.01                      # the two models do differ here
    np.testing.assert_allclose(spread.mode_fits[0].covariance,
                               alone.mode_fits[0].covariance + 0.5 * np.outer(d, d), atol=1e-12)
