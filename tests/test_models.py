"""factors: CTRA motion, periodic GP contour, star-convex and sensor-aware measurement models."""

from __future__ import annotations

import numpy as np
import pytest

from factors.ctra import SERIES_SWITCH, ctra_jacobian, ctra_predict, ctra_process_noise
from factors.gp import ContourGP, periodic_kernel, rectangle_radius
from factors.measurement import (
    associate_candidates,
    closest_on_chain,
    contour_candidates,
    contour_distance,
    contour_point,
    contour_point_jacobian,
    normal_offset,
    normal_offset_jacobian,
    plain_angles,
    range_rate,
    visibility_slack,
)

ANGLES = 2.0 * np.pi * np.arange(20) / 20


# ---------------------------------------------------------------------------------------------
# CTRA
# ---------------------------------------------------------------------------------------------
def test_ctra_matches_closed_form_circle() -> None:
    v, w, yaw, T = 6.0, 0.35, 0.7, 3.0
    out = ctra_predict(np.array([1.0, -2.0, v, 0.0, yaw, w]), T)
    R = v / w
    # circle: centre of rotation left of the heading
    cx, cy = 1.0 - R * np.sin(yaw), -2.0 + R * np.cos(yaw)
    expect = [cx + R * np.sin(yaw + w * T), cy - R * np.cos(yaw + w * T)]
    np.testing.assert_allclose(out[:2], expect, atol=1e-10)
    np.testing.assert_allclose(out[2:], [v, 0.0, yaw + w * T, w], atol=1e-12)


def test_ctra_straight_line_limit_and_continuity() -> None:
    v, a, yaw, T = 9.0, 1.2, -0.4, 0.5
    h = np.array([np.cos(yaw), np.sin(yaw)])
    straight = (v * T + 0.5 * a * T**2) * h
    out = ctra_predict(np.array([0.0, 0.0, v, a, yaw, 0.0]), T)
    np.testing.assert_allclose(out[:2], straight, atol=1e-12)
    # continuity through the series / closed-form switch and through w = 0
    w_sw = SERIES_SWITCH / T
    for w0 in (0.0, w_sw):
        ws = np.array([w0 - 1e-9, w0, w0 + 1e-9])
        k = np.column_stack([np.zeros(3), np.zeros(3), np.full(3, v), np.full(3, a),
                             np.full(3, yaw), ws])
        xy = ctra_predict(k, T)[:, :2]
        assert np.abs(np.diff(xy, axis=0)).max() < 1e-8


def test_ctra_jacobian_matches_finite_differences() -> None:
    T, e = 0.3, 1e-6
    for w in (0.4, 1e-5, 0.0):
        k = np.array([1.0, 2.0, 7.0, 0.5, 0.3, w])
        num = np.stack([(ctra_predict(k + e * d, T) - ctra_predict(k - e * d, T)) / (2 * e)
                        for d in np.eye(6)], axis=1)
        np.testing.assert_allclose(ctra_jacobian(k, T), num, atol=1e-7)


def test_ctra_batched_and_process_noise_psd() -> None:
    rng = np.random.default_rng(0)
    k = rng.normal(size=(4, 5, 8))
    out = ctra_predict(k, 0.05)
    assert out.shape == k.shape
    np.testing.assert_array_equal(out[..., 6:], k[..., 6:])
    np.testing.assert_allclose(out[2, 3], ctra_predict(k[2, 3], 0.05))
    Q = ctra_process_noise(k[..., :6], 0.05, 2.0, 0.5, 0.1)
    assert Q.shape == (4, 5, 6, 6)
    assert np.linalg.eigvalsh(Q).min() > -1e-15
    np.testing.assert_allclose(Q, np.swapaxes(Q, -1, -2))


