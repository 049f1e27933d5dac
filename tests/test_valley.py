"""A flat valley of the pose (fgloc.coarse.valley, fgloc.registration.modes.track_valley):
tied modes that are samples of a continuum along a road no vehicle turns off, reported as the
line they lie on with a covariance over it; known truth from closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from fgloc.coarse.valley import collinear, find_valley, flat_extent
from fgloc.config import CoarseConfig
from fgloc.geo import se2, se2_to_se3
from fgloc.registration.modes import (
    AMBIGUOUS,
    ModeChoice,
    ModeFit,
    PositionPrior,
    choose_mode,
    track_valley,
)

CFG = CoarseConfig()


def _fit(x: float, y: float, costs: np.ndarray) -> ModeFit:
    T = se2(x, y, 0.3)
    return ModeFit(T, se2_to_se3(T), None, np.asarray(costs, float), 0.7, True, np.eye(3))


def test_extent_ends_where_the_data_or_the_prior_end_it():
    flat = (-6.0, 12.0)                           # the data tie every pose in here

    def z_at(s: float) -> float:
        return 0.0 if flat[0] <= s <= flat[1] else np.inf

    s, open_lo, open_hi = flat_extent(np.array([0.0, 2.0, 4.0]), 1.0, 5.0, CFG, z_at)
    assert (s[0], s[-1]) == (-6.0, 12.0) and not open_lo and not open_hi
    assert np.allclose(np.diff(s), 0.5)
    # flat everywhere: the scan stops mode_z prior std. devs. from the prior (1 +- 15 m)
    s, open_lo, open_hi = flat_extent(np.array([0.0, 2.0]), 1.0, 5.0, CFG, lambda s: 0.0)
    assert s[0] == pytest.approx(-14.0) and s[-1] == pytest.approx(16.0)
    assert open_lo and open_hi
    # a pose between the modes the data rule out: distinct modes, no valley
    assert flat_extent(np.array([0.0, 2.0]), 1.0, 5.0, CFG,
                       lambda s: 5.0 if 0.7 < s < 1.3 else 0.0) is None


def test_collinear_needs_one_yaw_and_one_line():
    along = np.array([[0.0, 0.0, 0.1], [3.0, 4.0, 0.1], [6.0, 8.2, 0.1]])
    assert np.allclose(np.abs(collinear(along, CFG)), [0.6, 0.8], atol=0.02)
    assert collinear(along[:1], CFG) is None
    assert collinear(along + [[0, 0, 0], [0, 0, 0.05], [0, 0, 0]], CFG) is None  # 2.9 deg
    assert collinear(np.array([[0.0, 0.0, 0.0], [4.0, 0.0, 0.0], [2.0, 3.0, 0.0]]), CFG) is None


def test_posterior_of_a_long_valley_is_the_prior_and_of_a_short_one_uniform():
    poses = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    long = find_valley(poses, 0, np.array([1.0, 7.0]), 5.0, CFG, lambda xy: 0.0)
    mean, var = long.posterior()
    # N(1, 5^2) cut at +-3 sd: mean 1, variance 0.973 * 25 (+ the step's 0.25 / 12)
    assert mean == pytest.approx(1.0, abs=1e-6) and var == pytest.approx(24.33 + 0.02, rel=0.01)
    short = find_valley(poses, 0, np.array([1.0, 0.0]), 5.0, CFG,
                        lambda xy: 0.0 if -0.1 <= xy[0] <= 2.1 else np.inf)
    mean, var = short.posterior()
    assert (short.lo, short.hi) == (0.0, 2.0)
    assert mean == pytest.approx(1.0) and var == pytest.approx(0.5 + 0.25 / 12, rel=0.01)
    # inside the valley the scale-free statistic is no evidence: tied poses weigh alike
    tilted = find_valley(poses, 0, np.array([1.0, 0.0]), 5.0, CFG,
                         lambda xy: (2.5 if xy[0] > 1.01 else -1.0) if -0.1 <= xy[0] <= 2.1
                         else np.inf)
    assert tilted.posterior() == pytest.approx(short.posterior())


def test_modes_sampled_along_a_road_report_the_road_and_cover_the_truth():
    """Twelve tracks on a road along x that ends 9 m ahead and 8 m behind: every shift in
    between fits them alike. The coarse modes sampled it at x = 2, 4, 6 (the truth, x = -1,
    3 m beyond the last sample, as on robustness "combined" seed 4); the approximate position
    x = 0.5. Before, the result held only the three samples: the truth 3 m from all of them."""
    n = 12

    def cost_at(fit: ModeFit, T: np.ndarray) -> np.ndarray:
        x = T[0, 2]
        return np.ones(n) * (1.0 if -8.0 <= x <= 9.0 else 3.0)

    fits = [_fit(x, 0.0, np.ones(n)) for x in (2.0, 4.0, 6.0)]
    choice = choose_mode(fits, CFG)
    assert choice.status == AMBIGUOUS and len(choice.tied) == 3
    truth = np.array([-1.0, 0.0, 0.3])
    assert min(np.hypot(*(f.sensor[:2] - truth[:2])) for f in choice.fits) > 2.9
    prior = PositionPrior(np.array([0.5, 1.0]), 5.0)
    valley = track_valley(choice, cost_at, prior, CFG)
    assert valley is not None and valley.distance(truth[:2]) < 1e-9
    assert valley.lo + valley.origin[0] == pytest.approx(-8.0)
    assert valley.hi + valley.origin[0] == pytest.approx(9.0)
    assert not valley.open_lo and not valley.open_hi
    with_valley = ModeChoice(choice.fits, choice.z, choice.tied, valley)
    reported = with_valley.reported()
    assert reported[1] == pytest.approx(0.0) and reported[2] == pytest.approx(0.3)
    assert -1.0 < reported[0] < 2.0           # pulled from the samples towards the prior
    cov = with_valley.covariance(CFG)
    e = truth - reported
    assert e @ np.linalg.solve(cov, e) < 1.0
    assert np.sqrt(cov[0, 0]) > 3.0 and np.sqrt(cov[1, 1]) == pytest.approx(0.5, rel=0.01)
    assert "not determined" in with_valley.warnings("joint")[0]
    assert "both ends set by the data" in with_valley.warnings("joint")[0]
    # every track costlier between the modes at x = 4 and 6 (at 5 +- 0.6): distinct modes,
    # not samples of one road; no valley, the modes stand
    assert track_valley(choice, lambda f, T: np.ones(n) * (1.0 + (abs(T[0, 2] - 5.0) < 0.6)),
                        prior, CFG) is None


def test_valley_is_scanned_against_the_cost_at_the_fits_own_pose():
    """A joint fit keeps its start's per-track costs when the start fit the data better
    (:func:`fgloc.registration.joint.joint_from_tracks`): they are another scoring than
    ``cost_at`` at the fit's pose. The valley compares poses on the line with the fit's pose
    under one scoring: the road here ends at x = -8 and 9 m (every track 2 costlier beyond),
    which a baseline of the carried costs (the same values in another order) would hide."""
    n = 12
    b = np.arange(1.0, n + 1.0)

    def cost_at(fit: ModeFit, T: np.ndarray) -> np.ndarray:
        return b + (0.0 if -8.0 <= T[0, 2] <= 9.0 else 2.0)

    carried = b[::-1].copy()                      # the start's costs: another scoring
    fits = [_fit(x, 0.0, carried) for x in (2.0, 4.0, 6.0)]
    choice = choose_mode(fits, CFG)
    valley = track_valley(choice, cost_at, PositionPrior(np.array([0.5, 1.0]), 50.0), CFG)
    assert valley is not None
    assert valley.lo + valley.origin[0] == pytest.approx(-8.0)
    assert valley.hi + valley.origin[0] == pytest.approx(9.0)
