"""Tracks of road users that are not motor vehicles (cyclists, pedestrians) are told from the
vehicles' and kept out of the registration, against the simulator's truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from factors.gp import rectangle_radius
from fgloc.config import Config, from_dict
from fgloc.pipeline import track
from fgloc.sim import SimConfig, simulate_detailed
from fgloc.sim.real_map import simulate_on_map
from fgloc.tracking.config import TrackingConfig
from fgloc.tracking.road_users import is_motor_vehicle, split_road_users
from fgloc.tracks import N_KIN, N_STATE, Track, V, contour_angles


def _box_track(track_id: int, length: float, width: float, steps: int = 5,
               speed: float = 10.0) -> Track:
    states = np.zeros((steps, N_STATE))
    states[:, V] = speed
    states[:, N_KIN:] = rectangle_radius(contour_angles(), length, width)
    return Track(track_id, np.arange(steps) * 0.05, states, np.zeros(steps, dtype=np.int8))


@pytest.mark.parametrize(("length", "width", "vehicle"),
                         [(4.5, 1.8, True), (3.1, 1.5, True), (11.0, 2.5, True), (4.5, 1.35, True),
                          (2.7, 3.2, True), (2.9, 2.5, True), (2.5, 2.0, True),
                          (1.8, 0.6, False), (2.9, 1.8, False), (2.5, 1.99, False),
                          (4.5, 1.2, False), (1.2, 4.5, False), (0.6, 1.8, False)])
def test_contour_size_tells_a_motor_vehicle(length: float, width: float,
                                            vehicle: bool) -> None:
    assert is_motor_vehicle(_box_track(0, length, width), TrackingConfig()) is vehicle
    # both thresholds at 0 keep every track
    keep_all = TrackingConfig(min_vehicle_length=0.0, min_vehicle_width=0.0, walking_speed=0.0)
    assert is_motor_vehicle(_box_track(0, length, width), keep_all)


def test_a_track_at_walking_speed_is_not_a_motor_vehicle() -> None:
    cfg = TrackingConfig()
    assert not is_motor_vehicle(_box_track(0, 4.4, 1.9, speed=1.3), cfg)     # a pedestrian
    assert not is_motor_vehicle(_box_track(0, 4.4, 1.9, speed=-2.4), cfg)    # either way
    assert is_motor_vehicle(_box_track(0, 4.4, 1.9, speed=2.6), cfg)
    # 90th percentile: a car slow for 16 of 20 steps, then driving off, is a car
    car = _box_track(0, 4.5, 1.8, steps=20, speed=0.8)
    car.states[16:, V] = 8.0
    assert is_motor_vehicle(car, cfg)
    car.states[16:, V] = 0.8
    car.states[19, V] = 8.0          # one fast step (a spike) does not make a walker a car
    assert not is_motor_vehicle(car, cfg)
    assert is_motor_vehicle(car, TrackingConfig(walking_speed=0.0))


def test_split_keeps_order_and_uses_the_median_over_steps() -> None:
    car = _box_track(1, 4.5, 1.8)
    bike = _box_track(2, 1.8, 0.6)
    # a car whose contour was cyclist-sized in 2 of 5 steps is still a car
    mixed = _box_track(3, 4.5, 1.8)
    mixed.states[:2, N_KIN:] = rectangle_radius(contour_angles(), 1.8, 0.6)
    vehicles, others = split_road_users([bike, car, mixed], TrackingConfig())
    assert [t.id for t in vehicles] == [1, 3] and [t.id for t in others] == [2]


def test_cyclists_tracks_are_dropped_and_the_cars_kept() -> None:
    sim = from_dict(SimConfig, {"traffic": {"cyclists_per_minute": 8.0}}, None)
    res = simulate_detailed("intersection", 1, 30.0, config=sim)
    run = track(res.scenario, Config(), oracle_pose=True)
    kept = run.tracks.tracks
    dropped = set(run.tracks.diagnostics["not_motor_vehicles"])
    assert dropped and not dropped & {t.id for t in kept}

    def majority(det_index: np.ndarray) -> str:
        src = res.source[det_index]
        src = src[src >= 0]
        return res.vehicle_class[np.bincount(src).argmax()] if len(src) else "clutter"

    # at most two kept tracks with most of their detections on a cyclist (seen too sparsely
    # to leave the car-sized prior), and less than half of the cyclists' tracked returns in
    # the kept tracks (38 % here)
    classes = [majority(t.det_index) for t in kept]
    on_bike = np.concatenate([res.source[t.det_index] for t in kept])
    bike_ids = [i for i, c in enumerate(res.vehicle_class) if c == "bicycle"]
    bike_returns_kept = np.isin(on_bike, bike_ids).sum()
    assert classes.count("bicycle") <= 2
    everything = track(res.scenario, Config(tracking=TrackingConfig(
        min_vehicle_length=0.0, min_vehicle_width=0.0, walking_speed=0.0)),
        oracle_pose=True).tracks.tracks
    on_bike_all = np.concatenate([res.source[t.det_index] for t in everything])
    assert bike_returns_kept < 0.5 * np.isin(on_bike_all, bike_ids).sum()
    # no car track lost: the cars' tracks with and without the rule are the same
    cars = sorted(t.id for t in everything if majority(t.det_index) != "bicycle")
    assert cars == sorted(t.id for t, c in zip(kept, classes) if c != "bicycle")


def test_pedestrians_tracks_are_dropped_by_their_speed() -> None:
    """On the example crop with pedestrians on its crosswalks and shared paths: their tracks
    keep car-sized contours, the size rule keeps them, the speed bound drops them; no motor
    vehicle's track goes."""
    sim_cfg = SimConfig()
    sim_cfg.real_map.pedestrians_per_minute = 30.0
    res = simulate_on_map(Path(__file__).parent / "data" / "lanelet2_example_crop.osm", 2,
                          duration=40.0, crop_radius=150.0, config=sim_cfg).result
    with_speed = track(res.scenario, Config(), oracle_pose=True).tracks.tracks
    size_only = track(res.scenario, Config(tracking=TrackingConfig(walking_speed=0.0)),
                      oracle_pose=True).tracks.tracks

    def walkers(tracks: list[Track]) -> list[int]:
        ids = []
        for t in tracks:
            src = res.source[t.det_index]
            src = src[src >= 0]
            if len(src) and res.vehicle_class[np.bincount(src).argmax()] == "pedestrian":
                ids.append(t.id)
        return ids

    assert len(walkers(size_only)) >= 2
    assert len(walkers(with_speed)) <= 0.25 * len(walkers(size_only))
    vehicles = sorted(set(t.id for t in size_only) - set(walkers(size_only)))
    assert vehicles == sorted(set(t.id for t in with_speed) - set(walkers(with_speed)))