# ---------------------------------------------------------------------------------------------
# GP contour
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("symmetry, sl", [(0.0, 0.0), (0.8, 2.0)])
def test_kernel_symmetric_psd(symmetry: float, sl: float) -> None:
    gp = ContourGP(ANGLES, symmetry=symmetry, sl=sl, sw=0.3)
    np.testing.assert_allclose(gp.K, gp.K.T)
    assert np.linalg.eigvalsh(gp.K).min() > -1e-10
    u = np.linspace(0, 2 * np.pi, 37)
    k = gp.kernel(u, u)
    assert np.linalg.eigvalsh(0.5 * (k + k.T)).min() > -1e-9
    # convention: l squared once, sr^2 inside k
    d = 0.9
    assert periodic_kernel(np.array(0.0), np.array(d), 2.0, 0.5, 0.3) == pytest.approx(
        4.0 * np.exp(-2.0 * np.sin(d / 2) ** 2 / 0.25) + 0.09)


def test_gp_conditional_matches_gaussian_conditioning() -> None:
    gp = ContourGP(ANGLES, sf=0.6, length=0.5, sr=0.8, symmetry=0.5, sl=1.0, sw=0.2)
    theta = np.array([0.1, 1.3, 2.0, 4.4, ANGLES[3]])
    rng = np.random.default_rng(1)
    f = gp.mu + rng.normal(0.0, 0.4, 20)
    # joint covariance of [f(theta); f(basis)] and the block formula
    u = np.concatenate([theta, ANGLES])
    S = gp.kernel(u, u)
    S11, S12, S22 = S[:5, :5], S[:5, 5:], S[5:, 5:]
    mean = gp.mean(theta) + S12 @ np.linalg.solve(S22, f - gp.mu)
    cov = S11 - S12 @ np.linalg.solve(S22, S12.T)
    H, var = gp.conditional(theta)
    np.testing.assert_allclose(gp.radius(f, theta), mean, atol=1e-6)
    np.testing.assert_allclose(gp.mean(theta) + H @ (f - gp.mu), mean, atol=1e-6)
    np.testing.assert_allclose(var, np.diag(cov), atol=1e-6)
    assert var[-1] == pytest.approx(0.0, abs=1e-6)             # at a basis angle


def test_contour_decay_covariance_is_stationary() -> None:
    gp = ContourGP(ANGLES)
    f = gp.mu + 1.0
    f1, Q1 = gp.decay(f, tau=0.4, dt=0.5)
    np.testing.assert_allclose(f1 - gp.mu, np.exp(-0.2) * (f - gp.mu))
    np.testing.assert_allclose(Q1, (1 - np.exp(-0.4)) * gp.K)
    # N(mu, K) is stationary: e^2 K + Q = K
    e = np.exp(-0.2)
    np.testing.assert_allclose(e**2 * gp.K + Q1, gp.K, atol=1e-12)
    # two half steps equal one step (mean and covariance)
    fa, Qa = gp.decay(f, 0.4, 0.25)
    fb, Qb = gp.decay(fa, 0.4, 0.25)
    ea = np.exp(-0.1)
    np.testing.assert_allclose(fb, f1, atol=1e-12)
    np.testing.assert_allclose(ea**2 * Qa + Qb, Q1, atol=1e-12)


def test_rectangle_radius() -> None:
    r = rectangle_radius(np.array([0.0, np.pi / 2, np.pi, np.arctan2(1.0, 2.0)]), 4.0, 2.0)
    np.testing.assert_allclose(r, [2.0, 1.0, 2.0, np.hypot(2.0, 1.0)])


# ---------------------------------------------------------------------------------------------
# measurement models
# ---------------------------------------------------------------------------------------------
def test_contour_point_plain_angle_roundtrip_and_jacobian() -> None:
    gp = ContourGP(ANGLES)
    c, yaw = np.array([3.0, -1.0]), 0.6
    theta = np.array([0.2, 1.9, 3.5])
    r = gp.radius(gp.mu, theta)
    p = contour_point(c, yaw, r, theta)
    np.testing.assert_allclose(np.mod(plain_angles(p, c, yaw), 2 * np.pi), theta)
    H, _ = gp.conditional(theta)
    J = contour_point_jacobian(yaw, r, theta, H)
    e = 1e-6
    state = np.concatenate([c, [yaw], gp.mu])

    def h(s: np.ndarray) -> np.ndarray:
        return contour_point(s[:2], s[2], gp.radius(s[3:], theta), theta)

    num = np.stack([(h(state + e * d) - h(state - e * d)) / (2 * e) for d in np.eye(23)], -1)
    np.testing.assert_allclose(J, num, atol=1e-6)


