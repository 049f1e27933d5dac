"""Lane samples labelled by the curvature of their lane's path (fgloc.map.path_labels)."""

from __future__ import annotations

import numpy as np
import pytest

from fgloc.labels import LEFT, RIGHT, STRAIGHT
from fgloc.map.path_labels import path_curvature, path_labels


def _lanes(chords: list[np.ndarray], step: float = 0.25
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[tuple[int, bool]]]:
    """Samples (about ``step`` m apart), unit driving directions and lane indices of lanes that
    are the straight segments between consecutive points of each of ``chords`` ((n, 2) each):
    one lane per segment, as a hand-mapped map draws a curve with 2-node lanelets."""
    xy, heading, lane, keys = [], [], [], []
    for a, b in (pair for c in chords for pair in zip(c[:-1], c[1:])):
        n = max(2, int(np.ceil(np.linalg.norm(b - a) / step)) + 1)
        t = np.linspace(0.0, 1.0, n)[:, None]
        xy.append(a + t * (b - a))
        heading.append(np.tile((b - a) / np.linalg.norm(b - a), (n, 1)))
        lane.append(np.full(n, len(keys)))
        keys.append((len(keys) + 1, False))
    return np.vstack(xy), np.vstack(heading), np.concatenate(lane), keys


def _circle_chords(radius: float, a0: float, a1: float, n: int) -> np.ndarray:
    a = np.linspace(a0, a1, n + 1)
    return radius * np.column_stack([np.cos(a), np.sin(a)])


@pytest.mark.parametrize("sigma", [2.0, 4.0])
@pytest.mark.parametrize("ccw", [True, False])
def test_a_roundabout_of_straight_lanelets_turns_all_the_way(sigma: float, ccw: bool) -> None:
    """A circle of radius 20 m drawn as 16 straight 2-node lanelets (7.8 m each; their own
    bounds have no curvature): away from the chain's ends the path curvature averages 1/20
    m^-1 within 10 % and nowhere falls below 1/50 (the kinks are spread over sigma, the chords
    between them keep a little of it; with sigma = 1 m the chords' middles, 3.9 m from a kink,
    are straight), so every sample there is labelled LEFT (counter-clockwise) or RIGHT
    (clockwise)."""
    a0, a1 = (0.0, 2 * np.pi) if ccw else (2 * np.pi, 0.0)
    xy, heading, lane, keys = _lanes([_circle_chords(20.0, a0, a1, 16)])
    kappa = path_curvature(xy, heading, lane, keys, sigma)
    inner = (lane >= 2) & (lane <= 13)
    sign = 1.0 if ccw else -1.0
    assert np.mean(sign * kappa[inner]) == pytest.approx(1 / 20.0, rel=0.1)
    assert np.min(sign * kappa[inner]) > 1 / 50.0
    labels = path_labels(xy, heading, lane, keys, sigma, 0.01)
    assert np.all(labels[inner] == (LEFT if ccw else RIGHT))


def test_a_kink_is_spread_over_sigma_and_turns_by_its_angle() -> None:
    """Two straight lanes meeting at a 30 deg kink: the curvature integrates to the kink's
    angle over the chain, peaks at the join with the Gaussian's height (30 deg / (sigma
    sqrt(2 pi))) and is straight 4 sigma away from it."""
    sigma, turn = 2.0, np.deg2rad(30.0)
    p0, p1 = np.array([-30.0, 0.0]), np.array([0.0, 0.0])
    p2 = 30.0 * np.array([np.cos(turn), np.sin(turn)])
    xy, heading, lane, keys = _lanes([np.array([p0, p1, p2])])
    kappa = path_curvature(xy, heading, lane, keys, sigma)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    assert np.trapezoid(kappa, s) == pytest.approx(turn, rel=0.03)
    assert kappa.max() == pytest.approx(turn / (sigma * np.sqrt(2 * np.pi)), rel=0.1)
    far = np.linalg.norm(xy - p1, axis=1) > 4 * sigma
    assert np.abs(kappa[far]).max() < 0.01
    labels = path_labels(xy, heading, lane, keys, sigma, 0.01)
    assert np.all(labels[far] == STRAIGHT) and np.any(labels == LEFT)


def test_a_lane_without_neighbours_keeps_its_own_curvature() -> None:
    """One lane sampled densely on an arc of radius 50 m, nothing before or after it: 1/50
    within 5 % in its middle; an empty input gives nothing."""
    a = np.linspace(0.0, 0.8, 161)
    xy = 50.0 * np.column_stack([np.cos(a), np.sin(a)])
    heading = np.column_stack([-np.sin(a), np.cos(a)])
    kappa = path_curvature(xy, heading, np.zeros(len(a), int), [(1, False)], 2.0)
    assert np.allclose(kappa[40:-40], 1 / 50.0, rtol=0.05)
    assert path_curvature(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, int), [], 2.0).size == 0


def test_config_names_a_bad_lane_label_rule() -> None:
    from fgloc.config import MapConfig

    assert MapConfig().lane_labels == "path"
    with pytest.raises(ValueError, match="lane_labels must be 'lanelet' or 'path'"):
        MapConfig(lane_labels="curvature")
    with pytest.raises(ValueError, match="path_sigma must be >= 0"):
        MapConfig(lane_labels="path", path_sigma=-1.0)
