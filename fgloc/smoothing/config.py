"""Configuration of the GTSAM smoothers (``[smoothing]`` in the fgloc config TOML).

The motion, contour and noise models are the tracker's (``[tracking]``: process noise, GP
kernel, contour scatter, radar noise), so filter and smoother estimate the same model; this
section only holds what is specific to the smoothers.
"""

from __future__ import annotations

from dataclasses import dataclass

#: smoother names of ``fgloc track --smoother`` (``none`` = the filter's tracks)
SMOOTHERS: tuple[str, ...] = ("none", "fixed-lag", "batch")


@dataclass
class SmoothingConfig:
    """GP-EOT smoothers in GTSAM (batch Levenberg-Marquardt, incremental fixed-lag)."""

    smoother: str = "batch"
    """Smoother of ``--method smoother-sicp``: "batch" (offline, whole tracks) or
    "fixed-lag" (online)."""
    lag: float = 2.0
    """Fixed-lag smoother: states older than this (s) are marginalized."""
    max_detections: int = 32
    """At most this many detections (a regular subsample) of one track in one frame enter its
    measurement factor (all of them when 0)."""
    huber_k: float = 2.0
    """Huber threshold (in row std. devs.) of the per-row IRLS weights of a measurement
    factor (0 disables the robust weights)."""
    radar_noise: bool = True
    """Per-row measurement noise as in the tracker: range / azimuth noise along the row's
    normal and the GP interpolation variance on top of ``tracking.sigma_contour``."""
    max_iterations: int = 30
    """Batch: Levenberg-Marquardt iteration limit per track."""
    relative_tolerance: float = 1e-4
    """Batch: stop when the relative decrease of the error is below this."""
    marginals: bool = False
    """Batch: compute each state's marginal covariance (gtsam.Marginals) into the output
    tracks; otherwise the smoothed tracks carry no covariances."""
    relinearize_threshold: float = 0.1
    """Fixed-lag (ISAM2): relinearize a variable whose update exceeds this."""
    relinearize_skip: int = 10
    """Fixed-lag (ISAM2): check for relinearization every this many updates."""

    def __post_init__(self) -> None:
        if self.smoother not in SMOOTHERS[1:]:
            raise ValueError(f"smoother must be one of {', '.join(SMOOTHERS[1:])}, "
                             f"got {self.smoother!r}")
        if not self.lag > 0:
            raise ValueError(f"lag must be > 0 s, got {self.lag}")
        if self.max_detections < 0 or self.max_iterations < 1 or self.relinearize_skip < 1:
            raise ValueError("max_detections >= 0, max_iterations >= 1 and "
                             "relinearize_skip >= 1 are required")
