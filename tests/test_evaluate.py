"""Pose errors: closed-form offsets and angle wrapping."""

from __future__ import annotations

import numpy as np
import pytest

from fgloc.evaluation.pose import pose_error, pose_error_vector
from fgloc.geo import se3_from_pose


def test_pose_error_known_offsets():
    truth = se3_from_pose(10.0, 20.0, 6.0, np.deg2rad(179.5), np.deg2rad(4.0), 0.0)
    est = se3_from_pose(10.3, 19.6, 5.5, np.deg2rad(-179.7), np.deg2rad(3.0), np.deg2rad(0.5))
    e = pose_error(est, truth)
    assert e.dx == pytest.approx(0.3)
    assert e.dy == pytest.approx(0.4)
    assert e.d2d == pytest.approx(0.5)
    assert e.dyaw_deg == pytest.approx(0.8)  # wrapped across +-180
    assert e.dz == pytest.approx(0.5)
    assert e.dpitch_deg == pytest.approx(1.0)
    assert e.droll_deg == pytest.approx(0.5)
    assert "2D m" in e.table()


def test_pose_error_vector_signed_and_wrapped():
    """Estimate minus truth in x, y and yaw, the yaw difference wrapped across +-pi."""
    truth = se3_from_pose(10.0, -5.0, 6.0, np.pi - 0.01, 0.02, 0.0)
    est = se3_from_pose(10.3, -5.2, 6.5, -np.pi + 0.02, 0.0, 0.01)
    np.testing.assert_allclose(pose_error_vector(est, truth), [0.3, -0.2, 0.03], atol=1e-9)
    np.testing.assert_allclose(pose_error_vector(truth, est), [-0.3, 0.2, -0.03], atol=1e-9)
