"""Configuration of ``--method joint`` (``[joint]`` in the fgloc config TOML)."""

from __future__ import annotations

from dataclasses import dataclass

from fgloc.smoothing.config import SMOOTHERS

#: Where the joint optimization starts the sensor pose.
STARTS: tuple[str, ...] = ("sicp", "coarse")
#: Where a contour point should lie beside its target line (:mod:`fgloc.registration.joint`).
LATERAL_MODELS: tuple[str, ...] = ("contour", "visible-side")
#: Nonlinear optimizers of one round.
OPTIMIZERS: tuple[str, ...] = ("gauss-newton", "levenberg-marquardt")
#: How the pose covariance is computed (:mod:`fgloc.registration.joint`).
COVARIANCES: tuple[str, ...] = ("track-robust", "model")


@dataclass
class JointConfig:
    """Joint refinement: one SE(2) sensor-pose correction shared by semantic point-to-point
    factors, optimized together with every track state (:mod:`fgloc.registration.joint`).
    Distances in metres, angles in degrees. The track factors (process, contour measurement,
    prior) are the smoother's (``[smoothing]``, ``[tracking]``) but for ``extent_rows``; the
    target lines are ``[fine]``'s lanelet centre lines shifted by
    ``coarse.visible_side_offset``; the trajectory subset is ``fine.n_trajectories`` /
    ``fine.trajectory_share``."""

    start: str = "sicp"
    """Initial pose: "sicp" = filter-sicp's result, "coarse" = the coarse pose."""
    smoother: str = "none"
    """The tracks the joint starts from and linearizes its track factors at: "none" = the
    filter's; "batch" / "fixed-lag" = the filter's smoothed first by that smoother
    (``[smoothing]``'s other settings; the filter-sicp start stays on the filter's tracks).
    The batch smoother halves the lateral error of a track's first seconds; the joint came
    out closer from its tracks on the default simulated intersections and T-junctions (seeds
    1-5) but not under changed simulator settings, at ~4 CPU s per track-minute more
    (docs/experiments.md, joint section)."""
    lateral_model: str = "contour"
    """Target of a contour point: "contour" = the lane centre line moved sideways by the
    point's lateral place in its vehicle (r sin theta: a vehicle drives centred in its lane);
    "visible-side" = the lane centre lines shifted ``coarse.visible_side_offset`` towards the
    sensor (filter-sicp's target), the same for every point."""
    extent_rows: bool = False
    """Extent rows (the measured ends of a vehicle, docs/method.md 5.4) in the joint's track
    factors; the other track-factor settings are ``[smoothing]``'s. Off by default: on the
    simulated intersections and T-junctions (seeds 1-5) the joint came out closer without
    them (docs/experiments.md, joint section)."""
    relinearize_tracks: bool = False
    """Relinearize the track factors (process, contour measurement) at every round; False =
    linearize them once at the filter's states (they are nearly linear there; the rounds then
    call Python only for the point factors)."""
    step_stride: int = 4
    """Every this many steps of a track enter the graph (with their detections; the process
    factors span the gap): 4 = 5 Hz states from a 20 Hz radar. The refined tracks are output
    at that rate."""
    min_track_steps: int = 5
    """Tracks with fewer steps (after the stride) are left out."""
    max_points_per_frame: int = 8
    """At most this many detections (a regular subsample) of one track in one frame become
    points of its point-to-point factor."""
    max_correspondence: float = 3.0
    """A contour point farther than this (m) from every compatible target point gets no
    correspondence in that round."""
    heading_weight: float = 4.0
    """Correspondences are searched in (x, y, w cos psi, w sin psi) with this w (m): a line
    whose direction differs from the vehicle's heading by 30 deg looks about 2 m farther
    away, so vehicles match the lane they drive along, not a crossing one."""
    label_weight_other: float = 0.1
    """Compatibility of a point with a target of another label (same label: 1); the match is
    the least d^2 / compatibility and the point is weighted by it. 0 = labels must agree."""
    sigma_line: float = 0.3
    """Without ``estimate_noise``: standard deviation (m) of one frame's mean across its target
    line (a frame's points share it) and of the point scatter (Huber scale); frames are then
    treated as independent."""
    along_weight: float = 0.0
    """Weight of the along-line component relative to the across-line one (0 = point to
    line: the position along a lane carries no information)."""
    huber_k: float = 2.0
    """Huber threshold (in sigma_line) of the per-point robust weights; 0 = none."""
    join_smoothing_length: float = 1.5
    """Steering length (m) of the target lines through lanelet joins: each lane line chained
    with the lanes before and after it (the routing graph's, or where the map has none for
    it, the best-aligned lane whose end meets it) and smoothed by a spline that penalizes the
    change of its curvature, so a kink of hand-mapped lanelets is spread over a few times
    this length the way a vehicle, which cannot turn its heading at a point, drives it
    (:mod:`fgloc.map.lane_joins`; about a vehicle's speed times its steering time constant:
    1.5 m = 0.15 s at 10 m/s; a kink of angle theta ends about 0.3 theta length m off its
    vertex). 0 = the lanelets' centre lines as mapped. 1.5 (of 1.5 / 2 / 3) came out best on
    the real map's junctions under paths made three ways and changes nothing on the
    synthetic layouts (docs/experiments.md, issue 22)."""
    centre_ambiguity: float = 1.0
    """Scale of the centre-line ambiguity in the point noise: a point matched where its
    lanelet's two centre-line constructions lie ``2 a`` m apart (``[map] centre_line``,
    :meth:`fgloc.scenario.Lanelet.centre`) has its frame noise ``frame`` grown to
    ``sqrt(frame^2 + (centre_ambiguity a)^2)``, so hand-mapped turns whose centre is not
    known weigh less (a lane bent into a two-way street's half adds its bend to ``a`` in
    quadrature, :func:`fgloc.scenario.lane_ambiguity`); 0 = off. Changes nothing where the
    constructions agree and no lane bends (the simulated layouts)."""
    centre_line_sigma: float = 0.5
    """Prior standard deviation of the centre-line share: one parameter, shared by every
    point, that moves each target by that share of the offset from the arc-length centre
    line of its lanelet to lanelet2's (``[map] centre_line``,
    :meth:`fgloc.scenario.Lanelet.centre`): where between the two constructions the vehicles
    drive, estimated from the data (0 = the "mean" line, -0.5 = the arc-length one, +0.5 =
    lanelet2's); 0 = off. Moves nothing where the constructions agree (the simulated
    layouts)."""
    offset_sigma: float = 0.3
    """Prior standard deviation (m) of each track's lateral offset from its target lines
    (shared by all of its points: models their correlation) without ``estimate_noise``;
    0 = no offset variables."""
    side_bias_sigma: float = 0.0
    """Prior standard deviation (m) of a common side bias: one offset, shared by every
    vehicle, of the contour points towards the sensor (a tracker that fills a vehicle's
    unseen far side with the mean width places every centre, and so the matched lateral
    places, a little towards the sensor; unmodelled, that bias is read as a pose shift).
    0 = no side-bias variable."""
    consider_side_bias_sigma: float = 0.1
    """Standard deviation (m) of a constant side bias that is not estimated but *considered*
    in the covariance (Schmidt: the pose's sensitivity to it, times this, is added; only
    without ``side_bias_sigma``): the tracker's centres lie across their lanes by a bias it
    shares among vehicles (measured -0.1 m near, +0.2 m far on T-junction 3), which a
    T-junction, all lanes on one side of the sensor, cannot tell from the sensor's position
    across the road. 0 = off."""
    consider_lane_bias_sigma: float = 0.1
    """Standard deviation (m) of a lateral bias shared by the vehicles of one lanelet,
    considered per lanelet (independent between lanelets; Schmidt, like
    ``consider_side_bias_sigma``): a lane centre line drawn off in the map, drivers keeping
    to one side of that lane, the tracker's bias at that lane's range and aspect. The
    per-track offsets cannot carry it (every vehicle of the lane shares it), so without it the
    covariance trusts one lane as much as its number of vehicles says. 0 = off."""
    lane_bias_sigma: float = 0.0
    """Prior standard deviation (m) of one lateral bias per lane, *estimated* (a global
    parameter per lane line that holds matched points, :mod:`fgloc.registration.lane_bias`)
    instead of considered: the estimate becomes the generalized least-squares one under
    that model, a lane weighing at most about one line measurement of this std. dev.
    however many vehicles it carries; of ``consider_lane_bias_sigma`` only what it exceeds
    this by is considered on top (the marginal covariance holds the biases). Needs the
    lines' lane ids. 0 = off."""
    consider_coarse_tilt: bool = True
    """Add the coarse roll and pitch's uncertainty (``CoarseResult.tilt_covariance``) to the
    sensor's covariance: the joint keeps the coarse tilt, and a tilt error moves the sensor,
    several metres above the vehicles the registration aligns, sideways
    (:func:`fgloc.registration.fine.coarse_tilt_covariance`). Where one road leaves the roll
    about it to the prior (T-junction 5: 2.3 deg off, 0.2 m across the road) this is the
    largest error term. False = leave it out."""
    range_bias_sigma: float = 0.1
    """Prior standard deviation (m per 100 m of range) of a range-proportional side bias: an
    offset of every contour point towards the sensor that grows with its distance from the
    sensor (the tracker's centre of a far vehicle, seen through a widening azimuth scatter,
    lies off its lane). Its sign and size depend on the site: measured against the truth,
    +0.08 m per 100 m on the simulated intersections and T-junctions, -0.05 to -0.07 on the
    real map's junctions 1 and 2. Where one road runs nearly radially from the sensor and a
    far road crosses it, the bias moves the far road's vehicles along the radial one, as a
    translation would: there the prior decides, and 0.2 let a spurious bias carry the pose
    0.2 m along the road (docs/experiments.md, issue 22). 0 = none."""
    estimate_noise: bool = True
    """Estimate the noise levels from the data (``fgloc.registration.joint.NoiseLevels``:
    point scatter, frame scatter, the correlation of consecutive frames, the tracks' offset
    scatter) at the start pose and again whenever the pose settles, until they settle too;
    False = ``sigma_line`` and ``offset_sigma`` as given."""
    min_sigma: float = 0.1
    """Floor (m) of the estimated noise levels."""
    refine_tracks: bool = True
    """Optimize the track states with the pose (False: states held at the filter's)."""
    pose_prior_sigma: float = 20.0
    """Standard deviation (m) of the prior on the pose translation at the coarse pose: keeps
    directions no factor observes (along a straight road) finite and flagged. Along such a
    direction the coarse pose is itself unobserved (15 m off on the simulated straight road,
    seed 1), so the prior must be about as wide as the coarse position search."""
    pose_prior_sigma_yaw_deg: float = 2.0
    """Standard deviation (deg) of that prior's yaw."""
    max_rounds: int = 16
    """At most this many re-association + optimization rounds. The pose converges like ICP,
    linearly (each round's step ~0.5-0.7 of the previous one), and a noise re-estimation can
    restart it: with 8, 7 of 30 runs on varied simulator settings (radar noise x2, spread
    reflections, clutter, traffic; docs/experiments.md) stopped 1-20 mm short of settled."""
    optimizer: str = "levenberg-marquardt"
    """Optimizer of a round: "levenberg-marquardt" (damped) or "gauss-newton" (one
    linearization and one error evaluation per iteration, but undamped: on simulated
    intersections it stopped on an indeterminate system -- weakly observed speed /
    acceleration of short tracks -- so it is not the default)."""
    iterations: int = 4
    """Optimizer iterations per round."""
    tol_position: float = 0.002
    """Stop when a round moves the pose by less than this (m) ..."""
    tol_yaw_deg: float = 0.002
    """... and turns it by less than this (deg)."""
    covariance: str = "track-robust"
    """Pose covariance: "model" = the inverse of the pose's reduced information (the factors'
    noise model taken as true); "track-robust" = the cluster-robust sandwich over tracks
    (:func:`fgloc.registration.sicp.track_robust_covariance`), never below the model
    one: errors a whole track shares (its shape, its driver's line) and that the noise model
    misses widen it by as much as the tracks disagree."""
    weak_sigma: float = 0.3
    """A direction of the pose (metric coordinates: translation of the matched points'
    centroid, rotation as arc length at their RMS radius) whose standard deviation exceeds
    this (m) is reported as weakly observed."""
    resolved_max_std: float = 1.0
    """One mode left is ``ambiguous`` when the reported covariance's std. dev. (m) along its
    least determined horizontal direction exceeds this (the other methods' tolerance,
    ``coarse.resolved_max_std`` = 0.3 m, is too tight for the joint's covariance, which adds
    considered biases no data shrink: on the sparse-traffic bench its largest was 0.38 m at
    0.14 m error; three vehicles in a minute on a 60 m junction of a real map leave 3.8 m)."""


