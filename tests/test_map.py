"""Target cloud: Menger labels, polygon crop, labelled cloud, PLY round trip."""

from __future__ import annotations

import numpy as np
import pytest

from fgloc.config import MapConfig
from fgloc.errors import LocalizationError
from fgloc.geo import LocalFrame
from fgloc.io.ply import read_ply, write_labelled_ply
from fgloc.labels import LEFT, RIGHT, STRAIGHT
from fgloc.map import (
    build_target_cloud,
    label_lanelet,
    lanelet_curvatures,
    menger_curvature,
    points_in_polygon,
)
from fgloc.scenario import (
    AlsCloud,
    Lanelet,
    LaneletMap,
    RadarData,
    Scenario,
    SensorConfig,
)

GAMMA = 0.01


def arc(radius: float, sweep_deg: float, ccw: bool, n: int = 15) -> np.ndarray:
    """(n, 3) points on a circle of ``radius`` m starting at the origin heading +x."""
    th = np.deg2rad(np.linspace(0.0, sweep_deg, n))
    y = radius * (1.0 - np.cos(th))
    pts = np.column_stack([radius * np.sin(th), y if ccw else -y, np.zeros(n)])
    return pts


def lanelet_from_left(left: np.ndarray, lid: int = 1, width: float = 3.5) -> Lanelet:
    """A lanelet whose right bound is the left bound shifted ``width`` m to the right."""
    d = np.gradient(left[:, :2], axis=0)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    right = left.copy()
    right[:, :2] += width * np.column_stack([d[:, 1], -d[:, 0]])
    return Lanelet(id=lid, left=left, right=right)


# --------------------------------------------------------------------------------------------
# Menger curvature
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("radius", "ccw", "expected"),
    [(20.0, True, LEFT), (20.0, False, RIGHT), (50.0, True, LEFT), (50.0, False, RIGHT),
     (150.0, True, STRAIGHT), (150.0, False, STRAIGHT)],
    ids=["r20-ccw", "r20-cw", "r50-ccw", "r50-cw", "r150-ccw", "r150-cw"],
)
def test_label_of_arcs(radius: float, ccw: bool, expected: int) -> None:
    ll = lanelet_from_left(arc(radius, 60.0, ccw))
    assert label_lanelet(ll, GAMMA) == expected


def test_menger_curvature_of_circle_is_inverse_radius_with_sign() -> None:
    for r in (10.0, 50.0, 150.0):
        p = arc(r, 90.0, ccw=True, n=3)
        assert menger_curvature(p[0], p[1], p[2]) == pytest.approx(1.0 / r, rel=1e-9)
        assert menger_curvature(p[2], p[1], p[0]) == pytest.approx(-1.0 / r, rel=1e-9)


def test_menger_curvature_vectorized_and_degenerate() -> None:
    a = np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 1.0]])
    b = np.array([[1.0, 0.0], [5.0, 0.0], [1.0, 1.0]])
    c = np.array([[1.0, 1.0], [10.0, 0.0], [1.0, 1.0]])
    k = menger_curvature(a, b, c)
    assert k.shape == (3,)
    # right triangle with legs 1, 1: circumradius sqrt(2)/2, counter-clockwise
    assert k[0] == pytest.approx(np.sqrt(2.0))
    assert k[1] == 0.0  # collinear
    assert k[2] == 0.0  # coincident


def test_exact_straight_and_reversed_order() -> None:
    left = np.column_stack([np.linspace(0, 80, 9), np.linspace(0, 30, 9), np.zeros(9)])
    assert label_lanelet(lanelet_from_left(left), GAMMA) == STRAIGHT
    turn = arc(30.0, 90.0, ccw=True)
    assert label_lanelet(lanelet_from_left(turn), GAMMA) == LEFT
    # driving the same curve the other way round turns right
    assert label_lanelet(lanelet_from_left(turn[::-1].copy()), GAMMA) == RIGHT


def test_middle_point_is_by_arc_length() -> None:
    # dense vertices on the first half of a left arc, sparse on the second: the middle vertex
    # would sit near the start, the arc-length middle is the true middle of the curve
    th = np.deg2rad(np.concatenate([np.linspace(0, 45, 40), [67.5, 90.0]]))
    r = 30.0
    left = np.column_stack([r * np.sin(th), r * (1 - np.cos(th)), np.zeros(th.size)])
    ll = lanelet_from_left(left)
    assert lanelet_curvatures([ll])[0] == pytest.approx(1.0 / r, rel=0.01)


