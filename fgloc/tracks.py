"""Track types shared by the tracker, the smoothers, the registration and the evaluation.

A state row is ``[x, y, v, a, yaw, yawrate, r_0, ..., r_{19}]``: centre (m) in the track set's
frame, speed (m/s), longitudinal acceleration (m/s^2), yaw (rad, CCW from the frame's x axis),
yaw rate (rad/s) and the star-convex contour radii (m) at angles ``2*pi*i/20`` in the vehicle
frame (x along the heading, y to the left), measured from the centre.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from factors.state import N_CONTOUR, N_KIN, N_STATE, YAW, YAWRATE, A, V, X, Y
from fgloc.geo import se2_params

__all__ = [
    "A", "N_CONTOUR", "N_KIN", "N_STATE", "V", "X", "Y", "YAW", "YAWRATE",
    "Track", "TrackSet", "contour_angles", "contour_length_width",
]


def contour_angles(n: int = N_CONTOUR) -> np.ndarray:
    """(n,) contour basis angles ``2*pi*i/n`` (rad) in the vehicle frame."""
    return 2.0 * np.pi * np.arange(n) / n


def contour_length_width(states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n,) length and width (m) of the star-convex contours of state rows (n, N_STATE): the
    radii along the heading (front + rear) and across it (left + right)."""
    f = states[:, N_KIN:]
    q = f.shape[1] // 4
    return f[:, 0] + f[:, 2 * q], f[:, q] + f[:, 3 * q]


@dataclass
class Track:
    """One tracked vehicle.

    t: (n,) s, increasing. states: (n, N_STATE). covariances: (n, N_STATE, N_STATE) or None.
    labels: (n,) int8 label codes (fgloc.labels) from kappa = yawrate / v.
    det_index: (m,) int64 indices into the scenario's RadarData of the detections this track
    used; det_step: (m,) int64 index into ``t`` of the step that used each of them.
    length_floor: a lower bound (m) of the vehicle's length the tracker measured (the
    largest occupied length behind the seen end of a truck seen end-on that set its
    contour's length; ``[tracking] occupancy_gap``), 0 without; the batch smoother keeps the
    length above it (:mod:`fgloc.smoothing.length_floor`). standing: (n,) bool, the steps at
    which the vehicle stood without a detection (the rows of a stand the re-linking joined
    across, :mod:`fgloc.tracking.relink`), or None for none; the smoothers hold their speed,
    acceleration and yaw rate at 0 (:mod:`fgloc.smoothing.standing`). Neither is stored in the
    track files.
    """

    id: int
    t: np.ndarray
    states: np.ndarray
    labels: np.ndarray
    covariances: np.ndarray | None = None
    det_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    det_step: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    length_floor: float = 0.0
    standing: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def standing_steps(self) -> np.ndarray:
        """(k,) int64 indices of the ``standing`` steps (empty without)."""
        if self.standing is None:
            return np.zeros(0, dtype=np.int64)
        return np.flatnonzero(self.standing).astype(np.int64)

    def contour_points(self, k: int) -> np.ndarray:
        """(N_CONTOUR, 2) contour points of step k in the track set's frame."""
        s = self.states[k]
        ang = contour_angles() + s[YAW]
        r = s[N_KIN:]
        return np.column_stack([s[X] + r * np.cos(ang), s[Y] + r * np.sin(ang)])


@dataclass
class TrackSet:
    """All tracks of a recording, in one 2D frame.

    frame: "C" (coarse frame: radar points after T_coarse, the tracker's frame) or "L" (local
    ENU). T_frame_to_L: 3x3 SE(2) that maps this frame to L (identity when frame == "L").
    """

    tracks: list[Track]
    frame: str = "C"
    T_frame_to_L: np.ndarray = field(default_factory=lambda: np.eye(3))
    diagnostics: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.tracks)

    def left_out(self) -> tuple[int, str]:
        """How many tracks the tracker left out as other road users (its diagnostics'
        ``not_motor_vehicles``) and why, as "(a smaller or slower than a motor vehicle, b off
        the drivable lanelets on the map's other ways, c off every drivable lanelet, d behind
        buildings)" (``off_lane``, ``off_road``, ``hidden``; :mod:`fgloc.tracking.road_users`)."""
        others = len(self.diagnostics.get("not_motor_vehicles", []))
        told = {k: len(self.diagnostics.get(k, [])) for k in ("off_lane", "off_road", "hidden")}
        return others, (f"({others - sum(told.values())} smaller or slower than a motor "
                        f"vehicle, {told['off_lane']} off the drivable lanelets on the map's "
                        f"other ways, {told['off_road']} off every drivable lanelet, "
                        f"{told['hidden']} behind buildings)")

    def in_local(self) -> TrackSet:
        """The same tracks expressed in L (applies ``T_frame_to_L``; a no-op copy for L).

        Centres and covariances are rotated and translated, yaw is shifted by the rotation angle
        (not wrapped); v, a, yaw rate, radii and labels are invariant under the rigid transform.
        """
        tx, ty, theta = se2_params(self.T_frame_to_L)
        R = self.T_frame_to_L[:2, :2]
        out = []
        for tr in self.tracks:
            s = np.array(tr.states, dtype=np.float64)
            s[:, :2] = s[:, :2] @ R.T + (tx, ty)
            s[:, YAW] += theta
            cov = None
            if tr.covariances is not None:
                J = np.eye(s.shape[1])
                J[:2, :2] = R
                cov = J @ tr.covariances @ J.T
            out.append(
                Track(
                    tr.id,
                    tr.t.copy(),
                    s,
                    tr.labels.copy(),
                    cov,
                    tr.det_index.copy(),
                    tr.det_step.copy(),
                    tr.length_floor,
                    None if tr.standing is None else tr.standing.copy(),
                )
            )
        return TrackSet(out, frame="L", T_frame_to_L=np.eye(3), diagnostics=dict(self.diagnostics))
