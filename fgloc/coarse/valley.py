"""A flat valley of the pose: tied modes that are samples of a continuum along one direction.

Where every vehicle drives one straight road (nothing turns off it), shifting the sensor along
that road moves every detection along its lane and no fit can tell the shifts apart: the
modes the coarse stage keeps there (equal lane scores, 1-9 m apart along the road) are samples
of a continuum, and where its samples stop says nothing (at most ``max_modes`` of them within
``mode_search_radius``). A :class:`Valley` is that continuum: the line through the tied modes
and the extent along it over which the comparison that tied them ties every pose (scanned at
steps of half the mode separation, out to ``mode_z`` prior standard deviations from the
approximate position; the scan's ends beyond that are the prior's, not the data's).

Along the valley the data are indifferent and the user's approximate position
(``approx_position_sigma``) is all that says where the sensor is: the posterior along it is the
prior ``N(s_a, sigma^2)`` (``s_a`` the approximate position's projection) truncated to the
valley; its mean is the reported position, its variance the reported covariance along the
valley (across the valley and in yaw the modes' own spread stays).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from fgloc.config import CoarseConfig
from fgloc.geo import wrap_angle


@dataclass(frozen=True)
class Valley:
    """A line of tied poses in L.

    origin: (2,) m, the sensor position of the fit the line passes through (s = 0); yaw (rad)
    that fit's yaw, which every pose on the line keeps. direction: (2,) unit vector along the
    line. s: (n,) m along ``direction`` from ``origin``, the scanned tied poses (steps of half
    the mode separation), ascending. open_lo, open_hi: whether
    the scan stopped at that end on its limit (the prior's range) rather than on a pose the
    data rule out. prior_s: the approximate position's projection (m along the line), sigma:
    its std. dev. (m).
    """

    origin: np.ndarray
    yaw: float
    direction: np.ndarray
    s: np.ndarray
    open_lo: bool
    open_hi: bool
    prior_s: float
    sigma: float

    @property
    def lo(self) -> float:
        return float(self.s[0])

    @property
    def hi(self) -> float:
        return float(self.s[-1])

    def point(self, s: float) -> np.ndarray:
        """(2,) m in L of the position ``s`` m along the line."""
        return self.origin + s * self.direction

    def posterior(self) -> tuple[float, float]:
        """Mean (m along the line) and variance (m^2) of the position along the valley: the
        prior truncated to it, i.e. the scanned poses (each standing for its step) weighted by
        ``exp(-(s - prior_s)^2 / (2 sigma^2))``. Inside the valley the per-track statistic is
        no measure of evidence: it is scale-free, so the tiny cost differences of a flat
        direction give it any value up to ``sqrt(n)``."""
        q = ((self.s - self.prior_s) / self.sigma) ** 2
        w = np.exp(-0.5 * (q - q.min()))
        mean = float(np.sum(w * self.s) / w.sum())
        step = float(np.min(np.diff(self.s))) if len(self.s) > 1 else 0.0
        return mean, float(np.sum(w * (self.s - mean) ** 2) / w.sum()) + step**2 / 12.0

    def distance(self, xy: np.ndarray) -> float:
        """Distance (m) of the point ``xy`` (2,) in L from the segment [lo, hi]."""
        s = float(np.clip((np.asarray(xy) - self.origin) @ self.direction, self.lo, self.hi))
        return float(np.hypot(*(np.asarray(xy) - self.point(s))))


def collinear(poses: np.ndarray, cfg: CoarseConfig) -> np.ndarray | None:
    """The unit direction (2,) of the line the planar poses (k, 3) (x, y m, yaw rad) lie on,
    or None: at least two poses, their yaws within ``cfg.mode_separation_deg`` of the first's
    and their positions within half ``cfg.mode_separation`` of their principal axis (the same
    pose but for a shift along it)."""
    if len(poses) < 2:
        return None
    if np.max(np.abs(wrap_angle(poses[:, 2] - poses[0, 2]))) >= np.deg2rad(
            cfg.mode_separation_deg):
        return None
    d = poses[:, :2] - poses[:, :2].mean(axis=0)
    u = np.linalg.svd(d, full_matrices=False)[2][0]
    across = d @ np.array([-u[1], u[0]])
    return u if np.max(np.abs(across)) <= 0.5 * cfg.mode_separation else None


def flat_extent(s_modes: np.ndarray, prior_s: float, sigma: float, cfg: CoarseConfig,
                z_at: Callable[[float], float]) -> tuple[np.ndarray, bool, bool] | None:
    """The tied poses along a line: (s, open_lo, open_hi) (see :class:`Valley`), or None
    when a pose between the modes at ``s_modes`` (m along the line) is not tied (they are
    distinct modes, not samples of one continuum). ``z_at(s)``: the standard errors by which
    the best beats the pose ``s`` m along the line (tied below ``cfg.mode_z``). Steps of half
    ``cfg.mode_separation`` from the innermost to the outermost mode, and on outwards while
    tied, to ``cfg.mode_z`` prior std. devs. (``sigma``) from ``prior_s`` or the outermost mode,
    whichever is farther."""
    step = 0.5 * cfg.mode_separation
    lo, hi = float(np.min(s_modes)), float(np.max(s_modes))
    n = max(1, int(np.ceil((hi - lo) / step)))
    s = list(np.linspace(lo, hi, n + 1))
    if any(z_at(x) >= cfg.mode_z for x in s):
        return None
    reach = cfg.mode_z * sigma
    opened = []
    for sign, limit in ((1.0, max(hi, prior_s + reach)), (-1.0, min(lo, prior_s - reach))):
        end = hi if sign > 0 else lo
        while sign * (limit - end) >= step and z_at(end + sign * step) < cfg.mode_z:
            end += sign * step
            s.append(end)
        opened.append(sign * (limit - end) < step)
    return np.sort(s), opened[1], opened[0]


def find_valley(poses: np.ndarray, origin: int, prior_xy: np.ndarray, sigma: float,
                cfg: CoarseConfig, z_at: Callable[[np.ndarray], float]) -> Valley | None:
    """The valley through the tied planar poses (k, 3) (x, y m, yaw rad in L), or None when
    they are not samples of one continuum (:func:`collinear`, :func:`flat_extent`). The line
    passes through ``poses[origin]`` with its yaw; ``z_at(xy)``: the standard errors by which
    the best beats that pose moved to the position ``xy`` (2,) (tied below ``cfg.mode_z``);
    prior_xy (2,) m, sigma (m): the approximate position and its std. dev."""
    u = collinear(poses, cfg)
    if u is None:
        return None
    o = poses[origin, :2]
    s_modes = (poses[:, :2] - o) @ u
    prior_s = float((prior_xy - o) @ u)
    ext = flat_extent(s_modes, prior_s, sigma, cfg, lambda s: z_at(o + s * u))
    return None if ext is None else Valley(o, float(poses[origin, 2]), u, *ext, prior_s, sigma)
