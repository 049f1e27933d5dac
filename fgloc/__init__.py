"""fgloc: self-localization of roadside 4D radar sensors from the traffic they track.

The library entry points: ``fgloc.load_scenario(path)`` reads a scenario directory,
``fgloc.localize(scenario, method="icp", config=None)`` localizes its sensor,
``fgloc.localize_many(scenario, methods, config=None)`` localizes it with several methods
sharing their common stages, and ``fgloc.track(scenario, config=None, oracle_pose=False)``
tracks its vehicles. They are
imported on first use, so ``import fgloc.geo`` stays cheap.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

__version__ = "0.1.0"
_LAZY = {
    "load_scenario": "fgloc.io",
    "localize": "fgloc.pipeline",
    "localize_many": "fgloc.pipeline",
    "track": "fgloc.pipeline",
    "METHODS": "fgloc.pipeline",
}
__all__ = sorted(_LAZY)


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'fgloc' has no attribute {name!r}")
