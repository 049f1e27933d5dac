"""Measurement models of a star-convex GP object seen by a radar at a known position (2D).

Frames: everything in one 2D tracking frame; angles ``theta`` are in the object frame (rad,
x along the heading) and measured from the object centre.

* :func:`contour_point` -- the star-convex model: a detection whose contour angle is ``theta*``
  is predicted at ``c + u(theta* + yaw) f(theta*)`` with ``f(theta*) | f`` from the GP
  conditional (``u(a) = [cos a, sin a]``).
* plain model -- ``theta*`` is the angle of the detection seen from the (predicted) centre,
  :func:`plain_angles`.
* sensor-position-aware model (after Kellner-style "GP improved" trackers) -- from the sensor
  position, :func:`contour_candidates` samples the contour densely, keeps the points a radar can
  see (outward normal facing the sensor and line of sight not crossing the contour), and
  :func:`associate_candidates` assigns the detections to them with the Hungarian method
  (scipy.optimize.linear_sum_assignment on squared distances; each candidate may take up to
  ``capacity`` detections by replication), giving each detection the candidate's ``theta*``.
  Detections then pull on the part of the contour they can physically come from instead of the
  part that happens to lie in their direction from a possibly wrong centre.
  :func:`project_on_contour` then slides each ``theta*`` to the closest point of the contour
  next to its candidate, so the residual has no along-contour part from the candidate spacing
  or the capacity limit (like point-to-closest-point ICP, it still pulls an end of the visible
  contour out to detections beyond it).
* normal-offset form of the sensor-aware model (:func:`closest_on_chain`,
  :func:`normal_offset`): each detection is matched to the closest point of the *visible* part
  of the contour (the polyline of visible samples) and only its offset along the contour's
  outward normal there is a measurement (1D, like point-to-plane ICP): where on a face a
  detection lies carries no information. The visible extent is measured separately: the
  extreme detections along a face that is seen lie at the face's ends, i.e. the same scalar
  form with the axis direction as "normal" and the axis angle (0, pi/2, pi, 3 pi/2) as
  ``theta`` (``extent`` rows of the tracker).
* :func:`range_rate` -- Doppler of a detection on a rigid body moving with CTRA kinematics.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment


def unit(a: np.ndarray) -> np.ndarray:
    """``(..., 2)`` unit vectors ``[cos a, sin a]``."""
    a = np.asarray(a)
    out = np.empty((*a.shape, 2), dtype=np.result_type(a, float))
    np.cos(a, out=out[..., 0])
    np.sin(a, out=out[..., 1])
    return out


def contour_point(centre: np.ndarray, yaw: np.ndarray, radius: np.ndarray,
                  theta: np.ndarray) -> np.ndarray:
    """Star-convex point(s) ``centre + u(theta + yaw) radius``: centre (..., 2), yaw (...),
    radius and theta (..., m) -> (..., m, 2)."""
    yaw = np.asarray(yaw)[..., None]
    return np.asarray(centre)[..., None, :] + unit(theta + yaw) * np.asarray(radius)[..., None]


def contour_point_jacobian(yaw: np.ndarray | float, radius: np.ndarray, theta: np.ndarray,
                           H: np.ndarray) -> np.ndarray:
    """``(..., m, 2, 3 + n)`` Jacobian of :func:`contour_point` (with ``radius = mu* + H (f -
    mu)``) w.r.t. ``[x, y, yaw, f_1..f_n]`` for fixed ``theta*`` (..., m); yaw (...), radius
    (..., m), ``H`` (..., m, n) from the GP conditional (leading axes are a batch)."""
    u = unit(theta + np.asarray(yaw)[..., None])               # (..., m, 2)
    J = np.zeros((*H.shape[:-1], 2, 3 + H.shape[-1]))
    J[..., 0, 0] = J[..., 1, 1] = 1.0
    J[..., 0, 2] = -u[..., 1] * radius
    J[..., 1, 2] = u[..., 0] * radius
    J[..., 3:] = u[..., :, None] * H[..., None, :]
    return J


def plain_angles(z: np.ndarray, centre: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Contour angle (rad, object frame) of detections z (..., m, 2) seen from the centre
    (..., 2) of an object with heading yaw (...): shape (..., m)."""
    d = np.asarray(z) - np.asarray(centre)[..., None, :]
    return np.arctan2(d[..., 1], d[..., 0]) - np.asarray(yaw)[..., None]


