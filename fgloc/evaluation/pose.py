"""Pose errors against ground truth (the paper's Table I row and the vertical components)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from fgloc.geo import pose_from_se3, wrap_angle


@dataclass(frozen=True)
class PoseError:
    """Absolute errors of an estimated sensor pose: metres and degrees.

    dx, dy are along grid east and north; dyaw, dpitch, droll are wrapped to [0, 180].
    """

    dx: float
    dy: float
    d2d: float
    dyaw_deg: float
    dz: float
    dpitch_deg: float
    droll_deg: float

    def to_json(self) -> dict[str, float]:
        return asdict(self)

    def table(self) -> str:
        """Two-line text table (header + values)."""
        head = f"{'|dx| m':>8} {'|dy| m':>8} {'2D m':>8} {'|dyaw| deg':>11} {'|dz| m':>8} "
        head += f"{'|dpitch| deg':>13} {'|droll| deg':>12}"
        row = f"{self.dx:8.3f} {self.dy:8.3f} {self.d2d:8.3f} {self.dyaw_deg:11.3f} "
        row += f"{self.dz:8.3f} {self.dpitch_deg:13.3f} {self.droll_deg:12.3f}"
        return head + "\n" + row


def pose_error(T_est: np.ndarray, T_true: np.ndarray) -> PoseError:
    """Errors of ``T_est`` against ``T_true`` (both 4x4 sensor -> the same frame).

    Both poses must be in the same frame; pass local-frame poses (never subtract raw UTM
    numbers in float32).
    """
    e = pose_from_se3(T_est)
    g = pose_from_se3(T_true)
    dx, dy, dz = (abs(e[i] - g[i]) for i in range(3))
    dang = [abs(float(np.rad2deg(wrap_angle(e[i] - g[i])))) for i in range(3, 6)]
    return PoseError(
        dx=float(dx),
        dy=float(dy),
        d2d=float(np.hypot(dx, dy)),
        dyaw_deg=dang[0],
        dz=float(dz),
        dpitch_deg=dang[1],
        droll_deg=dang[2],
    )


def pose_error_vector(T_est: np.ndarray, T_true: np.ndarray) -> np.ndarray:
    """(3,) signed planar error of ``T_est`` against ``T_true`` (4x4, the same frame): x (m),
    y (m), yaw (rad, wrapped) of the estimate minus the truth, in the order of result.json's
    ``covariance`` (for NEES ``e @ inv(cov) @ e``)."""
    e = pose_from_se3(T_est)
    g = pose_from_se3(T_true)
    return np.array([e[0] - g[0], e[1] - g[1], float(wrap_angle(e[3] - g[3]))])
