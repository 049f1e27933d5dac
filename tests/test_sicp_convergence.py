"""SICP along a weakly observed direction: a straight road with one short side road (a
T-junction's main road with one turning vehicle) is observed along the road only through
the side road's few points, so ICP creeps along it by a nearly constant fraction per
iteration while the RMSE hardly changes. With the defaults (the pose-step test and the
accelerated iterations) it ends where it ends from the known pose; plain iterations with the
RMSE test alone (the paper's) stop short."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fgloc.geo import se2, transform_points
from fgloc.labels import STRAIGHT
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


def test_step_tolerances_are_checked():
    for field in ("step_tol", "step_tol_deg"):
        with pytest.raises(ValueError, match=field):
            sicp(np.zeros((3, 2)), np.zeros(3), np.zeros((3, 2)), np.zeros(3), np.eye(3),
                 dataclasses.replace(SicpConfig(), **{field: -1.0}))
