"""Configuration of the GTSAM smoothers (``[smoothing]`` in the fgloc config TOML).

The motion, contour and noise models are the tracker's (``[tracking]``: process noise, GP
kernel, contour scatter, radar noise), so filter and smoother estimate the same model; this
section only holds what is specific to the smoothers.
"""

from __future__ import annotations

from dataclasses import dataclass

#: smoother names of ``fgloc track --smoother`` (``none`` = the filter's tracks)
SMOOTHERS: tuple[str, ...] = ("none", "fixed-lag", "batch")


@dataclass
class SmoothingConfig:
    """GP-EOT smoothers in GTSAM (batch Levenberg-Marquardt, incremental fixed-lag)."""

    smoother: str = "batch"
    """Smoother of ``--method smoother-sicp``: "batch" (offline, whole tracks) or
    "fixed-lag" (online)."""
    lag: float = 2.0
    """Fixed-lag smoother: states older than this (s) are marginalized."""
    max_detections: int = 24
    """At most this many detections (a regular subsample) of one track in one frame enter its
    measurement factor (all of them when 0; the tracker's update takes 24)."""
    huber_k: float = 2.0
    """Huber threshold (in row std. devs.) of the per-row IRLS weights of a measurement
    factor: its normal-offset, range-rate and extent rows (0 disables the robust weights).
    On the extent rows since a one-frame outlier shifted a whole smoothed track: robustness
    combined, seed 4, a van hid the rear half of a receding 9.4 m truck for a frame, whose
    rear row pulled the rear 2.5 m in; the batch carried the truck 0.5-1.8 m forwards over
    its 282 steps (centre RMS 0.74 m, 0.38 m with the weights; docs/experiments.md)."""
    size_walk_scale: float = 0.0
    """Scale of the tracker's length / width random walk (``tracking.sigma_length_rw``,
    ``sigma_width_rw``) in the smoothers' process noise: the filter needs it to let a
    contour grow into a vehicle seen more fully later; a smoother sees those later views
    already, and a rigid vehicle keeps its size (0 = the size changes only through the GP
    decay, 1 = the filter's process noise)."""
    contour_tau: float = 0.05
    """Forgetting rate (1/s) of the contour in the smoothers' process factors (decay towards
    the mean shape, noise (1 - exp(-2 tau dt)) K); the tracker's default ``tracking.tau``.
    A near-rigid 0.005 was not better on simulated intersections (60 s, seeds 1 / 2: pooled
    centre RMS 0.368 / 0.374 m against 0.385 / 0.315 m)."""
    extent_rows: bool = True
    """Add the tracker's visible-extent rows (``tracking.extent_*``: the extreme detections
    along a seen face mark its ends, from all detections of the frame, ends next to the FOV's
    edge excluded; selection re-done per linearization) to each measurement factor. Without
    them the normal-offset rows leave the length free and the smoothed contour shrinks."""
    extent_face_min_points: int = 12
    """An extent row of the smoothers needs at least this many detections in its frame on
    the face whose ends it marks -- within twice ``[tracking] sigma_range`` of the face's
    outermost detection: the seen side for the length rows, the seen front or rear for the
    width rows (0 = no such test). With a few returns on a face its extreme detections stop
    short of the corner away from the sensor by about their spacing, and summed over a
    whole track these rows shrank the vehicle to that bias: far-sparse / combined settings,
    seeds 1-2, batch per-track centre RMS 0.376 / 0.268 m -> 0.282 / 0.174 m, IoU 0.703 /
    0.756 -> 0.802 / 0.857 (docs/experiments.md, issue 20)."""
    long_vehicle_length: float = 9.0
    """A track whose filtered contour reaches this length (m, front + rear radius) and keeps
    it on at least half of its remaining steps is a long vehicle (truck, bus; the tracker
    promoted it or saw it long): the batch smoother gives it the tracker's long-vehicle
    contour model for the whole track -- GP mean the ``[tracking] long_length`` x
    ``long_width`` rectangle (contour prior, decay target, size modes) and that GP's prior
    on its first contour instead of the filter's car-sized birth contour; the fixed-lag
    smoother switches to it online once the filter's contour has stayed that long for 1 s.
    The joint registration keeps the car model for every track (its point rows take one
    contour model). 0 = off."""
    length_floor_sigma: float = 0.3
    """Batch: the occupied length the tracker measured behind a truck's seen end
    (``Track.length_floor``; ``[tracking] occupancy_gap``), less twice ``[tracking]
    sigma_range``, is a floor under the smoothed length: a step whose contour (front + rear
    radius) is shorter by d (m) adds 0.5 (d / length_floor_sigma)^2 to the cost
    (:mod:`fgloc.smoothing.length_floor`; seen end-on the smoother's rows would shorten the
    truck to its grazing side returns). 0 = off."""
    stand_sigma_speed: float = 0.05
    """Std. dev. (m/s) of a standing step's speed about 0: the steps at which a vehicle stood
    between two tracks the re-linking joined (``Track.standing``; ``[tracking] stand_time``)
    hold no detection, and the smoothers hold them still (:mod:`fgloc.smoothing.standing`)."""
    stand_sigma_yawrate: float = 0.01
    """Std. dev. (rad/s) of a standing step's yaw rate about 0."""
    use_doppler: bool = True
    """Add range-rate rows to each measurement factor (the tracker's Doppler measurement,
    ``tracking.sigma_doppler``): they observe speed, heading and yaw rate, which the contour
    rows leave to the process model (without them the speed of a vehicle seen only from
    behind drifts and its contour grows)."""
    radar_noise: bool = True
    """Per-row measurement noise as in the tracker: range / azimuth noise along the row's
    normal and the GP interpolation variance on top of ``tracking.sigma_contour``."""
    max_iterations: int = 10
    """Batch: Levenberg-Marquardt iteration limit per track."""
    relative_tolerance: float = 1e-3
    """Batch: stop when the relative decrease of the error is below this."""
    batch_steps: int = 16384
    """Batch: optimize the tracks in groups of at most this many steps (track order; a longer
    track is a group of its own). The optimizer's arrays take about 60 kB a step, so this
    bounds its memory on long recordings (a 60 s junction has 6000-9000 steps, one group).
    Tracks share no variable: each gets the same optimum in any grouping, up to rounding."""
    marginals: bool = False
    """Batch: compute each state's marginal covariance (gtsam.Marginals) into the output
    tracks; otherwise the smoothed tracks carry no covariances."""
    relinearize_threshold: float = 1.0
    """Fixed-lag (ISAM2): relinearize a variable whose update exceeds this (any component,
    state units). Measured on intersection seeds 1-3 (docs/experiments.md, "Fixed-lag
    smoother speed"): 0.3 with a check every 3 updates let a badly born track diverge (heading
    flipped, contour 19 m long) and cost more CPU; 1.0 checked every update did not."""
    relinearize_skip: int = 1
    """Fixed-lag (ISAM2): check for relinearization every this many updates (1: every
    update, which is what stops a new track's first Gauss-Newton steps from diverging)."""

    def __post_init__(self) -> None:
        if self.smoother not in SMOOTHERS[1:]:
            raise ValueError(f"smoother must be one of {', '.join(SMOOTHERS[1:])}, "
                             f"got {self.smoother!r}")
        if not self.contour_tau > 0:
            raise ValueError(f"contour_tau must be > 0 1/s, got {self.contour_tau}")
        if self.long_vehicle_length < 0:
            raise ValueError(f"long_vehicle_length must be >= 0 m, got "
                             f"{self.long_vehicle_length}")
        if self.extent_face_min_points < 0:
            raise ValueError(f"extent_face_min_points must be >= 0, got "
                             f"{self.extent_face_min_points}")
        if self.length_floor_sigma < 0:
            raise ValueError(f"length_floor_sigma must be >= 0 m, got "
                             f"{self.length_floor_sigma}")
        if not (self.stand_sigma_speed > 0 and self.stand_sigma_yawrate > 0):
            raise ValueError("stand_sigma_speed and stand_sigma_yawrate must be > 0, got "
                             f"{self.stand_sigma_speed}, {self.stand_sigma_yawrate}")
        if not self.lag > 0:
            raise ValueError(f"lag must be > 0 s, got {self.lag}")
        if self.max_detections < 0 or self.max_iterations < 1 or self.relinearize_skip < 1:
            raise ValueError("max_detections >= 0, max_iterations >= 1 and "
                             "relinearize_skip >= 1 are required")
        if self.batch_steps < 1:
            raise ValueError(f"batch_steps must be >= 1, got {self.batch_steps}")
