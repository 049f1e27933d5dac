"""Tracking quality against ground truth (paper V-A: centre RMS, yaw error, IoU) plus counts.

Everything runs in the local frame L. The truth (:class:`fgloc.scenario.TrackTruth`) is
interpolated to each track's own time stamps -- linear in x, y, v and yaw rate, and in the
unwrapped yaw -- and never extrapolated beyond its time span, so truth and radar may be
sampled at different rates by independent generators.

Matching policy (one vehicle, possibly several tracks one after the other)
-------------------------------------------------------------------------
1. A (track, vehicle) pair is a *candidate* when the track has at least ``min_overlap_steps``
   time steps inside the vehicle's truth time span and the mean centre distance over those
   steps is below ``gate``; its cost is that mean distance.
2. Primary matches: one-to-one Hungarian assignment over the candidates
   (``scipy.optimize.linear_sum_assignment``), maximizing the number of matches first and
   minimizing the summed cost second.
3. Fragments (track breaks): each still unassigned track, cheapest candidate first, is
   attached to a candidate vehicle when it overlaps in time with every track already
   attached to that vehicle by less than ``handover_s`` (0.5 s: a vehicle's new track
   confirmed a moment before its old one's last row, either of the two the primary match;
   0 = no overlap at all, not even a shared time stamp). A fragment
   counts as matched -- its states enter the state metrics -- and is reported in
   ``fragments`` (a track break, not a false track).
4. Every other track -- no candidate, or only candidates already followed at the same time
   (a duplicate track) -- is a *false track*.

Counts use the *eligible* vehicles only: those visible for at least ``min_visible_s`` in
total (sum of the truth sampling intervals whose both ends are visible). Visibility comes
from an explicit mask per vehicle, from the true sensor pose and field of view, or, by
default, the whole truth span counts as visible. A track matched to an ineligible vehicle
(one seen only briefly) is neither a false track nor a counted match, but its states do
enter the state metrics, since it follows a real vehicle.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from fgloc.geo import wrap_angle
from fgloc.map import labels_from_curvature
from fgloc.scenario import AlsCloud, GroundTruth, TrackTruth
from fgloc.tracks import N_KIN, YAW, Track, TrackSet, contour_angles

#: states per chunk of the vectorized polygon clipping (bounds the temporary memory)
_CLIP_CHUNK = 16_384


# --------------------------------------------------------------------------------------------
# results
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TrackRow:
    """Per-track result. role: "matched" (primary), "fragment" (a later piece of a vehicle
    already followed) or "false". n: the track's steps scored against its vehicle (0 for a
    false track, whose metrics are NaN). Metrics as in :class:`TrackingMetrics`."""

    track_id: int
    truth_id: int | None
    role: str
    n: int
    centre_rms: float
    yaw_error_deg: float
    iou: float
    label_accuracy: float


@dataclass(frozen=True)
class TrackingMetrics:
    """Tracking quality of a track set against the ground truth (see the module docstring).

    n_true: eligible true vehicles. n_tracks: all tracks. n_matched: eligible vehicles followed
    by at least one track. missed / missed_ids: eligible vehicles without a track.
    false_tracks: tracks following no vehicle. fragments: extra tracks of an already followed
    vehicle (track breaks). tracked_share = n_matched / n_true. n_states: scored (track, time)
    pairs. centre_rms (m): RMS of the centre distance over all scored pairs. yaw_error_deg:
    mean absolute wrapped yaw difference. iou: mean IoU of the 20-point star-convex contour
    polygon with the true length x width rectangle at the true pose. label_accuracy: share of
    scored states whose label equals the one from the true curvature kappa = yawrate / v
    (kappa = 0 where v = 0). centre_rms_track_mean (m): the paper's "average RMS" (V-A), the
    mean of the per-track ``rows[k].centre_rms`` over matched and fragment tracks; the pooled
    centre_rms weights every state equally instead.
    Metrics without any scored state are NaN (``None`` in JSON).
    """

    n_true: int
    n_tracks: int
    n_matched: int
    missed: int
    false_tracks: int
    fragments: int
    tracked_share: float
    n_states: int
    centre_rms: float
    centre_rms_track_mean: float
    yaw_error_deg: float
    iou: float
    label_accuracy: float
    missed_ids: tuple[int, ...] = ()
    rows: tuple[TrackRow, ...] = ()

    def to_json(self) -> dict:
        """JSON-ready dict; NaN becomes None, rows become a list of dicts."""
        return _nan_to_none(asdict(self))

    def table(self, per_track: bool = False) -> str:
        """Two-line text table (header + values), optionally followed by one line per track."""
        head = (f"{'true':>5} {'tracks':>6} {'matched':>7} {'missed':>6} {'false':>5} "
                f"{'frag':>4} {'share':>6} {'RMS m':>7} {'trkRMS':>7} {'yaw deg':>8} {'IoU':>6} "
                f"{'label':>6}")
        row = (f"{self.n_true:5d} {self.n_tracks:6d} {self.n_matched:7d} {self.missed:6d} "
               f"{self.false_tracks:5d} {self.fragments:4d} {self.tracked_share:6.3f} "
               f"{self.centre_rms:7.3f} {self.centre_rms_track_mean:7.3f} "
               f"{self.yaw_error_deg:8.3f} {self.iou:6.3f} {self.label_accuracy:6.3f}")
        lines = [head, row]
        if per_track:
            lines.append(f"{'track':>6} {'truth':>6} {'role':>8} {'n':>6} {'RMS m':>7} "
                         f"{'yaw deg':>8} {'IoU':>6} {'label':>6}")
            lines += [
                f"{r.track_id:6d} {'-' if r.truth_id is None else r.truth_id:>6} {r.role:>8} "
                f"{r.n:6d} {r.centre_rms:7.3f} {r.yaw_error_deg:8.3f} {r.iou:6.3f} "
                f"{r.label_accuracy:6.3f}"
                for r in self.rows
            ]
        return "\n".join(lines)


def _nan_to_none(obj: object) -> object:
    if isinstance(obj, float) and math.isnan(obj):
        return None
    if isinstance(obj, dict):
        return {k: _nan_to_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_nan_to_none(v) for v in obj]
    return obj


# --------------------------------------------------------------------------------------------
# geometry: visibility and IoU
# --------------------------------------------------------------------------------------------
def in_field_of_view(
    xy: np.ndarray, sensor_pose: np.ndarray, hfov_deg: float = 360.0, max_range: float = math.inf
) -> np.ndarray:
    """(n,) bool: which points (n, 2) in L lie in the sensor's horizontal field of view.

    sensor_pose: 4x4 S -> L. A point is inside when its azimuth from the sensor position,
    measured from the boresight projected onto the ground plane, is within +-hfov_deg/2 and its
    horizontal distance is at most max_range (m).
    """
    d = np.asarray(xy, dtype=float)[:, :2] - sensor_pose[:2, 3]
    boresight = math.atan2(sensor_pose[1, 0], sensor_pose[0, 0])
    az = wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - boresight)
    return (np.abs(az) <= math.radians(hfov_deg) / 2.0) & (np.hypot(d[:, 0], d[:, 1]) <= max_range)


def visible_states(truth: GroundTruth, hfov_deg: float = 360.0, max_range: float = math.inf,
                   als: AlsCloud | None = None) -> dict[int, np.ndarray]:
    """Per true vehicle id, (n,) bool over its truth states: which the sensor at the true pose
    sees. In its field of view (:func:`in_field_of_view`) and, given the ALS ``als`` (in the
    truth's frame L), not behind one of its buildings
    (:class:`fgloc.tracking.sightlines.Buildings`: the sight line to 2 m above the ground under
    the vehicle's centre): a vehicle that stands behind a building is not missed."""
    from fgloc.tracking.sightlines import Buildings

    pose = truth.sensor_pose
    buildings = None if als is None else Buildings.of(als, pose[:2, 3], max_range)
    out = {}
    for tr in truth.tracks:
        seen = in_field_of_view(tr.states[:, 1:3], pose, hfov_deg, max_range)
        if buildings is not None and seen.any():
            seen[seen] = ~buildings.hidden(pose[:3, 3], tr.states[seen, 1:3])
        out[tr.id] = seen
    return out


def visible_duration(t: np.ndarray, visible: np.ndarray) -> float:
    """Seconds spent visible: the sum of the sampling intervals whose both ends are visible."""
    both = visible[1:] & visible[:-1]
    return float(np.sum(np.diff(t)[both]))


def polygon_area(poly: np.ndarray) -> np.ndarray:
    """(N,) signed shoelace areas (m^2, positive counter-clockwise) of polygons (N, m, 2)."""
    x, y = poly[..., 0], poly[..., 1]
    return 0.5 * np.sum(x * np.roll(y, -1, axis=-1) - np.roll(x, -1, axis=-1) * y, axis=-1)


def box_intersection_area(poly: np.ndarray, half_l: np.ndarray, half_w: np.ndarray) -> np.ndarray:
    """(N,) area (m^2) of polygons (N, m, 2) clipped to the boxes |x| <= half_l, |y| <= half_w.

    Vectorized Sutherland-Hodgman clipping against the four half-planes, then the shoelace
    area (sign follows the polygon's orientation). Exact for any simple polygon, convex or not:
    the clipped closed curve keeps the polygon's winding number inside the box, and the
    degenerate edges it may run along a box side enclose no area.
    """
    poly = np.asarray(poly, dtype=float)
    for axis, sign, half in ((0, 1.0, half_l), (0, -1.0, half_l), (1, 1.0, half_w),
                             (1, -1.0, half_w)):
        poly = _clip_half_plane(poly, axis, sign, np.asarray(half, dtype=float))
    return polygon_area(poly)


def _clip_half_plane(poly: np.ndarray, axis: int, sign: float, half: np.ndarray) -> np.ndarray:
    """Clip polygons (N, m, 2) to ``sign * p[axis] <= half``; returns (N, m', 2).

    Rows with fewer vertices than m' repeat their last vertex (zero-length edges change
    neither clipping nor area); rows clipped away entirely are all zeros.
    """
    n, m = poly.shape[:2]
    dp = sign * poly[..., axis] - half[:, None]
    dq = np.roll(dp, -1, axis=1)
    inside_q = dq <= 0.0
    cross = (dp <= 0.0) != inside_q
    frac = np.divide(dp, dp - dq, out=np.zeros_like(dp), where=cross)
    hit = poly + (np.roll(poly, -1, axis=1) - poly) * frac[..., None]
    table = np.concatenate([poly, hit], axis=1).reshape(-1, 2)
    # per edge p_i -> p_(i+1), Sutherland-Hodgman emits the crossing point (table slot m + i),
    # then p_(i+1) (slot (i + 1) % m) when it is inside
    slot = np.column_stack([m + np.arange(m), (np.arange(m) + 1) % m]).ravel()
    valid = np.stack([cross, inside_q], axis=2).reshape(n, 2 * m)
    rows, cols = np.nonzero(valid)
    if rows.size == 0:
        return np.zeros((n, 0, 2))
    src = rows * (2 * m) + slot[cols]
    count = np.bincount(rows, minlength=n)
    start = np.cumsum(count) - count
    k = np.minimum(np.arange(count.max()), np.maximum(count - 1, 0)[:, None])
    out = table[src[np.minimum(start[:, None] + k, src.size - 1)]]
    out[count == 0] = 0.0
    return out


def iou_polygon_rectangle(
    poly: np.ndarray, centre: np.ndarray, yaw: np.ndarray, length: np.ndarray, width: np.ndarray
) -> np.ndarray:
    """(N,) IoU of simple polygons (N, m, 2) with rectangles, all in one frame (m, rad).

    Rectangle k is length[k] x width[k], centred at centre[k] (N, 2), its length along
    yaw[k]. Each polygon is moved into its rectangle's frame and clipped there; states are
    processed in chunks to bound the memory.
    """
    poly = np.asarray(poly, dtype=float)
    n = poly.shape[0]
    length, width = np.broadcast_to(length, n), np.broadcast_to(width, n)
    out = np.zeros(n)
    for a in range(0, n, _CLIP_CHUNK):
        sl = slice(a, a + _CLIP_CHUNK)
        c, s = np.cos(yaw[sl])[:, None], np.sin(yaw[sl])[:, None]
        d = poly[sl] - centre[sl, None, :]
        local = np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)
        inter = np.abs(box_intersection_area(local, length[sl] / 2.0, width[sl] / 2.0))
        union = np.abs(polygon_area(local)) + length[sl] * width[sl] - inter
        out[sl] = np.divide(inter, union, out=np.zeros_like(inter), where=union > 0.0)
    return out


def contour_polygons(states: np.ndarray) -> np.ndarray:
    """(N, N_CONTOUR, 2) star-convex contour polygons of state rows (N, N_STATE), in the
    states' frame (the vectorized :meth:`fgloc.tracks.Track.contour_points`)."""
    ang = contour_angles()
    c, s = np.cos(states[:, YAW, None]), np.sin(states[:, YAW, None])
    r = states[:, N_KIN:]
    # cos/sin of (basis angle + yaw) by the addition theorem
    dx = r * (np.cos(ang) * c - np.sin(ang) * s)
    dy = r * (np.sin(ang) * c + np.cos(ang) * s)
    return np.stack([states[:, 0, None] + dx, states[:, 1, None] + dy], axis=-1)


# --------------------------------------------------------------------------------------------
# truth interpolation and matching
# --------------------------------------------------------------------------------------------
@dataclass
class _Truth:
    """A true vehicle prepared for interpolation: t (n,) and cols (n, 5) [x, y, yaw unwrapped,
    v, yawrate]."""

    id: int
    length: float
    width: float
    t: np.ndarray
    cols: np.ndarray
    eligible: bool

    def at(self, t: np.ndarray) -> np.ndarray:
        """(k, 5) truth at times t inside [t[0], t[-1]] (linear interpolation)."""
        return np.column_stack([np.interp(t, self.t, self.cols[:, k]) for k in range(5)])


@dataclass
class _Pair:
    """A candidate (track, vehicle) pair: the track's steps inside the truth span and the
    truth there."""

    track: int
    truth: int
    steps: np.ndarray
    truth_at: np.ndarray
    cost: float


def _prepare_truth(tr: TrackTruth, visible: np.ndarray | None, min_visible_s: float) -> _Truth:
    s = np.asarray(tr.states, dtype=float)
    if s.shape[0] < 2 or np.any(np.diff(s[:, 0]) <= 0):
        raise ValueError(f"true vehicle {tr.id}: needs >= 2 states with increasing t")
    vis = np.ones(s.shape[0], dtype=bool) if visible is None else np.asarray(visible, dtype=bool)
    if vis.shape != (s.shape[0],):
        raise ValueError(f"true vehicle {tr.id}: visibility mask must have shape ({len(s)},)")
    cols = np.column_stack([s[:, 1], s[:, 2], np.unwrap(s[:, 3]), s[:, 4], s[:, 5]])
    eligible = visible_duration(s[:, 0], vis) >= min_visible_s - 1e-9
    return _Truth(tr.id, float(tr.length), float(tr.width), s[:, 0], cols, eligible)


def _candidates(
    tracks: list[Track], truths: list[_Truth], gate: float, min_overlap_steps: int
) -> list[_Pair]:
    """Every (track, vehicle) pair with enough common steps and a mean distance below gate."""
    if not tracks or not truths:
        return []
    # cheap pre-filter: the time spans overlap and the xy bounding boxes come within the gate
    tr_box = np.array([_box(tr.t, tr.states[:, :2]) for tr in tracks])
    gt_box = np.array([_box(gt.t, gt.cols[:, :2]) for gt in truths])
    near = np.all((tr_box[:, None, :3] <= gt_box[None, :, 3:] + (0, gate, gate))
                  & (gt_box[None, :, :3] <= tr_box[:, None, 3:] + (0, gate, gate)), axis=2)
    pairs = []
    for i, j in zip(*np.nonzero(near)):
        tr, gt = tracks[i], truths[j]
        steps = np.flatnonzero((tr.t >= gt.t[0]) & (tr.t <= gt.t[-1]))
        if steps.size < max(min_overlap_steps, 1):
            continue
        t = tr.t[steps]
        dx = tr.states[steps, 0] - np.interp(t, gt.t, gt.cols[:, 0])
        dy = tr.states[steps, 1] - np.interp(t, gt.t, gt.cols[:, 1])
        cost = float(np.mean(np.hypot(dx, dy)))
        if cost < gate:
            pairs.append(_Pair(int(i), int(j), steps, gt.at(t), cost))
    return pairs


def _box(t: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """[t_min, x_min, y_min, t_max, x_max, y_max] of a track (all +-inf when empty)."""
    if t.size == 0:
        return np.array([np.inf] * 3 + [-np.inf] * 3)
    return np.r_[t[0], xy.min(axis=0), t[-1], xy.max(axis=0)]


def _assign(pairs: list[_Pair], tracks: list[Track], n_truth: int, handover_s: float
            ) -> dict[int, tuple[_Pair, str]]:
    """track index -> (pair, "matched" | "fragment") following the module's matching policy
    (a fragment overlaps the vehicle's other tracks by less than ``handover_s``)."""
    if not pairs:
        return {}
    big = 1.0 + 2.0 * sum(p.cost for p in pairs)  # above any sum of real costs: max cardinality
    cost = np.full((len(tracks), n_truth), big)
    by_ij = {(p.track, p.truth): p for p in pairs}
    for (i, j), p in by_ij.items():
        cost[i, j] = p.cost
    out: dict[int, tuple[_Pair, str]] = {}
    for i, j in zip(*linear_sum_assignment(cost)):
        if (i, j) in by_ij:
            out[int(i)] = (by_ij[(i, j)], "matched")
    spans: dict[int, list[tuple[float, float]]] = {}
    for p, _ in out.values():
        spans.setdefault(p.truth, []).append((tracks[p.track].t[0], tracks[p.track].t[-1]))
    for p in sorted(pairs, key=lambda q: q.cost):
        if p.track in out:
            continue
        t0, t1 = tracks[p.track].t[0], tracks[p.track].t[-1]
        if all(min(t1, b) - max(t0, a) < handover_s for a, b in spans.get(p.truth, [])):
            out[p.track] = (p, "fragment")
            spans.setdefault(p.truth, []).append((t0, t1))
    return out


def evaluate_tracks(
    tracks: TrackSet,
    truth: GroundTruth,
    *,
    eta: float = 0.01,
    gate: float = 3.0,
    min_visible_s: float = 2.0,
    min_overlap_steps: int = 5,
    handover_s: float = 0.5,
    sensor_pose: np.ndarray | None = None,
    hfov_deg: float | None = None,
    max_range: float | None = None,
    visible: Mapping[int, np.ndarray] | None = None,
) -> TrackingMetrics:
    """Score ``tracks`` (any frame with its T_frame_to_L) against ``truth`` (in L).

    eta: curvature threshold (rad/m) of the true labels. gate: largest mean centre distance (m)
    of a match. min_visible_s: visible time (s) that makes a vehicle eligible for the counts.
    min_overlap_steps: fewest track steps inside a vehicle's truth span for a match.
    handover_s: a further track of a followed vehicle that overlaps its other tracks by less
    than this (s) is a fragment, not a false track (module docstring, step 3).
    Visibility (at most one source): ``visible`` maps a true vehicle id to an (n,) bool mask
    over its truth states (missing ids: all visible); or ``sensor_pose`` (4x4 S -> L, e.g.
    ``truth.sensor_pose``) with optional ``hfov_deg`` (default 360) and ``max_range`` (m,
    default unlimited); or neither: all truth states are visible.
    """
    if sensor_pose is None and (hfov_deg is not None or max_range is not None):
        raise ValueError("hfov_deg and max_range need sensor_pose")
    if sensor_pose is not None and visible is not None:
        raise ValueError("give either visible or sensor_pose, not both")
    masks: dict[int, np.ndarray] = dict(visible or {})
    if sensor_pose is not None:
        fov = (360.0 if hfov_deg is None else hfov_deg,
               math.inf if max_range is None else max_range)
        masks = {tr.id: in_field_of_view(tr.states[:, 1:3], sensor_pose, *fov)
                 for tr in truth.tracks}
    truths = [_prepare_truth(tr, masks.get(tr.id), min_visible_s) for tr in truth.tracks]
    local = tracks.in_local().tracks
    assigned = _assign(_candidates(local, truths, gate, min_overlap_steps), local, len(truths),
                       handover_s)

    rows, err = [], []
    for i, tr in enumerate(local):
        if i not in assigned:
            rows.append(TrackRow(tr.id, None, "false", 0, *(math.nan,) * 4))
            continue
        pair, role = assigned[i]
        e = _state_errors(tr, truths[pair.truth], pair, eta)
        err.append(e)
        rows.append(TrackRow(tr.id, truths[pair.truth].id, role, len(pair.steps),
                             *_summary(e)))
    eligible = {gt.id for gt in truths if gt.eligible}
    followed = {truths[p.truth].id for p, _ in assigned.values()}
    missed = tuple(sorted(eligible - followed))
    n_true = len(eligible)
    n_matched = n_true - len(missed)
    all_err = np.vstack(err) if err else np.zeros((0, 4))
    rms, yaw_deg, iou, label_acc = _summary(all_err)
    return TrackingMetrics(
        n_true=n_true,
        n_tracks=len(local),
        n_matched=n_matched,
        missed=len(missed),
        false_tracks=sum(r.role == "false" for r in rows),
        fragments=sum(r.role == "fragment" for r in rows),
        tracked_share=n_matched / n_true if n_true else math.nan,
        n_states=int(all_err.shape[0]),
        centre_rms=rms,
        centre_rms_track_mean=_mean_track_rms(rows),
        yaw_error_deg=yaw_deg,
        iou=iou,
        label_accuracy=label_acc,
        missed_ids=missed,
        rows=tuple(rows),
    )


def _mean_track_rms(rows: list[TrackRow]) -> float:
    """Mean of the per-track centre RMS over tracks that follow a vehicle (NaN if none)."""
    vals = [r.centre_rms for r in rows if r.role != "false" and np.isfinite(r.centre_rms)]
    return float(np.mean(vals)) if vals else math.nan


def _state_errors(tr: Track, gt: _Truth, pair: _Pair, eta: float) -> np.ndarray:
    """(k, 4) per scored step: centre distance (m), |yaw error| (deg), IoU, label correct."""
    s = tr.states[pair.steps]
    x, y, yaw, v, yawrate = pair.truth_at.T
    dist = np.hypot(s[:, 0] - x, s[:, 1] - y)
    dyaw = np.abs(np.rad2deg(wrap_angle(s[:, YAW] - yaw)))
    iou = iou_polygon_rectangle(contour_polygons(s), np.column_stack([x, y]), yaw,
                                np.full(len(s), gt.length), np.full(len(s), gt.width))
    kappa = np.divide(yawrate, v, out=np.zeros_like(v), where=v != 0.0)
    correct = tr.labels[pair.steps] == labels_from_curvature(kappa, eta)
    return np.column_stack([dist, dyaw, iou, correct.astype(float)])


def _summary(err: np.ndarray) -> tuple[float, float, float, float]:
    """(centre RMS, mean yaw error, mean IoU, label accuracy) of (k, 4) errors; NaN if k = 0."""
    if err.shape[0] == 0:
        return (math.nan,) * 4
    rms = float(np.sqrt(np.mean(err[:, 0] ** 2)))
    return rms, float(np.mean(err[:, 1])), float(np.mean(err[:, 2])), float(np.mean(err[:, 3]))
