"""``--method filter-sicp``: the paper's full pipeline (sections III, IV-B).

target cloud -> coarse ICP (T_coarse, S -> L, SE(3)) -> GP-EOT tracking in the coarse frame C
-> labelled source cloud (:mod:`fgloc.registration.source`) -> semantic ICP in SE(2) from the
identity (C is within about a metre of L) -> ``T_fine`` (C -> L) -> ``T_utm = T~_fine · T_coarse``.

What the source and the target are is configured in ``[fine]`` (:class:`FineConfig`). The
paper registers the tracks' detections to the labelled ALS road points from a 50 m first
correspondence range. Started from the coarse pose that makes the pose worse: inside the road
the cost is flat (any pose keeping the points on the asphalt fits) and the wide first ranges
let off-road detections pull it by about a metre (docs/experiments.md). The default instead
registers the same labelled detections to the labelled lanelet centre lines shifted towards
the sensor (the radar sees a vehicle's near side) by the offset measured on the tracks at each
lane sample's aspect (``[fine] visible_side = "aspect"``, :mod:`fgloc.registration.visible_side`)
or by the constant ``coarse.visible_side_offset``, from a 5 m first range: the coarse stage's lane
model, but with only the detections the tracker assigned to vehicles (clutter and ghost points
left out) and with labels that keep turning vehicles on the turn lanes where lanes cross.
Measured on simulated intersections and T-junctions it lowers the coarse pose's mean error;
registering the tracked centres to the centre lines ("centres" / "lane-centres") is limited
by the tracker's lateral centre bias.
"""

from __future__ import annotations

import dataclasses
from dataclasses import asdict
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

from fgloc.config import Config, MapConfig
from fgloc.geo import se2_params, se2_to_se3, transform_points, wrap_angle
from fgloc.labels import NAMES, mirrored
from fgloc.map.lane_models import KEEP_RIGHT, min_width
from fgloc.progress import Timer
from fgloc.registration.config import FineConfig, SicpConfig
from fgloc.registration.modes import (
    ModeFit,
    choose_mode,
    mode_track_costs,
    placed_where_ended,
    position_prior,
)
from fgloc.registration.sicp import (
    SemanticTargets,
    SicpResult,
    sicp,
    track_covariance,
)
from fgloc.registration.slip import slip_starts
from fgloc.registration.source import (
    SourceCloud,
    build_source_cloud,
    check_fine_config,
    measures_visible_side,
    require_tracks,
)
from fgloc.registration.visible_side import VisibleSide
from fgloc.result import LocalizationResult, json_ready
from fgloc.scenario import TWO_WAY_MIN_WIDTH, Lanelet, LaneletMap, Scenario

if TYPE_CHECKING:
    from fgloc.coarse import CoarseResult, LaneCentres
    from fgloc.map import TargetCloud
    from fgloc.tracks import TrackSet


