"""Starts one lane over for the far tracks: the fine stage's guard against a lane slip.

Seen from 100-150 m, a far road's same-direction lanes lie about a degree apart around the
sensor, and the radar's azimuth noise spreads a far vehicle's detections across most of a
lane (0.4 deg is 1 m at 140 m). The nearest-neighbour cost then lets a far cluster's tails
match the lane beside it, and where the near tracks cannot tell a turn of a degree from
their own offsets, a pose that puts the far vehicles one lane over fits as well or better
(junction 12 seed 2 of the independent generator: every method 0.7-0.9 deg off with that
one mode and NEES 11-199; docs/experiments.md, issue 22). The coarse stage's modes are a
degree apart at least, so the two poses were one mode.

:func:`slip_starts` turns a fit about the sensor by the angle that moves each of the
farthest tracks (with a same-direction lane beside its own) one lane spacing across, both
ways; the fine stage registers from those starts too and compares every fit
(:func:`fgloc.registration.modes.choose_mode`), its final fits merging only within ``[fine]
merge_deg``: the unslipped pose becomes a mode of its own, tied or better. On by default
(``slip_tracks = 2``, ``merge_deg = 0.5``; figures in docs/experiments.md). Frames: the fit
is C -> L (3x3 SE(2)), the source points and the sensor in C, the targets in L; metres and
radians.
"""

from __future__ import annotations

import numpy as np

from fgloc.geo import se2, transform_points
from fgloc.registration.sicp import ALL, SemanticTargets
from fgloc.registration.source import SourceCloud

#: A lane beside another: its nearest sample lies at least this far across (m) ...
MIN_SPACING: float = 1.0
#: ... and at most this far along (m) from the matched one, driven the same way (cosine).
MAX_ALONG: float = 2.0
MIN_COS: float = 0.9
#: Candidate samples searched around each matched one (m, count).
SEARCH_RADIUS: float = 6.0
SEARCH_K: int = 32


def lane_spacing(targets: SemanticTargets, matched: np.ndarray) -> np.ndarray:
    """Per matched target sample (indices (n,) into ``targets``, which needs directions and
    lane ids) the distance (m) across its lane to the nearest sample of another lane driven
    the same way beside it (inf: none within :data:`SEARCH_RADIUS`)."""
    idx, tree = targets.tree(ALL)
    q, da, la = targets.xy[matched], targets.direction[matched], targets.lane[matched]
    k = min(SEARCH_K, len(idx))
    dk, jk = tree.query(q, k=k, distance_upper_bound=SEARCH_RADIUS)
    found = np.isfinite(dk.reshape(len(q), k))
    jk = idx[np.where(found, jk.reshape(len(q), k), 0)]
    off = targets.xy[jk] - q[:, None, :]
    along = np.einsum("nkj,nj->nk", off, da)
    across = np.abs(off[..., 1] * da[:, None, 0] - off[..., 0] * da[:, None, 1])
    beside = (found & (targets.lane[jk] != la[:, None]) & (np.abs(along) < MAX_ALONG)
              & (np.einsum("nkj,nj->nk", targets.direction[jk], da) > MIN_COS)
              & (across >= MIN_SPACING))
    return np.where(beside, across, np.inf).min(axis=1)


def slip_starts(src: SourceCloud, targets: SemanticTargets, T: np.ndarray,
                sensor_c: np.ndarray, n_tracks: int, max_deg: float, match_range: float,
                gate_deg: float) -> list[np.ndarray]:
    """Starts (3x3 SE(2) C -> L each) that turn the fit ``T`` (3x3 C -> L) about the sensor
    (``sensor_c`` (2,) m in C) so that each of the ``n_tracks`` farthest tracks of ``src``
    with a lane beside its own moves one lane spacing across, one start each way.

    A track counts when at least half (and 3) of its points matched within ``match_range``
    m (a lane of their driving direction within ``gate_deg``) have a same-direction lane
    beside theirs (:func:`lane_spacing`); its range is its points' median distance from the
    sensor, its spacing their median. Turns beyond ``max_deg`` deg or within 0.1 deg of a
    kept one are left out. None without target directions and lane ids or source
    directions, or with ``n_tracks`` 0."""
    if (n_tracks <= 0 or targets.direction is None or targets.lane is None
            or src.direction is None or len(src) == 0):
        return []
    moved = transform_points(T, src.xy)
    sensor = transform_points(T, np.asarray(sensor_c, float).reshape(1, 2))[0]
    d, j = targets.nearest(ALL, moved, match_range, src.direction @ T[:2, :2].T,
                           float(np.cos(np.deg2rad(gate_deg))))
    ok = np.flatnonzero(np.isfinite(d))
    if not len(ok):
        return []
    spacing = lane_spacing(targets, j[ok])
    rng = np.hypot(*(moved[ok] - sensor).T)
    tracks = []
    for tid in np.unique(src.track_id[ok]):
        sel = src.track_id[ok] == tid
        beside = np.isfinite(spacing[sel])
        if beside.sum() >= max(3, sel.sum() / 2):
            tracks.append((float(np.median(rng[sel])), float(np.median(spacing[sel][beside]))))
    turns: list[float] = []
    for r, s in sorted(tracks, reverse=True)[:n_tracks]:
        turn = s / max(r, 1e-9)
        if (np.rad2deg(turn) <= max_deg
                and all(abs(turn - t) > np.deg2rad(0.1) for t in turns)):
            turns.append(turn)
    about, back = se2(*sensor, 0.0), se2(*(-sensor), 0.0)
    return [about @ se2(0.0, 0.0, sign * t) @ back @ T for t in turns for sign in (1.0, -1.0)]
