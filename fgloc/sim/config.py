"""Simulator configuration: a tree of dataclasses with documented defaults.

Load from a TOML table with :func:`fgloc.config.from_dict` (``from_dict(SimConfig, table, path)``).
Ranges are ``(low, high)`` pairs sampled uniformly per scenario (or per object) from the seed.
Lengths in metres, angles in degrees, times in seconds, rates per second.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class SiteConfig:
    """Where on Earth the scenario is placed (world CRS, default around Ingolstadt)."""

    crs: str = "EPSG:25832"
    """World CRS of the scenario (metres, E/N)."""
    east: tuple[float, float] = (677000.0, 680000.0)
    """Range of the junction's easting."""
    north: tuple[float, float] = (5400000.0, 5403000.0)
    """Range of the junction's northing."""
    ground_height: tuple[float, float] = (365.0, 375.0)
    """Range of the ground height (m above the vertical datum) at the junction."""


@dataclass
class RoadSimConfig:
    """Road layout geometry."""

    lane_width: float = 3.5
    """Lane width (m)."""
    lanes_per_direction: list[int] = field(default_factory=lambda: [1, 2])
    """Choices for the number of lanes per direction of each road."""
    crossing_angle_jitter_deg: float = 12.0
    """Crossing/branching angle is 90 deg +- up to this (uniform)."""
    crossing_angle_deg: tuple[float, float] | None = None
    """If set, the crossing/branching angle (deg, between the two roads of an intersection or
    the major road and the branch of a T-junction) is uniform in this range instead (e.g.
    [70, 80] for an oblique junction)."""
    arm_length: float = 150.0
    """Length of each junction arm from the junction centre (m); also the half length of the
    straight road and the length of the curve's straight legs beyond the arc's end."""
    junction_margin: float = 8.0
    """Stop line distance beyond the crossing road's edge (m): the junction-box size (the box
    extends ``half road width / sin(angle) + junction_margin`` from the centre along each arm);
    sets the junction turn radii (about 8-16 m at the default)."""
    curve_radius: tuple[float, float] = (40.0, 90.0)
    """Radius of the road centre line in the ``curve`` case (m). Keep < 100 m so the curve
    lanelets label as turns with the Menger rule (gamma = 0.01 1/m)."""
    curve_angle_deg: tuple[float, float] = (60.0, 100.0)
    """Heading change over the arc in the ``curve`` case."""


@dataclass
class SensorSimConfig:
    """Mounting of the radar and the prior a user would write into sensor.toml."""

    mast_height: tuple[float, float] = (5.0, 8.0)
    """Sensor height above the road (m)."""
    pitch_deg: tuple[float, float] = (2.0, 6.0)
    """Pitch (deg, > 0 = boresight down)."""
    roll_deg: float = 1.5
    """Roll is uniform in +- this (deg)."""
    setback: tuple[float, float] = (2.0, 5.0)
    """Distance of the mast from the road edge (m)."""
    junction_distance: tuple[float, float] = (18.0, 32.0)
    """Distance along an arm from the junction centre to the mast (m)."""
    yaw_jitter_deg: float = 8.0
    """Yaw deviates from 'looking at the junction / along the road' by up to +- this (deg)."""
    approx_position_sigma: float = 3.0
    """Std. dev. (m, per axis) of the approximate position written to sensor.toml."""
    yaw_guess_sigma_deg: float = 3.0
    """Std. dev. (deg) of the yaw guess written to sensor.toml."""


