"""Re-linking of the tracks the tracker lost inside the field of view (frame C).

A confirmed track that ends inside the field of view -- missed for ``delete_after`` s, or
diverged (its misfit above ``diverge_excess``, its heading against its vehicle, its contour
wider than ``max_width``) -- often followed a vehicle that is still there: one turning
across the line of sight far out (its range rate below ``doppler_min``, its returns dropped
as static: the track coasts on the turn it had and slides off), one hidden for a second
behind another, one with a few far returns.
The vehicle gets a new track a moment later, and one vehicle has two tracks.

A lost track A continues as a track B whose first row comes at most ``relink_time`` s after
A's last row when, with B's state ``relink_settle`` s after its first row (its first rows
hold the birth's guesses: the lane's heading, a default speed where the Doppler gives none):

* the headings of A's last row and of that state differ by at most ``relink_max_turn_deg``,
  and an arc of radius ``relink_min_radius`` through A's last and B's first centre turns at
  least as much (a road vehicle turns no tighter; a slow track's ends 1.5 m apart with
  headings 80 deg apart are not one vehicle's motion);
* A's last row run forward at constant velocity and that state run backward at constant
  velocity meet halfway in time within ``relink_gate`` m plus ``relink_velocity_error``
  m/s times the time between the two rows (two tangents of a turn meet near its corner; a
  vehicle following in the same lane is a headway behind; the two runs are exact for a
  constant acceleration, and an error in an end's velocity, or a vehicle that braked and
  held its speed while unseen, moves them apart the more the longer the gap).

Pairs are taken by that distance over its gate (a stand's: over ``relink_gate``), smallest
first, each track at most once as A and once as B; chains (A, B, C) join into one track with
A's id. The frames between A's last and B's first row get rows interpolated between them:
heading and speed linear in time from A's last row to B's settled state (constant yaw rate
and acceleration, as the CTRA model has them), the centre on the cubic Hermite curve from
A's last to B's first centre with tangents along the two headings, A's contour; covariances
blended linearly between the end rows' (not a filter's). A tangent's length is the speed
times the gap, at most three times the chord's component along that heading (the
Fritsch-Carlson bound: the curve does not run backward along it); without the bound, ends
whose positions disagree with their speeds (a lost track coasting ahead of the vehicle, a
new track's first row behind it) make the curve loop.
A vehicle that stops (at a stop line, in a queue) returns only static detections; they are
dropped, its track ends and a new one starts where it moves off, up to a minute later. A
lost track A continues as a track B whose first row comes at most ``stand_time`` s after A's
last row across a stand when A's last row and B's settled state are both slower than
``stand_speed``, their headings differ by at most ``stand_max_turn_deg``, and A braked to a
stop at ``stand_accel`` and B started from a stop at it lie within ``relink_gate`` m of each
other (the stop points: A's last centre ``v^2 / (2 stand_accel)`` on along its heading, B's
first centre as far back along its). A pair that passes both tests is joined by the model
whose ends meet closer for its gate -- a stand only if no other track's box covered A's stop
point in between (the vehicle left unseen and another came to stand where it stood: a queue
moves up to a stop line). The rows of a stand brake at ``stand_accel`` from A's last row to
A's stop point, stand there (speed, acceleration and yaw rate 0, A's heading), and move off
at the constant acceleration that reaches B's first row at its speed (half that speed on
average: a vehicle creeps off slowly, its returns still static, before its new track is
born; in a queue it may creep up to the stop line first), turning to B's heading on the way.
The standing rows are flagged in ``Track.standing``,
and the smoothers hold their speed at 0 (interpolated rows hold no detection, and a
smoother left alone there finds the smoothest motion between the two ends: on through the
stop and back).

Like the length retrodiction this is not causal: the reported rows of a track use later
detections.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from fgloc.geo import wrap_angle
from fgloc.labels import kappa_labels
from fgloc.tracking.config import TrackingConfig
from fgloc.tracks import N_CONTOUR, N_KIN, YAW, YAWRATE, A, Track, V, X, Y

#: m/s: the slowest first speed of a track that moved off from a stand the start ramp assumes
_MIN_START_SPEED = 0.1


@dataclass(frozen=True)
class Link:
    """Track ``first`` continues as track ``then``; ``miss`` (m): how far apart the two
    tracks' ends arrive -- the constant-velocity runs of ``first``'s last row forward and
    ``then``'s settled state backward halfway in time, or with ``stand`` the two stop points
    (module docstring) --, at most ``gate`` (m)."""

    first: int
    then: int
    miss: float
    gate: float
    stand: bool = False

    @property
    def rank(self) -> float:
        """The miss over its gate: pairs are taken smallest first."""
        return self.miss / self.gate


def _heading(yaw: float) -> np.ndarray:
    """(2,) unit vector along ``yaw`` (rad)."""
    return np.array([np.cos(yaw), np.sin(yaw)])


def _settled(tr: Track, settle: float) -> tuple[float, np.ndarray]:
    """(time s, state row) of ``tr`` ``settle`` s after its first row (its last if shorter)."""
    k = min(int(np.searchsorted(tr.t, tr.t[0] + settle)), len(tr) - 1)
    return float(tr.t[k]), tr.states[k]


def _stop_points(xa: np.ndarray, b: Track, xb: np.ndarray, accel: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Where A (last row ``xa``) stops braking at ``accel`` m/s^2 and where B (first row of
    ``b``, settled state ``xb``) started from a stop at it, (2,) each."""
    stop = xa[[X, Y]] + _heading(xa[YAW]) * xa[V] ** 2 / (2.0 * accel)
    start = b.states[0][[X, Y]] - _heading(xb[YAW]) * xb[V] ** 2 / (2.0 * accel)
    return stop, start


