"""Configuration of the fine registration (``[sicp]`` in the fgloc config TOML)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class SicpConfig:
    """Semantic ICP in SE(2) (paper III-C, IV-B)."""

    max_correspondence: float = 50.0
    """Initial maximum correspondence distance (m)."""
