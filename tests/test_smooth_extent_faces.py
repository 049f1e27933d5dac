"""The batch smoother's extent rows on a car with few returns per frame (issue 20), against
the simulator's truth: a face's end rows need enough detections on that face."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from test_tracking_robustness import SPARSE

from fgloc.config import Config, from_dict
from fgloc.evaluation.tracking import evaluate_tracks
from fgloc.pipeline import track
from fgloc.sim import SimConfig, simulate_detailed
from fgloc.smoothing.run import smooth_tracks
from fgloc.tracks import contour_length_width


def _car_run(seed: int):
    """One car on the straight road with the far-sparse returns (25 per frame at 20 m, 4 at
    150 m, corners at the one nearest to the sensor), 25 s, filter with the true pose."""
    table = {"traffic": {"class_mix": [1.0, 0.0, 0.0]}, "radar": SPARSE}
    scn = simulate_detailed("straight", seed, 25.0, vehicles=1,
                            config=from_dict(SimConfig, table, None)).scenario
    cfg = Config()
    return scn, cfg, track(scn, cfg, oracle_pose=True)


def _metrics(scn, tracks):
    return evaluate_tracks(tracks, scn.truth, sensor_pose=scn.truth.sensor_pose,
                           hfov_deg=scn.sensor.hfov_deg, max_range=scn.sensor.max_range)


def _check(seed: int) -> None:
    scn, cfg, run = _car_run(seed)
    batch = smooth_tracks(scn, run.tracks, run.T_placement, "batch", cfg)
    old = copy.deepcopy(cfg)
    old.smoothing.extent_face_min_points = 0
    every = smooth_tracks(scn, run.tracks, run.T_placement, "batch", old)
    m0, m1, m2 = (_metrics(scn, ts) for ts in (run.tracks, batch, every))
    width = float(np.median(contour_length_width(batch.tracks[0].states)[1]))
    width_every = float(np.median(contour_length_width(every.tracks[0].states)[1]))
    true_width = scn.truth.tracks[0].width
    print(f"seed {seed}: IoU filter / batch / batch with every extent row {m0.iou:.3f} / "
          f"{m1.iou:.3f} / {m2.iou:.3f}, centre RMS {m0.centre_rms:.3f} / {m1.centre_rms:.3f} "
          f"/ {m2.centre_rms:.3f} m, width {width:.2f} / {width_every:.2f} m (true "
          f"{true_width:.2f})")
    assert len(batch.tracks) == 1 and m1.n_states > 100
    assert m1.iou >= 0.8 and m1.iou > m0.iou
    assert m1.centre_rms < 0.25
    # the cause: every frame's extent rows (a few front-face returns that stop short of the
    # far corner) make the smoothed car narrower or pull its centre towards the returns, and
    # its IoU lower (seed 7 at 98d9f66: width 1.76 / 1.73 m, centre RMS 0.167 / 0.341 m)
    assert m2.iou < m1.iou - 0.05
    assert width_every < width - 0.05 or m2.centre_rms > m1.centre_rms + 0.05


# measured on seeds 1-8 (docs/experiments.md): IoU up on 6 of the 7 with a track (seed 5:
# 0.767 -> 0.711), seeds 4 / 6 / 7 0.718 / 0.677 / 0.618 -> 0.840 / 0.854 / 0.819
def test_batch_keeps_a_sparse_car_wide_and_centred() -> None:
    _check(6)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [4, 7])
def test_batch_keeps_more_sparse_cars_wide_and_centred(seed: int) -> None:
    _check(seed)
