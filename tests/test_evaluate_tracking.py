"""Tracking metrics on constructed cases with known answers, and the polygon IoU."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from matplotlib.path import Path as MplPath

from fgloc.evaluation.tracking import (
    box_intersection_area,
    evaluate_tracks,
    in_field_of_view,
    iou_polygon_rectangle,
)
from fgloc.geo import se2, se2_inv, se3_from_pose
from fgloc.labels import LEFT, RIGHT, STRAIGHT
from fgloc.scenario import GroundTruth, TrackTruth
from fgloc.tracks import N_CONTOUR, N_KIN, N_STATE, YAW, Track, TrackSet, contour_angles

T_C_TO_L = se2(5.0, -3.0, 0.4)
# id: (x0, y0, yaw0, v, yawrate, t0, t1, length, width, label); vehicle 3 crosses yaw = -pi
VEHICLES = {
    1: (-30.0, -5.0, 0.0, 10.0, 0.0, 0.0, 6.0, 4.5, 1.8, STRAIGHT),
    2: (0.0, 20.0, 1.5, 8.0, 0.25, 1.0, 7.0, 4.8, 2.0, LEFT),
    3: (20.0, -20.0, -3.0, 6.0, -0.2, 0.5, 5.5, 4.0, 1.7, RIGHT),
}


def _pose(vid: int, t: np.ndarray) -> np.ndarray:
    """(n, 6) analytic [t, x, y, yaw, v, yawrate] of a constant-turn-rate vehicle in L."""
    x0, y0, yaw0, v, w, t0, *_ = VEHICLES[vid]
    yaw = yaw0 + w * (t - t0)
    if w == 0.0:
        x, y = x0 + v * (t - t0) * np.cos(yaw0), y0 + v * (t - t0) * np.sin(yaw0)
    else:
        x = x0 + v / w * (np.sin(yaw) - np.sin(yaw0))
        y = y0 - v / w * (np.cos(yaw) - np.cos(yaw0))
    return np.column_stack([t, x, y, np.angle(np.exp(1j * yaw)), np.full_like(t, v),
                            np.full_like(t, w)])


def _truth(rate_hz: float, ids=(1, 2, 3)) -> GroundTruth:
    tracks = []
    for vid in ids:
        length, width = VEHICLES[vid][7:9]
        tracks.append(TrackTruth(vid, length, width, _pose(vid, _times(vid, rate_hz))))
    return GroundTruth("EPSG:25832", np.eye(4), tracks)


def _rect_radii(length: float, width: float) -> np.ndarray:
    """Radii of the rectangle's boundary at the contour angles (20-point star approximation)."""
    a = contour_angles()
    with np.errstate(divide="ignore"):
        return np.minimum(length / 2 / np.abs(np.cos(a)), width / 2 / np.abs(np.sin(a)))


def _track(vid: int, t: np.ndarray, tid: int | None = None, dxy=(0.0, 0.0), dyaw=0.0) -> Track:
    """A track following vehicle vid at times t (in L), optionally offset."""
    p = _pose(vid, t)
    length, width, label = VEHICLES[vid][7:10]
    s = np.zeros((len(t), N_STATE))
    s[:, :2] = p[:, 1:3] + dxy
    s[:, 2], s[:, YAW], s[:, 5] = p[:, 4], p[:, 3] + dyaw, p[:, 5]
    s[:, N_KIN:] = _rect_radii(length, width)
    return Track(vid if tid is None else tid, t, s, np.full(len(t), label, dtype=np.int8))


def _in_c(tracks: list[Track]) -> TrackSet:
    """Copies of the tracks moved into frame C (T_C_TO_L maps them back to L)."""
    inv = se2_inv(T_C_TO_L)
    out = []
    for tr in tracks:
        s = tr.states.copy()
        s[:, :2] = s[:, :2] @ inv[:2, :2].T + inv[:2, 2]
        s[:, YAW] -= 0.4
        out.append(Track(tr.id, tr.t, s, tr.labels))
    return TrackSet(out, frame="C", T_frame_to_L=T_C_TO_L)


