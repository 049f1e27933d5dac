"""The coarse source keeps only moving detections on a trail (:func:`fgloc.coarse.points.on_trail`):
a vehicle's detections follow each other frame after frame, a false alarm stands alone.

Checked against the Poisson count a uniform clutter gives in closed form, a sparse far vehicle's
trail, and the independent generator's "uniform" clutter (bench/independent_gen.py on the crop
of the Lanelet2 example map, BSD-3-Clause, copyright 2018 FZI, see
tests/data/LICENSE-lanelet2_mapping_example), whose detections are told apart by the true
vehicles' footprints.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_independent_gen import CROP, JUNCTION_3, nearest_vehicle

from bench.independent_gen import generate
from fgloc.coarse import coarse_localize
from fgloc.coarse.points import dbscan_not_noise, dynamic_points, on_trail
from fgloc.config import CoarseConfig, Config
from fgloc.evaluation.pose import pose_error
from fgloc.io import load_scenario
from fgloc.map import build_target_cloud
from fgloc.scenario import Scenario


def test_uniform_clutter_keeps_its_poisson_share() -> None:
    """15 false alarms a frame over a 150 m square at 20 Hz: a point's neighbours in the box
    of +-3 m and +-0.3 s (13 frames) are Poisson with mean 15 * 36 / 150^2 * 13 = 0.312, so
    P(at least 2) = 1 - e^-0.312 (1 + 0.312) = 0.040 of them stay (fewer at the square's
    edges, where part of the box is empty)."""
    rng = np.random.default_rng(5)
    frames = 2000
    t = np.repeat(np.arange(frames) / 20.0, 15)
    xy = rng.uniform(0.0, 150.0, (len(t), 2))
    kept = on_trail(xy, t, 3.0, 0.3, 2)
    lam = 15 * 36 / 150.0**2 * 13
    expected = 1.0 - np.exp(-lam) * (1.0 + lam)
    inner = np.all((xy > 3.0) & (xy < 147.0), axis=1) & (t >= 0.3) & (t <= t[-1] - 0.3)
    assert kept[inner].mean() == pytest.approx(expected, rel=0.15)
    assert kept.mean() < kept[inner].mean()
    assert on_trail(xy, t, 3.0, 0.3, 0).all()


def test_a_sparse_vehicle_stays_on_its_trail() -> None:
    """One return a frame, anywhere on a 4.5 m car's length, with 0.3 m noise: at 20 Hz and
    15 m/s the neighbouring frames' returns lie within the box (all kept); at 10 Hz and
    20 m/s (2 m a frame) only the next frame's often do and 18 % go (the voxel + DBSCAN
    filter after it drops so thin a trail of one vehicle anyway)."""
    rng = np.random.default_rng(7)
    for rate, speed, share in ((20.0, 15.0, 0.99), (10.0, 20.0, 0.75)):
        t = np.arange(200) / rate
        along = speed * t + rng.uniform(-2.25, 2.25, t.size)
        xy = np.column_stack([along, np.full(t.size, 30.0)]) + rng.normal(0.0, 0.3, (t.size, 2))
        assert on_trail(xy, t, 3.0, 0.3, 2).mean() >= share, rate


def test_trail_config_is_validated() -> None:
    for bad in ({"trail_radius": 0.0}, {"trail_window": -1.0}, {"trail_min_neighbours": -1},
                {"search_points": 0}, {"refine_points": 0}, {"vertical_points": 0}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            CoarseConfig(**bad)


@pytest.fixture(scope="module")
def uniform(tmp_path_factory) -> Scenario:
    out = generate(CROP, JUNCTION_3, 1, tmp_path_factory.mktemp("trail") / "j3",
                   vehicles_per_minute=12.0, duration=30.0, clutter="uniform")
    return load_scenario(out)


def test_independent_false_alarms_leave_and_vehicles_stay(uniform: Scenario) -> None:
    """The independent generator's moving detections that lie within 1 m of a true vehicle's
    footprint stay (at least 98 %), the others (its 15 false alarms a frame) go (at most
    10 % stay); the count dropped is what ``dynamic_points`` reports."""
    radar = uniform.radar
    moving = np.abs(radar.doppler) >= CoarseConfig().doppler_min
    vehicle = nearest_vehicle(uniform, moving) <= 1.0
    assert (~vehicle).sum() > vehicle.sum() // 4          # false alarms are many here
    cfg = CoarseConfig()
    trail = on_trail(radar.xyz[moving, :2], radar.t[moving], cfg.trail_radius, cfg.trail_window,
                     cfg.trail_min_neighbours)
    assert trail[vehicle].mean() >= 0.98
    assert trail[~vehicle].mean() <= 0.10
    assert dynamic_points(radar, cfg).n_off_trail == int((~trail).sum())


def test_coarse_fit_under_uniform_false_alarms(uniform: Scenario) -> None:
    """The fit's source is the vehicles': nearly all of it lies on the road (fitness 0.80
    with the false alarms kept, ``trail_min_neighbours = 0``), and the pose is a coarse one
    (0.64 m, 0.40 deg here; seeds 1-6 of this setting 0.06-0.64 m, and 0.36 m on seed 1's
    scenario before the generator's vehicles yielded to each other)."""
    cfg = Config()
    target = build_target_cloud(uniform, cfg.map)
    res = coarse_localize(uniform, target, cfg.coarse, map_cfg=cfg.map)
    err = pose_error(res.T_coarse, uniform.truth.sensor_pose)
    assert res.n_points_off_trail > 0 and res.fitness >= 0.95
    assert err.d2d < 1.0 and err.dyaw_deg < 0.5


def test_dbscan_noise_test_in_closed_form() -> None:
    """Points 0.4 m apart on a line with eps 0.5 m and 3 points: each inner point has itself
    and its two neighbours (core), the ends only two (border: within eps of a core point);
    a point 0.9 m beyond an end is within eps of no core point (noise), and a pair alone is
    noise. min_points 1: every point is core."""
    line = np.column_stack([np.arange(6) * 0.4, np.zeros(6), np.zeros(6)])
    pts = np.vstack([line, [[2.0 + 0.9, 0.0, 0.0], [50.0, 0.0, 0.0], [50.3, 0.0, 0.0]]])
    assert dbscan_not_noise(pts, 0.5, 3).tolist() == [True] * 6 + [False] * 3
    assert dbscan_not_noise(pts, 0.5, 1).all()
    assert dbscan_not_noise(np.zeros((0, 3)), 0.5, 3).shape == (0,)


def test_dbscan_noise_test_agrees_with_open3d() -> None:
    """The peer: Open3D's cluster_dbscan labels exactly the same points noise on random
    clouds, uniform and clustered, flat and deep, over radii and point counts."""
    from fgloc._open3d import open3d

    o3d = open3d()
    rng = np.random.default_rng(11)
    kept = noise = 0
    for trial in range(40):
        n, scale = int(rng.integers(5, 2000)), rng.uniform(5.0, 150.0)
        pts = rng.uniform(0.0, scale, (n, 3)) * [1.0, 1.0, rng.uniform(0.01, 1.0)]
        if trial % 2:
            pts[n // 4:] = rng.normal(rng.uniform(0.0, scale, 3), rng.uniform(0.5, 5.0),
                                      (n - n // 4, 3))
        eps, k = rng.uniform(0.2, 4.0), int(rng.integers(1, 12))
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
        peer = np.asarray(cloud.cluster_dbscan(eps, k, False)) >= 0
        mine = dbscan_not_noise(pts, eps, k)
        np.testing.assert_array_equal(mine, peer, err_msg=f"trial {trial}")
        kept, noise = kept + int(peer.sum()), noise + int((~peer).sum())
    assert kept > 1000 and noise > 1000           # both outcomes were compared
