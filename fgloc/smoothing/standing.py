"""A vehicle's standing steps held still in the smoothers.

The re-linking joins the two tracks of a vehicle that stood (at a stop line, in a queue: its
returns were static and dropped) with rows that brake, stand and start
(:func:`fgloc.tracking.relink.stand_rows`), the standing ones flagged in ``Track.standing``.
Those rows hold no detection. Left to the process factors alone, a smoother finds the
smoothest motion between the stand's two ends instead -- a car that arrives and leaves at 2
m/s drives on through the stop and comes back, or turns round (a prototype of the link
without these rows: 5 m on and 180 deg round over a 20 s stand).

Every standing step adds two rows: its speed and its yaw rate, each whitened by
``[smoothing] stand_sigma_speed`` (m/s) and ``stand_sigma_yawrate`` (rad/s) -- a zero-velocity
update. The process model then keeps the centre and the heading (its position noise lets
a queue creep).
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from factors.track_system import NormalEquations
from fgloc.smoothing.length_floor import FlooredTracks
from fgloc.tracks import N_STATE, YAWRATE, V

#: the state entries a standing step holds at 0
_HELD = (V, YAWRATE)


def stand_jacobian(sigma_speed: float, sigma_yawrate: float) -> np.ndarray:
    """(2, 26) Jacobian of the whitened standing rows (speed / sigma_speed, yaw rate /
    sigma_yawrate); the rows are linear: residual = J x."""
    J = np.zeros((len(_HELD), N_STATE))
    J[0, V], J[1, YAWRATE] = 1.0 / sigma_speed, 1.0 / sigma_yawrate
    return J


def standing_factor(key: int, sigma_speed: float, sigma_yawrate: float) -> gtsam.CustomFactor:
    """gtsam factor of one standing step's rows (:func:`stand_jacobian`) on ``key``; unit
    noise (the rows are whitened)."""
    J = np.asfortranarray(stand_jacobian(sigma_speed, sigma_yawrate))

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list) -> np.ndarray:
        if H is not None:
            H[0] = J
        return J @ values.atVector(this.keys()[0])

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(len(_HELD)), [int(key)], error)


@dataclass
class StandingTracks(FlooredTracks):
    """:class:`fgloc.smoothing.length_floor.FlooredTracks` plus the standing rows of the
    stacked steps ``stand_step`` (N_s,) (unique), Jacobian ``stand_J`` (2, 26)
    (:func:`stand_jacobian`)."""

    stand_step: np.ndarray
    stand_J: np.ndarray

    def evaluate(self, x: np.ndarray) -> NormalEquations:
        ne = super().evaluate(x)
        if not len(self.stand_step):
            return ne
        s = self.stand_step
        r = np.asarray(x, dtype=float)[s] @ self.stand_J.T                # (N_s, 2)
        ne.cost[s] += 0.5 * np.sum(r * r, axis=1)
        ne.D[s] += self.stand_J.T @ self.stand_J
        ne.g[s] += r @ self.stand_J
        return ne
