"""The tracker on traffic the default simulator does not make (issue 20), against the
simulator's truth: a platoon of three cars 1 s apart, a 12 m truck seen along one side, a car
far out with 3-5 returns per frame."""

from __future__ import annotations

import numpy as np
import pytest

from bench.robustness import tracks_covering_two
from fgloc.config import Config, from_dict
from fgloc.evaluation.tracking import contour_polygons, evaluate_tracks
from fgloc.pipeline import track
from fgloc.sim import SimConfig, simulate_detailed
from fgloc.tracks import YAW


def _run(table: dict, seed: int, duration: float, vehicles: int):
    cfg = from_dict(SimConfig, table, None)
    res = simulate_detailed("straight", seed, duration, vehicles=vehicles, config=cfg)
    scn = res.scenario
    tracks = track(scn, Config(), oracle_pose=True).tracks
    m = evaluate_tracks(tracks, scn.truth, sensor_pose=scn.truth.sensor_pose,
                        hfov_deg=scn.sensor.hfov_deg, max_range=scn.sensor.max_range)
    return res, tracks, m


CARS = [1.0, 0.0, 0.0]


# seeds whose platoon drives towards / away from the sensor inside its view (checked below:
# three eligible vehicles); on the other seeds 1-8 the platoon is out of view
@pytest.mark.parametrize("seed", [1, 2, 6])
def test_platoon_of_three_cars_gives_three_tracks(seed: int) -> None:
    table = {"traffic": {"class_mix": CARS, "platoon_size": [3, 3],
                         "platoon_headway": [1.0, 1.0], "headway": 0.3},
             "road": {"lanes_per_direction": [1]}}
    res, tracks, m = _run(table, seed, 25.0, 3)
    assert len(res.scenario.truth.tracks) == 3
    assert m.n_matched == m.n_true == 3
    assert m.false_tracks == 0 and m.fragments == 0
    assert tracks_covering_two(tracks, res.scenario) == 0


