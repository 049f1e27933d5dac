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
from fgloc.fine import run_filter_sicp
from fgloc.geo import transform_points
from fgloc.labels import STRAIGHT
from fgloc.progress import Timer
from fgloc.result import LocalizationResult, json_ready
from fgloc.scenario import Scenario
from fgloc.smoothing.run import run_smoother_sicp, smooth_tracks
from fgloc.tracks import TrackSet

if TYPE_CHECKING:
    from fgloc.coarse import CoarseResult

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

    target, coarse = target_and_coarse(scn, cfg, timer)
    src = transform_points(coarse.T_coarse, coarse.source_xyz)
    diag = {k: v for k, v in asdict(coarse).items() if k not in ("T_coarse", "source_xyz")}
    return LocalizationResult(
        method="icp",
        frame=scn.frame,
        T_local=coarse.T_coarse,
        converged=coarse.converged,
        diagnostics={"target": target.summary(), "coarse": json_ready(diag)},
        warnings=[*target.warnings, *coarse.warnings],
        config=cfg,
        source_xyz=src,
        source_label=np.full(len(src), STRAIGHT, dtype=np.int8),
        target=target,
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
