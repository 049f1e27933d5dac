"""The localization pipeline: one function per method, chosen by name from one registry.

``localize(scenario, method, config)`` is the library entry point; the CLI calls it too.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from fgloc.config import Config
from fgloc.errors import FglocError
from fgloc.geo import transform_points
from fgloc.labels import STRAIGHT
from fgloc.progress import Timer
from fgloc.registration.fine import run_filter_sicp
from fgloc.result import LocalizationResult, json_ready
from fgloc.scenario import Scenario
from fgloc.smoothing.run import run_smoother_sicp, smooth_tracks
from fgloc.tracks import TrackSet

if TYPE_CHECKING:
    from fgloc.coarse import CoarseResult
    from fgloc.map import TargetCloud

MethodFn = Callable[[Scenario, Config, Timer], LocalizationResult]


@dataclass
class TrackingRun:
    """Tracks of a scenario and the pose that placed the detections.

    T_placement: 4x4 S -> L used to place the detections (T_coarse, or the true pose with
    ``oracle_pose``); tracks are in frame C of that placement. coarse: the coarse result, or
    None with ``oracle_pose``.
    """

    tracks: TrackSet
    T_placement: np.ndarray
    coarse: CoarseResult | None
    timings: dict[str, float] = field(default_factory=dict)


def track(
    scenario: Scenario, config: Config | None = None, *, oracle_pose: bool = False,
    smoother: str = "none",
) -> TrackingRun:
    """Track the vehicles of ``scenario`` with the GP-EOT filter.

    The detections are placed with T_coarse from the coarse stage, or, with ``oracle_pose``,
    with the ground-truth sensor pose, to measure tracking alone (paper section V-A).
    ``smoother`` ("none", "fixed-lag" or "batch", :mod:`fgloc.smoothing`) then refines the
    filter's tracks (same type, same frame).
    """
    from fgloc.coarse import target_and_coarse
    from fgloc.tracking import track_scenario

    cfg = config or Config()
    timer = Timer()
    coarse = None
    if oracle_pose:
        if scenario.truth is None:
            raise FglocError("--oracle-pose needs the scenario's ground_truth.json")
        T = scenario.truth.sensor_pose
    else:
        _, coarse = target_and_coarse(scenario, cfg, timer)
        T = coarse.T_coarse
    with timer.stage("tracking"):
        tracks = track_scenario(scenario, T, cfg.tracking)
    if smoother != "none":
        with timer.stage(f"smoothing ({smoother})"):
            tracks = smooth_tracks(scenario, tracks, T, smoother, cfg)
    return TrackingRun(tracks, T, coarse, dict(timer.seconds))


def _run_icp(scn: Scenario, cfg: Config, timer: Timer) -> LocalizationResult:
    """Coarse-only localization: accumulated dynamic points + ICP (the paper's Table II
    baseline)."""
    from fgloc.coarse import target_and_coarse

    return _icp_result(scn, cfg, *target_and_coarse(scn, cfg, timer))


def _icp_result(scn: Scenario, cfg: Config, target: TargetCloud, coarse: CoarseResult
                ) -> LocalizationResult:
    """The icp method's result from the shared target cloud and coarse stage: the best coarse
    mode, ``ambiguous`` when the coarse stage kept several (the covariance then spans them)."""
    from fgloc.registration.modes import RESOLVED, coarse_choice

    src = transform_points(coarse.T_coarse, coarse.source_xyz)
    diag = {k: v for k, v in asdict(coarse).items() if k not in ("T_coarse", "source_xyz")}
    choice = coarse_choice(coarse)
    return LocalizationResult(
        method="icp",
        frame=scn.frame,
        T_local=choice.best.T_local,
        converged=coarse.converged,
        covariance=None if choice.status == RESOLVED else choice.covariance(cfg.coarse),
        diagnostics={"target": target.summary(), "coarse": json_ready(diag)},
        warnings=[*target.warnings, *coarse.warnings, *choice.warnings("icp")],
        config=cfg,
        source_xyz=src,
        source_label=np.full(len(src), STRAIGHT, dtype=np.int8),
        target=target,
        status=choice.status,
        modes=json_ready(choice.summary(scn.frame)),
        mode_fits=choice.fits,
        z_std=choice.best.z_std,
    )


def _run_joint(scn: Scenario, cfg: Config, timer: Timer) -> LocalizationResult:
    """``--method joint`` (:mod:`fgloc.registration.joint`; gtsam is imported on use)."""
    from fgloc.registration.joint import run_joint

    return run_joint(scn, cfg, timer)


#: method name -> implementation; ``fgloc localize --method`` offers exactly these keys.
METHODS: dict[str, MethodFn] = {"icp": _run_icp, "filter-sicp": run_filter_sicp,
                                "smoother-sicp": run_smoother_sicp, "joint": _run_joint}


def localize(
    scenario: Scenario, method: str = "icp", config: Config | None = None
) -> LocalizationResult:
    """Localize the sensor of ``scenario`` with ``method``; returns the pose in L and UTM.

    Raises :class:`fgloc.errors.LocalizationError` when the data cannot support a pose.
    """
    if method not in METHODS:
        raise FglocError(f"unknown method {method!r}; available: {', '.join(METHODS)}")
    cfg = config or Config()
    timer = Timer()
    res = METHODS[method](scenario, cfg, timer)
    res.timings = dict(timer.seconds)
    return res


class SharedStages:
    """The stages several methods share on one scenario, each computed on first use and kept:
    the target cloud and coarse pose, the filter's tracks (placed by T_coarse) and their
    batch / fixed-lag smoothing. ``config`` sets them ([map], [coarse], [tracking],
    [smoothing]); the stage seconds are kept per stage, so a method's result can report what
    a run of its own would have spent."""

    def __init__(self, scenario: Scenario, config: Config | None = None) -> None:
        self.scenario = scenario
        self.config = config or Config()
        self.seconds: dict[str, float] = {}
        self._cache: dict[str, object] = {}

    def _stage(self, key: str, fn: Callable[[Timer], object]) -> object:
        if key not in self._cache:
            timer = Timer()
            self._cache[key] = fn(timer)
            self.seconds.update(timer.seconds)
        return self._cache[key]

    def coarse(self) -> tuple[TargetCloud, CoarseResult]:
        from fgloc.coarse import target_and_coarse

        return self._stage("coarse", lambda t: target_and_coarse(self.scenario, self.config, t))

    def tracks(self) -> TrackSet:
        from fgloc.tracking import track_scenario

        _, coarse = self.coarse()

        def run(timer: Timer) -> TrackSet:
            with timer.stage("tracking"):
                return track_scenario(self.scenario, coarse.T_coarse, self.config.tracking)
        return self._stage("tracks", run)

    def smoothed(self, name: str | None = None) -> TrackSet:
        """The filter's tracks smoothed by ``name`` (default ``[smoothing] smoother``)."""
        _, coarse = self.coarse()
        name = name or self.config.smoothing.smoother

        def run(timer: Timer) -> TrackSet:
            with timer.stage(f"smoothing ({name})"):
                return smooth_tracks(self.scenario, self.tracks(), coarse.T_coarse, name,
                                     self.config)
        return self._stage(f"smoothed {name}", run)

    def times(self, *stages: str) -> dict[str, float]:
        """Seconds of the named shared stages (those that ran)."""
        return {k: v for k, v in self.seconds.items() if k in stages}


