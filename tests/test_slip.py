"""Starts one lane over for the far tracks (fgloc.registration.slip) and what they do to a
fit whose far vehicles slipped a lane (issue 22, the independent generator's junction 12
seed 2), on a synthetic road: closed-form turns and a SICP run against known truth."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fgloc.config import Config
from fgloc.geo import se2, transform_points
from fgloc.registration.config import SicpConfig
from fgloc.registration.modes import ModeFit, choose_mode, merge_modes, track_costs
from fgloc.registration.sicp import SemanticTargets, sicp
from fgloc.registration.slip import lane_spacing, slip_starts
from fgloc.registration.source import SourceCloud

SENSOR = np.array([0.0, -20.0])
STEP = 0.25


def _road() -> SemanticTargets:
    """Two lanes driven +x at y = 0 and y = 3 m (lanes 0, 1) and one driven -x at y = -3.5 m
    (lane 2), x from -20 to 200 m, one label."""
    x = np.arange(-20.0, 200.0, STEP)
    xy = np.vstack([np.column_stack([x, np.full_like(x, y)]) for y in (0.0, 3.0, -3.5)])
    direction = np.vstack([np.tile(d, (len(x), 1)) for d in ([1, 0], [1, 0], [-1, 0])])
    lane = np.repeat([0, 1, 2], len(x))
    return SemanticTargets.build(xy, np.zeros(len(xy)), direction.astype(float), lane=lane)


def _cloud(tracks: list[tuple[int, float, float, float, int, float]],
           rng: np.random.Generator) -> SourceCloud:
    """Per (track id, x from, x to, lane y, heading sign, lateral noise std. dev.): points
    every metre along x on that lane, noisy across it."""
    parts = []
    for tid, x0, x1, y, sign, sd in tracks:
        x = np.arange(x0, x1, 1.0)
        xy = np.column_stack([x, y + rng.normal(0.0, sd, len(x))])
        parts.append((xy, np.full(len(x), tid), np.tile([sign, 0.0], (len(x), 1))))
    xy = np.vstack([p[0] for p in parts])
    return SourceCloud(xy, np.zeros(len(xy), np.int8), np.concatenate([p[1] for p in parts]),
                       "detections", len(tracks), len(tracks), len(xy),
                       np.vstack([p[2] for p in parts]).astype(float))


def test_lane_spacing_finds_the_same_direction_lane_beside():
    t = _road()
    on = {k: int(np.flatnonzero((t.lane == k) & (np.abs(t.xy[:, 0] - 100.0) < 1e-9))[0])
          for k in range(3)}
    spacing = lane_spacing(t, np.array([on[0], on[1], on[2]]))
    # lanes 0 and 1 are 3 m apart; lane 2 runs the other way: nothing beside it
    np.testing.assert_allclose(spacing[:2], 3.0, atol=1e-9)
    assert np.isinf(spacing[2])


def test_a_far_track_turns_the_fit_by_one_lane_at_its_range():
    t = _road()
    src = _cloud([(1, 140.0, 150.0, 0.0, 1, 0.0), (2, 10.0, 20.0, 0.0, 1, 0.0)],
                 np.random.default_rng(0))
    starts = slip_starts(src, t, np.eye(3), SENSOR, 1, 3.0, 1.5, 90.0)
    assert len(starts) == 2
    r = float(np.median(np.hypot(*(src.xy[src.track_id == 1] - SENSOR).T)))
    for start, lane_y in zip(starts, (3.0, -3.0)):
        # a turn about the sensor: it stays put, the far track moves one spacing across
        np.testing.assert_allclose(transform_points(start, SENSOR[None])[0], SENSOR, atol=1e-9)
        turn = np.arctan2(start[1, 0], start[0, 0])
        assert abs(abs(turn) - 3.0 / r) < 1e-9
        far = transform_points(start, src.xy[src.track_id == 1])
        assert abs(np.median(far[:, 1]) - lane_y) < 0.1
    # the near track alone would need 7 deg: beyond the 3 deg bound, and none for no track
    near = _cloud([(2, 10.0, 20.0, 0.0, 1, 0.0)], np.random.default_rng(0))
    assert slip_starts(near, t, np.eye(3), SENSOR, 2, 3.0, 1.5, 90.0) == []
    assert slip_starts(src, t, np.eye(3), SENSOR, 0, 3.0, 1.5, 90.0) == []
    # a far track on the lane driven the other way has no lane beside it
    other = _cloud([(1, 140.0, 150.0, -3.5, -1, 0.0), (2, 10.0, 20.0, 0.0, 1, 0.0)],
                   np.random.default_rng(0))
    assert slip_starts(other, t, np.eye(3), SENSOR, 1, 3.0, 1.5, 90.0) == []


def test_a_slipped_fit_meets_the_pose_one_lane_back():
    """Far cluster (170-190 m, 1 m of lateral noise, about 0.3 deg of azimuth noise there) on
    lane 0 and two near tracks on lane 0 at 15-30 m (0.3 m noise), started with the far
    cluster one lane over (turned about the sensor by 0.95 deg, as the coarse stage left
    junction 12 seed 2): SICP keeps the slip (1.14 deg); from a slip start it reaches the
    pose without it (0.09 deg), at a lower cost here, and the comparison reports that one."""
    t = _road()
    src = _cloud([(1, 170.0, 190.0, 0.0, 1, 1.0), (2, 15.0, 30.0, 0.0, 1, 0.3),
                  (3, 15.0, 30.0, 0.0, 1, 0.3)], np.random.default_rng(3))
    slipped = se2(*SENSOR, 3.0 / 180.0) @ se2(*(-SENSOR), 0.0)
    cfg = SicpConfig(max_correspondence=1.5, min_correspondence=1.5, info_window=0.0)
    fits = []
    for start in [slipped, *slip_starts(src, t, slipped, SENSOR, 2, 3.0, 1.5, 90.0)]:
        T = sicp(src.xy, src.label, t, None, start, cfg, source_direction=src.direction).T
        T4 = np.eye(4)
        T4[:2, :2], T4[:2, 3] = T[:2, :2], T[:2, 2]
        fits.append(ModeFit(T, T4, np.diag([0.01, 0.01, 1e-6]),
                            track_costs(src, t, T, 1.5, 90.0), 1.0, True, start))
    assert _yaw_deg(fits[0]) > 0.8                              # the slip stays
    assert min(abs(_yaw_deg(f)) for f in fits[1:]) < 0.15      # a slip start finds the truth
    best = choose_mode(fits, Config().coarse, merge_deg=0.5).best
    assert abs(_yaw_deg(best)) < 0.15 and np.hypot(*best.T_fine[:2, 2]) < 0.15


def _yaw_deg(f: ModeFit) -> float:
    return float(np.rad2deg(np.arctan2(f.T_fine[1, 0], f.T_fine[0, 0])))


def test_the_fine_stage_keeps_fits_under_a_degree_apart():
    """Two fits 0.8 deg apart at one position: one mode at the coarse stage's separation
    (``mode_separation_deg``, 1 deg), two at a ``merge_deg`` of 0.5 deg (the fine stage's
    default)."""
    cfg = Config()
    fits = []
    for yaw_deg, cost in ((0.0, 10.0), (0.8, 10.5)):
        T = se2(0.0, 0.0, np.deg2rad(yaw_deg))
        T4 = np.eye(4)
        T4[:2, :2] = T[:2, :2]
        fits.append(ModeFit(T, T4, None, np.array([cost]), 1.0, True, np.eye(3)))
    assert len(merge_modes(fits, cfg.coarse)) == 1
    assert len(merge_modes(fits, cfg.coarse, 0.5)) == 2
    assert merge_modes(fits, cfg.coarse)[0] is fits[0]


def test_slip_settings_are_checked():
    from fgloc.registration.config import FineConfig
    from fgloc.registration.source import check_fine_config

    for field, bad in (("slip_tracks", -1), ("merge_deg", -0.5)):
        with pytest.raises(ValueError, match=field):
            check_fine_config(dataclasses.replace(FineConfig(), **{field: bad}))
