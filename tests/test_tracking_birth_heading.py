"""A new track's heading prior where lanes cross (issue 20): the lane the cluster is on and
the Doppler, not the birth zone's lane; one tentative track per heading where crossing lanes
tie. Against known truth: rigid-body Doppler in closed form and a car simulated on one of two
lanes crossing at 70 deg next to the sensor."""

from __future__ import annotations

import numpy as np
import pytest

from factors.measurement import range_rate
from fgloc.geo import wrap_angle
from fgloc.scenario import Lanelet
from fgloc.tracking.birth import BirthZones, FieldOfView, LaneHeadings, doppler_misfit
from fgloc.tracking.config import TrackingConfig
from fgloc.tracking.tracker import Tracker, _Frame

SENSOR = np.zeros(2)
HEIGHT = 5.0


def _rng3(z: np.ndarray) -> np.ndarray:
    """3D ranges of detections z (k, 2) 0.8 m above the road from a sensor HEIGHT m up."""
    return np.hypot(np.linalg.norm(z - SENSOR, axis=1), HEIGHT - 0.8)


def test_doppler_misfit_of_a_rigid_motion() -> None:
    """Detections of a car turning at 0.3 rad/s, 10 m/s along 20 deg, 40 m out: the true
    heading explains their Doppler exactly, the lane driven the other way does not (the speed
    would be negative) nor does one across the line of sight (it would need more than
    max_speed); a heading 40 deg off is explained by a rotation about the sensor too (one
    frame's Doppler cannot tell it, hence the heading hypotheses)."""
    rng = np.random.default_rng(0)
    centre, yaw, v, w = np.array([40.0, 5.0]), np.deg2rad(20.0), 10.0, 0.3
    z = centre + rng.uniform(-2.0, 2.0, (12, 2))
    r3 = _rng3(z)
    dop = range_rate(z, r3, centre, np.asarray(v), np.asarray(yaw), np.asarray(w), SENSOR)
    los = np.arctan2(centre[1], centre[0])
    heads = np.array([yaw, yaw + np.pi, los + np.pi / 2, yaw + np.deg2rad(40.0)])
    rss = doppler_misfit(z, dop, r3, SENSOR, heads, 40.0, 1.0)
    assert rss[0] < 1e-12
    assert rss[1] > 100.0 and rss[2] > 1.0
    assert rss[3] < 0.05


def _lanes() -> tuple[LaneHeadings, np.ndarray, np.ndarray]:
    """Two one-way lanes crossing at P = (30, -15) (a junction box next to the sensor): A
    heading -35 deg, B heading +35 deg, each 3.5 m wide and 120 m long, centred on P."""
    p = np.array([30.0, -15.0])
    out = []
    for i, deg in enumerate((-35.0, 35.0)):
        h = np.array([np.cos(np.deg2rad(deg)), np.sin(np.deg2rad(deg))])
        n = np.array([-h[1], h[0]])
        s = np.linspace(-60.0, 60.0, 121)[:, None]
        c = p + s * h
        left, right = c + 1.75 * n, c - 1.75 * n
        pad = np.zeros((len(s), 1))
        out.append(Lanelet(i + 1, np.hstack([left, pad]), np.hstack([right, pad])))
    return LaneHeadings.of(out), p, np.deg2rad(np.array([-35.0, 35.0]))