def lane_centre_points(
    scn: Scenario, target: TargetCloud, step: float, towards: np.ndarray | None = None,
    offset: float | VisibleSide = 0.0, two_way_min_width: float = TWO_WAY_MIN_WIDTH,
    centre: str = "resampled", labels: MapConfig | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(K, 2) samples (m, in L) of the lane centre lines of the lanelets in ``target``
    (:meth:`LaneCentres.of_target`: one per direction on a wide two-way lanelet), every about
    ``step`` m, the (K,) label code of each (its lanelet's label, mirrored on a lane driven
    against the lanelet's direction), the (K, 2) unit driving direction of each, the (K,)
    ambiguity (m) of where vehicles drive there (:meth:`LaneCentres.ambiguity`: its lanelet's
    centre line, a lane bent into its neighbour) and the (K,) lane id of each
    (:attr:`LaneCentres.lane`).
    With ``towards`` (2,) m, every sample is shifted ``offset`` m sideways towards that point
    (the sensor); a :class:`VisibleSide` offset shifts each sample by its value at the
    sample's aspect seen from there. ``two_way_min_width`` (m) sets the lane model of two-way
    lanelets (:func:`fgloc.map.lane_models.min_width`), ``centre`` the kind of the lanelets'
    centre lines (``[map] centre_line``), ``labels`` how the samples are labelled
    (:func:`lane_labels`; None: by their lanelets)."""
    from fgloc.coarse import LaneCentres

    lanelets = target.lanelets(scn.lanelets)
    lanes = LaneCentres.of_target(target, scn.lanelets, step, two_way_min_width, centre)
    if towards is not None and isinstance(offset, VisibleSide):
        offset = offset.at(lanes.aspect(towards))
    xy = lanes.xy if towards is None else lanes.towards(towards, offset).xy
    return (xy, lane_labels(target, lanelets, lanes, labels, scn.lanelets), lanes.direction,
            lanes.ambiguity(), lanes.lane)


def lane_labels(target: TargetCloud, lanelets: list[Lanelet], lanes: LaneCentres,
                cfg: MapConfig | None = None, lmap: LaneletMap | None = None) -> np.ndarray:
    """(K,) int8 label code of each sample of ``lanes`` (built from ``lanelets``, of the map
    ``lmap``): its lanelet's label in ``target``, mirrored (left <-> right) on a lane driven
    against the lanelet's direction; with ``cfg.lane_labels = "path"`` the label of its lane's
    path curvature instead (:mod:`fgloc.map.path_labels`)."""
    if cfg is not None and cfg.lane_labels == "path" and len(lanes.xy):
        from fgloc.map.lane_joins import lane_keys
        from fgloc.map.path_labels import path_labels

        # kept in target.memo like the lanes themselves (the entry holds them, so their id
        # cannot be reused while it lives): every mode and each probe of a valley asks again
        key = ("path labels", id(lanes), id(lmap), cfg.path_sigma, cfg.gamma)
        hit = target.memo.get(key)
        if hit is not None:
            return hit[1]
        keys = lane_keys(lanelets, lanes.lanelet, lanes.against, lanes.lane)
        labels = path_labels(lanes.xy, lanes.direction, lanes.lane, keys, cfg.path_sigma, cfg.gamma,
                             lmap).astype(np.int8)
        labels.setflags(write=False)
        target.memo[key] = ((lanes, lmap), labels)
        return labels
    own = np.array([target.lanelet_labels[ll.id] for ll in lanelets], np.int8)[lanes.lanelet]
    return np.where(lanes.against, mirrored(own), own).astype(np.int8)


def fine_targets(
    scn: Scenario, target: TargetCloud, cfg: Config, sensor_xy: np.ndarray,
    lanes: str = KEEP_RIGHT, side: VisibleSide | None = None,
) -> SemanticTargets:
    """The labelled SICP target in L of ``cfg.fine.target`` (see :class:`FineConfig`);
    sensor_xy: (2,) m, the sensor's position in L (for "visible-sides"); lanes: the lane model
    of two-way streets (:mod:`fgloc.map.lane_models`; not read for "road-points"); side: the
    visible-side offsets measured on the tracks ("visible-sides"; None: the constant
    ``coarse.visible_side_offset``)."""
    check_fine_config(cfg.fine)
    kind, step = cfg.fine.target, cfg.fine.lane_sample_step
    if kind == "road-points":
        return SemanticTargets.build(target.xyz[:, :2], target.label)
    width = min_width(lanes, cfg.map.two_way_min_width)
    towards: np.ndarray | None = None
    offset: float | VisibleSide = 0.0
    if kind == "visible-sides":
        towards = sensor_xy
        offset = cfg.coarse.visible_side_offset if side is None else side
    xy, label, direction, ambiguity, lane = lane_centre_points(
        scn, target, step, towards, offset, width, cfg.map.centre_line, cfg.map)
    return SemanticTargets.build(xy, label, direction,
                                 centre_weights(ambiguity, cfg.fine.centre_weight_sigma), lane)


def centre_weights(ambiguity: np.ndarray, sigma: float) -> np.ndarray | None:
    """(K,) weights ``sigma^2 / (sigma^2 + a^2)`` of lane samples whose centre line is
    ambiguous by ``a`` m (``[fine] centre_weight_sigma``, m); None (all 1) when ``sigma`` is
    0."""
    if sigma == 0.0:
        return None
    return sigma**2 / (sigma**2 + np.square(ambiguity))


def mode_targets(scn: Scenario, target: TargetCloud, cfg: Config, coarse: CoarseResult,
                 start: np.ndarray, lanes: str = KEEP_RIGHT, side: VisibleSide | None = None
                 ) -> SemanticTargets:
    """:func:`fine_targets` for the mode whose placement is ``start`` (3x3 C -> L) applied to
    the coarse frame and whose lane model is ``lanes``: the visible sides face that mode's
    sensor position."""
    return fine_targets(scn, target, cfg, transform_points(start, coarse.T_coarse[None, :2, 3])[0],
                        lanes, side)


def fine_sicp_config(cfg: Config) -> SicpConfig:
    """``cfg.sicp`` with ``cfg.fine.start_range`` (when > 0) as the first correspondence range
    (the floor is lowered to it when it is smaller)."""
    start = cfg.fine.start_range
    if start <= 0.0:
        return cfg.sicp
    return dataclasses.replace(cfg.sicp, max_correspondence=start,
                               min_correspondence=min(cfg.sicp.min_correspondence, start))


def sensor_covariance(cov_fine: np.ndarray | None, T_fine: np.ndarray,
                      sensor_c: np.ndarray, tilt: np.ndarray | None = None
                      ) -> np.ndarray | None:
    """3x3 covariance of the sensor's (x, y, yaw) in L from that of T_fine's (tx, ty, yaw),
    plus ``tilt`` (3x3, :func:`coarse_tilt_covariance`) when given.

    The sensor at ``sensor_c`` (2,) m in C lands at ``R p + t``; its Jacobian w.r.t. (tx, ty,
    yaw) is ``[[1, 0, -(R p)_y], [0, 1, (R p)_x], [0, 0, 1]]``.
    """
    if cov_fine is None:
        return None
    rp = T_fine[:2, :2] @ sensor_c
    J = np.array([[1.0, 0.0, -rp[1]], [0.0, 1.0, rp[0]], [0.0, 0.0, 1.0]])
    cov = J @ cov_fine @ J.T
    return cov if tilt is None else cov + tilt


def coarse_tilt_covariance(coarse: CoarseResult) -> np.ndarray | None:
    """3x3 covariance of the sensor's (x, y, yaw) in L that the coarse tilt's error causes
    (None without ``coarse.tilt_covariance``).

    The fine stages keep the coarse roll and pitch. A tilt error, the small rotation ``w``
    (about L's x and y axes) between the true and the coarse attitude, moves a point placed at
    height ``z`` sideways by ``z (w_y, -w_x)``; a planar registration aligns the vehicles at
    their reflection height, so the sensor, ``dh`` higher, keeps ``dh (w_y, -w_x)`` of it.
    ``dh`` is the sensor's height above the median placed dynamic point. Where one road
    leaves the roll about it to the prior (a straight road, a T-junction) this is a
    translation across the road the registration cannot see.
    """
    if coarse.tilt_covariance is None or not len(coarse.source_xyz):
        return None
    T = coarse.T_coarse
    z = coarse.source_xyz @ T[2, :3] + T[2, 3]
    dh = T[2, 3] - float(np.median(z))
    M = dh * np.array([[0.0, 1.0], [-1.0, 0.0]])
    out = np.zeros((3, 3))
    out[:2, :2] = M @ coarse.tilt_covariance @ M.T
    return out


def _sicp_diagnostics(res: SicpResult, scfg: SicpConfig, targets: SemanticTargets,
                      cfg: FineConfig) -> dict[str, object]:
    """JSON-ready summary of the SICP stage."""
    tx, ty, yaw = se2_params(res.T)
    deg = res.degeneracy
    return {
        "target": cfg.target,
        "target_points_per_label": {NAMES[k]: targets.count(k) for k in NAMES},
        "mode": scfg.mode,
        "start_range": scfg.max_correspondence,
        "final_range": res.final_range,
        "fitness": res.fitness,
        "inlier_rmse": res.inlier_rmse,
        "iterations": res.iterations,
        "converged": res.converged,
        "stop_reason": res.stop_reason,
        "label_counts": res.label_counts,
        "dropped_labels": res.dropped_labels,
        "sigma": res.sigma,
        "T_fine": {"x": tx, "y": ty, "yaw_deg": float(np.rad2deg(yaw))},
        "degeneracy": None if deg is None else {
            "condition_number": deg.condition_number,
            "eigenvalues": deg.eigenvalues.tolist(),
            "weakest_direction_u_v_arc": deg.weakest_direction.tolist(),
            "radius": deg.radius,
        },
    }


def _source_xyz_local(src: SourceCloud, T_fine: np.ndarray, target: TargetCloud) -> np.ndarray:
    """(N, 3) source points in L after the final pose, each at the height of the nearest road
    point (for the PLY and the plot)."""
    xy = transform_points(T_fine, src.xy)
    if len(target) == 0 or len(xy) == 0:
        return np.column_stack([xy, np.zeros(len(xy))])
    _, j = cKDTree(target.xyz[:, :2]).query(xy)
    return np.column_stack([xy, target.xyz[j, 2]])


def model_spread(scn: Scenario, cfg: Config, target: TargetCloud, coarse: CoarseResult,
                 start: np.ndarray, lanes: str, src_constant: SourceCloud, fit: SicpResult,
                 scfg: SicpConfig) -> tuple[np.ndarray, np.ndarray]:
    """``[fine] model_spread``: the 3x3 covariance term ``model_spread d d^T`` and ``d``, the
    difference (x m, y m, yaw rad) of the sensor in L between ``fit`` (the measured
    visible-side offsets) and a fit from the same ``start`` with the constant offset
    ``coarse.visible_side_offset`` (source ``src_constant``: its unweighted voxels).

    The two offset models bracket where a vehicle's returns lie; where they place the sensor
    apart, the pose depends on that model choice as much as on the data, which the fit's own
    covariance (the tracks' disagreement under one model) does not see."""
    targets = mode_targets(scn, target, cfg, coarse, start, lanes, None)
    other = sicp(src_constant.xy, src_constant.label, targets, None, start, scfg,
                 source_direction=src_constant.direction)
    sensor_c = coarse.T_coarse[None, :2, 3]
    d = np.r_[transform_points(fit.T, sensor_c)[0] - transform_points(other.T, sensor_c)[0],
              wrap_angle(se2_params(fit.T)[2] - se2_params(other.T)[2])]
    return cfg.fine.model_spread * np.outer(d, d), d


def register_tracks(
    scn: Scenario, cfg: Config, target: TargetCloud, coarse: CoarseResult, tracks: TrackSet,
    timer: Timer, method: str,
) -> LocalizationResult:
    """The fine stage: source cloud from ``tracks`` (frame C of ``coarse.T_coarse``) -> SICP
    against the ``cfg.fine.target`` from the identity -> T_fine (C -> L) -> the result of
    ``method`` with T_local = T~_fine · T_coarse.

    A label with too few source or target points is dropped with a warning; a SICP that stops
    on its iteration limit or finds too few correspondences leaves ``converged`` False (with
    too few correspondences the pose stays the coarse one). The result's ``covariance`` is the
    sensor's (x, y, yaw) covariance that counts the evidence per track
    (:func:`fgloc.registration.sicp.track_covariance`) plus the coarse tilt's
    (:func:`coarse_tilt_covariance`: the fine stage keeps the coarse roll and pitch); the one
    from SICP's information, which treats every source point as independent, is in the
    diagnostics as ``sicp.sensor_covariance_uncalibrated``. With measured visible-side offsets
    each mode is also registered with the constant offset and ``[fine] model_spread`` times the
    outer product of the two fits' difference is added (:func:`model_spread`). The source cloud
    is in L after the final pose and the tracks carry ``T_frame_to_L = T_fine``.

    Every coarse mode (``coarse.modes``) is registered, from its start (the tracks placed by
    the best mode moved rigidly onto it), against the targets seen from its sensor position;
    with ``[fine] slip_tracks`` the best fit is registered again from its slip starts
    (:mod:`fgloc.registration.slip`); the fits are compared on the same source cloud
    (:mod:`fgloc.registration.modes`; merged within ``[fine] merge_deg``) and the best one is
    reported; when they cannot be told apart, or the one left is not pinned to
    ``coarse.resolved_max_std`` (or has no covariance: too few matched points, or one
    straight track that fixes nothing along its road), the result is ``ambiguous`` and its
    covariance covers the modes (their spread plus each one's own covariance).
    Raises :class:`fgloc.errors.LocalizationError` when ``tracks`` holds no vehicle track
    (:func:`fgloc.registration.source.require_tracks`).
    """
    require_tracks(tracks, method)
    with timer.stage("source cloud"):
        src = build_source_cloud(scn, tracks, coarse.T_coarse, cfg)
        src_constant = None
        if measures_visible_side(cfg.fine) and cfg.fine.model_spread > 0.0:
            constant = dataclasses.replace(cfg, fine=dataclasses.replace(
                cfg.fine, visible_side="constant"))
            src_constant = build_source_cloud(scn, tracks, coarse.T_coarse, constant)
    scfg = fine_sicp_config(cfg)
    spreads: list[np.ndarray] = []
    runs: list[tuple[SicpResult, SemanticTargets]] = []
    fits: list[ModeFit] = []
    sensor_c = coarse.T_coarse[:2, 3]
    tilt = coarse_tilt_covariance(coarse)

    def fit_from(start: np.ndarray, lanes: str, lane_score: float) -> None:
        """Register from ``start`` (3x3 C -> L) against the lanes ``lanes`` seen from it;
        appends the fit, its SICP result and targets (and its model spread)."""
        targets = mode_targets(scn, target, cfg, coarse, start, lanes, src.visible_side)
        res = sicp(src.xy, src.label, targets, None, start, scfg,
                   weights=src.weight, source_direction=src.direction)
        T_local, z_std = placed_where_ended(coarse, se2_to_se3(res.T) @ coarse.T_coarse)
        cov = sensor_covariance(track_covariance(res, src.xy, src.track_id, targets, scfg,
                                                 sensor_c), res.T, sensor_c, tilt)
        if src_constant is not None:
            spread, d = model_spread(scn, cfg, target, coarse, start, lanes, src_constant,
                                     res, scfg)
            cov = None if cov is None else cov + spread
            spreads.append(d)
        fits.append(ModeFit(res.T, T_local, cov,
                            mode_track_costs(src, targets, res.T, cfg),
                            lane_score, res.converged, start, z_std, lanes))
        runs.append((res, targets))

    with timer.stage("SICP"):
        for start, mode in zip(coarse.mode_starts(), coarse.modes or [None]):
            fit_from(start, KEEP_RIGHT if mode is None else mode.lanes,
                     1.0 if mode is None else mode.lane_score)
        base = min(range(len(fits)), key=lambda k: fits[k].cost)
        for start in slip_starts(src, runs[base][1], fits[base].T_fine, sensor_c,
                                 cfg.fine.slip_tracks, cfg.coarse.mode_search_yaw_deg,
                                 cfg.coarse.mode_cost_scale, cfg.sicp.direction_gate_deg):
            fit_from(start, fits[base].lanes, fits[base].lane_score)
    # lane-line targets give every fit a covariance unless the data fix no pose
    choice = choose_mode(fits, cfg.coarse, prior=position_prior(scn, cfg.coarse),
                         require_covariance=cfg.fine.target != "road-points",
                         merge_deg=cfg.fine.merge_deg or None)
    best = next(i for i, f in enumerate(fits) if f is choice.best)
    res, targets = runs[best]
    T_fine = res.T
    warnings = [*target.warnings, *coarse.warnings, *res.warnings, *choice.warnings(method)]
    doubted = tracks.diagnostics.get("off_lane_doubted") or []
    if doubted:
        warnings.append(f"tracking: {len(doubted)} tracks ran off every drivable lanelet "
                        "(along the map's other ways: rails, walkways, bicycle lanes; or off "
                        "the roads), more than half the detections: kept as vehicles, the "
                        "coarse pose may be a lane off")
    if res.stop_reason == "max_iterations":
        warnings.append(f"SICP stopped on its iteration limit ({scfg.max_iterations}) before "
                        f"the RMSE settled: not converged")
    elif res.stop_reason == "too_few_correspondences":
        warnings.append(f"SICP found fewer than 3 correspondences for the {len(src)} source "
                        "points: the pose is the coarse one")
    coarse_diag = {k: v for k, v in asdict(coarse).items() if k not in ("T_coarse", "source_xyz")}
    tracking_diag = {k: v for k, v in tracks.diagnostics.items() if k != "birth_zones"}
    n_states = sum(len(tr) for tr in tracks.tracks)
    return LocalizationResult(
        method=method,
        frame=scn.frame,
        T_local=choice.best.T_local,
        converged=coarse.converged and res.converged,
        covariance=choice.covariance(cfg.coarse),
        diagnostics=json_ready({
            "target": target.summary(),
            "coarse": coarse_diag,
            "tracking": {**tracking_diag, "n_tracks": len(tracks), "n_states": n_states},
            "source": src.summary(),
            "sicp": {
                **_sicp_diagnostics(res, scfg, targets, cfg.fine),
                "sensor_covariance_uncalibrated": sensor_covariance(
                    res.covariance, T_fine, sensor_c),
                **({"constant_offset_difference": {
                    "dx_m": spreads[best][0], "dy_m": spreads[best][1],
                    "dyaw_deg": np.rad2deg(spreads[best][2])}} if spreads else {}),
            },
        }),
        warnings=warnings,
        config=cfg,
        source_xyz=_source_xyz_local(src, T_fine, target),
        source_label=src.label,
        target=target,
        tracks=dataclasses.replace(tracks, T_frame_to_L=T_fine),
        status=choice.status,
        modes=json_ready(choice.summary(scn.frame)),
        mode_fits=choice.fits,
        z_std=choice.best.z_std,
        weak_direction=choice.weak_summary(scn.frame),
    )
