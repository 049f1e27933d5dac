"""Gaussian-process star-convex contour: periodic kernel, prior mean, conditional, decay.

The contour is the radial function ``f(theta)`` (m) from the object centre, ``theta`` in the
object frame (rad, x along the heading). The state holds ``f`` at ``n`` basis angles.

Kernel convention (paper eq. for k(u, u'))::

    k0(u, u') = sf^2 exp(-2 sin^2((u - u') / 2) / l^2)
    k(u, u')  = (1 - s) k0(u, u') + s k_sym(u, u') + sr^2

* ``l`` (rad) is the length scale exactly as written: ``sin^2`` is divided by ``l^2`` once.
* ``sr^2`` is **inside** k (and hence inside K, the conditional and the decay noise): it is the
  prior variance of a common radius offset (the overall size), a rank-one part of K.
* ``sl^2 gL(u) gL(u') + sw^2 gW(u) gW(u')`` (optional, "size modes"): ``gL, gW`` are the
  derivatives of the mean rectangle's radial function w.r.t. its length and width, so the prior
  lets the whole front/back (sides) move out together by a length (width) change of std. dev.
  ``sl`` (``sw``) m -- a truck is a long car, not a big circle. The full kernel is
  ``k + sl^2 gL gL' + sw^2 gW gW'`` (a sum of PSD kernels).
* ``k_sym(u, u') = sf^2 / 4 sum_g exp(-2 sin^2((u - g u') / 2) / l^2)`` over the mirror group
  ``g in {u, -u, pi - u, pi + u}`` (a vehicle is symmetric about its long and short axes): it
  is the covariance of the group-averaged process, hence positive semi-definite, and lets a
  measured side inform the unseen opposite side. ``s = 0`` (``symmetry``) is the paper's kernel.

The GP prior mean ``mu(theta)`` is a rectangle's radial function (a typical car) instead of the
paper's zero: a zero-mean radius is unphysical and the decay would shrink unseen sides to a point.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def periodic_kernel(u: np.ndarray, u2: np.ndarray, sf: float, length: float, sr: float,
                    symmetry: float = 0.0) -> np.ndarray:
    """Kernel ``k(u, u2)`` (see module doc for the convention), elementwise with numpy
    broadcasting: pass ``u[:, None], u2[None, :]`` for a matrix."""
    u = np.asarray(u, dtype=float)
    u2 = np.asarray(u2, dtype=float)

    def k0(d: np.ndarray) -> np.ndarray:
        return np.exp(-2.0 * np.sin(d / 2.0) ** 2 / length**2)

    k = (1.0 - symmetry) * k0(u - u2)
    if symmetry:
        k = k + symmetry * 0.25 * (k0(u - u2) + k0(u + u2) + k0(u - np.pi + u2)
                                   + k0(u - np.pi - u2))
    return sf**2 * k + sr**2


def rectangle_radius_gradient(theta: np.ndarray, length: float,
                              width: float) -> tuple[np.ndarray, np.ndarray]:
    """Derivatives of :func:`rectangle_radius` w.r.t. length and width (dimensionless)."""
    c = np.abs(np.cos(theta))
    s = np.abs(np.sin(theta))
    front = c * width >= s * length                     # the ray leaves through the front/back
    dl = np.where(front, 0.5 / np.maximum(c, 1e-12), 0.0)
    dw = np.where(front, 0.0, 0.5 / np.maximum(s, 1e-12))
    return dl, dw


def rectangle_radius(theta: np.ndarray, length: float, width: float) -> np.ndarray:
    """Radial function (m) of a ``length`` x ``width`` rectangle centred at the origin, x along
    the length, at angles ``theta`` (rad)."""
    c = np.abs(np.cos(theta))
    s = np.abs(np.sin(theta))
    with np.errstate(divide="ignore"):
        return np.minimum(np.where(c > 0, 0.5 * length / np.maximum(c, 1e-300), np.inf),
                          np.where(s > 0, 0.5 * width / np.maximum(s, 1e-300), np.inf))


def decay_mean(f: np.ndarray, mean: np.ndarray, tau: float, dt: float | np.ndarray
               ) -> np.ndarray:
    """Mean of the contour process (:meth:`ContourGP.decay`): ``mean + exp(-tau dt) (f -
    mean)`` for radii ``f`` (..., n), decay target ``mean`` (n,) or (..., n) m, ``dt`` (...)
    s, ``tau`` 1/s."""
    e = np.exp(-tau * np.asarray(dt, dtype=float))[..., None]
    mean = np.asarray(mean, dtype=float)
    return mean + e * (np.asarray(f) - mean)


@dataclass(frozen=True)
class ContourGP:
    """The GP contour model at fixed basis angles.

    angles: (n,) basis angles (rad). sf, length, sr, symmetry, sl, sw: kernel (module doc).
    mean_length, mean_width: rectangle (m) of the prior mean radial function.
    """

    angles: np.ndarray
    sf: float = 0.5
    length: float = 0.8
    sr: float = 1.0
    symmetry: float = 0.8
    mean_length: float = 4.6
    mean_width: float = 1.9
    sl: float = 0.0
    sw: float = 0.0
    K: np.ndarray = field(init=False, repr=False)
    K_inv: np.ndarray = field(init=False, repr=False)
    mu: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        K = self.kernel(self.angles, self.angles)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "K_inv", np.linalg.inv(K))
        object.__setattr__(self, "mu", self.mean(self.angles))

    @property
    def n(self) -> int:
        return int(self.angles.shape[0])

    def kernel(self, u: np.ndarray, u2: np.ndarray) -> np.ndarray:
        """``(len(u), len(u2))`` kernel matrix (with the size modes)."""
        u, u2 = np.asarray(u, dtype=float), np.asarray(u2, dtype=float)
        k = periodic_kernel(u[:, None], u2[None, :], self.sf, self.length, self.sr,
                            self.symmetry)
        (l1, w1), (l2, w2) = (rectangle_radius_gradient(a, self.mean_length, self.mean_width)
                              for a in (u, u2))
        return k + self.sl**2 * np.outer(l1, l2) + self.sw**2 * np.outer(w1, w2)

    def mean(self, theta: np.ndarray) -> np.ndarray:
        """Prior mean radius (m) at angles theta (rad)."""
        return rectangle_radius(np.asarray(theta, dtype=float), self.mean_length, self.mean_width)

    def conditional(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``H (m, n)`` and ``R_f (m,)`` of ``f(theta*) | f ~ N(mu* + H (f - mu), R_f)``:
        ``H = k(theta*, angles) K^-1``, ``R_f = k(theta*, theta*) - H k(angles, theta*)``
        (paper eq. f* | f, with the prior mean added)."""
        theta = np.asarray(theta, dtype=float).ravel()
        ks = self.kernel(theta, self.angles)
        H = ks @ self.K_inv
        gl, gw = rectangle_radius_gradient(theta, self.mean_length, self.mean_width)
        kss = (periodic_kernel(theta, theta, self.sf, self.length, self.sr, self.symmetry)
               + self.sl**2 * gl**2 + self.sw**2 * gw**2)
        var = kss - np.sum(H * ks, axis=1)
        return H, np.maximum(var, 0.0)

    def radius(self, f: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """Conditional-mean radius (m) at angles ``theta (m,)`` for basis radii ``f (..., n)``:
        shape ``(..., m)``."""
        H, _ = self.conditional(theta)
        return self.mean(np.ravel(theta)) + (np.asarray(f) - self.mu) @ H.T

    def decay(self, f: np.ndarray, tau: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Contour process over ``dt`` s with forgetting rate ``tau`` (1/s): the deviation from
        the prior mean decays, ``f' = mu + exp(-tau dt) (f - mu)``, with noise
        ``Q = (1 - exp(-2 tau dt)) K``, so N(mu, K) is stationary (paper's model, centred on
        mu instead of 0). ``f`` (..., n) and ``dt`` (...) may carry a batch shape. Returns
        ``(f' (..., n), Q (..., n, n))``."""
        e = np.exp(-tau * np.asarray(dt, dtype=float))[..., None]
        return decay_mean(f, self.mu, tau, dt), (1.0 - e * e)[..., None] * self.K
