"""Length retrodiction of a finished track (frame C): a vehicle's length is constant, so the
length the filter knows at the track's end also holds at its start.

While a vehicle is seen head-on or from behind its length is unobservable: the filter keeps the
car-sized prior (or the long-vehicle hypothesis) and places the centre half that length behind
the seen face. A truck approaching from far away is thus tracked with a contour metres too
short and a centre metres too far towards the sensor until its side comes into view. Once
the track ends, the longest it was measured (the largest running median of its contour
length over the steps whose length std. dev. is small: not the car-sized prior, not the
overshoot of a new track's first updates or of a few steps) is carried back to every step
with a shorter contour: the contour gets that length, and the centre moves away from the
sensor along the heading by half the change times |cos| of the angle between the heading
and the line of sight: seen end-on (a truck approaching from far away) the end facing the
sensor stays where it was measured and all the length goes to the far, unseen end; seen
broadside both ends were seen alike and the contour grows about its centre. A track that was
born on a vehicle's far part and later grew towards the sensor (the tracker's
``occupancy_toward``) measured the far end before that growth: there the length goes to the
end facing the sensor.
Contours are never shortened: the detections lie on or inside the vehicle, so a contour is
short where its returns were sparse (far out, partly occluded, leaving the view), rarely too
long.
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from factors.gp import rectangle_radius
from fgloc.tracks import N_KIN, YAW, V, X, Y, contour_angles, contour_length_width


def length_variance(P: np.ndarray) -> np.ndarray:
    """Variance (m^2) of the contour length (front + rear radius) of state covariances
    (..., N_STATE, N_STATE)."""
    i, j = N_KIN, N_KIN + (np.shape(P)[-1] - N_KIN) // 2
    return P[..., i, i] + P[..., j, j] + 2.0 * P[..., i, j]


#: a growth of the contour by at least this (m) says which of its ends moved
GROWTH = 2.0
#: ... when it took at most this long (s)
GROWTH_TIME = 1.0


def _grew_towards_sensor(states: np.ndarray, t: np.ndarray, length: np.ndarray,
                         s_lo: np.ndarray, h: np.ndarray, longest: float) -> int:
    """Rows (counted from the start) before the contour first reached the track's length
    ``longest`` (within ``GROWTH`` / 4) by a growth of at least ``GROWTH`` m within
    ``GROWTH_TIME`` s that moved its far end at most half as far as its end facing the
    sensor, the vehicle's own motion over the growth (the track's speed along its heading,
    rows at times ``t`` s) taken out: a vehicle born on its far part, its near part unseen
    next to the blind range, whose contour grew back over it. 0: none, a slower growth
    (both ends may have moved: a truck approaching head-on grew from the long-vehicle
    prior's 10 m to 11.7 m over 14 s, its ends 3.4 and 4.1 m off the motion), or the far end
    moved."""
    long = np.flatnonzero(length >= longest - 0.25 * GROWTH)
    if not len(long):
        return 0
    k1 = int(long[0])
    short = np.flatnonzero(length[:k1] <= longest - GROWTH)
    if not len(short):
        return 0
    k0 = int(short[-1])
    if t[k1] - t[k0] > GROWTH_TIME:
        return 0                    # a slow growth: both ends may have moved
    if np.sign(s_lo[k0]) != np.sign(s_lo[k1]):
        return 0                    # the vehicle passed the sensor: its ends swapped roles
    ends = [k0, k1]
    # centre -> far end at the two rows
    side = -np.sign(s_lo[ends])[:, None] * 0.5 * length[ends][:, None] * h[ends]
    xy = states[ends][:, [X, Y]]
    ds = np.sum(0.5 * (states[k0:k1, V] + states[k0 + 1:k1 + 1, V]) * np.diff(t[k0:k1 + 1]))
    moved = xy[1] - xy[0] - ds * 0.5 * (h[k0] + h[k1])      # the vehicle's motion taken out
    far_moved = np.linalg.norm(moved + side[1] - side[0])
    near_moved = np.linalg.norm(moved - side[1] + side[0])
    return k1 if far_moved <= 0.5 * near_moved else 0


def retrodict_length(states: np.ndarray, length_sd: np.ndarray, sensor: np.ndarray,
                     window: int, max_sd: float, prior: np.ndarray | None = None,
                     occupied: np.ndarray | None = None,
                     far_anchored: np.ndarray | None = None,
                     t: np.ndarray | None = None) -> np.ndarray:
    """States (n, N_STATE) of one track with its longest measured length carried back.

    The track's length (m) is the largest median contour length over ``window`` consecutive
    rows (all when fewer) among the rows whose length std. dev. ``length_sd`` (n,) (m) is at
    most ``max_sd``; without such rows the states are returned unchanged. Rows flagged in
    ``prior`` (n,) (their length held by the long-vehicle prior: a hypothesis, and its
    repeated pseudo-measurement shrinks the std. dev. below ``max_sd``) count only when no
    other row qualifies (a truck whose side is never seen keeps the hypothesis' length; a
    van that tripped it and later showed its side keeps its measured one). Rows flagged in
    ``occupied`` (n,) count as measured whatever their std. dev.: their length is reached by
    the occupied length of the detections pooled behind the seen end (the tracker's
    ``occupancy_gap``; seen end-on the filter's own length stays unobservable). Each shorter
    row's contour is lengthened to it (the rectangle offset ``rectangle_radius(L_track, W) -
    rectangle_radius(L, W)`` added to its radii, so the GP's shape detail stays); such a
    row's centre moves along the heading, away from the sensor position ``sensor`` (2,), by
    half the added length times |cos| of the angle between the heading and the line of sight
    (the end facing the sensor stays put when seen end-on). Rows flagged in ``far_anchored``
    (n,) move towards the sensor instead: their far end is the measured one (the track,
    born on the far part of its vehicle, later grew towards the sensor); with the row times
    ``t`` (n,) (s), so do the rows before a quick growth towards the sensor found from the
    states themselves (:func:`_grew_towards_sensor`; the tracker flags only the growths
    its occupied length makes), those of them seen from the same side (the sign of the
    line of sight along the heading: before a vehicle passed the sensor its other end faced
    it). Returns a new array; ``window`` <= 0 returns a copy unchanged.
    """
    out = np.array(states, dtype=float, copy=True)
    measured = np.asarray(length_sd) <= max_sd
    if occupied is not None:
        measured |= np.asarray(occupied, dtype=bool)
    if prior is not None and np.any(measured & ~prior):
        measured &= ~np.asarray(prior, dtype=bool)
    if window <= 0 or not measured.any():
        return out
    length, width = contour_length_width(out)
    seen = length[measured]
    w = min(window, len(seen))
    longest = float(np.max(np.median(sliding_window_view(seen, w), axis=1)))
    grow = np.maximum(longest - length, 0.0)
    h = np.column_stack([np.cos(out[:, YAW]), np.sin(out[:, YAW])])
    rel = np.asarray(sensor, dtype=float) - out[:, [X, Y]]
    s_lo = np.sum(rel * h, axis=1)
    toward = 0 if t is None else _grew_towards_sensor(out, np.asarray(t), length, s_lo, h,
                                                        longest)
    if toward:
        far_anchored = (np.zeros(len(out), dtype=bool) if far_anchored is None
                        else np.asarray(far_anchored, dtype=bool).copy())
        # only the rows seen from the same side: before the vehicle passed the sensor
        # its other end faced it
        far_anchored[:toward] |= np.sign(s_lo[:toward]) == np.sign(s_lo[toward])
    # share of the added length at the far end: |cos| of the angle between the heading and
    # the line of sight (1 end-on, 0 broadside, where both ends are seen alike)
    end_on = np.abs(s_lo) / np.maximum(np.linalg.norm(rel, axis=1), 1e-6)
    shift = -np.sign(s_lo) * 0.5 * grow * end_on
    if far_anchored is not None:
        shift = np.where(far_anchored, -shift, shift)
    out[:, [X, Y]] += shift[:, None] * h
    ang = contour_angles()[None, :]
    L, W = length[:, None], width[:, None]
    out[:, N_KIN:] += rectangle_radius(ang, L + grow[:, None], W) - rectangle_radius(ang, L, W)
    return out
