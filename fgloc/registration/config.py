"""Configuration of the fine registration (``[sicp]`` in the fgloc config TOML)."""

from __future__ import annotations

from dataclasses import dataclass, field

#: Correspondence modes of :func:`fgloc.registration.sicp.sicp`.
MODES: tuple[str, ...] = ("hard", "soft", "none")
#: Robust kernels of the iteratively reweighted alignment.
KERNELS: tuple[str, ...] = ("none", "huber", "cauchy")


def _default_compatibility() -> list[list[float]]:
    return [[1.0, 0.1, 0.1], [0.1, 1.0, 0.1], [0.1, 0.1, 1.0]]


@dataclass
class SicpConfig:
    """Semantic ICP in SE(2) (paper III-C, IV-B). Distances in metres."""

    mode: str = "hard"
    """Correspondences: "hard" = each source point matched only to target points of its own
    label; "soft" = matched in all labels by the cost d^2 / compatibility[source][target] and
    weighted by that compatibility; "none" = plain ICP (labels ignored)."""
    compatibility: list[list[float]] = field(default_factory=_default_compatibility)
    """3x3 label compatibility of the "soft" mode, rows = source label, columns = target label
    in the order straight, left, right; values in [0, 1], 0 forbids the pair."""
    max_correspondence: float = 50.0
    """Maximum correspondence distance (m) of the first iteration (paper: 50 m)."""
    min_correspondence: float = 1.5
    """Floor (m) of the shrinking maximum correspondence distance; the final range, which also
    defines fitness and inlier RMSE."""
    range_decay: float = 0.8
    """The maximum correspondence distance is multiplied by this after every iteration until it
    reaches min_correspondence (1.0 keeps max_correspondence throughout)."""
    max_iterations: int = 100
    """Iteration limit (paper: 100); stopping on it is reported as not converged."""
    rmse_tol: float = 1e-4
    """Converged when, at the range floor, the inlier RMSE changes by less than this (m)
    between two iterations (paper: 1e-4) and the last alignment moved the pose by less than
    ``step_tol`` / ``step_tol_deg``."""
    step_tol: float = 0.002
    """... moved the matched points' centroid by less than this (m; 0 = the RMSE test alone, the
    paper's). Along a weakly observed direction (a straight road; a T-junction's main road
    with few turning vehicles) ICP creeps: the RMSE changes by the square of a small step and
    the RMSE test alone stopped 0.2-0.3 m short of where the iterations go (T-junction, 5
    vehicles per minute, seed 5: 0.61 m from the truth; 0.39 m with this test, 0.35 m with
    ``accelerate`` too)."""
    step_tol_deg: float = 0.002
    """... and turned it by less than this (deg; 0 = the RMSE test alone)."""
    accelerate: bool = True
    """At the range floor, when two consecutive alignments point the same way and shrink,
    jump to where their geometric series ends (accelerated ICP, Besl & McKay 1992; at most 25
    steps): ICP creeps along a weakly observed direction by a nearly constant fraction per
    iteration. The jump is taken only where it lowers the trimmed matching cost (the sum of
    ``min(d^2 / c, r^2)`` over the points at the floor range ``r``): where the steps shrink
    slowly for another reason (matches changing lanes) the series overshoots (the independent
    generator's junction 12 seed 1: a start 0.4 m from the fit jumped 2.4 m, then 8 m, and
    ended 3 m away). False: plain iterations (the paper's)."""
    kernel: str = "none"
    """Robust kernel of the iteratively reweighted alignment: "none", "huber" or "cauchy"."""
    kernel_scale: float = 1.0
    """Scale (m) of the robust kernel: Huber weight min(1, c/d), Cauchy 1 / (1 + (d/c)^2)."""
    min_points_per_label: int = 10
    """A label with source points but fewer than this many source or target points is dropped
    with a warning (its points take no part)."""
    sigma_floor: float = 0.05
    """Lower bound (m) of the residual standard deviation used for the information matrix."""
    offset_sigma_floor: float = 0.1
    """Lower bound (m) of the standard deviation of a track's common offset from its lane in
    the track covariance (:func:`fgloc.registration.sicp.track_covariance`; the joint's
    ``min_sigma`` likewise): with a handful of tracks the offsets' spread is no estimate."""
    consider_side_bias_sigma: float = 0.1
    """Standard deviation (m) of a constant shift of every matched point towards the sensor
    (the visible-side offset's or the tracker's error, shared by all vehicles) that the track
    covariance *considers* (adds the pose's sensitivity to it, Schmidt; not estimated): where
    every lane passes on one side of the sensor it moves the pose across the road. The
    joint's ``consider_side_bias_sigma`` likewise. 0 = off."""
    consider_lane_bias_sigma: float = 0.1
    """Standard deviation (m) of a lateral shift shared by the matched points of one lane
    (a centre line drawn off in the map, the drivers of one lane keeping to one side of it),
    one per lane, independent, considered in the track covariance like
    ``consider_side_bias_sigma``: the vehicles of one lane share it, so their number does not
    shrink it. The joint's ``consider_lane_bias_sigma`` likewise. 0 = off."""
    direction_gate_deg: float = 90.0
    """When the source points and the target carry driving directions (filter-sicp: the tracks'
    headings and the lanes' directions), a source point is matched only to target points whose
    direction lies within this angle (deg) of its own: never to the lane of the other direction
    (on a two-way street mapped as one lanelet the two lanes lie 3 m apart). 180 = directions
    ignored."""
    info_window: float = 8.0
    """Half-width (m) of the square target neighbourhood whose spread shapes each
    correspondence's weight matrix in the information (so sliding along a road shows as weak);
    0 = isotropic (plain point-to-point information)."""

    def __post_init__(self) -> None:
        for name in ("consider_side_bias_sigma", "consider_lane_bias_sigma"):
            if getattr(self, name) < 0.0:
                raise ValueError(f"{name} must be >= 0 (m), got {getattr(self, name)}")


