"""Re-linking of the tracks the tracker lost inside the field of view
(:mod:`fgloc.tracking.relink`): the gap rows in closed-form cases, the link tests, a car
whose returns vanish for 1.5 s keeping one track, and vehicles that stand keeping theirs
(simulator truth)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fgloc.config import Config, from_dict
from fgloc.evaluation.tracking import evaluate_tracks
from fgloc.pipeline import track
from fgloc.scenario import RadarData
from fgloc.sim import SimConfig, simulate_detailed
from fgloc.tracking import TrackingConfig
from fgloc.tracking.relink import candidate_links, gap_rows, relink, stand_rows
from fgloc.tracks import N_KIN, N_STATE, YAW, YAWRATE, A, Track, V, X, Y

DT = 0.05


def _track(tid: int, t: np.ndarray, xy: np.ndarray, yaw: np.ndarray, speed: float,
           var: float = 1.0) -> Track:
    """A track with rows at times t (n,), centres xy (n, 2), headings yaw (n,) and one
    detection per row."""
    n = len(t)
    states = np.zeros((n, N_STATE))
    states[:, X], states[:, Y], states[:, YAW], states[:, V] = xy[:, 0], xy[:, 1], yaw, speed
    states[:, N_KIN:] = 1.5
    return Track(id=tid, t=t, states=states, labels=np.zeros(n, dtype=np.int8),
                 covariances=np.repeat(var * np.eye(N_STATE)[None], n, axis=0),
                 det_index=np.arange(n, dtype=np.int64) + 1000 * tid,
                 det_step=np.arange(n, dtype=np.int64))


def _straight(tid: int, t0: float, t1: float, speed: float = 10.0, heading: float = 0.0,
              offset: float = 0.0, var: float = 1.0) -> Track:
    """Rows from t0 to t1 (s) of a vehicle on the line through the origin at ``heading``
    (rad), at ``offset`` (m) along it at t = 0."""
    t = np.arange(round(t0 / DT), round(t1 / DT) + 1) * DT
    u = np.array([np.cos(heading), np.sin(heading)])
    xy = (offset + speed * t)[:, None] * u
    return _track(tid, t, xy, np.full(len(t), heading), speed, var)


def test_gap_rows_on_a_straight_line_are_exact() -> None:
    a, b = _straight(1, 0.0, 1.0, var=1.0), _straight(2, 2.0, 3.0, var=3.0)
    times = np.arange(21, 40) * DT
    states, covs = gap_rows(a, b, times, 0.5)
    np.testing.assert_allclose(states[:, X], 10.0 * times, atol=1e-9)
    np.testing.assert_allclose(states[:, [Y, YAW, A, YAWRATE]], 0.0, atol=1e-9)
    np.testing.assert_allclose(states[:, V], 10.0, atol=1e-9)
    np.testing.assert_allclose(states[:, N_KIN:], a.states[-1:, N_KIN:].repeat(19, axis=0))
    # covariances blended from A's last to B's first row's
    np.testing.assert_allclose(covs[:, 0, 0], 1.0 + 2.0 * (times - 1.0), atol=1e-9)


def test_gap_rows_follow_a_quarter_turn() -> None:
    """A car on a circle of radius 10 m at 5 m/s, counter-clockwise: A ends heading +x at
    (0, -10), B starts a quarter turn later heading +y at (10, 0); the Hermite curve keeps
    within 0.15 m of the circle, its heading and yaw rate those of the turn."""
    radius, speed = 10.0, 5.0
    g = 0.5 * np.pi * radius / speed
    a = _track(1, np.array([0.0]), np.array([[0.0, -radius]]), np.array([0.0]), speed)
    b = _track(2, np.array([g]), np.array([[radius, 0.0]]), np.array([0.5 * np.pi]), speed)
    times = np.linspace(0.0, g, 12)[1:-1]
    states, _ = gap_rows(a, b, times, 0.5)
    r = np.hypot(states[:, X], states[:, Y])
    assert np.max(np.abs(r - radius)) < 0.15
    tangent = np.arctan2(states[:, Y], states[:, X]) + 0.5 * np.pi
    assert np.max(np.abs(np.angle(np.exp(1j * (states[:, YAW] - tangent))))) < np.deg2rad(3)
    np.testing.assert_allclose(states[:, YAWRATE], speed / radius, rtol=0.15)


@pytest.mark.parametrize("b_first", [(0.4, 0.9), (-0.5, 0.3)])
def test_gap_rows_do_not_loop_when_the_ends_disagree_with_their_speeds(b_first) -> None:
    """A coasted ahead of the car, or B's first row lags it: A ends at the origin heading +x
    at 5 m/s, B starts 0.65 s later at ``b_first`` (1 m away, not the 3.25 m the speed asks
    for) heading +x. The rows keep the heading (no turn, no yaw rate) and the centre moves
    monotonically from A's end to B's start, never beyond either along +x."""
    g = 0.65
    a = _track(1, np.array([0.0]), np.array([[0.0, 0.0]]), np.array([0.0]), 5.0)
    b = _track(2, np.array([g]), np.array([b_first]), np.array([0.0]), 5.0)
    times = np.linspace(0.0, g, 15)[1:-1]
    states, _ = gap_rows(a, b, times, 0.5)
    np.testing.assert_allclose(states[:, [YAW, YAWRATE, A]], 0.0, atol=1e-12)
    np.testing.assert_allclose(states[:, V], 5.0)
    x = np.concatenate([[0.0], states[:, X], [b_first[0]]])
    y = np.concatenate([[0.0], states[:, Y], [b_first[1]]])
    for c in (x, y):
        assert np.all(np.diff(c) * np.sign(c[-1]) >= -1e-12)


def test_a_lost_track_is_joined_to_its_continuation() -> None:
    a, b = _straight(1, 0.0, 1.0), _straight(2, 2.0, 3.0)
    frames = np.arange(0, 61) * DT
    out, links = relink([a, b], {1}, frames, TrackingConfig())
    assert len(out) == 1 and [(k.first, k.then) for k in links] == [(1, 2)]
    tr = out[0]
    assert tr.id == 1
    np.testing.assert_allclose(tr.t, frames)
    np.testing.assert_allclose(tr.states[:, X], 10.0 * frames, atol=1e-9)
    # B's detections still point at B's rows
    from_b = tr.det_index >= 2000
    np.testing.assert_allclose(tr.t[tr.det_step[from_b]], b.t[b.det_step])
    np.testing.assert_array_equal(tr.det_index[~from_b], a.det_index)
    assert len(tr.labels) == len(tr.t)


@pytest.mark.parametrize("case", ["not lost", "other way", "follower", "late", "off",
                                  "tight turn"])
def test_tracks_of_other_vehicles_stay_apart(case: str) -> None:
    cfg = TrackingConfig()
    a = _straight(1, 0.0, 1.0)
    b = _straight(2, 2.0, 3.0)
    lost = {1}
    if case == "not lost":
        lost = set()
    elif case == "other way":            # enters where A was, driving back
        b = _straight(2, 2.0, 3.0, heading=np.pi, offset=-40.0)
    elif case == "follower":             # the car 1.5 s (15 m) behind A in its lane
        b = _straight(2, 2.0, 3.0, offset=-15.0)
    elif case == "tight turn":           # 1 m/s, then 1.65 m on heading 80 deg: a 1.3 m radius
        a = _straight(1, 0.0, 1.0, speed=1.0)
        b = _straight(2, 2.0, 3.0, speed=1.0, heading=np.deg2rad(80.0), offset=-0.5)
        assert candidate_links([a, b], lost, dataclasses.replace(cfg, relink_min_radius=0.0))
    elif case == "late":
        b = _straight(2, 1.0 + cfg.relink_time + 0.1, 1.0 + cfg.relink_time + 2.0)
    else:
        cfg = dataclasses.replace(cfg, relink_time=0.0)
    out, links = relink([a, b], lost, np.arange(0, 121) * DT, cfg)
    assert links == [] and [tr.id for tr in out] == [1, 2]


def _braking(tid: int, t0: float, t1: float, shift: float = 0.0) -> Track:
    """Rows from t0 to t1 (s) of a car on the x axis, at the origin at t = ``shift``: 10 m/s,
    braking at 2.5 m/s^2 from ``shift`` + 1.5 s to 5 m/s, then holding that."""
    t = np.arange(round(t0 / DT), round(t1 / DT) + 1) * DT
    u = t - shift
    fine = np.linspace(-10.0, 20.0, 30001)
    speed = np.clip(10.0 - 2.5 * (fine - 1.5), 5.0, 10.0)
    x = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(fine))])
    x -= np.interp(0.0, fine, x)
    tr = _track(tid, t, np.column_stack([np.interp(u, fine, x), np.zeros(len(t))]),
                np.zeros(len(t)), 0.0)
    tr.states[:, V] = np.interp(u, fine, speed)
    return tr


@pytest.mark.parametrize("velocity_error", [0.5, 0.0])
def test_a_car_braking_unseen_for_four_seconds_keeps_one_track(velocity_error: float) -> None:
    """A car at 10 m/s, unseen from 1 to 5 s (hidden behind another), brakes meanwhile to
    5 m/s and holds that: the constant-velocity runs of A's last row (10 m/s) and of B's
    state 0.5 s after its first row (5 m/s) meet 3.75 m apart halfway, beyond ``relink_gate``
    but within the gate that grows with the 4.5 s between them (3 + 0.5 x 4.5 = 5.25 m);
    the car 1.5 s behind it in its lane is not joined to it (11.25 m)."""
    cfg = dataclasses.replace(TrackingConfig(), relink_velocity_error=velocity_error)
    a, b = _braking(1, 0.0, 1.0), _braking(2, 5.0, 7.0)
    follower = _braking(3, 5.0, 7.0, shift=1.5)
    links = candidate_links([a, b], {1}, cfg)
    if velocity_error == 0.0:
        assert links == []
        return
    assert [(k.first, k.then) for k in links] == [(1, 2)]
    assert links[0].miss == pytest.approx(3.75, abs=0.01)
    assert links[0].gate == pytest.approx(5.25) and links[0].rank < 1.0
    frames = np.arange(0, 141) * DT
    assert [tr.id for tr in relink([a, b], {1}, frames, cfg)[0]] == [1]
    assert candidate_links([a, follower], {1}, cfg) == []


def test_the_nearer_continuation_wins_and_chains_join() -> None:
    a = _straight(1, 0.0, 1.0)
    near = _straight(2, 2.0, 3.0, offset=0.5)
    far = _straight(3, 2.0, 3.0, offset=-2.0)
    then = _straight(4, 4.0, 5.0, offset=0.5)
    out, links = relink([a, near, far, then], {1, 2}, np.arange(0, 121) * DT,
                        TrackingConfig())
    assert sorted((k.first, k.then) for k in links) == [(1, 2), (2, 4)]
    assert [tr.id for tr in out] == [1, 3]
    joined = out[0]
    np.testing.assert_allclose(joined.t, np.arange(0, 101) * DT)


def test_stand_rows_brake_stand_and_start() -> None:
    """A ends at the origin heading +x at 2 m/s (t = 1 s), B starts 10 s later at x = 2 m at
    2 m/s; at 2 m/s^2 A brakes for 1 s to a stop at x = 1 m, and the vehicle moves off from
    there 1 s before B's first row (1 m at 1 m/s on average): the closed-form ramps, the
    stand flagged and held at x = 1 m."""
    a = _straight(1, 0.0, 1.0, speed=2.0, offset=-2.0)          # at x = 0 at t = 1 s
    b = _straight(2, 11.0, 12.0, speed=2.0, offset=-20.0)       # at x = 2 m at t = 11 s
    times = np.arange(21, 220) * DT
    states, covs, standing = stand_rows(a, b, times, 0.5, 2.0)
    w, u = times - 1.0, 11.0 - times
    braking, starting = w < 1.0, u < 1.0
    np.testing.assert_array_equal(standing, ~braking & ~starting)
    x = np.where(braking, 2.0 * w - w * w, np.where(starting, 2.0 - 2.0 * u + u * u, 1.0))
    np.testing.assert_allclose(states[:, X], x, atol=1e-9)
    np.testing.assert_allclose(states[:, V], np.where(braking, 2.0 * (1.0 - w),
                                                      np.where(starting, 2.0 * (1.0 - u), 0.0)),
                               atol=1e-9)
    np.testing.assert_allclose(states[:, A], np.where(braking, -2.0,
                                                      np.where(starting, 2.0, 0.0)))
    np.testing.assert_allclose(states[:, [Y, YAW, YAWRATE]], 0.0, atol=1e-12)
    assert covs is not None and covs.shape == (len(times), N_STATE, N_STATE)


def _stopping(tid: int, t0: float, t1: float, x_end: float, speed: float = 1.5) -> Track:
    """Rows from t0 to t1 (s) of a vehicle on the x axis at ``speed``, at ``x_end`` at t1."""
    return _straight(tid, t0, t1, speed=speed, offset=x_end - speed * t1)


@pytest.mark.parametrize("case", ["stand", "queue follower", "fast", "turned", "late", "off"])
def test_a_vehicle_that_stood_keeps_one_track(case: str) -> None:
    """A slows to 1.5 m/s and is lost at x = 0 (t = 2 s); a track starting 20 s later at
    x = 1.5 m, as slow, heading the same way, is A moving off: one track across a stand. Not
    so a car one queue place (7 m) behind, a fast one, one turned by 45 deg, one after
    ``stand_time``, or any with ``stand_time`` 0."""
    cfg = TrackingConfig()
    a = _stopping(1, 0.0, 2.0, 0.0)
    b = _stopping(2, 22.0, 23.0, 1.5 + 1.5)                     # at x = 1.5 m at t = 22 s
    if case == "queue follower":
        b = _stopping(2, 22.0, 23.0, -7.0 + 1.5)
    elif case == "fast":
        b = _straight(2, 22.0, 23.0, speed=8.0, offset=1.0 - 8.0 * 22.0)
    elif case == "turned":
        b = _straight(2, 22.0, 23.0, speed=1.5, heading=np.pi / 4, offset=-1.5 * 22.0)
    elif case == "late":
        b = _stopping(2, 2.0 + cfg.stand_time + 0.1, 2.0 + cfg.stand_time + 1.0, 2.0)
    elif case == "off":
        cfg = dataclasses.replace(cfg, stand_time=0.0)
    frames = np.arange(0, 1400) * DT
    out, links = relink([a, b], {1}, frames, cfg)
    if case != "stand":
        assert links == [] and [tr.id for tr in out] == [1, 2]
        return
    assert [(k.first, k.then, k.stand) for k in links] == [(1, 2, True)]
    tr = out[0]
    assert tr.standing is not None and len(tr.standing) == len(tr)
    still = tr.standing_steps()
    # braked within 0.75 s of A's last row (1.5 m/s at 2 m/s^2) to x = 0.5625 m; moved off
    # from there 1.25 s before B's first row (0.9375 m at 1.5 / 2 m/s on average)
    np.testing.assert_allclose(tr.t[still[[0, -1]]], [2.75, 20.75], atol=DT)
    np.testing.assert_allclose(tr.states[still][:, X], 0.5625)
    np.testing.assert_allclose(tr.states[still][:, V], 0.0)
    assert np.all(np.diff(tr.states[:, X]) >= -1e-12)            # never backwards


@pytest.mark.parametrize("gap", [1.0, 20.0])
def test_a_stop_point_another_track_covered_is_no_stand(gap: float) -> None:
    """A slows to 1.5 m/s and is lost at x = 0 (t = 2 s); B starts ``gap`` s later at
    x = 0.6 m, as slow: the stand model's ends meet closer (0.53 m) than the moving one's
    (0.90 m after 1 s). A third track stands over A's stop point meanwhile: no stand; after
    1 s the moving model joins the two, after 20 s (beyond ``relink_time``) nothing does."""
    a = _stopping(1, 0.0, 2.0, 0.0)
    b = _stopping(2, 2.0 + gap, 3.0 + gap, 0.6 + 1.5)
    other = _straight(3, 2.0, 2.0 + gap, speed=0.0, offset=0.6)
    frames = np.arange(0, 1400) * DT
    alone = candidate_links([a, b], {1}, TrackingConfig())
    assert [(k.then, k.stand) for k in alone] == [(2, True)]
    np.testing.assert_allclose(alone[0].miss, 0.525, atol=1e-9)
    out, links = relink([a, b, other], {1}, frames, TrackingConfig())
    if gap > TrackingConfig().relink_time:
        assert links == [] and [tr.id for tr in out] == [1, 2, 3]
        return
    assert [(k.first, k.then, k.stand) for k in links] == [(1, 2, False)]
    np.testing.assert_allclose(links[0].miss, 0.9, atol=1e-9)
    assert out[0].standing is None


def _without(radar: RadarData, drop: np.ndarray) -> RadarData:
    keep = ~drop
    return RadarData(radar.t[keep], radar.xyz[keep], radar.doppler[keep],
                     None if radar.rcs is None else radar.rcs[keep],
                     None if radar.frame is None else radar.frame[keep])


@pytest.mark.parametrize(("unseen", "relink_time"), [(1.5, 3.0), (1.5, 0.0), (4.0, None),
                                                     (4.0, 3.0)])
def test_a_car_unseen_for_a_while_keeps_one_track(unseen: float,
                                                  relink_time: float | None) -> None:
    """Straight road, one car approaching from 150 m (seen 6-19 s); its returns dropped from
    11 s for ``unseen`` s (1.5 s; 4 s: hidden behind another), longer than ``delete_after``:
    one track, its gap rows within 1 m of the car; without re-linking, or with a
    ``relink_time`` shorter than the gap, the car has two (None: the default)."""
    sim = from_dict(SimConfig, {"traffic": {"class_mix": [1.0, 0.0, 0.0]}}, None)
    res = simulate_detailed("straight", 1, 25.0, vehicles=1, config=sim)
    scn = res.scenario
    gap = ((res.source == scn.truth.tracks[0].id) & (scn.radar.t >= 11.0)
           & (scn.radar.t < 11.0 + unseen))
    scn = dataclasses.replace(scn, radar=_without(scn.radar, gap))
    cfg = Config()
    if relink_time is not None:
        cfg.tracking.relink_time = relink_time
    tracks = track(scn, cfg, oracle_pose=True).tracks
    m = evaluate_tracks(tracks, scn.truth, sensor_pose=scn.truth.sensor_pose,
                        hfov_deg=scn.sensor.hfov_deg, max_range=scn.sensor.max_range)
    assert m.n_matched == m.n_true == 1 and m.false_tracks == 0
    if cfg.tracking.relink_time < unseen:
        assert m.fragments == 1
        return
    assert m.fragments == 0 and len(tracks.tracks) == 1
    tr = tracks.in_local().tracks[0]
    truth = scn.truth.tracks[0].states
    inside = (tr.t > 11.1) & (tr.t < 10.9 + unseen)
    assert inside.sum() >= 20
    tx = np.interp(tr.t[inside], truth[:, 0], truth[:, 1])
    ty = np.interp(tr.t[inside], truth[:, 0], truth[:, 2])
    assert np.max(np.hypot(tr.states[inside, X] - tx, tr.states[inside, Y] - ty)) < 1.0
