"""Stage 2, coarse localization: the accumulated dynamic radar points (the coarse source)
registered to the target cloud's road and lane centres, the vertical fit (z, pitch, roll) and
the coarse modes, giving ``T_coarse`` (sensor frame S -> local frame L, SE(3)); paper III-A.

Modules: :mod:`~fgloc.coarse.points` (the source), :mod:`~fgloc.coarse.icp` (planar targets,
ICP, search), :mod:`~fgloc.coarse.vertical` (vertical fit), :mod:`~fgloc.coarse.localize` (the
stage and its modes); their public names are re-exported here.
"""

from fgloc.coarse.icp import LaneCentres, icp_planar
from fgloc.coarse.localize import CoarseMode, CoarseResult, coarse_localize, target_and_coarse
from fgloc.coarse.points import dynamic_points
from fgloc.coarse.vertical import StaticGround, VerticalFit, below_fov_floor, fit_vertical

__all__ = [
    "CoarseMode",
    "CoarseResult",
    "LaneCentres",
    "StaticGround",
    "VerticalFit",
    "below_fov_floor",
    "coarse_localize",
    "dynamic_points",
    "fit_vertical",
    "icp_planar",
    "target_and_coarse",
]
