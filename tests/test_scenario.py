"""Frame grouping of radar detections when the optional ``frame`` column is absent."""

from __future__ import annotations

import numpy as np

from fgloc.scenario import RadarData, burst_frame_ids


def _radar(t: np.ndarray, frame: np.ndarray | None = None) -> RadarData:
    n = len(t)
    return RadarData(t=t, xyz=np.zeros((n, 3)), doppler=np.zeros(n), frame=frame)


def test_frame_column_wins():
    r = _radar(np.array([0.0, 0.0, 0.05]), frame=np.array([7, 7, 9]))
    np.testing.assert_array_equal(r.frame_ids(), [7, 7, 9])


def test_shared_timestamps_form_frames():
    t = np.repeat(np.arange(5) * 0.05, 30)
    ids = _radar(t).frame_ids()
    assert len(np.unique(ids)) == 5
    np.testing.assert_array_equal(ids, np.repeat(np.arange(5), 30))


def test_individual_stamps_grouped_into_bursts():
    rng = np.random.default_rng(0)
    # 20 Hz frames, 40 detections each stamped within the first 8 ms of the frame
    t = np.sort(np.concatenate([k * 0.05 + rng.uniform(0, 0.008, 40) for k in range(20)]))
    ids = _radar(t).frame_ids()
    assert len(np.unique(ids)) == 20
    assert np.all(np.bincount(ids) == 40)


def test_continuous_stamps_fall_back_to_50_ms_windows():
    t = np.linspace(0.0, 1.0, 2001)[:-1]  # evenly spread, no gaps at all
    ids = burst_frame_ids(t)
    assert len(np.unique(ids)) == 20
    spans = [np.ptp(t[ids == k]) for k in np.unique(ids)]
    assert max(spans) < 0.05
