"""Aerial laser scan synthesis: classified points over a square tile around the sensor.

ASPRS classes: 2 ground, 11 road surface (the paved area of every lanelet and the junction),
6 building (flat roofs), 5 high vegetation (tree crowns), 1 unclassified (wires, birds, noise).
Fully vectorized over points; loops only run over buildings (a handful).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from fgloc.scenario import BUILDING_CLASS, AlsCloud
from fgloc.sim.config import AlsSimConfig
from fgloc.sim.roads import RoadArea
from fgloc.sim.scenery import Scenery
from fgloc.sim.terrain import Terrain

GROUND, UNCLASSIFIED, HIGH_VEGETATION, ROAD = 2, 1, 5, 11


def _roofs(xy: np.ndarray, z: np.ndarray, cls: np.ndarray, scn: Scenery,
           terrain: Terrain) -> None:
    """Points inside a building footprint hit its flat roof (in place)."""
    for c, size, yaw, h in zip(scn.building_centre, scn.building_size, scn.building_yaw,
                               scn.building_height):
        r = 0.5 * np.hypot(*size)
        near = np.flatnonzero((np.abs(xy[:, 0] - c[0]) <= r) & (np.abs(xy[:, 1] - c[1]) <= r))
        d = xy[near] - c
        u = d[:, 0] * np.cos(yaw) + d[:, 1] * np.sin(yaw)
        v = -d[:, 0] * np.sin(yaw) + d[:, 1] * np.cos(yaw)
        inside = near[(np.abs(u) <= size[0] / 2) & (np.abs(v) <= size[1] / 2)]
        z[inside] = terrain.ground(c) + h
        cls[inside] = BUILDING_CLASS


def _crowns(rng: np.random.Generator, xy: np.ndarray, z: np.ndarray, cls: np.ndarray,
            scn: Scenery, canopy_hit: float) -> None:
    """Pulses inside a crown return from its dome-shaped top with probability canopy_hit."""
    if not len(scn.tree_radius):
        return
    d, idx = cKDTree(scn.tree_centre).query(xy, distance_upper_bound=scn.tree_radius.max(),
                                             workers=-1)
    near = np.zeros(len(xy), dtype=bool)
    fin = np.isfinite(d)
    near[fin] = d[fin] < scn.tree_radius[idx[fin]]
    hit = np.flatnonzero(near & (rng.random(len(xy)) < canopy_hit))
    r, h = scn.tree_radius[idx[hit]], scn.tree_height[idx[hit]]
    dome = np.sqrt(np.clip(1.0 - (d[hit] / r) ** 2, 0.0, 1.0))
    z[hit] += h * (0.55 + 0.45 * dome) - rng.uniform(0.0, 1.0, len(hit))
    cls[hit] = HIGH_VEGETATION


def synthesize_als(rng: np.random.Generator, cfg: AlsSimConfig, terrain: Terrain,
                   area: RoadArea, scn: Scenery, centre: np.ndarray) -> AlsCloud:
    """ALS tile of side ``cfg.extent`` centred on ``centre`` (L, m); float32 xyz in L."""
    half = cfg.extent / 2.0
    n = int(rng.poisson(cfg.density * cfg.extent**2))
    xy = centre + rng.uniform(-half, half, (n, 2))
    z = terrain.ground(xy)
    cls = np.full(n, GROUND, dtype=np.uint8)
    road = area.clearance(xy, 1.0) <= 0.0
    z[road] += terrain.road_raise
    cls[road] = ROAD
    _roofs(xy, z, cls, scn, terrain)
    _crowns(rng, xy, z, cls, scn, cfg.canopy_hit)
    odd = rng.random(n) < cfg.unclassified_fraction
    z[odd] += rng.uniform(0.5, 30.0, int(odd.sum()))
    cls[odd] = UNCLASSIFIED
    z += rng.normal(0.0, cfg.height_sigma, n)
    return AlsCloud(np.column_stack([xy, z]).astype(np.float32), cls)
