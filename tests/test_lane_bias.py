"""The lanes' bias std. dev. re-estimated by EM (:class:`fgloc.registration.lane_bias.
LaneBiases`) against the closed-form maximum-likelihood condition of a one-way random-effects
model."""

import numpy as np
import pytest

from fgloc.registration.lane_bias import LaneBiases


@pytest.mark.parametrize("spread", [0.05, 0.3])
def test_em_reaches_the_maximum_likelihood_sigma(spread):
    """L lanes, lane j's data a mean offset ``y_j`` of precision ``h_j`` (1/m^2), plus one
    global parameter the lanes do not touch. From the posterior at the start sigma (the
    information and the estimate a round of the joint hands over) the EM ends where the
    marginal likelihood of ``y_j ~ N(0, sigma^2 + 1/h_j)`` is flat:
    ``sum_j (y_j^2 / s_j^2 - 1 / s_j) = 0``, ``s_j = sigma^2 + 1/h_j``."""
    rng = np.random.default_rng(4)
    L = 12
    h = rng.uniform(100.0, 2500.0, L)                      # lane data std. dev. 0.02-0.1 m
    y = rng.normal(0.0, spread, L) + rng.normal(0.0, 1.0 / np.sqrt(h))
    start = 0.1
    w0 = 1.0 / start**2
    info = np.diag(np.concatenate([[4.0], h + w0]))
    glob = np.concatenate([[0.3], h * y / (h + w0)])        # posterior means at the start
    lanes = LaneBiases(start)
    lanes.reestimate_sigma(info, glob, 1)
    s = lanes.sigma**2 + 1.0 / h
    score = np.sum(y**2 / s**2 - 1.0 / s)
    assert abs(score) < 1e-3 * np.sum(1.0 / s), (lanes.sigma, score)
    assert 0.3 * spread < lanes.sigma < 2.0 * spread


def test_sigma_keeps_its_floor_when_the_lanes_agree():
    """Lanes whose offsets are all 0: the likelihood peaks at sigma 0; the estimate stops at
    the floor (0.01 m) and reports it moved."""
    h = np.full(5, 400.0)
    info = np.diag(h + 1.0 / 0.2**2)
    lanes = LaneBiases(0.2)
    assert not lanes.reestimate_sigma(info, np.zeros(5), 0)
    assert lanes.sigma == pytest.approx(0.01)


def test_free_params_count_the_biases_the_data_fix():
    """A bias the data fix (variance far below the prior's) counts as one parameter, one only
    its prior holds (variance the prior's) as none: 2 lanes of data precision 1e6 and 1e-6
    (1/m^2) under a 0.1 m prior count about 1."""
    prior = 1.0 / 0.1**2
    info = np.diag([50.0, 1e6 + prior, 1e-6 + prior])
    assert LaneBiases(0.1).free_params(info, 1) == pytest.approx(1.0, abs=1e-3)
