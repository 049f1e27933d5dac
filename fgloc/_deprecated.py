"""Deprecated module paths kept for one release after the stage layout of issue 23.

An alias module imports its new home and sets ``__getattr__ = moved(__name__, new)``: the
import of the old path warns once (:class:`DeprecationWarning`) and every name is read from
the new module.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from types import ModuleType
from typing import Any


def moved(old: str, new: ModuleType) -> Callable[[str], Any]:
    """Warn that module ``old`` moved to ``new`` and return a module ``__getattr__`` that
    forwards every attribute to ``new``."""
    warnings.warn(f"{old} is deprecated and will be removed in the next release; "
                  f"import {new.__name__} instead", DeprecationWarning, stacklevel=3)

    def __getattr__(name: str) -> Any:
        return getattr(new, name)

    return __getattr__
