"""Coarse localization (paper III-A, IV-B): accumulated dynamic radar points registered to the
road points of the target cloud, giving ``T_coarse`` (sensor frame S -> local frame L, SE(3)).

Method
------
1. Source: detections with ``|doppler| >= lambda`` from the whole recording, voxel-downsampled
   per Doppler sign and filtered by DBSCAN's noise test to drop isolated clutter.
2. The pose is split as ``R = Rz(yaw) R_tilt`` with ``R_tilt = Ry(pitch) Rx(roll)``. Dynamic
   points lie on vehicle bodies 0.3-1.5 m above the asphalt while the target is the asphalt, so a
   3D point-to-point ICP would pull the sensor down by the reflection height. Instead:

   * horizontal (x, y, yaw): a planar problem. The levelled source ``R_tilt p`` projected to the
     ground must lie on the road, i.e. inside the lanelets, near target points in 2D;
   * vertical (z, pitch, roll): the levelled heights of the moving detections themselves (not
     the voxel centroids: a centroid is no unbiased sample of the heights it averages) must
     equal the road height under each plus a mean reflection height
     (``CoarseConfig.reflection_height``), a linear
     least-squares fit against the ALS road heights (ridge-regularized so a single straight road
     cannot make the roll about it diverge).

   The two alternate a few times in the refinement (step 4), starting at pitch = roll = 0.
3. Start of the horizontal problem: an exhaustive, cheap search over yaw (the whole circle, or a
   window around ``yaw_guess_deg``) x a grid of start positions around the approximate position.
   Each hypothesis is scored by a robust fitness, the mean of ``clip(1 - d / tau, 0, 1)`` over the
   source points, ``d`` being the distance to the nearest road cell read from a precomputed
   raster (a point on the road scores 1, a point ``tau`` m or more off the road 0, so neither
   outliers nor the luck of the first guess decide). The best distinct hypotheses are refined
   with a planar point-to-point ICP against the road points (shrinking correspondence range, one
   2D KD-tree) and re-scored with exact KD-tree distances; the best one wins.
4. Lane-centre refinement. Inside the road the road-area fit is flat (every pose that keeps the
   cloud on the asphalt fits equally well), which leaves about a metre of slack. Vehicles drive
   along the lane centres, and the radar sees their sensor-facing side, so the last stage
   registers the cloud to the lanelet centre lines (of the lanelets in the target cloud),
   sampled every ``lane_sample_step`` m and shifted towards the current sensor position by
   ``visible_side_offset`` m where the sensor sees the lane head-on to
   ``visible_side_offset_broadside`` m where it sees it broadside (:func:`side_offsets`),
   alternating with the vertical fit. A point moving away from the sensor is matched only to
   lanes driven away from it and vice versa (``SignedLanes``; lanes within
   ``lane_doppler_gate_deg`` of square to the line of sight admit both).

Fitness and inlier RMSE are planar (2D) quantities: the share of source points with a road point
within the last correspondence range, and the RMS 2D distance of those points.

The pieces: the source (step 1) in :mod:`fgloc.coarse.points`, the planar targets, ICP and
search (steps 2-4) in :mod:`fgloc.coarse.icp`, the vertical fit in :mod:`fgloc.coarse.vertical`;
this module drives them and keeps the modes (:class:`CoarseMode`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from fgloc.coarse.icp import (
    IcpOutcome,
    LaneCentres,
    RoadModel,
    ScoreRaster,
    SignedLanes,
    apply_planar,
    distinct_peaks,
    icp_planar,
    robust_score,
    search_grid,
)
from fgloc.coarse.points import dynamic_points
from fgloc.coarse.valley import Valley, find_valley
from fgloc.coarse.vertical import StaticGround, below_fov_floor, fit_vertical, rodrigues
from fgloc.config import CoarseConfig, Config, MapConfig
from fgloc.errors import LocalizationError
from fgloc.geo import pose_from_se3, rot_from_ypr, rot_z, se2, se3, wrap_angle, ypr_from_rot
from fgloc.map import TargetCloud, approx_position_local, build_target_cloud, check_inside_als
from fgloc.map.lane_models import KEEP_RIGHT, lane_models, min_width, other_model_note
from fgloc.progress import Timer
from fgloc.registration.considered import bias_columns, least_squares_consider, side_sign
from fgloc.scenario import Scenario


@dataclass
class CoarseResult:
    """Outcome of :func:`coarse_localize`.

    T_coarse: 4x4 transform S -> L. pose: (x, y, z, yaw, pitch, roll) of T_coarse, m and rad.
    fitness: share of source points with a road point within the last ICP range (2D).
    inlier_rmse: RMS 2D distance (m) of those points. n_points_dynamic: detections with
    ``|doppler| >= lambda``. n_points_used: after voxel + DBSCAN. n_points_off_trail: the
    dynamic detections dropped as no vehicle's (:func:`fgloc.coarse.points.on_trail`).
    yaw_search: (yaw_deg, best score over the start positions) per searched yaw, None when
    not searched. timings: stage -> seconds. source_xyz: (n_points_used, 3) filtered dynamic
    points in S. valley: the line the modes are samples of, where the lane score ties every
    pose along it (:mod:`fgloc.coarse.valley`; ``mode_margin`` of the best mode's score), or
    None.
    tie_covariance: 3x3 of the best mode's sensor (x, y, yaw) in L (m^2, rad^2) over the poses
    around it whose lane score ties with it (:func:`lane_tie_covariance`) plus the biases its
    lane fit considers (:func:`lane_fit_considered`), or None. z_std: the
    vertical fit's std. dev. of z (m). n_static_ground: the static ground returns that fit used
    (0: the moving returns alone; :class:`~fgloc.coarse.vertical.VerticalFit`).
    """

    T_coarse: np.ndarray
    pose: tuple[float, float, float, float, float, float]
    fitness: float
    inlier_rmse: float
    n_points_dynamic: int
    n_points_used: int
    converged: bool
    message: str
    yaw_search: list[tuple[float, float]] | None
    timings: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    source_xyz: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    tilt_covariance: np.ndarray | None = None
    modes: list[CoarseMode] = field(default_factory=list)
    z_std: float | None = None
    n_static_ground: int = 0
    valley: Valley | None = None
    tie_covariance: np.ndarray | None = None
    n_points_off_trail: int = 0

    @property
    def tilt_std(self) -> tuple[float, float] | None:
        """Std. devs. (rad) of the sensor's pitch and roll: ``tilt_covariance`` turned into the
        levelled sensor axes (roll about the boresight, pitch about the axis across it);
        None without a vertical fit."""
        if self.tilt_covariance is None:
            return None
        to_l = rot_z(self.pose[3])[:2, :2]
        lev = to_l.T @ self.tilt_covariance @ to_l
        return float(np.sqrt(lev[1, 1])), float(np.sqrt(lev[0, 0]))

    def mode_starts(self) -> list[np.ndarray]:
        """Per mode, the 3x3 SE(2) start of T_fine (C -> L) that moves the coarse frame C of
        ``T_coarse`` onto that mode's placement (the identity for the first, best mode);
        ``[np.eye(3)]`` when no modes were kept."""
        return [m.start for m in self.modes] or [np.eye(3)]


@dataclass
class CoarseMode:
    """One distinct coarse pose within ``mode_margin`` of the best lane-centre score.

    pose2d: (x, y, yaw) of the sensor in L (m, rad). lane_score: its robust lane-centre score
    (:func:`robust_score`, 1 = every point on a shifted centre line). start: 3x3 SE(2) C -> L
    that moves the best mode's placement onto this one (the same tilt: the registrations
    later reuse the tracks placed by the best mode, moved rigidly). z, z_std: the sensor height
    (m in L) of the vertical fit at this mode's pose and its std. dev. (m; None without a fit);
    a final pose nearest this mode's position takes this height
    (:func:`fgloc.registration.modes.height_mode`). lanes: the lane model of
    two-way streets it was found with (:mod:`fgloc.map.lane_models`); the later stages register
    it against the same.
    """

    pose2d: np.ndarray
    lane_score: float
    start: np.ndarray
    z: float
    z_std: float | None = None
    lanes: str = KEEP_RIGHT

    def placed(self, T_local: np.ndarray) -> np.ndarray:
        """``T_local`` (4x4 S -> L) with this mode's height."""
        out = np.array(T_local, dtype=float)
        out[2, 3] = self.z
        return out