def check_joint_config(cfg: JointConfig) -> None:
    """Raise ValueError naming the first invalid JointConfig field."""
    problems = {
        "start": cfg.start not in STARTS,
        "smoother": cfg.smoother not in SMOOTHERS,
        "lateral_model": cfg.lateral_model not in LATERAL_MODELS,
        "step_stride": cfg.step_stride < 1,
        "min_track_steps": cfg.min_track_steps < 2,
        "max_points_per_frame": cfg.max_points_per_frame < 1,
        "max_correspondence": not cfg.max_correspondence > 0.0,
        "heading_weight": cfg.heading_weight < 0.0,
        "label_weight_other": not 0.0 <= cfg.label_weight_other <= 1.0,
        "sigma_line": not cfg.sigma_line > 0.0,
        "along_weight": not 0.0 <= cfg.along_weight <= 1.0,
        "huber_k": cfg.huber_k < 0.0,
        "offset_sigma": cfg.offset_sigma < 0.0,
        "join_smoothing_length": cfg.join_smoothing_length < 0.0,
        "centre_ambiguity": cfg.centre_ambiguity < 0.0,
        "centre_line_sigma": cfg.centre_line_sigma < 0.0,
        "side_bias_sigma": cfg.side_bias_sigma < 0.0,
        "range_bias_sigma": cfg.range_bias_sigma < 0.0,
        "consider_side_bias_sigma": cfg.consider_side_bias_sigma < 0.0,
        "consider_lane_bias_sigma": cfg.consider_lane_bias_sigma < 0.0,
        "lane_bias_sigma": cfg.lane_bias_sigma < 0.0,
        "min_sigma": not cfg.min_sigma > 0.0,
        "pose_prior_sigma": not cfg.pose_prior_sigma > 0.0,
        "pose_prior_sigma_yaw_deg": not cfg.pose_prior_sigma_yaw_deg > 0.0,
        "max_rounds": cfg.max_rounds < 1,
        "optimizer": cfg.optimizer not in OPTIMIZERS,
        "iterations": cfg.iterations < 1,
        "tol_position": cfg.tol_position < 0.0,
        "tol_yaw_deg": cfg.tol_yaw_deg < 0.0,
        "covariance": cfg.covariance not in COVARIANCES,
        "weak_sigma": not cfg.weak_sigma > 0.0,
        "resolved_max_std": not cfg.resolved_max_std > 0.0,
    }
    bad = [k for k, v in problems.items() if v]
    if bad:
        raise ValueError(f"invalid joint config field {bad[0]}: {getattr(cfg, bad[0])!r}")
