"""Readers and writers for every file of a scenario directory (docs/formats.md).

Everything read is converted to the local frame L of :class:`fgloc.geo.LocalFrame` (radar
stays in the sensor frame); writers convert back to world coordinates and write atomically.
"""

from fgloc.io.als import find_als_tiles, read_als, write_als
from fgloc.io.ground_truth import read_ground_truth, write_ground_truth
from fgloc.io.lanelet_map import read_lanelet_map, write_lanelet_map
from fgloc.io.radar import read_radar, write_radar
from fgloc.io.scenario_dir import find_radar_file, load_scenario, write_scenario
from fgloc.io.sensor_file import read_sensor_toml, write_sensor_toml
from fgloc.io.tracks_csv import read_tracks_csv, write_tracks_csv

__all__ = [
    "find_als_tiles",
    "find_radar_file",
    "load_scenario",
    "read_als",
    "read_ground_truth",
    "read_lanelet_map",
    "read_radar",
    "read_sensor_toml",
    "read_tracks_csv",
    "write_als",
    "write_ground_truth",
    "write_lanelet_map",
    "write_radar",
    "write_scenario",
    "write_sensor_toml",
    "write_tracks_csv",
]
