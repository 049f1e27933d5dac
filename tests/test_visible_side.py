"""The visible-side offset per aspect measured on the tracks (fgloc.registration.visible_side)
and what it does to the fine registration where one lane seen broadside fixes the pose along a
street seen head-on (junction 2 of the real map, issue 22)."""

from __future__ import annotations

import numpy as np

from fgloc.coarse.icp import LaneCentres
from fgloc.geo import se2, transform_points
from fgloc.registration.config import SicpConfig
from fgloc.registration.sicp import SemanticTargets, sicp
from fgloc.registration.visible_side import ASPECT_EDGES, measure_visible_side
from fgloc.scenario import Lanelet
from fgloc.tracks import N_STATE, YAW, Track

SENSOR = np.array([0.0, 0.0])


def true_offset(aspect: np.ndarray) -> np.ndarray:
    """Offset (m) of a vehicle's detections towards the sensor: 0.35 m head-on to 0.9 m
    broadside, as measured on simulated traffic (docs/experiments.md, issue 22)."""
    return 0.35 + 0.55 * aspect


def _lanelet(lid: int, start: tuple[float, float], end: tuple[float, float]) -> Lanelet:
    """A straight 3.5 m wide lanelet from ``start`` to ``end``."""
    a, b = np.array(start), np.array(end)
    d = (b - a) / np.linalg.norm(b - a)
    n = np.array([-d[1], d[0]]) * 1.75
    s = np.linspace(0.0, 1.0, 20)[:, None]
    line = a + s * (b - a)
    z = np.zeros((20, 1))
    return Lanelet(lid, np.hstack([line + n, z]), np.hstack([line - n, z]))


def _junction() -> LaneCentres:
    """A main street seen head-on from the sensor (along x, 5 m to the side of it) and one
    cross street seen broadside (along y at x = 40 m): only the cross street fixes x."""
    return LaneCentres.build([_lanelet(1, (10.0, -5.0), (120.0, -5.0)),
                              _lanelet(2, (40.0, -40.0), (40.0, 40.0))], 0.25)


def _tracks(lanes: LaneCentres, every: int = 4) -> tuple[list[Track], np.ndarray]:
    """One track per lane sample (every ``every``-th), one state each, its detection placed
    ``true_offset`` of the aspect towards the sensor; returns the tracks and the (N, 2)
    detections they index."""
    idx = np.arange(0, len(lanes.xy), every)
    aspect = lanes.aspect(SENSOR)[idx]
    side = np.sign(np.einsum("ij,ij->i", SENSOR - lanes.xy[idx], lanes.normal[idx]))
    det = lanes.xy[idx] + (true_offset(aspect) * side)[:, None] * lanes.normal[idx]
    tracks = []
    for k, i in enumerate(idx):
        st = np.zeros((1, N_STATE))
        st[0, :2] = lanes.xy[i]
        st[0, YAW] = np.arctan2(lanes.normal[i, 0], -lanes.normal[i, 1])  # left normal -> heading
        tracks.append(Track(k, np.zeros(1), st, np.zeros(1, np.int8),
                            det_index=np.array([k]), det_step=np.array([0])))
    return tracks, det


def test_offsets_are_the_detections_mean_per_aspect_bin_in_any_frame():
    lanes = _junction()
    tracks, det = _tracks(lanes)
    side = measure_visible_side(tracks, det, SENSOR, fallback=0.3)
    aspect = lanes.aspect(SENSOR)[::4]
    for b in range(len(ASPECT_EDGES) - 1):
        inside = (aspect >= ASPECT_EDGES[b]) & (aspect < ASPECT_EDGES[b + 1])
        if inside.sum() >= 20:
            assert abs(side.offset[b] - true_offset(aspect[inside]).mean()) < 1e-9
        else:
            assert np.isnan(side.offset[b])
    # a rigid move of everything (another coarse frame) measures the same offsets
    T = se2(-3.0, 7.0, 0.4)
    moved = [Track(tr.id, tr.t, tr.states.copy(), tr.labels, det_index=tr.det_index,
                   det_step=tr.det_step) for tr in tracks]
    for tr in moved:
        tr.states[:, :2] = transform_points(T, tr.states[:, :2])
        tr.states[:, YAW] += 0.4
    again = measure_visible_side(moved, transform_points(T, det), transform_points(
        T, SENSOR[None])[0], fallback=0.3)
    np.testing.assert_allclose(again.offset, side.offset, atol=1e-9)
    # without detections: the fallback everywhere
    assert np.all(measure_visible_side([], det, SENSOR, 0.3).at(np.array([0.0, 0.5, 1.0])) == 0.3)


def test_measured_offsets_fix_the_pose_along_a_street_seen_head_on():
    """The constant offset puts the broadside cross street's detections 0.5-0.6 m nearer the
    sensor than its target, and nothing else fixes x: the pose slides; the measured per-aspect
    offsets do not."""
    lanes = _junction()
    tracks, det = _tracks(lanes, every=1)
    label = np.zeros(len(det), np.int64)
    cfg = SicpConfig(max_correspondence=5.0, min_correspondence=1.5, info_window=0.0)
    side = measure_visible_side(tracks, det, SENSOR, fallback=0.3)
    errors = {}
    for name, offset in [("constant", 0.3), ("aspect", side.at(lanes.aspect(SENSOR)))]:
        target = SemanticTargets.build(lanes.towards(SENSOR, offset).xy, np.zeros(len(lanes.xy)))
        res = sicp(det, label, target, None, np.eye(3), cfg)
        errors[name] = np.hypot(*res.T[:2, 2])
    assert errors["constant"] > 0.3
    assert errors["aspect"] < 0.05
