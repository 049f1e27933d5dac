"""Driving-behaviour labels shared by the target cloud (lanelets) and the source cloud (tracks).

Lanelets get theirs from Menger curvature (:mod:`fgloc.map`, the paper's rule) or, for the
movements through a junction, from the map's routing graph (:func:`routing_labels`).
"""

from __future__ import annotations

import numpy as np

from factors.state import YAWRATE, V
from fgloc.geo import wrap_angle
from fgloc.scenario import Lanelet, LaneletMap

STRAIGHT: int = 0
LEFT: int = 1
RIGHT: int = 2
#: label code -> name as written in files (tracks.csv, PLY comments, result.json)
NAMES: dict[int, str] = {STRAIGHT: "straight", LEFT: "left", RIGHT: "right"}
CODES: dict[str, int] = {v: k for k, v in NAMES.items()}


def kappa_labels(states: np.ndarray, eta: float, min_speed: float) -> np.ndarray:
    """(n,) int8 label codes from kappa = yawrate / v (rad/m): left above eta, right below
    -eta, straight otherwise and when |v| < min_speed (m/s)."""
    v = states[:, V]
    fast = np.abs(v) >= min_speed
    kappa = np.where(fast, states[:, YAWRATE] / np.where(fast, v, 1.0), 0.0)
    out = np.full(len(v), STRAIGHT, dtype=np.int8)
    out[kappa > eta] = LEFT
    out[kappa < -eta] = RIGHT
    return out


def mirrored(codes: np.ndarray) -> np.ndarray:
    """Label codes of the same paths driven the other way: LEFT and RIGHT swapped."""
    codes = np.asarray(codes)
    return np.where(codes == LEFT, RIGHT, np.where(codes == RIGHT, LEFT, codes)).astype(codes.dtype)


def label_names(codes: np.ndarray) -> np.ndarray:
    """Array of label names for an array of label codes."""
    lut = np.array([NAMES[k] for k in sorted(NAMES)], dtype=object)
    return lut[np.asarray(codes, dtype=np.int64)]


def _end_heading(lanelet: Lanelet, at_end: bool, n: int = 11) -> np.ndarray:
    """Unit vector (2,) of the driving direction over the last (first) 10 % of the centre line."""
    c = lanelet.centerline(n)
    d = c[-1] - c[-2] if at_end else c[1] - c[0]
    return d / max(float(np.linalg.norm(d)), 1e-12)


def junction_movements(lmap: LaneletMap) -> list[list[int]]:
    """Chains of lanelet ids that form one movement through a junction in the routing graph.

    The graph is cut into links: maximal chains whose inner connections are one-to-one (one
    successor, which has one predecessor). A link is a junction movement when its predecessor
    branches (has several successors: a diverge) or its successor is a merge (has several
    predecessors).
    """
    succ = lmap.successors
    pred = lmap.predecessors()

    def one_to_one(a: int) -> bool:
        s = succ.get(a, ())
        return len(s) == 1 and len(pred.get(s[0], ())) == 1

    out, seen = [], set()
    for lid in sorted(set(succ) | set(pred)):
        if lid in seen:
            continue
        first = lid
        for _ in range(len(succ) + 1):  # walk back to the link's start (a cycle stops here)
            p = pred.get(first, ())
            if len(p) != 1 or not one_to_one(p[0]) or p[0] == lid:
                break
            first = p[0]
        chain = [first]
        while one_to_one(chain[-1]) and succ[chain[-1]][0] not in chain:
            chain.append(succ[chain[-1]][0])
        seen.update(chain)
        before, after = pred.get(chain[0], ()), succ.get(chain[-1], ())
        if (any(len(succ.get(b, ())) > 1 for b in before)
                or any(len(pred.get(a, ())) > 1 for a in after)):
            out.append(chain)
    return out


def _direction(lanelets: list[Lanelet], at_end: bool) -> float:
    """Mean driving direction (rad) at the end (start) of ``lanelets``."""
    h = np.sum([_end_heading(ll, at_end) for ll in lanelets], axis=0)
    return float(np.arctan2(h[1], h[0]))


def routing_labels(lmap: LaneletMap, turn_angle: float) -> dict[int, int]:
    """Labels of the lanelets of junction movements (:func:`junction_movements`).

    A movement turns when the heading changes by more than ``turn_angle`` (rad) from its
    predecessors' end to its successors' start (CCW positive: LEFT, else RIGHT; the movement's
    own start or end where the map has no predecessor or successor). A movement can be split
    into several lanelets and run on into the exit road, so each of its lanelets carries the
    turn only when it turns by more than ``turn_angle / 2`` the same way itself: the lanelet
    next to the branch (after the diverge, before the merge) measured from its predecessor's end
    to its successor's start (coarsely drawn junction lanelets make their turn in the kinks),
    every other one from its own start to its own end. The rest are STRAIGHT; lanelets outside
    movements are not in the result.
    """
    by_id = {ll.id: ll for ll in lmap.lanelets}
    pred = lmap.predecessors()
    out: dict[int, int] = {}
    for chain in junction_movements(lmap):
        lls = [by_id[i] for i in chain if i in by_id]
        if len(lls) != len(chain):
            continue
        before = [by_id[i] for i in pred.get(chain[0], ()) if i in by_id]
        after = [by_id[i] for i in lmap.successors.get(chain[-1], ()) if i in by_id]
        start = [_direction([ll], False) for ll in lls]
        end = [_direction([ll], True) for ll in lls]
        h_in = [_direction(before, True) if before else start[0], *end[:-1]]
        h_out = [*start[1:], _direction(after, False) if after else end[-1]]
        turn = float(wrap_angle(h_out[-1] - h_in[0]))
        if abs(turn) <= turn_angle:
            out.update({i: STRAIGHT for i in chain})
            continue
        branch = {0} if any(len(lmap.successors.get(b.id, ())) > 1 for b in before) else set()
        if any(len(pred.get(a.id, ())) > 1 for a in after):
            branch.add(len(chain) - 1)
        for k, lid in enumerate(chain):
            a, b = (h_in[k], h_out[k]) if k in branch else (start[k], end[k])
            own = float(wrap_angle(b - a))
            out[lid] = (LEFT if turn > 0 else RIGHT) if own * turn > 0 and abs(own) > \
                turn_angle / 2 else STRAIGHT
    return out