@dataclass
class RadarSimConfig:
    """4D radar measurement model (one frame = one scan)."""

    rate_hz: float = 20.0
    """Frame rate (Hz)."""
    hfov_deg: float = 120.0
    """Horizontal field of view (deg, centred on the boresight)."""
    vfov_deg: float = 30.0
    """Vertical field of view (deg, centred on the boresight)."""
    max_range: float = 200.0
    """Maximum range (m)."""
    sigma_range: float = 0.15
    """Range noise std. dev. (m)."""
    sigma_azimuth_deg: float = 0.2
    """Azimuth noise std. dev. (deg)."""
    sigma_elevation_deg: float = 0.7
    """Elevation noise std. dev. (deg)."""
    sigma_doppler: float = 0.07
    """Doppler noise std. dev. (m/s)."""
    points_per_degree: float = 14.0
    """Expected vehicle detections per degree of the vehicle's angular extent seen from the
    sensor (so the count falls roughly as 1/range), before the detection probability."""
    returns_at_reference: float | None = None
    """Returns-per-range model: expected vehicle detections per vehicle and frame at
    ``reference_range``, falling as ``(reference_range / range) ** returns_exponent`` (then times
    the detection probability). None (default): the ``points_per_degree`` model."""
    reference_range: float = 20.0
    """Reference range (m) of ``returns_at_reference``."""
    returns_exponent: float = 1.0
    """Fall-off exponent of the returns-per-range model (1: as 1/range)."""
    corner_fraction: float = 0.4
    """Fraction of vehicle detections concentrated at a corner (see ``corners``)."""
    corner_spread: float = 0.6
    """Std. dev. (m) of the distance of those corner detections from the corner."""
    corners: str = "nearest"
    """Which corners the corner detections concentrate at: "nearest" (the corner nearest to the
    sensor, default) or "visible" (either end of the visible edge they fall on, i.e. every
    visible corner)."""
    wheel_fraction: float = 0.0
    """Fraction of vehicle detections at the wheels of the visible long side: at 1/6 of the
    length from the front or the rear (equally likely), spread along the side by
    ``wheel_spread``. Vehicles seen head-on or from behind only (no long side visible) get
    these on their visible edges instead. Default 0 (no wheel concentration)."""
    wheel_spread: float = 0.3
    """Std. dev. (m) along the side of the wheel detections around the axle."""
    wheel_radius: float = 0.0
    """Radius (m) of the wheels the wheel detections lie on; > 0 gives them micro-Doppler: a
    return at height h on a wheel rolling at the body's speed v moves along the heading at
    v h / wheel_radius (0 at the road, 2 v at the top), h uniform in [0, 2 wheel_radius] (also
    the return's height above the road; the wheel's vertical velocity, which reaches the
    Doppler only through the elevation angle, is left out). 0 (default): wheel detections
    move with the body."""
    roof_fraction: float = 0.0
    """Fraction of vehicle detections that come from the roof instead of the faces: uniform over
    the footprint (seen from above, inside the outline, not on it) at the roof height, with
    the body's rigid-body velocity. Real radars see roof racks, windscreens and roof edges;
    an outline-only model (the default 0) never puts a return inside a vehicle's footprint,
    which is what a contour tracker must tell from its outline. Drawn after the corner and
    wheel shares (it takes a share of every kind of face return)."""
    range_half_detection: float = 0.75
    """Range (fraction of max_range) where the detection probability is 0.5."""
    range_falloff: float = 12.0
    """Width (m) of the logistic fall-off of the detection probability with range."""
    clutter_per_frame: float = 180.0
    """Expected static clutter detections per frame (curbs, poles, facades, trunks)."""
    clutter_doppler_sigma: float = 0.03
    """Std. dev. (m/s) of the true doppler of static clutter (vibration, multipath)."""
    curb_height: float = 0.15
    """Height (m above the road surface) of the curb scatterers along the road edges (a kerb's
    top; fgloc's vertical fit assumes ``[coarse] static_height`` 0.1 +- 0.05 m for static
    ground returns, so other heights test that prior)."""
    ghost_fraction: float = 0.0
    """Multipath ghosts: each building facade facing the sensor mirrors each visible vehicle
    return in front of it with this probability (the double bounce shows at the return's
    mirror image behind the facade, moving mirrored; :mod:`fgloc.sim.radar`). 0 (default):
    none."""
    false_alarms_per_frame: float = 10.0
    """Expected uniform false alarms per frame (random position in the FOV, random doppler)."""
    false_alarm_doppler: float = 20.0
    """False-alarm doppler is uniform in +- this (m/s)."""
    rcs_sigma: float = 4.0
    """Std. dev. (dB) of the per-detection RCS around the source's mean."""
    return_height: tuple[float, float] | None = None
    """Height range (m above the road surface under the return) of vehicle returns: uniform
    in ``[low, high]``, clipped to the vehicle's roof height. None (default): uniform between
    0.3 m and 90 % of the vehicle class's roof height (car 1.5 m, van 2.2 m, truck 3.6 m)."""

    def __post_init__(self) -> None:
        if self.corners not in ("nearest", "visible"):
            raise ValueError(f"corners must be 'nearest' or 'visible', got {self.corners!r}")
        if not 0.0 <= self.corner_fraction + self.wheel_fraction <= 1.0:
            raise ValueError("corner_fraction + wheel_fraction must lie in [0, 1], got "
                             f"{self.corner_fraction} + {self.wheel_fraction}")
        if not 0.0 <= self.ghost_fraction <= 1.0:
            raise ValueError(f"ghost_fraction must lie in [0, 1], got {self.ghost_fraction}")
        if not 0.0 <= self.roof_fraction <= 1.0:
            raise ValueError(f"roof_fraction must lie in [0, 1], got {self.roof_fraction}")
        if self.wheel_radius < 0.0:
            raise ValueError(f"wheel_radius must be >= 0 (m), got {self.wheel_radius}")
        if not 0.0 <= self.curb_height <= 1.0:
            raise ValueError(f"curb_height must lie in [0, 1] (m), got {self.curb_height}")
        if self.return_height is not None and not 0.0 <= self.return_height[0] \
                <= self.return_height[1]:
            raise ValueError(f"return_height must be [low, high] with 0 <= low <= high (m), "
                             f"got {list(self.return_height)}")