def _times(vid: int, rate_hz: float = 20.0) -> np.ndarray:
    """The vehicle's truth span sampled at rate_hz, both ends included exactly."""
    t0, t1 = VEHICLES[vid][5:7]
    return np.linspace(t0, t1, round((t1 - t0) * rate_hz) + 1)


def _perfect(**kw) -> list[Track]:
    return [_track(vid, _times(vid), **kw) for vid in VEHICLES]


def _star_rect_iou(length: float, width: float) -> float:
    """IoU of the inscribed 20-point star polygon with its rectangle: fan of triangles."""
    r = _rect_radii(length, width)
    area = 0.5 * np.sum(r * np.roll(r, -1)) * np.sin(2 * np.pi / N_CONTOUR)
    return area / (length * width)


def _mean_star_iou(counts: dict[int, int]) -> float:
    n = sum(counts.values())
    return sum(c * _star_rect_iou(*VEHICLES[v][7:9]) for v, c in counts.items()) / n


# --------------------------------------------------------------------------------------------
# metrics
# --------------------------------------------------------------------------------------------
def test_perfect_tracks_same_rate():
    m = evaluate_tracks(_in_c(_perfect()), _truth(20.0))
    assert (m.n_true, m.n_tracks, m.n_matched, m.missed, m.false_tracks, m.fragments) == (
        3, 3, 3, 0, 0, 0)
    assert m.tracked_share == 1.0
    assert m.n_states == 2 * 121 + 101
    assert m.centre_rms == pytest.approx(0.0, abs=1e-9)
    assert m.yaw_error_deg == pytest.approx(0.0, abs=1e-9)
    assert _star_rect_iou(4.5, 1.8) < 0.96  # the 20-point polygon cuts the corners
    assert m.iou == pytest.approx(_mean_star_iou({1: 121, 2: 121, 3: 101}), abs=1e-9)
    assert m.label_accuracy == 1.0
    assert {(r.track_id, r.truth_id, r.role) for r in m.rows} == {
        (1, 1, "matched"), (2, 2, "matched"), (3, 3, "matched")}


def test_truth_at_10_hz_tracks_at_20_hz():
    m = evaluate_tracks(_in_c(_perfect()), _truth(10.0))
    assert m.n_matched == 3 and m.n_states == 2 * 121 + 101
    # linear interpolation of a 10 Hz arc: chord sagitta (v dt)^2 / (8 R) <= 0.064 / 32 m
    assert 1e-5 < m.centre_rms < 2.5e-3
    assert m.yaw_error_deg == pytest.approx(0.0, abs=1e-9)  # yaw is linear in t
    assert m.iou == pytest.approx(_mean_star_iou({1: 121, 2: 121, 3: 101}), abs=2e-3)


def test_centre_shift_and_yaw_offset():
    shifted = evaluate_tracks(_in_c(_perfect(dxy=(0.18, -0.24))), _truth(20.0))
    assert shifted.centre_rms == pytest.approx(0.3, abs=1e-9)
    assert shifted.yaw_error_deg == pytest.approx(0.0, abs=1e-9)
    assert all(r.centre_rms == pytest.approx(0.3) for r in shifted.rows)
    turned = evaluate_tracks(_in_c(_perfect(dyaw=np.deg2rad(-5.0))), _truth(20.0))
    assert turned.yaw_error_deg == pytest.approx(5.0, abs=1e-9)
    assert turned.centre_rms == pytest.approx(0.0, abs=1e-9)
    perfect = evaluate_tracks(_in_c(_perfect()), _truth(20.0))
    assert turned.iou < perfect.iou - 0.01 and shifted.iou < perfect.iou - 0.01


