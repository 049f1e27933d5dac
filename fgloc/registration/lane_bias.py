"""Lateral biases of the lanes *estimated* in the joint (``[joint] lane_bias_sigma``).

A lane's vehicles can share an offset from its target line: a centre line drawn off in the
map, drivers keeping to one side of their lane, the tracker's bias at that lane's range and
aspect. :mod:`fgloc.registration.considered` adds such biases to the covariance only
(``consider_lane_bias_sigma``); the estimate stays the ordinary weighted least-squares one,
in which a lane weighs as much as its number of points says, so one busy lane that is off
pulls the pose with it. Estimating the biases -- one global parameter per lane that holds
matched points, prior ``N(0, lane_bias_sigma^2)`` -- makes the estimate the generalized
least-squares one under the same model: the correlated part of a lane's errors is taken out,
and a lane tells the pose at most about as much as one line measurement of std. dev.
``lane_bias_sigma``. The pose's marginal covariance then contains the biases' share, so
they are no longer considered on top.

Frames: a bias moves every target of its lane along the point's oriented normal (L).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fgloc.registration.considered import lane_columns


@dataclass
class LaneBiases:
    """The lanes' estimated lateral biases (m) across the rounds of the joint: ``values``
    keeps each lane's last estimate (lane id -> m), ``ids`` (L,) are the lanes of the current
    round (those that hold matched points, ascending), whose biases are the last L global
    parameters of its problem; ``sigma`` (m) is their prior std. dev."""

    sigma: float
    values: dict[int, float] = field(default_factory=dict)
    ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    def select(self, lane: np.ndarray) -> np.ndarray:
        """Take the lanes of the points ``lane`` (P,) (-1 = unmatched) as the round's and
        return each point's coefficients (P, L) of their biases (1 in its lane's column)."""
        lane = np.asarray(lane, dtype=np.int64)
        self.ids = np.unique(lane[lane >= 0])
        return lane_columns(lane)

    def params(self) -> np.ndarray:
        """(L,) the round's lanes' biases (m) at their last estimate (0 for a new lane)."""
        return np.array([self.values.get(int(i), 0.0) for i in self.ids])

    def prior_weights(self) -> np.ndarray:
        """(L,) prior sqrt information (1/m) of the round's lanes' biases."""
        return np.full(len(self.ids), 1.0 / self.sigma)

    def store(self, params: np.ndarray) -> None:
        """Keep the round's estimates ``params`` (L,) m for the next rounds."""
        self.values.update({int(i): float(v) for i, v in zip(self.ids, params)})

    def free_params(self, variance: np.ndarray) -> float:
        """How many parameters the round's lane biases count as in a small-sample correction:
        ``sum_j (1 - v_j / sigma^2)`` (0 for a bias its prior holds, 1 for one the data fix),
        ``variance`` (L,) m^2 their marginal variances ``v_j``."""
        return float(np.sum(np.clip(1.0 - np.asarray(variance) / self.sigma**2, 0.0, 1.0)))

    def summary(self) -> dict[str, float]:
        """JSON-ready lane id -> estimated bias (m) of every lane estimated so far."""
        return {str(i): round(v, 4) for i, v in sorted(self.values.items())}
