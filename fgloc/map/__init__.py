"""Stage 1, the map: the lanelets' driving-behaviour labels and the labelled target cloud (road
points of the ALS inside the lanelets near the sensor, in the local frame L), paper IV-A.

Modules: :mod:`~fgloc.map.lanelet_labels` (the lanelets' labels), :mod:`~fgloc.map.target_cloud`
(the target cloud); their public names are re-exported here.
"""

from fgloc.map.lanelet_labels import (
    LaneletLabels,
    label_lanelet,
    labels_from_curvature,
    lanelet_curvatures,
    map_labels,
    menger_curvature,
)
from fgloc.map.target_cloud import (
    TargetCloud,
    approx_position_local,
    build_target_cloud,
    check_inside_als,
    crop_to_lanelets,
    points_in_polygon,
    select_road_points,
    voxel_centroids,
)

__all__ = [
    "LaneletLabels",
    "TargetCloud",
    "approx_position_local",
    "build_target_cloud",
    "check_inside_als",
    "crop_to_lanelets",
    "label_lanelet",
    "labels_from_curvature",
    "lanelet_curvatures",
    "map_labels",
    "menger_curvature",
    "points_in_polygon",
    "select_road_points",
    "voxel_centroids",
]