@dataclass
class TrafficSimConfig:
    """Vehicle arrivals, classes and driving behaviour."""

    arrival_interval: float = 2.5
    """Mean time between vehicle arrivals (s) when the vehicle count is not given: the traffic
    density is 60 / arrival_interval vehicles per minute (before the headway delays)."""
    class_mix: tuple[float, float, float] = (0.7, 0.2, 0.1)
    """Probabilities of car, van, truck."""
    speed_straight: tuple[float, float] = (8.0, 15.0)
    """Cruise speed range (m/s); trucks draw from the lower 60 %."""
    speed_turn: tuple[float, float] = (5.0, 8.0)
    """Speed range in junction turns (m/s)."""
    turn_curvature: float = 0.02
    """Path curvature (1/m) above which the turn speed applies."""
    lateral_accel: float = 2.5
    """Maximum lateral acceleration (m/s^2), caps the speed in curves."""
    accel: float = 1.5
    """Longitudinal acceleration (m/s^2)."""
    decel: float = 2.0
    """Longitudinal deceleration (m/s^2)."""
    transition_length: float = 6.0
    """Length (m) over which the path curvature ramps in and out (smooth yaw rate)."""
    headway: float = 1.0
    """Minimum time gap (s) between two vehicles using the same piece of road."""
    truck_length: tuple[float, float] | None = None
    """If set, truck lengths (m) are uniform in this range; None: normal, 11.0 +- 0.6 m."""
    platoon_size: tuple[int, int] = (1, 1)
    """Vehicles per platoon, uniform in [low, high]; (1, 1) (default) = independent arrivals.
    A platoon drives one route at one speed profile; its arrivals are Poisson with mean
    interval ``arrival_interval`` x the mean platoon size (same vehicles per minute)."""
    cyclists_per_minute: float = 0.0
    """Cyclists per minute (Poisson), besides the motor vehicles; 0 = none. They ride the
    vehicles' routes ``cyclist_offset`` m right of the lane centre line."""
    cyclist_speed: tuple[float, float] = (4.0, 7.0)
    """Cyclists' cruise speed range (m/s); 70 % of it in junction turns."""
    cyclist_offset: float = 1.4
    """How far (m) right of the lane centre line cyclists ride (on a 3.5 m lane: 0.35 m from
    its edge)."""
    platoon_headway: tuple[float, float] = (1.0, 1.0)
    """Time headway (s, front to front) of each platoon follower behind its predecessor,
    uniform in this range; never closer than ``headway`` between them (time gap, rear to
    front)."""
    stop_share: float = 0.0
    """Share of the motor vehicles that stop once on their route, at a stop line ``stop_gap``
    m before their first crossing with another route, for a time drawn from ``stop_time``
    (a red light, a yield): standing, their returns are static (zero Doppler). A vehicle on
    the same lane that would come up behind a standing one before it has left joins a queue
    (``queue_gap``, ``queue_discharge``); the others wait (entry delayed, as for every
    conflict). Routes crossing no other route (straight road, curve) have no stop line. 0
    (default) = no vehicle stops."""
    stop_time: tuple[float, float] = (3.0, 15.0)
    """Standing time (s) of a stopping vehicle, uniform in [low, high]."""
    stop_gap: float = 2.0
    """Distance (m) from a stopped vehicle's front to its route's first crossing."""
    queue_gap: float = 2.0
    """Distance (m) from a queued vehicle's front to the rear of the vehicle it stands behind."""
    queue_discharge: float = 2.0
    """A queued vehicle moves off this long (s) after the vehicle ahead of it."""
    platoon_abreast: bool = False
    """Platoon followers drive the lane beside their predecessor's instead of its own (a route
    whose start lies 2-4.5 m to the side of the predecessor's, heading within 15 deg; its own
    where there is none) at its cruise speed: with a headway below a car's length over the
    speed, pairs of vehicles side by side in adjacent lanes. False (default): one route."""

    def __post_init__(self) -> None:
        if self.cyclists_per_minute < 0 or not 0 < self.cyclist_speed[0] <= self.cyclist_speed[1]:
            raise ValueError(f"cyclists_per_minute must be >= 0 and cyclist_speed [low, high] with "
                             f"0 < low <= high (m/s), got {self.cyclists_per_minute} and "
                             f"{list(self.cyclist_speed)}")
        if not 0.0 <= self.stop_share <= 1.0 or not 0.0 <= self.stop_time[0] <= self.stop_time[1]:
            raise ValueError(f"stop_share must be in [0, 1] and stop_time [low, high] with "
                             f"0 <= low <= high (s), got {self.stop_share} and "
                             f"{list(self.stop_time)}")
        lo, hi = self.platoon_size
        if not 1 <= lo <= hi:
            raise ValueError(f"platoon_size must be [low, high] with 1 <= low <= high, "
                             f"got {list(self.platoon_size)}")


