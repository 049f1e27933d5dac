"""The localization result: the pose, its uncertainty, per-stage diagnostics; JSON in and out."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from fgloc.config import Config, to_dict
from fgloc.errors import InputError
from fgloc.geo import LocalFrame, pose_from_se3, to_latlon, true_heading_deg
from fgloc.io.json_file import read_json

if TYPE_CHECKING:
    from fgloc.map import TargetCloud
    from fgloc.registration.modes import ModeFit
    from fgloc.tracks import TrackSet


def json_ready(value: Any) -> Any:
    """A diagnostics value with numpy arrays and scalars turned into JSON types (recursively);
    a NaN or infinite number becomes None (JSON has no such numbers: a SICP left with no
    correspondences has no RMSE)."""
    if isinstance(value, np.ndarray):
        clean = value.dtype.kind in "biu" or (value.dtype.kind == "f"
                                              and bool(np.isfinite(value).all()))
        return value.tolist() if clean else json_ready(value.tolist())
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return json_ready(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    return value


@dataclass
class LocalizationResult:
    """What a localization method found.

    T_local: 4x4 sensor frame S -> local frame L. covariance: 3x3 of (x [m], y [m], yaw [rad])
    in L, or None when the method gives none. diagnostics: per stage, JSON-ready dicts.
    source_xyz: (N, 3) float64 source points in L (after the final pose), for reports.
    source_label: (N,) int label codes of those points (all STRAIGHT when unlabelled).
    target: the labelled target cloud the pose was registered against (for reports).
    tracks: the vehicle tracks the method used (with ``T_frame_to_L`` set), or None.
    status: "resolved", or "ambiguous" when the coarse stage's modes could not be told apart
    (:mod:`fgloc.registration.modes`; the pose is the best mode's, the covariance covers every
    mode). modes: JSON-ready summary of every mode (best first;
    :meth:`fgloc.registration.modes.ModeChoice.summary`). mode_fits: the modes' fits
    (:class:`fgloc.registration.modes.ModeFit`, best first; the joint starts from them).
    z_std: std. dev. (m) of the sensor height, or None when the method gives none. tilt_std:
    std. devs. (rad) of the pitch and the roll (the coarse vertical fit's, which every method
    keeps; :attr:`fgloc.coarse.CoarseResult.tilt_std`), or None. valley:
    JSON-ready line the tied modes are samples of, along which the data do not fix the pose
    (:meth:`fgloc.registration.modes.ModeChoice.valley_summary`), or None. weak_direction:
    JSON-ready direction in which the only mode left is not pinned to ``coarse.
    resolved_max_std`` (:meth:`fgloc.registration.modes.ModeChoice.weak_summary`), or None.
    """

    method: str
    frame: LocalFrame
    T_local: np.ndarray
    converged: bool
    covariance: np.ndarray | None = None
    diagnostics: dict[str, Any] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    config: Config = field(default_factory=Config)
    source_xyz: np.ndarray | None = None
    source_label: np.ndarray | None = None
    target: TargetCloud | None = None
    tracks: TrackSet | None = None
    status: str = "resolved"
    modes: list[dict[str, Any]] = field(default_factory=list)
    mode_fits: list[ModeFit] = field(default_factory=list)
    z_std: float | None = None
    tilt_std: tuple[float, float] | None = None
    valley: dict[str, Any] | None = None
    weak_direction: dict[str, Any] | None = None

    @property
    def crs(self) -> str:
        return self.frame.crs

    @property
    def T_utm(self) -> np.ndarray:
        """4x4 sensor -> world (UTM) transform, float64."""
        return self.frame.pose_to_world(self.T_local)

    def to_json(self) -> dict[str, Any]:
        """The result.json document (see docs/formats.md, "Outputs")."""
        x, y, z, yaw, pitch, roll = pose_from_se3(self.T_utm)
        lat, lon = to_latlon(self.crs, x, y)
        doc: dict[str, Any] = {
            "method": self.method,
            "status": self.status,
            "converged": bool(self.converged),
            "crs": self.crs,
            "sensor": {
                "x": x,
                "y": y,
                "z": z,
                "yaw_deg": math.degrees(yaw),
                "pitch_deg": math.degrees(pitch),
                "roll_deg": math.degrees(roll),
            },
            "T_utm": self.T_utm.tolist(),
            "lat": lat,
            "lon": lon,
            "true_heading_deg": true_heading_deg(self.crs, x, y, yaw),
            "covariance": None if self.covariance is None else np.asarray(self.covariance).tolist(),
            "covariance_order": ["x_m", "y_m", "yaw_rad"],
            "z_std_m": self.z_std,
            "pitch_std_deg": None if self.tilt_std is None else math.degrees(self.tilt_std[0]),
            "roll_std_deg": None if self.tilt_std is None else math.degrees(self.tilt_std[1]),
            "modes": self.modes,
            "valley": self.valley,
            "weak_direction": self.weak_direction,
            "local_origin": list(self.frame.origin),
            "diagnostics": self.diagnostics,
            "timings_s": self.timings,
            "warnings": self.warnings,
            "config": to_dict(self.config),
        }
        return doc


@dataclass(frozen=True)
class SavedPose:
    """The pose read back from a result.json: 4x4 sensor -> world, the CRS, the method, whether
    it converged and its status ("resolved" or "ambiguous")."""

    crs: str
    T_utm: np.ndarray
    method: str
    converged: bool
    status: str = "resolved"


def read_result_json(path: str | Path) -> SavedPose:
    """Read the pose of a result.json written by fgloc (validated)."""
    p = Path(path)
    doc = read_json(p)
    if not isinstance(doc, dict):
        raise InputError(p, "expected a JSON object")
    for key in ("crs", "T_utm"):
        if key not in doc:
            raise InputError(p, "missing key", field=key)
    T = np.asarray(doc["T_utm"], dtype=float) if isinstance(doc["T_utm"], list) else None
    if T is None or T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InputError(p, "expected a finite 4x4 matrix", field="T_utm")
    if not isinstance(doc["crs"], str):
        raise InputError(p, "expected a CRS string", field="crs")
    return SavedPose(
        crs=doc["crs"],
        T_utm=T,
        method=str(doc.get("method", "unknown")),
        converged=bool(doc.get("converged", True)),
        status=str(doc.get("status", "resolved")),
    )
