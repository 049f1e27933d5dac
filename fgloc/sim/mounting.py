"""Sensor mounting: a mast at the roadside looking at the junction / along the road."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgloc.geo import se3_from_pose, wrap_angle
from fgloc.sim.config import SensorSimConfig
from fgloc.sim.roads import RoadArea, RoadNetwork
from fgloc.sim.terrain import Terrain


@dataclass
class Mounting:
    """True mounting: mast foot xy (m), height above the road (m), yaw/pitch/roll (rad;
    pitch > 0 = boresight down)."""

    xy: np.ndarray
    height: float
    yaw: float
    pitch: float
    roll: float

    def pose(self, terrain: Terrain) -> np.ndarray:
        """4x4 transform S -> L (sensor at ``height`` above the road surface under the mast)."""
        z = float(terrain.road(self.xy[None])[0]) + self.height
        return se3_from_pose(self.xy[0], self.xy[1], z, self.yaw, self.pitch, self.roll)


def place_sensor(rng: np.random.Generator, cfg: SensorSimConfig, net: RoadNetwork,
                 area: RoadArea) -> Mounting:
    """Mast beside a random anchor of the network, clear of every lane, facing its target."""
    for _ in range(100):
        anchor = net.anchors[int(rng.integers(len(net.anchors)))]
        side = float(rng.choice(anchor.sides))
        setback = rng.uniform(*cfg.setback)
        normal = np.array([-np.sin(anchor.tangent), np.cos(anchor.tangent)])
        xy = anchor.point + side * (anchor.half_width + setback) * normal
        if area.clearance(xy[None])[0] >= 0.9 * cfg.setback[0]:
            break
    else:
        raise RuntimeError("no roadside position found for the sensor")
    look = anchor.target - xy
    yaw = float(np.arctan2(look[1], look[0])) + np.deg2rad(rng.uniform(-1, 1) * cfg.yaw_jitter_deg)
    return Mounting(
        xy,
        float(rng.uniform(*cfg.mast_height)),
        float(wrap_angle(yaw)),
        float(np.deg2rad(rng.uniform(*cfg.pitch_deg))),
        float(np.deg2rad(rng.uniform(-1, 1) * cfg.roll_deg)),
    )