def _link(a: Track, b: Track, cfg: TrackingConfig,
          covered: Callable[[np.ndarray, float, float, tuple[int, int]], bool]
          ) -> Link | None:
    """The link of lost track ``a`` to the later track ``b`` by the better of the two tests
    of the module docstring, None if neither passes. ``covered(point, t0, t1, ids)``:
    whether a track other than ``ids`` covered ``point`` strictly between ``t0`` and ``t1``
    s (then the stand model does not apply)."""
    ta, xa = float(a.t[-1]), a.states[-1]
    tb, xb = _settled(b, cfg.relink_settle)
    turn = abs(wrap_angle(xb[YAW] - xa[YAW]))
    best = None
    chord = float(np.linalg.norm(b.states[0][[X, Y]] - xa[[X, Y]]))
    if (b.t[0] - ta <= cfg.relink_time and turn <= np.deg2rad(cfg.relink_max_turn_deg)
            and chord >= 2.0 * cfg.relink_min_radius * np.sin(0.5 * turn)):
        half = 0.5 * (tb - ta)
        meet_a = xa[[X, Y]] + xa[V] * _heading(xa[YAW]) * half
        meet_b = xb[[X, Y]] - xb[V] * _heading(xb[YAW]) * half
        best = Link(a.id, b.id, float(np.linalg.norm(meet_a - meet_b)),
                    cfg.relink_gate + cfg.relink_velocity_error * (tb - ta))
    if (b.t[0] - ta <= cfg.stand_time and turn <= np.deg2rad(cfg.stand_max_turn_deg)
            and max(xa[V], xb[V]) <= cfg.stand_speed):
        stop, start = _stop_points(xa, b, xb, cfg.stand_accel)
        stand = Link(a.id, b.id, float(np.linalg.norm(stop - start)), cfg.relink_gate, True)
        if (stand.rank <= 1.0 and (best is None or stand.rank < best.rank)
                and not covered(stop, ta, float(b.t[0]), (a.id, b.id))):
            best = stand
    return best if best is not None and best.rank <= 1.0 else None