_SHARED = {"icp": ("target cloud", "coarse ICP"),
           "filter-sicp": ("target cloud", "coarse ICP", "tracking")}
_SHARED["joint"] = _SHARED["filter-sicp"]


def localize_many(scenario: Scenario, methods: list[str], config: Config | None = None,
                  stages: SharedStages | None = None) -> dict[str, LocalizationResult]:
    """Localize ``scenario`` with every method in ``methods`` (names of :data:`METHODS`),
    computing the stages they share once: the target cloud and coarse pose, the filter's
    tracks, the smoothing, and filter-sicp's registration (joint starts from it). Results are
    the same as separate :func:`localize` calls; each one's ``timings`` holds the shared
    stages it depends on plus its own, i.e. what a separate run would report.

    ``stages`` reuses shared stages across calls (e.g. a sweep over ``[fine]`` or ``[joint]``
    settings: they must have been built with the same [map], [coarse], [tracking] and
    [smoothing]; only ``config``'s other sections are read here)."""
    from fgloc.registration.fine import register_tracks
    from fgloc.registration.joint import joint_from_tracks

    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise FglocError(f"unknown method {unknown[0]!r}; available: {', '.join(METHODS)}")
    cfg = config or Config()
    st = stages or SharedStages(scenario, cfg)
    out: dict[str, LocalizationResult] = {}
    own: dict[str, dict[str, float]] = {}

    def fine(method: str, tracks: TrackSet) -> LocalizationResult:
        timer = Timer()
        target, coarse = st.coarse()
        res = register_tracks(scenario, cfg, target, coarse, tracks, timer, method=method)
        own[method] = dict(timer.seconds)
        return res

    for method in methods:
        if method == "icp":
            out[method], own[method] = _icp_result(scenario, cfg, *st.coarse()), {}
        elif method == "smoother-sicp":
            out[method] = fine(method, st.smoothed())
        elif "filter-sicp" not in out:          # filter-sicp, or joint's start
            out["filter-sicp"] = fine("filter-sicp", st.tracks())
        if method == "joint":
            timer = Timer()
            target, coarse = st.coarse()
            smoother = cfg.joint.smoother
            smoothed = None if smoother == "none" else st.smoothed(smoother)
            out[method] = joint_from_tracks(scenario, cfg, target, coarse, st.tracks(), timer,
                                            start=out["filter-sicp"], smoothed=smoothed)
            own[method] = {**own["filter-sicp"], **timer.seconds}
    smoothing = f"smoothing ({cfg.smoothing.smoother})"
    for method in methods:
        shared = _SHARED.get(method, (*_SHARED["filter-sicp"], smoothing))
        if method == "joint" and cfg.joint.smoother != "none":
            shared = (*shared, f"smoothing ({cfg.joint.smoother})")
        out[method].timings = {**st.times(*shared), **own[method]}
    return {m: out[m] for m in methods}
