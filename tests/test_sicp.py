"""Semantic ICP in SE(2): label gating, soft/hard/none modes, robust kernels, stop reasons,
dropped labels, information matrix and KD-tree reuse."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial import cKDTree

import fgloc.registration.sicp as sicp_mod
from fgloc.config import Config, dump_config, load_config
from fgloc.geo import se2, se2_inv, se2_params, transform_points
from fgloc.labels import LEFT, RIGHT, STRAIGHT
from fgloc.registration.config import SicpConfig
from fgloc.registration.sicp import SemanticTargets, sicp

STEP = 0.05  # target sampling (m) of the constructed lane centre lines


def _line(a, b, u: np.ndarray | None = None) -> np.ndarray:
    """Points on the segment a -> b: every STEP m, or at the fractions u."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if u is None:
        u = np.linspace(0.0, 1.0, int(round(np.linalg.norm(b - a) / STEP)) + 1)
    return a + u[:, None] * (b - a)


def _arc(c, r: float, a0: float, a1: float, u: np.ndarray | None = None) -> np.ndarray:
    """Points on the circular arc of centre c and radius r (m) from angle a0 to a1 (rad)."""
    if u is None:
        u = np.linspace(0.0, 1.0, int(round(abs(a1 - a0) * r / STEP)) + 1)
    a = a0 + u * (a1 - a0)
    return np.asarray(c, float) + r * np.column_stack([np.cos(a), np.sin(a)])


def _stack(parts: list[tuple[np.ndarray, int]]) -> tuple[np.ndarray, np.ndarray]:
    return np.vstack([p for p, _ in parts]), np.concatenate([np.full(len(p), k) for p, k in parts])


