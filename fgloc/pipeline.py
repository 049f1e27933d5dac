"""The localization pipeline: which stages each method needs (:data:`METHODS`, the one place
that knows), the stages several methods share, computed once per scenario
(:class:`SharedStages`), and the entry points.

``localize(scenario, method, config)`` is the library entry point (the CLI calls it too); it is
``localize_many(scenario, [method], config)[method]``, so one code path runs every method.
Data flows map -> coarse -> tracking -> smoothing -> registration (the subpackages of
:mod:`fgloc`); the stages are imported on use, so ``fgloc config`` needs no gtsam (and no
stage imports Open3D, the benchmarks' peer).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, replace
from functools import partial
from typing import TYPE_CHECKING

import numpy as np

from fgloc.config import Config
from fgloc.errors import FglocError, LocalizationError
from fgloc.geo import transform_points
from fgloc.labels import STRAIGHT
from fgloc.progress import Timer
from fgloc.result import LocalizationResult, json_ready
from fgloc.scenario import Scenario
from fgloc.tracks import TrackSet

if TYPE_CHECKING:
    from fgloc.coarse import CoarseResult
    from fgloc.config import CoarseConfig
    from fgloc.map import TargetCloud
    from fgloc.registration.modes import ModeChoice, ModeFit
    from fgloc.registration.sicp import SemanticTargets


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


class SharedStages:
    """The stages several methods share on one scenario, each computed on first use and kept:
    the target cloud and coarse pose, the filter's tracks and their batch / fixed-lag
    smoothing. ``config`` sets them ([map], [coarse], [tracking], [smoothing]); the tracks are
    placed by T_coarse, or by ``T_placement`` (4x4 S -> L, e.g. the true pose) when given.
    Each stage's seconds are kept with the stages it read, so a method's result can report
    what a run of its own would have spent."""

    def __init__(self, scenario: Scenario, config: Config | None = None,
                 T_placement: np.ndarray | None = None) -> None:
        self.scenario = scenario
        self.config = config or Config()
        self.T_placement = T_placement
        self.seconds: dict[str, float] = {}
        self._cache: dict[str, object] = {}
        self._stage_seconds: dict[str, dict[str, float]] = {}
        self._read: dict[str, set[str]] = {}       # stage -> the stages it read, itself included
        self._readers: list[set[str]] = []         # the stages read by each reading in progress

    def _stage(self, key: str, fn: Callable[[Timer], object]) -> object:
        if key not in self._cache:
            timer = Timer()
            with self.reading() as read:
                self._cache[key] = fn(timer)
            self._read[key] = read | {key}
            self._stage_seconds[key] = dict(timer.seconds)
            self.seconds.update(timer.seconds)
        for readers in self._readers:
            readers.update(self._read[key])
        return self._cache[key]

    @contextmanager
    def reading(self) -> Iterator[set[str]]:
        """Collect the names of the stages read (directly or through another stage) inside the
        ``with`` block into the yielded set."""
        read: set[str] = set()
        self._readers.append(read)
        try:
            yield read
        finally:
            self._readers.pop()

    def seconds_of(self, stages: set[str]) -> dict[str, float]:
        """Seconds of the named stages' steps, in the order they ran."""
        out: dict[str, float] = {}
        for key, secs in self._stage_seconds.items():
            if key in stages:
                out.update(secs)
        return out

    def coarse(self) -> tuple[TargetCloud, CoarseResult]:
        from fgloc.coarse import target_and_coarse

        return self._stage("coarse", lambda t: target_and_coarse(self.scenario, self.config, t))

    def placement(self) -> np.ndarray:
        """4x4 S -> L that places the detections: ``T_placement``, else T_coarse."""
        return self.coarse()[1].T_coarse if self.T_placement is None else self.T_placement

    def tracks(self) -> TrackSet:
        from fgloc.tracking import track_scenario

        T = self.placement()

        def run(timer: Timer) -> TrackSet:
            with timer.stage("tracking"):
                return track_scenario(self.scenario, T, self.config.tracking)
        return self._stage("tracks", run)

    def smoothed(self, name: str | None = None) -> TrackSet:
        """The filter's tracks smoothed by ``name`` (default ``[smoothing] smoother``)."""
        from fgloc.smoothing.run import smooth_tracks

        name = name or self.config.smoothing.smoother
        tracks, T = self.tracks(), self.placement()

        def run(timer: Timer) -> TrackSet:
            with timer.stage(f"smoothing ({name})"):
                return smooth_tracks(self.scenario, tracks, T, name, self.config)
        return self._stage(f"smoothed {name}", run)

    def get(self, name: str, config: Config) -> object:
        """The output of the stage a :class:`Method` names in ``needs``: "coarse" (target cloud,
        coarse result), "tracks" (the filter's), "smoothed" (those smoothed by ``[smoothing]
        smoother``), "joint-smoothed" (by ``config``'s ``[joint] smoother``; None for "none")."""
        if name == "coarse":
            return self.coarse()
        if name == "tracks":
            return self.tracks()
        if name == "smoothed":
            return self.smoothed()
        if name == "joint-smoothed":
            return None if config.joint.smoother == "none" else self.smoothed(config.joint.smoother)
        raise ValueError(f"unknown shared stage {name!r}")


