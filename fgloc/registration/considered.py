"""Biases a covariance *considers* without estimating them (Schmidt's consider parameters),
shared by the joint's graph covariance, the SICP track covariance (filter-sicp,
smoother-sicp) and icp's lane-fit covariance (:func:`fgloc.coarse.localize.lane_fit_considered`).

A bias ``c_j ~ N(0, sigma_j^2)`` (m) that shifts every point of a group along its line's
normal moves a least-squares pose estimate by ``K c``; the estimate's covariance grows by
``K diag(sigma^2) K^T``. Two such biases are considered for lane-line targets:

* a constant side bias of every point towards the sensor (the tracker's or the visible-side
  offset's error shared by all vehicles): where lanes pass on both sides of the sensor the
  geometry tells it from the pose, where all lie on one side (a T-junction) it moves the pose
  across the road by about its sigma;
* one lateral bias per lane (a centre line drawn off in the map, the drivers of one lane
  keeping to one side of it, the tracker's bias at that lane's range and aspect): the
  vehicles of one lane share it, so their number does not shrink it.

Frames: whatever frame the points, normals and sensor position share (L in every caller).
"""

from __future__ import annotations

import numpy as np


def side_sign(target: np.ndarray, normal: np.ndarray, sensor: np.ndarray) -> np.ndarray:
    """(P,) +1 where the sensor (2,) lies on the side of each point's line that its unit
    ``normal`` (P, 2) points to, else -1: a shift of ``sign * c`` along the normal moves the
    point ``c`` m towards the sensor. target (P, 2): the points on their lines."""
    return np.where(np.einsum("pi,pi->p", sensor - target, normal) >= 0.0, 1.0, -1.0)


def lane_columns(lane: np.ndarray) -> np.ndarray:
    """(P, L) coefficients of one lateral bias per lane: row p is 1 in the column of point p's
    lane (``lane`` (P,) lane ids, -1 = unmatched: a zero row), columns in order of the ids."""
    lane = np.asarray(lane).reshape(-1)
    ok = np.flatnonzero(lane >= 0)
    ids, which = np.unique(lane[ok], return_inverse=True)
    cols = np.zeros((len(lane), len(ids)))
    cols[ok, which.reshape(-1)] = 1.0
    return cols


def bias_columns(sign: np.ndarray, side_sigma: float, lane: np.ndarray | None,
                 lane_sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """The considered biases of P points: their coefficients (P, C) and std. devs. (C,) m.
    The side bias first (column ``sign`` (P,), :func:`side_sign`; when ``side_sigma`` > 0),
    then one per lane (:func:`lane_columns` of ``lane`` (P,); when given and ``lane_sigma``
    > 0). C = 0 when neither is."""
    cols, sd = [np.zeros((len(sign), 0))], []
    if side_sigma > 0.0:
        cols.append(np.asarray(sign, dtype=float)[:, None])
        sd.append(side_sigma)
    if lane_sigma > 0.0 and lane is not None:
        cols.append(lane_columns(lane))
        sd += [lane_sigma] * cols[-1].shape[1]
    return np.concatenate(cols, axis=1), np.array(sd)


def consider_covariance(info: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """(G, G) covariance added to the estimated parameters' by C biases that are considered,
    not estimated: info (G + C, G + C) the information (or any positive multiple of it)
    augmented by the biases last, the biases independent, ``c_j ~ N(0, sigma_j^2)`` m. The
    estimate moves by ``K c``, ``K = -S_ee^-1 S_ec`` (G, C), so ``K diag(sigma^2) K^T`` is
    added; the biases' own block ``S_cc`` is not used."""
    sigma = np.atleast_1d(np.asarray(sigma, dtype=float))
    G = len(info) - len(sigma)
    K = -np.linalg.solve(info[:G, :G], info[:G, G:])
    return (K * sigma**2) @ K.T


def least_squares_consider(H: np.ndarray, wa: np.ndarray, columns: np.ndarray,
                           sigma: np.ndarray) -> np.ndarray:
    """:func:`consider_covariance` of a weighted least-squares estimate ``dT = H^-1 sum_i w_i
    a_i r_i`` (``H = sum_i w_i a_i a_i^T``, G x G) whose residuals ``r_i`` the biases shift by
    ``columns`` (P, C) times them: ``wa`` (P, G) the rows ``w_i a_i``, sigma (C,) m."""
    cross = wa.T @ columns
    info = np.block([[H, cross], [cross.T, np.eye(columns.shape[1])]])
    return consider_covariance(info, sigma)
