"""Configuration of the GP-EOT tracker (``[tracking]`` in the fgloc config TOML)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class TrackingConfig:
    """GP-EOT tracker settings (paper III-B, IV-B)."""

    eta: float = 0.01
    """Curvature threshold (rad/m) for the left/right/straight state labels."""