def range_rate(z: np.ndarray, rng: np.ndarray, centre: np.ndarray, v: np.ndarray,
               yaw: np.ndarray, yawrate: np.ndarray, sensor: np.ndarray) -> np.ndarray:
    """Doppler (m/s, positive away from the sensor) of detections at z (..., m, 2) with 3D
    ranges rng (..., m) on a rigid body with centre (..., 2), speed v, heading yaw and yaw rate
    (...): ``(v u(yaw) + yawrate e_z x (z - c)) . (z - s) / rng``. Shape (..., m)."""
    z, centre, sensor = np.asarray(z), np.asarray(centre), np.asarray(sensor)
    zx, zy = z[..., 0], z[..., 1]
    w = np.asarray(yawrate)[..., None]
    vx = (np.asarray(v) * np.cos(yaw))[..., None] - w * (zy - centre[..., None, 1])
    vy = (np.asarray(v) * np.sin(yaw))[..., None] + w * (zx - centre[..., None, 0])
    return (vx * (zx - sensor[..., 0]) + vy * (zy - sensor[..., 1])) / rng


def _shift(a: np.ndarray, k: int) -> np.ndarray:
    """``np.roll(a, -k, axis=-1)`` (element i + k at i, cyclic), with less overhead."""
    return np.concatenate([a[..., k:], a[..., :k]], axis=-1)


def contour_candidates(points: np.ndarray, sensor: np.ndarray) -> np.ndarray:
    """Mask (..., m) of the contour points (..., m, 2) (closed CCW polygons, dense; leading
    axes are a batch) visible from the sensor position (2,): the outward normal (central
    difference) faces the sensor and the line of sight crosses no contour edge before reaching
    the point. (Field-of-view limits are the caller's: AND this with them.)"""
    p = np.asarray(points, dtype=float)
    s = np.asarray(sensor, dtype=float)
    m = p.shape[-2]
    px, py = p[..., 0].reshape(-1, m), p[..., 1].reshape(-1, m)     # (B, m) batch flattened
    nx, ny = _shift(px, 1), _shift(py, 1)
    tx, ty = nx - _shift(px, -1), ny - _shift(py, -1)
    facing = (ty * (s[0] - px) - tx * (s[1] - py)) > 0
    # self-occlusion (only of the facing points): segment s -> p_i against the edges
    # (p_j, p_j+1) not adjacent to i
    b, i = np.nonzero(facing)
    ex, ey = (nx - px)[b], (ny - py)[b]                            # (F, m) edges
    ax, ay = (px - s[0])[b], (py - s[1])[b]                        # (F, m) edge starts - s
    dx, dy = ax[np.arange(len(i)), i, None], ay[np.arange(len(i)), i, None]   # sight lines
    den = dx * ey - dy * ex
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ax * ey - ay * ex) / den
        w = (ax * dy - ay * dx) / den
    j = np.arange(m)
    adjacent = (j[None, :] == i[:, None]) | (j[None, :] == ((i - 1) % m)[:, None])
    hit = (t > 0) & (t < 1 - 1e-9) & (w >= 0) & (w <= 1) & ~adjacent
    occluded = hit.any(axis=-1)
    facing[b[occluded], i[occluded]] = False
    return facing.reshape(p.shape[:-1])


