"""Coordinate frames and rigid transforms in the DESIGN.md convention.

Frames
------
* World ``W``: a projected CRS (default EPSG:25832), metres, (E, N, up).
* Local ``L``: world minus an origin (E0, N0, Z0) rounded to metres; all computation runs here
  so no arithmetic touches ~5e6 m numbers.
* Sensor ``S``: x boresight, y left, z up.

Rotations are ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (radians). Yaw is CCW from grid east.
With ``Ry(pitch)`` a positive pitch tilts the boresight down (the x axis maps to
(cos p, 0, -sin p)), matching ground_truth.json's "pitch_deg > 0 means the boresight points down".
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from pyproj import CRS, Proj, Transformer


# --------------------------------------------------------------------------------------------
# angles
# --------------------------------------------------------------------------------------------
def wrap_angle(a: np.ndarray | float) -> np.ndarray | float:
    """Wrap radians to [-pi, pi); scalars stay Python floats."""
    r = (np.asarray(a, dtype=float) + np.pi) % (2.0 * np.pi) - np.pi
    return float(r) if np.ndim(r) == 0 else r


# --------------------------------------------------------------------------------------------
# SO(3) / SE(3)
# --------------------------------------------------------------------------------------------
def rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_from_ypr(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """``R = Rz(yaw) Ry(pitch) Rx(roll)`` (radians)."""
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)


def ypr_from_rot(R: np.ndarray) -> tuple[float, float, float]:
    """Inverse of :func:`rot_from_ypr`; returns (yaw, pitch, roll) in radians.

    pitch is in [-pi/2, pi/2]; at gimbal lock (|pitch| = pi/2) roll is set to 0.
    """
    R = np.asarray(R, dtype=float)
    pitch = float(np.arcsin(np.clip(-R[2, 0], -1.0, 1.0)))
    if abs(abs(R[2, 0]) - 1.0) < 1e-12:
        yaw = float(np.arctan2(-R[0, 1], R[1, 1]))
        return yaw, pitch, 0.0
    yaw = float(np.arctan2(R[1, 0], R[0, 0]))
    roll = float(np.arctan2(R[2, 1], R[2, 2]))
    return yaw, pitch, roll


def se3(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """4x4 homogeneous matrix from a rotation and a translation."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, dtype=float).reshape(3)
    return T


def se3_from_pose(
    x: float, y: float, z: float, yaw: float, pitch: float, roll: float
) -> np.ndarray:
    """4x4 sensor-to-frame transform from position (m) and angles (rad)."""
    return se3(rot_from_ypr(yaw, pitch, roll), [x, y, z])


def pose_from_se3(T: np.ndarray) -> tuple[float, float, float, float, float, float]:
    """(x, y, z, yaw, pitch, roll) of a 4x4 transform; angles in radians."""
    yaw, pitch, roll = ypr_from_rot(T[:3, :3])
    return float(T[0, 3]), float(T[1, 3]), float(T[2, 3]), yaw, pitch, roll


