"""Driving-behaviour labels of the lanelets (paper IV-A).

Every lanelet gets a label (:mod:`fgloc.labels`) from the signed Menger curvature of its LEFT
bound through the start point, the arc-length middle point and the end point: ``c > gamma`` and
counter-clockwise -> LEFT, ``c > gamma`` and clockwise -> RIGHT, else STRAIGHT (gamma = 0.01 1/m
in the paper). With ``[map] labels = "routing"`` (default) the lanelets of a junction movement in
the map's routing graph take the label the routing graph gives instead
(:func:`fgloc.labels.routing_labels`).

Middle point (the paper leaves it open): the point at half the arc length of the left bound
(linear interpolation), so that unevenly spaced vertices do not move it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgloc.config import MapConfig
from fgloc.labels import LEFT, RIGHT, STRAIGHT, routing_labels
from fgloc.scenario import Lanelet, LaneletMap, resample_polyline


def menger_curvature(p_st: np.ndarray, p_md: np.ndarray, p_ed: np.ndarray) -> np.ndarray | float:
    """Signed Menger curvature (1/m) of point triples in the horizontal plane.

    ``c = 4 Area / (|a| |b| |c|)`` with the triangle's side lengths; the sign is positive when
    (p_st, p_md, p_ed) turn counter-clockwise (seen from above), negative when clockwise. Inputs
    are (..., 2) or (..., 3) arrays (z ignored) broadcast against each other; degenerate triples
    (coincident points) give 0. Returns a float for single triples.
    """
    a = np.asarray(p_st, dtype=float)[..., :2]
    b = np.asarray(p_md, dtype=float)[..., :2]
    c = np.asarray(p_ed, dtype=float)[..., :2]
    ab, bc, ca = b - a, c - b, a - c
    cross = ab[..., 0] * (c - a)[..., 1] - ab[..., 1] * (c - a)[..., 0]  # = 2 * signed area
    denom = np.linalg.norm(ab, axis=-1) * np.linalg.norm(bc, axis=-1) * np.linalg.norm(ca, axis=-1)
    safe = np.where(denom > 0.0, denom, 1.0)
    k = np.where(denom > 0.0, 2.0 * cross / safe, 0.0)
    return float(k) if np.ndim(k) == 0 else k


def labels_from_curvature(k: np.ndarray, gamma: float) -> np.ndarray:
    """Label codes (int8) from signed curvatures (1/m): |k| > gamma turns, sign gives the side."""
    k = np.asarray(k, dtype=float)
    out = np.full(k.shape, STRAIGHT, dtype=np.int8)
    out[k > gamma] = LEFT
    out[k < -gamma] = RIGHT
    return out


def _bound_triples(lanelets: list[Lanelet]) -> np.ndarray:
    """(n, 3, 2) start, arc-length middle and end point of every lanelet's left bound."""
    if not lanelets:
        return np.zeros((0, 3, 2))
    return np.stack([resample_polyline(ll.left[:, :2], 3) for ll in lanelets])


def lanelet_curvatures(lanelets: list[Lanelet]) -> np.ndarray:
    """(n,) signed Menger curvature (1/m) of every lanelet's left bound."""
    tri = _bound_triples(lanelets)
    return np.asarray(menger_curvature(tri[:, 0], tri[:, 1], tri[:, 2]), dtype=float).reshape(-1)


def label_lanelet(lanelet: Lanelet, gamma: float) -> int:
    """Label code of one lanelet (see the module docstring)."""
    return int(labels_from_curvature(lanelet_curvatures([lanelet]), gamma)[0])


@dataclass
class LaneletLabels:
    """Label code, signed Menger curvature (1/m) and label source ("routing" or "curvature")
    of every drivable lanelet, by id."""

    code: dict[int, int]
    curvature: dict[int, float]
    source: dict[int, str]


def map_labels(lmap: LaneletMap, cfg: MapConfig) -> LaneletLabels:
    """Labels of the map's drivable lanelets (``cfg.labels``): the routing graph's for the
    lanelets of junction movements (:func:`fgloc.labels.routing_labels`) when ``"routing"``,
    Menger curvature for every other lanelet."""
    ids = [ll.id for ll in lmap.lanelets]
    curv = lanelet_curvatures(lmap.lanelets)
    code = {i: int(c) for i, c in zip(ids, labels_from_curvature(curv, cfg.gamma))}
    source = dict.fromkeys(ids, "curvature")
    if cfg.labels == "routing":
        routed = routing_labels(lmap, np.deg2rad(cfg.turn_angle_deg))
        code.update(routed)
        source.update(dict.fromkeys(routed, "routing"))
    return LaneletLabels(code, {i: float(k) for i, k in zip(ids, curv)}, source)
