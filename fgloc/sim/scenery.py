"""Static objects beside the roads: buildings (boxes), trees and poles, in L.

Placement is by rejection sampling (one loop iteration per candidate object, never per point):
objects keep clear of the road, of each other and of the sensor mast.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgloc.sim.config import AlsSimConfig
from fgloc.sim.roads import RoadArea, RoadNetwork


def box_corners(centre: np.ndarray, yaw: np.ndarray, length: np.ndarray,
                width: np.ndarray) -> np.ndarray:
    """(..., 4, 2) CCW corners of oriented rectangles (front-right, front-left, rear-left,
    rear-right) from centres (..., 2), yaw (...) rad, length and width (...) m."""
    sx = np.array([0.5, 0.5, -0.5, -0.5])
    sy = np.array([-0.5, 0.5, 0.5, -0.5])
    lx = np.asarray(length)[..., None] * sx
    ly = np.asarray(width)[..., None] * sy
    c, s = np.cos(yaw)[..., None], np.sin(yaw)[..., None]
    x = np.asarray(centre)[..., 0:1] + c * lx - s * ly
    y = np.asarray(centre)[..., 1:2] + s * lx + c * ly
    return np.stack([x, y], axis=-1)


@dataclass
class Scenery:
    """Buildings: centre (b, 2), size (b, 2) length/width, yaw (b,), height (b,) above ground.
    Trees: centre (t, 2), crown radius (t,), height (t,). Poles: (p, 2) positions, height (p,)."""

    building_centre: np.ndarray
    building_size: np.ndarray
    building_yaw: np.ndarray
    building_height: np.ndarray
    tree_centre: np.ndarray
    tree_radius: np.ndarray
    tree_height: np.ndarray
    pole_xy: np.ndarray
    pole_height: np.ndarray

    def building_corners(self) -> np.ndarray:
        """(b, 4, 2) CCW footprint corners."""
        return box_corners(self.building_centre, self.building_yaw, self.building_size[:, 0],
                           self.building_size[:, 1])


def _footprint_grid(centre: np.ndarray, size: np.ndarray, yaw: float) -> np.ndarray:
    """(25, 2) points covering a rectangle (for clearance checks)."""
    g = np.linspace(-0.5, 0.5, 5)
    u, v = np.meshgrid(g * size[0], g * size[1])
    c, s = np.cos(yaw), np.sin(yaw)
    return centre + np.column_stack([c * u.ravel() - s * v.ravel(), s * u.ravel() + c * v.ravel()])


def _place_buildings(rng: np.random.Generator, cfg: AlsSimConfig, area: RoadArea,
                     centre: np.ndarray) -> tuple[np.ndarray, ...]:
    """Randomly oriented boxes inside the tile around ``centre`` (the mast), clear of the road,
    the mast and each other; returns centres (b, 2), sizes (b, 2), yaws (b,)."""
    placed: list[tuple[np.ndarray, np.ndarray, float]] = []
    half = cfg.extent / 2.0
    for _ in range(60 * cfg.buildings):
        if len(placed) == cfg.buildings:
            break
        c = centre + rng.uniform(-half, half, 2)
        size = rng.uniform(*cfg.building_size, 2)
        yaw = rng.uniform(-np.pi, np.pi)
        pts = _footprint_grid(c, size, yaw)
        radius = 0.5 * np.hypot(*size)
        if (np.any(np.abs(pts - centre) > half)
                or area.clearance(pts, cfg.building_clearance).min() < cfg.building_clearance
                or np.linalg.norm(c - centre) < radius + 5.0
                or any(np.linalg.norm(c - q) < radius + 0.5 * np.hypot(*sz) + 2.0
                       for q, sz, _ in placed)):
            continue
        placed.append((c, size, yaw))
    if not placed:
        return np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0)
    return (np.array([p[0] for p in placed]), np.array([p[1] for p in placed]),
            np.array([p[2] for p in placed]))


def place_scenery(rng: np.random.Generator, cfg: AlsSimConfig, net: RoadNetwork,
                  area: RoadArea, sensor_xy: np.ndarray) -> Scenery:
    """Buildings, trees and poles around ``sensor_xy`` within the ALS extent."""
    b_centre, b_size, b_yaw = _place_buildings(rng, cfg, area, sensor_xy)
    b_height = rng.uniform(*cfg.building_height, len(b_yaw))
    # trees: candidates everywhere, keep those clear of roads, buildings and the mast
    n_cand = 20 * cfg.trees
    cand = sensor_xy + rng.uniform(-cfg.extent / 2, cfg.extent / 2, (n_cand, 2))
    radius = rng.uniform(*cfg.crown_radius, n_cand)
    ok = area.clearance(cand, 10.0) > radius + 0.5
    ok &= np.linalg.norm(cand - sensor_xy, axis=1) > radius + 3.0
    if len(b_yaw):
        d_b = np.linalg.norm(cand[:, None] - b_centre[None], axis=2)
        ok &= np.all(d_b > 0.5 * np.hypot(b_size[:, 0], b_size[:, 1]) + radius[:, None], axis=1)
    idx = np.flatnonzero(ok)[: cfg.trees]
    t_centre, t_radius = cand[idx], radius[idx]
    t_height = rng.uniform(*cfg.tree_height, len(idx))
    # poles: beside the curbs, 1-2.5 m off the road edge
    edge, normal = net.curb_line(1.0)
    n_cand = 20 * max(cfg.poles, 1)
    pick = rng.integers(0, len(edge), n_cand)
    cand = edge[pick] + rng.uniform(1.0, 2.5, n_cand)[:, None] * normal[pick]
    ok = (area.clearance(cand, 5.0) > 0.8) & (np.linalg.norm(cand - sensor_xy, axis=1) > 3.0)
    ok &= np.max(np.abs(cand - sensor_xy), axis=1) < cfg.extent / 2
    poles = cand[np.flatnonzero(ok)[: cfg.poles]]
    return Scenery(b_centre, b_size, b_yaw, b_height, t_centre, t_radius, t_height, poles,
                   rng.uniform(4.0, 10.0, len(poles)))