def _extent_along_heading(states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(k,) extent (m) of each state's contour polygon along its heading, and (k, 2) the unit
    headings."""
    h = np.column_stack([np.cos(states[:, YAW]), np.sin(states[:, YAW])])
    return np.ptp(np.einsum("kmd,kd->km", contour_polygons(states), h), axis=1), h


def _side_lengths(tracks, sensor: np.ndarray) -> np.ndarray:
    """Contour extent along the heading of every track state 20-120 m from the sensor whose
    vehicle shows the sensor one long side (the sensor beyond the side by more than the
    vehicle's half width)."""
    out = []
    for tr in tracks.in_local().tracks:
        length, h = _extent_along_heading(tr.states)
        rel = sensor - tr.states[:, :2]
        dist = np.linalg.norm(rel, axis=1)
        lateral = np.abs(rel[:, 0] * h[:, 1] - rel[:, 1] * h[:, 0])
        out.append(length[(lateral > 1.5) & (dist > 20.0) & (dist < 120.0)])
    return np.concatenate(out) if out else np.zeros(0)


#: known failures (issue 20, not met): none since ``tracking.occupancy_bound`` (issue-20n;
#: seed 5 reported a duplicate track on the truck's far end before)
KNOWN_TRUCK_FAILURES: tuple[int, ...] = ()
#: none since ``tracking.occupancy_bound`` (issue-20n): seeds 5 / 6, receding end-on, came out
#: 14.34 / 13.53 m (bar 13.5 m), 12.58 / 12.67 m with it
KNOWN_SIDE_LENGTH_FAILURES: tuple[int, ...] = ()


def _truck_seeds(known: tuple[int, ...]) -> list:
    return [pytest.param(s, marks=pytest.mark.xfail(strict=True, reason="known failure"))
            if s in known else s for s in range(1, 9)]


TRUCK_SEEDS = _truck_seeds(KNOWN_TRUCK_FAILURES)


TRUCK_12M = {"traffic": {"class_mix": [0.0, 0.0, 1.0], "truck_length": [12.0, 12.0]},
             "road": {"lanes_per_direction": [1]}}


@pytest.mark.parametrize("seed", _truck_seeds(KNOWN_SIDE_LENGTH_FAILURES))
def test_truck_seen_along_one_side_gets_its_length(seed: int) -> None:
    res, tracks, m = _run(TRUCK_12M, seed, 25.0, 1)
    assert m.n_matched == 1 and m.false_tracks == 0
    lengths = _side_lengths(tracks, res.scenario.truth.sensor_pose[:2, 3])
    assert len(lengths) > 20
    assert 10.5 <= np.median(lengths) <= 13.5, np.median(lengths)


@pytest.mark.parametrize("seed", TRUCK_SEEDS)
def test_truck_seen_head_on_is_not_pulled_towards_the_sensor(seed: int) -> None:
    """While the sensor is beyond the truck's front or rear (its length unobservable; most of
    the straight road), the track's contour is at least 10.5 m long and its centre within
    0.7 m of the truth towards the sensor on average (the filter alone: a car-sized contour
    for the first seconds, centre ~4 m towards the sensor, 1.0-1.5 m on average)."""
    res, tracks, m = _run(TRUCK_12M, seed, 25.0, 1)
    assert m.n_matched == 1 and m.false_tracks == 0
    gt = res.scenario.truth.tracks[0]
    sensor = res.scenario.truth.sensor_pose[:2, 3]
    (tr,) = tracks.in_local().tracks
    s = gt.states
    k = (tr.t >= s[0, 0]) & (tr.t <= s[-1, 0])
    xy = np.column_stack([np.interp(tr.t[k], s[:, 0], s[:, i]) for i in (1, 2)])
    yaw = np.interp(tr.t[k], s[:, 0], np.unwrap(s[:, 3]))
    rel = sensor - xy
    end_seen = np.abs(rel[:, 0] * np.cos(yaw) + rel[:, 1] * np.sin(yaw)) > gt.length / 2
    assert end_seen.sum() > 50
    to_sensor = rel / np.linalg.norm(rel, axis=1, keepdims=True)
    bias = np.sum((tr.states[k, :2] - xy) * to_sensor, axis=1)[end_seen]
    length, _ = _extent_along_heading(tr.states[k][end_seen])
    assert length.min() >= 10.5, length.min()
    assert abs(float(np.mean(bias))) <= 0.7, np.mean(bias)


# seeds whose truck drives away from the sensor inside its view (checked below)
@pytest.mark.parametrize("seed", [5, 6])
def test_receding_truck_seen_end_on_does_not_outgrow_its_returns(seed: int) -> None:
    """A 12 m truck driving away, seen from behind with its long side at grazing incidence
    (sin <= 0.35, 40 m and more away): no rows of its own hold the far end, which drifted out
    with the rear face's -- median 14.3 / 13.5 m (seeds 5 / 6) without
    ``tracking.occupancy_bound``; bounded by the length its own detections reach behind the
    rear, 12.6 / 12.7 m."""
    res, tracks, m = _run(TRUCK_12M, seed, 25.0, 1)
    assert m.n_matched == 1 and m.false_tracks == 0
    sensor = res.scenario.truth.sensor_pose[:2, 3]
    (tr,) = tracks.in_local().tracks
    length, h = _extent_along_heading(tr.states)
    rel = sensor - tr.states[:, :2]
    dist = np.linalg.norm(rel, axis=1)
    grazing = np.abs(rel[:, 0] * h[:, 1] - rel[:, 1] * h[:, 0]) <= 0.35 * dist
    behind = np.sum(rel * h, axis=1) < 0.0
    k = grazing & behind & (dist > 40.0)
    assert k.sum() > 100
    assert 11.0 <= np.median(length[k]) <= 13.0, np.median(length[k])


#: the robustness matrix's far-sparse returns (bench/robustness.py): 25 per vehicle and frame
#: at 20 m falling to about 4 at 150 m
SPARSE = {"returns_at_reference": 25.0, "reference_range": 20.0, "returns_exponent": 0.91,
          "range_half_detection": 0.95}
#: known failure (not met): seed 3's track stays short: 6.79 m with ``tracking.occupancy_bound``
#: (issue-20n) and the young tracks' gate (issue-20o); the gate alone passes, the bound alone
#: gives 6.37 m. Seed 2 (10.11 m since ``tracking.visible_slack``) passes with the bound;
#: seed 6 added a false track until births wait for a vehicle to leave the withheld range
KNOWN_SPARSE_TRUCK_FAILURES = (3,)
SPARSE_TRUCK_SEEDS = _truck_seeds(KNOWN_SPARSE_TRUCK_FAILURES)


@pytest.mark.parametrize("seed", SPARSE_TRUCK_SEEDS)
def test_truck_seen_end_on_with_sparse_returns_gets_its_length(seed: int) -> None:
    """A 12 m truck with sparse returns, seen end-on for most of the road: its long side
    shows at grazing incidence with a few returns per frame, mostly beyond a car-sized
    contour's gate; pooled over the updates behind the seen end they give its length
    (``tracking.occupancy_gap``). Without that (occupancy_gap = 0) 6 of seeds 1-8 had no
    track within 3 m of the truck (contours 4.6-7 m, centres ~3.5 m towards the sensor)."""
    res, tracks, m = _run({**TRUCK_12M, "radar": SPARSE}, seed, 25.0, 1)
    assert m.n_matched == 1 and m.false_tracks == 0 and m.fragments == 0
    (tr,) = tracks.in_local().tracks
    length, _ = _extent_along_heading(tr.states)
    assert 10.5 <= np.median(length) <= 13.5, np.median(length)
    # 0.33-0.88 m on the passing seeds (without it: no track within 3 m)
    assert m.centre_rms_track_mean <= 1.0, m.centre_rms_track_mean


@pytest.mark.parametrize("seed", [1, 3, 5, 7, 8])
def test_far_car_with_few_returns_keeps_one_track(seed: int) -> None:
    """4 returns per frame at every range (Poisson: mostly 2-6), the road reaching 220 m
    (seeds whose car drives beyond 180 m: checked below)."""
    table = {"radar": {"returns_at_reference": 4.0, "returns_exponent": 0.0,
                       "max_range": 230.0, "range_half_detection": 1.2},
             "road": {"arm_length": 220.0, "lanes_per_direction": [1]},
             "traffic": {"class_mix": CARS}}
    res, tracks, m = _run(table, seed, 30.0, 1)
    tr = res.scenario.truth.tracks[0]
    far = np.linalg.norm(tr.states[:, 1:3] - res.scenario.truth.sensor_pose[:2, 3], axis=1)
    assert far.max() > 180.0
    assert m.n_matched == 1 and m.fragments == 0 and m.false_tracks == 0
    assert len(tracks) == 1


def test_trucks_first_seen_late_get_their_length() -> None:
    """The robustness matrix's far-sparse setting, intersection seed 1: two trucks (11.3,
    10.9 m) hidden behind other traffic until the recording's last 4 s. The second is then
    seen 55-36 m out with its line of sight 22-36 deg off its heading, its side's returns
    2-3 m apart: beyond a car-sized contour's gate, too far apart for the chain. Pooled
    behind its front up to ``tracking.occupancy_max_incidence`` (sin 0.6) they give its
    length; at 0.35 its track stayed 5.4 m long, its centre 2.8 m RMS off."""
    from bench.robustness import sim_config

    res = simulate_detailed("intersection", 1, 60.0, config=sim_config("far-sparse"))
    scn = res.scenario
    seen = scn.radar.t
    late = [i for i, kind in enumerate(res.vehicle_class)
            if kind == "truck" and np.any(res.source == i) and seen[res.source == i].min() > 55.0]
    assert len(late) == 2
    tracks = track(scn, Config(), oracle_pose=True).tracks
    m = evaluate_tracks(tracks, scn.truth, sensor_pose=scn.truth.sensor_pose,
                        hfov_deg=scn.sensor.hfov_deg, max_range=scn.sensor.max_range)
    for gt in (t for t in scn.truth.tracks if t.id in late):
        (row,) = [r for r in m.rows if r.truth_id == gt.id]
        assert row.role == "matched" and row.centre_rms <= 1.0, (gt.id, row.centre_rms)
        (tr,) = [t for t in tracks.in_local().tracks if t.id == row.track_id]
        length, _ = _extent_along_heading(tr.states)
        last = tr.t >= tr.t[-1] - 1.0
        assert abs(np.median(length[last]) - gt.length) <= 1.5, (gt.id, gt.length)


def test_roof_returns_do_not_carry_a_car_track_away_from_the_sensor() -> None:
    """Straight road, two cars (seed 1) with a tenth of their returns from their roofs (the
    independent generator's share): with the deep returns weighed down the tracks' mean
    error along the heading stays below 0.35 m (0.16 and 0.27 m measured; without roof
    returns 0.08 and 0.10 m); without it one car's track runs 1.15 m ahead of its car."""
    sim = from_dict(SimConfig, {"traffic": {"class_mix": [1.0, 0.0, 0.0]},
                                "radar": {"roof_fraction": 0.1}}, None)
    scn = simulate_detailed("straight", 1, 25.0, vehicles=2, config=sim).scenario
    worst = {}
    for sigmas in (1.0, 0.0):
        cfg = Config()
        cfg.tracking.interior_sigmas = sigmas
        along = []
        for tr in track(scn, cfg, oracle_pose=True).tracks.in_local().tracks:
            for gt in scn.truth.tracks:
                k = (tr.t >= gt.states[0, 0]) & (tr.t <= gt.states[-1, 0])
                if k.sum() < 20:
                    continue
                g = [np.interp(tr.t[k], gt.states[:, 0], gt.states[:, c]) for c in (1, 2, 3)]
                if np.hypot(tr.states[k, 0] - g[0], tr.states[k, 1] - g[1]).mean() < 3.0:
                    along.append(abs(np.mean((tr.states[k, 0] - g[0]) * np.cos(g[2])
                                             + (tr.states[k, 1] - g[1]) * np.sin(g[2]))))
        assert len(along) == 2
        worst[sigmas] = max(along)
    assert worst[1.0] < 0.35 and worst[0.0] > 0.9