def test_missing_and_false_tracks():
    tracks = _perfect()[:2]  # vehicle 3 has no track
    tracks.append(_track(1, np.arange(0.0, 6.0, 0.05), tid=99, dxy=(500.0, 500.0)))
    m = evaluate_tracks(_in_c(tracks), _truth(10.0))
    assert (m.n_true, m.n_tracks, m.n_matched, m.missed, m.false_tracks) == (3, 3, 2, 1, 1)
    assert m.missed_ids == (3,)
    assert m.tracked_share == pytest.approx(2 / 3)
    false_row = next(r for r in m.rows if r.track_id == 99)
    assert false_row.role == "false" and false_row.truth_id is None and false_row.n == 0
    assert math.isnan(false_row.centre_rms)
    js = json.loads(json.dumps(m.to_json()))
    assert js["missed"] == 1 and js["rows"][2]["centre_rms"] is None
    assert "share" in m.table() and "false" in m.table(per_track=True)


def test_track_break_is_a_fragment_and_a_duplicate_is_false():
    tracks = _perfect()
    t = tracks[0].t
    first, second = _track(1, t[:50], tid=10), _track(1, t[60:], tid=11)
    dup = _track(2, np.arange(2.0, 5.0, 0.05), tid=20, dxy=(0.5, 0.0))
    m = evaluate_tracks(_in_c([first, second, dup, *tracks[1:]]), _truth(10.0))
    assert (m.n_matched, m.missed, m.fragments, m.false_tracks) == (3, 0, 1, 1)
    roles = {r.track_id: (r.truth_id, r.role) for r in m.rows}
    assert roles[10] == (1, "matched") and roles[11] == (1, "fragment")
    assert roles[20] == (None, "false")  # overlaps track 2 in time; track 2 is closer
    assert roles[2] == (2, "matched")
    assert m.n_states == 50 + 61 + 121 + 101


@pytest.mark.parametrize("overlap, handover_s, role", [
    (0.2, 0.5, "fragment"),     # a new track a moment before the old one's last row
    (0.0, 0.0, "false"),        # rows at the same time: an overlap without the tolerance
    (1.0, 0.5, "false"),        # a second of two tracks on one vehicle: a duplicate
])
def test_a_hand_over_overlapping_by_less_than_the_tolerance_is_a_fragment(
        overlap: float, handover_s: float, role: str) -> None:
    """Vehicle 1 tracked by track 10 until t = 3 s and by track 11 from 3 s - ``overlap``:
    a fragment when the overlap is shorter than ``handover_s``, else a false track (the
    vehicle followed by the other at the same time); the other vehicles' tracks unchanged."""
    tracks = _perfect()
    t = tracks[0].t
    first = _track(1, t[t <= 3.0 + 1e-9], tid=10)
    second = _track(1, t[t >= 3.0 - overlap - 1e-9], tid=11, dxy=(0.2, 0.0))
    m = evaluate_tracks(_in_c([first, second, *tracks[1:]]), _truth(10.0),
                        handover_s=handover_s)
    roles = {r.track_id: r.role for r in m.rows}
    assert {roles[10], roles[11]} == {"matched", role}
    assert (m.fragments, m.false_tracks) == ((1, 0) if role == "fragment" else (0, 1))
    assert m.n_matched == 3 and m.missed == 0


def test_labels_overlap_and_gate():
    tracks = _perfect()
    tracks[1].labels[:30] = STRAIGHT  # vehicle 2 turns left: 30 wrong labels
    # starts 1 s before and ends 1.5 s after the truth span [0.5, 5.5]
    long = _track(3, np.concatenate([np.linspace(-0.5, 0.45, 20), _times(3),
                                     np.linspace(5.55, 7.0, 30)]))
    far = _track(1, np.arange(0.0, 6.0, 0.05), tid=5, dxy=(3.5, 0.0))  # beyond the 3 m gate
    m = evaluate_tracks(_in_c([tracks[0], tracks[1], long, far]), _truth(10.0))
    row3 = next(r for r in m.rows if r.track_id == 3)
    assert row3.n == 101  # only the steps inside the truth span are scored
    assert m.label_accuracy == pytest.approx(1.0 - 30 / m.n_states)
    assert next(r for r in m.rows if r.track_id == 5).role == "false"
    assert evaluate_tracks(_in_c([far]), _truth(10.0), gate=4.0).n_matched == 1


