"""The labelled source cloud of the fine registration, built from the tracks (paper III-C).

The paper's source cloud Z is the set of radar measurements the tracker used, each labelled by
the driving behaviour (kappa = yawrate / v against eta) of its track's state, voxel-downsampled
to the target's voxel size. :func:`build_source_cloud` builds it (``FineConfig.source =
"detections"``) and two track-derived alternatives: the tracked vehicle centres ("centres") and
the tracked contour points ("contours"), all in the coarse frame C.

Rules chosen here:

* Trajectory subset: the paper registers a random subset of the trajectories (20 of 80, 50 of
  146). ``n_trajectories`` and ``trajectory_share`` pick one without replacement with the
  caller's generator (seeded from ``Config.seed``), so a run is reproducible.
* Downsampling: one 2D voxel grid anchored at the origin of C; points are averaged per
  (label, voxel) pair so labels stay pure. A voxel holding points of several tracks keeps the
  track id of its first point (in track order), so ``track_id`` says where a point came from,
  not which tracks share its voxel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgloc.config import Config
from fgloc.errors import LocalizationError
from fgloc.geo import transform_points
from fgloc.labels import NAMES
from fgloc.registration.config import (
    SOURCE_KINDS,
    TARGET_KINDS,
    VISIBLE_SIDE_MODELS,
    FineConfig,
)
from fgloc.registration.visible_side import (
    VisibleSide,
    measure_visible_side,
    onto_cross_section,
)
from fgloc.scenario import Scenario
from fgloc.tracks import N_CONTOUR, N_KIN, YAW, Track, TrackSet, contour_angles


@dataclass
class SourceCloud:
    """Labelled source points of the fine registration.

    xy: (N, 2) float64 m in the coarse frame C. label: (N,) int8 codes of :mod:`fgloc.labels`.
    track_id: (N,) int64 id of the track each point came from (first point of its voxel).
    kind: the ``FineConfig.source`` it was built as. n_tracks_used / n_tracks_total: trajectories
    in the cloud / available. n_raw: points before downsampling. direction: (N, 2) unit driving
    direction in C of the tracks' states the points came from (mean over the voxel; the first
    point's where the voxel's directions cancel). weight: None, or (N,) the number of
    detections each point averages (``[fine] visible_side = "aspect"``: SICP weights the
    points by it; the detections are then moved along their tracks' headings onto the
    cross-sections through the tracked centres before averaging,
    :func:`fgloc.registration.visible_side.onto_cross_section`). visible_side: the
    visible-side offsets measured on the tracks (:mod:`fgloc.registration.visible_side`) the
    target is shifted by, or None (the constant ``coarse.visible_side_offset``).
    """

    xy: np.ndarray
    label: np.ndarray
    track_id: np.ndarray
    kind: str
    n_tracks_used: int
    n_tracks_total: int
    n_raw: int
    direction: np.ndarray | None = None
    weight: np.ndarray | None = None
    visible_side: VisibleSide | None = None

    def __len__(self) -> int:
        return int(self.xy.shape[0])

    def summary(self) -> dict[str, object]:
        """JSON-ready counts: points in total and per label name, trajectories used."""
        return {
            "kind": self.kind,
            "n_points": len(self),
            "n_points_raw": self.n_raw,
            "points_per_label": {NAMES[k]: int((self.label == k).sum()) for k in NAMES},
            "n_tracks_used": self.n_tracks_used,
            "n_tracks_total": self.n_tracks_total,
            **({} if self.visible_side is None
               else {"visible_side": self.visible_side.summary()}),
        }


def check_fine_config(cfg: FineConfig) -> None:
    """Raise ValueError naming the first invalid FineConfig field."""
    problems = {
        "source": cfg.source not in SOURCE_KINDS,
        "target": cfg.target not in TARGET_KINDS,
        "visible_side": cfg.visible_side not in VISIBLE_SIDE_MODELS,
        "slip_tracks": not cfg.slip_tracks >= 0,
        "merge_deg": not cfg.merge_deg >= 0.0,
        "lane_sample_step": not cfg.lane_sample_step > 0.0,
        "centre_weight_sigma": not cfg.centre_weight_sigma >= 0.0,
        "start_range": not cfg.start_range >= 0.0,
        "model_spread": not cfg.model_spread >= 0.0,
        "n_trajectories": cfg.n_trajectories is not None and cfg.n_trajectories < 1,
        "trajectory_share": not 0.0 < cfg.trajectory_share <= 1.0,
        "voxel_size": cfg.voxel_size is not None and not cfg.voxel_size > 0.0,
    }
    bad = [k for k, v in problems.items() if v]
    if bad:
        raise ValueError(f"invalid fine config field {bad[0]}: {getattr(cfg, bad[0])!r}")


def require_tracks(tracks: TrackSet, method: str) -> None:
    """Raise :class:`fgloc.errors.LocalizationError` when ``tracks`` holds no vehicle track:
    the message says how many the tracker found and why it left them out
    (:meth:`fgloc.tracks.TrackSet.left_out`) and what to change."""
    if tracks.tracks:
        return
    others, why = tracks.left_out()
    if others == 0:
        found = ("the tracker found no track (too few moving detections that stay together "
                 "over several frames)")
        change = "record longer or with more traffic"
    else:
        found = f"the tracker left out all {others} of its tracks as other road users {why}"
        change = ("record longer or with more traffic, or loosen [tracking] walking_speed, "
                  "min_vehicle_length, min_vehicle_width, off_lane_margin or off_road_margin")
    raise LocalizationError(f"{method}: no vehicle track to register: {found}; {change} "
                            "(icp needs no tracks)")


def choose_tracks(n: int, cfg: FineConfig, rng: np.random.Generator) -> np.ndarray:
    """Sorted indices of the trajectories to use out of ``n``: all, or a random subset of
    ``min(n_trajectories, ceil(trajectory_share * n))`` drawn without replacement."""
    k = int(np.ceil(cfg.trajectory_share * n - 1e-9))
    if cfg.n_trajectories is not None:
        k = min(k, cfg.n_trajectories)
    if k >= n:
        return np.arange(n)
    return np.sort(rng.choice(n, size=k, replace=False))


def _track_points(
    scn: Scenario, tr: Track, T_coarse: np.ndarray, kind: str, cross_section: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(n, 2) points in C of one track, the (n,) label and the (n,) heading (rad, C) of each;
    with ``cross_section`` detections are moved onto their states' cross-sections
    (:func:`fgloc.registration.visible_side.onto_cross_section`)."""
    if kind == "detections":
        xy = transform_points(T_coarse, np.asarray(scn.radar.xyz, float)[tr.det_index])[:, :2]
        yaw = tr.states[tr.det_step, YAW]
        if cross_section:
            xy = onto_cross_section(xy, tr.states[tr.det_step, :2], yaw)
        return xy, tr.labels[tr.det_step], yaw
    if kind == "centres":
        return tr.states[:, :2], tr.labels, tr.states[:, YAW]
    s = tr.states
    ang = contour_angles()[None, :] + s[:, YAW, None]
    r = s[:, N_KIN : N_KIN + N_CONTOUR]
    xy = np.stack([s[:, 0, None] + r * np.cos(ang), s[:, 1, None] + r * np.sin(ang)], axis=-1)
    return (xy.reshape(-1, 2), np.repeat(tr.labels, N_CONTOUR),
            np.repeat(s[:, YAW], N_CONTOUR))