def test_range_rate_of_rigid_body() -> None:
    sensor = np.zeros(2)
    z = np.array([[10.0, 0.0], [0.0, 10.0]])
    # moving along +x at 5 m/s without rotation: 5 m/s away at (10, 0), 0 at (0, 10)
    d = range_rate(z, np.linalg.norm(z, axis=1), np.array([0.0, 0.0]), 5.0, 0.0, 0.0, sensor)
    np.testing.assert_allclose(d, [5.0, 0.0])
    # pure rotation about (10, 10): point (10, 0) moves along +x -> range rate 1 m/s at w = 0.1
    d = range_rate(z[:1], np.array([10.0]), np.array([10.0, 10.0]), 0.0, 0.0, 0.1, sensor)
    np.testing.assert_allclose(d, [1.0])


def _box(length: float, width: float, n: int = 36) -> np.ndarray:
    theta = 2 * np.pi * np.arange(n) / n
    return contour_point(np.zeros(2), 0.0, rectangle_radius(theta, length, width), theta)


def test_candidates_visible_sides_of_a_box() -> None:
    pts = _box(4.0, 2.0)
    # a sample next to a corner has a blended (central-difference) normal: it may count for
    # the face it touches, so "on the front face" means within one sample of it (x > 1.7)
    ahead = contour_candidates(pts, np.array([30.0, 0.0]))
    assert np.all(pts[ahead, 0] > 1.7)                         # only the front face
    assert np.sum(pts[ahead, 0] > 1.99) >= 5
    front_left = contour_candidates(pts, np.array([30.0, 30.0]))
    xs, ys = pts[front_left, 0], pts[front_left, 1]
    assert np.all((xs > 1.7) | (ys > 0.99))                    # front and left faces
    assert np.any(xs < 0.0) and np.any(ys < 0.0)               # both faces seen along
    assert not np.any(((xs < -1.7) & (ys < 0.99)) | ((ys < -0.7) & (xs < 1.99)))


def test_candidates_self_occlusion() -> None:
    # a plus-shaped (star-convex) outline, arms of half-width 0.5 and length 3
    outline = np.array([[3, -0.5], [3, 0.5], [0.5, 0.5], [0.5, 3], [-0.5, 3], [-0.5, 0.5],
                        [-3, 0.5], [-3, -0.5], [-0.5, -0.5], [-0.5, -3], [0.5, -3],
                        [0.5, -0.5]], dtype=float)
    nxt = np.roll(outline, -1, axis=0)
    pts = np.vstack([a + f * (b - a) for a, b in zip(outline, nxt)
                     for f in np.linspace(0, 1, 10, endpoint=False)])
    vis = contour_candidates(pts, np.array([6.0, 3.0]))

    def at(x: float, y: float) -> bool:
        return bool(vis[np.argmin(np.linalg.norm(pts - [x, y], axis=1))])

    assert at(0.5, 1.5)            # right face of the upper arm, in plain view
    assert at(3.0, 0.0)            # tip of the right arm
    assert not at(0.5, -1.5)       # faces the sensor, but the right arm is in the way
    assert not at(-3.0, 0.0)       # back face


def test_hungarian_association() -> None:
    cand = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    z = np.array([[0.1, 0.0], [0.2, 0.0], [2.1, 0.0]])
    np.testing.assert_array_equal(associate_candidates(z, cand, 1), [0, 1, 2])
    np.testing.assert_array_equal(associate_candidates(z, cand, 2), [0, 0, 2])
    # more detections than candidates x capacity: capacity is raised to the minimum (2) so
    # that everyone is assigned; the farthest of the three near candidate 0 moves over
    z4 = np.array([[0.0, 0.1], [0.0, -0.1], [0.3, 0.0], [1.9, 0.0]])
    np.testing.assert_array_equal(associate_candidates(z4, cand[[0, 2]], 1), [0, 0, 1, 1])


