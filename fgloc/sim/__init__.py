"""Scenario simulator: a synthetic roadside radar recording with ALS, Lanelet2 map and truth.

A test instrument for fgloc (no real recording needed): ``simulate(case, seed)`` returns a
:class:`fgloc.scenario.Scenario` in the local frame L with the ground truth filled in.
"""

from fgloc.sim.config import SimConfig
from fgloc.sim.core import CASES, SimResult, simulate, simulate_detailed

__all__ = ["CASES", "SimConfig", "SimResult", "simulate", "simulate_detailed"]
