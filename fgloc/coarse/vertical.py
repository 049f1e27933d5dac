"""The coarse stage's vertical fit: sensor height, pitch and roll from the moving returns' and
the static ground returns' heights against the ALS road (step 2 of :mod:`fgloc.coarse.localize`),
and the field-of-view test that keeps the returns whose heights are unbiased."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from fgloc.coarse.icp import RoadModel, apply_planar
from fgloc.config import CoarseConfig
from fgloc.scenario import RadarData

#: how many nearest moving detections, and nearest static ones, a static return's height is
#: compared by (:meth:`TrafficBeside.below_traffic`)
NEAR_MOVING, NEAR_STATIC = 32, 16
#: ASPRS classes that are never an obstacle above the road: ground, noise, water, road surface,
#: ignored ground
_GROUND_LIKE = np.array([2, 7, 9, 11, 20])


@dataclass
class StaticGround:
    """Static returns near the ground whose height the ALS gives (kerbs, the road's edge).

    src: (M, 3) detections in S with ``|doppler| <= static_doppler_max`` (a regular subsample
    of at most ``static_points``) that repeat (:func:`repeated`: ``static_repeats`` others
    within ``static_repeat_radius``; horizontal, in S). busy: (M,) True where the traffic
    passes (more than ``static_traffic_max`` moving detections within
    ``static_traffic_radius``, horizontal in S): a kerb beside a lane, or a vehicle standing
    in a queue (:meth:`rows` tells them by their height); None: none. beside: the moving
    detections beside each (:class:`TrafficBeside`); None: no test. high: 2D KD-tree over
    the ALS points outside the road classes (buildings, vegetation, poles) and their heights
    ``high_z`` (M',) in L. lanes: a KD-tree over the lane centre samples (a return within
    ``static_lane_clearance`` of a lane centre may be a vehicle that stands or crosses the
    beam, not the ground).
    """

    src: np.ndarray
    high: cKDTree | None
    high_z: np.ndarray
    lanes: cKDTree
    busy: np.ndarray | None = None
    beside: TrafficBeside | None = None

    @classmethod
    def build(cls, radar: RadarData, als_xyz: np.ndarray, als_class: np.ndarray,
              centre: np.ndarray, reach: float, lane_xy: np.ndarray, cfg: CoarseConfig
              ) -> StaticGround:
        """From the radar rows, the ALS (xyz (N, 3) in L, ASPRS classes (N,)) within ``reach``
        m of ``centre`` (2,) (every class but ground, road, water, noise and ignored ground
        may be an obstacle; the height test decides for unclassified points) and the lane
        centre samples ``lane_xy`` (K, 2) m in L (of every lane model)."""
        xyz = np.asarray(radar.xyz, dtype=float)
        st = xyz[np.abs(radar.doppler) <= cfg.static_doppler_max]
        st = st[:: max(1, len(st) // cfg.static_points)] if len(st) else np.zeros((0, 3))
        st = st[repeated(st[:, :2], cfg.static_repeat_radius, cfg.static_repeats)]
        moving = xyz[np.abs(radar.doppler) >= cfg.doppler_min]
        busy = beside = None
        if len(moving) and len(st):
            tree = cKDTree(moving[:, :2])
            busy = tree.query_ball_point(st[:, :2], r=cfg.static_traffic_radius,
                                         return_length=True) > cfg.static_traffic_max
            beside = TrafficBeside(
                moving, tree.query(st[:, :2], k=NEAR_MOVING,
                                   distance_upper_bound=cfg.static_beside_radius)[1],
                cKDTree(st[:, :2]).query(st[:, :2], k=NEAR_STATIC,
                                         distance_upper_bound=cfg.static_repeat_radius)[1])
        near = np.hypot(*(als_xyz[:, :2] - centre).T) <= reach
        off = near & ~np.isin(als_class, _GROUND_LIKE)
        high = cKDTree(als_xyz[off, :2]) if off.any() else None
        return cls(st, high, als_xyz[off, 2].astype(float), cKDTree(lane_xy), busy, beside)

    def rows(self, r_tilt: np.ndarray, pose2d: np.ndarray, road: RoadModel,
             cfg: CoarseConfig) -> tuple[np.ndarray, np.ndarray]:
        """The static returns that qualify at this placement: their levelled sensor-centred
        coordinates (K, 3) and the ALS road height under each (K,). A return qualifies within
        ``static_ground_distance`` m of a road point, at least ``static_lane_clearance`` m from
        every lane centre, with no ALS point higher than ``static_clearance_height`` m above
        that road height within ``static_clearance`` m (no wall, tree or pole it could be).
        Those where the traffic passes (``busy``) qualify only when at least
        ``static_min_points`` others do and the two groups' median heights above the road
        agree within ``static_traffic_tolerance`` m (kerbs beside a lane are as high as the
        others; a standing vehicle's returns lie higher). Those beside the traffic qualify only
        when, as a group, they lie lower than it (``static_beside_radius``;
        :meth:`TrafficBeside.below_traffic`)."""
        lev = self.src @ r_tilt.T
        xy = apply_planar(lev[:, :2], pose2d)
        zr, dn = road.road_height(xy)
        ok = (dn <= cfg.static_ground_distance) & (
            self.lanes.query(xy)[0] >= cfg.static_lane_clearance)
        if self.high is not None and ok.any():
            d, i = self.high.query(xy[ok], k=8, distance_upper_bound=cfg.static_clearance)
            found = np.isfinite(d)
            hz = np.where(found, self.high_z[np.minimum(i, len(self.high_z) - 1)], -np.inf)
            ok[np.flatnonzero(ok)] = ~np.any(hz > zr[ok, None] + cfg.static_clearance_height,
                                             axis=1)
        if self.busy is not None and (ok & self.busy).any():
            clear, busy = ok & ~self.busy, ok & self.busy
            h = lev[:, 2] - zr              # height above the road less the sensor's
            if clear.sum() < cfg.static_min_points or abs(
                    np.median(h[busy]) - np.median(h[clear])) > cfg.static_traffic_tolerance:
                ok = clear
        if self.beside is not None:
            beside, lower = self.beside.below_traffic(lev[:, 2], r_tilt, cfg)
            if (ok & beside).any() and np.median(lower[ok & beside]) < 0.5 * (
                    cfg.reflection_height - cfg.static_height):
                ok &= ~beside
        return lev[ok], zr[ok]


@dataclass
class TrafficBeside:
    """The moving detections beside each static return of a :class:`StaticGround`.

    moving: (N, 3) the moving detections in S (``|doppler| >= doppler_min``). near_moving:
    (M, 32) indices into ``moving`` of each static return's nearest within
    ``static_beside_radius`` (``N`` where fewer). near_static: (M, 16) indices into the static
    returns of each one's nearest within ``static_repeat_radius`` (itself included; ``M``
    where fewer). Horizontal neighbours in S: the tilt moves them little over a few metres.
    """

    moving: np.ndarray
    near_moving: np.ndarray
    near_static: np.ndarray

    def below_traffic(self, lev_z: np.ndarray, r_tilt: np.ndarray, cfg: CoarseConfig
                      ) -> tuple[np.ndarray, np.ndarray]:
        """Which static returns have the traffic beside them (at least ``static_beside_min``
        moving detections within ``static_beside_radius``), and how far (m) their
        neighbours' median height lies below that traffic's median height (NaN where none),
        from the static returns' levelled heights ``lev_z`` (M,) (m, sensor-centred) and the
        moving detections levelled by ``r_tilt``."""
        traffic, n = _median_of(self.moving @ r_tilt[2], self.near_moving)
        own, _ = _median_of(lev_z, self.near_static)
        return n >= cfg.static_beside_min, traffic - own


def _median_of(z: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of ``idx`` (M, k) indices into ``z`` (``len(z)`` = none), the median of those
    values (NaN without any) and how many there are."""
    found = idx < len(z)
    v = np.full(idx.shape, np.nan)
    v[found] = z[idx[found]]
    n = found.sum(axis=1)
    med = np.full(len(idx), np.nan)
    med[n > 0] = np.nanmedian(v[n > 0], axis=1)
    return med, n


def repeated(xy: np.ndarray, radius: float, repeats: int) -> np.ndarray:
    """Mask of the points (xy (N, 2) m, in S) with at least ``repeats`` others within ``radius``
    m: a fixed scatterer (a kerb) returns again and again from where it stands, a false alarm
    with a Doppler near 0 by chance stands alone."""
    if repeats <= 0 or len(xy) == 0:
        return np.ones(len(xy), dtype=bool)
    if len(xy) <= repeats:
        return np.zeros(len(xy), dtype=bool)
    d = cKDTree(xy).query(xy, k=repeats + 1)[0][:, -1]
    return d <= radius


@dataclass
class VerticalFit:
    """The vertical fit's small turn w = (wx, wy) rad about the levelled axes (to add to the
    ``tilt`` it started from), the sensor height z (m in L), the 5x5 covariance of (wx, wy, z,
    h_v, h_s) (z's variance at [2, 2]) and how many static ground returns it used (0: the
    moving returns alone)."""

    w: np.ndarray
    z: float
    cov: np.ndarray
    n_static: int


def fit_vertical(
    lev: np.ndarray, xy_l: np.ndarray, road: RoadModel, allowed: np.ndarray,
    tilt: tuple[float, float], z_prior: float, cfg: CoarseConfig,
    statics: tuple[np.ndarray, np.ndarray] | None = None,
) -> VerticalFit | None:
    """Small tilt (wx, wy) rad about the levelled axes and the sensor height z (m in L) from the
    moving returns ``lev`` (N, 3, levelled, sensor-centred) and the static ground returns
    ``statics`` ((K, 3) levelled, (K,) ALS road height under each; :meth:`StaticGround.rows`).

    Unknowns ``(wx, wy, z, h_v, h_s)``: h_v the mean height of the moving returns above the
    road, h_s that of the static ones. Rows: ``lev_z + wx lev_y - wy lev_x + z - h = z_road``
    for the ``allowed`` moving points within ``cfg.icp_ranges[-1]`` of the road (h = h_v) and
    for the static ones (h = h_s), each group dropping residuals beyond 3 of its MADs. Priors:
    z ~ z_prior (``height_prior_sigma``), total pitch, roll ~ 0 (``tilt_prior_sigma_deg``;
    ``tilt`` = current (pitch, roll) rad, to first order wy adds to the pitch and wx to the
    roll), h_v ~ ``reflection_height`` +- ``reflection_height_sigma`` (nobody knows where a
    given radar's returns sit on the bodies; 0 fixes it), h_s ~ ``static_height`` +-
    ``static_height_sigma``. The moving returns alone fix only ``z - h_v`` (and the tilt): their
    height errors are largely systematic (body heights, field of view), so they weigh as
    ``vertical_effective_points`` measurements of sigma ``height_residual_sigma``. The static
    ones (at least ``static_min_points``) weigh as at most ``static_effective_points``
    measurements of their own scatter (1.4826 MAD), each row divided by
    ``sqrt(1 + (range / static_noise_range)^2)`` (the elevation noise grows with range).
    The static returns are dropped (the fit redone on the moving ones) when they are no ground
    returns by the fit's own account (false alarms, returns off standing vehicles or other
    structures): the fit puts them less than ``static_height_gap`` below the moving returns
    (``h_v - h_s``), or the z they give differs from the moving returns' own by more than
    ``static_consistency`` std. devs. of that difference. None when fewer than 10 moving
    points lie on the road.
    """
    zr, dn = road.road_height(xy_l)
    use = allowed & (dn <= cfg.icp_ranges[-1])
    if use.sum() < 10:
        return None
    nv = int(use.sum())
    groups = [(np.column_stack([lev[use, 1], -lev[use, 0], np.ones(nv), -np.ones(nv),
                                np.zeros(nv)]), zr[use] - lev[use, 2])]
    if statics is not None and len(statics[1]) >= cfg.static_min_points:
        ls, zg = statics
        ns = len(zg)
        # the elevation noise makes a return's height noise grow with its range
        scale = np.sqrt(1.0 + (np.hypot(ls[:, 0], ls[:, 1]) / cfg.static_noise_range) ** 2)
        groups.append((np.column_stack([ls[:, 1], -ls[:, 0], np.ones(ns), np.zeros(ns),
                                        -np.ones(ns)]) / scale[:, None], (zg - ls[:, 2]) / scale))
    st = np.deg2rad(cfg.tilt_prior_sigma_deg)
    sd = np.array([st, st, cfg.height_prior_sigma, max(cfg.reflection_height_sigma, 1e-6),
                   max(cfg.static_height_sigma, 1e-6)])
    a_prior = np.diag(1.0 / sd)
    b_prior = np.array([-tilt[1], -tilt[0], z_prior, cfg.reflection_height,
                        cfg.static_height]) / sd
    keep = [np.ones(len(b), dtype=bool) for _, b in groups]
    sigma = [cfg.height_residual_sigma, np.inf]

    def solve(with_statics: bool) -> tuple[np.ndarray, np.ndarray]:
        aw, bw = [a_prior], [b_prior]
        for g, ((a, b), k) in enumerate(zip(groups, keep)):
            if g == 1 and not with_statics:
                continue
            eff = cfg.vertical_effective_points if g == 0 else min(
                cfg.static_effective_points, k.sum())
            wd = np.sqrt(eff / k.sum()) / sigma[g]
            aw.append(a[k] * wd)
            bw.append(b[k] * wd)
        a_all = np.vstack(aw)
        return np.linalg.lstsq(a_all, np.concatenate(bw), rcond=None)[0], \
            np.linalg.inv(a_all.T @ a_all)

    for it in range(4):
        sol, cov = solve(it > 0)            # the statics join once a first solution exists
        for g, (a, b) in enumerate(groups):
            r = b - a @ sol
            med = np.median(r[keep[g]]) if it else np.median(r)
            mad = 1.4826 * np.median(np.abs(r - med)[keep[g]] if it else np.abs(r - med))
            keep[g] = np.abs(r - med) <= 3.0 * (mad + 1e-6)
            if g == 1:
                sigma[1] = max(mad, 0.05)
    if len(groups) == 1:
        return VerticalFit(sol[:2], float(sol[2]), cov, 0)
    # the statics' z against the moving returns' alone: nested estimates, so the difference's
    # variance is the difference of their variances
    alone, cov_alone = solve(False)
    d = sol[2] - alone[2]
    if sol[3] - sol[4] < cfg.static_height_gap or d * d > cfg.static_consistency ** 2 * max(
            cov_alone[2, 2] - cov[2, 2], 1e-12):
        return fit_vertical(lev, xy_l, road, allowed, tilt, z_prior, cfg)
    return VerticalFit(sol[:2], float(sol[2]), cov, int(keep[1].sum()))


def below_fov_floor(
    src: np.ndarray, r_tilt: np.ndarray, z: float, z_road: np.ndarray, vfov_deg: float
) -> np.ndarray:
    """Mask of points (N, 3, in S) whose whole vertical extent above the road is in view.

    Near the mast the lower edge of the vertical field of view (elevation -vfov/2 in S) passes
    above the road, so only the upper parts of vehicles return detections there and their
    heights are biased high. A point qualifies when, along its azimuth, that edge reaches the
    road (height ``z_road`` (N,) m in L) before the point's horizontal distance, for the sensor at
    height ``z`` (m in L) with tilt ``r_tilt``.
    """
    az = np.arctan2(src[:, 1], src[:, 0])
    e = -0.5 * np.deg2rad(vfov_deg)
    ce = np.cos(e)
    ray = np.column_stack([ce * np.cos(az), ce * np.sin(az), np.full_like(az, np.sin(e))])
    ray = ray @ r_tilt.T
    lev = src @ r_tilt.T
    rho = np.hypot(lev[:, 0], lev[:, 1])
    edge = z + ray[:, 2] / np.maximum(np.hypot(ray[:, 0], ray[:, 1]), 1e-9) * rho
    return edge <= z_road


def rodrigues(w: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (rad)."""
    th = float(np.linalg.norm(w))
    if th < 1e-12:
        return np.eye(3)
    k = w / th
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(th) * kx + (1.0 - np.cos(th)) * kx @ kx
