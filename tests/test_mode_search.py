"""The coarse mode search (:func:`fgloc.coarse.localize.lane_modes`) keeps its modes on the
full data's lane scores: an end of the subsample ICP that falls below ``mode_margin`` of the
best only on the subsample's noisier score still reaches the polishing
(``mode_rough_margin``), and the full data decides. Closed form on three straight lanes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fgloc.coarse import LaneCentres
from fgloc.coarse.icp import IcpOutcome
from fgloc.coarse.localize import _Refined, lane_modes
from fgloc.config import CoarseConfig


def _lanes() -> LaneCentres:
    """Three lanes along +x at y = 10, 13.5 and 17 m, samples every 0.5 m."""
    s = np.arange(-80.0, 80.0 + 1e-9, 0.5)
    n = len(s)
    xy = np.vstack([np.column_stack([s, np.full(n, y)]) for y in (10.0, 13.5, 17.0)])
    return LaneCentres(xy, np.tile([0.0, 1.0], (3 * n, 1)), np.zeros(3 * n, bool),
                       np.zeros(3 * n, np.int64), np.repeat([0, 1, 2], n))


def _points() -> np.ndarray:
    """500 points in the sensor frame, ordered so that every tenth (the 50-point subsample)
    favours the pose B one lane over (y + 3.5 m) while the whole set favours the pose A at
    the origin: 400 on y = 10 and 13.5 (on lanes for both poses), 70 on y = 17 (on a lane for
    A only, B puts them at 20.5), 30 on y = 6.5 (for B only, A leaves them 3.5 m off)."""
    x = np.arange(500) * 0.25 - 62.5
    y = np.where(np.arange(500) % 2, 10.0, 13.5)
    pts = np.column_stack([x, y])
    b_only = np.r_[np.arange(0, 50, 10), np.arange(1, 500, 10)[:25]]   # 5 sampled, 25 not
    a_only = np.r_[np.arange(50, 70, 10), np.arange(3, 500, 10)[:68]]  # 2 sampled, 68 not
    pts[b_only, 1], pts[a_only, 1] = 6.5, 17.0
    return np.column_stack([pts, np.zeros(500)])


@pytest.mark.parametrize("rough, kept_a", [(0.90, True), (0.97, False)])
def test_a_tie_on_the_full_data_is_kept_whatever_its_subsample_score(rough, kept_a) -> None:
    """Subsample scores: A (43 + 2) / 50, B (43 + 5) / 50: A at 0.94 of B. Full data: A (400
    + 70) / 500, B (400 + 30) / 500: B at 0.91 of A (less the points' distance to the lane
    samples 0.5 m apart; the lanes are straight, so the poses slide along x). With the
    default rough share A is polished and is the best mode; a rough share equal to
    ``mode_margin`` (the former rule) drops it before the full data is seen and leaves B's
    lane as the only one of the modes."""
    cfg = CoarseConfig(mode_points=50, visible_side_offset=0.0,
                       visible_side_offset_broadside=0.0, lane_doppler_gate_deg=90.0,
                       mode_rough_margin=rough)
    assert CoarseConfig().mode_rough_margin == 0.90
    a, b = np.zeros(3), np.array([0.0, 3.5, 0.0])
    final = _Refined(a, np.eye(3), 6.0, IcpOutcome(a, True, 1))
    src = _points()
    modes = lane_modes([(1.0, a), (1.0, b)], final, src, np.ones(len(src), bool), _lanes(),
                       cfg)
    best = modes[0][1]
    assert bool(abs(best[1]) < 0.1) == kept_a
    assert any(abs(p[1] - b[1]) < 0.1 for _, p in modes) != kept_a
    if kept_a:
        # 470 points on a lane, each within 0.25 m of its nearest sample (0.5 m apart): the
        # score's 1 - d / tau (tau = 2 m) is at least 0.875 for each
        assert 470 / 500 * (1.0 - 0.25 / 2.0) <= modes[0][0] <= 470 / 500
        assert all(s >= cfg.mode_margin * modes[0][0] for s, _ in modes)


def test_the_rough_share_is_validated() -> None:
    for bad in ({"mode_rough_margin": 0.0}, {"mode_rough_margin": 0.99},
                {"mode_margin": 1.2}):
        with pytest.raises(ValueError, match="mode_rough_margin <= mode_margin"):
            dataclasses.replace(CoarseConfig(), **bad)
