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
from fgloc.tracks import N_KIN, YAW, X, Y, contour_angles, contour_length_width


def length_variance(P: np.ndarray) -> np.ndarray:
    """Variance (m^2) of the contour length (front + rear radius) of state covariances
    (..., N_STATE, N_STATE)."""
    i, j = N_KIN, N_KIN + (np.shape(P)[-1] - N_KIN) // 2
    return P[..., i, i] + P[..., j, j] + 2.0 * P[..., i, j]


def retrodict_length(states: np.ndarray, length_sd: np.ndarray, sensor: np.ndarray,
                     window: int, max_sd: float, prior: np.ndarray | None = None,
                     occupied: np.ndarray | None = None,
                     far_anchored: np.ndarray | None = None) -> np.ndarray:
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
    born on the far part of its vehicle, later grew towards the sensor). Returns a new
    array; ``window`` <= 0 returns a copy unchanged.
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
