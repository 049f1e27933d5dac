"""The coarse lane fits shift each lane sample towards the sensor by an offset that grows from
``coarse.visible_side_offset`` (lane seen head-on) to ``visible_side_offset_broadside`` (seen
broadside), linear in the |sin| of the aspect (closed form on straight lanes), and equal
offsets give the former constant shift."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fgloc.coarse import LaneCentres
from fgloc.coarse.localize import side_offsets
from fgloc.config import CoarseConfig


def _lanes() -> LaneCentres:
    """A lane along +x at y = 10 m and one along +y at x = -20 m, samples every 0.5 m."""
    s = np.arange(-60.0, 60.0 + 1e-9, 0.5)
    n = len(s)
    xy = np.vstack([np.column_stack([s, np.full(n, 10.0)]),
                    np.column_stack([np.full(n, -20.0), s])])
    normal = np.vstack([np.tile([0.0, 1.0], (n, 1)), np.tile([-1.0, 0.0], (n, 1))])
    return LaneCentres(xy, normal, np.zeros(2 * n, bool), np.zeros(2 * n, np.int64),
                       np.repeat([0, 1], n))


def test_offsets_grow_from_head_on_to_broadside_with_the_sine_of_the_aspect() -> None:
    """Sensor at (0, 0): a sample at (x, 10) of the lane along x is seen at |sin| = 10 / r, one
    at (-20, y) of the lane along y at 20 / r; the samples move that offset towards the sensor
    (-y for the first lane, +x for the second)."""
    lanes = _lanes()
    cfg = CoarseConfig(visible_side_offset=0.2, visible_side_offset_broadside=0.6)
    r = np.linalg.norm(lanes.xy, axis=1)
    aspect = np.where(lanes.lane == 0, 10.0, 20.0) / r
    expected = 0.2 + 0.4 * aspect
    off = side_offsets(lanes, np.zeros(2), cfg)
    np.testing.assert_allclose(off, expected, atol=1e-12)
    assert off.min() == pytest.approx(0.2 + 0.4 * 10.0 / np.hypot(60.0, 10.0))
    assert off[np.argmin(r)] == pytest.approx(0.6)       # (0, 10): broadside
    moved = lanes.towards(np.zeros(2), off).xy
    np.testing.assert_allclose(moved - lanes.xy,
                               np.where((lanes.lane == 0)[:, None],
                                        np.column_stack([0.0 * r, -expected]),
                                        np.column_stack([expected, 0.0 * r])), atol=1e-12)


def test_equal_offsets_are_the_constant_shift() -> None:
    lanes = _lanes()
    cfg = CoarseConfig(visible_side_offset=0.3, visible_side_offset_broadside=0.3)
    sensor = np.array([5.0, -4.0])
    seen = lanes.seen_from(sensor, side_offsets(lanes, sensor, cfg), 20.0)
    constant = lanes.seen_from(sensor, 0.3, 20.0)
    np.testing.assert_allclose(seen.receding.xy, constant.receding.xy, atol=1e-12)
    np.testing.assert_allclose(seen.approaching.xy, constant.approaching.xy, atol=1e-12)


@pytest.mark.parametrize("name", ["visible_side_offset", "visible_side_offset_broadside"])
def test_a_negative_offset_is_refused(name: str) -> None:
    with pytest.raises(ValueError, match=name):
        dataclasses.replace(CoarseConfig(), **{name: -0.1})