def test_eligibility_from_field_of_view_and_masks():
    # sensor at the origin looking south-east, 100 deg: azimuths -95..5 deg. Vehicle 1 (y = -5,
    # x = -30 + 10 t) is inside for x >= -0.44 m, from t = 3 s: 3 s; vehicle 2 (north-west)
    # never; vehicle 3 (from (20, -20) westwards) for its first 3 s or so
    sensor = se3_from_pose(0.0, 0.0, 6.0, np.deg2rad(-45.0), np.deg2rad(10.0), 0.0)
    fov = {"sensor_pose": sensor, "hfov_deg": 100.0, "max_range": 100.0}
    vis = in_field_of_view(_truth(10.0).tracks[0].states[:, 1:3], **fov)
    assert vis.sum() == 31 and vis[30:].all()
    assert not in_field_of_view(_truth(10.0).tracks[1].states[:, 1:3], **fov).any()
    assert not in_field_of_view(np.array([[30.0, -5.0]]), sensor, 100.0, 25.0)[0]  # range
    tracks = _perfect()
    m = evaluate_tracks(_in_c(tracks[:2]), _truth(10.0), **fov)
    # vehicle 2 is ineligible: its track is neither false nor counted; vehicle 3 is missed
    assert (m.n_true, m.n_matched, m.missed, m.false_tracks) == (2, 1, 1, 0)
    assert m.missed_ids == (3,)
    assert m.n_states == 242  # the ineligible vehicle's track is still scored
    short = evaluate_tracks(_in_c(_perfect()), _truth(10.0), min_visible_s=5.5)
    assert short.n_true == 2  # vehicle 3 lasts 5 s
    masks = {1: np.zeros(61, dtype=bool)}
    assert evaluate_tracks(_in_c(_perfect()), _truth(10.0), visible=masks).n_true == 2
    with pytest.raises(ValueError, match="sensor_pose"):
        evaluate_tracks(_in_c(_perfect()), _truth(10.0), hfov_deg=90.0)


# --------------------------------------------------------------------------------------------
# IoU
# --------------------------------------------------------------------------------------------
def _rect_poly(cx: float, cy: float, length: float, width: float) -> np.ndarray:
    return np.array([[cx - length / 2, cy - width / 2], [cx + length / 2, cy - width / 2],
                     [cx + length / 2, cy + width / 2], [cx - length / 2, cy + width / 2]])


def test_iou_closed_forms():
    polys = np.stack([
        _rect_poly(0.0, 0.0, 4.0, 2.0),  # identical
        _rect_poly(2.0, 0.0, 4.0, 2.0),  # half overlapping: 4 / (8 + 8 - 4) = 1/3
        _rect_poly(0.0, 1.0, 4.0, 2.0),  # half overlapping sideways
        _rect_poly(10.0, 0.0, 4.0, 2.0),  # disjoint
        _rect_poly(0.0, 0.0, 4.0, 2.0)[::-1],  # identical, clockwise
        _rect_poly(0.0, 0.0, 1.0, 1.0),  # inside: 1 / 8
        _rect_poly(2.0, 1.0, 4.0, 2.0),  # quarter: 2 / 14
    ])
    iou = iou_polygon_rectangle(polys, np.zeros((7, 2)), np.zeros(7), np.full(7, 4.0),
                                np.full(7, 2.0))
    np.testing.assert_allclose(iou, [1.0, 1 / 3, 1 / 3, 0.0, 1.0, 1 / 8, 2 / 14], atol=1e-12)
    # the same pair moved and rotated together keeps its IoU
    R = np.array([[np.cos(2.0), -np.sin(2.0)], [np.sin(2.0), np.cos(2.0)]])
    moved = polys[1] @ R.T + (100.0, -50.0)
    iou2 = iou_polygon_rectangle(moved[None], np.array([[100.0, -50.0]]), np.array([2.0]),
                                 np.array([4.0]), np.array([2.0]))
    assert iou2[0] == pytest.approx(1 / 3, abs=1e-12)
    # a polygon containing the whole box clips to the box
    big = _rect_poly(0.3, -0.2, 10.0, 10.0)[None]
    assert box_intersection_area(big, np.array([2.0]), np.array([1.0]))[0] == pytest.approx(8.0)


