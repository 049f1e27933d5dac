"""The GP-EOT factors of many tracks, evaluated for all steps at once: the normal equations
of the whole track graph in a few vectorized numpy calls instead of one Python callback per
factor.

It holds exactly the factors of :mod:`factors.gtsam_factors` -- a Gaussian prior on each
track's first state, a process factor between consecutive states, a stacked contour measurement
factor (normal-offset rows + optional visible-extent and range-rate rows) per step with
detections -- with the same residuals, noise and re-association per evaluation, and its cost
equals ``0.5 * sum of squared whitened residuals`` of the same gtsam graph (tests compare the
two). What changes is the evaluation: every process factor of every track in one batched CTRA
call, every measurement frame in batched association calls (frames padded to a common number of
detections, in chunks to bound memory).

Steps of all tracks are stacked: track ``t`` owns steps ``start[t]:start[t + 1]``; state
array ``x`` (N, 26) in the layout of :mod:`factors.state`. Because tracks share no variable and
a process factor joins only consecutive steps, the Gauss-Newton system is block tridiagonal
with 26 x 26 blocks (:class:`NormalEquations`), a banded matrix of half-bandwidth 51 over all
tracks at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factors.gtsam_factors import (
    ContourMeasurement,
    ExtentRows,
    RangeRateRows,
    measurement_rows,
    process_error,
    process_jacobian_x0,
)
from factors.state import N_STATE


def sqrt_information(cov: np.ndarray) -> np.ndarray:
    """(..., d, d) ``W`` with ``W^T W = cov^-1`` (``W = L^-1``, ``cov = L L^T``): the
    whitening of a Gaussian with covariance ``cov`` (..., d, d). ``ValueError`` if a
    covariance is not positive definite."""
    try:
        L = np.linalg.cholesky(0.5 * (cov + np.swapaxes(cov, -1, -2)))
    except np.linalg.LinAlgError as exc:
        raise ValueError("a covariance is not positive definite") from exc
    return np.linalg.inv(L)


def _apply(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(..., m) ``A v`` for A (..., m, n), v (..., n)."""
    return (A @ v[..., None])[..., 0]


def _apply_t(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(..., n) ``A^T v`` for A (..., m, n), v (..., m)."""
    return (v[..., None, :] @ A)[..., 0, :]


def _gram(A: np.ndarray) -> np.ndarray:
    """(..., n, n) ``A^T A`` for A (..., m, n)."""
    return np.swapaxes(A, -1, -2) @ A


@dataclass
class NormalEquations:
    """Gauss-Newton system of the stacked tracks at one estimate.

    cost (N,): ``0.5 * |whitened residual|^2`` of each step's factors (a prior and a
    measurement count at their step, a process factor at its later step). D (N, 26, 26):
    diagonal blocks ``sum J_i^T J_i``; B (P, 26, 26): the block (later step, earlier step) of
    each process factor; g (N, 26): ``J^T r`` (the gradient of the cost).
    """

    cost: np.ndarray
    D: np.ndarray
    B: np.ndarray
    g: np.ndarray


@dataclass
class StackedTracks:
    """All factors of a set of tracks (module docstring).

    start (T + 1,): step offsets of the tracks. prior_mean (T, 26) / prior_W (T, 26, 26):
    Gaussian prior on each first step (``W`` from :func:`sqrt_information`). proc_step (P,):
    the later step of each process factor (the earlier is ``proc_step - 1``), proc_dt (P,) s,
    proc_W (P, 26, 26): whitening of its noise (fixed at the reference state). meas_step
    (F,): the step of each measurement frame; meas: per chunk of frames a batched
    :class:`ContourMeasurement`, :class:`ExtentRows` and :class:`RangeRateRows` (each of the
    last two or None), ``chunks`` their frame offsets. proc_mean (P, 20) m: the decay target
    of each process factor (its track's GP prior mean: tracks may have different contour
    models); tau: the contour forgetting rate (1/s).
    """

    start: np.ndarray
    prior_mean: np.ndarray
    prior_W: np.ndarray
    proc_step: np.ndarray
    proc_dt: np.ndarray
    proc_W: np.ndarray
    meas_step: np.ndarray
    meas: list[tuple[ContourMeasurement, ExtentRows | None, RangeRateRows | None]]
    chunks: np.ndarray
    proc_mean: np.ndarray
    tau: float

    @property
    def n(self) -> int:
        """Number of stacked steps N."""
        return int(self.start[-1])

    def track_of_step(self) -> np.ndarray:
        """(N,) index of the track owning each step."""
        return np.repeat(np.arange(len(self.start) - 1), np.diff(self.start))

    def evaluate(self, x: np.ndarray) -> NormalEquations:
        """Cost per step and the normal equations at states ``x`` (N, 26)."""
        x = np.asarray(x, dtype=float)
        if x.shape != (self.n, N_STATE):
            raise ValueError(f"states shape {x.shape}, expected ({self.n}, {N_STATE})")
        cost = np.zeros(self.n)
        D = np.zeros((self.n, N_STATE, N_STATE))
        g = np.zeros((self.n, N_STATE))
        # priors
        first = self.start[:-1]
        r = _apply(self.prior_W, x[first] - self.prior_mean)
        cost[first] += 0.5 * np.sum(r * r, axis=1)
        D[first] += _gram(self.prior_W)
        g[first] += _apply_t(self.prior_W, r)
        # process factors
        p1 = self.proc_step
        p0 = p1 - 1
        B = np.zeros((0, N_STATE, N_STATE))
        if len(p1):
            r = _apply(self.proc_W, process_error(x[p0], x[p1], self.proc_dt, None, self.tau,
                                                  self.proc_mean))
            cost[p1] += 0.5 * np.sum(r * r, axis=1)
            J0 = self.proc_W @ process_jacobian_x0(x[p0], self.proc_dt, self.tau)
            D[p0] += _gram(J0)
            D[p1] += _gram(self.proc_W)
            B = np.swapaxes(self.proc_W, 1, 2) @ J0
            g[p0] += _apply_t(J0, r)
            g[p1] += _apply_t(self.proc_W, r)
        # measurement frames, chunk by chunk
        for (meas, *extras), a, b in zip(self.meas, self.chunks[:-1], self.chunks[1:]):
            steps = self.meas_step[a:b]
            r, J = measurement_rows(meas, tuple(extras), x[steps], True)
            r, J = r / meas.sigma, J / meas.sigma
            cost[steps] += 0.5 * np.sum(r * r, axis=1)
            D[steps] += _gram(J)
            g[steps] += _apply_t(J, r)
        return NormalEquations(cost, D, B, g)