def _car_frame(centre: np.ndarray, yaw: float, v: float, rng: np.random.Generator,
               n: int) -> _Frame:
    """n detections on the faces of a 4.5 x 1.8 m car (centre, yaw) seen from the sensor,
    0.05 m noise, with its rigid-body range rate (speed v m/s, no yaw rate)."""
    h = np.array([np.cos(yaw), np.sin(yaw)])
    lat = np.array([-h[1], h[0]])
    rel = SENSOR - centre
    fa = 2.25 * np.sign(rel @ h) * h                   # the seen end
    sa = 0.9 * np.sign(rel @ lat) * lat                # the seen side
    t = rng.uniform(-1.0, 1.0, n)
    on_end = rng.random(n) < 0.5
    z = np.where(on_end[:, None], centre + fa + t[:, None] * 0.9 * lat,
                 centre + sa + t[:, None] * 2.25 * h)
    z = z + rng.normal(0.0, 0.05, z.shape)
    r3 = _rng3(z)
    dop = range_rate(z, r3, centre, np.asarray(v), np.asarray(yaw), np.asarray(0.0), SENSOR)
    return _Frame(z, r3, dop, np.arange(n))


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_car_leaving_the_crossing_gets_its_own_lanes_heading(seed: int) -> None:
    """A car on lane A (-35 deg) at 10 m/s away from the sensor, 6 returns a frame, starting
    at the crossing inside a birth zone of lane B (+35 deg; the zone's disc covers both
    lanes there): the zone's heading was taken before, and a track started 70 deg off went
    on as a false track covering its vehicle and the next (simulated oblique junction,
    combined setting seed 5; here three tracks born on B's heading diverged one after the
    other and the car had no track until it had left the zone, 1.4 s on). Now: one track
    from the car's first frames, on lane A's heading, centred on the car."""
    lanes, p, yaws = _lanes()
    cfg = TrackingConfig()
    fov = FieldOfView.of(np.eye(4), 120.0, 200.0)
    zone_b = BirthZones.explicit([[*(p + np.array([-4.0, -3.0])), 12.0, 35.0]])
    tracker = Tracker(cfg, fov, zone_b, lanes)
    rng = np.random.default_rng(seed)
    h = np.array([np.cos(yaws[0]), np.sin(yaws[0])])
    start = p + 1.0 * h
    for k in range(30):
        centre = start + 1.0 * k * h                    # 10 m/s, 0.1 s frames
        tracker.step(0.1 * k, _car_frame(centre, yaws[0], 10.0, rng, 6))
    alive = [i for i, r in enumerate(tracker.recs) if r.confirmed]
    assert len(alive) == 1, [(r.id, r.confirmed) for r in tracker.recs]
    x = tracker.x[alive[0]]
    assert abs(np.rad2deg(wrap_angle(x[4] - yaws[0]))) < 5.0
    assert np.linalg.norm(x[:2] - centre) < 1.0
    out = tracker.finish()
    assert len(out) == 1 and out[0].t[0] <= 0.2, [(tr.id, tr.t[0]) for tr in out]


def _two_way_street(one_way: str) -> Lanelet:
    """A 7 m wide street mapped as one lanelet along +x from (-20, 30) to (100, 30), tagged
    ``one_way`` = one_way."""
    x = np.linspace(-20.0, 100.0, 121)[:, None]
    pad = np.zeros_like(x)
    left = np.hstack([x, np.full_like(x, 33.5), pad])
    right = np.hstack([x, np.full_like(x, 26.5), pad])
    return Lanelet(1, left, right, {"one_way": one_way})


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_car_driving_a_two_way_lanelet_backwards_gets_its_heading(seed: int) -> None:
    """Real maps draw two-way streets as one lanelet (tag one_way = no) driven both ways. A car
    driving it against the lanelet's direction (heading 180 deg) at 10 m/s, 40 m from the
    sensor and seen nearly across the line of sight: before, the births knew the lanelet's own
    direction only, and since a heading mirrored about the line of sight explains the same
    Doppler (plus a yaw rate), the car got one (real map, centre traffic, junction 2, seed 3:
    157 deg off). Now the lanelet gives both directions and the Doppler picks the car's; a
    one-way lanelet still gives only its own. The birth zones count a two-way lanelet once
    per direction: one where each direction enters the FOV."""
    rng = np.random.default_rng(seed)
    yaw = np.pi
    centre = np.array([35.0 + rng.uniform(-3.0, 3.0), 31.75])
    frame = _car_frame(centre, yaw, 10.0, rng, 30)
    cfg = TrackingConfig()
    for tag, expected in (("no", yaw), ("yes", None)):
        lanes = LaneHeadings.of([_two_way_street(tag)])
        heads = lanes.headings_near(centre, cfg.lane_search_radius, frame.z, frame.doppler,
                                    frame.rng, SENSOR, cfg.birth_sigma_doppler,
                                    cfg.max_speed, cfg.max_yawrate, cfg.birth_hypotheses,
                                    cfg.birth_hypothesis_margin,
                                    np.deg2rad(cfg.birth_hypothesis_sep_deg))
        if expected is None:
            assert len(heads) == 1 and abs(wrap_angle(heads[0] - yaw)) > np.deg2rad(90.0)
        else:
            assert abs(wrap_angle(heads[0] - expected)) < np.deg2rad(1.0), heads
    T = np.eye(4)
    T[2, 3] = HEIGHT
    fov = FieldOfView.of(T, 120.0, 200.0)
    for tag, n_zones in (("no", 2), ("yes", 1)):
        zones = BirthZones.from_map([_two_way_street(tag)], fov, 6.0, 5.0)
        assert len(zones) == n_zones
    both = BirthZones.from_map([_two_way_street("no")], fov, 6.0, 5.0)
    assert sorted(np.round(np.rad2deg(np.abs(both.yaw)))) == [0.0, 180.0]
