"""A lanelet's centre line (``[map] centre_line``, :meth:`fgloc.scenario.Lanelet.centre`): the
arc-length construction, lanelet2's and the mean of both, the ambiguity between them, the lanes
built on them, and the joint's point noise that counts the ambiguity. Checked against
lanelet2 itself and against closed forms: an arc drawn with many nodes (the constructions
agree) and a turn drawn with few, unevenly spaced ones (from the Lanelet2 example map, lanelet
45096: they lie up to 2 m apart)."""

from __future__ import annotations

import lanelet2
import numpy as np
import pytest
from lanelet2.core import LineString3d, Point3d, getId
from scipy.spatial import cKDTree

from fgloc.coarse import LaneCentres
from fgloc.config import Config, MapConfig, from_dict
from fgloc.errors import InputError
from fgloc.registration.fine import centre_weights
from fgloc.registration.joint import LaneLines, NoiseLevels, _ambiguity, centre_shift
from fgloc.registration.joint_config import check_joint_config
from fgloc.registration.source import check_fine_config
from fgloc.scenario import CENTRE_LINES, Lanelet, centre_ambiguity, resample_polyline

#: lanelet 45096 of the Lanelet2 example map (BSD-3-Clause, FZI), bounds relative to its
#: left bound's first node: a left turn, the outer bound drawn with 5 nodes, the inner with 4
TURN_LEFT = np.array([[0.0, 0.0], [-6.02, 2.95], [-11.78, 6.24], [-12.29, 10.04], [-11.7, 13.82]])
TURN_RIGHT = np.array([[1.09, 3.17], [-0.57, 4.19], [-3.62, 9.15], [-3.78, 10.9]])


def _lanelet(left: np.ndarray, right: np.ndarray, lid: int = 1, one_way: str = "yes") -> Lanelet:
    z = np.zeros((1,))
    return Lanelet(lid, np.column_stack([left, np.resize(z, len(left))]),
                   np.column_stack([right, np.resize(z, len(right))]),
                   {"subtype": "road", "one_way": one_way})


def _arc(radius: float, n: int) -> np.ndarray:
    a = np.linspace(0.0, 0.5 * np.pi, n)
    return radius * np.column_stack([np.cos(a), np.sin(a)])


def _dense(line: np.ndarray) -> cKDTree:
    return cKDTree(resample_polyline(line, 2000))


def test_lanelet2_centerline_is_lanelet2s() -> None:
    ll = _lanelet(TURN_LEFT, TURN_RIGHT)
    ref = lanelet2.core.Lanelet(
        getId(), *(LineString3d(getId(), [Point3d(getId(), x, y, 0.0) for x, y in b])
                   for b in (TURN_LEFT, TURN_RIGHT))).centerline
    np.testing.assert_allclose(ll.lanelet2_centerline(), [[p.x, p.y] for p in ref])
    assert ll.lanelet2_centerline() is ll.lanelet2_centerline()         # computed once


def test_constructions_agree_on_an_arc_drawn_with_many_nodes() -> None:
    """Concentric arcs, 3.5 m apart, 40 nodes each: every kind lies on the middle arc
    (radius 11.75 m) within 2 cm and the ambiguity is below 1 cm."""
    ll = _lanelet(_arc(10.0, 40), _arc(13.5, 40))
    for kind in CENTRE_LINES:
        line, off = ll.centre(60, kind)
        np.testing.assert_allclose(np.linalg.norm(line, axis=1), 11.75, atol=0.02)
        assert np.linalg.norm(off, axis=1).max() < 0.02