# --------------------------------------------------------------------------------------------
# driver
# --------------------------------------------------------------------------------------------
def _yaw_candidates(yaw_guess_deg: float | None, cfg: CoarseConfig) -> np.ndarray:
    """Searched yaws (rad): the whole circle, or a window around the guess."""
    step = np.deg2rad(cfg.yaw_search_step_deg)
    if yaw_guess_deg is None:
        return np.arange(-np.pi, np.pi, step)
    w = np.deg2rad(cfg.yaw_guess_window_deg)
    return np.deg2rad(yaw_guess_deg) + np.arange(-w, w + 1e-9, step)


def outside_search(pose2d: np.ndarray, centre: np.ndarray, yaw_guess_deg: float | None,
                   cfg: CoarseConfig) -> str | None:
    """Why the planar pose (x, y, yaw; m, rad in L) lies outside the searched region grown to
    twice its size (``position_search_radius`` about ``centre``, sensor.toml's approximate
    position; ``yaw_guess_window_deg`` about ``yaw_guess_deg`` when given), None inside."""
    far = float(np.hypot(*(pose2d[:2] - centre)))
    if far > 2.0 * cfg.position_search_radius:
        return (f"{far:.1f} m from sensor.toml's approx_position (searched within "
                f"coarse.position_search_radius = {cfg.position_search_radius:g} m)")
    if yaw_guess_deg is not None:
        off = abs(float(np.rad2deg(wrap_angle(pose2d[2] - np.deg2rad(yaw_guess_deg)))))
        if off > 2.0 * cfg.yaw_guess_window_deg:
            return (f"yaw {off:.1f} deg from sensor.toml's yaw_guess_deg (searched within "
                    f"coarse.yaw_guess_window_deg = {cfg.yaw_guess_window_deg:g} deg)")
    return None


