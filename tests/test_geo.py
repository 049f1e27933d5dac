"""Frames and transforms: closed-form cases and inverse round trips."""

from __future__ import annotations

import numpy as np
import pytest

from fgloc.geo import (
    LocalFrame,
    meridian_convergence,
    pose_from_se3,
    rot_from_ypr,
    se2,
    se2_inv,
    se2_params,
    se2_to_se3,
    se3_from_pose,
    se3_inv,
    transform_points,
    true_heading_deg,
    utm_zone,
    wrap_angle,
    ypr_from_rot,
)


def test_wrap_angle_scalar_and_array():
    assert wrap_angle(3 * np.pi / 2) == pytest.approx(-np.pi / 2)
    assert wrap_angle(-3 * np.pi / 2) == pytest.approx(np.pi / 2)
    np.testing.assert_allclose(wrap_angle(np.array([0.1, 2 * np.pi + 0.1])), [0.1, 0.1])


@pytest.mark.parametrize("ypr", [(0.3, 0.05, -0.02), (-2.9, -0.4, 1.2), (3.1, 0.0, 0.0)])
def test_ypr_round_trip(ypr):
    R = rot_from_ypr(*ypr)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(ypr_from_rot(R), ypr, atol=1e-12)


def test_positive_pitch_points_boresight_down():
    R = rot_from_ypr(0.0, np.deg2rad(5.0), 0.0)
    boresight = R @ np.array([1.0, 0.0, 0.0])
    assert boresight[2] < 0
    assert np.rad2deg(np.arcsin(-boresight[2])) == pytest.approx(5.0)


def test_yaw_is_ccw_from_east():
    R = rot_from_ypr(np.pi / 2, 0.0, 0.0)
    np.testing.assert_allclose(R @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)


def test_se3_inverse_and_points():
    T = se3_from_pose(1.0, -2.0, 6.0, 0.7, 0.05, -0.01)
    np.testing.assert_allclose(T @ se3_inv(T), np.eye(4), atol=1e-12)
    p = np.array([[10.0, 0.0, 0.0], [0.0, 5.0, -1.0]])
    back = transform_points(se3_inv(T), transform_points(T, p))
    np.testing.assert_allclose(back, p, atol=1e-12)
    np.testing.assert_allclose(pose_from_se3(T), (1.0, -2.0, 6.0, 0.7, 0.05, -0.01), atol=1e-12)


def test_se2_compose_inverse_and_lift():
    A, B = se2(1.0, 2.0, 0.5), se2(-3.0, 0.5, -1.2)
    np.testing.assert_allclose(se2_params(A @ B)[2], wrap_angle(0.5 - 1.2))
    np.testing.assert_allclose(A @ se2_inv(A), np.eye(3), atol=1e-12)
    T3 = se2_to_se3(A)
    p = np.array([[4.0, -1.0]])
    np.testing.assert_allclose(transform_points(T3, np.c_[p, [2.0]])[:, :2], transform_points(A, p))
    assert transform_points(T3, np.c_[p, [2.0]])[0, 2] == pytest.approx(2.0)


def test_local_frame_round_trip_exact_in_float64():
    f = LocalFrame.around(677123.4, 5401234.6, 371.2)
    assert f.origin == (677123.0, 5401235.0, 371.0)
    w = np.array([[677100.123, 5401200.456, 372.5]])
    np.testing.assert_array_equal(f.to_world(f.to_local(w)), w)
    T = se3_from_pose(1.0, 2.0, 6.0, 0.1, 0.0, 0.0)
    np.testing.assert_allclose(f.pose_to_local(f.pose_to_world(T)), T)


def test_meridian_convergence_sign_and_size():
    # Ingolstadt, ~2.4 deg east of the zone-32 central meridian (9 E): grid north lies east of
    # true north by about 1.8 deg there.
    c = np.rad2deg(meridian_convergence("EPSG:25832", 677000.0, 5400000.0))
    assert 1.5 < c < 2.1
    # On the central meridian (E = 500 km) the convergence vanishes.
    assert abs(np.rad2deg(meridian_convergence("EPSG:25832", 500000.0, 5400000.0))) < 1e-6
    # Grid north (yaw 90 deg) has true heading = convergence.
    assert true_heading_deg("EPSG:25832", 677000.0, 5400000.0, np.pi / 2) == pytest.approx(c)


def test_utm_zone():
    assert utm_zone("EPSG:25832") == 32
    assert utm_zone("EPSG:32633") == 33
    assert utm_zone("EPSG:4326") is None
