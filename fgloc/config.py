"""Configuration: a tree of dataclasses loaded from TOML, validated on load, dumpable.

Every field has a documented default, so an empty file (or none) is a valid configuration.
Unknown keys and wrong types are errors naming the file and the dotted key.
"""

from __future__ import annotations

import dataclasses
import sys
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from fgloc.errors import InputError
from fgloc.registration.config import FineConfig, SicpConfig
from fgloc.registration.joint_config import JointConfig
from fgloc.scenario import CENTRE_LINES, TWO_WAY_MIN_WIDTH
from fgloc.smoothing.config import SmoothingConfig
from fgloc.tracking.config import TrackingConfig

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

T = TypeVar("T")

#: ``[coarse] tie_test`` values (:func:`fgloc.registration.modes.separation_z`).
TIE_TESTS = ("self-normalized", "robust")


@dataclass
class MapConfig:
    """Target cloud (paper IV-A)."""

    voxel_size: float = 0.5
    """Voxel edge (m) for downsampling the road points."""
    gamma: float = 0.01
    """Menger-curvature threshold (1/m) separating turns from straights."""
    road_classes: list[int] = field(default_factory=lambda: [2, 11])
    """ASPRS classes that may be road surface (2 ground, 11 road surface)."""
    crop_margin: float = 0.0
    """Grow each lanelet polygon by this many metres before cropping."""
    sensor_margin: float = 50.0
    """ALS points farther than sensor.max_range + this (m) from the approximate sensor position
    are ignored (covers the position uncertainty and keeps big tiles cheap)."""
    labels: str = "routing"
    """Lanelet labels: "routing" = a lanelet of a junction movement in the map's routing graph
    (between a diverge and a merge) is a turn when the headings of its predecessor and
    successor differ by more than ``turn_angle_deg``, every other lanelet by Menger curvature;
    "curvature" = Menger curvature for every lanelet (the paper's rule)."""
    turn_angle_deg: float = 30.0
    """Heading change (deg) from a junction movement's predecessor to its successor above which
    the movement is a turn ("routing" labels)."""
    lane_labels: str = "path"
    """Labels of the lane samples (the fine and the joint targets): "path" = the curvature of
    the lane's path through its joins, smoothed over ``path_sigma`` m, against ``gamma`` (what
    a vehicle driving it shows, as the tracks are labelled; :mod:`fgloc.map.path_labels`),
    "lanelet" = their lanelet's (``labels``)."""
    path_sigma: float = 2.0
    """Gaussian smoothing length (m) of the lanes' headings for ``lane_labels = "path"``."""
    two_way_lanes: str = "auto"
    """Where each direction drives on a two-way street mapped as one lanelet (``one_way =
    no``; :mod:`fgloc.map.lane_models`): "keep-right" = one lane per direction on the centre of
    its right half (lanelets at least ``two_way_min_width`` m wide), "centre" = the centre line
    both ways, "auto" = both as modes of the pose, chosen on the tracks' fit (or reported
    ambiguous) like the coarse stage's other modes."""
    two_way_min_width: float = TWO_WAY_MIN_WIDTH
    """Width (m) from which a two-way lanelet holds one lane per direction ("keep-right")."""
    centre_line: str = "mean"
    """Where a lanelet's centre line lies (the lanes of every method are built on it;
    :meth:`fgloc.scenario.Lanelet.centre`): "resampled" = the mean of its bounds resampled
    by arc length, "lanelet2" = lanelet2's ``centerline`` (built from the bounds' vertices),
    "mean" = midway between them. The two constructions agree on bounds drawn with many
    evenly spaced nodes (the simulated layouts: within 2.4 cm) but lie up to 2 m apart on
    hand-mapped turns (the Lanelet2 example map: over 0.37 m on a tenth of its road
    lanelets). Where vehicles drive there is not known. "mean" is off by at most half that
    from either. The joint counts that half as the line's ambiguity (``[joint]
    centre_ambiguity``) and estimates where between the two the vehicles drive (``[joint]
    centre_line_sigma``)."""

    def __post_init__(self) -> None:
        if self.centre_line not in CENTRE_LINES:
            raise ValueError(f"centre_line must be one of {', '.join(CENTRE_LINES)}, got "
                             f"{self.centre_line!r}")
        if self.labels not in ("routing", "curvature"):
            raise ValueError(f"labels must be 'routing' or 'curvature', got {self.labels!r}")
        if self.lane_labels not in ("lanelet", "path"):
            raise ValueError(f"lane_labels must be 'lanelet' or 'path', got {self.lane_labels!r}")
        if not self.path_sigma >= 0.0:
            raise ValueError(f"path_sigma must be >= 0 (m), got {self.path_sigma}")
        if not 0.0 < self.turn_angle_deg < 180.0:
            raise ValueError(f"turn_angle_deg must be in (0, 180), got {self.turn_angle_deg}")
        if self.two_way_lanes not in ("auto", "keep-right", "centre"):
            raise ValueError("two_way_lanes must be 'auto', 'keep-right' or 'centre', got "
                             f"{self.two_way_lanes!r}")
        if not self.two_way_min_width > 0.0:
            raise ValueError(f"two_way_min_width must be > 0, got {self.two_way_min_width}")


