"""Driving-behaviour labels shared by the target cloud (lanelets) and the source cloud (tracks).

Lanelets get theirs from Menger curvature (:mod:`fgloc.map`, the paper's rule) or, for the
movements through a junction, from the map's routing graph (:func:`routing_labels`).
"""

from __future__ import annotations

import numpy as np

from fgloc.geo import wrap_angle
from fgloc.scenario import Lanelet, LaneletMap

STRAIGHT: int = 0
LEFT: int = 1
RIGHT: int = 2
#: label code -> name as written in files (tracks.csv, PLY comments, result.json)
NAMES: dict[int, str] = {STRAIGHT: "straight", LEFT: "left", RIGHT: "right"}
CODES: dict[str, int] = {v: k for k, v in NAMES.items()}


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
    successor, which has one predecessor). A link with a predecessor and a successor is a
    junction movement when its predecessor branches (has several successors: a diverge) or its
    successor is a merge (has several predecessors).
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
        if before and after and (any(len(succ.get(b, ())) > 1 for b in before)
                                 or any(len(pred.get(a, ())) > 1 for a in after)):
            out.append(chain)
    return out


def _turn(before: list[Lanelet], after: list[Lanelet]) -> float:
    """Heading change (rad, CCW positive, wrapped) from the mean driving direction at the end of
    ``before`` to the mean one at the start of ``after``."""
    h_in = np.sum([_end_heading(ll, True) for ll in before], axis=0)
    h_out = np.sum([_end_heading(ll, False) for ll in after], axis=0)
    return float(wrap_angle(np.arctan2(h_out[1], h_out[0]) - np.arctan2(h_in[1], h_in[0])))


def routing_labels(lmap: LaneletMap, turn_angle: float) -> dict[int, int]:
    """Labels of the lanelets of junction movements (:func:`junction_movements`).

    A movement turns when the heading changes by more than ``turn_angle`` (rad) from its
    predecessors' end to its successors' start (CCW positive: LEFT, else RIGHT). A movement can
    be split into several lanelets and run on into the exit road, so each of its lanelets is
    judged between its own neighbours: it carries the movement's turn when its heading change
    has the same sign and exceeds ``turn_angle / 2``, else it is STRAIGHT. Lanelets outside
    movements are not in the result.
    """
    by_id = {ll.id: ll for ll in lmap.lanelets}
    pred = lmap.predecessors()
    out: dict[int, int] = {}
    for chain in junction_movements(lmap):
        lls = [by_id.get(i) for i in chain]
        before = [by_id[i] for i in pred.get(chain[0], ()) if i in by_id]
        after = [by_id[i] for i in lmap.successors.get(chain[-1], ()) if i in by_id]
        if not before or not after or None in lls:
            continue
        turn = _turn(before, after)
        if abs(turn) <= turn_angle:
            out.update({i: STRAIGHT for i in chain})
            continue
        code = LEFT if turn > 0 else RIGHT
        ends = [before, *[[ll] for ll in lls], after]
        for k, lid in enumerate(chain):
            own = _turn(ends[k], ends[k + 2])
            out[lid] = code if own * turn > 0 and abs(own) > turn_angle / 2 else STRAIGHT
    return out
