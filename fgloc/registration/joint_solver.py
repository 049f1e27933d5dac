"""The joint registration's least-squares problem and its solver: track states, one sensor
pose and per-track lateral offsets, vectorized.

Variables: the stacked track states ``x`` (N, 26) (:class:`factors.track_system.StackedTracks`
order), the global parameters ``p`` -- the pose ``(tx, ty, phi)`` (C -> L) and, optionally, a
side bias ``beta`` (m): the common offset of every vehicle's contour points towards the
sensor (a point's offset along its normal is ``b_t + beta side_i``, ``side_i = +-1`` the
sensor's side of its line) -- and one lateral offset ``b_t`` (m) per track (none when the
offsets are off). Cost (``0.5 |whitened residual|^2`` summed):

* the track factors (prior, process, contour measurement) as a quadratic model about a
  linearization point ``x_lin``: ``c + g . dx + 0.5 dx^T H dx`` with ``dx = x - x_lin`` and
  ``H`` block tridiagonal (:class:`TrackQuadratic`; the joint linearizes them once at the
  filter's states, or again each round with ``relinearize_tracks``);
* the point-to-point rows of every matched point (:func:`factors.registration_factors.
  point_rows_batch`, weights fixed per round), evaluated exactly at each iteration;
* a Gaussian prior on the global parameters (the pose at the coarse pose: zero) and on
  each offset (mean 0).

The Gauss-Newton system is arrow shaped: the banded track block ``A``, the border ``E`` to
the global parameters and the offsets (the offset ``b_t`` touches only track t's states) and
a small dense block ``C``. :func:`solve_arrow` eliminates the states with one banded Cholesky
for G + 2 right-hand sides (gradient, a column per global parameter, the offset columns of
all tracks packed in one because ``A`` is block diagonal over tracks) and solves the reduced
(G + T) system; the global parameters' marginal covariance is the inverse of their Schur complement
-- the same matrix ``gtsam.Marginals`` returns for the pose of the equivalent factor graph
(tests).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factors.registration_factors import N_POSE, point_rows_batch
from factors.state import N_STATE
from fgloc.smoothing.banded_lm import BandedLayout, damp_diagonal, solve_damped


@dataclass
class TrackQuadratic:
    """Quadratic model of the track factors about ``x_lin`` (N, 26): cost ``c`` at it,
    gradient ``g`` (N, 26), diagonal blocks ``D`` (N, 26, 26), blocks ``B`` (P, 26, 26) at
    (``below[p]``, ``below[p] - 1``)."""

    x_lin: np.ndarray
    c: float
    g: np.ndarray
    D: np.ndarray
    B: np.ndarray
    below: np.ndarray

    def apply(self, dx: np.ndarray) -> np.ndarray:
        """``H dx`` (N, 26) for dx (N, 26)."""
        out = (self.D @ dx[..., None])[..., 0]
        lo = self.below
        out[lo] += (self.B @ dx[lo - 1][..., None])[..., 0]
        out[lo - 1] += (np.swapaxes(self.B, 1, 2) @ dx[lo][..., None])[..., 0]
        return out

    def cost(self, x: np.ndarray) -> float:
        dx = x - self.x_lin
        return float(self.c + np.sum(self.g * dx) + 0.5 * np.sum(dx * self.apply(dx)))

    def gradient(self, x: np.ndarray) -> np.ndarray:
        return self.g + self.apply(x - self.x_lin)


@dataclass
class PointSet:
    """The matched contour points of a round, padded per frame: frame_step (F,) the global
    step of each frame's state, frame_track (F,) its track; theta / mean (F, K), H (F, K, n),
    target / normal (F, K, 2) in L, sqrt_info (F, K, 2, 2) (1/m), weights (F, K) (0 for
    padding and unmatched points); gp_mu (n,) the prior mean radii; side (F, K, nb) each
    point's coefficients of the nb side-bias parameters (the sign of the sensor's side of its
    line along the normal, times 1 or its range in hm), None = no side bias."""

    frame_step: np.ndarray
    frame_track: np.ndarray
    theta: np.ndarray
    H: np.ndarray
    mean: np.ndarray
    target: np.ndarray
    normal: np.ndarray
    sqrt_info: np.ndarray
    weights: np.ndarray
    gp_mu: np.ndarray
    side: np.ndarray | None = None

    @property
    def n_global(self) -> int:
        """Number of global parameters: the pose (3) and the side-bias parameters."""
        return N_POSE + (0 if self.side is None else self.side.shape[-1])

    def rows(self, x: np.ndarray, glob: np.ndarray, b: np.ndarray | None,
             jacobian: bool = False):
        """Weighted residual (F, K, 2) and, with ``jacobian``, its derivatives w.r.t. the
        global parameters (F, K, 2, G), the state (F, K, 2, 26) and the track's offset
        (F, K, 2) at states x (N, 26), global parameters ``glob`` (G,) and offsets b (T,)
        (None = without) (:func:`factors.registration_factors.point_rows_batch`)."""
        off = np.zeros((len(self.frame_step), 1)) if b is None else b[self.frame_track, None]
        if self.side is not None:
            off = off + self.side @ glob[N_POSE:]
        e, J = point_rows_batch(glob[:N_POSE], x[self.frame_step], off, self.theta, self.H,
                                self.mean, self.target, self.normal, self.sqrt_info,
                                self.weights, self.gp_mu, jacobian)
        if J is None or self.side is None:
            return e, J
        Jp, Jx, Jb = J
        return e, (np.concatenate([Jp, self.side[..., None, :] * Jb[..., None]], axis=-1),
                   Jx, Jb)


@dataclass
class Priors:
    """Prior of the global parameters: mean (G,) and sqrt information (G,) (diagonal,
    1/sigma); offset prior sqrt information (scalar, 1/m; 0 = no offsets)."""

    pose_mean: np.ndarray
    pose_w: np.ndarray
    offset_w: float


@dataclass
class ArrowSystem:
    """Normal equations of the joint problem (module docstring) at one estimate: track
    block D (N, 26, 26) / B (P, 26, 26), border to the G global parameters E (N, 26, G) and
    to the owning track's offset e (N, 26), the global block Hp (G, G), offset diagonal Hb
    (T,), offset-global block Hbp (T, G), gradients gx (N, 26), gp (G,), gb (T,), and each
    track's point rows' share of the global gradient gp_track (T, G) (without the prior)."""

    D: np.ndarray
    B: np.ndarray
    E: np.ndarray
    e: np.ndarray
    Hp: np.ndarray
    Hb: np.ndarray
    Hbp: np.ndarray
    gx: np.ndarray
    gp: np.ndarray
    gb: np.ndarray
    gp_track: np.ndarray


def joint_cost(tq: TrackQuadratic, pts: PointSet, pri: Priors, x: np.ndarray,
               glob: np.ndarray, b: np.ndarray | None) -> float:
    """The total cost (module docstring) at (x, global parameters, b)."""
    e, _ = pts.rows(x, glob, b)
    rp = pri.pose_w * (glob - pri.pose_mean)
    rb = 0.0 if b is None else pri.offset_w**2 * np.sum(b * b)
    return tq.cost(x) + 0.5 * (np.sum(e * e) + np.sum(rp * rp) + rb)


def linearize(tq: TrackQuadratic, pts: PointSet, pri: Priors, n_tracks: int,
              x: np.ndarray, glob: np.ndarray, b: np.ndarray | None) -> ArrowSystem:
    """The :class:`ArrowSystem` at (x, global parameters, b)."""
    e, (Jp, Jx, Jb) = pts.rows(x, glob, b, jacobian=True)
    F, K = e.shape[:2]
    e = e.reshape(F, 2 * K)
    G = pts.n_global
    Jp, Jx, Jb = Jp.reshape(F, 2 * K, G), Jx.reshape(F, 2 * K, N_STATE), Jb.reshape(F, -1)
    JxT = np.swapaxes(Jx, 1, 2)
    s, t = pts.frame_step, pts.frame_track
    D = tq.D.copy()
    D[s] += JxT @ Jx
    gx = tq.gradient(x)
    gx[s] += (JxT @ e[..., None])[..., 0]
    E = np.zeros((len(x), N_STATE, G))
    E[s] = JxT @ Jp
    eb = np.zeros((len(x), N_STATE))
    eb[s] = (JxT @ Jb[..., None])[..., 0]
    Hp = np.einsum("fki,fkj->ij", Jp, Jp) + np.diag(pri.pose_w**2)
    gp_frame = np.einsum("fki,fk->fi", Jp, e)
    gp_track = _track_sums(t, gp_frame, n_tracks)
    gp = gp_frame.sum(axis=0) + pri.pose_w**2 * (glob - pri.pose_mean)
    Hb = np.bincount(t, np.sum(Jb * Jb, axis=1), minlength=n_tracks) + pri.offset_w**2
    Hbp = _track_sums(t, np.einsum("fk,fki->fi", Jb, Jp), n_tracks)
    gb = np.bincount(t, np.sum(Jb * e, axis=1), minlength=n_tracks)
    if b is not None:
        gb = gb + pri.offset_w**2 * b
    return ArrowSystem(D, tq.B, E, eb, Hp, Hb, Hbp, gx, gp, gb, gp_track)


@dataclass
class ArrowSolution:
    """Step (dx (N, 26), dp (G,), db (T,)) and the global parameters' reduced information
    (G, G) (their Schur complement of everything else, of the damped system)."""

    dx: np.ndarray
    dp: np.ndarray
    db: np.ndarray
    pose_information: np.ndarray


def solve_arrow(sys: ArrowSystem, layout: BandedLayout, owner: np.ndarray, offsets: bool,
                lam: float = 0.0) -> ArrowSolution:
    """Solve ``(H + lambda (diag(H) + DAMPING_FLOOR)) step = -g`` (module docstring,
    :func:`fgloc.smoothing.banded_lm.damp_diagonal`); owner (N,) the
    track of each step; ``offsets`` False drops the offset variables. ``LinAlgError`` if the
    damped track block is not positive definite."""
    n, T, G = len(sys.D), len(sys.Hb), len(sys.gp)
    rhs = np.empty((sys.gx.size, G + 2), order="F")      # solved in place (solve_damped)
    rhs[:, 0], rhs[:, 1:G + 1], rhs[:, G + 1] = (sys.gx.reshape(-1), sys.E.reshape(-1, G),
                                                 sys.e.reshape(-1))
    Y = solve_damped(layout, sys.D, sys.B, lam, rhs)
    Ag, AE, Ae = Y[:, 0], Y[:, 1:G + 1], Y[:, G + 1]
    Ef, ef = sys.E.reshape(-1, G), sys.e.reshape(-1)
    row_track = np.repeat(owner, N_STATE)
    Sp = damp_diagonal(sys.Hp, lam) - Ef.T @ AE
    rp = -sys.gp + Ef.T @ Ag
    if offsets and T:
        Hb = damp_diagonal(sys.Hb[:, None, None], lam)[:, 0, 0]
        Sb = Hb - np.bincount(row_track, ef * Ae, minlength=T)
        Sbp = sys.Hbp - _track_sums(row_track, ef[:, None] * AE, T)
        rb = -sys.gb + np.bincount(row_track, ef * Ag, minlength=T)
        # eliminate the offsets (diagonal) from the reduced system
        S = Sp - Sbp.T @ (Sbp / Sb[:, None])
        dp = np.linalg.solve(S, rp - Sbp.T @ (rb / Sb))
        db = (rb - Sbp @ dp) / Sb
        dx = -Ag - AE @ dp - Ae * db[row_track]
    else:
        S = Sp
        dp = np.linalg.solve(S, rp)
        db = np.zeros(T)
        dx = -Ag - AE @ dp
    return ArrowSolution(dx.reshape(n, N_STATE), dp, db, 0.5 * (S + S.T))


def _track_sums(row_track: np.ndarray, values: np.ndarray, T: int) -> np.ndarray:
    """(T, k) sums of the rows of ``values`` (R, k) per track (``row_track`` (R,))."""
    out = np.zeros((T, values.shape[1]))
    np.add.at(out, row_track, values)
    return out
