"""The coarse stage's lane fits match a moving point only to lanes driven the way its Doppler
sign says (``coarse.lane_doppler_gate_deg``): the lanes seen from a sensor split by the sign
they admit (closed form), the dynamic cloud keeps one point per voxel and sign, and on a
two-way street driven on its centre line the keep-right lane model (a lane per direction 1.5 m
either side) no longer fits as well as the centre model by taking each vehicle to the nearer
lane of either direction."""

from __future__ import annotations

import numpy as np
import pytest

from fgloc.coarse import LaneCentres, dynamic_points
from fgloc.coarse.icp import PlanarTarget, SignedLanes
from fgloc.config import CoarseConfig
from fgloc.scenario import RadarData


def _two_lanes() -> tuple[LaneCentres, np.ndarray]:
    """Lane 0 along +x at y = 10 m, lane 1 along -x at y = 13.5 m, samples every 0.5 m over
    x in [-60, 60]; and the x of every sample."""
    x = np.arange(-60.0, 60.0 + 1e-9, 0.5)
    n = len(x)
    xy = np.vstack([np.column_stack([x, np.full(n, 10.0)]),
                    np.column_stack([x[::-1], np.full(n, 13.5)])])
    normal = np.vstack([np.tile([0.0, 1.0], (n, 1)), np.tile([0.0, -1.0], (n, 1))])
    lanes = LaneCentres(xy, normal, np.zeros(2 * n, bool), np.zeros(2 * n, np.int64),
                        np.repeat([0, 1], n))
    return lanes, xy[:, 0]


@pytest.mark.parametrize("gate_deg", [0.0, 20.0, 45.0])
def test_seen_from_splits_the_lanes_by_the_doppler_sign_of_their_traffic(gate_deg: float
                                                                           ) -> None:
    """Sensor at the origin: a sample of lane 0 (driven +x) at x with line of sight u has
    d . u = x / r; it admits receding points where x / r >= -sin(gate), approaching ones where
    x / r <= sin(gate); lane 1 (driven -x) the mirror image. Samples shifted 0.3 m towards the
    sensor."""
    lanes, x = _two_lanes()
    seen = lanes.seen_from(np.zeros(2), 0.3, gate_deg)
    shifted = lanes.xy - 0.3 * np.sign(lanes.xy[:, 1:2]) * np.array([0.0, 1.0])
    r = np.linalg.norm(shifted, axis=1)
    away = np.where(lanes.lane == 0, 1.0, -1.0) * shifted[:, 0] / r
    tol = np.sin(np.deg2rad(gate_deg))
    for target, admitted in ((seen.receding, away >= -tol), (seen.approaching, away <= tol)):
        assert sorted(map(tuple, target.xy)) == sorted(map(tuple, shifted[admitted]))
    # lanes square to the line of sight (x = 0) are in both only with a gate; far ones never
    both = {tuple(p) for p in seen.receding.xy} & {tuple(p) for p in seen.approaching.xy}
    assert all(abs(p[0]) <= np.hypot(p[0], p[1]) * tol + 1e-9 for p in both)
    assert len(both) == int(np.sum(np.abs(away) <= tol))


def test_a_ninety_degree_gate_admits_every_lane_for_both_signs() -> None:
    lanes, _ = _two_lanes()
    seen = lanes.seen_from(np.array([5.0, -3.0]), 0.3, 90.0)
    assert len(seen.receding.xy) == len(seen.approaching.xy) == len(lanes.xy)


def test_signed_query_matches_each_point_to_the_lanes_of_its_sign() -> None:
    """A receding point between the two lanes, nearer lane 1, is matched to lane 0 when lane 0
    is the one driven away from the sensor there (x > 0: lane 0 runs +x); an approaching point
    at the same place to lane 1; a plain target takes the nearer lane for both."""
    lanes, _ = _two_lanes()
    seen = lanes.seen_from(np.zeros(2), 0.0, 20.0)
    p = np.array([[40.0, 12.5], [40.0, 12.5]])
    d, near = seen.query(p, np.array([True, False]), 5.0)
    np.testing.assert_allclose(near[:, 1], [10.0, 13.5])
    np.testing.assert_allclose(d, [2.5, 1.0])
    plain = PlanarTarget.of(lanes.xy)
    np.testing.assert_allclose(plain.query(p, None, 5.0)[1][:, 1], [13.5, 13.5])
    with pytest.raises(ValueError, match="Doppler signs"):
        seen.query(p, None, 5.0)
    far = seen.query(np.array([[40.0, 30.0]]), np.array([True]), 5.0)
    assert np.isinf(far[0][0]) and np.allclose(far[1], [[40.0, 30.0]])
    assert isinstance(seen, SignedLanes)


def test_dynamic_points_keep_one_point_per_voxel_and_doppler_sign() -> None:
    """Two vehicles' detections on the same 6 m strip, one receding (+4 m/s), one approaching
    (-4 m/s), plus static returns (0 m/s): the cloud holds both signs over the strip (the
    voxels do not average the two directions into one point) and no static point."""
    rng = np.random.default_rng(3)
    n = 300
    x = rng.uniform(20.0, 26.0, n)
    y = rng.normal(5.0, 0.2, n)
    xyz = np.column_stack([x, y, rng.normal(0.5, 0.1, n)])
    doppler = np.repeat([4.0, -4.0, 0.0], n // 3)
    radar = RadarData(np.arange(n) * 0.01, xyz, doppler)
    source = dynamic_points(radar, CoarseConfig())
    pts, receding = source.xyz, source.receding
    assert source.n_dynamic == 200 and source.n_off_trail == 0   # two dense trails: all on
    # the vertical fit's detections are the moving ones themselves, not the voxels
    np.testing.assert_array_equal(source.detections, xyz[:200])
    assert receding.any() and (~receding).any()
    for sign in (True, False):
        on = pts[receding == sign]
        assert on[:, 0].min() < 21.0 and on[:, 0].max() > 25.0
    # one point per (voxel, sign): a voxel holding detections of both signs gives two
    voxel = np.floor(xyz[:200] / 0.5).astype(int)
    ahead, back = {tuple(v) for v in voxel[:100]}, {tuple(v) for v in voxel[100:]}
    assert ahead & back                       # the two directions share voxels
    assert int(receding.sum()) == len(ahead) and int((~receding).sum()) == len(back)


def test_gate_config_is_checked() -> None:
    with pytest.raises(ValueError, match="lane_doppler_gate_deg"):
        CoarseConfig(lane_doppler_gate_deg=120.0)
