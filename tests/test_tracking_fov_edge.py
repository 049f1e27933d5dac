"""Detections of a car driving along the field of view's edge are matched to the face they
come from (``[tracking] chain_fov_margin``), against known geometry: the car's seen long side
lies 0.1-0.5 m inside the FOV's edge 120 m out, the track's contour 0.7 m further out (a
small sideways error), so its side lies just outside the sector."""

from __future__ import annotations

import numpy as np

from factors.gp import rectangle_radius
from fgloc.tracking.birth import BirthZones, FieldOfView, LaneHeadings
from fgloc.tracking.config import TrackingConfig
from fgloc.tracking.tracker import Tracker
from fgloc.tracks import N_KIN, N_STATE, YAW, V, X, Y

HALF_FOV_DEG = 60.0
#: sideways error (m) of the track, outwards
SHIFT = 0.7


def _side_normals(margin: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals the sensor-aware model matches 6 side returns to, and the car's heading."""
    fov = FieldOfView.of(np.eye(4), 2 * HALF_FOV_DEG, 200.0)
    cfg = TrackingConfig(chain_fov_margin=margin)
    tracker = Tracker(cfg, fov, BirthZones.explicit([]), LaneHeadings.of([]))
    edge = np.deg2rad(HALF_FOV_DEG)
    out = np.array([-np.sin(edge), np.cos(edge)])              # outward normal of the edge
    along = np.array([np.cos(edge), np.sin(edge)])
    # driving towards the sensor 8 deg off the edge's line, its right side (the one the
    # sensor sees) towards the edge
    yaw = edge + np.pi + np.deg2rad(8.0)
    h = np.array([np.cos(yaw), np.sin(yaw)])
    right = np.array([h[1], -h[0]])
    assert right @ out > 0.9
    side = 120.0 * along + np.linspace(-1.8, 1.2, 6)[:, None] * h + 0.95 * right
    shift = -(np.max(side @ out) + 0.1) * out
    centre, side = 120.0 * along + shift, side + shift
    assert np.all(fov.contains(side)) and not np.any(fov.contains(side + SHIFT * out))
    x = np.zeros(N_STATE)
    x[[X, Y]] = centre + SHIFT * out
    x[YAW], x[V] = yaw, 10.0
    x[N_KIN:] = rectangle_radius(tracker.gp.angles, 4.6, 1.9)
    tracker.x, tracker.P = x[None], 0.01 * np.eye(N_STATE)[None]
    assert (fov.sensor - centre) @ right > 0.95
    valid = np.ones((1, len(side)), dtype=bool)
    _, _, normal, *_ = tracker._aware_batch(np.array([0]), side[None], valid, side[None], valid)
    return normal[0, :len(side)], h


def test_side_returns_next_to_the_fov_edge_are_matched_to_the_side() -> None:
    normal, h = _side_normals(TrackingConfig().chain_fov_margin)
    assert np.all(np.abs(normal @ h) < 0.3)


def test_without_the_margin_they_went_to_the_front_face() -> None:
    """The failure the margin fixes: the side outside the sector left the front face as the
    only visible part, 1.5-3 m from the side returns."""
    normal, h = _side_normals(0.0)
    assert np.mean(np.abs(normal @ h) > 0.7) >= 0.5