def se3_inv(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform."""
    R = T[:3, :3]
    return se3(R.T, -R.T @ T[:3, 3])


def transform_points(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Apply a 4x4 (to (N,3)) or 3x3 SE(2) (to (N,2)) transform to row points."""
    p = np.asarray(p, dtype=float)
    d = T.shape[0] - 1
    return p @ T[:d, :d].T + T[:d, d]


# --------------------------------------------------------------------------------------------
# SE(2)
# --------------------------------------------------------------------------------------------
def se2(x: float, y: float, yaw: float) -> np.ndarray:
    """3x3 homogeneous SE(2) matrix."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])


def se2_params(T: np.ndarray) -> tuple[float, float, float]:
    """(x, y, yaw) of a 3x3 SE(2) matrix."""
    return float(T[0, 2]), float(T[1, 2]), float(np.arctan2(T[1, 0], T[0, 0]))


def se2_inv(T: np.ndarray) -> np.ndarray:
    x, y, yaw = se2_params(T)
    R = T[:2, :2]
    t = -R.T @ np.array([x, y])
    return se2(t[0], t[1], -yaw)


def se2_to_se3(T2: np.ndarray) -> np.ndarray:
    """Lift SE(2) to SE(3): rotation about z, z translation 0 (the paper's T~_fine)."""
    x, y, yaw = se2_params(T2)
    return se3(rot_z(yaw), [x, y, 0.0])


# --------------------------------------------------------------------------------------------
# CRS and the local frame
# --------------------------------------------------------------------------------------------
@lru_cache(maxsize=64)
def transformer(src: str, dst: str) -> Transformer:
    """Cached pyproj transformer, always (x=lon/E, y=lat/N) order."""
    return Transformer.from_crs(CRS.from_user_input(src), CRS.from_user_input(dst), always_xy=True)


def parse_crs(text: str) -> CRS:
    """Parse a CRS string (``EPSG:25832``, WKT, ...); raises ValueError with pyproj's reason."""
    try:
        return CRS.from_user_input(text)
    except Exception as exc:  # pyproj raises CRSError, a ValueError subclass in most versions
        raise ValueError(f"not a valid CRS: {text!r} ({exc})") from exc


def utm_zone(crs: CRS | str) -> int | None:
    """UTM zone number of a projected UTM CRS, else None."""
    crs = CRS.from_user_input(crs)
    name = crs.utm_zone
    if not name:
        return None
    return int(name[:-1])


def natural_utm_zone(lon_deg: float) -> int:
    """The standard 6-degree UTM zone containing a longitude (no Norway/Svalbard exceptions)."""
    return int(np.floor((lon_deg + 180.0) / 6.0)) % 60 + 1


def same_crs(a: str | CRS, b: str | CRS) -> bool:
    """True when two CRS definitions describe the same horizontal system."""
    ca, cb = CRS.from_user_input(a), CRS.from_user_input(b)
    if ca == cb:
        return True
    ea, eb = ca.to_epsg(min_confidence=70), cb.to_epsg(min_confidence=70)
    if ea is not None and ea == eb:
        return True
    ha = ca.sub_crs_list[0] if ca.is_compound else ca
    hb = cb.sub_crs_list[0] if cb.is_compound else cb
    return ha.equals(hb, ignore_axis_order=True)


def horizontal_crs(crs: str | CRS) -> CRS:
    """The horizontal part of a (possibly compound) CRS."""
    c = CRS.from_user_input(crs)
    return c.sub_crs_list[0] if c.is_compound else c


def meridian_convergence(crs: str, east: float, north: float) -> float:
    """Meridian convergence (radians) at a world point: angle from true north to grid north.

    Positive east of the central meridian in the northern hemisphere. A grid yaw (CCW from grid
    east) becomes a true heading (clockwise from true north) with :func:`true_heading_deg`.
    """
    hcrs = horizontal_crs(crs)
    lon, lat = transformer(hcrs.to_string(), "EPSG:4326").transform(east, north)
    factors = Proj(hcrs).get_factors(lon, lat)
    return float(np.deg2rad(factors.meridian_convergence))


def true_heading_deg(crs: str, east: float, north: float, yaw: float) -> float:
    """True heading (degrees clockwise from true north, [0, 360)) of a grid yaw (radians CCW
    from grid east) at a world point."""
    grid_azimuth = 90.0 - np.rad2deg(yaw)
    conv = np.rad2deg(meridian_convergence(crs, east, north))
    return float((grid_azimuth + conv) % 360.0)


def to_latlon(crs: str, east: float, north: float) -> tuple[float, float]:
    """(lat, lon) in degrees of a world point."""
    lon, lat = transformer(horizontal_crs(crs).to_string(), "EPSG:4326").transform(east, north)
    return float(lat), float(lon)


@dataclass(frozen=True)
class LocalFrame:
    """Local ENU frame ``L``: world coordinates minus ``origin`` (E0, N0, Z0), metres.

    The origin is rounded to whole metres so that the offsets are exact in float64.
    """

    origin: tuple[float, float, float]
    crs: str = "EPSG:25832"

    @staticmethod
    def around(
        east: float, north: float, height: float = 0.0, crs: str = "EPSG:25832"
    ) -> LocalFrame:
        return LocalFrame((float(round(east)), float(round(north)), float(round(height))), crs)

    def to_local(self, pts: np.ndarray) -> np.ndarray:
        """World (N,2) or (N,3) float64 -> local float64."""
        pts = np.asarray(pts, dtype=np.float64)
        o = np.asarray(self.origin[: pts.shape[-1]])
        return pts - o

    def to_world(self, pts: np.ndarray) -> np.ndarray:
        """Local (N,2) or (N,3) -> world float64."""
        pts = np.asarray(pts, dtype=np.float64)
        o = np.asarray(self.origin[: pts.shape[-1]])
        return pts + o

    def pose_to_world(self, T_local: np.ndarray) -> np.ndarray:
        """Sensor->L 4x4 transform to sensor->W (translation shifted by the origin)."""
        T = np.array(T_local, dtype=np.float64)
        T[:3, 3] += np.asarray(self.origin)
        return T

    def pose_to_local(self, T_world: np.ndarray) -> np.ndarray:
        T = np.array(T_world, dtype=np.float64)
        T[:3, 3] -= np.asarray(self.origin)
        return T
