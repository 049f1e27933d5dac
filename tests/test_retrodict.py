"""Length retrodiction of a finished track (fgloc.tracking.retrodict) against known truth: a
12 m x 2.5 m truck driving straight at the sensor, tracked car-sized while only its front is
seen."""

from __future__ import annotations

import numpy as np

from factors.gp import rectangle_radius
from fgloc.tracking.retrodict import contour_length_width, retrodict_length
from fgloc.tracks import N_KIN, N_STATE, YAW, X, Y, contour_angles

TRUE_LENGTH, TRUE_WIDTH = 12.0, 2.5
SENSOR = np.array([0.0, 5.0])


def _states(xs: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Rows of a vehicle heading -x (towards the sensor) whose front is at the true front
    (x - TRUE_LENGTH / 2) and whose contour is lengths (m) long: the centre sits half the
    contour length behind the seen front, as the filter places it."""
    out = np.zeros((len(xs), N_STATE))
    front = xs - 0.5 * TRUE_LENGTH
    out[:, X] = front + 0.5 * lengths
    out[:, YAW] = np.pi
    ang = contour_angles()
    for k, length in enumerate(lengths):
        out[k, N_KIN:] = rectangle_radius(ang, length, TRUE_WIDTH)
    return out


def test_truck_seen_head_on_gets_its_length_and_centre_back() -> None:
    xs = np.linspace(150.0, 30.0, 60)                    # true centres, 5 m beside the sensor
    lengths = np.where(np.arange(60) < 30, 4.6, TRUE_LENGTH)     # car-sized until its side
    before = _states(xs, lengths)
    assert np.max(np.abs(before[:, X] - xs)) > 3.0       # 3.7 m towards the sensor
    after = retrodict_length(before, SENSOR, window=20)
    length, width = contour_length_width(after)
    np.testing.assert_allclose(length, TRUE_LENGTH, atol=1e-9)
    np.testing.assert_allclose(width, TRUE_WIDTH, atol=1e-9)
    np.testing.assert_allclose(after[:, X], xs, atol=1e-9)
    np.testing.assert_allclose(after[:, Y], 0.0, atol=1e-12)


def test_never_shortens_and_ignores_a_short_overshoot() -> None:
    xs = np.linspace(150.0, 30.0, 60)
    lengths = np.full(60, TRUE_LENGTH)
    lengths[:5] = 13.0                       # seen longer early on: kept
    lengths[40:45] = 20.0                    # a few steps' overshoot: not carried back
    lengths[50:] = 9.0                       # sparse returns at the end: lengthened to 12 m
    after = retrodict_length(_states(xs, lengths), SENSOR, window=20)
    length, _ = contour_length_width(after)
    np.testing.assert_allclose(length[:5], 13.0, atol=1e-9)
    np.testing.assert_allclose(length[40:45], 20.0, atol=1e-9)
    np.testing.assert_allclose(length[50:], TRUE_LENGTH, atol=1e-9)
    np.testing.assert_allclose(after[50:, X], xs[50:], atol=1e-9)


def test_centre_stays_where_the_side_is_seen_and_off_is_identity() -> None:
    # the sensor beside the vehicle: both ends are measured, the contour grows about its centre
    xs = np.full(30, 0.0)
    lengths = np.where(np.arange(30) < 10, 8.0, TRUE_LENGTH)
    states = _states(xs, lengths)
    states[:, X] = 0.0
    after = retrodict_length(states, SENSOR, window=20)
    np.testing.assert_allclose(after[:, X], 0.0, atol=1e-12)
    np.testing.assert_allclose(contour_length_width(after)[0], TRUE_LENGTH, atol=1e-9)
    np.testing.assert_array_equal(retrodict_length(states, SENSOR, window=0), states)
