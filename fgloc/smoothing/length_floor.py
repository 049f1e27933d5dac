"""The occupied length the tracker measured as a floor under the batch smoother's length.

Seen end-on (a truck driving towards or away from the sensor) a vehicle's length is
unobservable in any one frame: the smoother's measurement rows see the near face and a few
grazing returns of the side, and its contour shrinks towards what they cover. The tracker
measures the length over the track's history instead: the occupied length of the detections
pooled behind the seen end (``[tracking] occupancy_gap``; a lower bound: where those
detections first leave a gap, less the last few), which it reports as ``Track.length_floor``
(the largest that set the contour's length, 0 without).

The batch smoother adds one one-sided row per (track, step) of a track with such a floor
(less twice ``[tracking] sigma_range``: the occupied length ends at a detection, whose range
noise may put it beyond the vehicle's end; a dense-return truck's was 0.2 m too long): the
contour length ``r_0 + r_{n/2}`` (front + rear radius, m) below the floor by ``d`` costs
``0.5 (d / sigma)^2``, above it nothing (``[smoothing] length_floor_sigma``). The smoother may
still lengthen the vehicle (a side seen later) or shorten a contour the filter let grow beyond
the vehicle, but not below what the tracker measured behind its seen end.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from factors.track_system import NormalEquations, StackedTracks
from fgloc.tracks import N_CONTOUR, N_KIN, N_STATE

#: state indices of the front and rear radius (their sum is the contour's length)
_FRONT, _REAR = N_KIN, N_KIN + N_CONTOUR // 2


def floor_rows(x: np.ndarray, floor: np.ndarray, sigma: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """Whitened residuals (K,) and Jacobians (K, 26) of the length floor at states x (K, 26)
    with floors (K,) m: ``min(length - floor, 0) / sigma`` (m / m)."""
    x = np.asarray(x, dtype=float)
    short = x[:, _FRONT] + x[:, _REAR] - np.asarray(floor, dtype=float)
    active = short < 0.0
    r = np.where(active, short, 0.0) / sigma
    J = np.zeros((len(x), N_STATE))
    J[:, _FRONT] = J[:, _REAR] = np.where(active, 1.0 / sigma, 0.0)
    return r, J


def length_floor_factor(key: int, floor: float, sigma: float) -> gtsam.CustomFactor:
    """gtsam factor of one floor row (:func:`floor_rows`) on the state ``key``; unit noise
    (the row is whitened)."""

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list) -> np.ndarray:
        x = values.atVector(this.keys()[0])[None]
        r, J = floor_rows(x, np.array([floor]), sigma)
        if H is not None:
            H[0] = np.asfortranarray(J)
        return r

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(1), [int(key)], error)


@dataclass
class FlooredTracks(StackedTracks):
    """:class:`factors.track_system.StackedTracks` plus one floor row per step in
    ``floor_step`` (N_f,) (unique stacked steps) with floors ``floor`` (N_f,) m and
    ``floor_sigma`` m."""

    floor_step: np.ndarray
    floor: np.ndarray
    floor_sigma: float

    def evaluate(self, x: np.ndarray) -> NormalEquations:
        ne = super().evaluate(x)
        if not len(self.floor_step):
            return ne
        s = self.floor_step
        r, J = floor_rows(np.asarray(x, dtype=float)[s], self.floor, self.floor_sigma)
        ne.cost[s] += 0.5 * r * r
        ne.D[s] += J[:, :, None] * J[:, None, :]
        ne.g[s] += J * r[:, None]
        return ne