def test_normal_offset_and_jacobian() -> None:
    gp = ContourGP(ANGLES, sl=1.0, sw=0.2)
    c, yaw = np.array([3.0, -1.0]), 0.6
    theta = np.array([0.2, 1.9, 3.5])
    normal = np.array([[1.0, 0.0], [0.6, 0.8], [0.0, -1.0]])
    z = np.array([[6.0, 1.0], [1.0, 2.0], [2.0, -4.0]])
    f = gp.mu + 0.1 * np.sin(3 * ANGLES)
    r = gp.radius(f, theta)
    p = contour_point(c, yaw, r, theta)
    np.testing.assert_allclose(normal_offset(z, c, yaw, r, theta, normal),
                               np.sum(normal * (z - p), axis=1))
    H, _ = gp.conditional(theta)
    J = normal_offset_jacobian(yaw, r, theta, H, normal)
    state = np.concatenate([c, [yaw], f])

    def h(s: np.ndarray) -> np.ndarray:
        return normal_offset(z, s[:2], s[2], gp.radius(s[3:], theta), theta, normal)

    e = 1e-6
    num = np.stack([(h(state + e * d) - h(state - e * d)) / (2 * e) for d in np.eye(23)], -1)
    np.testing.assert_allclose(J, num, atol=1e-6)


def test_closest_on_visible_chain() -> None:
    n = 48
    theta = 2 * np.pi * np.arange(n) / n
    pts = contour_point(np.zeros(2), 0.0, rectangle_radius(theta, 4.0, 2.0), theta)
    sensor = np.array([30.0, 0.0])                             # sees the front face only
    vis = contour_candidates(pts, sensor)
    z = np.array([[2.3, 0.2], [2.1, -0.5], [2.5, 3.0]])        # the last beyond the face's end
    th, normal = closest_on_chain(z, pts, theta, vis)
    # matched on the front face: outward normal +x; the angle of the closest point
    np.testing.assert_allclose(normal[:2], [[1.0, 0.0]] * 2, atol=1e-9)
    q = contour_point(np.zeros(2), 0.0, rectangle_radius(th, 4.0, 2.0), th)
    np.testing.assert_allclose(q[:2], [[2.0, 0.2], [2.0, -0.5]], atol=0.05)
    # the offset along the normal ignores where on the face a detection lies
    np.testing.assert_allclose(np.sum(normal[:2] * (z[:2] - q[:2]), axis=1), [0.3, 0.1],
                               atol=0.05)
    # beyond the face's end: matched to the chain's end (the corner), normal still outward
    assert q[2, 1] > 0.8 and normal[2, 0] > 0.3
    np.testing.assert_allclose(np.linalg.norm(normal, axis=1), 1.0)
    # nothing of the hidden back face is matched
    assert np.all(q[:, 0] > 1.7)


def test_detections_far_from_the_visible_chain_take_the_whole_contour() -> None:
    """A 4 x 2 m box seen head-on shows its front face only; returns 1.5-3.5 m behind that
    face on its right side (the side a turning vehicle shows while its contour's heading
    lags) are 0.05 m from the side and 1.5 m or more from the front face. Matched to the
    visible chain they pull on the front face (normal +x); with ``slack`` they go to the
    side they lie on (normal -y), and a return on the front face stays there."""
    n = 48
    theta = 2 * np.pi * np.arange(n) / n
    pts = contour_point(np.zeros(2), 0.0, rectangle_radius(theta, 4.0, 2.0), theta)
    vis = contour_candidates(pts, np.array([30.0, 0.0]))
    z = np.array([[0.5, -1.05], [-0.5, -1.05], [-1.5, -1.05], [2.05, 0.3]])
    _, chain = closest_on_chain(z, pts, theta, vis)
    assert np.all(chain[:3, 0] > 0.3)                     # pulled on by the front
    th, normal = closest_on_chain(z, pts, theta, vis, slack=1.0)
    np.testing.assert_allclose(normal[:3], [[0.0, -1.0]] * 3, atol=1e-9)
    np.testing.assert_allclose(normal[3], [1.0, 0.0], atol=1e-9)
    q = contour_point(np.zeros(2), 0.0, rectangle_radius(th, 4.0, 2.0), th)
    np.testing.assert_allclose(q[:3], [[0.5, -1.0], [-0.5, -1.0], [-1.5, -1.0]], atol=0.05)
    # a slack wider than their distance to the chain changes nothing
    _, wide = closest_on_chain(z, pts, theta, vis, slack=5.0)
    np.testing.assert_allclose(wide, chain)