# --------------------------------------------------------------------------------------------
# point in polygon
# --------------------------------------------------------------------------------------------
def brute_force_inside(pt: np.ndarray, poly: np.ndarray) -> bool:
    """Winding number of one point (reference; the polygon is closed implicitly)."""
    wn = 0
    n = len(poly)
    for i in range(n):
        a, b = poly[i], poly[(i + 1) % n]
        cross = (b[0] - a[0]) * (pt[1] - a[1]) - (pt[0] - a[0]) * (b[1] - a[1])
        if a[1] <= pt[1] < b[1] and cross > 0:
            wn += 1
        elif b[1] <= pt[1] < a[1] and cross < 0:
            wn -= 1
    return wn != 0


CONCAVE = np.array([[0, 0], [10, 0], [10, 10], [6, 10], [6, 3], [4, 3], [4, 10], [0, 10]], float)
STAR = np.array(
    [[np.cos(a) * r, np.sin(a) * r] for a, r in zip(np.linspace(0, 2 * np.pi, 12, endpoint=False),
                                                   [10, 4] * 6)]
)


@pytest.mark.parametrize("poly", [CONCAVE, STAR, CONCAVE[::-1].copy()], ids=["U", "star", "U-cw"])
def test_points_in_polygon_matches_brute_force(poly: np.ndarray) -> None:
    rng = np.random.default_rng(3)
    lo, hi = poly.min(axis=0) - 2, poly.max(axis=0) + 2
    pts = rng.uniform(lo, hi, size=(4000, 2))
    got = points_in_polygon(pts, poly)
    ref = np.array([brute_force_inside(p, poly) for p in pts])
    assert got.sum() > 500 and (~got).sum() > 500
    np.testing.assert_array_equal(got, ref)


def test_points_on_edges_and_in_notch() -> None:
    on_edge = np.array([[5.0, 0.0], [10.0, 5.0], [6.0, 6.0], [5.0, 3.0], [0.0, 0.0]])
    notch = np.array([[5.0, 5.0], [5.0, 9.9]])  # inside the U's gap: outside the polygon
    assert points_in_polygon(on_edge, CONCAVE).all()
    assert not points_in_polygon(notch, CONCAVE).any()
    # a margin grows the polygon: the notch centre is 1 m from both notch walls
    assert points_in_polygon(np.array([[5.0, 6.0]]), CONCAVE, margin=1.01).all()


# --------------------------------------------------------------------------------------------
# target cloud
# --------------------------------------------------------------------------------------------
def constructed_scenario(road_class: int = 11, fill: int = 2) -> Scenario:
    """Three lanelets: a straight (id 10), a left arc (id 20) and a right arc (id 30), with a
    0.25 m ALS grid of class ``road_class`` inside the lanelets and ``fill`` elsewhere."""
    straight = lanelet_from_left(np.array([[-40.0, 0.0, 0.0], [0.0, 0.0, 0.0]]), lid=10)
    left = lanelet_from_left(arc(20.0, 90.0, ccw=True) + [0.0, 0.0, 0.0], lid=20)
    right = lanelet_from_left(arc(20.0, 90.0, ccw=False) + [0.0, -3.5, 0.0], lid=30)
    lmap = LaneletMap([straight, left, right])
    g = np.arange(-50.0, 40.0, 0.25)
    gx, gy = np.meshgrid(g, g, indexing="ij")
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    inside = np.zeros(len(xy), dtype=bool)
    for ll in lmap.lanelets:
        inside |= points_in_polygon(xy, ll.polygon())
    cls = np.where(inside, road_class, fill).astype(np.uint8)
    xyz = np.column_stack([xy, 0.01 * xy[:, 0]]).astype(np.float32)
    frame = LocalFrame.around(691000.0, 5335000.0)
    sensor = SensorConfig(approx_position=(691000.0 - 5.0, 5335000.0 + 8.0), max_range=100.0)
    empty = RadarData(np.zeros(0), np.zeros((0, 3)), np.zeros(0))
    return Scenario(frame, sensor, empty, AlsCloud(xyz, cls), lmap)


