"""Stage 2, coarse localization: the accumulated dynamic radar points (the coarse source)
registered to the target cloud's road and lane centres, the vertical fit (z, pitch, roll) and
the coarse modes, giving ``T_coarse`` (sensor frame S -> local frame L, SE(3)); paper III-A.

The implementation is :mod:`fgloc.coarse.localize`; its public names are re-exported here.
"""

from fgloc.coarse.localize import (
    CoarseMode,
    CoarseResult,
    LaneCentres,
    StaticGround,
    below_fov_floor,
    coarse_localize,
    dynamic_points,
    fit_vertical,
    icp_planar,
    target_and_coarse,
)

__all__ = [
    "CoarseMode",
    "CoarseResult",
    "LaneCentres",
    "StaticGround",
    "below_fov_floor",
    "coarse_localize",
    "dynamic_points",
    "fit_vertical",
    "icp_planar",
    "target_and_coarse",
]