def test_contour_distance_is_the_offset_from_the_closest_contour_point() -> None:
    """A 12 x 2.5 m box (a truck) about (3, -1), turned by 0.4 rad: a point on its long side
    is 0 off, one 0.5 m beyond its front face 0.5 m, its centre 1.25 m (half the width: the
    nearest side) although 6 m from either end along the ray that the radial excess takes,
    a point 0.3 m inside a side 0.3 m; batched boxes give the single ones'."""
    n = 48
    theta = 2 * np.pi * np.arange(n) / n
    c, yaw = np.array([3.0, -1.0]), 0.4
    pts = contour_point(c, yaw, rectangle_radius(theta, 12.0, 2.5), theta)
    h, lat = np.array([np.cos(yaw), np.sin(yaw)]), np.array([-np.sin(yaw), np.cos(yaw)])
    z = c + np.array([[2.0 * h[0] + 1.25 * lat[0], 2.0 * h[1] + 1.25 * lat[1]],
                      6.5 * h, [0.0, 0.0], -4.0 * h - 0.95 * lat])
    d = contour_distance(z, pts)
    np.testing.assert_allclose(d, [0.0, 0.5, 1.25, 0.3], atol=1e-9)
    other = contour_point(np.zeros(2), 0.0, rectangle_radius(theta, 4.6, 1.9), theta)
    both = contour_distance(np.stack([z, z - c]), np.stack([pts, other]))
    np.testing.assert_allclose(both[0], d)
    np.testing.assert_allclose(both[1], contour_distance(z - c, other))


def test_visibility_slack_grows_with_the_cross_range_noise() -> None:
    """max(floor, 3 sqrt(sigma_r^2 + (sigma_az r)^2)): the floor 20 m out (0.92 m < 1 m),
    2.72 m 100 m out with the tracker's 0.25 m / 0.5 deg; inf stays inf."""
    z = np.array([[20.0, 0.0], [0.0, 100.0]]) + [5.0, -3.0]
    sensor = np.array([5.0, -3.0])
    slack = visibility_slack(z, sensor, 0.25, np.deg2rad(0.5), 1.0)
    np.testing.assert_allclose(slack, [1.0, 3.0 * np.hypot(0.25, np.deg2rad(0.5) * 100.0)])
    assert slack[1] == pytest.approx(2.72, abs=0.01)
    assert np.all(np.isinf(visibility_slack(z, sensor, 0.25, 0.01, np.inf)))


def test_visibility_and_chain_batched_match_single() -> None:
    rng = np.random.default_rng(3)
    n = 48
    theta = 2 * np.pi * np.arange(n) / n
    sensor = np.array([20.0, 15.0])
    boxes = [(4.6, 1.9, 0.3), (11.0, 2.5, -1.2), (5.5, 2.0, 2.5)]
    pts = np.stack([contour_point(np.array([1.0 * k, -2.0 * k]), yaw,
                                  rectangle_radius(theta, length, width), theta)
                    for k, (length, width, yaw) in enumerate(boxes)])
    z = pts[:, :: n // 8] + rng.normal(0.0, 0.3, (3, 8, 2))
    vis = contour_candidates(pts, sensor)
    th, nm = closest_on_chain(z, pts, theta, vis)
    for k in range(3):
        np.testing.assert_array_equal(vis[k], contour_candidates(pts[k], sensor))
        t1, n1 = closest_on_chain(z[k], pts[k], theta, vis[k])
        np.testing.assert_allclose(th[k], t1)
        np.testing.assert_allclose(nm[k], n1)