def _covers(tr: Track, t0: float, t1: float, point: np.ndarray) -> bool:
    """Whether ``tr``'s box (its front, left, rear and right contour radii about its centre,
    along its heading) covers ``point`` (2,) at a row strictly between ``t0`` and ``t1`` s."""
    rows = tr.states[(tr.t > t0) & (tr.t < t1)]
    if not len(rows):
        return False
    d = point - rows[:, [X, Y]]
    c, s = np.cos(rows[:, YAW]), np.sin(rows[:, YAW])
    along, across = d[:, 0] * c + d[:, 1] * s, d[:, 1] * c - d[:, 0] * s
    q = N_CONTOUR // 4
    r = rows[:, N_KIN:]
    inside = ((along <= r[:, 0]) & (along >= -r[:, 2 * q])
              & (across <= r[:, q]) & (across >= -r[:, 3 * q]))
    return bool(inside.any())


def candidate_links(tracks: list[Track], lost: set[int], cfg: TrackingConfig) -> list[Link]:
    """Every pair (lost track, later track) that passes a test of the module docstring,
    smallest :attr:`Link.rank` first."""
    starts = np.array([tr.t[0] for tr in tracks])
    ends = np.array([tr.t[-1] for tr in tracks])
    order = np.argsort(starts, kind="stable")
    reach = max(cfg.relink_time, cfg.stand_time)

    def covered(point: np.ndarray, t0: float, t1: float, ids: tuple[int, int]) -> bool:
        """Another vehicle stood or drove at ``point`` meanwhile."""
        alive = np.flatnonzero((starts < t1) & (ends > t0))
        return any(_covers(tracks[j], t0, t1, point) for j in alive
                   if tracks[j].id not in ids)

    links = []
    for a in tracks:
        if a.id not in lost:
            continue
        ta = float(a.t[-1])
        lo, hi = np.searchsorted(starts[order], [ta, ta + reach], side="right")
        links += [k for k in (_link(a, tracks[j], cfg, covered) for j in order[lo:hi])
                  if k is not None]
    return sorted(links, key=lambda k: k.rank)


def gap_rows(a: Track, b: Track, times: np.ndarray, settle: float
             ) -> tuple[np.ndarray, np.ndarray | None]:
    """States (k, N_STATE) and covariances (k, N_STATE, N_STATE) or None at ``times`` (k,),
    strictly between ``a``'s last and ``b``'s first row, of a vehicle that kept moving
    (module docstring)."""
    xa, xb = a.states[-1], _settled(b, settle)[1]
    t0, g = float(a.t[-1]), float(b.t[0] - a.t[-1])
    s = ((np.asarray(times, dtype=float) - t0) / g)[:, None]
    pa, pb = xa[[X, Y]], b.states[0][[X, Y]]
    turn = wrap_angle(xb[YAW] - xa[YAW])
    ua, ub = _heading(xa[YAW]), _heading(xa[YAW] + turn)
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
    return out, _blend(a, b, s[:, 0])