@dataclass
class AlsSimConfig:
    """Aerial laser scan synthesis."""

    extent: float = 400.0
    """Side of the square ALS tile centred on the sensor (m)."""
    density: float = 6.0
    """Point density (points per m^2)."""
    height_sigma: float = 0.03
    """Height noise std. dev. (m)."""
    slope: tuple[float, float] = (0.005, 0.02)
    """Ground slope range (dimensionless rise/run) in a random direction."""
    road_raise: float = 0.1
    """Road surface height above the surrounding ground (m)."""
    buildings: int = 8
    """Number of buildings (fewer when no free space is found)."""
    building_height: tuple[float, float] = (8.0, 25.0)
    """Building height range (m)."""
    building_size: tuple[float, float] = (10.0, 30.0)
    """Building side length range (m)."""
    building_clearance: float = 6.0
    """Minimum distance of buildings from the road edge (m)."""
    trees: int = 40
    """Number of trees."""
    tree_height: tuple[float, float] = (6.0, 16.0)
    """Tree height range (m)."""
    crown_radius: tuple[float, float] = (2.0, 4.5)
    """Tree crown radius range (m)."""
    canopy_hit: float = 0.75
    """Probability that an ALS pulse inside a crown returns from the crown."""
    poles: int = 12
    """Number of roadside poles (radar clutter; too thin for the ALS)."""
    unclassified_fraction: float = 0.002
    """Fraction of points left unclassified (class 1: wires, birds, noise)."""


