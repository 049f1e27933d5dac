"""Re-linking of the tracks the tracker lost inside the field of view (frame C).

A confirmed track that ends inside the field of view -- missed for ``delete_after`` s, or
diverged (its misfit above ``diverge_excess``, its contour wider than ``max_width``) -- often
followed a vehicle that is still there: one turning across the line of sight far out (its
range rate below ``doppler_min``, its returns dropped as static: the track coasts on the turn
it had and slides off), one hidden for a second behind another, one with a few far returns.
The vehicle gets a new track a moment later, and one vehicle has two tracks.

A lost track A continues as a track B whose first row comes at most ``relink_time`` s after
A's last row when, with B's state ``relink_settle`` s after its first row (its first rows
hold the birth's guesses: the lane's heading, a default speed where the Doppler gives none):

* the headings of A's last row and of that state differ by at most ``relink_max_turn_deg``;
* A's last row run forward at constant velocity and that state run backward at constant
  velocity meet within ``relink_gate`` m halfway in time (two tangents of a turn meet
  near its corner; a vehicle following in the same lane is a headway behind).

Pairs are taken by that distance, smallest first, each track at most once as A and once as
B; chains (A, B, C) join into one track with A's id. The frames between A's last and B's
first row get rows interpolated between them: heading and speed linear in time from A's
last row to B's settled state (constant yaw rate and acceleration, as the CTRA model has
them), the centre on the cubic Hermite curve from A's last to B's first centre with tangents
along the two headings, A's contour; covariances blended linearly between the end rows' (not
a filter's). A tangent's length is the speed times the gap, at most three times the chord's
component along that heading (the Fritsch-Carlson bound: the curve does not run backward
along it); without the bound, ends whose positions disagree with their speeds (a lost track
coasting ahead of the vehicle, a new track's first row behind it) make the curve loop.
Like the length retrodiction this is not causal: the reported rows of a track use later
detections.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgloc.geo import wrap_angle
from fgloc.labels import kappa_labels
from fgloc.tracking.config import TrackingConfig
from fgloc.tracks import YAW, YAWRATE, A, Track, V, X, Y


@dataclass(frozen=True)
class Link:
    """Track ``first`` continues as track ``then``; ``miss`` (m): how far apart the
    constant-velocity runs of the two (``first``'s last row forward, ``then``'s settled
    state backward) arrive halfway in time."""

    first: int
    then: int
    miss: float


def _velocity(state: np.ndarray) -> np.ndarray:
    """(2,) velocity (m/s) of a state row."""
    return state[V] * np.array([np.cos(state[YAW]), np.sin(state[YAW])])


def _settled(tr: Track, settle: float) -> tuple[float, np.ndarray]:
    """(time s, state row) of ``tr`` ``settle`` s after its first row (its last if shorter)."""
    k = min(int(np.searchsorted(tr.t, tr.t[0] + settle)), len(tr) - 1)
    return float(tr.t[k]), tr.states[k]


def candidate_links(tracks: list[Track], lost: set[int], cfg: TrackingConfig) -> list[Link]:
    """Every pair (lost track, later track) that passes the tests of the module docstring,
    smallest ``miss`` first."""
    max_turn = np.deg2rad(cfg.relink_max_turn_deg)
    starts = np.array([tr.t[0] for tr in tracks])
    order = np.argsort(starts, kind="stable")
    links = []
    for a in tracks:
        if a.id not in lost:
            continue
        ta, xa = float(a.t[-1]), a.states[-1]
        lo, hi = np.searchsorted(starts[order], [ta, ta + cfg.relink_time], side="right")
        for b in (tracks[k] for k in order[lo:hi]):
            tb, xb = _settled(b, cfg.relink_settle)
            if abs(wrap_angle(xb[YAW] - xa[YAW])) > max_turn:
                continue
            half = 0.5 * (tb - ta)
            meet_a = xa[[X, Y]] + _velocity(xa) * half
            meet_b = xb[[X, Y]] - _velocity(xb) * half
            miss = float(np.linalg.norm(meet_a - meet_b))
            if miss <= cfg.relink_gate:
                links.append(Link(a.id, b.id, miss))
    return sorted(links, key=lambda k: k.miss)


def gap_rows(a: Track, b: Track, times: np.ndarray, settle: float
             ) -> tuple[np.ndarray, np.ndarray | None]:
    """States (k, N_STATE) and covariances (k, N_STATE, N_STATE) or None at ``times`` (k,),
    strictly between ``a``'s last and ``b``'s first row (module docstring)."""
    xa, xb = a.states[-1], _settled(b, settle)[1]
    t0, g = float(a.t[-1]), float(b.t[0] - a.t[-1])
    s = ((np.asarray(times, dtype=float) - t0) / g)[:, None]
    pa, pb = xa[[X, Y]], b.states[0][[X, Y]]
    turn = wrap_angle(xb[YAW] - xa[YAW])
    ua, ub = (np.array([np.cos(y), np.sin(y)]) for y in (xa[YAW], xa[YAW] + turn))
    chord = pb - pa
    ma = ua * min(abs(xa[V]) * g, 3.0 * max(float(chord @ ua), 0.0))
    mb = ub * min(abs(xb[V]) * g, 3.0 * max(float(chord @ ub), 0.0))
    s2, s3 = s * s, s * s * s
    p = ((2 * s3 - 3 * s2 + 1) * pa + (s3 - 2 * s2 + s) * ma + (-2 * s3 + 3 * s2) * pb
         + (s3 - s2) * mb)
    out = np.repeat(xa[None], len(s), axis=0)
    out[:, X], out[:, Y] = p[:, 0], p[:, 1]
    out[:, YAW] = xa[YAW] + turn * s[:, 0]              # continuous from A's (not wrapped)
    out[:, V] = xa[V] + (xb[V] - xa[V]) * s[:, 0]
    out[:, YAWRATE], out[:, A] = turn / g, (xb[V] - xa[V]) / g
    if a.covariances is None or b.covariances is None:
        return out, None
    w = s[:, :, None]
    return out, (1.0 - w) * a.covariances[-1] + w * b.covariances[0]


def _join(a: Track, b: Track, frame_times: np.ndarray, cfg: TrackingConfig) -> Track:
    """One track: ``a``'s rows, the gap rows, ``b``'s rows; ``a``'s id."""
    ft = np.asarray(frame_times, dtype=float)
    times = ft[(ft > a.t[-1]) & (ft < b.t[0])]
    states, covs = gap_rows(a, b, times, cfg.relink_settle)
    all_states = np.concatenate([a.states, states, b.states])
    covariances = (None if covs is None
                   else np.concatenate([a.covariances, covs, b.covariances]))
    return Track(
        id=a.id,
        t=np.concatenate([a.t, times, b.t]),
        states=all_states,
        labels=kappa_labels(all_states, cfg.eta, cfg.label_min_speed),
        covariances=covariances,
        det_index=np.concatenate([a.det_index, b.det_index]),
        det_step=np.concatenate([a.det_step, b.det_step + len(a) + len(times)]),
        length_floor=max(a.length_floor, b.length_floor),
    )


def relink(tracks: list[Track], lost: set[int], frame_times: np.ndarray,
           cfg: TrackingConfig) -> tuple[list[Track], list[Link]]:
    """The tracks with every lost track joined to the track it continues as (module
    docstring; ``relink_time`` 0: unchanged), by id; and the links taken. ``lost``: ids of
    the tracks ended inside the field of view; ``frame_times`` (F,) s: every frame's time
    (the gap rows')."""
    if cfg.relink_time <= 0.0 or not lost:
        return tracks, []
    taken: list[Link] = []
    first_of, then_of = set(), set()
    for link in candidate_links(tracks, lost, cfg):
        if link.first in first_of or link.then in then_of:
            continue
        taken.append(link)
        first_of.add(link.first)
        then_of.add(link.then)
    if not taken:
        return tracks, []
    by_id = {tr.id: tr for tr in tracks}
    successor = {k.first: k.then for k in taken}
    out = []
    for tr in tracks:
        if tr.id in then_of:
            continue                                    # joined to its predecessor
        nxt = successor.get(tr.id)
        while nxt is not None:
            tr = _join(tr, by_id[nxt], frame_times, cfg)
            nxt = successor.get(nxt)
        out.append(tr)
    return sorted(out, key=lambda tr: tr.id), taken
