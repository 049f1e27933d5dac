"""4D radar sensor model: vehicle reflections, static clutter, false alarms, occlusion, noise.

Per frame (vectorized over all frames at once):

* vehicles: the footprint edges facing the sensor (back-face culling) reflect; the expected
  count is ``points_per_degree`` x the vehicle's angular extent (or ``returns_at_reference``
  x (reference_range / range) ** returns_exponent) x the detection probability (logistic in
  range), split over the visible edges by their projected length, with a share concentrated
  at the corner nearest to the sensor (or at every visible corner) and optionally a share at
  the wheels of the visible long side, and optionally a share on the roof (inside the
  footprint, at the roof's height); heights from ``return_height`` (default between 0.3 m
  and 90 % of the roof).
  Doppler is the range rate of the rigid-body point velocity ``v_c + yawrate x (p - c)``.
* static clutter: persistent scatterers on curbs, poles, building facades and tree trunks,
  each detected per frame with a probability scaled to ``clutter_per_frame``.
* occlusion: a point is dropped when its line of sight passes through another vehicle's or a
  building's box below the box's roof height.
* multipath ghosts (``ghost_fraction`` > 0, default off): a building facade facing the sensor
  mirrors the vehicle returns in front of it; the double bounce shows at the return's mirror
  image behind the facade, moving mirrored, where the sight line to the image meets the
  facade below its top. Each visible vehicle return is mirrored by each facade with
  probability ``ghost_fraction``, ``GHOST_LOSS_DB`` weaker. The ghosts and their noise come
  from a random generator of their own, so every other detection is the same as without
  them.
* noise in range, azimuth, elevation and doppler; points outside the FOV or max range after
  noise are dropped. False alarms are uniform in the FOV with random doppler.

Sources: track id (>= 0) for vehicle detections, CLUTTER, FALSE_ALARM and GHOST otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgloc.geo import wrap_angle
from fgloc.scenario import RadarData, TrackTruth
from fgloc.sim.config import RadarSimConfig
from fgloc.sim.roads import RoadNetwork
from fgloc.sim.scenery import Scenery, box_corners
from fgloc.sim.terrain import Terrain
from fgloc.sim.traffic import VEHICLE_CLASSES

CLUTTER = -1
FALSE_ALARM = -2
GHOST = -3
#: how much weaker (dB) a multipath ghost returns than the vehicle return it mirrors
GHOST_LOSS_DB = 6.0
#: occluder key of "no box" / padding
NO_BOX = -1
#: points per chunk in the occlusion test (memory bound)
CHUNK = 65536
#: roof height (m above the road) per vehicle class index
ROOF_HEIGHT = np.array([vc.height for vc in VEHICLE_CLASSES])


@dataclass
class Points:
    """Candidate reflections in L: frame (n,), xyz (n, 3), velocity xy (n, 2) m/s, true extra
    doppler (n,) m/s (clutter jitter), mean rcs (n,) dBsm, source (n,), own box key (n,)."""

    frame: np.ndarray
    xyz: np.ndarray
    vel: np.ndarray
    doppler_extra: np.ndarray
    rcs: np.ndarray
    source: np.ndarray
    own: np.ndarray

    def take(self, idx: np.ndarray) -> Points:
        return Points(*(getattr(self, f)[idx] for f in self.__dataclass_fields__))

    @staticmethod
    def concat(parts: list[Points]) -> Points:
        return Points(*(np.concatenate([getattr(p, f) for p in parts])
                        for f in Points.__dataclass_fields__))


@dataclass
class Boxes:
    """Occluders per frame: corners (F, K, 4, 2) CCW (NaN padding), top height (F, K) in L,
    key (F, K) int (track id, or -2 - building index; NO_BOX for padding)."""

    corners: np.ndarray
    top: np.ndarray
    key: np.ndarray

    def with_static(self, corners: np.ndarray, top: np.ndarray, key: np.ndarray) -> Boxes:
        """These boxes plus static ones (b, 4, 2), (b,), (b,) present in every frame."""
        f = self.corners.shape[0]
        joined = [np.concatenate([mine, np.broadcast_to(extra, (f, *extra.shape))], axis=1)
                  for mine, extra in ((self.corners, corners), (self.top, top), (self.key, key))]
        return Boxes(*joined)


def detection_probability(r: np.ndarray, cfg: RadarSimConfig) -> np.ndarray:
    """Logistic fall-off: 0.5 at range_half_detection * max_range, 0 beyond max_range."""
    r50 = cfg.range_half_detection * cfg.max_range
    p = 1.0 / (1.0 + np.exp((np.asarray(r) - r50) / cfg.range_falloff))
    return np.where(np.asarray(r) <= cfg.max_range, p, 0.0)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


# --------------------------------------------------------------------------------------------
# vehicles
# --------------------------------------------------------------------------------------------
@dataclass
class VehicleRows:
    """One row per (vehicle, frame): frame, track id, class, centre (2), yaw, v, yawrate,
    length, width (SI units, L)."""

    frame: np.ndarray
    track: np.ndarray
    kind: np.ndarray
    centre: np.ndarray
    yaw: np.ndarray
    v: np.ndarray
    yawrate: np.ndarray
    length: np.ndarray
    width: np.ndarray

    @staticmethod
    def from_tracks(tracks: list[TrackTruth], kinds: np.ndarray, rate: float) -> VehicleRows:
        if not tracks:
            e = np.zeros(0)
            ei = np.zeros(0, dtype=np.int64)
            return VehicleRows(ei, ei, ei, np.zeros((0, 2)), e, e, e, e, e)
        st = np.vstack([t.states for t in tracks])
        n = [len(t.states) for t in tracks]
        track, kind, length, width = (np.repeat(np.asarray(v), n) for v in (
            [t.id for t in tracks], kinds, [t.length for t in tracks], [t.width for t in tracks]))
        return VehicleRows(np.rint(st[:, 0] * rate).astype(np.int64), track, kind, st[:, 1:3],
                           st[:, 3], st[:, 4], st[:, 5], length, width)

    def corners(self) -> np.ndarray:
        return box_corners(self.centre, self.yaw, self.length, self.width)


def expected_returns(cfg: RadarSimConfig, extent_deg: np.ndarray, rng: np.ndarray) -> np.ndarray:
    """Expected detections per vehicle and frame at centre range ``rng`` (m), angular extent
    ``extent_deg``: the returns-per-range model if set, else points_per_degree x extent; times
    the detection probability."""
    if cfg.returns_at_reference is None:
        base = cfg.points_per_degree * extent_deg
    else:
        base = cfg.returns_at_reference * (cfg.reference_range / np.maximum(rng, 1.0)) \
            ** cfg.returns_exponent
    return base * detection_probability(rng, cfg)


def _wheels(rng: np.random.Generator, cfg: RadarSimConfig, rows: VehicleRows,
            visible: np.ndarray, r: np.ndarray, u: np.ndarray, edge: np.ndarray,
            frac: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Move the share ``wheel_fraction`` of detections (``u`` in [corner_fraction,
    corner_fraction + wheel_fraction)) to an axle of the visible long side (edge 1 = left side
    from the front, edge 3 = right side from the rear); returns the new edge and fraction and
    the (m,) mask of the moved detections."""
    wheel = (u >= cfg.corner_fraction) & (u < cfg.corner_fraction + cfg.wheel_fraction)
    side = np.where(visible[r, 1], 1, 3)
    wheel &= visible[r, 1] | visible[r, 3]
    n = int(wheel.sum())
    from_front = np.where(rng.random(n) < 0.5, 1.0 / 6.0, 5.0 / 6.0)
    f = from_front + rng.normal(0.0, cfg.wheel_spread, n) / rows.length[r[wheel]]
    edge, frac = edge.copy(), frac.copy()
    edge[wheel] = side[wheel]
    frac[wheel] = np.clip(np.where(side[wheel] == 1, f, 1.0 - f), 0.0, 1.0)
    return edge, frac, wheel