@dataclass
class CoarseConfig:
    """Coarse localization: accumulated dynamic points + ICP (paper III-A, IV-B)."""

    doppler_min: float = 0.5
    """lambda: minimum |doppler| (m/s) for a detection to count as dynamic."""
    voxel_size: float = 0.5
    """Voxel edge (m) for the accumulated dynamic cloud."""
    dbscan_eps: float = 1.5
    """DBSCAN neighbourhood radius (m) of the noise filter."""
    dbscan_min_points: int = 5
    """DBSCAN core-point count of the noise filter."""
    trail_radius: float = 3.0
    """Before the voxels, a moving detection is kept only on a trail: with at least
    ``trail_min_neighbours`` other moving detections within this many metres (along each
    horizontal axis of S) and ``trail_window`` s (:func:`fgloc.coarse.points.on_trail`). A
    vehicle returns detections frame after frame, a false alarm stands alone: on fgloc's
    simulator 99.9 % of the vehicles' moving detections are kept and 6-8 % of the false
    alarms (10 a frame, 20 Hz; also with far, sparse returns)."""
    trail_window: float = 0.3
    """Half-width (s) of the trail's time window (see ``trail_radius``)."""
    trail_min_neighbours: int = 2
    """Neighbours a moving detection needs on its trail (see ``trail_radius``); 0 = off."""
    min_points: int = 200
    """Fewer dynamic points after filtering than this is an error."""
    icp_ranges: list[float] = field(default_factory=lambda: [20.0, 10.0, 5.0, 2.5, 1.5])
    """Shrinking maximum correspondence distances (m), one ICP stage each (the hypothesis
    search's road ICP, when it ends below its start's robust score at the last range, is run
    again stage by stage, each kept only where it does not lower that score); the last one
    also defines fitness and inlier RMSE."""
    icp_iterations: int = 50
    """Iterations per ICP stage."""
    yaw_search_step_deg: float = 1.0
    """Yaw step (deg) of the hypothesis search (the whole circle without a yaw guess)."""
    yaw_guess_window_deg: float = 10.0
    """With a yaw guess, yaws within +- this (deg) of it are searched."""
    position_search_radius: float = 12.0
    """Half-width (m) of the grid of start positions around the approximate position."""
    position_search_step: float = 1.0
    """Grid step (m) of those start positions."""
    search_points: int = 600
    """About this many source points (a regular subsample) score the hypotheses."""
    refine_points: int = 10000
    """About this many source points (a regular subsample) are used by the refinement."""
    vertical_points: int = 10000
    """At most this many moving on-trail detections (a regular subsample) give the vertical
    fit its moving rows (the detections themselves, not the voxel-averaged source)."""
    search_candidates: int = 6
    """Best distinct hypotheses refined by ICP before choosing."""
    score_tau: float = 3.0
    """Distance (m) off the road at which a point stops counting in the hypothesis score."""
    raster_cell: float = 0.5
    """Cell (m) of the road distance raster used by the hypothesis search."""
    reflection_height: float = 1.0
    """Prior mean (m) of the moving returns' mean height above the road (vehicle bodies:
    bumpers and wheel arches to roofs; unknown for a given radar, estimated in the vertical
    fit with ``reflection_height_sigma``)."""
    reflection_height_sigma: float = 0.4
    """Prior std. dev. (m) of that mean height (0 = fixed at ``reflection_height``)."""
    static_doppler_max: float = 0.15
    """Detections with ``|doppler|`` up to this (m/s) may be static ground returns (kerbs, the
    road's edge) for the vertical fit."""
    static_points: int = 20000
    """At most about this many static detections (a regular subsample) are considered."""
    static_ground_distance: float = 1.0
    """A static ground return lies within this distance (m) of a road point of the ALS."""
    static_lane_clearance: float = 1.5
    """... and at least this far (m) from every lane centre (not a standing vehicle)."""
    static_clearance: float = 1.5
    """... with no ALS obstacle point (wall, tree, pole) within this distance (m) ..."""
    static_clearance_height: float = 0.5
    """... higher than this (m) above the road height there."""
    static_height: float = 0.1
    """Prior mean (m) of the static ground returns' height above the ALS road height (kerb
    edges, road surface)."""
    static_height_sigma: float = 0.05
    """Prior std. dev. (m) of that height (shared by all static returns)."""
    static_noise_range: float = 30.0
    """Range (m) beyond which a static return's height noise grows with its range (elevation
    noise): its row in the vertical fit is divided by ``sqrt(1 + (range / this)^2)``."""
    static_repeats: int = 3
    """A static detection counts as a ground return only with at least this many others within
    ``static_repeat_radius`` (horizontal, in the sensor frame): a fixed scatterer returns
    again and again, a false alarm with a Doppler near 0 stands alone (0 = no such test)."""
    static_repeat_radius: float = 1.0
    """Horizontal radius (m) of that test."""
    static_traffic_radius: float = 0.5
    """Where more than ``static_traffic_max`` moving detections (``|doppler| >=
    doppler_min``) lie within this horizontal radius (m, in S) of a static return, the traffic
    passes: it is a kerb beside a lane or a vehicle standing in a queue."""
    static_traffic_max: int = 10
    """See ``static_traffic_radius``."""
    static_traffic_tolerance: float = 0.25
    """The static returns where the traffic passes count as ground only when their median
    height above the road lies within this (m) of the other static returns' (at least
    ``static_min_points`` of them): kerbs beside a lane do, standing vehicles lie higher."""
    static_beside_radius: float = 2.5
    """The moving detections within this horizontal radius (m, in S) of a static return (its
    nearest 32) are the traffic beside it. The static returns with at least
    ``static_beside_min`` of them count as ground only when, by the median over them, their
    neighbours (within ``static_repeat_radius``) lie lower than the traffic's median height
    by at least half the gap the priors put between vehicle returns and ground returns
    (``(reflection_height - static_height) / 2``): a kerb beside a lane lies lower than the
    bodies passing it, a vehicle standing in a queue returns from its body as the moving ones
    do. Heights levelled in S: neither the sensor height nor the ALS enters."""
    static_beside_min: int = 5
    """See ``static_beside_radius`` (a static return with fewer moving detections beside it
    is not part of that test)."""
    static_consistency: float = 3.0
    """The vertical fit drops the static ground returns when the sensor height they give
    differs from the moving returns' own by more than this many std. devs. of the difference."""
    static_height_gap: float = 0.2
    """... or when the fit puts them less than this (m) below the moving returns' mean height:
    a ground return (kerb, road edge) lies lower than a vehicle body's returns on average
    (bumpers and up); static returns as high as those are standing vehicles or clutter."""
    static_min_points: int = 30
    """Fewer qualifying static returns than this: the vertical fit uses the moving ones only."""
    static_effective_points: float = 100.0
    """The static ground returns weigh like at most this many independent measurements of
    their scatter (1.4826 MAD) in the vertical fit."""
    lane_icp_ranges: list[float] = field(default_factory=lambda: [3.0, 2.0])
    """Correspondence ranges (m) of the lane-centre refinement ICP stages."""
    lane_sample_step: float = 0.25
    """Spacing (m) of the samples on the lanelet centre lines."""
    visible_side_offset: float = 0.3
    """Mean lateral offset (m) of vehicle detections from the lane centre towards the sensor
    (the radar sees the sensor-facing side and nearest corner of each vehicle), for a lane
    seen head-on (the lane fits; the fine stage's and the joint's constant offset)."""
    visible_side_offset_broadside: float = 0.4
    """The same offset (m) for a lane seen broadside: the lane fits shift each lane sample by
    ``visible_side_offset + (visible_side_offset_broadside - visible_side_offset) * a``, ``a``
    the |sin| of the angle between the lane and the line of sight (the side faces the sensor
    more, the farther the line of sight turns from the lane). Measured on the coarse source
    at the true pose: 0.27 m head-on to 0.41 m broadside (fgloc's simulator), 0.35-0.44 m at
    every aspect (the independent generator; docs/experiments.md). = visible_side_offset:
    one constant offset."""
    lane_doppler_gate_deg: float = 20.0
    """The lane-centre fits match a dynamic point moving away from the sensor (Doppler > 0)
    only to lanes driven away from it, one moving towards it only to lanes driven towards it,
    except on lanes within this angle (deg) of square to the line of sight (there the sign says
    nothing: vehicles turn off the lane's direction, Doppler is noisy); 90 = Doppler ignored."""
    height_residual_sigma: float = 0.7
    """Std. dev. (m) of a dynamic point's height about road + reflection height (body height
    spread and elevation noise) in the vertical fit."""
    height_prior_sigma: float = 1.0
    """Std. dev. (m) of the prior on the sensor height (road height + approx_height)."""
    vertical_effective_points: float = 20.0
    """The dynamic points weigh like this many independent height measurements in that fit."""
    tilt_prior_sigma_deg: float = 5.0
    """Std. dev. (deg) of the zero-mean prior on pitch and roll in the vertical fit."""
    alternations: int = 3
    """Rounds of horizontal ICP / vertical fit in the refinement."""
    mode_margin: float = 0.97
    """A distinct pose whose lane-centre score is at least this share of the best one's is
    kept as a mode; every later method registers and compares every mode."""
    mode_rough_margin: float = 0.90
    """The mode search's ends on its ``mode_points`` subsample within this share of the best
    one's are polished with every point (where ``mode_margin`` then applies); below
    ``mode_margin`` because the subsample's score is noisier than the full data's."""
    mode_separation: float = 1.0
    """Modes are at least this far apart (m) or ``mode_separation_deg`` apart in yaw; final
    poses closer than both merge into the better one."""
    mode_separation_deg: float = 1.0
    """Yaw separation (deg) of distinct modes (see ``mode_separation``)."""
    mode_search_radius: float = 10.0
    """Half-width (m) of the lane-level search for other modes around the refined pose
    (lane-width shifts along and across the roads)."""
    mode_search_cell: float = 0.5
    """Cell (m) of the lane-centre score raster of that search (its position step)."""
    mode_search_yaw_deg: float = 3.0
    """Half-width (deg) of that search's yaws around the refined yaw."""
    mode_search_yaw_step_deg: float = 0.5
    """Yaw step (deg) of that search."""
    mode_candidates: int = 12
    """Best distinct peaks of that search carried through the lane-centre ICP."""
    mode_points: int = 600
    """About this many levelled points (a regular subsample) run the mode search's ICPs."""
    mode_search_iterations: int = 15
    """Iterations per ICP stage of the mode search's starts (the kept ends are polished with
    ``icp_iterations``)."""
    max_modes: int = 4
    """At most this many modes (the best first) are carried to the later stages."""
    mode_cost_scale: float = 1.5
    """Scale c (m) of the robust cost that compares the modes' final fits:
    ``min(d, c)^2 / c^2`` per tracked detection, d its distance to the nearest target line
    point of its label."""
    mode_z: float = 3.0
    """A mode is told apart from the best when the best fits better by at least this many
    standard errors over the tracks (``tie_test`` on the per-track cost differences);
    otherwise the result is ``ambiguous``."""
    tie_test: str = "robust"
    """How the per-track cost differences D between a mode and the best are read as standard
    errors (:func:`fgloc.registration.modes.separation_z`): "self-normalized" (``sum D /
    sqrt(sum D^2)``: at most sqrt(k) when k tracks differ, so a few turning tracks never
    outvote many indifferent straight ones) or "robust" (the larger of that and the sum
    without the one most favourable track over an absolute scale, the median track's spread
    with ``tie_noise_floor`` as its least)."""
    tie_noise_floor: float = 1.0
    """Least std. dev. (cost units: detections at the full robust cost) of an indifferent
    track's cost difference in the "robust" ``tie_test``."""
    approx_position_sigma: float = 5.0
    """Std. dev. (m, per axis) of sensor.toml's ``approx_position`` (documented as off by up to
    about 10 m: 2 sigma) as a prior on the sensor's position. It decides only which of the
    modes the data cannot tell apart is reported (``ambiguous`` results), and where on a line of
    tied poses (a road no vehicle turns off) the sensor is reported, with what std. dev."""
    resolved_max_std: float = 0.3
    """The tolerance (m) a ``resolved`` pose must meet, as one standard deviation: a pose the
    modes resolve is still reported ``ambiguous`` when the std. dev. of the sensor position
    along its least determined horizontal direction (the covariance's largest x-y eigenvalue)
    exceeds it -- the data do not pin the pose to it (a T-junction's main road whose position
    only a few turning vehicles fix). Applies to icp, filter-sicp and smoother-sicp (the
    joint's conservative covariance warns of its weak directions instead, ``[joint]
    weak_sigma``). Tied modes that all end within ``mode_separation`` of the reported one (fits
    of the two lane models) count as one resolved pose when the covariance covering them
    passes it (the joint's too). Set it to the tolerance you need; ``inf`` =
    never."""
    consider_side_bias_sigma: float = 0.1
    """Standard deviation (m) of a constant shift of every lane towards the sensor (the
    ``visible_side_offset``'s error) that icp's covariance considers on top of the lane-score
    tie (Schmidt: the lane fit's sensitivity to it; :func:`fgloc.coarse.localize.
    lane_fit_considered`): where every lane passes on one side of the sensor it moves the pose
    across the road. ``[sicp]`` and ``[joint] consider_side_bias_sigma`` likewise. 0 = off."""
    consider_lane_bias_sigma: float = 0.1
    """Standard deviation (m) of a lateral shift shared by the points matched to one lane, one
    per lane, considered in icp's covariance like ``consider_side_bias_sigma``. 0 = off."""
    min_fitness: float = 0.5
    """A final fitness below this marks the result as not converged."""
    default_height: float = 6.0
    """Sensor height above the road (m) used when sensor.toml has no approx_height."""

    def __post_init__(self) -> None:
        for name in ("consider_side_bias_sigma", "consider_lane_bias_sigma",
                     "visible_side_offset", "visible_side_offset_broadside"):
            if getattr(self, name) < 0.0:
                raise ValueError(f"{name} must be >= 0 (m), got {getattr(self, name)}")
        if not 0.0 <= self.lane_doppler_gate_deg <= 90.0:
            raise ValueError("lane_doppler_gate_deg must be in [0, 90], got "
                             f"{self.lane_doppler_gate_deg}")
        if not self.resolved_max_std > 0.0:
            raise ValueError(f"resolved_max_std must be > 0 (m), got {self.resolved_max_std}")
        for name in ("trail_radius", "trail_window"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if self.trail_min_neighbours < 0:
            raise ValueError("trail_min_neighbours must be >= 0, got "
                             f"{self.trail_min_neighbours}")
        for name in ("search_points", "refine_points", "vertical_points"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if not 0.0 < self.mode_rough_margin <= self.mode_margin <= 1.0:
            raise ValueError("need 0 < mode_rough_margin <= mode_margin <= 1, got "
                             f"{self.mode_rough_margin} and {self.mode_margin}")
        if not self.approx_position_sigma > 0.0:
            raise ValueError("approx_position_sigma must be > 0 (m), got "
                             f"{self.approx_position_sigma}")
        if self.tie_test not in TIE_TESTS:
            raise ValueError(f"tie_test must be one of {', '.join(TIE_TESTS)}, got "
                             f"{self.tie_test!r}")
        if not self.tie_noise_floor > 0.0:
            raise ValueError(f"tie_noise_floor must be > 0, got {self.tie_noise_floor}")


@dataclass
class Config:
    """The whole configuration (``fgloc config --dump`` writes it with every default)."""

    seed: int = 0
    """Seed of every random choice fgloc makes."""
    map: MapConfig = field(default_factory=MapConfig)
    coarse: CoarseConfig = field(default_factory=CoarseConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    sicp: SicpConfig = field(default_factory=SicpConfig)
    fine: FineConfig = field(default_factory=FineConfig)
    smoothing: SmoothingConfig = field(default_factory=SmoothingConfig)
    joint: JointConfig = field(default_factory=JointConfig)


# --------------------------------------------------------------------------------------------
# generic dataclass <-> dict with validation
# --------------------------------------------------------------------------------------------
def _type_ok(value: Any, tp: Any) -> tuple[bool, Any]:
    """Check (and mildly coerce: int -> float) a TOML value against a type annotation."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        for arg in typing.get_args(tp):
            if arg is type(None):
                if value is None:
                    return True, None
                continue
            ok, v = _type_ok(value, arg)
            if ok:
                return True, v
        return False, value
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            return False, value
        args = typing.get_args(tp)
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(value) != len(args):
                return False, value
            pairs = list(zip(value, args))
        else:
            pairs = [(v, args[0] if args else Any) for v in value]
        out = []
        for v, a in pairs:
            ok, cv = _type_ok(v, a)
            if not ok:
                return False, value
            out.append(cv)
        return True, (tuple(out) if origin is tuple else out)
    if tp is Any:
        return True, value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return False, value
        return True, float(value)
    if tp is int:
        return (isinstance(value, int) and not isinstance(value, bool)), value
    if tp is bool:
        return isinstance(value, bool), value
    if tp is str:
        return isinstance(value, str), value
    return isinstance(value, tp), value


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def from_dict(cls: type[T], data: dict[str, Any], path: str | Path | None, prefix: str = "") -> T:
    """Build dataclass ``cls`` from a TOML table, rejecting unknown keys and wrong types."""
    if not isinstance(data, dict):
        raise InputError(path, f"expected a table, got {type(data).__name__}", field=prefix or None)
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(data) - names)
    if unknown:
        key = f"{prefix}{unknown[0]}"
        raise InputError(path, f"unknown key (allowed: {', '.join(sorted(names))})", field=key)
    kwargs: dict[str, Any] = {}
    for name, value in data.items():
        tp = hints[name]
        key = f"{prefix}{name}"
        if dataclasses.is_dataclass(tp):
            kwargs[name] = from_dict(tp, value, path, prefix=f"{key}.")
            continue
        ok, coerced = _type_ok(value, tp)
        if not ok:
            raise InputError(
                path, f"expected {_type_name(tp)}, got {type(value).__name__} {value!r}", field=key
            )
        kwargs[name] = coerced
    try:
        return cls(**kwargs)
    except ValueError as exc:  # a section's own validation (__post_init__)
        raise InputError(path, str(exc), field=prefix.rstrip(".") or None) from None


def to_dict(obj: Any) -> dict[str, Any]:
    """Dataclass -> plain dict (tuples become lists), dropping None values (TOML has no null)."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if dataclasses.is_dataclass(v):
            out[f.name] = to_dict(v)
        elif v is not None:
            out[f.name] = list(v) if isinstance(v, tuple) else v
    return out


def read_toml(path: str | Path) -> dict[str, Any]:
    """Parse a TOML file; syntax errors become :class:`InputError` with the line."""
    p = Path(path)
    try:
        with p.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise InputError(p, "file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(p, f"invalid TOML: {exc}") from None
    except UnicodeDecodeError as exc:
        raise InputError(p, f"not UTF-8 text: {exc}") from None


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def dumps_toml(data: dict[str, Any], _prefix: str = "") -> str:
    """Write a nested dict of scalars/lists/tables as TOML (the subset fgloc uses)."""
    lines = [f"{k} = {_toml_value(v)}" for k, v in data.items() if not isinstance(v, dict)]
    for k, v in data.items():
        if isinstance(v, dict):
            name = f"{_prefix}{k}"
            lines.append("")
            lines.append(f"[{name}]")
            lines.append(dumps_toml(v, f"{name}.").strip("\n"))
    return "\n".join(lines).strip("\n") + "\n"


def load_config(path: str | Path | None) -> Config:
    """Load a fgloc config TOML (None: all defaults)."""
    if path is None:
        return Config()
    return from_dict(Config, read_toml(path), path)


def dump_config(cfg: Config) -> str:
    return dumps_toml(to_dict(cfg))