def side_offsets(lanes: LaneCentres, sensor_xy: np.ndarray, cfg: CoarseConfig) -> np.ndarray:
    """(K,) m, how far each lane sample is shifted towards the sensor at ``sensor_xy`` (2,):
    ``visible_side_offset`` head-on to ``visible_side_offset_broadside`` broadside, linear in
    the |sin| of the aspect (:meth:`LaneCentres.aspect`)."""
    head_on, broadside = cfg.visible_side_offset, cfg.visible_side_offset_broadside
    return head_on + (broadside - head_on) * lanes.aspect(sensor_xy)


def _seen_from(lanes: LaneCentres, sensor_xy: np.ndarray, cfg: CoarseConfig) -> SignedLanes:
    """The lane-centre target of the lane fits: the centre lines shifted towards the sensor
    position ``sensor_xy`` (2,) by :func:`side_offsets`, split by Doppler sign
    (``lane_doppler_gate_deg``)."""
    return lanes.seen_from(sensor_xy, side_offsets(lanes, sensor_xy, cfg),
                           cfg.lane_doppler_gate_deg)


def _lane_fit(lev: np.ndarray, receding: np.ndarray, target: SignedLanes | LaneCentres,
              pose: np.ndarray, cfg: CoarseConfig, iterations: int | None = None
              ) -> tuple[float, np.ndarray]:
    """Lane-centre ICP of levelled points ``lev`` (N, 2) with Doppler signs ``receding`` (N,)
    from ``pose`` against ``target`` (given the lanes: those seen from the pose's sensor
    position, start and end); (robust lane score, end pose). ``iterations`` per ICP stage
    (default ``cfg.icp_iterations``)."""
    tau = cfg.lane_icp_ranges[-1]
    lanes = target if isinstance(target, LaneCentres) else None
    if lanes is not None:
        target = _seen_from(lanes, pose[:2], cfg)
    end = icp_planar(lev, target, pose, cfg.lane_icp_ranges,
                     iterations or cfg.icp_iterations, receding=receding).pose
    if lanes is not None:
        target = _seen_from(lanes, end[:2], cfg)
    d = target.query(apply_planar(lev, end), receding, tau)[0]
    return robust_score(d, tau), end


def same_pose(a: np.ndarray, b: np.ndarray, cfg: CoarseConfig,
              yaw_deg: float | None = None) -> bool:
    """Whether planar poses ``a`` and ``b`` (x, y, yaw: m, m, rad) lie within
    ``cfg.mode_separation`` m and ``yaw_deg`` (default ``mode_separation_deg``) of each
    other: one mode, not two."""
    sep = cfg.mode_separation_deg if yaw_deg is None else yaw_deg
    return bool(np.hypot(*(a[:2] - b[:2])) < cfg.mode_separation
                and abs(wrap_angle(a[2] - b[2])) < np.deg2rad(sep))


def _distinct(pose: np.ndarray, kept: list[tuple[float, np.ndarray]], cfg: CoarseConfig) -> bool:
    """Whether ``pose`` is ``mode_separation`` m or ``mode_separation_deg`` from every kept."""
    return not any(same_pose(pose, k[1], cfg) for k in kept)


