"""Length retrodiction of a finished track (fgloc.tracking.retrodict) against known truth: a
12 m x 2.5 m truck driving straight at the sensor, tracked car-sized while only its front is
seen."""

from __future__ import annotations

import numpy as np

from factors.gp import rectangle_radius
from fgloc.tracking.retrodict import length_variance, retrodict_length
from fgloc.tracks import N_KIN, N_STATE, YAW, V, X, Y, contour_angles, contour_length_width

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


def _sd(lengths: np.ndarray) -> np.ndarray:
    """Length std. dev. (m): the car-sized prior's 1.5 m, 0.2 m once the side is seen."""
    return np.where(lengths < TRUE_LENGTH, 1.5, 0.2)


def test_truck_seen_head_on_gets_its_length_and_centre_back() -> None:
    xs = np.linspace(150.0, 30.0, 60)                    # true centres, 5 m beside the sensor
    lengths = np.where(np.arange(60) < 30, 4.6, TRUE_LENGTH)     # car-sized until its side
    before = _states(xs, lengths)
    assert np.max(np.abs(before[:, X] - xs)) > 3.0       # 3.7 m towards the sensor
    after = retrodict_length(before, _sd(lengths), SENSOR, window=20, max_sd=0.35)
    length, width = contour_length_width(after)
    np.testing.assert_allclose(length, TRUE_LENGTH, atol=1e-9)
    np.testing.assert_allclose(width, TRUE_WIDTH, atol=1e-9)
    # seen end-on, all the added length goes to the rear: the centre moves back by half of
    # it times |cos| of the line of sight's angle to the heading (0.986-0.999 here)
    end_on = np.abs(before[:, X] - SENSOR[0]) / np.hypot(before[:, X] - SENSOR[0], SENSOR[1])
    expected = before[:, X] + 0.5 * (TRUE_LENGTH - lengths) * end_on
    np.testing.assert_allclose(after[:, X], expected, atol=1e-9)
    np.testing.assert_allclose(after[:, X], xs, atol=0.06)           # the truth within 6 cm
    np.testing.assert_allclose(after[:, Y], 0.0, atol=1e-12)


def test_never_shortens_and_ignores_a_short_overshoot() -> None:
    xs = np.linspace(150.0, 30.0, 60)
    lengths = np.full(60, TRUE_LENGTH)
    lengths[:5] = 13.0                       # seen longer early on: kept
    lengths[40:45] = 20.0                    # a few steps' overshoot: not carried back
    lengths[50:] = 9.0                       # sparse returns at the end: lengthened to 12 m
    after = retrodict_length(_states(xs, lengths), np.full(60, 0.2), SENSOR, window=20,
                             max_sd=0.35)
    length, _ = contour_length_width(after)
    np.testing.assert_allclose(length[:5], 13.0, atol=1e-9)
    np.testing.assert_allclose(length[40:45], 20.0, atol=1e-9)
    np.testing.assert_allclose(length[50:], TRUE_LENGTH, atol=1e-9)
    np.testing.assert_allclose(after[50:, X], xs[50:], atol=0.06)


def test_centre_stays_where_the_side_is_seen_and_off_is_identity() -> None:
    # the sensor beside the vehicle: both ends are measured, the contour grows about its centre
    xs = np.full(30, 0.0)
    lengths = np.where(np.arange(30) < 10, 8.0, TRUE_LENGTH)
    states = _states(xs, lengths)
    states[:, X] = 0.0
    after = retrodict_length(states, np.full(30, 0.2), SENSOR, window=20, max_sd=0.35)
    np.testing.assert_allclose(after[:, X], 0.0, atol=1e-12)
    np.testing.assert_allclose(contour_length_width(after)[0], TRUE_LENGTH, atol=1e-9)
    off = retrodict_length(states, np.full(30, 0.2), SENSOR, window=0, max_sd=0.35)
    np.testing.assert_array_equal(off, states)


def test_unmeasured_lengths_are_not_carried_back() -> None:
    # a new track's overshoot while its length is still uncertain is not the vehicle's length
    xs = np.linspace(30.0, 150.0, 60)                    # driving away from the sensor
    lengths = np.full(60, 4.6)
    lengths[:25] = 8.0
    sd = np.where(np.arange(60) < 25, 0.8, 0.2)
    states = _states(xs, lengths)
    after = retrodict_length(states, sd, SENSOR, window=20, max_sd=0.35)
    np.testing.assert_allclose(after, states)
    # nothing measured: unchanged
    np.testing.assert_allclose(retrodict_length(states, np.full(60, 0.8), SENSOR, 20, 0.35),
                               states)


def test_a_hypothesised_length_is_carried_back_only_when_nothing_was_measured() -> None:
    # a 5.5 m van that tripped the long-vehicle hypothesis (10 m, its pseudo-measurement
    # shrinking the std. dev.) for 20 steps and then showed its side: the measured 5.5 m stays
    xs = np.linspace(150.0, 30.0, 60)
    lengths = np.where((np.arange(60) >= 10) & (np.arange(60) < 30), 10.0, 5.5)
    prior = lengths == 10.0
    states = _states(xs, lengths)
    after = retrodict_length(states, np.full(60, 0.2), SENSOR, window=20, max_sd=0.35,
                             prior=prior)
    length, _ = contour_length_width(after)
    np.testing.assert_allclose(length[~prior], 5.5, atol=1e-9)      # not lengthened to 10 m
    np.testing.assert_allclose(length[prior], 10.0, atol=1e-9)      # never shortened
    # without the flags the hypothesis was carried back to the whole track
    unflagged = contour_length_width(retrodict_length(states, np.full(60, 0.2), SENSOR, 20,
                                                      0.35))[0]
    np.testing.assert_allclose(unflagged, 10.0, atol=1e-9)
    # a truck whose side is never seen: the hypothesis is all there is and is carried back
    lengths = np.where(np.arange(60) < 20, 4.6, 10.0)
    after = retrodict_length(_states(xs, lengths), np.where(lengths > 5, 0.2, 1.5), SENSOR,
                             window=20, max_sd=0.35, prior=lengths > 5)
    np.testing.assert_allclose(contour_length_width(after)[0], 10.0, atol=1e-9)