def stand_rows(a: Track, b: Track, times: np.ndarray, settle: float, accel: float
               ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """States (k, N_STATE), covariances (k, N_STATE, N_STATE) or None and the (k,) standing
    flags at ``times`` (k,), strictly between ``a``'s last and ``b``'s first row, of a
    vehicle that braked to a stop, stood and moved off (module docstring)."""
    xa, xb, xb0 = a.states[-1], _settled(b, settle)[1], b.states[0]
    ta, tb = float(a.t[-1]), float(b.t[0])
    g = tb - ta
    w = np.asarray(times, dtype=float) - ta                     # since A's last row
    u = tb - np.asarray(times, dtype=float)                     # until B's first row
    va, vb = max(float(xa[V]), 0.0), max(float(xb0[V]), 0.0)
    brake = min(va / accel, 0.5 * g)
    stop = xa[[X, Y]] + _heading(xa[YAW]) * va * brake / 2.0
    turn = wrap_angle(xb[YAW] - xa[YAW])
    # moving off from the stop point at a constant acceleration, reaching B's first row at
    # its speed: the start takes twice the distance over that speed
    ahead = max(float((xb0[[X, Y]] - stop) @ _heading(xb0[YAW])), 0.0)
    start = min(2.0 * ahead / max(vb, _MIN_START_SPEED), g - brake)
    braking, starting = w < brake, (u < start) & (w >= brake)
    out = np.repeat(xa[None], len(w), axis=0)
    out[:, YAW] = xa[YAW]                       # held; turned while moving off (not wrapped)
    out[:, V] = out[:, A] = out[:, YAWRATE] = 0.0
    out[:, :2] = stop
    wb = w[braking]
    out[braking, :2] = xa[[X, Y]] + _heading(xa[YAW]) * (va * (wb - wb * wb / (2.0 * brake))
                                                          )[:, None]
    out[braking, V] = va * (1.0 - wb / brake)
    out[braking, A] = -va / brake if brake > 0 else 0.0
    moved = (1.0 - u[starting] / start) if start > 0 else np.ones(int(starting.sum()))
    out[starting, :2] = stop + np.outer(moved * moved, xb0[[X, Y]] - stop)
    out[starting, V] = vb * moved
    out[starting, A] = vb / start if start > 0 else 0.0
    out[starting, YAW] += turn * moved
    out[starting, YAWRATE] = turn / start if start > 0 else 0.0
    return out, _blend(a, b, w / g), ~braking & ~starting


def _blend(a: Track, b: Track, s: np.ndarray) -> np.ndarray | None:
    """Covariances (k, N_STATE, N_STATE) blended linearly from ``a``'s last row's to ``b``'s
    first row's at the gap fractions ``s`` (k,) (not a filter's); None without."""
    if a.covariances is None or b.covariances is None:
        return None
    w = np.asarray(s, dtype=float)[:, None, None]
    return (1.0 - w) * a.covariances[-1] + w * b.covariances[0]


def _standing(tr: Track) -> np.ndarray:
    """(n,) the track's standing flags (all False without)."""
    return np.zeros(len(tr), dtype=bool) if tr.standing is None else tr.standing


def _join(a: Track, b: Track, stand: bool, frame_times: np.ndarray,
          cfg: TrackingConfig) -> Track:
    """One track: ``a``'s rows, the gap rows (of a stand with ``stand``), ``b``'s rows;
    ``a``'s id."""
    ft = np.asarray(frame_times, dtype=float)
    times = ft[(ft > a.t[-1]) & (ft < b.t[0])]
    if stand:
        states, covs, still = stand_rows(a, b, times, cfg.relink_settle, cfg.stand_accel)
    else:
        (states, covs), still = gap_rows(a, b, times, cfg.relink_settle), np.zeros(len(times),
                                                                                  dtype=bool)
    all_states = np.concatenate([a.states, states, b.states])
    covariances = (None if covs is None
                   else np.concatenate([a.covariances, covs, b.covariances]))
    standing = np.concatenate([_standing(a), still, _standing(b)])
    return Track(
        id=a.id,
        t=np.concatenate([a.t, times, b.t]),
        states=all_states,
        labels=kappa_labels(all_states, cfg.eta, cfg.label_min_speed),
        covariances=covariances,
        det_index=np.concatenate([a.det_index, b.det_index]),
        det_step=np.concatenate([a.det_step, b.det_step + len(a) + len(times)]),
        length_floor=max(a.length_floor, b.length_floor),
        standing=standing if standing.any() else None,
    )


def relink(tracks: list[Track], lost: set[int], frame_times: np.ndarray,
           cfg: TrackingConfig) -> tuple[list[Track], list[Link]]:
    """The tracks with every lost track joined to the track it continues as (module
    docstring; ``relink_time`` and ``stand_time`` 0: unchanged), by id; and the links
    taken. ``lost``: ids of the tracks ended inside the field of view; ``frame_times`` (F,)
    s: every frame's time (the gap rows')."""
    if max(cfg.relink_time, cfg.stand_time) <= 0.0 or not lost:
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
    successor = {k.first: k for k in taken}
    out = []
    for tr in tracks:
        if tr.id in then_of:
            continue                                    # joined to its predecessor
        nxt = successor.get(tr.id)
        while nxt is not None:
            tr = _join(tr, by_id[nxt.then], nxt.stand, frame_times, cfg)
            nxt = successor.get(nxt.then)
        out.append(tr)
    return sorted(out, key=lambda tr: tr.id), taken