def _star(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 20, 2) random non-convex star polygons around random centres near the origin."""
    r = rng.uniform(0.3, 3.0, (n, N_CONTOUR))
    a = contour_angles() + rng.uniform(0, 2 * np.pi, (n, 1))
    c = rng.uniform(-2.0, 2.0, (n, 1, 2))
    return c + np.stack([r * np.cos(a), r * np.sin(a)], axis=-1)


def test_iou_non_convex_star_against_grid_estimate():
    rng = np.random.default_rng(3)
    polys = _star(rng, 6)
    yaw = rng.uniform(-np.pi, np.pi, 6)
    iou = iou_polygon_rectangle(polys, np.zeros((6, 2)), yaw, np.full(6, 4.5), np.full(6, 1.8))
    h = 0.01
    g = np.arange(-6.0, 6.0, h) + h / 2
    gx, gy = np.meshgrid(g, g)
    pts = np.column_stack([gx.ravel(), gy.ravel()])
    for k in range(6):
        in_poly = MplPath(polys[k]).contains_points(pts)
        c, s = np.cos(yaw[k]), np.sin(yaw[k])
        u, v = c * pts[:, 0] + s * pts[:, 1], -s * pts[:, 0] + c * pts[:, 1]
        in_rect = (np.abs(u) <= 2.25) & (np.abs(v) <= 0.9)
        grid = (in_poly & in_rect).sum() / (in_poly | in_rect).sum()
        assert 0.05 < grid < 0.95
        assert iou[k] == pytest.approx(grid, abs=4e-3)


def test_iou_batches_match_single_evaluations():
    rng = np.random.default_rng(4)
    base = _star(rng, 7)
    idx = rng.integers(0, 7, 40_000)  # more than one clipping chunk, mixed vertex counts
    yaw = rng.uniform(-np.pi, np.pi, 7)
    lengths, widths = rng.uniform(3.0, 6.0, 7), rng.uniform(1.5, 2.5, 7)
    batch = iou_polygon_rectangle(base[idx], np.zeros((idx.size, 2)), yaw[idx], lengths[idx],
                                  widths[idx])
    single = [iou_polygon_rectangle(base[k : k + 1], np.zeros((1, 2)), yaw[k : k + 1],
                                    lengths[k : k + 1], widths[k : k + 1])[0] for k in range(7)]
    np.testing.assert_allclose(batch, np.asarray(single)[idx], atol=1e-12)


def test_paper_average_rms_is_the_mean_of_per_track_rms():
    # vehicle 1 off by 0.3 m, vehicles 2 and 3 perfect: per-track RMS 0.3, 0, 0
    tracks = [_track(1, _times(1), dxy=(0.3, 0.0)), _track(2, _times(2)), _track(3, _times(3))]
    m = evaluate_tracks(_in_c(tracks), _truth(20.0))
    assert m.centre_rms_track_mean == pytest.approx(0.1, abs=1e-9)
    n1 = len(_times(1))
    pooled = np.sqrt(0.09 * n1 / sum(len(_times(v)) for v in (1, 2, 3)))
    assert m.centre_rms == pytest.approx(pooled, abs=1e-9)