def voxel_per_label(
    xy: np.ndarray, label: np.ndarray, voxel: float, values: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Average points (N, 2) per occupied (label, voxel) cell of a grid of edge ``voxel`` m
    anchored at the origin. Returns the (M, 2) centroids (with ``values`` (N, D): the cells'
    (M, D) means of those instead), their (M,) labels, the (M,) index of the first input
    point of each cell and the (M,) number of input points in each."""
    if xy.shape[0] == 0:
        width = 2 if values is None else values.shape[1]
        return np.zeros((0, width)), label[:0], np.zeros(0, dtype=np.int64), np.zeros(0)
    cell = np.floor(xy / voxel).astype(np.int64)
    cell -= cell.min(axis=0)
    span = cell.max(axis=0) + 1
    key = (label.astype(np.int64) * span[0] + cell[:, 0]) * span[1] + cell[:, 1]
    _, first, inv = np.unique(key, return_index=True, return_inverse=True)
    inv = inv.reshape(-1)
    n = np.bincount(inv).astype(float)
    v = xy if values is None else values
    cent = np.column_stack([np.bincount(inv, weights=v[:, k]) / n for k in range(v.shape[1])])
    return cent, label[first], first, n


def build_source_cloud(
    scn: Scenario, tracks: TrackSet, T_coarse: np.ndarray, cfg: Config,
    rng: np.random.Generator | None = None,
) -> SourceCloud:
    """Labelled source cloud in C from the tracks (module docstring), as ``cfg.fine`` says.

    tracks: the tracker's output in frame C (``det_index`` into ``scn.radar``, ``det_step`` into
    each track's states). T_coarse: 4x4 S -> L that placed the detections, i.e. S -> C. The
    voxel edge is ``cfg.fine.voxel_size``, else ``cfg.map.voxel_size`` (the target's). rng draws
    the trajectory subset (None: ``np.random.default_rng(cfg.seed)``). Raises ValueError for an
    invalid ``cfg.fine``.
    """
    fine = cfg.fine
    check_fine_config(fine)
    voxel = cfg.map.voxel_size if fine.voxel_size is None else fine.voxel_size
    used = choose_tracks(len(tracks), fine, rng or np.random.default_rng(cfg.seed))
    per_aspect = measures_visible_side(fine)
    parts = [_track_points(scn, tracks.tracks[i], T_coarse, fine.source, per_aspect)
             for i in used]
    xy = np.vstack([p[0] for p in parts]) if parts else np.zeros((0, 2))
    label = np.concatenate([p[1] for p in parts] + [np.zeros(0, np.int8)]).astype(np.int8)
    heading = np.concatenate([p[2] for p in parts] + [np.zeros(0)])
    track_id = np.concatenate(
        [np.full(len(p[1]), tracks.tracks[i].id, dtype=np.int64) for i, p in zip(used, parts)]
        + [np.zeros(0, np.int64)]
    )
    unit = np.column_stack([np.cos(heading), np.sin(heading)])
    means, lab, first, count = voxel_per_label(xy, label, voxel, np.hstack([xy, unit]))
    cent, direction = means[:, :2], means[:, 2:]
    norm = np.linalg.norm(direction, axis=1, keepdims=True)
    direction = np.where(norm > 1e-6, direction / np.maximum(norm, 1e-12), unit[first])
    side = None
    if per_aspect:
        placed = transform_points(T_coarse, np.asarray(scn.radar.xyz, float))[:, :2]
        side = measure_visible_side([tracks.tracks[i] for i in used], placed,
                                    np.asarray(T_coarse)[:2, 3], cfg.coarse.visible_side_offset,
                                    cfg.tracking.mean_width / 2.0)
    return SourceCloud(cent, lab, track_id[first], fine.source, int(used.size), len(tracks),
                       int(xy.shape[0]), direction, count if side is not None else None, side)


def measures_visible_side(fine: FineConfig) -> bool:
    """Whether the fine stage measures the visible-side offsets on the tracks: the detections
    registered to the visible sides with ``visible_side = "aspect"``."""
    return (fine.visible_side == "aspect" and fine.source == "detections"
            and fine.target == "visible-sides")
