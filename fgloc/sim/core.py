"""simulate(): a whole synthetic scenario (radar, ALS, Lanelet2 map, sensor prior, truth).

Every random choice comes from one ``np.random.SeedSequence(seed)`` spawned into one
independent generator per stage, so the result is a pure function of
(case, seed, duration, vehicles, config), and changing e.g. the traffic settings leaves the
road layout, the sensor mounting and the ALS unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgloc.geo import LocalFrame
from fgloc.scenario import AlsCloud, GroundTruth, LaneletMap, Scenario, SensorConfig
from fgloc.sim.als import synthesize_als
from fgloc.sim.config import SimConfig
from fgloc.sim.mounting import Mounting, place_sensor
from fgloc.sim.radar import simulate_radar
from fgloc.sim.roads import RoadArea, RoadNetwork, build_network, to_lanelets
from fgloc.sim.scenery import Scenery, place_scenery
from fgloc.sim.terrain import Terrain
from fgloc.sim.traffic import VEHICLE_CLASSES, PathUsers, simulate_traffic

CASES = ("intersection", "tjunction", "curve", "straight")
_STAGES = ("road", "sensor", "site", "scenery", "als", "traffic", "radar")


@dataclass
class SimResult:
    """A scenario plus simulator-only knowledge: per-detection source (track id >= 0,
    -1 static clutter, -2 false alarm, -3 multipath ghost) and each track's vehicle class
    name."""

    scenario: Scenario
    source: np.ndarray
    vehicle_class: list[str]


def simulate(case: str, seed: int, duration: float = 60.0, vehicles: int | None = None,
             config: SimConfig | None = None) -> Scenario:
    """A synthetic scenario of ``duration`` s for one of CASES; see :func:`simulate_detailed`."""
    return simulate_detailed(case, seed, duration, vehicles, config).scenario


def simulate_detailed(case: str, seed: int, duration: float = 60.0, vehicles: int | None = None,
                      config: SimConfig | None = None) -> SimResult:
    """Simulate ``case`` (one of CASES) deterministically from ``seed``.

    vehicles: number of vehicles generated in total (None: Poisson arrivals every
    ``config.traffic.arrival_interval`` s on average). Vehicles whose life does not overlap
    the recording are dropped from the truth. All geometry is in the local frame L whose origin
    is the rounded approximate sensor position and the rounded ground height under the mast.
    """
    if case not in CASES:
        raise ValueError(f"unknown case {case!r}; expected one of {', '.join(CASES)}")
    if duration <= 0:
        raise ValueError(f"duration must be positive, got {duration}")
    cfg = config or SimConfig()
    rng = dict(zip(_STAGES, (np.random.default_rng(s)
                             for s in np.random.SeedSequence(seed).spawn(len(_STAGES)))))

    # layout and mast in the site frame (junction at the origin)
    net = build_network(case, rng["road"], cfg.road, cfg.sensor.junction_distance)
    mount = place_sensor(rng["sensor"], cfg.sensor, net, RoadArea(net))

    # world placement; L origin = rounded approximate mast position / ground height there
    site = rng["site"]
    centre_en = np.array([site.uniform(*cfg.site.east), site.uniform(*cfg.site.north)])
    centre_h = site.uniform(*cfg.site.ground_height)
    slope = site.uniform(*cfg.als.slope)
    downhill = site.uniform(-np.pi, np.pi)
    grad = slope * np.array([np.cos(downhill), np.sin(downhill)])
    approx_en = centre_en + mount.xy + site.normal(0.0, cfg.sensor.approx_position_sigma, 2)
    ground_at_mast = centre_h + float(grad @ mount.xy)
    frame = LocalFrame.around(approx_en[0], approx_en[1], ground_at_mast, cfg.site.crs)
    offset = centre_en - np.asarray(frame.origin[:2])
    net.translate(offset)
    mount.xy = mount.xy + offset
    terrain = Terrain(centre_h - float(grad @ offset) - frame.origin[2], grad, cfg.als.road_raise)
    area = RoadArea(net)

    scenery = place_scenery(rng["scenery"], cfg.als, net, area, mount.xy)
    als = synthesize_als(rng["als"], cfg.als, terrain, area, scenery, mount.xy)
    return drive_and_observe(rng["traffic"], rng["radar"], site, cfg, net, mount, terrain,
                             scenery, frame, approx_en, als, to_lanelets(net, terrain.road),
                             duration, vehicles)


def drive_and_observe(traffic_rng: np.random.Generator, radar_rng: np.random.Generator,
                      site_rng: np.random.Generator, cfg: SimConfig, net: RoadNetwork,
                      mount: Mounting, terrain: Terrain, scenery: Scenery, frame: LocalFrame,
                      approx_en: np.ndarray, als: AlsCloud, lanelets: LaneletMap,
                      duration: float,
                      vehicles: int | None, others: tuple[PathUsers, ...] = ()) -> SimResult:
    """The shared tail of every simulator: traffic on ``net`` for ``duration`` s, the radar's
    detections from the mast ``mount`` over ``terrain`` and ``scenery`` (all in the local
    frame L of ``frame``), the user's sensor prior (``approx_en``: approximate mast easting /
    northing in ``frame.crs``; a yaw guess drawn from ``site_rng``) and the ground truth;
    ``als`` and ``lanelets`` pass through to the scenario; ``others``: road users on ways of
    their own (:func:`fgloc.sim.traffic.simulate_traffic`)."""
    n_frames = max(1, int(round(duration * cfg.radar.rate_hz)))
    times = np.arange(n_frames) / cfg.radar.rate_hz
    traffic = simulate_traffic(traffic_rng, cfg.traffic, net, times, vehicles, others)
    pose = mount.pose(terrain)
    radar, source = simulate_radar(radar_rng, cfg.radar, pose, traffic.tracks, traffic.kinds,
                                   net, scenery, terrain, n_frames)
    yaw_guess = np.rad2deg(mount.yaw) + site_rng.normal(0.0, cfg.sensor.yaw_guess_sigma_deg)
    sensor = SensorConfig(
        approx_position=(float(approx_en[0]), float(approx_en[1])),
        crs=frame.crs,
        approx_height=round(mount.height * 2.0) / 2.0,
        yaw_guess_deg=float((yaw_guess + 180.0) % 360.0 - 180.0),
        hfov_deg=cfg.radar.hfov_deg,
        vfov_deg=cfg.radar.vfov_deg,
        max_range=cfg.radar.max_range,
    )
    scenario = Scenario(frame=frame, sensor=sensor, radar=radar, als=als,
                        lanelets=lanelets, truth=GroundTruth(frame.crs, pose, traffic.tracks),
                        path=None)
    return SimResult(scenario, source, [VEHICLE_CLASSES[k].name for k in traffic.kinds])