def test_constructions_differ_on_a_turn_drawn_with_few_nodes() -> None:
    ll = _lanelet(TURN_LEFT, TURN_RIGHT)
    n = 80
    own, off = ll.centre(n, "resampled")
    other, off2 = ll.centre(n, "lanelet2")
    mean, off3 = ll.centre(n, "mean")
    np.testing.assert_allclose(own, ll.centerline(n))
    np.testing.assert_allclose(other, resample_polyline(ll.lanelet2_centerline(), n))
    np.testing.assert_array_equal(off, off2)
    np.testing.assert_array_equal(off, off3)
    # the offset reaches lanelet2's line, the nearest point of it (both lines start and stop
    # at the bounds' midpoints); the ambiguity is half its length
    gap, _ = _dense(ll.lanelet2_centerline()).query(own)
    np.testing.assert_allclose(np.linalg.norm(off, axis=1), gap, atol=0.01)
    np.testing.assert_allclose(_dense(ll.lanelet2_centerline()).query(own + off)[0], 0.0,
                               atol=0.005)
    amb = 0.5 * np.linalg.norm(off, axis=1)
    assert amb[[0, -1]].max() < 1e-9
    assert 0.5 < amb.max() < 1.2
    # the mean lies midway: the ambiguity away from the arc-length line and from lanelet2's
    np.testing.assert_allclose(np.linalg.norm(mean - own, axis=1), amb, atol=1e-9)
    np.testing.assert_allclose(_dense(ll.lanelet2_centerline()).query(mean)[0], amb,
                               atol=0.005)
    with pytest.raises(ValueError, match="centre line"):
        ll.centre(n, "spline")


def test_lanes_follow_the_centre_line_asked_both_ways() -> None:
    """A two-way lanelet on the turn driven on its centre line both ways (the "centre" lane
    model): the lanes are the lanelet's centre line of the kind asked, backwards for the
    lane against it, and carry the ambiguity in their driving direction."""
    ll = _lanelet(TURN_LEFT, TURN_RIGHT, one_way="no")
    for kind in CENTRE_LINES:
        lanes = LaneCentres.build([ll], 0.5, np.inf, centre=kind)
        fwd, back = ~lanes.against, lanes.against
        n = int(fwd.sum())
        assert n == int(back.sum()) >= 20
        line, off = ll.centre(n, kind)
        np.testing.assert_allclose(lanes.xy[fwd], line, atol=1e-9)
        np.testing.assert_allclose(lanes.xy[back], line[::-1], atol=1e-9)
        np.testing.assert_allclose(lanes.centre_offset[fwd], off)
        np.testing.assert_allclose(lanes.centre_offset[back], off[::-1])
        # the normals are the left normals of the driving direction
        d = np.gradient(lanes.xy[fwd], axis=0)
        assert (np.einsum("ij,ij->i", lanes.normal[fwd], d) < 1e-9).all()


def test_sicp_lane_targets_weigh_less_where_the_centre_is_ambiguous() -> None:
    """``[fine] centre_weight_sigma``: a lane sample ambiguous by a m weighs s^2 / (s^2 + a^2)
    in filter-sicp's and smoother-sicp's alignment; the turn drawn with few nodes weighs down
    to a fifth or less, the arc drawn with many nodes keeps its weight."""
    np.testing.assert_allclose(centre_weights(np.array([0.0, 0.25, 0.5]), 0.25),
                               [1.0, 0.5, 0.2])
    assert centre_weights(np.array([0.3]), 0.0) is None
    turn, arc = _lanelet(TURN_LEFT, TURN_RIGHT, 1), _lanelet(_arc(10.0, 40), _arc(13.5, 40), 2)
    lanes = LaneCentres.build([turn, arc], 0.25, centre="mean")
    amb = centre_ambiguity(lanes.centre_offset)
    np.testing.assert_allclose(amb, 0.5 * np.linalg.norm(lanes.centre_offset, axis=1))
    w = centre_weights(amb, Config().fine.centre_weight_sigma)
    assert w[lanes.lanelet == 1].min() > 0.99
    assert w[lanes.lanelet == 0].min() < 0.2
    assert w[lanes.lanelet == 0][[0, -1]].min() > 0.99      # both lines end mid-bounds
    cfg = Config()
    cfg.fine.centre_weight_sigma = -0.1
    with pytest.raises(ValueError, match="centre_weight_sigma"):
        check_fine_config(cfg.fine)