def _roof(rng: np.random.Generator, cfg: RadarSimConfig, rows: VehicleRows, r: np.ndarray,
          p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Move the share ``roof_fraction`` of the detections (rows ``r`` (m,) of ``rows``, at
    ``p`` (m, 2) in L) to points uniform over their vehicle's footprint; returns the new
    positions and the (m,) mask of the moved ones (their height is the roof's)."""
    roof = rng.random(len(r)) < cfg.roof_fraction
    k = r[roof]
    along = (rng.random(len(k)) - 0.5) * rows.length[k]
    across = (rng.random(len(k)) - 0.5) * rows.width[k]
    h = np.column_stack([np.cos(rows.yaw[k]), np.sin(rows.yaw[k])])
    p = p.copy()
    p[roof] = rows.centre[k] + along[:, None] * h + across[:, None] * np.column_stack(
        [-h[:, 1], h[:, 0]])
    return p, roof


def return_heights(rng: np.random.Generator, cfg: RadarSimConfig,
                   kind: np.ndarray) -> np.ndarray:
    """(m,) heights (m above the road) of vehicle returns of class indices ``kind``:
    ``cfg.return_height`` uniform and clipped to the roof, or 0.3 m to 90 % of the roof."""
    roof = ROOF_HEIGHT[kind]
    if cfg.return_height is None:
        return rng.uniform(0.3, 0.9 * roof)
    low, high = cfg.return_height
    return np.minimum(rng.uniform(low, high, len(kind)), roof)


def vehicle_points(rng: np.random.Generator, cfg: RadarSimConfig, rows: VehicleRows,
                   pose: np.ndarray, terrain: Terrain) -> Points:
    """Reflections on the visible footprint edges of every vehicle in every frame (rows wholly
    outside the horizontal FOV of the S -> L ``pose`` are skipped)."""
    s2 = pose[:2, 3]
    c = rows.corners()                                   # (R, 4, 2)
    e = np.roll(c, -1, axis=1) - c                       # edge vectors
    elen = np.linalg.norm(e, axis=2)
    mid = c + 0.5 * e
    normal = np.stack([e[..., 1], -e[..., 0]], axis=-1) / elen[..., None]
    visible = np.sum(normal * (s2 - mid), axis=2) > 0
    los = (mid - s2) / np.linalg.norm(mid - s2, axis=2, keepdims=True)
    weight = np.abs(_cross(e, los)) * visible            # projected visible length
    to_centre = rows.centre - s2
    centre_ang = np.arctan2(to_centre[:, 1], to_centre[:, 0])
    rel = wrap_angle(np.arctan2(c[..., 1] - s2[1], c[..., 0] - s2[0]) - centre_ang[:, None])
    extent = np.degrees(np.ptp(rel, axis=1))
    rng_c = np.linalg.norm(to_centre, axis=1)
    lam = expected_returns(cfg, extent, rng_c)
    boresight = np.arctan2(pose[1, 0], pose[0, 0])
    centre_rel = wrap_angle(centre_ang - boresight)
    half = np.deg2rad(cfg.hfov_deg / 2 + 3.0)
    outside = (centre_rel + rel.min(axis=1) > half) | (centre_rel + rel.max(axis=1) < -half)
    lam[(weight.sum(axis=1) <= 0) | outside] = 0.0
    count = rng.poisson(lam)
    r = np.repeat(np.arange(len(count)), count)
    m = len(r)
    cdf = np.cumsum(weight[r], axis=1)
    edge = np.minimum(((rng.random(m) * cdf[:, -1])[:, None] >= cdf).sum(axis=1), 3)
    length = elen[r, edge]
    along = rng.random(m)
    u = rng.random(m)
    corner = u < cfg.corner_fraction
    along[corner] = np.minimum(np.abs(rng.normal(0.0, cfg.corner_spread, corner.sum()))
                               / length[corner], 1.0)
    start = c[r, edge]
    end = c[r, (edge + 1) % 4]
    start_near = np.linalg.norm(start - s2, axis=1) <= np.linalg.norm(end - s2, axis=1)
    if cfg.corners == "visible":
        start_near[corner] = rng.random(int(corner.sum())) < 0.5
    frac = np.where(start_near, along, 1.0 - along)
    wheel = np.zeros(m, dtype=bool)
    if cfg.wheel_fraction > 0:
        edge, frac, wheel = _wheels(rng, cfg, rows, visible, r, u, edge, frac)
        start, end = c[r, edge], c[r, (edge + 1) % 4]
    p = start + frac[:, None] * (end - start)
    kind = rows.kind[r]
    roof = np.zeros(m, dtype=bool)
    if cfg.roof_fraction > 0:
        p, roof = _roof(rng, cfg, rows, r, p)
        wheel &= ~roof
    road = terrain.road(p)
    z = road + return_heights(rng, cfg, kind)
    z[roof] = road[roof] + ROOF_HEIGHT[kind[roof]]
    heading = np.column_stack([np.cos(rows.yaw[r]), np.sin(rows.yaw[r])])
    arm = p - rows.centre[r]
    vel = rows.v[r, None] * heading + rows.yawrate[r, None] * np.column_stack([-arm[:, 1],
                                                                              arm[:, 0]])
    if cfg.wheel_radius > 0 and wheel.any():
        # micro-Doppler: on a rolling wheel the point at height h moves at v h / R
        h = rng.uniform(0.0, 2.0 * cfg.wheel_radius, int(wheel.sum()))
        z[wheel] = road[wheel] + h
        vel[wheel] += ((h / cfg.wheel_radius - 1.0) * rows.v[r[wheel]])[:, None] * heading[wheel]
    rcs = np.array([vc.rcs for vc in VEHICLE_CLASSES])[kind]
    track = rows.track[r]
    return Points(rows.frame[r], np.column_stack([p, z]), vel, np.zeros(m), rcs, track, track)


def vehicle_boxes(rows: VehicleRows, n_frames: int, terrain: Terrain) -> Boxes:
    """Vehicle footprints padded per frame (F, Vmax)."""
    order = np.argsort(rows.frame, kind="stable")
    frame = rows.frame[order]
    counts = np.bincount(frame, minlength=n_frames)
    k = max(int(counts.max(initial=0)), 1)
    slot = np.arange(len(frame)) - np.repeat(np.cumsum(counts) - counts, counts)
    corners = np.full((n_frames, k, 4, 2), np.nan)
    top = np.full((n_frames, k), np.nan)
    key = np.full((n_frames, k), NO_BOX, dtype=np.int64)
    corners[frame, slot] = rows.corners()[order]
    top[frame, slot] = terrain.road(rows.centre[order]) + ROOF_HEIGHT[rows.kind[order]]
    key[frame, slot] = rows.track[order]
    return Boxes(corners, top, key)


# --------------------------------------------------------------------------------------------
# static clutter
# --------------------------------------------------------------------------------------------
def facing_facades(corners: np.ndarray, sensor: np.ndarray
                   ) -> list[tuple[np.ndarray, np.ndarray, int]]:
    """The facades of buildings ``corners`` (B, 4, 2) CCW in L that face the sensor at
    ``sensor`` (2+,): (first corner (2,), second corner (2,), building index) each, the
    sensor on the outer side of the edge (the right of a CCW edge)."""
    out = []
    for b, box in enumerate(corners):
        for a, c in zip(box, np.roll(box, -1, axis=0)):
            outward = np.array([c[1] - a[1], a[0] - c[0]])
            if np.dot(outward, sensor[:2] - 0.5 * (a + c)) > 0:
                out.append((a, c, b))
    return out


def ghost_points(rng: np.random.Generator, fraction: float, pts: Points,
                 corners: np.ndarray, top: np.ndarray, sensor: np.ndarray) -> Points:
    """Multipath ghosts (module docstring) of the vehicle points among ``pts`` (source >= 0):
    each facade of buildings ``corners`` (B, 4, 2) CCW with tops ``top`` (B,) m in L facing
    ``sensor`` (3,) mirrors each point in front of it with probability ``fraction``, where the
    sight line from the sensor to the mirror image crosses the facade below its top. The
    image moves with the mirrored velocity; source GHOST, no own box, rcs GHOST_LOSS_DB
    lower."""
    veh = pts.take(np.flatnonzero(pts.source >= 0))
    parts = [veh.take(np.zeros(0, dtype=np.int64))]
    for a, c, b in facing_facades(corners, sensor):
        along = c - a
        n = np.array([along[1], -along[0]]) / np.linalg.norm(along)      # outward unit normal
        pick = np.flatnonzero(rng.random(len(veh.xyz)) < fraction)
        cand = veh.take(pick)
        depth = (cand.xyz[:, :2] - a) @ n                                 # > 0: in front
        image = cand.xyz.copy()
        image[:, :2] -= 2.0 * depth[:, None] * n
        d_sensor = float((sensor[:2] - a) @ n)
        t = d_sensor / (d_sensor + depth)                    # sight line meets the facade
        hit = sensor + t[:, None] * (image - sensor)
        share = ((hit[:, :2] - a) @ along) / (along @ along)
        ok = (depth > 0.0) & (share >= 0.0) & (share <= 1.0) & (hit[:, 2] <= top[b])
        g = cand.take(np.flatnonzero(ok))
        g.xyz = image[ok]
        g.vel = g.vel - 2.0 * (g.vel @ n)[:, None] * n
        g.rcs = g.rcs - GHOST_LOSS_DB
        g.source = np.full(len(g.xyz), GHOST)
        g.own = np.full(len(g.xyz), NO_BOX)
        parts.append(g)
    return Points.concat(parts)


def static_scatterers(net: RoadNetwork, scn: Scenery, terrain: Terrain, sensor: np.ndarray,
                      curb_height: float) -> tuple[Points, np.ndarray]:
    """Persistent scatterers (frame -1): curbs (``curb_height`` m above the road), poles,
    facades facing the sensor, trunks, and their (n,) relative strengths."""
    parts: list[tuple[np.ndarray, float, float, int]] = []   # xyz, weight, rcs, own key
    curb, _ = net.curb_line(2.0)
    parts.append((np.column_stack([curb, terrain.road(curb) + curb_height]), 0.25, 0.0,
                  NO_BOX))
    for xy, h in zip(scn.pole_xy, scn.pole_height):
        zs = terrain.ground(xy[None]) + np.arange(0.5, h, 1.0)
        parts.append((np.column_stack([np.tile(xy, (len(zs), 1)), zs]), 1.0, 10.0, NO_BOX))
    for a, c, b in facing_facades(scn.building_corners(), sensor):
        f = np.linspace(0.0, 1.0, max(2, int(np.linalg.norm(c - a) / 1.5)))
        xy = a + f[:, None] * (c - a)
        zs = np.arange(1.0, min(scn.building_height[b], 12.0), 2.0)
        grid = np.repeat(xy, len(zs), axis=0)
        z = terrain.ground(grid) + np.tile(zs, len(xy))
        parts.append((np.column_stack([grid, z]), 0.4, 15.0, -2 - b))
    for xy in scn.tree_centre:
        zs = terrain.ground(xy[None]) + np.array([0.8, 1.8])
        parts.append((np.column_stack([np.tile(xy, (2, 1)), zs]), 0.6, 5.0, NO_BOX))
    xyz = np.vstack([p[0] for p in parts])
    n = [len(p[0]) for p in parts]
    weight, rcs, own = (np.repeat([p[k] for p in parts], n) for k in (1, 2, 3))
    pts = Points(np.full(len(xyz), -1), xyz, np.zeros((len(xyz), 2)), np.zeros(len(xyz)),
                 rcs, np.full(len(xyz), CLUTTER), own.astype(np.int64))
    return pts, weight


def clutter_points(rng: np.random.Generator, cfg: RadarSimConfig, scat: Points,
                   weight: np.ndarray, sensor: np.ndarray, n_frames: int) -> Points:
    """Per-frame draws of the scatterers: about clutter_per_frame per frame in total."""
    p = weight * detection_probability(np.linalg.norm(scat.xyz - sensor, axis=1),
                                                   cfg)
    if p.sum() <= 0 or n_frames == 0:
        return scat.take(np.zeros(0, dtype=np.int64))
    n = int(rng.poisson(cfg.clutter_per_frame * n_frames))
    pts = scat.take(rng.choice(len(p), n, p=p / p.sum()))
    pts.frame = rng.integers(0, n_frames, n)
    pts.doppler_extra = rng.normal(0.0, cfg.clutter_doppler_sigma, n)
    return pts


# --------------------------------------------------------------------------------------------
# occlusion, measurement, false alarms
# --------------------------------------------------------------------------------------------
def occluded(pts: Points, sensor: np.ndarray, boxes: Boxes) -> np.ndarray:
    """(n,) True where the line of sight to a point crosses another box below its roof.

    Candidate (point, box) pairs come from an angular-interval and range test; only those get
    the exact segment-edge intersection test.
    """
    a = sensor[:2]
    centre = boxes.corners.mean(axis=2)
    to_c = centre - a
    dist_c = np.linalg.norm(to_c, axis=-1)
    u_c = to_c / dist_c[..., None]
    rel = boxes.corners - a
    cos_half = (np.sum(rel * u_c[..., None, :], axis=-1)
                / np.linalg.norm(rel, axis=-1)).min(axis=-1)
    r_low = dist_c - np.linalg.norm(boxes.corners - centre[..., None, :], axis=-1).max(axis=-1)
    out = np.zeros(len(pts.frame), dtype=bool)
    for lo in range(0, len(out), CHUNK):
        f, xyz, own = (x[lo:lo + CHUNK] for x in (pts.frame, pts.xyz, pts.own))
        d = xyz[:, :2] - a
        r = np.linalg.norm(d, axis=1)
        ux, uy = d[:, 0:1] / r[:, None], d[:, 1:2] / r[:, None]
        cand = ((ux * u_c[f, :, 0] + uy * u_c[f, :, 1] >= cos_half[f])
                & (r[:, None] > r_low[f]) & (boxes.key[f] != own[:, None]))
        i, k = np.nonzero(cand)
        corners = boxes.corners[f[i], k]                               # (P, 4, 2)
        e = np.roll(corners, -1, axis=1) - corners
        ac = corners - a
        di = d[i, None, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            den = _cross(di, e)
            t = _cross(ac, e) / den
            u = _cross(ac, di) / den
        z_los = sensor[2] + t * (xyz[i, 2, None] - sensor[2])
        hit = ((t > 0) & (t < 1) & (u >= 0) & (u <= 1)
               & (z_los < boxes.top[f[i], k][:, None])).any(axis=1)
        out[lo + i[hit]] = True
    return out


def measure(rng: np.random.Generator, cfg: RadarSimConfig, pose: np.ndarray,
            pts: Points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Noisy detections in S: xyz (n, 3), doppler (n,), and the (n,) mask of those inside the
    FOV and range after noise."""
    rel = pts.xyz - pose[:3, 3]
    r, az, el = to_spherical(rel @ pose[:3, :3])
    doppler = np.sum(pts.vel * rel[:, :2], axis=1) / r + pts.doppler_extra
    n = len(r)
    r = r + rng.normal(0.0, cfg.sigma_range, n)
    az = az + rng.normal(0.0, np.deg2rad(cfg.sigma_azimuth_deg), n)
    el = el + rng.normal(0.0, np.deg2rad(cfg.sigma_elevation_deg), n)
    doppler = doppler + rng.normal(0.0, cfg.sigma_doppler, n)
    return spherical_to_xyz(r, az, el), doppler, in_fov(r, az, el, cfg)


def in_fov(r: np.ndarray, az: np.ndarray, el: np.ndarray, cfg: RadarSimConfig,
           margin_deg: float = 0.0, margin_m: float = 0.0) -> np.ndarray:
    """Mask of (range m, azimuth rad, elevation rad) inside the field of view and range,
    optionally widened by ``margin_deg`` in angle and ``margin_m`` in range."""
    half_h = np.deg2rad(cfg.hfov_deg / 2 + margin_deg)
    half_v = np.deg2rad(cfg.vfov_deg / 2 + margin_deg)
    return ((np.abs(az) <= half_h) & (np.abs(el) <= half_v) & (r > 0.5)
            & (r <= cfg.max_range + margin_m))


def to_spherical(p_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Range (m), azimuth and elevation (rad) of (n, 3) points in S."""
    r = np.linalg.norm(p_s, axis=1)
    az = np.arctan2(p_s[:, 1], p_s[:, 0])
    el = np.arcsin(np.clip(p_s[:, 2] / np.maximum(r, 1e-9), -1.0, 1.0))
    return r, az, el


def spherical_to_xyz(r: np.ndarray, az: np.ndarray, el: np.ndarray) -> np.ndarray:
    ce = np.cos(el)
    return np.column_stack([r * ce * np.cos(az), r * ce * np.sin(az), r * np.sin(el)])


def false_alarms(rng: np.random.Generator, cfg: RadarSimConfig,
                 n_frames: int) -> tuple[np.ndarray, ...]:
    """Uniform false alarms in the FOV: frame, xyz (S), doppler, rcs."""
    n = int(rng.poisson(cfg.false_alarms_per_frame * n_frames))
    az = np.deg2rad(rng.uniform(-cfg.hfov_deg / 2, cfg.hfov_deg / 2, n))
    el = np.deg2rad(rng.uniform(-cfg.vfov_deg / 2, cfg.vfov_deg / 2, n))
    r = rng.uniform(1.0, cfg.max_range, n)
    dop = rng.uniform(-cfg.false_alarm_doppler, cfg.false_alarm_doppler, n)
    return rng.integers(0, n_frames, n), spherical_to_xyz(r, az, el), dop, rng.uniform(-10, 5, n)


def _pre_fov(pts: Points, pose: np.ndarray, cfg: RadarSimConfig) -> np.ndarray:
    """Noise-free FOV test with a margin (cheap pruning before occlusion)."""
    return in_fov(*to_spherical((pts.xyz - pose[:3, 3]) @ pose[:3, :3]), cfg, margin_deg=3.0,
                  margin_m=1.0)


def simulate_radar(rng: np.random.Generator, cfg: RadarSimConfig, pose: np.ndarray,
                   tracks: list[TrackTruth], kinds: np.ndarray, net: RoadNetwork,
                   scn: Scenery, terrain: Terrain, n_frames: int) -> tuple[RadarData, np.ndarray]:
    """All detections of ``n_frames`` frames at ``cfg.rate_hz`` and their sources."""
    sensor = pose[:3, 3]
    rows = VehicleRows.from_tracks(tracks, kinds, cfg.rate_hz)
    scat, weight = static_scatterers(net, scn, terrain, sensor, cfg.curb_height)
    seen = np.flatnonzero(_pre_fov(scat, pose, cfg))
    pts = Points.concat([vehicle_points(rng, cfg, rows, pose, terrain),
                         clutter_points(rng, cfg, scat.take(seen), weight[seen], sensor,
                                        n_frames)])
    pts = pts.take(np.flatnonzero(_pre_fov(pts, pose, cfg)))
    building_corners = scn.building_corners()
    building_top = terrain.ground(scn.building_centre) + scn.building_height
    boxes = vehicle_boxes(rows, n_frames, terrain).with_static(
        building_corners, building_top, -2 - np.arange(len(scn.building_height)))
    pts = pts.take(np.flatnonzero(~occluded(pts, sensor, boxes)))
    xyz, doppler, keep = measure(rng, cfg, pose, pts)
    if cfg.ghost_fraction > 0.0:
        own_rng = rng.spawn(1)[0]                     # the main stream's draws unchanged
        ghosts = ghost_points(own_rng, cfg.ghost_fraction, pts, building_corners,
                              building_top, sensor)
        g_xyz, g_doppler, g_keep = measure(own_rng, cfg, pose, ghosts)
        pts = Points.concat([pts, ghosts])
        xyz, doppler = np.vstack([xyz, g_xyz]), np.concatenate([doppler, g_doppler])
        keep = np.concatenate([keep, g_keep])
    fa_frame, fa_xyz, fa_dop, fa_rcs = false_alarms(rng, cfg, n_frames)
    frame = np.concatenate([pts.frame[keep], fa_frame])
    rcs = np.concatenate([pts.rcs[keep] + rng.normal(0.0, cfg.rcs_sigma, int(keep.sum())),
                          fa_rcs])
    source = np.concatenate([pts.source[keep], np.full(len(fa_frame), FALSE_ALARM)])
    order = np.argsort(frame, kind="stable")
    frame = frame[order].astype(np.int64)
    radar = RadarData(frame / cfg.rate_hz, np.vstack([xyz[keep], fa_xyz])[order],
                      np.concatenate([doppler[keep], fa_dop])[order], rcs[order], frame)
    return radar, source[order]
