"""Field of view, birth zones, lane headings and the initial state of a new track (frame C).

Frame C is the radar frame after ``T_coarse`` (S -> L estimate), so it approximates L within the
coarse error: the lanelet map (L) is used in C as is, for birth zones and heading priors.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from fgloc.geo import wrap_angle
from fgloc.scenario import Lanelet

#: spacing (m) of the centre-line samples used for headings and FOV entries
LANE_STEP: float = 1.0
#: a lanelet starting within this distance (m) of another's end continues it
CONNECT_TOL: float = 1.0


@dataclass(frozen=True)
class FieldOfView:
    """Horizontal FOV sector in C: sensor position (2,), boresight yaw (rad), half angle (rad),
    max range (m), and the near blind range (m): closer than min_range the lower edge of the
    vertical FOV passes above the vehicle bodies (the mast looks over them)."""

    sensor: np.ndarray
    boresight: float
    half_angle: float
    max_range: float
    min_range: float = 0.0

    @staticmethod
    def of(T_S_to_C: np.ndarray, hfov_deg: float, max_range: float, vfov_deg: float = 180.0,
           reflection_height: float = 0.0) -> FieldOfView:
        """From the S -> C pose; min_range from the sensor height above C's z = 0 (the road
        near the mast in L) minus reflection_height (m), the boresight depression and
        vfov_deg."""
        T = np.asarray(T_S_to_C, dtype=float)
        R = T[:3, :3]
        lower = np.arcsin(np.clip(-R[2, 0], -1.0, 1.0)) + np.deg2rad(vfov_deg) / 2.0
        drop = T[2, 3] - reflection_height
        min_range = drop / np.tan(lower) if 0.0 < lower < np.pi / 2 and drop > 0 else 0.0
        return FieldOfView(T[:2, 3].copy(), float(np.arctan2(R[1, 0], R[0, 0])),
                           np.deg2rad(hfov_deg) / 2.0, float(max_range), float(min_range))

    def blind(self, p: np.ndarray) -> np.ndarray:
        """(n,) points (n, 2) in the near blind range."""
        return np.linalg.norm(np.asarray(p) - self.sensor, axis=-1) < self.min_range

    def outside_distance(self, p: np.ndarray) -> np.ndarray:
        """(n,) how far (m, about) the points (n, 2) are outside the sector (<= 0 inside)."""
        return self._outside_range(p)[0]

    def _outside_range(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`outside_distance` and the range (n,) (m) from the sensor."""
        d = np.asarray(p) - self.sensor
        r = np.sqrt(d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1])
        off = np.abs(wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - self.boresight))
        lateral = r * np.sin(np.clip(off - self.half_angle, 0.0, np.pi / 2))
        return np.maximum(np.where(off > self.half_angle, lateral, -np.inf),
                          r - self.max_range), r

    def contains(self, p: np.ndarray) -> np.ndarray:
        return self.outside_distance(p) <= 0.0

    def seen(self, p: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """(n,) points (n, 2) inside the sector (or at most ``margin`` m outside it) and beyond
        the blind range (with margin 0 the same as ``contains(p) & ~blind(p)``, one pass)."""
        out, r = self._outside_range(p)
        return (out <= margin) & (r >= self.min_range)


@dataclass(frozen=True)
class LaneHeadings:
    """Lanelet centre-line samples (n, 2) in C with their driving direction (n,) rad."""

    xy: np.ndarray
    heading: np.ndarray
    tree: cKDTree

    @staticmethod
    def of(lanelets: list[Lanelet]) -> LaneHeadings:
        """Samples of every driving direction (:func:`driven_centrelines`)."""
        xy, hd = [], []
        for c in driven_centrelines(lanelets):
            d = np.gradient(c, axis=0)
            xy.append(c)
            hd.append(np.arctan2(d[:, 1], d[:, 0]))
        pts = np.vstack(xy) if xy else np.zeros((0, 2))
        return LaneHeadings(pts, np.concatenate(hd) if hd else np.zeros(0), cKDTree(pts))

    def headings_near(self, p: np.ndarray, radius: float, z: np.ndarray, doppler: np.ndarray,
                      rng: np.ndarray, sensor: np.ndarray, sigma_doppler: float,
                      max_speed: float, max_yawrate: float, max_hypotheses: int = 1,
                      margin: float = 0.0, separation: float = np.pi) -> np.ndarray:
        """Heading hypotheses (h,) (rad; h <= max_hypotheses, empty if no lanelet is near) of a
        new cluster at p (2,) from the centre-line samples within radius (m) of it.

        z (k, 2) the cluster's detections, doppler (k,) m/s, rng (k,) 3D ranges, sensor (2,).
        A sample is ruled out when the cluster's Doppler, fitted by the best rigid motion
        along its direction (:func:`doppler_misfit`), leaves a residual sum of squares larger
        than the best sample's by more than ``(3 sigma_doppler)^2`` (a lane driven the other
        way, or one across the line of sight that would need an implausible speed). The first
        hypothesis is the nearest sample left; further ones are samples left at most
        ``margin`` (m) farther away whose heading differs by more than ``separation`` (rad)
        from every hypothesis before them: where lanes cross (a junction box) the cluster's
        position cannot tell them apart, and with a free yaw rate one frame's Doppler cannot
        either (a rotation about the sensor changes no Doppler)."""
        if len(self.xy) == 0:
            return np.zeros(0)
        idx = np.asarray(self.tree.query_ball_point(p, radius), dtype=np.int64)
        if not len(idx):
            return np.zeros(0)
        dist = np.linalg.norm(self.xy[idx] - p, axis=1)
        heading = self.heading[idx]
        rss = doppler_misfit(z, doppler, rng, sensor, heading, max_speed, max_yawrate)
        ok = rss <= rss.min() + (3.0 * sigma_doppler) ** 2
        order = np.argsort(np.where(ok, dist, np.inf))[: int(ok.sum())]
        order = order[dist[order] <= dist[order[0]] + margin]
        out = [float(heading[order[0]])]
        for i in order[1:]:
            if len(out) >= max_hypotheses:
                break
            if np.all(np.abs(wrap_angle(heading[i] - np.asarray(out))) > separation):
                out.append(float(heading[i]))
        return np.asarray(out)


def doppler_misfit(z: np.ndarray, doppler: np.ndarray, rng: np.ndarray, sensor: np.ndarray,
                   headings: np.ndarray, max_speed: float, max_yawrate: float) -> np.ndarray:
    """(c,) residual sum of squares ((m/s)^2) of the Doppler (k,) (m/s, positive away from the
    sensor) of the detections z (k, 2) (3D ranges rng (k,)) about the best rigid motion with
    each heading (c,) (rad): speed v in [0, max_speed] (m/s, forwards only: a lane is driven
    one way) and yaw rate w in [-max_yawrate, max_yawrate] (rad/s) about the detections'
    centroid, ``doppler_i = (v u(heading) + w e_z x (z_i - centroid)) . (z_i - sensor) / rng_i``
    (:func:`factors.measurement.range_rate`), fitted by least squares with the bounds applied
    in turn (v, then w given v, then v given w)."""
    z = np.asarray(z, dtype=float)
    d = np.asarray(doppler, dtype=float)
    los = (z - sensor) / np.asarray(rng, dtype=float)[:, None]                  # (k, 2)
    rel = z - z.mean(axis=0)
    w_col = rel[:, 0] * los[:, 1] - rel[:, 1] * los[:, 0]                       # (k,)
    h = np.stack([np.cos(headings), np.sin(headings)], axis=1)                  # (c, 2)
    g = los @ h.T                                                               # (k, c)
    gg, gw, ww = np.sum(g * g, axis=0), g.T @ w_col, float(w_col @ w_col)
    gd, wd = g.T @ d, float(w_col @ d)
    det = gg * ww - gw * gw
    ok = det > 1e-9 * np.maximum(gg * ww, 1e-12)
    v = np.where(ok, (ww * gd - gw * wd) / np.where(ok, det, 1.0),
                 gd / np.maximum(gg, 1e-12))
    v = np.clip(v, 0.0, max_speed)
    w = np.clip((wd - gw * v) / max(ww, 1e-12), -max_yawrate, max_yawrate)
    v = np.clip((gd - gw * w) / np.maximum(gg, 1e-12), 0.0, max_speed)
    r = d[:, None] - g * v - w_col[:, None] * w
    return np.sum(r * r, axis=0)


def _centreline(ll: Lanelet) -> np.ndarray:
    length = float(np.sum(np.linalg.norm(np.diff(ll.left[:, :2], axis=0), axis=1)))
    return ll.centerline(max(2, int(np.ceil(length / LANE_STEP)) + 1))


def driven_centrelines(lanelets: list[Lanelet]) -> list[np.ndarray]:
    """The lanelets' centre lines (m, 2) sampled about ``LANE_STEP`` m apart in each direction
    a vehicle drives them: every lanelet's own direction, and a two-way lanelet's (tag
    ``one_way`` = no) also backwards (a two-way street mapped as one lanelet is driven both
    ways; where on it each direction keeps is the lane models' business, not the births')."""
    out = []
    for ll in lanelets:
        c = _centreline(ll)
        out += [c, c[::-1]] if ll.two_way else [c]
    return out


@dataclass(frozen=True)
class BirthZones:
    """Discs in C: centres (k, 2), radii (k,), yaw prior (k,) rad."""

    centre: np.ndarray
    radius: np.ndarray
    yaw: np.ndarray

    def __len__(self) -> int:
        return int(self.centre.shape[0])

    def locate(self, p: np.ndarray) -> int | None:
        """Index of the zone containing p (2,) (nearest centre), or None."""
        if len(self) == 0:
            return None
        d = np.linalg.norm(self.centre - p, axis=1)
        i = int(np.argmin(d))
        return i if d[i] <= self.radius[i] else None

    @staticmethod
    def explicit(zones: list[list[float]]) -> BirthZones:
        """From [x, y, radius, yaw_deg] rows (L == C up to the coarse error)."""
        z = np.asarray(zones, dtype=float).reshape(-1, 4)
        return BirthZones(z[:, :2], z[:, 2], np.deg2rad(z[:, 3]))

    @staticmethod
    def from_map(lanelets: list[Lanelet], fov: FieldOfView, radius: float,
                 depth: float) -> BirthZones:
        """Zones where lanelet centre lines enter the FOV sector (the angular edges or the
        range limit), ``depth`` m along the lane into it, and where a lanelet without a
        predecessor starts inside the FOV; the yaw prior is the lane direction there. Two-way
        lanelets count once per direction (:func:`driven_centrelines`); a line ending where
        another starts precedes it only when it leads on in the same direction (within 90
        deg), not when it comes back (a two-way lanelet's other direction)."""
        lines = driven_centrelines(lanelets)
        starts = np.array([c[0] for c in lines]) if lines else np.zeros((0, 2))
        ends = np.array([c[-1] for c in lines]) if lines else np.zeros((0, 2))
        end_tree = cKDTree(ends) if len(ends) else None
        out: list[tuple[float, float, float]] = []
        for c, s in zip(lines, starts):
            inside = fov.contains(c)
            prev_inside = np.concatenate([[False], inside[:-1]])
            if end_tree is not None and inside[0]:
                pred = [j for j in end_tree.query_ball_point(s, CONNECT_TOL)
                        if np.dot(lines[j][-1] - lines[j][-2], c[1] - c[0]) > 0.0]
                # continuation of an in-FOV predecessor: not an entry
                prev_inside[0] = any(fov.contains(lines[j][-2:-1])[0] for j in pred)
            seg = np.linalg.norm(np.diff(c, axis=0), axis=1)
            arc = np.concatenate([[0.0], np.cumsum(seg)])
            for i in np.flatnonzero(inside & ~prev_inside):
                k = int(np.searchsorted(arc, arc[i] + depth))
                k = min(k, len(c) - 1)
                d = c[min(k + 1, len(c) - 1)] - c[max(k - 1, 0)]
                out.append((c[k, 0], c[k, 1], float(np.arctan2(d[1], d[0]))))
        if not out:
            return BirthZones(np.zeros((0, 2)), np.zeros(0), np.zeros(0))
        a = np.asarray(out)
        return BirthZones(a[:, :2], np.full(len(a), radius), a[:, 2])



def initial_kinematics(z: np.ndarray, doppler: np.ndarray, rng: np.ndarray, yaw: float,
                       sensor: np.ndarray, length: float, width: float,
                       default_speed: float,
                       noise: float = 0.0) -> tuple[np.ndarray, float, float, np.ndarray]:
    """Centre (2,), yaw (rad), speed (m/s) and box size (2,) (length, width; m) of a new track
    from its first cluster.

    z (k, 2) detections in C, doppler (k,) m/s, rng (k,) 3D ranges, yaw the heading prior.
    Speed: median of doppler / (u(yaw) . line of sight) over detections where the heading is
    not across the line of sight, else ``default_speed``; a negative speed flips the heading.
    Centre: the box of size max(prior, cluster extent - 2 noise) per axis of the heading frame
    whose sensor-side edges coincide with the cluster's (a radar sees the near sides only);
    noise (m) is the detections' position std. dev., by which the extent of a few noisy
    detections exceeds the vehicle's on each side (far out, azimuth noise alone spreads a
    car's detections wider than a truck).
    """
    h = np.array([np.cos(yaw), np.sin(yaw)])
    los = z - sensor
    proj = (los @ h) / rng
    ok = np.abs(proj) > 0.3
    v = float(np.median(doppler[ok] / proj[ok])) if ok.any() else default_speed
    if v < 0:
        yaw, v, h = yaw + np.pi, -v, -h
    axes = np.stack([h, [-h[1], h[0]]])                         # (2, 2): long, lateral
    q = z @ axes.T
    lo, hi = q.min(axis=0), q.max(axis=0)
    size = np.maximum([length, width], hi - lo - 2.0 * noise)
    s = axes @ sensor
    near_lo = s < 0.5 * (lo + hi)
    mid = np.where(near_lo, lo + size / 2, hi - size / 2)
    return mid @ axes, float(wrap_angle(yaw)), min(v, 40.0), size