def track(
    scenario: Scenario, config: Config | None = None, *, oracle_pose: bool = False,
    smoother: str = "none",
) -> TrackingRun:
    """Track the vehicles of ``scenario`` with the GP-EOT filter.

    The detections are placed with T_coarse from the coarse stage, or, with ``oracle_pose``,
    with the ground-truth sensor pose, to measure tracking alone (paper section V-A).
    ``smoother`` ("none", "fixed-lag" or "batch", :mod:`fgloc.smoothing`) then refines the
    filter's tracks (same type, same frame). The stages are :class:`SharedStages`'.
    """
    cfg = config or Config()
    T = None
    if oracle_pose:
        if scenario.truth is None:
            raise FglocError("--oracle-pose needs the scenario's ground_truth.json")
        T = scenario.truth.sensor_pose
    st = SharedStages(scenario, cfg, T)
    tracks = st.tracks() if smoother == "none" else st.smoothed(smoother)
    coarse = None if oracle_pose else st.coarse()[1]
    return TrackingRun(tracks, st.placement(), coarse, dict(st.seconds))


def _icp(scn: Scenario, cfg: Config, timer: Timer, coarse_stage: tuple[TargetCloud, CoarseResult]
         ) -> LocalizationResult:
    """``--method icp``, coarse-only localization (the paper's Table II baseline): the best
    coarse mode with the covariance of its lane-score tie, ``ambiguous`` when the coarse stage
    kept several (the covariance then spans them) or the tie is wider than the tolerance
    (:func:`fgloc.registration.modes.coarse_choice`). No stage of its own (``timer``
    unused)."""
    from fgloc.registration.modes import coarse_choice, position_prior

    target, coarse = coarse_stage
    src = transform_points(coarse.T_coarse, coarse.source_xyz)
    diag = {k: v for k, v in asdict(coarse).items() if k not in ("T_coarse", "source_xyz")}
    choice = coarse_choice(coarse, cfg.coarse, position_prior(scn, cfg.coarse))
    res = LocalizationResult(
        method="icp",
        frame=scn.frame,
        T_local=choice.best.T_local,
        converged=coarse.converged,
        covariance=choice.covariance(cfg.coarse),
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
        weak_direction=choice.weak_summary(scn.frame),
    )
    return valley_result(res, replace(choice, valley=coarse.valley), cfg.coarse, coarse)


def choice_of(res: LocalizationResult) -> ModeChoice:
    """The comparison ``res`` reports: its mode fits (the reported one first) with their
    ``separation_z`` and ``tied`` flags from ``res.modes`` (``agreed`` when several tied ones
    were reported resolved)."""
    from fgloc.registration.modes import RESOLVED, ModeChoice

    tied = [k for k, m in enumerate(res.modes) if m["tied"]]
    return ModeChoice(list(res.mode_fits), np.array([float(m["separation_z"]) for m in res.modes]),
                      tied, agreed=len(tied) > 1 and res.status == RESOLVED)