#: What the source cloud of filter-sicp is made of (see :mod:`fgloc.registration.source`).
SOURCE_KINDS: tuple[str, ...] = ("detections", "centres", "contours")
#: What the source cloud of filter-sicp is registered to (see :mod:`fgloc.registration.fine`).
TARGET_KINDS: tuple[str, ...] = ("road-points", "lane-centres", "visible-sides")
#: How far the "visible-sides" target lies from the centre lines (see :class:`FineConfig`).
VISIBLE_SIDE_MODELS: tuple[str, ...] = ("aspect", "constant")


@dataclass
class FineConfig:
    """Fine stage of ``--method filter-sicp`` (``[fine]``): the labelled source cloud built from
    the tracks (paper III-C), the labelled target it is registered to, and the start of the SICP
    schedule. Distances in metres.

    The other paper parameters of this stage live where the stage that uses them is configured:
    lambda (doppler threshold, 0.5 m/s) is ``coarse.doppler_min`` and ``tracking.doppler_min``;
    eta (kappa = yawrate / v threshold of the source labels, 0.01 rad/m) is ``tracking.eta``;
    gamma (Menger-curvature threshold of the target labels, 0.01 1/m) is ``map.gamma``; the SICP
    schedule and stop rule (50 m, 100 iterations, dRMSE < 1e-4 m) are ``[sicp]``, except that
    ``start_range`` below overrides ``sicp.max_correspondence`` for this method.
    """

    source: str = "detections"
    """Source points: "detections" = the radar detections each track used, placed in C with
    T_coarse, labelled by their track's state (the paper); "centres" = the tracked vehicle
    centres (GP-EOT state x, y), which follow the lane centres; "contours" = the 20 contour
    points of every tracked state."""
    target: str = "visible-sides"
    """Target points: "road-points" = the labelled ALS road points of the target cloud (the
    paper); "lane-centres" = the centre lines of the target cloud's lanelets, sampled every
    ``lane_sample_step`` m, each sample labelled with its lanelet's label; "visible-sides" =
    those centre lines shifted ``coarse.visible_side_offset`` m towards the sensor (where the
    radar sees a vehicle's side on average; the target for "detections")."""
    visible_side: str = "aspect"
    """How far the "visible-sides" target is shifted towards the sensor, for the source
    "detections": "constant" = ``coarse.visible_side_offset`` everywhere, source voxels
    weighted equally; "aspect" (the default) = per aspect (|sin| of the angle between the line
    of sight and the lane), the mean offset of the tracks' detections from their tracks'
    centre lines at that aspect, measured on this run's tracks
    (:mod:`fgloc.registration.visible_side`), the detections moved along their tracks'
    headings onto the cross-sections through the tracked centres and the source voxels
    weighted by the detections they average, each aspect's offset clipped to [0,
    ``tracking.mean_width`` / 2]. On the real map's junctions (bench.real_map, routing labels,
    18 runs) "aspect" halves filter-sicp's error (0.282 -> 0.132 m mean, yaw 0.18 -> 0.06
    deg), on the synthetic layouts it lowers it from 0.145 to 0.105 m and in sparse traffic
    from 0.139 to 0.097 m (docs/experiments.md, issue 22)."""
    model_spread: float = 0.5
    """With ``visible_side = "aspect"``: each mode is also registered with the constant
    offset (the other model of where the returns lie), and ``model_spread`` times the outer
    product of the difference of the two fits' sensor (x, y, yaw) is added to the mode's
    covariance: a pose the two models disagree on is not reported as pinned (equal weight on
    both models, the estimate at the "aspect" fit: 0.5). 0 = no second fit. On a sparse
    T-junction (10 vehicles per minute, seed 5) "aspect" alone ended 0.45 m off with a
    largest std. dev. of 0.300 m (resolved); the constant fit lay 0.74 m from it."""
    slip_tracks: int = 2
    """When > 0, the fine stage also registers from the best fit turned about the sensor by
    the angle that moves each of this many farthest tracks (with a same-direction lane beside
    theirs) one lane spacing across, both ways (:mod:`fgloc.registration.slip`), and compares
    those fits as modes: a pose that slipped its far vehicles one lane over (about a degree
    at 150 m) meets the pose that did not. Turns beyond ``coarse.mode_search_yaw_deg`` are
    left out. 0 = none (the default until every table was rerun with 2; docs/experiments.md,
    issue 22)."""
    merge_deg: float = 0.5
    """The fine stage's fits merge into a better one within ``coarse.mode_separation`` m and
    this yaw (deg); 0 = ``coarse.mode_separation_deg`` (1 deg, the coarse stage's). A lane
    slip at 140 m ends 0.9 deg from the pose without it (independent generator, junction 12
    seed 2): at 1 deg the slip starts' fits would merge back into the slipped one."""
    lane_sample_step: float = 0.25
    """Spacing (m) of the samples on the lanelet centre lines (target "lane-centres")."""
    centre_weight_sigma: float = 0.25
    """Targets "lane-centres" and "visible-sides": a lane sample where the lanelet's centre
    line is ambiguous by ``a`` m (half the distance between its two constructions, ``[map]
    centre_line``; up to 1 m on hand-mapped turns; with the bend of a lane bent into a two-way
    street's half in quadrature, :func:`fgloc.scenario.lane_ambiguity`) weighs
    ``s^2 / (s^2 + a^2)`` in the alignment, ``s`` this value (m); 0 = every sample weighs 1.
    Where the map does not say where vehicles drive, their tracks pull less (as the joint's
    ``centre_ambiguity``). It counts whichever ``centre_line`` is matched; when the vehicles
    are known to drive one construction (a generator on lanelet2's lines), set 0 with that
    ``centre_line``."""
    n_trajectories: int | None = None
    """Use at most this many trajectories (tracks), chosen at random with ``Config.seed`` (the
    paper uses 20 of 80 and 50 of 146); None = all."""
    trajectory_share: float = 1.0
    """Use this share (0, 1] of the trajectories, chosen at random with ``Config.seed``; with
    n_trajectories both limits apply."""
    voxel_size: float | None = 1.0
    """Edge (m) of the per-label voxel grid the source points are averaged on; None (Python
    API only) = ``map.voxel_size``, the paper's choice of the target's voxel size. 1 m is the
    default because it registered better than 0.5 m in both variant grids
    (bench/fine_variants.py: mean 2D 0.136 m against 0.176 m over 10 runs)."""
    start_range: float = 5.0
    """First maximum correspondence distance (m) of SICP for this method, overriding
    ``sicp.max_correspondence`` (50 m in the paper, meant for a start far from the solution);
    0 = use ``sicp.max_correspondence``. The coarse pose is within about a metre, and a wide
    first range lets far, wrong correspondences bias the result (docs/experiments.md)."""