def associate_candidates(z: np.ndarray, candidates: np.ndarray, capacity: int) -> np.ndarray:
    """Index (k,) of the candidate (c, 2) assigned to each detection z (k, 2) by the Hungarian
    method on squared distances, every candidate replicated ``capacity`` times (raised to
    ``ceil(k / c)`` when needed so that every detection is assigned)."""
    k, c = len(z), len(candidates)
    rep = max(int(capacity), -(-k // c))
    d2 = np.sum((z[:, None, :] - candidates[None, :, :]) ** 2, axis=2)
    rows, cols = linear_sum_assignment(np.tile(d2, (1, rep)))
    out = np.empty(k, dtype=np.int64)
    out[rows] = cols % c
    return out


def project_on_contour(z: np.ndarray, points: np.ndarray, theta: np.ndarray,
                       idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Contour angle (k,) of the point closest to each detection z (k, 2) on the two edges of
    the closed polygon ``points`` (m, 2) -- sampled at the equally spaced angles ``theta``
    (m,) -- that meet at its assigned sample ``idx`` (k,), and the unit direction (k, 2) of the
    residual from that point to the detection (the outward edge normal when they coincide):
    across the contour, except beyond an end of the visible part, where it points outward
    along the contour."""
    m = len(points)
    step = 2.0 * np.pi / m
    a = points[idx]
    best_d = np.full(len(z), np.inf)
    out = theta[idx].astype(float)
    res = np.zeros_like(z)
    normal = np.zeros_like(z)
    for side in (-1, 1):
        e = points[(idx + side) % m] - a
        u = np.clip(np.sum((z - a) * e, axis=1) / np.maximum(np.sum(e * e, axis=1), 1e-12),
                    0.0, 1.0)
        r = z - (a + u[:, None] * e)
        d = np.linalg.norm(r, axis=1)
        better = (d < best_d)[:, None]
        best_d = np.where(better[:, 0], d, best_d)
        out = np.where(better[:, 0], theta[idx] + side * u * step, out)
        res = np.where(better, r, res)
        normal = np.where(better, side * np.stack([e[:, 1], -e[:, 0]], axis=1), normal)
    tiny = best_d < 1e-6
    direction = np.where(tiny[:, None], normal, res)
    direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-12)
    return out, direction


#: a detection leaves the visible chain only when it lies this many std. devs. of its position
#: noise farther from it than from the whole contour (:func:`visibility_slack`)
SLACK_SIGMAS = 3.0


def visibility_slack(z: np.ndarray, sensor: np.ndarray, sigma_range: float,
                     sigma_azimuth: float, floor: float) -> np.ndarray:
    """Per-detection ``slack`` (m) of :func:`closest_on_chain` for detections z (..., k, 2)
    seen from ``sensor`` (2,): at least ``floor`` (m) and ``SLACK_SIGMAS`` times the
    detection's position std. dev. ``sqrt(sigma_range^2 + (sigma_azimuth r)^2)`` (m; range
    noise ``sigma_range`` m, azimuth noise ``sigma_azimuth`` rad, r its 2D range in m): far
    out the cross-range noise scatters a face's returns metres off it, and only a detection
    beyond that is taken off the visible part. ``floor`` = inf gives inf (never)."""
    r = np.linalg.norm(np.asarray(z, dtype=float) - sensor, axis=-1)
    return np.maximum(floor, SLACK_SIGMAS * np.hypot(sigma_range, sigma_azimuth * r))


def _edge_distances(z: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, ...]:
    """Squared distance (..., k, m) of detections z (..., k, 2) to each edge (j, j + 1) of the
    closed polygon ``points`` (..., m, 2), the edge parameter (..., k, m) in [0, 1] of the
    closest point and the edges' x, y components and squared lengths (..., m)."""
    p = np.asarray(points, dtype=float)
    z = np.asarray(z, dtype=float)
    # x / y components apart (no reductions over the length-2 axis: same values, faster)
    px, py = p[..., 0], p[..., 1]
    ex, ey = _shift(px, 1) - px, _shift(py, 1) - py                # (..., m) edges
    ee = np.maximum(ex * ex + ey * ey, 1e-12)                       # (..., m)
    ex_, ey_ = ex[..., None, :], ey[..., None, :]
    dx = z[..., :, None, 0] - px[..., None, :]                      # (..., k, m)
    dy = z[..., :, None, 1] - py[..., None, :]
    u = (dx * ex_ + dy * ey_) / ee[..., None, :]
    np.clip(u, 0.0, 1.0, out=u)
    dx -= u * ex_
    dy -= u * ey_
    return dx * dx + dy * dy, u, ex, ey, ee


def contour_distance(z: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Distance (m) (..., k) of detections z (..., k, 2) to the closed polygon ``points``
    (..., m, 2) (leading axes are a batch), inside or outside it: the offset from the closest
    contour point that the measurement model's rows measure. Unlike the radial excess (along
    the ray from the centre) it stays at most half the width for a detection inside an
    elongated contour."""
    return np.sqrt(_edge_distances(z, points)[0].min(axis=-1))


def closest_on_chain(z: np.ndarray, points: np.ndarray, theta: np.ndarray,
                     visible: np.ndarray, slack: float | np.ndarray = np.inf
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Closest point of the visible part of a closed CCW polygon to each detection.

    z (..., k, 2) detections; points (..., m, 2) the polygon sampled at the equally spaced
    angles theta (m,); visible (..., m) mask (leading axes are a batch). The chain is every
    edge (j, j + 1) with both ends visible (all edges if there is none). A detection whose
    closest point on the chain is more than ``slack`` (m; scalar or (..., k), e.g.
    :func:`visibility_slack`) farther than its closest point on the whole polygon takes the
    latter: it cannot come from the part the polygon's pose shows (a contour whose heading
    lags a turning vehicle hides the side that the sensor sees, and that side's returns,
    metres behind the front, would pull the front round).
    Returns the contour angle (..., k) of the closest point (linear in the edge parameter)
    and the unit outward normal (..., k, 2) of that edge."""
    m = np.shape(points)[-2]
    step = 2.0 * np.pi / m
    vis = np.asarray(visible, dtype=bool)
    chain = vis & _shift(vis, 1)
    chain = chain | ~chain.any(axis=-1, keepdims=True)
    dist, u, ex, ey, ee = _edge_distances(z, points)
    anywhere = np.argmin(dist, axis=-1)                             # (..., k)
    d_any = np.take_along_axis(dist, anywhere[..., None], axis=-1)[..., 0]
    dist[~np.broadcast_to(chain[..., None, :], dist.shape)] = np.inf
    best = np.argmin(dist, axis=-1)                                 # (..., k)
    if np.isfinite(slack).any():
        d_vis = np.take_along_axis(dist, best[..., None], axis=-1)[..., 0]
        best = np.where(np.sqrt(d_vis) - np.sqrt(d_any) > slack, anywhere, best)
    out = theta[best] + np.take_along_axis(u, best[..., None], axis=-1)[..., 0] * step
    nb = np.sqrt(np.take_along_axis(ee, best, axis=-1))
    normal = np.empty((*best.shape, 2))
    normal[..., 0] = np.take_along_axis(ey, best, axis=-1) / nb
    normal[..., 1] = -np.take_along_axis(ex, best, axis=-1) / nb
    return out, normal


def normal_offset(z: np.ndarray, centre: np.ndarray, yaw: np.ndarray, radius: np.ndarray,
                  theta: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Offset (m) of detections z (..., m, 2) from the contour point at theta (..., m) along
    the fixed unit directions normal (..., m, 2): ``n . (z - contour_point)``; centre (..., 2),
    yaw (...), radius (..., m). Shape (..., m)."""
    p = contour_point(centre, yaw, radius, theta)
    return np.sum(np.asarray(normal) * (np.asarray(z) - p), axis=-1)


def interior_variance(z: np.ndarray, valid: np.ndarray, points: np.ndarray,
                      theta: np.ndarray, normal: np.ndarray, sensor: np.ndarray,
                      sigma_range: float, sigma_azimuth: float, sigma_contour: float,
                      sigmas: float) -> np.ndarray:
    """Extra variance (m^2) (T, k) of the outline rows of detections z (T, k, 2) (mask valid
    (T, k)) matched to the closed CCW polygons ``points`` (T, m, 2) -- sampled at the equally
    spaced angles ``2 pi j / m`` -- at contour angles theta (T, k) with unit normals
    (T, k, 2) (:func:`closest_on_chain`), seen from ``sensor`` (2,): a detection whose offset
    along its normal lies below its track's median offset by more than ``sigmas`` std. devs.
    of its position noise along that normal (range noise ``sigma_range`` m along the line of
    sight, azimuth noise ``sigma_azimuth`` rad across it, ``sigma_contour`` m isotropic)
    gains the square of that depth; else 0 (all 0 for sigmas <= 0). A roof return, seen
    from a mast, lies inside the outline: as an outline row it would pull the seen face in."""
    out = np.zeros(np.shape(valid))
    if sigmas <= 0.0 or not np.any(valid):
        return out
    m = np.shape(points)[-2]
    pos = np.asarray(theta) / (2.0 * np.pi / m)
    j = np.floor(pos).astype(np.int64) % m
    u = (pos - np.floor(pos))[..., None]
    a = np.take_along_axis(points, j[..., None], axis=-2)
    b = np.take_along_axis(points, ((j + 1) % m)[..., None], axis=-2)
    offset = np.sum(normal * (z - (a + u * (b - a))), axis=-1)      # + outside
    has = np.any(valid, axis=-1, keepdims=True)
    med = np.nanmedian(np.where(valid | ~has, offset, np.nan), axis=-1, keepdims=True)
    depth = np.where(valid, med - offset, 0.0)
    los = z - sensor
    rng = np.maximum(np.linalg.norm(los, axis=-1), 1e-6)
    c = np.sum(normal * los, axis=-1) / rng                         # normal . line of sight
    sd = np.sqrt(sigma_range**2 * c * c + (sigma_azimuth * rng) ** 2 * (1.0 - c * c)
                 + sigma_contour**2)
    deep = valid & (depth > sigmas * sd)
    out[deep] = depth[deep] ** 2
    return out


def normal_offset_jacobian(yaw: np.ndarray | float, radius: np.ndarray, theta: np.ndarray,
                           H: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """``(..., m, 3 + n)`` Jacobian of :func:`normal_offset` (``radius = mu* + H (f - mu)``)
    w.r.t. ``[x, y, yaw, f_1..f_n]`` for fixed theta (..., m) and normal (..., m, 2); yaw
    (...), radius (..., m), H (..., m, n): ``-n`` on the centre, ``-r n . u'`` on the yaw and
    ``-(n . u) H`` on the radii (``u = u(theta + yaw)``, ``u'`` its derivative)."""
    u = unit(theta + np.asarray(yaw)[..., None])               # (..., m, 2)
    n = np.asarray(normal, dtype=float)
    J = np.empty((*H.shape[:-1], 3 + H.shape[-1]))
    J[..., 0] = -n[..., 0]
    J[..., 1] = -n[..., 1]
    J[..., 2] = -radius * (n[..., 1] * u[..., 0] - n[..., 0] * u[..., 1])
    J[..., 3:] = -(n[..., 0] * u[..., 0] + n[..., 1] * u[..., 1])[..., None] * H
    return J