def valley_result(res: LocalizationResult, choice: ModeChoice, cfg: CoarseConfig,
                  coarse: CoarseResult) -> LocalizationResult:
    """``res`` (reporting ``choice`` without its valley) reporting the valley of ``choice``:
    the pose at its posterior mean (:meth:`ModeChoice.reported`, the height of the coarse mode
    nearest there), the covariance over it, the valley in ``valley`` and its warning in place
    of the modes'; the tracks and their source cloud moved with the pose. ``res`` itself
    when ``choice`` has no valley."""
    from fgloc.registration.modes import placed_where_ended

    if choice.valley is None:
        return res
    x, y, _ = choice.reported()
    origin = min(choice.fits, key=lambda f: np.hypot(*(f.sensor[:2] - choice.valley.origin)))
    T_local = np.array(origin.T_local, dtype=float)
    T_local[:2, 3] = (x, y)
    T_local, z_std = placed_where_ended(coarse, T_local)
    shift = np.eye(3)
    shift[:2, 2] = (x, y) - origin.sensor[:2]
    src, tracks = res.source_xyz, res.tracks
    if tracks is not None:
        moved = shift @ origin.T_fine
        if src is not None:
            src = src.copy()
            src[:, :2] = transform_points(moved @ np.linalg.inv(tracks.T_frame_to_L), src[:, :2])
        tracks = replace(tracks, T_frame_to_L=moved)
    prefix = f"{res.method}: ambiguous"
    return replace(res, T_local=T_local, covariance=choice.covariance(cfg), z_std=z_std,
                   warnings=[*(w for w in res.warnings if not w.startswith(prefix)),
                             *choice.warnings(res.method)],
                   valley=choice.valley_summary(res.frame), source_xyz=src, tracks=tracks)


def _with_valley(scn: Scenario, cfg: Config, coarse_stage: tuple[TargetCloud, CoarseResult],
                 tracks: TrackSet, res: LocalizationResult, visible_side: bool
                 ) -> LocalizationResult:
    """``res`` of a method on ``tracks`` reporting the valley of its tied modes
    (:func:`fgloc.registration.modes.track_valley`, scored on the source cloud of ``tracks``
    against each mode's fine targets, with the measured visible sides when ``visible_side``)
    when they are samples of one; else ``res`` itself."""
    from fgloc.registration.fine import mode_targets
    from fgloc.registration.modes import mode_track_costs, position_prior, track_valley
    from fgloc.registration.source import build_source_cloud

    if sum(bool(m["tied"]) for m in res.modes) < 2:
        return res
    target, coarse = coarse_stage
    src = build_source_cloud(scn, tracks, coarse.T_coarse, cfg)
    side = src.visible_side if visible_side else None

    built: dict[int, SemanticTargets] = {}     # id(fit) -> its targets, KD-trees built once

    def cost_at(fit: ModeFit, T: np.ndarray) -> np.ndarray:
        if id(fit) not in built:
            built[id(fit)] = mode_targets(scn, target, cfg, coarse, fit.start, fit.lanes, side)
        return mode_track_costs(src, built[id(fit)], T, cfg)

    choice = choice_of(res)
    valley = track_valley(choice, cost_at, position_prior(scn, cfg.coarse), cfg.coarse)
    return valley_result(res, replace(choice, valley=valley), cfg.coarse, coarse)


def _register(scn: Scenario, cfg: Config, timer: Timer,
              coarse_stage: tuple[TargetCloud, CoarseResult], tracks: TrackSet, *, method: str
              ) -> LocalizationResult:
    """``--method filter-sicp`` / ``smoother-sicp``: the fine stage on the given tracks
    (:func:`fgloc.registration.fine.register_tracks`)."""
    from fgloc.registration.fine import register_tracks

    res = register_tracks(scn, cfg, *coarse_stage, tracks, timer, method=method)
    with timer.stage("valley"):
        return _with_valley(scn, cfg, coarse_stage, tracks, res, visible_side=True)


