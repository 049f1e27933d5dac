"""Length retrodiction of a finished track (frame C): a vehicle's length is constant, so the
length the filter knows at the track's end also holds at its start.

While a vehicle is seen head-on or from behind its length is unobservable: the filter keeps the
car-sized prior (or the long-vehicle hypothesis) and places the centre half that length behind
the seen face. A truck approaching from far away is thus tracked with a contour metres too
short and a centre metres too far towards the sensor until its side comes into view. Once
the track ends, the longest it was measured (the largest running median of its contour
length over the steps whose length std. dev. is small: not the car-sized prior, not the
overshoot of a new track's first updates or of a few steps) is carried back to every step
with a shorter contour: the contour gets that length, and at the steps where only an end of
the vehicle was seen (the sensor beyond its front or rear, its long side not seen at a
useful incidence) the centre moves away from the sensor by half the change, keeping the
seen face where it was measured. Steps that saw a long side (their length measured by the
side's extent) grow about their centre.
Contours are never shortened: the detections lie on or inside the vehicle, so a contour is
short where its returns were sparse (far out, partly occluded, leaving the view), rarely too
long.
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from factors.gp import rectangle_radius
from fgloc.tracks import N_KIN, YAW, X, Y, contour_angles


def contour_length_width(states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n,) length and width (m) of the star-convex contours of state rows (n, N_STATE): the
    radii along the heading (front + rear) and across it (left + right)."""
    f = states[:, N_KIN:]
    q = f.shape[1] // 4
    return f[:, 0] + f[:, 2 * q], f[:, q] + f[:, 3 * q]


def length_variance(P: np.ndarray) -> np.ndarray:
    """Variance (m^2) of the contour length (front + rear radius) of state covariances
    (..., N_STATE, N_STATE)."""
    i, j = N_KIN, N_KIN + (np.shape(P)[-1] - N_KIN) // 2
    return P[..., i, i] + P[..., j, j] + 2.0 * P[..., i, j]


def retrodict_length(states: np.ndarray, length_sd: np.ndarray, sensor: np.ndarray,
                     window: int, max_sd: float, min_incidence: float) -> np.ndarray:
    """States (n, N_STATE) of one track with its longest measured length carried back.

    The track's length (m) is the largest median contour length over ``window`` consecutive
    rows (all when fewer) among the rows whose length std. dev. ``length_sd`` (n,) (m) is at
    most ``max_sd``; without such rows the states are returned unchanged. Each shorter row's
    contour is lengthened to it (the rectangle offset ``rectangle_radius(L_track, W) -
    rectangle_radius(L, W)`` added to its radii, so the GP's shape detail stays); such a row
    whose sensor position ``sensor`` (2,) lies beyond one of its ends (|longitudinal offset| >
    L / 2) and which did not see a long side (sin of the angle between the line of sight and
    the side facing the sensor below ``min_incidence``: its length unobservable) has its
    centre moved by half the added length along the heading, away from the sensor; the other
    rows grow about their centre. Returns a new array; ``window`` <= 0 returns a copy
    unchanged.
    """
    out = np.array(states, dtype=float, copy=True)
    measured = np.asarray(length_sd) <= max_sd
    if window <= 0 or not measured.any():
        return out
    length, width = contour_length_width(out)
    seen = length[measured]
    w = min(window, len(seen))
    longest = float(np.max(np.median(sliding_window_view(seen, w), axis=1)))
    grow = np.maximum(longest - length, 0.0)
    h = np.column_stack([np.cos(out[:, YAW]), np.sin(out[:, YAW])])
    lat = np.column_stack([-h[:, 1], h[:, 0]])
    rel = np.asarray(sensor, dtype=float) - out[:, [X, Y]]
    s_lo, s_la = np.sum(rel * h, axis=1), np.sum(rel * lat, axis=1)
    # the long side facing the sensor, seen at a useful incidence, measured the length
    los = rel - lat * (np.sign(s_la) * 0.5 * width)[:, None]
    inc = np.abs(np.sum(los * lat, axis=1)) / np.maximum(np.linalg.norm(los, axis=1), 1e-6)
    side_seen = (np.abs(s_la) > 0.5 * width) & (inc >= min_incidence)
    end_only = (np.abs(s_lo) > 0.5 * length) & ~side_seen
    shift = np.where(end_only, -np.sign(s_lo) * 0.5 * grow, 0.0)
    out[:, [X, Y]] += shift[:, None] * h
    ang = contour_angles()[None, :]
    L, W = length[:, None], width[:, None]
    out[:, N_KIN:] += rectangle_radius(ang, L + grow[:, None], W) - rectangle_radius(ang, L, W)
    return out