def test_target_cloud_labels_and_ids() -> None:
    scn = constructed_scenario()
    tc = build_target_cloud(scn, MapConfig(voxel_size=0.5))
    assert tc.lanelet_labels == {10: STRAIGHT, 20: LEFT, 30: RIGHT}
    assert tc.lanelet_curvature[20] == pytest.approx(1 / 20.0, rel=1e-6)
    assert tc.lanelet_curvature[30] == pytest.approx(-1 / 20.0, rel=1e-6)
    assert set(np.unique(tc.lanelet_id)) == {10, 20, 30}
    for lid, code in tc.lanelet_labels.items():
        sel = tc.lanelet_id == lid
        assert (tc.label[sel] == code).all()
        # every point of a lanelet lies in (or within half a voxel of) its polygon
        poly = next(ll for ll in scn.lanelets.lanelets if ll.id == lid).polygon()
        assert points_in_polygon(tc.xyz[sel, :2], poly, margin=0.36).all()
    # voxel 0.5 m on a 0.25 m grid: about a quarter of the points, one per occupied voxel
    straight = tc.xyz[tc.lanelet_id == 10]
    assert 40 * 3.5 * 4 * 0.8 < len(straight) < 40 * 3.5 * 4 * 1.3
    assert len(np.unique(np.floor(straight / 0.5), axis=0)) == len(straight)
    assert tc.xyz.dtype == np.float64 and tc.label.dtype == np.int8
    assert tc.warnings == []
    assert len(tc.of_label(LEFT)) == int((tc.lanelet_id == 20).sum())


def test_overlapping_lanelets_keep_one_copy_each() -> None:
    scn = constructed_scenario()
    twin = Lanelet(id=11, left=scn.lanelets.lanelets[0].left, right=scn.lanelets.lanelets[0].right)
    scn.lanelets.lanelets.append(twin)
    tc = build_target_cloud(scn, MapConfig())
    a, b = tc.xyz[tc.lanelet_id == 10], tc.xyz[tc.lanelet_id == 11]
    np.testing.assert_array_equal(np.sort(a, axis=0), np.sort(b, axis=0))
    assert len(tc.unique_xyz()) < len(tc)


def test_unclassified_als_falls_back_to_all_points_with_warning() -> None:
    tc = build_target_cloud(constructed_scenario(road_class=1, fill=1), MapConfig())
    assert len(tc) > 0 and any("no classified points" in w for w in tc.warnings)


def test_no_road_points_inside_lanelets_is_a_localization_error() -> None:
    with pytest.raises(LocalizationError, match="no ALS road points"):
        build_target_cloud(constructed_scenario(road_class=6, fill=6), MapConfig())


# --------------------------------------------------------------------------------------------
# PLY
# --------------------------------------------------------------------------------------------
def test_ply_round_trip_keeps_utm_to_the_millimetre(tmp_path) -> None:
    rng = np.random.default_rng(0)
    lo, hi = [690000.0, 5.33e6, 300.0], [692000.0, 5.34e6, 400.0]
    xyz = rng.uniform(lo, hi, size=(500, 3))
    xyz[0] = [691234.5678, 5335678.9012, 345.6789]
    label = rng.integers(0, 3, 500).astype(np.int8)
    lid = rng.integers(0, 10**6, 500)
    w = np.linspace(0, 1, 500)
    out = write_labelled_ply(tmp_path / "c.ply", xyz, label, lid, extra={"w": w})
    got = read_ply(out)
    assert np.abs(np.column_stack([got["x"], got["y"], got["z"]]) - xyz).max() < 1e-3
    assert got["x"].dtype == np.float64
    np.testing.assert_array_equal(got["label"], label)
    np.testing.assert_array_equal(got["lanelet_id"], lid)
    np.testing.assert_allclose(got["w"], w)
    header = out.read_bytes().split(b"end_header")[0].decode()
    assert "0=straight, 1=left, 2=right" in header
    assert [p.name for p in tmp_path.iterdir()] == ["c.ply"]  # no temporary file left


def test_ply_rejects_bad_shapes(tmp_path) -> None:
    with pytest.raises(ValueError, match="label"):
        write_labelled_ply(tmp_path / "c.ply", np.zeros((3, 3)), np.zeros(2))
    assert not any(tmp_path.iterdir())
