"""Scenarios written the way another tool following DESIGN.md's contract might write them.

A simulated scenario is re-written with other valid choices: LAS 1.2 point format 1 tiles
without a CRS record (the CRS then comes from sensor.toml), a Lanelet2 map written by lanelet2
itself, radar.csv without the optional columns, with CRLF line ends and UNIX epoch times (the
contract only asks for seconds, non-decreasing), a sensor.toml with only the required keys,
ground truth at 10 Hz on the same clock. It must load and localize like the original.
"""

from __future__ import annotations

import json
from pathlib import Path

import laspy
import numpy as np
import pytest
from lanelet2.core import GPSPoint, LineString3d, Point3d, getId
from lanelet2.core import Lanelet as L2Lanelet
from lanelet2.core import LaneletMap as L2Map
from lanelet2.io import Origin
from lanelet2.io import write as l2_write
from lanelet2.projection import UtmProjector

from fgloc.evaluation.pose import pose_error
from fgloc.geo import pose_from_se3, transformer
from fgloc.io import load_scenario
from fgloc.pipeline import localize
from fgloc.sim import simulate

#: the clock the variant's times count from: 2025-12-01 00:00 UTC in UNIX seconds
EPOCH = 1764547200.0


def _write_las12_without_crs(path: Path, xyz_world: np.ndarray, cls: np.ndarray) -> None:
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.offsets = np.floor(xyz_world.min(axis=0))
    header.scales = np.array([0.01, 0.01, 0.01])
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz_world[:, 0], xyz_world[:, 1], xyz_world[:, 2]
    las.classification = cls
    las.write(str(path))


def _write_map_with_lanelet2(path: Path, scn) -> None:
    to_wgs = transformer(scn.crs, "EPSG:4326")
    lon0, lat0 = to_wgs.transform(*scn.frame.origin[:2])
    proj = UtmProjector(Origin(lat0, lon0))
    lmap = L2Map()

    def line(pts_local: np.ndarray) -> LineString3d:
        w = scn.frame.to_world(pts_local)
        lon, lat = to_wgs.transform(w[:, 0], w[:, 1])
        pts = []
        for a, b, z in zip(lat, lon, w[:, 2]):
            p = proj.forward(GPSPoint(float(a), float(b), float(z)))
            pts.append(Point3d(getId(), p.x, p.y, p.z))
        return LineString3d(getId(), pts, {"type": "line_thin", "subtype": "solid"})

    for ll in scn.lanelets.lanelets:
        lmap.add(L2Lanelet(getId(), line(ll.left), line(ll.right), {"subtype": "road"}))
    l2_write(str(path), lmap, proj)


@pytest.fixture(scope="module")
def variant_dir(tmp_path_factory) -> tuple[Path, object]:
    scn = simulate("tjunction", 3, duration=30.0)
    d = tmp_path_factory.mktemp("variant")
    (d / "als").mkdir()
    world = scn.frame.to_world(scn.als.xyz.astype(np.float64))
    half = len(world) // 2  # two tiles, split arbitrarily
    _write_las12_without_crs(d / "als" / "a.LAS", world[:half], scn.als.classification[:half])
    _write_las12_without_crs(d / "als" / "b.las", world[half:], scn.als.classification[half:])
    _write_map_with_lanelet2(d / "map.osm", scn)
    r = scn.radar
    body = np.column_stack([r.t + EPOCH, r.xyz, r.doppler])
    lines = ["t,x,y,z,doppler"] + [",".join(f"{v:.5f}" for v in row) for row in body]
    (d / "radar.csv").write_bytes(("\r\n".join(lines) + "\r\n").encode())
    E, N = scn.sensor.approx_position
    (d / "sensor.toml").write_text(f'crs = "EPSG:25832"\n[sensor]\napprox_position = [{E}, {N}]\n')
    x, y, z = scn.frame.to_world(scn.truth.sensor_pose[:3, 3])
    _, _, _, yaw, pitch, roll = pose_from_se3(scn.truth.sensor_pose)
    tracks = []
    for tr in scn.truth.tracks:
        st = tr.states[::2].copy()  # 10 Hz
        st[:, 0] += EPOCH
        st[:, 1:3] = scn.frame.to_world(st[:, 1:3])
        tracks.append({"id": tr.id, "length": tr.length, "width": tr.width, "states": st.tolist()})
    gt = {
        "crs": "EPSG:25832",
        "sensor": {
            "x": x,
            "y": y,
            "z": z,
            "yaw_deg": np.rad2deg(yaw),
            "pitch_deg": np.rad2deg(pitch),
            "roll_deg": np.rad2deg(roll),
        },
        "tracks": tracks,
    }
    (d / "ground_truth.json").write_text(json.dumps(gt))
    return d, scn


def test_variant_loads_like_the_original(variant_dir):
    d, scn = variant_dir
    got = load_scenario(d)
    assert got.crs == "EPSG:25832"
    assert len(got.radar) == len(scn.radar) and got.radar.rcs is None
    assert np.allclose(got.radar.t - EPOCH, scn.radar.t, atol=1e-5)
    assert len(got.als) == len(scn.als)
    assert len(got.lanelets) == len(scn.lanelets)
    # same geometry in the world frame to within the LAS scale (1 cm) and map precision
    w_got = got.frame.to_world(got.lanelets.lanelets[0].left[:, :2])
    w_ref = scn.frame.to_world(scn.lanelets.lanelets[0].left[:, :2])
    assert np.abs(w_got - w_ref).max() < 0.01
    assert got.sensor.yaw_guess_deg is None and got.sensor.approx_height is None


@pytest.mark.parametrize(
    "method, max_2d, max_yaw", [("icp", 1.5, 1.5), ("filter-sicp", 0.7, 0.4)], ids=str
)
def test_variant_localizes_within_bounds(variant_dir, method, max_2d, max_yaw):
    d, _ = variant_dir
    got = load_scenario(d)
    res = localize(got, method=method)
    err = pose_error(res.T_local, got.truth.sensor_pose)
    assert err.d2d < max_2d and err.dyaw_deg < max_yaw, err
