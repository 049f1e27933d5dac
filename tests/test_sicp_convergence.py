"""SICP along a weakly observed direction: a straight road with one short side road (a
T-junction's main road with one turning vehicle) is observed along the road only through
the side road's few points, so ICP creeps along it by a nearly constant fraction per
iteration while the RMSE hardly changes. With the defaults (the pose-step test and the
accelerated iterations) it ends where it ends from the known pose; plain iterations with the
RMSE test alone (the paper's) stop short. An extrapolation that would raise the cost is
refused (an unguarded one slid 3 m along a road on the independent generator's junction 12)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fgloc.geo import se2, transform_points
from fgloc.labels import STRAIGHT
from fgloc.registration import sicp as sicp_module
from fgloc.registration.config import SicpConfig
from fgloc.registration.sicp import sicp


def _road(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Target samples (M, 2) of a 200 m two-lane road along x and of a 30 m side road
    leaving it at x = 20 m along y; source points (N, 2) in the target frame: vehicles on the
    main road's lanes (many) and on the side road (few), 5 cm noise."""
    rng = np.random.default_rng(seed)
    u = np.arange(-100.0, 100.0, 0.25)
    v = np.arange(0.0, 30.0, 0.25)
    target = np.vstack([np.column_stack([u, np.full_like(u, -1.75)]),
                        np.column_stack([u, np.full_like(u, 1.75)]),
                        np.column_stack([np.full_like(v, 20.0), 1.75 + v])])
    main = np.column_stack([rng.uniform(-60.0, 60.0, 1200),
                            rng.choice([-1.75, 1.75], 1200)])
    side = np.column_stack([np.full(40, 20.0), rng.uniform(4.0, 25.0, 40)])
    src = np.vstack([main, side]) + rng.normal(0.0, 0.05, (1240, 2))
    return target, src, np.full(len(target), STRAIGHT)


@pytest.mark.parametrize("seed", [1, 2])
def test_creep_along_a_weak_direction_ends_at_the_pose(seed):
    target, src_l, label = _road(seed)
    T_true = se2(0.3, -0.2, np.deg2rad(0.2))
    src = transform_points(np.linalg.inv(T_true), src_l)     # source frame: T_true maps it
    start = se2(0.3 - 0.8, -0.2, np.deg2rad(0.2))             # 0.8 m off along the road
    cfg = dataclasses.replace(SicpConfig(), max_correspondence=5.0)
    ends = {}
    plain = dataclasses.replace(cfg, step_tol=0.0, step_tol_deg=0.0, accelerate=False)
    for name, c, T0 in (("default", cfg, start), ("plain", plain, start),
                        ("from the truth", cfg, T_true)):
        res = sicp(src, np.full(len(src), STRAIGHT), target, label, T0, c)
        assert res.converged, (name, res.stop_reason)
        ends[name] = res.T[:2, 2] - T_true[:2, 2]
    err = {k: float(np.hypot(*v)) for k, v in ends.items()}
    assert err["from the truth"] < 0.05, ends   # the data's own minimum is the known pose
    assert err["default"] < 0.05, ends
    assert err["plain"] > max(0.1, 2.0 * err["default"]), ends


def test_an_extrapolation_that_raises_the_cost_is_refused(monkeypatch):
    """The first extrapolation proposed is replaced by a 5 m jump along the road (an
    overshoot of the geometric series where the steps shrink slowly): there the side road's
    points fall out of range and the main road's fit alike, so a jump taken would stay; it
    raises the cost and is refused, and the later, true extrapolations bring SICP to the pose."""
    target, src_l, label = _road(1)
    T_true = se2(0.3, -0.2, np.deg2rad(0.2))
    src = transform_points(np.linalg.inv(T_true), src_l)
    real_extrapolation = sicp_module._extrapolation
    proposed = []

    def overshoot_once(now, last, centre, turn):
        real = real_extrapolation(now, last, centre, turn)
        if real is not None:
            proposed.append(real)
            if len(proposed) == 1:
                return se2(5.0 * np.sign(now[0]), 0.0, 0.0)
        return real

    monkeypatch.setattr(sicp_module, "_extrapolation", overshoot_once)
    cfg = dataclasses.replace(SicpConfig(), max_correspondence=5.0)
    res = sicp(src, np.full(len(src), STRAIGHT), target, label,
               se2(0.3 - 0.8, -0.2, np.deg2rad(0.2)), cfg)
    assert len(proposed) >= 2                    # the jump, then the true extrapolations
    assert res.converged, res.stop_reason
    assert np.hypot(*(res.T[:2, 2] - T_true[:2, 2])) < 0.05


def test_step_tolerances_are_checked():
    for field in ("step_tol", "step_tol_deg"):
        with pytest.raises(ValueError, match=field):
            sicp(np.zeros((3, 2)), np.zeros(3), np.zeros((3, 2)), np.zeros(3), np.eye(3),
                 dataclasses.replace(SicpConfig(), **{field: -1.0}))
