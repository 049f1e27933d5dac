"""Planar paths made of primitives of constant curvature (straight lines and circular arcs).

A primitive is ``(length m, curvature 1/m)``, curvature > 0 turning left (CCW). A path is a start
point, a start heading (rad, CCW from the x axis) and a list of primitives; offsetting such a path
sideways gives again lines and concentric arcs, so lane bounds stay exact.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

Prim = tuple[float, float]


@dataclass
class Trace:
    """A sampled path. s: (n,) arc length (m); xy: (n, 2); heading: (n,) unwrapped rad;
    kappa: (n,) curvature (1/m)."""

    s: np.ndarray
    xy: np.ndarray
    heading: np.ndarray
    kappa: np.ndarray

    def normal(self) -> np.ndarray:
        """(n, 2) unit normals pointing left of the driving direction."""
        return np.column_stack([-np.sin(self.heading), np.cos(self.heading)])

    def offset(self, d: float) -> np.ndarray:
        """(n, 2) points ``d`` metres to the left (negative: right)."""
        return self.xy + d * self.normal()

    @property
    def length(self) -> float:
        return float(self.s[-1])


def _advance(xy: np.ndarray, heading: float, s: np.ndarray, kappa: float) -> np.ndarray:
    """Points at arc lengths ``s`` along a constant-curvature primitive (chord formula)."""
    half = 0.5 * kappa * s
    chord = s * np.sinc(half / np.pi)
    ang = heading + half
    return xy + np.column_stack([chord * np.cos(ang), chord * np.sin(ang)])


def end_pose(start: np.ndarray, heading: float, prims: list[Prim]) -> tuple[np.ndarray, float]:
    """End point and heading of a path."""
    xy = np.asarray(start, dtype=float)
    for length, kappa in prims:
        xy = _advance(xy, heading, np.array([length]), kappa)[0]
        heading += kappa * length
    return xy, heading


def trace(start: np.ndarray, heading: float, prims: list[Prim], ds: float) -> Trace:
    """Sample a path about every ``ds`` metres (both ends of every primitive included)."""
    xy0 = np.asarray(start, dtype=float)
    parts_s, parts_xy, parts_h, parts_k = [np.zeros(1)], [xy0[None]], [np.array([heading])], []
    s0 = 0.0
    first_kappa = prims[0][1]
    for length, kappa in prims:
        n = max(1, int(np.ceil(length / ds)))
        s = np.linspace(0.0, length, n + 1)[1:]
        parts_s.append(s0 + s)
        parts_xy.append(_advance(xy0, heading, s, kappa))
        parts_h.append(heading + kappa * s)
        parts_k.append(np.full(n, kappa))
        xy0 = parts_xy[-1][-1]
        heading += kappa * length
        s0 += length
    return Trace(
        np.concatenate(parts_s),
        np.vstack(parts_xy),
        np.concatenate(parts_h),
        np.concatenate([[first_kappa], *parts_k]),
    )


def offset_prims(prims: list[Prim], d: float) -> list[Prim]:
    """Primitives of the path offset ``d`` metres to the left (concentric arcs)."""
    return [(length * (1.0 - kappa * d), kappa / (1.0 - kappa * d)) for length, kappa in prims]


def reverse_prims(prims: list[Prim]) -> list[Prim]:
    """Primitives of the same path driven backwards from its end (heading + pi)."""
    return [(length, -kappa) for length, kappa in reversed(prims)]


def turn_prims(p0: np.ndarray, h0: float, p1: np.ndarray, h1: float) -> list[Prim]:
    """Line - circular arc - line from pose (p0, h0) to pose (p1, h1).

    The arc is tangent to both lines; its radius is the largest that fits, so one of the two
    straight parts has zero length (dropped). Raises ValueError when the lines do not meet ahead.
    """
    d0 = np.array([np.cos(h0), np.sin(h0)])
    d1 = np.array([np.cos(h1), np.sin(h1)])
    a, b = np.linalg.solve(np.column_stack([d0, d1]), np.asarray(p1) - np.asarray(p0))
    phi = float((h1 - h0 + np.pi) % (2.0 * np.pi) - np.pi)
    if a <= 0 or b <= 0 or abs(phi) < 1e-6:
        raise ValueError("turn poses do not define a forward turn")
    m = min(a, b)
    radius = m / np.tan(abs(phi) / 2.0)
    prims = [(a - m, 0.0), (radius * abs(phi), np.sign(phi) / radius), (b - m, 0.0)]
    return [(length, kappa) for length, kappa in prims if length > 1e-9]