def junction(seed: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Target and source (true pose = identity) of a junction, labelled.

    Target: lane centre lines of an east-west road (lanes y = 0, 3.5, 7), a north-south road
    (x = 15, 18.5), all straight; a left-turn arc (radius 15 m) from lane y = 0 into x = 15 and a
    right-turn arc (radius 18.5 m) from lane y = 7 south into x = 18.5, crossing the straight
    lanes. Source: points at random places on the left arc (60), the right arc (30) and the
    northbound lane x = 15 after the turn (30), like trajectory points of turning vehicles.
    Shifted by a lane width, the turn points lie on or next to straight lanes.
    """
    parts = [(_line((-60, y), (40, y)), STRAIGHT) for y in (0.0, 3.5, 7.0)]
    parts += [(_line((x, -30), (x, 60)), STRAIGHT) for x in (15.0, 18.5)]
    parts += [(_arc((0, 15), 15.0, -np.pi / 2, 0.0), LEFT)]
    parts += [(_arc((0, -11.5), 18.5, np.pi / 2, 0.0), RIGHT)]
    txy, tl = _stack(parts)
    g = np.random.default_rng(seed)
    sxy, sl = _stack([
        (_arc((0, 15), 15.0, -np.pi / 2, 0.0, g.uniform(0, 1, 60)), LEFT),
        (_arc((0, -11.5), 18.5, np.pi / 2, 0.0, g.uniform(0, 1, 30)), RIGHT),
        (_line((15, 16), (15, 45), g.uniform(0, 1, 30)), STRAIGHT),
    ])
    return txy, tl, sxy, sl


def pose_error(T: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """(translation error m, |yaw error| deg) of T against T_true."""
    x, y, yaw = se2_params(se2_inv(T_true) @ T)
    return float(np.hypot(x, y)), abs(float(np.rad2deg(yaw)))


@pytest.fixture(scope="module")
def displaced():
    """The junction with the source displaced by about a lane width and 3 degrees."""
    txy, tl, sxy, sl = junction()
    T_true = se2(0.4, -3.5, np.deg2rad(-3.0))  # maps the displaced source onto the target
    return txy, tl, transform_points(se2_inv(T_true), sxy), sl, T_true


def test_sicp_recovers_where_plain_icp_takes_the_wrong_lane(displaced):
    txy, tl, src, sl, T_true = displaced
    plain = sicp(src, sl, txy, tl, np.eye(3), SicpConfig(mode="none"))
    hard = sicp(src, sl, txy, tl, np.eye(3), SicpConfig(mode="hard"))
    e_plain, e_hard = pose_error(plain.T, T_true), pose_error(hard.T, T_true)
    assert plain.converged and e_plain[0] > 1.5, e_plain  # a stable wrong answer
    assert hard.converged and hard.stop_reason == "rmse_converged"
    assert e_hard[0] < 0.02 and e_hard[1] < 0.05, e_hard
    assert hard.fitness == 1.0 and hard.inlier_rmse < 0.02
    assert hard.label_counts == {"straight": 30, "left": 60, "right": 30}
    assert hard.dropped_labels == [] and hard.warnings == []
    assert np.all(hard.target_index >= 0)
    assert np.all(tl[hard.target_index] == sl)  # hard: every match within its own label


def test_soft_and_hard_agree_on_clean_data():
    txy, tl, sxy, sl = junction(seed=1)
    T_true = se2(0.5, 0.6, np.deg2rad(1.0))
    src = transform_points(se2_inv(T_true), sxy)
    hard = sicp(src, sl, txy, tl, np.eye(3), SicpConfig(mode="hard"))
    soft = sicp(src, sl, txy, tl, np.eye(3), SicpConfig(mode="soft"))
    assert pose_error(hard.T, T_true)[0] < 0.02
    dt, dyaw = pose_error(soft.T, hard.T)
    assert dt < 1e-3 and dyaw < 0.01


def test_soft_compatibility_zero_forbids_a_pair():
    """A source label whose compatible targets are all forbidden gets no correspondence."""
    txy, tl, sxy, sl = junction()
    compat = [[1.0, 0.1, 0.1], [0.0, 0.0, 0.0], [0.1, 0.1, 1.0]]
    res = sicp(sxy, sl, txy, tl, np.eye(3), SicpConfig(mode="soft", compatibility=compat))
    assert res.label_counts["left"] == 0 and res.label_counts["right"] == 30


def scattered(n: int, seed: int, spacing: float = 10.0) -> np.ndarray:
    """n points on a jittered grid, at least about ``spacing`` m apart (isolated features)."""
    g = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(n)))
    ij = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)[:n]
    return ij * spacing + g.uniform(-1.0, 1.0, (n, 2))


def test_robust_kernels_resist_gross_outliers():
    """10 % of the source are copies displaced by 3 m one way: they bias plain least squares."""
    txy = scattered(100, seed=0)
    tl = np.zeros(100, dtype=np.int64)
    T_true = se2(0.3, -0.2, np.deg2rad(0.5))
    bad = txy[:10] + np.array([0.0, 3.0])
    src = transform_points(se2_inv(T_true), np.vstack([txy, bad]))
    sl = np.zeros(len(src), dtype=np.int64)
    base = SicpConfig(mode="none", min_correspondence=5.0, kernel_scale=0.5)
    err = {k: pose_error(sicp(src, sl, txy, tl, np.eye(3),
                              dataclasses.replace(base, kernel=k)).T, T_true)[0]
           for k in ("none", "huber", "cauchy")}
    assert err["none"] > 0.15
    assert err["huber"] < 0.5 * err["none"]
    assert err["cauchy"] < 0.01


def test_user_weights_zero_exclude_points():
    txy = scattered(100, seed=0)
    tl = np.zeros(100, dtype=np.int64)
    src = np.vstack([txy, txy[:10] + np.array([0.0, 3.0])])
    w = np.r_[np.ones(100), np.zeros(10)]
    res = sicp(src, np.zeros(110), txy, tl, np.eye(3), SicpConfig(mode="none",
               min_correspondence=5.0), weights=w)
    assert pose_error(res.T, np.eye(3))[0] < 1e-9
    assert np.all(res.target_index[100:] == -1) and res.fitness == pytest.approx(100 / 110)


def test_stop_reasons(displaced):
    txy, tl, src, sl, _ = displaced
    done = sicp(src, sl, txy, tl, np.eye(3), SicpConfig())
    assert done.converged and done.stop_reason == "rmse_converged"
    assert done.iterations < 100 and done.final_range == 1.5
    capped = sicp(src, sl, txy, tl, np.eye(3), SicpConfig(max_iterations=5))
    assert not capped.converged and capped.stop_reason == "max_iterations"
    assert capped.iterations == 5
    none = sicp(src + 1000.0, sl, txy, tl, np.eye(3), SicpConfig())
    assert not none.converged and none.stop_reason == "too_few_correspondences"
    assert none.covariance is None and none.degeneracy is None and none.fitness == 0.0


def test_label_with_too_few_points_is_dropped_with_a_warning():
    txy, tl, sxy, sl = junction()
    keep = (sl != RIGHT) | (np.cumsum(sl == RIGHT) <= 4)  # 4 right-turn source points remain
    res = sicp(sxy[keep], sl[keep], txy, tl, np.eye(3), SicpConfig(min_points_per_label=10))
    assert res.dropped_labels == ["right"]
    assert len(res.warnings) == 1 and "right" in res.warnings[0]
    assert res.label_counts["right"] == 0 and res.label_counts["left"] == 60
    assert res.converged and pose_error(res.T, np.eye(3))[0] < 0.01


def test_information_matches_finite_differences():
    """Noisy case: Sum w J^T J / sigma^2 with J by central differences and the documented
    sigma^2; noise-free case: the numerical Hessian of the weighted cost / sigma_floor^2."""
    g = np.random.default_rng(4)
    txy = scattered(30, seed=1)
    T_true = se2(0.2, -0.1, 0.05)
    cfg = SicpConfig(mode="none", info_window=0.0, min_correspondence=3.0)

    def cost_hessian(res, src, w, sigma):
        y = txy[res.target_index]

        def cost(x):
            return 0.5 * np.sum(w * np.sum((transform_points(se2(*x), src) - y) ** 2, 1))

        x0, h, hess = np.array(se2_params(res.T)), 1e-4, np.zeros((3, 3))
        for i in range(3):
            for j in range(3):
                ei, ej = np.eye(3)[i] * h, np.eye(3)[j] * h
                hess[i, j] = (cost(x0 + ei + ej) - cost(x0 + ei - ej) - cost(x0 - ei + ej)
                              + cost(x0 - ei - ej)) / (4 * h * h)
        return hess / sigma**2

    w = g.uniform(0.5, 2.0, 30)
    clean = transform_points(se2_inv(T_true), txy)
    res = sicp(clean, np.zeros(30), txy, np.zeros(30), np.eye(3), cfg, weights=w)
    assert res.sigma == cfg.sigma_floor
    wn = w / w.mean()
    hess = cost_hessian(res, clean, wn, res.sigma)
    np.testing.assert_allclose(res.information, hess, rtol=1e-4, atol=1e-6 * np.abs(hess).max())

    noisy = clean + g.normal(0.0, 0.1, clean.shape)
    res = sicp(noisy, np.zeros(30), txy, np.zeros(30), np.eye(3), cfg, weights=w)
    x0, h = np.array(se2_params(res.T)), 1e-6
    jac = np.stack([(transform_points(se2(*(x0 + h * e)), noisy)
                     - transform_points(se2(*(x0 - h * e)), noisy)) / (2 * h)
                    for e in np.eye(3)], axis=-1)  # (n, 2, 3)
    r2 = np.sum((transform_points(res.T, noisy) - txy[res.target_index]) ** 2, axis=1)
    sigma2 = np.sum(wn * r2) / (2 * 30 - 3)
    assert res.sigma == pytest.approx(np.sqrt(sigma2)) and res.sigma > 0.05
    expected = np.einsum("n,nia,nib->ab", wn, jac, jac) / sigma2
    np.testing.assert_allclose(res.information, expected, rtol=1e-6)
    np.testing.assert_allclose(res.covariance, np.linalg.inv(expected), rtol=1e-6)


def straight_road(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Target: a 7 m wide straight road along x (grid every 0.5 m, x in [-60, 60]) and source:
    200 noisy trajectory points on its two lane centres (x in [-40, 40]) shifted slightly."""
    gx, gy = np.meshgrid(np.arange(-60.0, 60.01, 0.5), np.arange(-3.5, 3.51, 0.5))
    txy = np.column_stack([gx.ravel(), gy.ravel()]) + np.array([30.0, 20.0])
    g = np.random.default_rng(seed)
    src = np.column_stack([g.uniform(-40, 40, 200), np.repeat([-1.75, 1.75], 100)])
    src = src + g.normal(0.0, 0.1, src.shape) + np.array([30.3, 20.2])
    return txy, src


def test_straight_road_is_weak_along_the_road():
    txy, src = straight_road()
    res = sicp(src, np.zeros(200), txy, np.zeros(len(txy)), np.eye(3), SicpConfig())
    dg = res.degeneracy
    assert abs(dg.weakest_direction[0]) > 0.99  # (du, dv, da): along x, the road
    assert dg.condition_number > 3.0
    assert res.covariance is not None
    # a wider neighbourhood sees more of the strip: sliding looks weaker still
    wide = sicp(src, np.zeros(200), txy, np.zeros(len(txy)), np.eye(3),
                SicpConfig(info_window=15.0)).degeneracy
    assert abs(wide.weakest_direction[0]) > 0.99 and wide.condition_number > 10.0
    # without the target-shape weights the sliding direction looks as firm as any other
    iso = sicp(src, np.zeros(200), txy, np.zeros(len(txy)), np.eye(3),
               SicpConfig(info_window=0.0)).degeneracy
    assert iso.condition_number < 1.5 and abs(iso.weakest_direction[0]) < 0.5


def test_kd_trees_built_once_and_reused(monkeypatch, displaced):
    txy, tl, src, sl, _ = displaced
    built: list[int] = []

    class CountingTree(cKDTree):
        def __init__(self, data, *args, **kwargs):
            built.append(len(data))
            super().__init__(data, *args, **kwargs)

    monkeypatch.setattr(sicp_mod, "cKDTree", CountingTree)
    sicp(src, sl, txy, tl, np.eye(3), SicpConfig())
    assert sorted(built) == sorted(np.bincount(tl).tolist())  # one tree per label per call
    built.clear()
    targets = SemanticTargets.build(txy, tl)
    first = sicp(src, sl, targets, None, np.eye(3), SicpConfig())
    assert len(built) == 3
    second = sicp(src, sl, targets, None, np.eye(3), SicpConfig(mode="soft"))
    assert len(built) == 3  # reused, not rebuilt
    sicp(src, sl, targets, None, np.eye(3), SicpConfig(mode="none"))
    assert built[3:] == [len(txy)]  # plain ICP: one tree over every target point
    assert first.converged and second.converged


def test_bad_inputs_raise():
    txy, tl, sxy, sl = junction()
    with pytest.raises(ValueError, match="mode"):
        sicp(sxy, sl, txy, tl, np.eye(3), SicpConfig(mode="fuzzy"))
    with pytest.raises(ValueError, match="compatibility"):
        sicp(sxy, sl, txy, tl, np.eye(3), SicpConfig(compatibility=[[1.0]]))
    with pytest.raises(ValueError, match="compatibility"):
        sicp(sxy, sl, txy, tl, np.eye(3), SicpConfig(compatibility=[[1.0], [1.0, 0.1]]))
    with pytest.raises(ValueError, match="label codes"):
        sicp(sxy, np.full(len(sxy), 7), txy, tl, np.eye(3), SicpConfig())
    with pytest.raises(ValueError, match="source_xy"):
        sicp(sxy[:, :1], sl, txy, tl, np.eye(3), SicpConfig())


def test_config_round_trips_through_toml(tmp_path):
    cfg = Config(sicp=SicpConfig(mode="soft", kernel="cauchy",
                                 compatibility=[[1.0, 0.2, 0.0], [0.2, 1.0, 0.0], [0, 0, 1.0]]))
    p = tmp_path / "c.toml"
    p.write_text(dump_config(cfg))
    assert load_config(p).sicp == cfg.sicp


def _two_roads(seed: int, tau: float = 0.3, noise: float = 0.05
               ) -> tuple[SemanticTargets, np.ndarray, np.ndarray, np.ndarray]:
    """Lane lines of an east-west road (y = 0, driven east) and a north-south one (x = 15,
    driven north) with their directions; source points (true pose = identity) of 8 vehicles
    along the first (60 points each) and 2 along the second: every vehicle drives its lane
    off by its own offset ~ N(0, tau^2) (all of its points share it), each point with noise
    ``noise`` (m) across the lane. Returns targets, source xy, directions and track ids."""
    a, b = _line((-60, 0), (40, 0)), _line((15, -30), (15, 60))
    targets = SemanticTargets.build(np.vstack([a, b]), np.zeros(len(a) + len(b)),
                                    np.vstack([np.tile([1.0, 0.0], (len(a), 1)),
                                               np.tile([0.0, 1.0], (len(b), 1))]))
    g = np.random.default_rng(seed)
    xy, direction, track = [], [], []
    for j in range(10):
        s = g.uniform(-50.0, 30.0, 60) if j < 8 else g.uniform(5.0, 50.0, 60)
        off = g.normal(0.0, tau) + g.normal(0.0, noise, 60)
        xy.append(np.column_stack([s, off]) if j < 8 else np.column_stack([15.0 + off, s]))
        direction.append(np.tile([1.0, 0.0] if j < 8 else [0.0, 1.0], (60, 1)))
        track.append(np.full(60, j))
    return targets, np.vstack(xy), np.vstack(direction), np.concatenate(track)


def test_track_covariance_counts_the_evidence_per_track():
    """Vehicles drive their lanes off by a common offset each (tau 0.3 m) with little point
    noise (0.05 m): the points of one vehicle are not independent. Over 40 draws the per-track
    covariance is calibrated (mean NEES of (tx, ty, yaw) near 3 against the known truth, the
    identity), the per-point one claims far too much (NEES in the hundreds); along the east-west
    road, whose position only the 2 north-south vehicles fix, its std. dev. is about tau /
    sqrt(2)."""
    from fgloc.registration.sicp import track_covariance

    cfg = SicpConfig()
    nees_track, nees_point, sd_x = [], [], []
    for seed in range(40):
        targets, xy, direction, track = _two_roads(seed)
        res = sicp(xy, np.zeros(len(xy)), targets, None, np.eye(3), cfg,
                   source_direction=direction)
        e = np.array(se2_params(res.T))
        cov = track_covariance(res, xy, track, targets, cfg)
        nees_track.append(e @ np.linalg.solve(cov, e))
        nees_point.append(e @ np.linalg.solve(res.covariance, e))
        sd_x.append(np.sqrt(cov[0, 0]))
    assert 1.5 < np.mean(nees_track) < 5.0
    assert np.mean(nees_point) > 30.0
    assert 0.12 < np.median(sd_x) < 0.35
    # without directions on the target there is no normal to take the residual along
    plain = SemanticTargets.build(targets.xy, targets.label)
    assert track_covariance(sicp(xy, np.zeros(len(xy)), plain, None, np.eye(3), cfg), xy,
                            track, plain, cfg) is None


@pytest.mark.parametrize("w", [1.0, 1.0 / 3.0, 0.0])
def test_target_weights_scale_the_pull_of_what_is_matched_there(w):
    """Two point-symmetric sets of isolated features, as many in each: one mapped where it is
    (weight 1), one mapped 0.5 m east of where it is seen (weight w). Weighted least squares
    moves the source by the weighted mean offset, 0.5 w / (1 + w) m east, without a turn."""
    a = scattered(50, seed=0) + 5.0
    b = scattered(50, seed=1) + np.array([5.0, -80.0])
    src = np.vstack([a, -a, b, -b])
    offset = np.r_[np.zeros(2 * len(a)), np.full(2 * len(b), 0.5)]
    targets = SemanticTargets.build(src + np.column_stack([offset, np.zeros_like(offset)]),
                                    np.zeros(len(src)), weight=np.where(offset > 0.0, w, 1.0))
    res = sicp(src, np.zeros(len(src)), targets, None, np.eye(3),
               SicpConfig(mode="none", min_correspondence=2.0))
    x, y, yaw = se2_params(res.T)
    assert x == pytest.approx(0.5 * w / (1.0 + w), abs=1e-6)
    assert abs(y) < 1e-6 and abs(yaw) < 1e-8
    np.testing.assert_allclose(res.weights, np.where(offset > 0.0, w, 1.0))


def test_target_weights_are_checked():
    txy, tl = np.zeros((3, 2)), np.zeros(3)
    with pytest.raises(ValueError, match="target weight"):
        SemanticTargets.build(txy, tl, weight=np.ones(2))
    with pytest.raises(ValueError, match="target weight.*from 0.5 to 1.5"):
        SemanticTargets.build(txy, tl, weight=np.array([0.5, 1.0, 1.5]))
    with pytest.raises(ValueError, match="NaN"):
        SemanticTargets.build(txy, tl, weight=np.array([np.nan, 1.0, 1.0]))