@dataclass
class RealMapSimConfig:
    """Traffic on a real Lanelet2 map (``fgloc simulate --map``)."""

    two_way_traffic: str = "keep-right"
    """Where vehicles drive on a two-way lanelet (``one_way`` = no; the routing graph drives it
    in both directions): "keep-right" (default; right-hand traffic) the centre of the right
    half of their driving direction on one at least 5 m wide (a two-way street drawn as one
    lanelet; the centre line on a narrower one), "centre" the lanelet's centre line in both
    directions (as a generator that drives lanelet centre lines makes it)."""
    path_smoothing: str = "moving-average"
    """How a route's concatenated lane line (kinks where hand-mapped lanelets meet) becomes
    the path vehicles drive: "moving-average" (default) a moving average over
    ``2 * path_half_window + 1`` m (the samples are 1 m apart); "spline" a cubic smoothing
    spline of the line against arc length (:func:`scipy.interpolate.make_smoothing_spline`)
    whose equivalent kernel is about ``path_spline_length`` m wide; "none" the line itself
    (every kink driven as a 1 m arc)."""
    centre_line: str = "resampled"
    """Which centre line of a lanelet vehicles drive where they drive its centre:
    "resampled" (default) the mean of its bounds resampled by arc length (fgloc's own, the
    line its lane models use), "lanelet2" lanelet2's ``Lanelet.centerline`` (built from the
    bounds' vertices; on hand-mapped turns up to 2 m away from the resampled one), as a
    generator that drives lanelet2's centre lines makes them. The right half of a two-way
    street (keep-right) is the resampled one's either way."""
    pedestrians_per_minute: float = 0.0
    """Pedestrians arriving per minute on the map's pedestrian ways (crosswalks, walkways,
    lanelets for pedestrians; :mod:`fgloc.sim.map_paths`) within ``route_reach`` of the
    junction, walking them both ways (0.5 x 0.5 m, 1.7 m high). 0 (default): none, and the
    scenario bit for bit as without the setting."""
    pedestrian_speed: tuple[float, float] = (1.0, 1.6)
    """Range (m/s) of the pedestrians' walking speeds."""
    path_cyclists_per_minute: float = 0.0
    """Cyclists arriving per minute on the map's cycle ways (bicycle lanes, lanelets for
    bicycles) within ``route_reach`` of the junction, at ``[traffic] cyclist_speed``, both
    ways unless a way is tagged ``one_way=yes``. 0 (default): none. (``[traffic]
    cyclists_per_minute`` puts cyclists on the vehicles' lanes instead.)"""
    trams_per_minute: float = 0.0
    """Trams arriving per minute on the map's rails (lanelets of subtype ``rail``) within
    ``route_reach`` of the junction, in each rail's direction (both ways unless it is tagged
    ``one_way=yes``); 35 x 2.65 m, 3.5 m high. 0 (default): none."""
    tram_speed: tuple[float, float] = (8.0, 12.0)
    """Range (m/s) of the trams' cruise speeds."""
    path_half_window: int = 2
    """Half window (samples, 1 m apart) of the "moving-average" path smoothing."""
    path_spline_length: float = 3.0
    """Length (m) of the "spline" path smoothing: its penalty ``lam = length ** 4`` (roughly
    the width of the spline's equivalent kernel)."""

    def __post_init__(self) -> None:
        if self.two_way_traffic not in ("keep-right", "centre"):
            raise ValueError("two_way_traffic must be 'keep-right' or 'centre', got "
                             f"{self.two_way_traffic!r}")
        if self.path_smoothing not in ("moving-average", "spline", "none"):
            raise ValueError("path_smoothing must be 'moving-average', 'spline' or 'none', got "
                             f"{self.path_smoothing!r}")
        if self.centre_line not in ("resampled", "lanelet2"):
            raise ValueError("centre_line must be 'resampled' or 'lanelet2', got "
                             f"{self.centre_line!r}")
        if self.path_half_window < 0 or not self.path_spline_length > 0:
            raise ValueError("path_half_window must be >= 0 and path_spline_length > 0")
        if (min(self.pedestrians_per_minute, self.path_cyclists_per_minute,
                self.trams_per_minute) < 0
                or not 0 < self.pedestrian_speed[0] <= self.pedestrian_speed[1]
                or not 0 < self.tram_speed[0] <= self.tram_speed[1]):
            raise ValueError("pedestrians_per_minute, path_cyclists_per_minute and "
                             "trams_per_minute must be >= 0 and pedestrian_speed and tram_speed "
                             "[low, high] with 0 < low <= high (m/s), got "
                             f"{self.pedestrians_per_minute}, {self.path_cyclists_per_minute}, "
                             f"{self.trams_per_minute}, {list(self.pedestrian_speed)} and "
                             f"{list(self.tram_speed)}")


@dataclass
class SimConfig:
    """Every knob of the scenario simulator (see each section for units and defaults)."""

    site: SiteConfig = field(default_factory=SiteConfig)
    road: RoadSimConfig = field(default_factory=RoadSimConfig)
    sensor: SensorSimConfig = field(default_factory=SensorSimConfig)
    radar: RadarSimConfig = field(default_factory=RadarSimConfig)
    traffic: TrafficSimConfig = field(default_factory=TrafficSimConfig)
    als: AlsSimConfig = field(default_factory=AlsSimConfig)
    real_map: RealMapSimConfig = field(default_factory=RealMapSimConfig)
