"""The filter's width rows on a car with few returns per frame (issue 20), against the
simulator's truth: a seen front or rear gives a width row only with enough detections on it
(``[tracking] extent_face_min_points``)."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from test_smooth_extent_faces import _car_run, _metrics

from fgloc.pipeline import track
from fgloc.tracks import contour_length_width


def _width(tracks) -> float:
    return float(np.median(contour_length_width(tracks.tracks[0].states)[1]))


# measured on seeds 1-8 (docs/experiments.md): median width 0.04-0.25 m closer to the truth
# on the 7 with a track, IoU up on 6 (seed 5: 0.742 -> 0.736)
@pytest.mark.parametrize("seed", [6, pytest.param(7, marks=pytest.mark.slow)])
def test_filter_keeps_a_sparse_car_wide(seed: int) -> None:
    """One car on the straight road with the far-sparse returns (25 per frame at 20 m, 4 at
    150 m, most at its corner nearest to the sensor): with every frame's width rows its few
    front-face returns, which stop short of the far corner, made the filter's car 0.14-0.26
    m narrow; with the face test it is within 0.1 m of its width and its IoU is higher."""
    scn, cfg, run = _car_run(seed)
    every = copy.deepcopy(cfg)
    every.tracking.extent_face_min_points = 0
    old = track(scn, every, oracle_pose=True)
    assert len(run.tracks.tracks) == 1 and len(old.tracks.tracks) == 1
    true_width = scn.truth.tracks[0].width
    m_new, m_old = _metrics(scn, run.tracks), _metrics(scn, old.tracks)
    assert abs(_width(run.tracks) - true_width) < 0.1
    assert _width(old.tracks) < true_width - 0.12
    assert m_new.iou >= 0.8 and m_new.iou > m_old.iou + 0.05