def test_length_variance_of_front_plus_rear() -> None:
    rng = np.random.default_rng(3)
    A = rng.normal(size=(N_STATE, N_STATE))
    P = A @ A.T
    a = np.zeros(N_STATE)
    a[N_KIN] = a[N_KIN + (N_STATE - N_KIN) // 2] = 1.0
    np.testing.assert_allclose(length_variance(P), a @ P @ a)
    np.testing.assert_allclose(length_variance(np.stack([P, 2 * P])), [a @ P @ a, 2 * a @ P @ a])


def test_far_anchored_rows_keep_their_far_end() -> None:
    """A truck driving at the sensor whose track was born on its far part (the rear; e.g. the
    front was still outside the view) and later grew towards the sensor: rows flagged
    ``far_anchored`` measured the rear, so the added length goes to the front -- the centre
    moves towards the sensor by half of it times |cos| of the line of sight's angle to the
    heading, the mirror of the default."""
    xs = np.linspace(150.0, 30.0, 60)
    lengths = np.where(np.arange(60) < 30, 4.6, TRUE_LENGTH)
    rear = xs + 0.5 * TRUE_LENGTH
    before = _states(xs, lengths)
    before[:, X] = rear - 0.5 * lengths              # the contour ends at the true rear
    anchored = np.arange(60) < 30
    after = retrodict_length(before, _sd(lengths), SENSOR, window=20, max_sd=0.35,
                             far_anchored=anchored)
    end_on = np.abs(before[:, X] - SENSOR[0]) / np.hypot(before[:, X] - SENSOR[0], SENSOR[1])
    expected = before[:, X] - 0.5 * (TRUE_LENGTH - lengths) * end_on
    np.testing.assert_allclose(after[:, X], expected, atol=1e-9)
    np.testing.assert_allclose(after[:, X], xs, atol=0.06)
    plain = retrodict_length(before, _sd(lengths), SENSOR, window=20, max_sd=0.35)
    assert np.max(np.abs(plain[:30, X] - xs[:30])) > 7.0       # the near end kept instead


def _timed(states: np.ndarray, speed: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    """The states with their speed (m/s) set and the row times (s) that speed gives along
    their 2.03 m spacing."""
    out = states.copy()
    out[:, V] = speed
    step = float(np.mean(np.abs(np.diff(states[:, X]))))
    return out, np.arange(len(states)) * step / speed


def test_a_growth_towards_the_sensor_is_found_from_the_rows() -> None:
    """The far-anchored truck of the test above, without the tracker's flag: with the row
    times, the growth at row 30 moved the near end (the rear stayed where the truck's motion
    takes it), so the rows before it keep their far end; the head-on truck, whose front
    stayed, keeps the default."""
    xs = np.linspace(150.0, 30.0, 60)
    lengths = np.where(np.arange(60) < 30, 4.6, TRUE_LENGTH)
    before = _states(xs, lengths)
    before[:, X] = xs + 0.5 * TRUE_LENGTH - 0.5 * lengths          # ends at the true rear
    before, t = _timed(before)
    after = retrodict_length(before, _sd(lengths), SENSOR, window=20, max_sd=0.35, t=t)
    flagged = retrodict_length(before, _sd(lengths), SENSOR, window=20, max_sd=0.35,
                               far_anchored=np.arange(60) < 30)
    np.testing.assert_allclose(after, flagged, atol=1e-12)
    np.testing.assert_allclose(after[:, X], xs, atol=0.06)
    head_on, t = _timed(_states(xs, lengths))
    np.testing.assert_allclose(
        retrodict_length(head_on, _sd(lengths), SENSOR, window=20, max_sd=0.35, t=t),
        retrodict_length(head_on, _sd(lengths), SENSOR, window=20, max_sd=0.35), atol=1e-12)


def test_rows_from_before_the_vehicle_passed_the_sensor_keep_their_near_end() -> None:
    """A truck driving -x past a sensor at x = 100 (5 m beside its path), its front seen all
    along, its rear grown back towards the sensor at row 30 once past it: the rows from after
    the pass keep their far end (the front), those from before it their near end (the front
    too, which faced the sensor then): every row keeps the true front."""
    xs = np.linspace(150.0, 30.0, 60)
    lengths = np.where(np.arange(60) < 30, 4.6, TRUE_LENGTH)
    before, t = _timed(_states(xs, lengths))            # the contour ends at the true front
    sensor = np.array([100.0, 5.0])
    after = retrodict_length(before, _sd(lengths), sensor, window=20, max_sd=0.35, t=t)
    rel = sensor[0] - before[:, X]
    end_on = np.abs(rel) / np.hypot(rel, sensor[1])
    expected = before[:, X] + 0.5 * (TRUE_LENGTH - lengths) * end_on
    np.testing.assert_allclose(after[:, X], expected, atol=1e-9)
