"""The joint's track-robust pose covariance against Monte Carlo truth on a linear model with
errors shared within clusters (the tracks), which the model covariance ignores."""

from __future__ import annotations

import numpy as np
import pytest

from fgloc.registration.sicp import track_robust_covariance

SIGMA = 0.1                           # modelled per-point noise
PRIOR = np.array([1e-6, 1e-6, 1.0 / 20.0**2])   # prior information; the third is unobserved


def _replications(tau: float, n_rep: int = 400, clusters: int = 40, per: int = 10):
    """Estimates, model and robust covariances of theta = (intercept, slope, unobserved)
    from y = a + b x + u_c + e: u_c ~ N(0, tau^2) shared by a cluster, e ~ N(0, SIGMA^2);
    the model takes only e (weighted least squares with a prior at 0)."""
    rng = np.random.default_rng(7)
    x = rng.uniform(-1.0, 1.0, (clusters, per))
    A = np.stack([np.ones_like(x), x, np.zeros_like(x)], axis=-1)        # (C, n, 3)
    Af = A.reshape(-1, 3)
    info = Af.T @ Af / SIGMA**2 + np.diag(PRIOR)
    theta = np.array([0.3, -0.5, 0.0])
    est, robust = [], []
    for _ in range(n_rep):
        y = A @ theta + rng.normal(0.0, tau, (clusters, 1)) + rng.normal(0.0, SIGMA, x.shape)
        th = np.linalg.solve(info, Af.T @ y.reshape(-1) / SIGMA**2)
        scores = np.einsum("cni,cn->ci", A, A @ th - y) / SIGMA**2
        est.append(th)
        robust.append(track_robust_covariance(info, scores, PRIOR))
    return np.array(est), np.linalg.inv(info), np.mean(robust, axis=0)


@pytest.mark.parametrize("tau", [0.1, 0.0])
def test_robust_covariance_matches_the_spread_of_the_estimates(tau):
    est, model, robust = _replications(tau)
    empirical = np.cov(est[:, :2].T)
    ratio = np.diag(robust)[:2] / np.diag(empirical)
    assert np.all((ratio > 0.75) & (ratio < 1.33)), (ratio, np.diag(empirical))
    if tau > 0:
        # the shared errors make the intercept ~11x as uncertain as the model says
        assert empirical[0, 0] > 5 * model[0, 0] and robust[0, 0] > 5 * model[0, 0]
    # never below the model, and an unobserved direction keeps its prior variance
    assert np.all(np.linalg.eigvalsh(robust - model) > -1e-12)
    assert robust[2, 2] == pytest.approx(20.0**2, rel=1e-6)