def test_joint_point_noise_counts_the_ambiguity() -> None:
    levels = NoiseLevels(within=0.2, frame=0.3, rho=0.5, offset=0.2)
    per_frame = np.array([1, 4, 4])
    base = levels.point_sigma(per_frame)
    np.testing.assert_allclose(base, 0.3 * np.sqrt(3.0 * per_frame))
    amb = np.array([0.0, 0.4, 0.0])
    np.testing.assert_allclose(levels.point_sigma(per_frame, amb),
                               np.sqrt(0.09 + amb**2) * np.sqrt(3.0 * per_frame))
    lines = LaneLines.of(np.zeros((3, 2)), np.tile([0.0, 1.0], (3, 1)), np.zeros(3),
                         centre_offset=np.array([[0.2, 0.0], [0.0, -0.4], [0.36, 0.48]]))
    index = np.array([2, -1, 0, 1])
    np.testing.assert_allclose(_ambiguity(lines, index, 2.0), [0.6, 0.0, 0.2, 0.4])
    assert _ambiguity(lines, index, 0.0) == 0.0
    assert _ambiguity(LaneLines.of(np.zeros((3, 2)), np.tile([0.0, 1.0], (3, 1)),
                                   np.zeros(3)), index, 1.0) == 0.0
    with pytest.raises(ValueError, match="centre_offset"):
        LaneLines.of(np.zeros((3, 2)), np.tile([0.0, 1.0], (3, 1)), np.zeros(3),
                     centre_offset=np.zeros((2, 2)))
    # a bend (a lane bent into its neighbour's) adds in quadrature, also without offsets
    bent = LaneLines.of(lines.xy, lines.normal, lines.label,
                        centre_offset=lines.centre_offset, bend=np.array([0.0, 0.15, 0.4]))
    np.testing.assert_allclose(bent.ambiguity, [0.1, 0.25, 0.5])
    alone = LaneLines.of(lines.xy, lines.normal, lines.label, bend=np.array([0.0, 0.15, 0.4]))
    np.testing.assert_allclose(_ambiguity(alone, index, 1.0), [0.4, 0.0, 0.0, 0.15])
    with pytest.raises(ValueError, match="bend"):
        LaneLines.of(np.zeros((3, 2)), np.tile([0.0, 1.0], (3, 1)), np.zeros(3),
                     bend=np.zeros(2))
    # the share's coefficient: the offset along each point's oriented normal
    normal = np.array([[0.0, 1.0], [1.0, 0.0], [0.0, -1.0], [0.0, 1.0]])
    np.testing.assert_allclose(centre_shift(lines, index, normal), [0.48, 0.0, 0.0, -0.4])
    assert centre_shift(LaneLines.of(np.zeros((3, 2)), np.tile([0.0, 1.0], (3, 1)),
                                     np.zeros(3)), index, normal) is None


def test_centre_line_setting() -> None:
    assert MapConfig().centre_line == "mean" and Config().joint.centre_ambiguity == 1.0
    assert Config().joint.centre_line_sigma == 0.5
    assert from_dict(Config, {"map": {"centre_line": "lanelet2"}}, "x.toml") \
        .map.centre_line == "lanelet2"
    with pytest.raises(InputError, match="centre_line"):
        from_dict(Config, {"map": {"centre_line": "middle"}}, "x.toml")
    cfg = Config()
    cfg.joint.centre_ambiguity = -1.0
    with pytest.raises(ValueError, match="centre_ambiguity"):
        check_joint_config(cfg.joint)
    cfg = Config()
    cfg.joint.centre_line_sigma = -0.1
    with pytest.raises(ValueError, match="centre_line_sigma"):
        check_joint_config(cfg.joint)