def lane_modes(
    refined: list[tuple[float, np.ndarray]], final: _Refined, src: np.ndarray,
    receding: np.ndarray, lanes: LaneCentres, cfg: CoarseConfig,
) -> list[tuple[float, np.ndarray]]:
    """The distinct planar poses (x, y, yaw) that fit the lane centres within
    ``cfg.mode_margin`` of the best, as (lane score, pose), best first (at most ``max_modes``).

    Starts: ``final``'s pose, the road-area search's runner-ups (which cannot tell poses a lane
    apart) and the ``mode_candidates`` best distinct peaks of a lane-level search: every pose
    within ``mode_search_radius`` m (steps of the raster cell ``mode_search_cell``) and
    ``mode_search_yaw_deg`` (steps ``mode_search_yaw_step_deg``) of ``final``'s, scored like
    the road-area search (:func:`search_grid`) on a raster of the centre lines shifted
    towards ``final``'s sensor (``tau`` = the last lane ICP range; one raster per Doppler sign
    of ``src``'s points, ``receding`` (N,)). Each start is carried
    through the lane-centre ICP on a subsample of ``mode_points`` levelled points
    (``mode_search_iterations`` per stage) against those lines; the distinct ends within
    ``mode_rough_margin`` of the best (the subsample's scores are noisier) are polished and
    re-scored with every point of ``src`` (levelled with ``final``'s tilt) against the lines
    shifted towards their own, and ``mode_margin`` applies to those scores.
    """
    lev_all = (src @ final.r_tilt.T)[:, :2]
    stride = max(1, len(lev_all) // cfg.mode_points)
    lev, rec = lev_all[::stride], receding[::stride]
    target = _seen_from(lanes, final.pose2d[:2], cfg)
    r, cell, tau = cfg.mode_search_radius, cfg.mode_search_cell, cfg.lane_icp_ranges[-1]
    offs = np.arange(-np.floor(r / cell), np.floor(r / cell) + 1) * cell
    w, step = cfg.mode_search_yaw_deg, cfg.mode_search_yaw_step_deg
    yaws = final.pose2d[2] + np.deg2rad(np.arange(-w, w + 1e-9, step))
    scores = np.zeros((len(yaws), len(offs), len(offs)), dtype=np.float32)
    for lines, sel in ((target.receding, rec), (target.approaching, ~rec)):
        if sel.any() and len(lines.xy):       # a sign without lanes scores 0
            raster = ScoreRaster.build(lines.xy, cell, 2.0 * (r + tau) + cell, tau)
            scores += search_grid(lev[sel], raster, final.pose2d[:2], yaws, offs) * (
                sel.sum() / len(lev))
    peaks = distinct_peaks(scores, yaws, offs, cfg.mode_candidates,
                           np.deg2rad(cfg.mode_separation_deg), cfg.mode_separation)
    grid = [np.array([final.pose2d[0] + dx, final.pose2d[1] + dy, yaw])
            for _, yaw, dx, dy in peaks]
    ends = [_lane_fit(lev, rec, target, p, cfg, cfg.mode_search_iterations)
            for p in [final.pose2d, *(p for _, p in refined[1:]), *grid]]
    rough = _distinct_within(ends, cfg.mode_rough_margin, len(ends), cfg)
    polished = [_lane_fit(lev_all, receding, lanes, pose, cfg) for _, pose in rough]
    return _distinct_within(polished, cfg.mode_margin, cfg.max_modes, cfg)


def _distinct_within(scored: list[tuple[float, np.ndarray]], share: float, limit: int,
                     cfg: CoarseConfig) -> list[tuple[float, np.ndarray]]:
    """The (score, pose) of ``scored`` whose score is at least ``share`` of the best and whose
    pose is distinct (:func:`_distinct`) from every better one kept, best first, at most
    ``limit``."""
    ranked = sorted(scored, key=lambda item: -item[0])
    kept: list[tuple[float, np.ndarray]] = []
    for score, pose in ranked:
        if len(kept) < limit and score >= share * ranked[0][0] and _distinct(pose, kept, cfg):
            kept.append((score, pose))
    return kept


def coarse_modes(kept: list[tuple[float, np.ndarray, str]], final: _Refined,
                 heights: list[tuple[float, float | None]]) -> list[CoarseMode]:
    """The modes (best first; (lane score, pose, lane model) each) with their starts relative
    to ``final``'s placement (the first mode's start is the identity: ``final`` is refined from
    it) and their (z, z std. dev.)."""
    base = np.linalg.inv(se2(*final.pose2d))
    return [CoarseMode(pose, score, np.eye(3) if k == 0 else se2(*pose) @ base, *height, model)
            for k, ((score, pose, model), height) in enumerate(zip(kept, heights))]


def _height_at(detections: np.ndarray, road: RoadModel, statics: StaticGround,
               final: _Refined, pose2d: np.ndarray, z_prior: float, vfov_deg: float,
               cfg: CoarseConfig) -> tuple[float, float | None]:
    """The sensor height (m in L) and its std. dev. of the vertical fit of the moving
    ``detections`` (N, 3) in S at another planar pose with ``final``'s tilt (a mode a lane
    away stands on other road heights); ``final``'s own when the fit finds too few points."""
    lev = detections @ final.r_tilt.T
    xy_l = apply_planar(lev[:, :2], pose2d)
    seen = below_fov_floor(detections, final.r_tilt, final.z, road.road_height(xy_l)[0],
                           vfov_deg)
    pitch, roll = ypr_from_rot(final.r_tilt)[1:]
    out = fit_vertical(lev, xy_l, road, seen, (pitch, roll), z_prior, cfg,
                       statics.rows(final.r_tilt, pose2d, road, cfg))
    return (final.z, final.z_std) if out is None else (out.z, float(np.sqrt(out.cov[2, 2])))


def lane_valley(kept: list[tuple[float, np.ndarray, str]], ref: _Refined, src: np.ndarray,
                receding: np.ndarray, models: dict[str, LaneCentres], prior_xy: np.ndarray,
                cfg: CoarseConfig) -> Valley | None:
    """The valley of the kept modes ((lane score, pose, lane model) each, best first;
    :func:`fgloc.coarse.valley.find_valley`), or None (fewer than two, or of two lane models):
    a pose on the line through the best with its yaw ties when its lane score (``src`` (N, 3)
    levelled with ``ref``'s tilt, Doppler signs ``receding`` (N,), against the lanes seen from
    it) is within ``mode_margin`` of the best's. prior_xy (2,): the approximate position in L."""
    if len(kept) < 2 or len({model for *_, model in kept}) > 1:
        return None
    lev = (src @ ref.r_tilt.T)[:, :2]
    lanes, tau, yaw = models[kept[0][2]], cfg.lane_icp_ranges[-1], kept[0][1][2]
    bar = cfg.mode_margin * kept[0][0]

    def z_at(xy: np.ndarray) -> float:      # no evidence measure: 0 when tied, else ruled out
        pose = np.array([xy[0], xy[1], yaw])
        d = _seen_from(lanes, xy, cfg).query(apply_planar(lev, pose), receding, tau)[0]
        return 0.0 if robust_score(d, tau) >= bar else np.inf

    poses = np.array([pose for _, pose, _ in kept])
    return find_valley(poses, 0, prior_xy, cfg.approx_position_sigma, cfg, z_at)


def lane_tie_covariance(kept: list[tuple[float, np.ndarray, str]], ref: _Refined,
                        src: np.ndarray, receding: np.ndarray,
                        models: dict[str, LaneCentres], cfg: CoarseConfig) -> np.ndarray:
    """3x3 covariance of the best kept mode's sensor (x, y, yaw) in L (m^2, rad^2) from the
    poses around it whose lane score ties with it: the tie as +-3 std. devs.

    The lane score has no likelihood, only the coarse stage's own test of a tie: within
    ``mode_margin`` of the best (the test that keeps distinct modes). Around the best mode
    ((lane score, pose, lane model) first in ``kept``; ``src`` (N, 3) levelled with ``ref``'s
    tilt, Doppler signs ``receding`` (N,), against its model's lanes seen from each pose) the
    tie is walked in steps of a quarter of ``mode_separation`` / ``mode_separation_deg`` along
    the weakest horizontal direction (of headings every 15 deg, the one whose poses
    ``mode_separation`` away on both sides score highest), across it, and in yaw, each out to
    ``mode_search_radius`` / ``mode_search_yaw_deg``. A tie of extent L (plus one step, the
    walk's resolution) counts as +-3 std. devs., variance ``(L + step)^2 / 36``: the peak
    locates the pose better than the margin's stretch (as a uniform distribution over it,
    variance ``/ 12``, the sparse runs' NEES was 0.3, and half of them were ambiguous at 0.3 m
    with 0.02-0.25 m errors; docs/experiments.md). Where nothing turns off a road, a single
    peak's tie along it spans metres (T-junction, 10 vehicles per minute, seed 5: 5.5 m)."""
    score0, pose0, model = kept[0]
    lev = (src @ ref.r_tilt.T)[:, :2]
    lanes, tau = models[model], cfg.lane_icp_ranges[-1]

    def score(pose: np.ndarray) -> float:
        d = _seen_from(lanes, pose[:2], cfg).query(apply_planar(lev, pose), receding, tau)[0]
        return robust_score(d, tau)

    bar = cfg.mode_margin * max(score0, score(pose0))
    sep = cfg.mode_separation
    heads = np.deg2rad(np.arange(0.0, 180.0, 15.0))
    units = np.column_stack([np.cos(heads), np.sin(heads)])
    probe = [min(score(pose0 + np.array([*(k * sep * u), 0.0])) for k in (-1.0, 1.0))
             for u in units]
    u = units[int(np.argmax(probe))]
    axes = (np.array([*u, 0.0]), np.array([-u[1], u[0], 0.0]), np.array([0.0, 0.0, 1.0]))
    steps = (0.25 * sep, 0.25 * sep, np.deg2rad(0.25 * cfg.mode_separation_deg))
    limits = (cfg.mode_search_radius, cfg.mode_search_radius,
              np.deg2rad(cfg.mode_search_yaw_deg))
    var = []
    for axis, step, limit in zip(axes, steps, limits):
        extent = 0.0
        for sign in (-1.0, 1.0):
            k = 0
            while (k + 1) * step <= limit and score(pose0 + sign * (k + 1) * step * axis) >= bar:
                k += 1
            extent += k * step
        var.append((extent + step) ** 2 / 36.0)
    B = np.array(axes)                      # rows: along, across, yaw in (x, y, yaw)
    return B.T @ np.diag(var) @ B


def lane_fit_considered(pose: np.ndarray, lev: np.ndarray, receding: np.ndarray,
                        lanes: LaneCentres, cfg: CoarseConfig) -> np.ndarray:
    """3x3 covariance of the sensor's (x, y, yaw) in L (m^2, rad^2) that the biases of
    :mod:`fgloc.registration.considered` add to a lane fit ending at ``pose`` (x, y, yaw):
    a constant shift of every lane towards the sensor (``cfg.consider_side_bias_sigma``) and
    one per lane (``cfg.consider_lane_bias_sigma``). The lane-centre ICP is, linearized at
    its end, the least-squares fit of the levelled points ``lev`` (N, 2) (Doppler signs
    ``receding`` (N,)) matched within the last ``lane_icp_ranges`` to the lanes seen from
    ``pose``, each residual taken across its lane (point to line, unit weights); zeros with
    fewer than 3 matched points or a singular fit."""
    none = np.zeros((3, 3))
    if cfg.consider_side_bias_sigma == 0.0 and cfg.consider_lane_bias_sigma == 0.0:
        return none
    seen = lanes.towards(pose[:2], side_offsets(lanes, pose[:2], cfg))
    moved = apply_planar(lev, pose)
    d, near = _seen_from(lanes, pose[:2], cfg).query(moved, receding, cfg.lane_icp_ranges[-1])
    ok = np.isfinite(d)
    if ok.sum() < 3:
        return none
    i = seen.tree.query(near[ok])[1]                # the matched samples (distance 0)
    n, arm = lanes.normal[i], moved[ok] - pose[:2]
    a = np.column_stack([n[:, 0], n[:, 1], n[:, 1] * arm[:, 0] - n[:, 0] * arm[:, 1]])
    H = a.T @ a
    if np.linalg.cond(H) > 1e12:
        return none
    columns, sd = bias_columns(side_sign(seen.xy[i], n, pose[:2]), cfg.consider_side_bias_sigma,
                               lanes.lane[i], cfg.consider_lane_bias_sigma)
    return least_squares_consider(H, a, columns, sd)


def mode_warning(modes: list[CoarseMode]) -> list[str]:
    """A warning naming the other modes' distance from the best one (none for one mode)."""
    if len(modes) < 2:
        return []
    best = modes[0]
    parts = [f"{np.hypot(*(m.pose2d[:2] - best.pose2d[:2])):.1f} m / "
             f"{np.rad2deg(abs(wrap_angle(m.pose2d[2] - best.pose2d[2]))):.1f} deg "
             f"({m.lane_score:.3f} vs {best.lane_score:.3f}{other_model_note(m.lanes, best.lanes)})"
             for m in modes[1:]]
    return [f"coarse: {len(modes)} poses fit the lanes almost as well: the best and "
            f"{'; '.join(parts)} away; the later stages compare them (give "
            "sensor.yaw_guess_deg or a better approx_position to narrow the search)"]


def _start_height(road: RoadModel, centre: np.ndarray, height: float) -> float:
    """Road height (median of the 50 road points nearest the approximate position) + height."""
    _, idx = road.planar.tree.query(centre, k=min(50, len(road.z)))
    return float(np.median(road.z[np.atleast_1d(idx)])) + height


def _search(
    sub: np.ndarray, road: RoadModel, centre: np.ndarray, yaw_guess_deg: float | None,
    cfg: CoarseConfig,
) -> tuple[list[tuple[float, np.ndarray]], np.ndarray, np.ndarray]:
    """Hypothesis search + road ICP of the best distinct ones for source points (N, 2).

    Returns the refined (score, pose) pairs best first, the searched yaws and their scores.
    A road ICP (``icp_ranges``) that ends with a lower robust score (:func:`robust_score` at
    the last range, the score the peaks are ranked by) than its peak started with is run
    again from the peak one correspondence range at a time, each stage kept only where it
    does not lower that score: at a wide range, points that lie off the road at the true
    pose (multipath ghosts behind a facade) find road to match and can pull every peak into
    one worse fit (docs/experiments.md, issue 22).
    """
    yaws = _yaw_candidates(yaw_guess_deg, cfg)
    r = cfg.position_search_radius
    offs = np.arange(-r, r + 1e-9, cfg.position_search_step)
    scores = search_grid(sub, road, centre, yaws, offs)
    peaks = distinct_peaks(
        scores, yaws, offs, cfg.search_candidates, 3.5 * np.deg2rad(cfg.yaw_search_step_deg),
        3.5 * cfg.position_search_step,
    )
    def score(pose: np.ndarray) -> float:
        return robust_score(road.distance(apply_planar(sub, pose)), cfg.icp_ranges[-1])

    refined = []
    for _, yaw, dx, dy in peaks:
        start = np.array([centre[0] + dx, centre[1] + dy, yaw])
        pose = icp_planar(sub, road.planar, start, cfg.icp_ranges, cfg.icp_iterations).pose
        if (best := score(pose)) < (start_score := score(start)):
            pose, best = start, start_score
            for rng in cfg.icp_ranges:
                moved = icp_planar(sub, road.planar, pose, [rng], cfg.icp_iterations).pose
                if (moved_score := score(moved)) >= best:
                    pose, best = moved, moved_score
        refined.append((best, pose))
    refined.sort(key=lambda item: -item[0])
    return refined, yaws, scores


@dataclass
class _Refined:
    """Refinement state: planar pose (x, y, yaw), tilt rotation, sensor height, last ICP, and
    the covariance (2, 2) of the last vertical fit's tilt about L's x and y axes (rad^2; None
    before a fit)."""

    pose2d: np.ndarray
    r_tilt: np.ndarray
    z: float
    icp: IcpOutcome
    tilt_cov: np.ndarray | None = None
    z_std: float | None = None
    n_static: int = 0


def _refine(
    src: np.ndarray, receding: np.ndarray, detections: np.ndarray, road: RoadModel,
    lanes: LaneCentres, pose2d: np.ndarray, z: float, vfov_deg: float, cfg: CoarseConfig,
    statics: StaticGround | None = None,
) -> _Refined:
    """Alternate the lane-centre planar ICP of ``src`` (N, 3) in S (receding (N,): their
    Doppler signs) and the vertical fit of the moving ``detections`` (K, 3) in S (see the
    module docstring)."""
    r_tilt = np.eye(3)
    pitch = roll = 0.0
    z_prior = z
    tilt_cov = z_std = None
    n_static = 0
    out = IcpOutcome(pose2d, False, 0)
    for _ in range(cfg.alternations):
        lev = src @ r_tilt.T
        out = icp_planar(lev[:, :2], _seen_from(lanes, pose2d[:2], cfg), pose2d,
                         cfg.lane_icp_ranges, cfg.icp_iterations, receding=receding)
        pose2d = out.pose
        lev = detections @ r_tilt.T
        xy_l = apply_planar(lev[:, :2], pose2d)
        seen = below_fov_floor(detections, r_tilt, z, road.road_height(xy_l)[0], vfov_deg)
        rows = None if statics is None else statics.rows(r_tilt, pose2d, road, cfg)
        vertical = fit_vertical(lev, xy_l, road, seen, (pitch, roll), z_prior, cfg, rows)
        if vertical is None:
            break
        w, z, cov, n_static = vertical.w, vertical.z, vertical.cov, vertical.n_static
        z_std = float(np.sqrt(cov[2, 2]))
        # (wx, wy) turn about the levelled axes, which are L's turned by the yaw
        to_l = rot_z(pose2d[2])
        tilt_cov = to_l[:2, :2] @ cov[:2, :2] @ to_l[:2, :2].T
        full = to_l @ rodrigues(np.array([w[0], w[1], 0.0])) @ r_tilt
        yaw, pitch, roll = ypr_from_rot(full)
        pose2d = np.array([pose2d[0], pose2d[1], yaw])
        r_tilt = rot_from_ypr(0.0, pitch, roll)
    return _Refined(pose2d, r_tilt, z, out, tilt_cov, z_std, n_static)


def coarse_localize(scn: Scenario, target: TargetCloud, cfg: CoarseConfig,
                    map_cfg: MapConfig | None = None) -> CoarseResult:
    """Coarse pose of the sensor (S -> L) from the accumulated dynamic detections.

    ``map_cfg`` (default :class:`MapConfig`) sets the lane models of two-way streets
    (:func:`fgloc.map.lane_models.lane_models`): with two, each is refined from the road
    search's best start and its modes are found about its own refined pose (at most
    ``max_modes`` each); those within ``mode_margin`` of the best of all are kept and the best
    is refined.

    Raises :class:`LocalizationError` for an empty target cloud or fewer than ``cfg.min_points``
    filtered dynamic points, :class:`InputError` for an approximate position outside the ALS. A
    registration that ends with a fitness below ``cfg.min_fitness`` or an ICP still moving at
    its iteration limit is returned with ``converged=False`` and an explaining message.
    """
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    if len(target) == 0:
        raise LocalizationError("the target cloud is empty: no road points to register to")
    check_inside_als(scn)
    source = dynamic_points(scn.radar, cfg)
    src, receding, det = source.xyz, source.receding, source.detections
    timings["source filter"] = time.perf_counter() - t0
    if len(src) < cfg.min_points:
        raise LocalizationError(
            f"only {len(src)} dynamic points after voxel + DBSCAN filtering ({source.n_dynamic} "
            f"detections with |doppler| >= lambda = {cfg.doppler_min} m/s, "
            f"{source.n_off_trail} of them off any trail); at least {cfg.min_points} are "
            "needed: record longer or with more traffic, or lower coarse.doppler_min"
        )

    t = time.perf_counter()
    pad = 2.0 * (cfg.position_search_radius + cfg.score_tau)
    road = RoadModel.build(target, cfg.raster_cell, pad, cfg.score_tau)
    lanelets = target.lanelets(scn.lanelets)
    map_cfg = map_cfg or MapConfig()
    models = {m: LaneCentres.of_target(target, scn.lanelets, cfg.lane_sample_step,
                                     min_width(m, map_cfg.two_way_min_width),
                                     map_cfg.centre_line)
              for m in lane_models(lanelets, map_cfg)}
    centre = approx_position_local(scn)
    height = scn.sensor.approx_height
    z0 = _start_height(road, centre, cfg.default_height if height is None else height)
    timings["target models"] = time.perf_counter() - t

    t = time.perf_counter()
    sub = src[:: max(1, len(src) // cfg.search_points), :2]
    refined, yaws, scores = _search(sub, road, centre, scn.sensor.yaw_guess_deg, cfg)
    timings["hypothesis search"] = time.perf_counter() - t

    t = time.perf_counter()
    stride = max(1, len(src) // cfg.refine_points)
    fit, fit_rec = src[::stride], receding[::stride]
    statics = StaticGround.build(scn.radar, np.asarray(scn.als.xyz, dtype=float),
                                 np.asarray(scn.als.classification), centre,
                                 scn.sensor.max_range + pad,
                                 np.vstack([lc.xy for lc in models.values()]), cfg)
    refs = {model: _refine(fit, fit_rec, det, road, lanes, refined[0][1], z0, scn.sensor.vfov_deg,
                           cfg, statics) for model, lanes in models.items()}
    kept: list[tuple[float, np.ndarray, str]] = []
    for model, lanes in models.items():
        ref = refs[model]
        if cfg.max_modes > 1:
            kept += [(score, pose, model)
                     for score, pose in lane_modes(refined, ref, fit, fit_rec, lanes, cfg)]
        else:
            score, pose = _lane_fit((fit @ ref.r_tilt.T)[:, :2], fit_rec, lanes, ref.pose2d,
                                    cfg)
            kept.append((score, pose, model))
    kept.sort(key=lambda item: -item[0])
    # a lane model is a mode like any other: within mode_margin of the best of all, or dropped
    kept = [k for k in kept if k[0] >= cfg.mode_margin * kept[0][0]]
    ref = refs[kept[0][2]]
    if _distinct(ref.pose2d, kept[:1], cfg):      # another pose fits the lanes best
        ref = _refine(fit, fit_rec, det, road, models[kept[0][2]], kept[0][1], z0,
                      scn.sensor.vfov_deg, cfg, statics)
        kept[0] = (kept[0][0], ref.pose2d, kept[0][2])
    heights = [(ref.z, ref.z_std)] + [
        _height_at(det, road, statics, ref, pose, z0, scn.sensor.vfov_deg, cfg)
        for _, pose, _ in kept[1:]]
    modes = coarse_modes(kept, ref, heights)
    valley = lane_valley(kept, ref, fit, fit_rec, models, centre, cfg)
    tie = lane_tie_covariance(kept, ref, fit, fit_rec, models, cfg) + lane_fit_considered(
        kept[0][1], (fit @ ref.r_tilt.T)[:, :2], fit_rec, models[kept[0][2]], cfg)
    warnings = mode_warning(modes)
    if (outside := outside_search(ref.pose2d, centre, scn.sensor.yaw_guess_deg, cfg)):
        warnings.append(f"coarse: the pose ended far outside the searched region, {outside}: "
                        "either sensor.toml's guess is wrong (the lanes of a junction can turn "
                        "the fit back to the truth) or the fit settled on other road (little "
                        "of the road in view, a map without the road the vehicles drive): "
                        "check the guess and the overview")
    timings["refinement"] = time.perf_counter() - t

    T = se3(rot_z(ref.pose2d[2]) @ ref.r_tilt, [ref.pose2d[0], ref.pose2d[1], ref.z])
    d = road.distance(apply_planar((src @ ref.r_tilt.T)[:, :2], ref.pose2d), cfg.icp_ranges[-1])
    inl = np.isfinite(d)
    fitness = float(inl.mean())
    rmse = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else float("nan")
    problems = []
    if fitness < cfg.min_fitness:
        problems.append(f"fitness {fitness:.2f} below coarse.min_fitness = {cfg.min_fitness}")
    if not ref.icp.converged:
        problems.append(f"lane-centre ICP still moving after {cfg.icp_iterations} iterations")
    yaw_search = None
    if scn.sensor.yaw_guess_deg is None:
        per_yaw = scores.max(axis=(1, 2))
        yaw_search = [(float(np.rad2deg(y)), float(s)) for y, s in zip(yaws, per_yaw)]
    timings["total"] = time.perf_counter() - t0
    return CoarseResult(
        T_coarse=T,
        pose=pose_from_se3(T),
        fitness=fitness,
        inlier_rmse=rmse,
        n_points_dynamic=source.n_dynamic,
        n_points_used=int(len(src)),
        n_points_off_trail=source.n_off_trail,
        converged=not problems,
        message="; ".join(problems) if problems else "converged",
        yaw_search=yaw_search,
        timings=timings,
        warnings=warnings,
        source_xyz=src,
        tilt_covariance=ref.tilt_cov,
        modes=modes,
        z_std=ref.z_std,
        n_static_ground=ref.n_static,
        valley=valley,
        tie_covariance=tie,
    )


def target_and_coarse(scn: Scenario, cfg: Config, timer: Timer) -> tuple[TargetCloud, CoarseResult]:
    """The first two stages every method shares: the labelled target cloud, then the coarse
    pose; their wall times go to ``timer`` as "target cloud" and "coarse ICP"."""
    with timer.stage("target cloud"):
        target = build_target_cloud(scn, cfg.map)
    with timer.stage("coarse ICP"):
        coarse = coarse_localize(scn, target, cfg.coarse, cfg.map)
    return target, coarse
