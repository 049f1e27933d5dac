"""Configuration of the GP-EOT tracker (``[tracking]`` in the fgloc config TOML)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class TrackingConfig:
    """GP-EOT tracker settings (paper III-B, IV-B). Lengths in m, times in s, angles in deg
    unless named ``*_rad``; all in the tracking frame C."""

    eta: float = 0.01
    """Curvature threshold (rad/m) for the left/right/straight state labels."""
    label_min_speed: float = 1.0
    """Below this speed (m/s) kappa = yawrate / v is unreliable and the state is 'straight'."""

    # ---- detections and clustering -----------------------------------------------------------
    doppler_min: float = 0.5
    """lambda: detections with |doppler| (m/s) below this are static and ignored."""
    cluster_eps: float = 1.5
    """Single-linkage radius (m) for clustering unassociated detections into birth candidates."""
    cluster_min_points: int = 3
    """A birth candidate cluster needs at least this many detections."""

    # ---- measurement model -------------------------------------------------------------------
    measurement_model: str = "sensor-aware"
    """'sensor-aware' (normal offsets to the visible contour + visible extent) or 'plain'
    (2D point at the angle from the centre)."""
    n_candidates: int = 48
    """Dense contour samples for the sensor-aware visible chain."""
    max_detections_per_update: int = 24
    """At most this many detections (a regular subsample) enter one UKF update; all associated
    detections are still recorded in the track."""
    sigma_range: float = 0.25
    """Radar range noise (m) in the position measurement covariance."""
    sigma_azimuth_deg: float = 0.5
    """Radar azimuth noise (deg) in the position measurement covariance."""
    sigma_contour: float = 0.3
    """Scatter (m) of the detections about the modelled contour (model error), isotropic."""
    use_extent: bool = True
    """Sensor-aware model: the extreme detections along a face that is seen measure where the
    contour ends (visible-extent rows: the length from a seen side, the width from a seen
    front/rear), so the contour cannot grow beyond the detections unchecked."""
    sigma_extent: float = 0.35
    """Std. dev. (m) of an extent row (gap between the extreme detection and the face's end)."""
    extent_min_points: int = 4
    """An extent row needs at least this many detections in the update."""
    grow_margin: float = 1.0
    """An extent row's detection more than this (m) beyond the contour's end inflates the
    track's length (width) and centre covariance by the excess (the vehicle is larger than
    its contour so far: a truck coming into view)."""
    extent_edge_margin: float = 2.0
    """An extreme detection closer than this (m) to the FOV's edge or the blind range gives no
    extent row (the view of the face may be cut there)."""
    extent_min_cover: float = 0.5
    """... and only if its detections span at least this share of the contour's extent along
    the face (else the face is partly occluded or cut by the FOV: its extremes are not ends)."""
    extent_gap_correction: bool = True
    """The extreme detection along an axis lies inside the vehicle's end by about one sampling
    gap: with n detections spanning s (m) along that axis, the end is measured at the extreme
    plus s / (n - 1) (the unbiased end estimate of uniform samples; negligible with dense
    returns, ~1 m per end with 4-8 returns on a car far out), at most ``extent_gap_max``; the
    growth test (``grow_margin``) uses the extreme detection itself."""
    extent_gap_max: float = 0.6
    """Cap (m) of that sampling-gap correction."""
    extent_width_gap: bool = True
    """The same across the heading, at a side that is not seen: its extreme detection is one of
    the n_f detections on the seen front or rear (within 0.5 m of it), so the side is measured
    ``width / (n_f + 1)`` beyond it (the expected gap of uniform samples with the contour's
    width; not their span, mostly azimuth noise far out), at most ``extent_gap_max``. Without
    it sparse returns leave cars 0.17 m narrow with their centres 0.1-0.2 m towards the seen
    side (issue 20); the seen side's own row takes no gap (its detections lie along it)."""
    chain_fov_margin: float = 1.0
    """Contour points up to this far (m) outside the field of view still belong to the visible
    chain the detections are matched to (a detection is inside it, the track's contour may
    be a little off: a car driving along the FOV's edge had its seen side just outside, and
    its side returns went to the front face 1.5-3 m away, turning the yaw 10 deg in one
    update)."""
    interior_sigmas: float = 0.0
    """A detection that lies inside the contour deeper than the track's median detection by more
    than this many std. devs. of its position noise along the contour's normal there
    (``sigma_range``, ``sigma_azimuth_deg``, ``sigma_contour``) gains the square of that depth
    (m^2) as variance of its row (:func:`factors.measurement.interior_variance`; the filter
    only, not the smoothers; 0 = off, the default). A sensor on a mast sees the roofs, and a
    roof return lies inside the outline; as an outline row it pulls the seen face inwards and
    the contour grows on the unseen side (on the independent generator, a tenth of the returns
    on the roofs, cars seen end-on were tracked 0.35-0.41 m too far from the sensor). Relative
    to the median: a contour too large for all its detections still shrinks. At 1 the filter's
    tracks are better on the independent generator (38 runs, true pose: centre RMS static 0.520
    -> 0.453 m, occluded 0.653 -> 0.511 m, held-out 0.613 -> 0.524 m, fgloc's roof-returns
    setting 0.434 -> 0.280 m) but the poses are not (36 runs: joint occluded 0.091 -> 0.108 m, 8
    runs worse, 2 better; filter-sicp static 0.124 -> 0.146 m): off by default, for `fgloc
    track` users who want the tracks (docs/experiments.md)."""
    visible_slack: float = 1.0
    """A detection is matched to the part of the contour visible from the sensor (facing
    it, not self-occluded) unless that part is farther from it than the rest of the contour
    by more than this (m) and three std. devs. of its position noise (``sigma_range``,
    ``sigma_azimuth_deg``: :func:`factors.measurement.visibility_slack`): then to its
    closest point on the whole contour (inf = never). The visible part follows from the
    track's pose; a contour whose heading lags a turning vehicle seen head-on hides the side
    that comes into view, and that side's returns, metres behind the front face, pulled the
    front round (the heading a further 7 deg off in one update, the track lost). The
    smoothers alike, with their own radar noise (none with ``smoothing.radar_noise`` off:
    then the slack is this floor alone)."""
    extent_min_incidence: float = 0.25
    """A face gives extent rows only if sin(angle between the line of sight and the face) is at
    least this (a face seen at grazing incidence holds too few detections to reach its ends)."""
    use_doppler: bool = True
    """Use each detection's range rate as a measurement of the rigid-body point velocity."""
    sigma_doppler: float = 1.0
    """Doppler measurement noise (m/s), including model error."""

    # ---- GP contour --------------------------------------------------------------------------
    gp_sf: float = 0.15
    """sigma_f (m): prior std. dev. of the contour radius about the mean shape."""
    gp_length_rad: float = 0.35
    """l (rad): periodic-kernel length scale (sin^2 divided by l^2 once)."""
    gp_sr: float = 0.1
    """sigma_r (m): prior std. dev. of a common radius offset (inside k, see factors.gp)."""
    gp_symmetry: float = 0.8
    """Weight in [0, 1] of the mirror-symmetric kernel part (0 = paper's kernel)."""
    gp_sl: float = 1.5
    """Std. dev. (m) of the vehicle length about mean_length (size mode of the kernel)."""
    gp_sw: float = 0.2
    """Std. dev. (m) of the vehicle width about mean_width (size mode of the kernel)."""
    sigma_length_rw: float = 0.5
    """Random walk (m/sqrt(s)) of the contour's length mode (process noise)."""
    sigma_width_rw: float = 0.05
    """Random walk (m/sqrt(s)) of the contour's width mode (process noise)."""
    mean_length: float = 4.6
    """Length (m) of the rectangle that is the prior mean contour (and the decay target)."""
    mean_width: float = 1.9
    """Width (m) of that rectangle."""
    min_vehicle_length: float = 3.0
    """A track whose contour's longer side (median length or width over its steps, m) is
    below this is not a motor vehicle (a cyclist, a pedestrian): it is dropped from the tracks
    the registration and the smoothers use (:mod:`fgloc.tracking.road_users`); 0 keeps every
    track."""
    min_vehicle_width: float = 1.3
    """Likewise for the contour's shorter side (m); 0 keeps every track."""
    wide_vehicle_width: float = 2.0
    """A track whose contour's shorter side is at least this (m) is a motor vehicle however
    short its longer side (a car seen end-on whose length came out short; the cyclists'
    contours stay narrower, their width prior-bound below 2 m)."""
    walking_speed: float = 2.5
    """A track whose speed (m/s; the 90th percentile of |v| over its steps) stays below this
    is not a motor vehicle whatever its size: a pedestrian, whose few returns leave its
    contour at the car-sized prior (static returns are not tracked, so a vehicle's track is
    its moving part); 0 keeps every track."""
    off_lane_margin: float = 1.0
    """A track whose centre keeps at least this much nearer (m; the median over its steps) the
    area of a lanelet no motor vehicle may drive (a rail, a bicycle lane, a walkway) than any
    drivable lanelet's is not a motor vehicle (a tram on its own track bed); ``inf`` keeps
    every track. Inactive on maps without such lanelets."""
    off_road_margin: float = 3.0
    """A track whose centre keeps more than this (m; the median over its steps) from every
    drivable lanelet's area, whatever its direction, is no vehicle on the map's roads: a
    multipath ghost mirrored behind a facade or a barrier (on the independent generator most
    ghost tracks lay 7.6-42 m off with the true pose, vehicles' within 1.0 m), or a vehicle on a
    road the map lacks, which has no lane to register to. Above the coarse pose's usual error;
    ``inf`` keeps every track."""
    hidden_share: float = 0.5
    """A track whose centre lies behind a building of the ALS (class 6), as seen from the
    sensor, at more than this share of its steps is a multipath ghost: the radar has no line
    of sight there (:mod:`fgloc.tracking.sightlines`; this catches the ghosts a facade mirrors
    onto another road, which the off-road rule cannot). 1 keeps every track."""
    long_trigger_width: float = 2.8
    """Long-vehicle hypothesis: a track whose contour is at least this wide (m) less half the std.
    dev. of its width (cars and vans are narrower, trucks and buses about 2.5 m; above 2.5 m
    since ``extent_width_gap``: cars with dense returns come out 0.1-0.2 m wide and the gap
    adds to that, 2.3 m promoted cars far out to 5-6 m trucks) ..."""
    long_wide_updates: int = 10
    """... in this many updates in a row with a misfit (see diverge_excess) of at most ..."""
    long_max_misfit: float = 0.2
    """... this (m): noisy detections (azimuth noise far out) widen a face's extremes ..."""
    long_side_updates: int = 5
    """... whose long side was seen in fewer than this many updates (its length is not
    measured: seen head-on or from behind) ..."""
    long_length: float = 10.0
    """... gets a contour this long (m), its centre moved away from the seen face (0 = off)."""
    long_width: float = 2.5
    """Width (m) of the long-vehicle rectangle its contour decays towards (with long_length)."""
    long_sigma_length: float = 1.0
    """Std. dev. (m) of the long vehicle's length added along the unobservable direction."""
    span_history: int = 40
    """Visible length over the track's history: the lengthwise span (m) of a track's
    associated detections in each update with at least ``extent_min_points`` of them, less
    twice their position noise along the heading, is kept for this many updates (0 = off);
    its ``span_quantile`` quantile is a lower bound of the vehicle's length ..."""
    span_quantile: float = 0.8
    """... (a high quantile: sparse returns rarely reach both ends in one frame; not the
    maximum, so a frame that caught the vehicle behind does not count) ..."""
    span_margin: float = 0.4
    """... and a contour shorter than that bound by more than this (m) grows ..."""
    span_gain: float = 0.3
    """... by this share of the shortfall per update, towards the end beyond which its
    detections reach farther (the seen end stays put)."""
    occupancy_gap: float = 1.0
    """Occupied length while an end of the vehicle faces the sensor (0 = off): the distances
    behind the seen end of a track's detections and of the Doppler-consistent ones beside it
    beyond its ends (up to ``chain_reach``; free or held by another track; within its half
    width and 0.3 m sideways: not a neighbour in the next lane), pooled over
    the end-on updates of the last ``span_history`` frames,
    are a lower bound of its length up to their first gap wider than this (m) -- a truck's
    side seen at grazing incidence fills over the frames, a following vehicle leaves an
    empty band; a contour shorter than it by more than ``span_margin`` grows like the span
    bound's, away from the seen end ..."""
    occupancy_toward: bool = True
    """... Pooled the same way, the distances beyond the seen end towards the sensor (up to
    their first gap wider than ``occupancy_gap``) say how far the vehicle continues past the
    contour on the sensor's side (of the detections beside the contour, within its half
    width and 0.3 m; no farther than the frame's own detections reach); beyond
    ``span_margin`` plus twice ``sigma_range`` (the seen face's own range noise) the contour
    of a track with ``span_history`` updates grows towards the sensor by ``span_gain`` of
    the excess per update, the far end staying put; when that first happens within its
    first 2 ``span_history`` updates, its earlier rows' lengths are retrodicted from their
    far end: a track born on the far part of a truck that
    passed the sensor and recedes end-on takes its near part (robustness combined seed 5: a
    10.7 m truck followed by two tracks, 4.1 and 5.5 m) ..."""
    occupancy_min_points: int = 5
    """... (the bound is the distance that this many pooled detections reach or exceed) ..."""
    occupancy_max_incidence: float = 0.6
    """... in the updates where sin(angle between the line of sight and the heading) is at most
    this (about 37 deg: end-on or nearly, the long side at grazing or shallow incidence; a
    truck that comes into view late, e.g. from behind another vehicle, shows its side at
    20-35 deg with returns 2-3 m apart that the chain does not join: robustness far-sparse
    seed 1, a 10.9 m truck seen for 3 s, tracked 5.4 m long with its centre 2.9 m off at
    0.35) ..."""
    occupancy_min_updates: int = 10
    """... once the track has this many updates; before, at most ``occupancy_young_incidence``
    ..."""
    occupancy_young_incidence: float = 0.35
    """... (about 20 deg: end-on, where the seen end is the nearest face in range from the
    first frame on; farther off a young track's contour end is not yet its vehicle's: a truck
    track 5 frames old at 26 deg measured 12.5 m for 10.5 m; end-on from the first update a
    sparse truck's length comes 1.2 m sooner: straight road seed 6, 11.9 m against 10.7)."""
    occupancy_bound: bool = True
    """End-on, the distance (m) behind the seen end that ``occupancy_min_points`` of the
    track's own detections, pooled like the occupied length's (no gap rule: a side sampled at
    its corners and wheels has gaps), reach or exceed bounds its length from above once it is
    at least ``mean_length`` and ``extent_min_cover`` of the contour's length (the long side
    is in view: a face seen alone bounds nothing; nor while the long-vehicle prior holds an
    unseen side). A contour longer than that bound, the occupied and the span length by more
    than ``span_margin`` shrinks by ``span_gain`` of the excess per update, the seen end
    staying put. Seen at grazing incidence the far end gets no rows of its own and drifts
    with the seen face's (the robustness matrix's default seed 4: a receding 10.1 m truck
    came out 12.6 m)."""
    retrodict_window: int = 20
    """Length retrodiction of a finished track (:mod:`fgloc.tracking.retrodict`): a vehicle's
    length is constant, so the longest it was measured -- the largest median of its contour
    length over this many consecutive steps among those whose length std. dev. is at most
    ``retrodict_max_sd`` -- is carried back to every step with a shorter contour, its centre
    moved away from the sensor by half the added length times |cos| of the angle between the
    heading and the line of sight (seen end-on the face seen stays, broadside the contour
    grows about its centre). A truck seen head-on from far away is otherwise reported
    car-sized with its centre metres towards the sensor until its side comes into view. The
    output tracks' earlier steps then use later detections (not causal); their stored
    covariances are the filter's. 0 = off (the filter's states as they were)."""
    retrodict_max_sd: float = 0.35
    """... (m; about one extent row's ``sigma_extent``: the length is measured, not the prior
    or a transient of the first updates)."""
    tau: float = 0.05
    """Contour forgetting rate (1/s): f' = mu + exp(-tau dt) (f - mu), Q = (1-exp(-2 tau dt)) K."""

    # ---- kinematics --------------------------------------------------------------------------
    sigma_jerk: float = 2.0
    """Std. dev. (m/s^3) of the discrete white jerk of the CTRA process noise."""
    sigma_yaw_acc: float = 0.6
    """Std. dev. (rad/s^2) of the discrete white yaw acceleration."""
    sigma_pos: float = 0.05
    """Position random walk (m/sqrt(s)) for model error."""
    init_sigma_pos: float = 1.0
    """Initial std. dev. (m) of the centre of a new track."""
    init_sigma_speed: float = 3.0
    """Initial speed std. dev. (m/s)."""
    init_sigma_accel: float = 1.0
    """Initial acceleration std. dev. (m/s^2)."""
    init_sigma_yaw_deg: float = 15.0
    """Initial yaw std. dev. (deg) when a lanelet gives the direction."""
    init_sigma_yawrate: float = 0.15
    """Initial yaw-rate std. dev. (rad/s)."""
    default_speed: float = 8.0
    """Initial speed (m/s) when the Doppler cannot give it (motion across the line of sight)."""
    lane_search_radius: float = 6.0
    """A lanelet centre line within this distance (m) of a new cluster gives its heading (the
    nearest sample that explains the cluster's Doppler; the birth zone's lane direction only
    where no centre line is this near) ..."""
    birth_sigma_doppler: float = 0.3
    """... ruling out a sample when the best rigid motion along its direction (forwards, speed
    up to max_speed, yaw rate up to max_yawrate) leaves a Doppler residual sum of squares
    larger than the best sample's by more than (3 x this (m/s))^2: the scatter of a new
    cluster's Doppler about a rigid motion (radar noise and height)."""
    birth_hypotheses: int = 2
    """Where lane samples left by that test lie at most ``birth_hypothesis_margin`` (m) farther
    from a new cluster than the nearest one and head more than ``birth_hypothesis_sep_deg``
    away from it (lanes crossing in a junction box), the cluster starts up to this many
    tentative tracks, one per heading; once one of them reaches its confirmation hits, the
    one that took the most detections since their birth goes on and the others end (1 = the
    nearest lane's heading only) ..."""
    birth_hypothesis_margin: float = 1.0
    """... (m) ..."""
    birth_hypothesis_sep_deg: float = 30.0
    """... (deg; twice init_sigma_yaw_deg: a prior within that of the truth converges)."""

    max_speed: float = 40.0
    """Speeds (m/s) are clipped to [0, max_speed] after each update (no reversing)."""
    max_accel: float = 6.0
    """|a| (m/s^2) is clipped to this after each update."""
    max_yawrate: float = 1.0
    """|yaw rate| (rad/s) is clipped to this after each update."""
    min_radius: float = 0.3
    """Contour radii (m) are kept at least this after each update."""

    # ---- UKF ---------------------------------------------------------------------------------
    ukf_alpha: float = 1.0
    """Unscented transform spread alpha."""
    ukf_beta: float = 0.0
    """Unscented transform beta (prior distribution knowledge)."""
    ukf_kappa: float = 0.0
    """Unscented transform kappa."""

    # ---- association and management ----------------------------------------------------------
    gate: float = 0.7
    """A detection up to this far (m) outside a track's predicted contour may join it, plus up
    to twice the track's centre std. dev. (capped at gate_max)."""
    gate_max: float = 4.0
    """Cap (m) of the whole association gate."""
    gate_doppler: float = 2.0
    """A detection whose Doppler differs by more than this (m/s) plus three times the track's
    speed std. dev. from the track's predicted range rate at that point is not associated to
    it (0 = no Doppler gate)."""
    gate_long_extra: float = 1.5
    """Extra gate (m) along the heading of a large track (a truck's contour grows into its
    length); a car-sized track keeps the tight gate (no detections from the car behind)."""
    chain_gap: float = 1.0
    """Free detections beside a track's contour (within its sideways gate, Doppler-consistent)
    beyond its ends join it when they continue its detections lengthwise with no gap wider
    than this (m): the rest of a vehicle longer than its contour. Beyond the contour's end by
    more than the gate before its growth with the centre's std. dev. (gate, plus
    gate_long_extra for a large track), detections join only this way or when a shift of the
    contour explains them (the track's detections then span at most its length plus that
    gate at both ends), and seed no birth in that frame (0 = off: the grown gate takes
    them)."""
    chain_reach: float = 8.0
    """... up to this far (m) beyond the contour's end."""
    large_length: float = 6.5
    """A track whose contour is at least this long (m) ..."""
    large_width: float = 2.25
    """... or this wide (m) is large (truck-like: trucks are wider than cars)."""
    duplicate_long: float = 4.0
    """A track whose centre is within gate (m) sideways and this (m) lengthwise of a stronger
    track's contour extent is a duplicate (e.g. on a truck's front) and is dropped."""
    drop_duplicates: bool = True
    """A track ended by the duplicate rule is not reported (it followed part of a vehicle that
    a stronger track follows, e.g. a truck's far end: reporting it makes a false track)."""
    confirm_hits_zone: int = 3
    """A track born in a birth zone is confirmed after this many updates ..."""
    confirm_window_zone: int = 5
    """... within this many frames of its birth."""
    birth_anywhere: bool = True
    """Also start tracks outside the birth zones (vehicles present at t=0, out of occlusion)."""
    confirm_hits_anywhere: int = 8
    """A track born outside the zones is confirmed after this many updates ..."""
    confirm_window_anywhere: int = 12
    """... within this many frames of its birth."""
    delete_after: float = 1.0
    """A confirmed track missed for this long (s) is ended (its unmeasured tail is dropped)."""
    delete_after_blind: float = 3.0
    """The same while the track's centre is in the near blind range under the mast."""
    blind_no_update: bool = True
    """Tracks whose centre is in the near blind range take their detections but are not
    updated (only vehicle tops are seen there) and coast."""
    reflection_height: float = 0.8
    """Typical detection height (m) above the road: with the sensor height and the vertical FOV
    it sets the near blind range, whose contour points are not candidates."""
    min_output_hits: int = 10
    """A confirmed track with fewer updates than this when it ends is not reported (a short-lived
    duplicate, e.g. on a truck's far end, that the duplicate rule removed soon after)."""
    diverge_excess: float = 0.6
    """Divergence: a track whose associated detections lie farther than this from its
    contour (m; the median of their distances to the closest point of the predicted contour,
    no more than their radial excess, smoothed over ``diverge_time``: the track's misfit) no
    longer fits its vehicle and is ended (its detections start a new track). The radial
    excess alone (1.0 m until 2026-12-03) grows with a contour's elongation: a truck's
    returns from its top or far side lie up to half its length inside along the ray from
    the centre, and on the independent generator's scenarios truck tracks diverged every
    2-3 s while they followed their truck (trucks came out 1.3-2.9 m short on average)."""
    reverse_updates: int = 10
    """A track whose UKF update wants a speed below -``reverse_speed`` (before the clip at 0:
    speeds are forwards) in this many updates in a row heads against its vehicle's motion
    and has diverged like one whose misfit exceeds ``diverge_excess`` (0 = off). A track born
    on a truck in a junction with a heading 125 deg off turned to 180 deg and stood at zero
    speed on the truck creeping away, its contour fitting the returns (independent
    generator, static junction 1 seed 2: 4 s at 175 deg off); on 6 other runs no track
    reached 5 such updates in a row."""
    reverse_speed: float = 0.3
    """... (m/s)."""
    max_width: float = 4.0
    """A contour wider than this (m) covers more than one road vehicle (the widest are about
    2.6 m; a far car's azimuth noise widens its contour to about 3 m): the track has
    diverged like one whose misfit exceeds ``diverge_excess`` -- it ends, its detections
    start new tracks, and a diverged track is reported up to its last row whose misfit was
    at most half ``diverge_excess`` (a truck's track that took in a car crossing its path
    near the sensor grew to 40 x 8.5 m, and its length retrodiction carried 16.4 m back
    over the 17 s it had followed the 11 m truck)."""
    diverge_time: float = 0.5
    """Time constant (s) of the exponential smoothing of that misfit."""
    birth_blind_margin: float = 8.0
    """No track starts closer to the sensor than the near blind range plus this (m): under the
    mast only the tops of the vehicles are seen and a new track's heading and extent are
    unreliable there; the vehicle gets its track once it is farther out."""
    birth_reanchor: bool = True
    """A track's first update re-places its box when its birth cluster was small: with at
    least twice the birth cluster's detections (and ``extent_min_points``), those of them
    with a neighbour within ``cluster_eps`` give a new box as a birth would
    (:func:`fgloc.tracking.birth.initial_kinematics` along the track's heading: the
    sensor-side edges at the detections', the size at least the contour's); it replaces the
    contour's rectangle when the centres lie more than ``init_sigma_pos`` apart (not in a
    heading-hypothesis group: re-placed, a wrong heading fitted the returns better), and the
    track's birth row moves with it (the smoothers' and the joint's prior on a track's first
    state). A few returns on a vehicle's far part (its near part withheld next to the blind
    range) put the box's sensor-side end metres ahead of the vehicle's; the UKF then turned
    the box by up to 40 deg instead of moving it and the contour grew to 7-8 m (robustness
    combined seed 5: a 4 m car tracked 8 m long for 14 s, 2.1 m centre RMS)."""
    fov_margin: float = 2.0
    """A track whose centre is this far (m) outside the field of view is ended."""
    relink_time: float = 5.0
    """Re-linking (:mod:`fgloc.tracking.relink`): a confirmed track ended inside the field of
    view (missed for ``delete_after`` s or diverged) continues as a track whose first row
    comes at most this long (s) after its last (0 = off: the vehicle keeps two tracks; a car
    turning across the line of sight 173 m out, its returns dropped as static, had its track
    end and a new one start a second later; on the independent generator's occluded
    junctions vehicles hidden behind others came back after 3-5 s) ..."""
    relink_settle: float = 0.5
    """... judged by that track's state this long (s) after its first row (the first rows hold
    the birth's guesses: the lane's heading, ``default_speed``) ..."""
    relink_gate: float = 3.0
    """... when the ended track's last row run forward and that state run backward at constant
    velocity meet within this distance (m) halfway in time (a following car is a headway
    behind; over the robustness matrix and the real map's junctions, 81 runs, the nearest
    pair of tracks of two vehicles met 3.8 m apart, 30 of 65 pairs of one vehicle's tracks
    within 3 m) ..."""
    relink_velocity_error: float = 0.5
    """... plus this (m/s) times the time between the two rows (0 = a fixed gate): the two
    runs meet exactly for a vehicle at a constant acceleration, and an error in an end's
    velocity, or a speed change while unseen (braked, then held), moves them apart the more
    the longer the gap (with ``relink_time`` 5 s against a fixed gate and 3 s, on 54 runs of
    the independent generator with the true pose: 43 more links, 40 of one vehicle's tracks,
    1 of two vehicles', 2 of a false track and a vehicle's) ..."""
    relink_max_turn_deg: float = 90.0
    """... and their headings differ by at most this (deg; a vehicle entering the view where
    another left it drives the other way) ..."""
    relink_min_radius: float = 4.0
    """... and an arc of this radius (m; a road vehicle turns no tighter) through the ended
    track's last and the new track's first centre turns at least that much (their distance
    at least ``2 relink_min_radius sin(turn / 2)``). The rows between are interpolated."""
    stand_time: float = 60.0
    """Re-linking across a stand: a lost track continues as a track whose first row comes at
    most this long (s) after its last (0 = off) when the vehicle stood in between -- a
    vehicle that stops at a stop line or in a queue returns only static detections (its
    Doppler below ``doppler_min``), they are dropped, its track ends and a new one starts
    when it moves off -- ..."""
    stand_speed: float = 3.0
    """... when both the ended track's last row and the new track's state ``relink_settle`` s
    after its first row are slower than this (m/s) ..."""
    stand_accel: float = 2.0
    """... and the ended track braked to a stop at this rate (m/s^2) and the new one started
    from a stop at it lie within ``relink_gate`` of each other, their headings within
    ``stand_max_turn_deg``. The rows between brake, stand and start at this rate; the standing
    ones are flagged (``Track.standing``) and the smoothers hold them still. A pair that
    passes both tests takes the model whose ends meet closer."""
    stand_max_turn_deg: float = 30.0
    """Largest heading change (deg) across a stand."""

    # ---- birth zones -------------------------------------------------------------------------
    birth_zones: list[list[float]] | None = None
    """Explicit birth zones [x, y, radius, yaw_deg] in L; None = derived from the lanelet map
    where lanelet centre lines enter the field of view."""
    birth_zone_radius: float = 12.0
    """Radius (m) of the derived birth zones."""
    birth_zone_depth: float = 10.0
    """Derived zones sit this far (m) into the field of view along the lanelet."""

    store_covariances: bool = True
    """Keep the per-step state covariances in the output tracks."""
