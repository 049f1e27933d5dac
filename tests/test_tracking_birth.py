"""A new track's birth when the vehicle's near part is withheld from births (the range next to
the blind range under the mast, ``[tracking] birth_blind_margin``), against a known vehicle: a
car (a truck) driving away from the sensor out of that range, with sparse returns, splits into
a cluster on its rear face (withheld) and a few returns at the front of its side."""

from __future__ import annotations

import numpy as np
import pytest

from fgloc.tracking.birth import BirthZones, FieldOfView, LaneHeadings, initial_kinematics
from fgloc.tracking.config import TrackingConfig
from fgloc.tracking.tracker import Tracker, _Frame

SENSOR_HEIGHT = 6.0


def _fov() -> FieldOfView:
    """A sensor 6 m up at the origin looking along +x, 40 deg down: near blind range ~6 m."""
    T = np.eye(4)
    c, s = np.cos(np.deg2rad(40.0)), np.sin(np.deg2rad(40.0))
    T[:3, :3] = [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
    T[2, 3] = SENSOR_HEIGHT
    return FieldOfView.of(T, 120.0, 200.0, 30.0, TrackingConfig().reflection_height)


def _first_frame(centre_x: float, length: float, rear: bool, rng: np.random.Generator
                 ) -> tuple[_Frame, float]:
    """Detections of a vehicle (length m, 1.8 m wide) centred at (centre_x, 0) driving away
    along +x at 8 m/s: 12 on its rear face when ``rear`` and 4 on its right side within
    1.2 m of its front; returns the frame and the true front (m)."""
    front = centre_x + length / 2
    side = np.column_stack([front - rng.uniform(0.0, 1.2, 4), np.full(4, -0.9)])
    pts = [side]
    if rear:
        pts.append(np.column_stack([np.full(12, centre_x - length / 2),
                                    rng.uniform(-0.9, 0.9, 12)]))
    z = np.vstack(pts) + rng.normal(0.0, 0.05, (sum(len(p) for p in pts), 2))
    rng3 = np.hypot(np.hypot(z[:, 0], z[:, 1]), SENSOR_HEIGHT - 0.8)
    doppler = 8.0 * z[:, 0] / rng3
    return _Frame(z, rng3, doppler, np.arange(len(z))), front


@pytest.mark.parametrize("length", [4.5, 11.0])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_birth_waits_until_the_vehicle_has_left_the_withheld_range(length: float,
                                                                   seed: int) -> None:
    cfg = TrackingConfig()
    fov = _fov()
    edge = fov.min_range + cfg.birth_blind_margin          # births only beyond this range
    rng = np.random.default_rng(seed)
    # the rear face 1-2 m inside the withheld range, the front cluster beyond it
    centre0 = edge - rng.uniform(1.0, 2.0) + length / 2
    zones = BirthZones.explicit([[centre0 + 10.0, 0.0, 40.0, 0.0]])
    tracker = Tracker(cfg, fov, zones, LaneHeadings.of([]))
    for k in range(12):                                    # 8 m/s, 0.1 s frames
        centre = centre0 + 0.8 * k
        frame, front = _first_frame(centre, length, True, rng)
        tracker.step(0.1 * k, frame)
        if tracker.recs:
            break
        # the front cluster alone would put the box's near end on its own (4-6 m ahead of
        # the vehicle's for these lengths): no birth while the rear face is withheld
        assert centre - length / 2 < edge + 0.8, (k, centre)
    # born first (nearest cluster first: the lowest id, the stronger under the duplicate
    # rule) from the rear face once it has left the withheld range: its near end is the
    # vehicle's (the prior length from there: exact for the car, short for the truck). The
    # front cluster is born too in the same frame, a tentative second track (for the truck
    # 10 m on, outside the duplicate rule's reach: not met, issue 20's "no fragments")
    assert 1 <= len(tracker.recs) <= 2
    first = int(np.argmin([r.id for r in tracker.recs]))
    x = tracker.x[first]
    rear = centre - length / 2
    assert abs(x[0] - (rear + 0.5 * cfg.mean_length)) < 0.6, (x[0], rear)
    assert abs(x[1]) < 0.5
    # the same front cluster with nothing withheld behind it (a vehicle whose rear face is
    # where its detections begin) is born at once
    frame, _ = _first_frame(centre0, length, False, rng)
    alone = Tracker(cfg, fov, zones, LaneHeadings.of([]))
    alone.step(0.0, frame)
    assert len(alone.recs) == 1


def _car_frame(yaw: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit heading and left normal of a car with yaw (rad)."""
    h = np.array([np.cos(yaw), np.sin(yaw)])
    return h, np.array([-h[1], h[0]])


def _local(p: np.ndarray, centre: np.ndarray, yaw: float) -> np.ndarray:
    """Point p (2,) in the car's frame: lengthwise, sideways offset (m) from its centre."""
    h, lat = _car_frame(yaw)
    d = np.asarray(p) - centre
    return np.array([d @ h, d @ lat])


def test_head_on_birth_centres_the_box_on_a_partial_front_face() -> None:
    """A car 130 m out driving towards the sensor 15 deg off the line of sight: its long side
    is at grazing incidence (not seen), and the first cluster holds three returns on the half
    of the front face away from the sensor. Aligning the box's sensor-side edge with the
    cluster put the centre 1.35 m off sideways (the start of a yaw divergence and a second
    track on the vehicle); centred on the cluster it is off by at most half the sideways
    room the cluster leaves in the car's width (0.7 m)."""
    sensor = np.zeros(2)
    yaw = np.deg2rad(-78.0)
    centre = 130.0 * np.array([np.cos(np.deg2rad(87.0)), np.sin(np.deg2rad(87.0))])
    h, lat = _car_frame(yaw)
    la = np.array([0.4, 0.65, 0.9])
    assert _local(sensor, centre, yaw)[1] < 0.0                # sensor on the other side
    z = centre + 2.3 * h + la[:, None] * lat
    rng = np.linalg.norm(z - sensor, axis=1)
    dop = 12.0 * ((z - sensor) / rng[:, None]) @ h
    c, *_ = initial_kinematics(z, dop, rng, yaw, sensor, 4.6, 1.9, 8.0, 0.0)
    err = _local(c, centre, yaw)
    assert abs(err[0]) < 0.05                                  # the front face is seen
    assert abs(err[1]) <= 0.5 * (1.9 - np.ptp(la)) + 0.01


def test_corner_view_birth_keeps_the_seen_edges() -> None:
    """Seen at 45 deg, the near corner's two faces are seen: the box's sensor-side edges sit on
    the cluster's extremes although the cluster covers only part of each face."""
    sensor = np.zeros(2)
    yaw = np.deg2rad(-135.0)
    centre = 40.0 * np.array([np.cos(np.deg2rad(90.0)), np.sin(np.deg2rad(90.0))])
    h, lat = _car_frame(yaw)
    s = _local(sensor, centre, yaw)
    side = np.sign(s[1])
    front = [centre + 2.3 * h + side * w * lat for w in (0.95, 0.6, 0.3)]
    flank = [centre + u * h + side * 0.95 * lat for u in (2.0, 1.5, 1.0)]
    z = np.array(front + flank)
    rng = np.linalg.norm(z - sensor, axis=1)
    dop = 10.0 * ((z - sensor) / rng[:, None]) @ h
    c, *_ = initial_kinematics(z, dop, rng, yaw, sensor, 4.6, 1.9, 8.0, 0.0)
    assert np.linalg.norm(_local(c, centre, yaw)) < 0.05
