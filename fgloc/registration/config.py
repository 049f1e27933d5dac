"""Configuration of the fine registration (``[sicp]`` in the fgloc config TOML)."""

from __future__ import annotations

from dataclasses import dataclass, field

#: Correspondence modes of :func:`fgloc.registration.sicp.sicp`.
MODES: tuple[str, ...] = ("hard", "soft", "none")
#: Robust kernels of the iteratively reweighted alignment.
KERNELS: tuple[str, ...] = ("none", "huber", "cauchy")


def _default_compatibility() -> list[list[float]]:
    return [[1.0, 0.1, 0.1], [0.1, 1.0, 0.1], [0.1, 0.1, 1.0]]


@dataclass
class SicpConfig:
    """Semantic ICP in SE(2) (paper III-C, IV-B). Distances in metres."""

    mode: str = "hard"
    """Correspondences: "hard" = each source point matched only to target points of its own
    label; "soft" = matched in all labels by the cost d^2 / compatibility[source][target] and
    weighted by that compatibility; "none" = plain ICP (labels ignored)."""
    compatibility: list[list[float]] = field(default_factory=_default_compatibility)
    """3x3 label compatibility of the "soft" mode, rows = source label, columns = target label
    in the order straight, left, right; values in [0, 1], 0 forbids the pair."""
    max_correspondence: float = 50.0
    """Maximum correspondence distance (m) of the first iteration (paper: 50 m)."""
    min_correspondence: float = 1.5
    """Floor (m) of the shrinking maximum correspondence distance; the final range, which also
    defines fitness and inlier RMSE."""
    range_decay: float = 0.8
    """The maximum correspondence distance is multiplied by this after every iteration until it
    reaches min_correspondence (1.0 keeps max_correspondence throughout)."""
    max_iterations: int = 100
    """Iteration limit (paper: 100); stopping on it is reported as not converged."""
    rmse_tol: float = 1e-4
    """Converged when, at the range floor, the inlier RMSE changes by less than this (m)
    between two iterations (paper: 1e-4)."""
    kernel: str = "none"
    """Robust kernel of the iteratively reweighted alignment: "none", "huber" or "cauchy"."""
    kernel_scale: float = 1.0
    """Scale (m) of the robust kernel: Huber weight min(1, c/d), Cauchy 1 / (1 + (d/c)^2)."""
    min_points_per_label: int = 10
    """A label with source points but fewer than this many source or target points is dropped
    with a warning (its points take no part)."""
    sigma_floor: float = 0.05
    """Lower bound (m) of the residual standard deviation used for the information matrix."""
    info_window: float = 8.0
    """Half-width (m) of the square target neighbourhood whose spread shapes each
    correspondence's weight matrix in the information (so sliding along a road shows as weak);
    0 = isotropic (plain point-to-point information)."""