def _joint(scn: Scenario, cfg: Config, timer: Timer,
           coarse_stage: tuple[TargetCloud, CoarseResult], tracks: TrackSet,
           smoothed: TrackSet | None, *, start: LocalizationResult) -> LocalizationResult:
    """``--method joint`` (:mod:`fgloc.registration.joint`; gtsam is imported on use)."""
    from fgloc.registration.joint import joint_from_tracks

    res = joint_from_tracks(scn, cfg, *coarse_stage, tracks, timer, start=start,
                            smoothed=smoothed)
    with timer.stage("valley"):
        return _with_valley(scn, cfg, coarse_stage, tracks, res, visible_side=False)


@dataclass(frozen=True)
class Method:
    """How the pipeline runs one method.

    needs: the shared stages whose outputs ``run`` takes, in order (names of
    :meth:`SharedStages.get`); start: the method whose result ``run`` refines (passed as
    ``start=``), or None; run: the method's own stage,
    ``run(scenario, config, timer, *outputs of needs[, start=result])``.
    """

    needs: tuple[str, ...]
    run: Callable[..., LocalizationResult]
    start: str | None = None


#: method name -> what it needs and its own stage: the one place that knows which stages a
#: method runs; ``fgloc localize --method`` offers exactly these keys.
METHODS: dict[str, Method] = {
    "icp": Method(("coarse",), _icp),
    "filter-sicp": Method(("coarse", "tracks"), partial(_register, method="filter-sicp")),
    "smoother-sicp": Method(("coarse", "smoothed"), partial(_register, method="smoother-sicp")),
    "joint": Method(("coarse", "tracks", "joint-smoothed"), _joint, start="filter-sicp"),
}


def localize(
    scenario: Scenario, method: str = "icp", config: Config | None = None
) -> LocalizationResult:
    """Localize the sensor of ``scenario`` with ``method``; returns the pose in L and UTM.

    ``localize_many(scenario, [method], config)[method]``. Raises
    :class:`fgloc.errors.LocalizationError` when the data cannot support a pose.
    """
    return localize_many(scenario, [method], config)[method]


def localize_many(scenario: Scenario, methods: list[str], config: Config | None = None,
                  stages: SharedStages | None = None) -> dict[str, LocalizationResult]:
    """Localize ``scenario`` with every method in ``methods`` (names of :data:`METHODS`),
    computing what they share once: the shared stages (target cloud and coarse pose, the
    filter's tracks, the smoothing) and the result a method starts from (joint starts from
    filter-sicp's). Each result's ``timings`` holds the shared stages it read and the own
    stages of it and of the method it starts from, i.e. what a run of its own reports.

    ``stages`` reuses shared stages across calls (e.g. a sweep over ``[fine]`` or ``[joint]``
    settings: they must have been built with the same [map], [coarse], [tracking] and
    [smoothing]; only ``config``'s other sections are read here)."""
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise FglocError(f"unknown method {unknown[0]!r}; available: {', '.join(METHODS)}")
    cfg = config or Config()
    st = stages or SharedStages(scenario, cfg)
    done: dict[str, tuple[LocalizationResult, set[str], dict[str, float]]] = {}

    def run(method: str) -> tuple[LocalizationResult, set[str], dict[str, float]]:
        """(result, shared stages read, own seconds) of ``method`` and of what it starts
        from."""
        if method not in done:
            spec = METHODS[method]
            read: set[str] = set()
            own: dict[str, float] = {}
            kw = {}
            if spec.start is not None:
                try:
                    kw["start"], read, own = run(spec.start)
                except LocalizationError as exc:
                    raise LocalizationError(f"{method} starts from {spec.start}'s result, "
                                            f"which failed: {exc}") from exc
            with st.reading() as now:
                inputs = [st.get(name, cfg) for name in spec.needs]
            timer = Timer()
            res = spec.run(scenario, cfg, timer, *inputs, **kw)
            done[method] = (res, read | now, {**own, **timer.seconds})
        return done[method]

    out = {}
    for method in methods:
        res, read, own = run(method)
        res.timings = {**st.seconds_of(read), **own}
        res.tilt_std = st.coarse()[1].tilt_std      # every method keeps the coarse tilt
        out[method] = res
    return out
