"""Readers and writers of fgloc.io: round trips and the errors users get for bad input."""

from __future__ import annotations

import json
import logging
import math
import shutil
import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path

import lanelet2
import laspy
import numpy as np
import pytest
from lanelet2.io import Origin
from lanelet2.projection import UtmProjector
from pyproj import CRS, Transformer
from scipy.spatial import cKDTree

from fgloc.errors import InputError
from fgloc.geo import LocalFrame, pose_from_se3, se3_from_pose
from fgloc.io import (
    load_scenario,
    read_als,
    read_ground_truth,
    read_lanelet_map,
    read_radar,
    read_sensor_toml,
    write_als,
    write_ground_truth,
    write_lanelet_map,
    write_radar,
    write_scenario,
    write_sensor_toml,
)
from fgloc.scenario import (
    AlsCloud,
    GroundTruth,
    Lanelet,
    LaneletMap,
    RadarData,
    Scenario,
    SensorConfig,
    TrackTruth,
)

E0, N0, Z0 = 677000.0, 5400000.0, 372.0
CRS_ = "EPSG:25832"
FRAME = LocalFrame((E0, N0, Z0), CRS_)
WGS84_TO_UTM = Transformer.from_crs("EPSG:4326", CRS_, always_xy=True)


# --------------------------------------------------------------------------------------------
# builders
# --------------------------------------------------------------------------------------------
def make_radar(n: int = 300, optional: bool = True, seed: int = 0) -> RadarData:
    rng = np.random.default_rng(seed)
    t = np.repeat(np.arange(n // 10) * 0.05, 10)[:n] + 1.7e9
    return RadarData(
        t=t,
        xyz=rng.normal(0.0, 40.0, (n, 3)),
        doppler=rng.normal(0.0, 5.0, n),
        rcs=rng.normal(5.0, 3.0, n) if optional else None,
        frame=np.repeat(np.arange(n // 10), 10)[:n].astype(np.int64) if optional else None,
    )


def make_als(n: int = 4000, seed: int = 1) -> AlsCloud:
    """Points over 600 m x 600 m around the origin (4 world tiles of 1 km); road/ground points
    at Z0 + 0.3 m, buildings 20 m higher (so Z0 must come from classes 2/11 only)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-300.0, 300.0, (n, 2))
    cls = rng.choice(np.array([2, 6, 11], dtype=np.uint8), n, p=[0.3, 0.4, 0.3])
    z = 0.3 + rng.normal(0.0, 0.05, n) + np.where(cls == 6, 20.0, 0.0)
    return AlsCloud(xyz=np.column_stack([xy, z]).astype(np.float32), classification=cls)


def make_map() -> LaneletMap:
    s = np.linspace(-80.0, 80.0, 9)
    z = np.full_like(s, 0.25)
    a = np.linspace(0.0, np.pi / 2, 7)
    return LaneletMap(
        [
            Lanelet(1, np.column_stack([s, np.full_like(s, 3.5), z]),
                    np.column_stack([s, np.zeros_like(s), z]), {"subtype": "road"}),
            Lanelet(2, np.column_stack([s[::-1], np.full_like(s, 3.6), z]),
                    np.column_stack([s[::-1], np.full_like(s, 7.0), z]),
                    {"subtype": "road", "speed_limit": "50"}),
            Lanelet(3, np.column_stack([80 + 10 * np.sin(a), 10 - 10 * np.cos(a), 0 * a]),
                    np.column_stack([80 + 13.5 * np.sin(a), 13.5 - 13.5 * np.cos(a) - 3.5, 0 * a]),
                    {"subtype": "road", "turn_direction": "left"}),
        ]
    )


def make_truth() -> GroundTruth:
    states = np.column_stack([np.arange(5) * 0.1, np.linspace(-20, 20, 5), np.full(5, 1.75),
                              np.zeros(5), np.full(5, 10.0), np.zeros(5)])
    return GroundTruth(
        crs=CRS_,
        sensor_pose=se3_from_pose(1.5, -12.0, 6.2, 0.7, math.radians(3.0), math.radians(0.5)),
        tracks=[TrackTruth(7, 4.5, 1.8, states),
                TrackTruth(8, 12.0, 2.5, states[:1] + [0.0, 0.0, 3.0, 1.0, 8.0, 0.0])],
    )


def make_sensor(crs: str | None = CRS_) -> SensorConfig:
    return SensorConfig(approx_position=(E0 + 0.4, N0 - 0.3), crs=crs, approx_height=6.0,
                        yaw_guess_deg=40.0)


def make_scenario() -> Scenario:
    return Scenario(frame=FRAME, sensor=make_sensor(), radar=make_radar(), als=make_als(),
                    lanelets=make_map(), truth=make_truth())


@pytest.fixture(scope="module")
def scenario_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("scn") / "scenario"
    write_scenario(make_scenario(), d)
    return d


@pytest.fixture
def scn_copy(scenario_dir: Path, tmp_path: Path) -> Path:
    d = tmp_path / "scn"
    shutil.copytree(scenario_dir, d)
    return d


# --------------------------------------------------------------------------------------------
# radar
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("optional", [True, False], ids=["with-rcs-frame", "required-only"])
@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_radar_round_trip(tmp_path: Path, suffix: str, optional: bool) -> None:
    r = make_radar(optional=optional)
    write_radar(tmp_path / f"radar{suffix}", r)
    q = read_radar(tmp_path / f"radar{suffix}")
    exact = suffix == ".npz"
    tol, t_tol = (0.0, 0.0) if exact else (5e-5, 1e-6)  # CSV: 1e-4 m and 1e-6 s digits
    assert len(q) == len(r)
    np.testing.assert_allclose(q.t, r.t, rtol=0, atol=t_tol)
    np.testing.assert_allclose(q.xyz, r.xyz, rtol=0, atol=tol)
    np.testing.assert_allclose(q.doppler, r.doppler, rtol=0, atol=tol)
    if optional:
        np.testing.assert_array_equal(q.frame, r.frame)
        np.testing.assert_allclose(q.rcs, r.rcs, rtol=0, atol=tol)
    else:
        assert q.rcs is None and q.frame is None
    assert list(tmp_path.iterdir()) == [tmp_path / f"radar{suffix}"]  # no temporaries left


def test_radar_csv_tolerant_layout(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """BOM, CRLF, spaces, any column order, an unknown column, no trailing newline."""
    p = tmp_path / "radar.csv"
    p.write_bytes(
        b"\xef\xbb\xbf doppler , t,z,y ,x,comment,frame\r\n"
        b"-1.5, 0.0, 1, 2, 3,hello,4\r\n"
        b"2.25,0.1,4,5,6,x y,5"
    )
    with caplog.at_level(logging.WARNING, logger="fgloc.io.radar"):
        r = read_radar(p)
    np.testing.assert_array_equal(r.t, [0.0, 0.1])
    np.testing.assert_array_equal(r.xyz, [[3, 2, 1], [6, 5, 4]])
    np.testing.assert_array_equal(r.doppler, [-1.5, 2.25])
    np.testing.assert_array_equal(r.frame, [4, 5])
    assert r.rcs is None
    assert "comment" in caplog.text


GOOD = "t,x,y,z,doppler\n0.0,1,2,3,0.5\n0.1,1,2,3,0.5\n"


@pytest.mark.parametrize(
    ("text", "row", "field", "words"),
    [
        ("t,x,y,doppler\n0,1,2,0.5\n", 1, "z", "missing column"),
        ("t,x,y,z,doppler\n0,1,2,3,0.5\n0.1,1,2,3,nan\n", 3, "doppler", "NaN"),
        ("t,x,y,z,doppler\n0,1,2,3,0.5\n0.1,1,inf,3,1\n", 3, "y", "infinite"),
        ("t,x,y,z,doppler\n0,1,2,3,0.5\n0.1,abc,2,3,1\n", 3, "x", "not a number"),
        ("t,x,y,z,doppler\n0,1,2,3,0.5\n0.1,1,2\n", 3, "z", "fields"),
        ("t,x,y,z,doppler\n0.2,1,2,3,0.5\n\n0.1,1,2,3,1\n", 4, "t", "backwards"),
        ("t,x,y,z,doppler\n", 2, None, "no data rows"),
        ("", 1, None, "empty file"),
        ("0.0,1,2,3,0.5\n0.1,1,2,3,0.5\n", 1, None, "header missing"),
        ("t,x,y,z,doppler,frame\n0,1,2,3,0.5,1.5\n", 2, "frame", "integer"),
        ("t,x,y,z,doppler,x\n0,1,2,3,0.5,1\n", 1, "x", "duplicate"),
    ],
    ids=["missing-column", "nan", "inf", "non-numeric", "short-row", "t-backwards",
         "header-only", "empty-file", "no-header", "frame-not-int", "duplicate-column"],
)
def test_radar_csv_errors(tmp_path: Path, text: str, row: int, field: str | None,
                          words: str) -> None:
    p = tmp_path / "radar.csv"
    p.write_text(text)
    with pytest.raises(InputError) as ei:
        read_radar(p)
    err = ei.value
    assert (err.path, err.row, err.field) == (p, row, field)
    assert words in str(err)


def test_radar_npz_errors(tmp_path: Path) -> None:
    p = tmp_path / "radar.npz"
    np.savez(p, t=np.zeros(3), x=np.zeros(3), y=np.zeros(3), z=np.zeros(3))
    with pytest.raises(InputError, match="missing column 'doppler'") as ei:
        read_radar(p)
    assert ei.value.field == "doppler"
    np.savez(p, t=[0.0, 1.0, 0.5], x=np.zeros(3), y=np.zeros(3), z=np.zeros(3), doppler=np.zeros(3))
    with pytest.raises(InputError, match=r"backwards.*element 2") as ei:
        read_radar(p)
    assert ei.value.field == "t"


def test_radar_parquet_needs_pyarrow(tmp_path: Path) -> None:
    try:
        import pyarrow  # noqa: F401
    except ImportError:
        p = tmp_path / "radar.parquet"
        p.write_bytes(b"PAR1")
        with pytest.raises(InputError, match=r"fgloc\[parquet\]"):
            read_radar(p)
    else:
        write_radar(tmp_path / "radar.parquet", make_radar())
        np.testing.assert_array_equal(read_radar(tmp_path / "radar.parquet").t, make_radar().t)


# --------------------------------------------------------------------------------------------
# ALS
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_als_round_trip(tmp_path: Path, suffix: str) -> None:
    als = make_als()
    world = FRAME.to_world(als.xyz.astype(np.float64))
    write_als(tmp_path / f"tile{suffix}", world, als.classification, CRS_)
    with laspy.open(tmp_path / f"tile{suffix}") as r:
        assert r.header.parse_crs().to_epsg() == 25832
        assert r.header.point_format.id == 6
    cloud, frame = read_als([tmp_path / f"tile{suffix}"], (E0 + 0.4, N0 - 0.3), None)
    assert frame == FRAME  # CRS from the file; Z0 = round(372.3) from classes 2/11 only
    assert cloud.xyz.dtype == np.float32 and cloud.classification.dtype == np.uint8
    np.testing.assert_array_equal(cloud.classification, als.classification)
    assert np.abs(cloud.xyz - als.xyz).max() < 1e-3


def _write_las12(path: Path, world: np.ndarray, cls: np.ndarray, crs: str | None) -> None:
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.full(3, 0.01)
    header.offsets = np.floor(world.min(axis=0))
    if crs is not None:
        header.add_crs(CRS.from_user_input(crs))
    las = laspy.LasData(header)
    las.x, las.y, las.z = world.T
    las.classification = cls
    las.write(path)


def test_als_legacy_tiles_and_crs_rule(tmp_path: Path) -> None:
    """LAS 1.2 format 3 with GeoTIFF keys (upper-case .LAZ), a tile without CRS and a compound
    CRS tile read together; the sensor.toml CRS decides, chunks smaller than a tile."""
    als = make_als()
    world = FRAME.to_world(als.xyz.astype(np.float64))
    a, b, c = tmp_path / "a.LAZ", tmp_path / "b.las", tmp_path / "c.laz"
    _write_las12(a, world[:1000], als.classification[:1000], CRS_)
    _write_las12(b, world[1000:2000], als.classification[1000:2000], None)
    write_als(c, world[2000:], als.classification[2000:], "EPSG:25832+7837")
    cloud, frame = read_als([a, b, c], (E0, N0), CRS_, chunk_points=300)
    assert frame == FRAME
    assert cloud.source_files == [a, b, c]
    np.testing.assert_array_equal(cloud.classification, als.classification)
    assert np.abs(cloud.xyz - als.xyz).max() < 6e-3  # LAS 1.2 tiles at 1 cm scale


def test_als_errors(tmp_path: Path) -> None:
    als = make_als(100)
    world = FRAME.to_world(als.xyz.astype(np.float64))
    nocrs = tmp_path / "nocrs.las"
    _write_las12(nocrs, world, als.classification, None)
    with pytest.raises(InputError, match="has no CRS and sensor.toml sets no `crs`") as ei:
        read_als([nocrs], (E0, N0), None)
    assert ei.value.path == nocrs
    other = tmp_path / "utm33.laz"
    write_als(other, world, als.classification, "EPSG:25833")
    with pytest.raises(InputError, match="UTM zone 33N.*differs.*UTM zone 32N.*sensor.toml") as ei:
        read_als([other], (E0, N0), CRS_)
    assert ei.value.path == other
    good = tmp_path / "good.laz"
    write_als(good, world, als.classification, CRS_)
    with pytest.raises(InputError, match=r"differs.*good\.laz") as ei:
        read_als([good, other], (E0, N0), None)
    assert ei.value.path == other
    junk = tmp_path / "junk.las"
    junk.write_bytes(b"not a las file")
    with pytest.raises(InputError, match="not a readable LAS") as ei:
        read_als([junk], (E0, N0), CRS_)
    assert ei.value.path == junk


# --------------------------------------------------------------------------------------------
# Lanelet2 map
# --------------------------------------------------------------------------------------------
def test_map_round_trip_is_lanelet2_and_sub_mm(tmp_path: Path) -> None:
    lm = make_map()
    p = tmp_path / "map.osm"
    write_lanelet_map(p, lm, FRAME)
    # lanelet2 itself accepts the file, with our ids and tags
    proj = UtmProjector(Origin(48.7, 11.4))
    lmap, errors = lanelet2.io.loadRobust(str(p), proj)
    assert errors == []
    assert sorted(ll.id for ll in lmap.laneletLayer) == [1, 2, 3]
    assert lmap.laneletLayer[3].attributes["turn_direction"] == "left"
    back = read_lanelet_map(p, CRS_, FRAME)
    assert [ll.id for ll in back.lanelets] == [1, 2, 3]
    for a, b in zip(lm.lanelets, back.lanelets):
        assert np.abs(a.left - b.left).max() < 1e-3
        assert np.abs(a.right - b.right).max() < 1e-3
        assert b.attributes["type"] == "lanelet"
        assert {k: b.attributes[k] for k in a.attributes} == a.attributes
    assert back.lanelets[0].attributes["one_way"] == "yes"


OSM_HEAD = '<?xml version="1.0"?>\n<osm version="0.6">\n'


def _osm_lanelet(lat0: float, lon0: float, ele: bool = True, right_role: str = "right") -> str:
    tag = '<tag k="ele" v="371.25"/>' if ele else ""
    d = 0.00003
    nodes = [(-1, lat0, lon0), (-2, lat0, lon0 + 10 * d), (-3, lat0 + d, lon0),
             (-4, lat0 + d, lon0 + 10 * d)]
    xml = "".join(f'<node id="{i}" lat="{la:.10f}" lon="{lo:.10f}">{tag}</node>\n'
                  for i, la, lo in nodes)
    return (
        OSM_HEAD + xml
        + '<way id="-10"><nd ref="-3"/><nd ref="-4"/><tag k="type" v="line_thin"/></way>\n'
        + '<way id="-11"><nd ref="-1"/><nd ref="-2"/><tag k="type" v="line_thin"/></way>\n'
        + '<relation id="-20"><member type="way" ref="-10" role="left"/>'
        + f'<member type="way" ref="-11" role="{right_role}"/>'
        + '<tag k="type" v="lanelet"/><tag k="subtype" v="road"/></relation>\n'
        + '<relation id="-21"><member type="way" ref="-10" role="outer"/>'
        + '<tag k="type" v="multipolygon"/></relation>\n'
        + '<relation id="-22"><member type="relation" ref="-20" role="refers"/>'
        + '<tag k="type" v="regulatory_element"/><tag k="subtype" v="speed_limit"/></relation>\n'
        + "</osm>\n"
    )


@pytest.mark.parametrize("ele", [True, False], ids=["ele", "no-ele"])
def test_map_hand_written_matches_pyproj(tmp_path: Path, ele: bool) -> None:
    """A hand-written Lanelet2 file with negative ids and extra relations: the bound points
    match pyproj's projection of their lat/lon to < 1 mm; without ele z is 0 in L."""
    lat0, lon0 = 48.7279, 11.4069
    p = tmp_path / "map.osm"
    p.write_text(_osm_lanelet(lat0, lon0, ele))
    m = read_lanelet_map(p, CRS_, FRAME)
    assert len(m) == 1 and m.lanelets[0].id == -20
    ll = m.lanelets[0]
    e, n = WGS84_TO_UTM.transform([lon0, lon0 + 0.0003], [lat0, lat0])
    expected_right = np.column_stack([np.asarray(e) - E0, np.asarray(n) - N0])
    assert np.abs(ll.right[:, :2] - expected_right).max() < 1e-3
    assert ll.left.shape == (2, 3)
    np.testing.assert_allclose(ll.left[:, 2], 371.25 - Z0 if ele else 0.0)


def test_map_inverted_bound_is_reoriented(tmp_path: Path) -> None:
    """A right way drawn against the driving direction comes back parallel to the left."""
    p = tmp_path / "map.osm"
    p.write_text(_osm_lanelet(48.7279, 11.4069).replace('<nd ref="-1"/><nd ref="-2"/>',
                                                          '<nd ref="-2"/><nd ref="-1"/>'))
    ll = read_lanelet_map(p, CRS_, FRAME).lanelets[0]
    d_left, d_right = np.diff(ll.left[:, :2], axis=0)[0], np.diff(ll.right[:, :2], axis=0)[0]
    assert d_left @ d_right > 0.9 * np.linalg.norm(d_left) * np.linalg.norm(d_right)


def test_map_errors(tmp_path: Path) -> None:
    p = tmp_path / "map.osm"
    p.write_text(OSM_HEAD + '<node id="1" lat="48.7" lon="11.4"/>\n</osm>\n')
    with pytest.raises(InputError, match="no lanelet") as ei:
        read_lanelet_map(p, CRS_, FRAME)
    assert ei.value.path == p
    p.write_text(OSM_HEAD + '<node id="1" lat="48.7" lon="11.4">\n</osm>\n')
    with pytest.raises(InputError, match="not valid XML") as ei:
        read_lanelet_map(p, CRS_, FRAME)
    assert ei.value.row == 4
    p.write_text(_osm_lanelet(48.7279, 11.4069, right_role="rite"))
    with pytest.raises(InputError, match="right border") as ei:
        read_lanelet_map(p, CRS_, FRAME)
    assert ei.value.field == "relation -20"


def test_map_in_other_utm_zone(tmp_path: Path) -> None:
    p = tmp_path / "map.osm"
    p.write_text(_osm_lanelet(48.5, 15.5))
    with pytest.raises(InputError) as ei:
        read_lanelet_map(p, CRS_, FRAME, overlap_bbox=(-300.0, -300.0, 300.0, 300.0))
    msg = str(ei.value)
    assert ei.value.path == p
    assert "zone 33 (lon 15.50)" in msg and "EPSG:25832 (zone 32)" in msg
    assert "do not overlap" in msg
    # the same map near the ALS passes the check
    p.write_text(_osm_lanelet(48.7279, 11.4069))
    assert len(read_lanelet_map(p, CRS_, FRAME, overlap_bbox=(-300.0, -300.0, 300.0, 300.0)))


# --------------------------------------------------------------------------------------------
# sensor.toml
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("crs", [CRS_, None], ids=["crs", "no-crs"])
def test_sensor_round_trip(tmp_path: Path, crs: str | None) -> None:
    s = make_sensor(crs)
    write_sensor_toml(tmp_path / "sensor.toml", s)
    assert read_sensor_toml(tmp_path / "sensor.toml") == s
    minimal = tmp_path / "min.toml"
    minimal.write_text("[sensor]\napprox_position = [677000, 5400000]\n")
    assert read_sensor_toml(minimal) == SensorConfig(approx_position=(677000.0, 5400000.0))


@pytest.mark.parametrize(
    ("text", "field", "words"),
    [
        ('crs = "EPSG:25832"\ncolour = 1\n[sensor]\napprox_position = [1.0, 2.0]\n',
         "colour", "unknown key"),
        ("[sensor]\napprox_position = [1.0, 2.0]\nhfov = 100\n", "sensor.hfov", "unknown key"),
        ('[sensor]\napprox_position = [1.0, 2.0]\nmax_range = "far"\n', "sensor.max_range",
         "expected float"),
        ("[sensor]\napprox_position = [1.0]\n", "sensor.approx_position", "expected"),
        ("[sensor]\napprox_height = 6.0\n", "sensor.approx_position", "missing"),
        ("[sensor]\napprox_position = [1.0, 2.0]\nhfov_deg = 400\n", "sensor.hfov_deg", "(0, 360]"),
        ("[sensor]\napprox_position = [1.0, 2.0]\nvfov_deg = 0\n", "sensor.vfov_deg", "(0, 180]"),
        ("[sensor]\napprox_position = [1.0, 2.0]\nmax_range = -1\n", "sensor.max_range", "> 0"),
        ("[sensor]\napprox_position = [1.0, inf]\n", "sensor.approx_position", "finite"),
        ('crs = "EPSG:99999999"\n[sensor]\napprox_position = [1.0, 2.0]\n', "crs", "CRS"),
        ('crs = "EPSG:4326"\n[sensor]\napprox_position = [1.0, 2.0]\n', "crs", "projected"),
        ("[sensor\napprox_position = [1.0, 2.0]\n", None, "invalid TOML"),
    ],
    ids=["unknown-top", "unknown-sensor", "wrong-type", "wrong-length", "missing-position",
         "hfov-range", "vfov-range", "range-negative", "inf", "bad-crs", "geographic-crs",
         "syntax"],
)
def test_sensor_errors(tmp_path: Path, text: str, field: str | None, words: str) -> None:
    p = tmp_path / "sensor.toml"
    p.write_text(text)
    with pytest.raises(InputError) as ei:
        read_sensor_toml(p)
    assert (ei.value.path, ei.value.field) == (p, field)
    assert words in str(ei.value)


# --------------------------------------------------------------------------------------------
# ground_truth.json
# --------------------------------------------------------------------------------------------
def test_ground_truth_round_trip(tmp_path: Path) -> None:
    gt = make_truth()
    p = tmp_path / "ground_truth.json"
    write_ground_truth(p, gt, FRAME)
    raw = json.loads(p.read_text())
    assert raw["sensor"]["x"] == pytest.approx(E0 + 1.5)
    assert raw["sensor"]["pitch_deg"] == pytest.approx(3.0)
    assert raw["tracks"][0]["states"][0][1] == pytest.approx(E0 - 20.0)
    back = read_ground_truth(p, FRAME)
    np.testing.assert_allclose(back.sensor_pose, gt.sensor_pose, atol=1e-9)
    assert [(t.id, t.length, t.width) for t in back.tracks] == [(7, 4.5, 1.8), (8, 12.0, 2.5)]
    for b, g in zip(back.tracks, gt.tracks):
        np.testing.assert_allclose(b.states, g.states, atol=1e-9)
    # pitch > 0 tilts the boresight (sensor x) down in the world
    assert (back.sensor_pose[:3, :3] @ [1.0, 0.0, 0.0])[2] < 0


def _gt(**changes: object) -> str:
    data: dict = {"crs": CRS_, "sensor": dict(zip(
        ["x", "y", "z", "yaw_deg", "pitch_deg", "roll_deg"], [E0, N0, 380.0, 10.0, 2.0, 0.0])),
        "tracks": [{"id": 1, "length": 4.0, "width": 1.8, "states": [[0, E0, N0, 0, 5, 0]]}]}
    for k, v in changes.items():
        if k == "states":
            data["tracks"][0]["states"] = v
        elif v is None:
            del (data if k == "tracks" else data["sensor"])[k]
        else:
            data[k] = v
    return json.dumps(data, indent=1)


@pytest.mark.parametrize(
    ("text", "row", "field", "words"),
    [
        ('{"crs": "EPSG:25832",\n "sensor": {"x": 1,}\n}', 2, None, "invalid JSON"),
        (_gt(yaw_deg=None), None, "sensor.yaw_deg", "missing key"),
        (_gt(states=[[0, 1, 2, 3, 4]]), None, "tracks[0].states", "(n, 6)"),
        (_gt(states=[[0, 1, 2, 3, 4, "x"]]), None, "tracks[0].states", "(n, 6)"),
        (_gt(states=[[0, 1, 2, 3, 4, 5], [0, 1, 2, 3, 4, float("nan")]]), None,
         "tracks[0].states[1]", "non-finite"),
        (_gt(crs="EPSG:25833"), None, "crs", "differs"),
        (_gt(tracks={"id": 1}), None, "tracks", "list"),
        (_gt(tracks=None), None, "tracks", "missing key"),
        (_gt(states=[]), None, "tracks[0].states", "non-empty"),
    ],
    ids=["syntax", "missing-key", "states-shape", "states-type", "nan", "crs-mismatch",
         "tracks-not-list", "tracks-missing", "track-without-states"],
)
def test_ground_truth_errors(tmp_path: Path, text: str, row: int | None, field: str | None,
                             words: str) -> None:
    p = tmp_path / "ground_truth.json"
    p.write_text(text)
    with pytest.raises(InputError) as ei:
        read_ground_truth(p, FRAME)
    assert (ei.value.path, ei.value.row, ei.value.field) == (p, row, field)
    assert words in str(ei.value)


# --------------------------------------------------------------------------------------------
# whole scenario
# --------------------------------------------------------------------------------------------
def _assert_same_scenario(a: Scenario, b: Scenario) -> None:
    assert b.frame == a.frame and b.crs == CRS_
    assert b.sensor == a.sensor
    np.testing.assert_allclose(b.radar.xyz, a.radar.xyz, atol=1e-4)
    np.testing.assert_allclose(b.radar.t, a.radar.t, atol=1e-6)
    np.testing.assert_array_equal(b.radar.frame, a.radar.frame)
    # ALS comes back grouped by tile: match every point to its nearest original
    assert len(b.als) == len(a.als)
    dist, idx = cKDTree(a.als.xyz).query(b.als.xyz)
    assert dist.max() < 1e-3 and len(np.unique(idx)) == len(a.als)
    np.testing.assert_array_equal(b.als.classification, a.als.classification[idx])
    assert [ll.id for ll in b.lanelets.lanelets] == [ll.id for ll in a.lanelets.lanelets]
    for la, lb in zip(a.lanelets.lanelets, b.lanelets.lanelets):
        assert np.abs(la.left - lb.left).max() < 1e-3 and np.abs(la.right - lb.right).max() < 1e-3
    np.testing.assert_allclose(b.truth.sensor_pose, a.truth.sensor_pose, atol=1e-9)
    x, y, z, yaw, pitch, roll = pose_from_se3(b.frame.pose_to_world(b.truth.sensor_pose))
    assert (x, y) == pytest.approx((E0 + 1.5, N0 - 12.0))


def test_write_then_load_scenario(scenario_dir: Path) -> None:
    names = sorted(str(p.relative_to(scenario_dir)) for p in scenario_dir.rglob("*"))
    assert names == ["als", "als/676_5399.laz", "als/676_5400.laz", "als/677_5399.laz",
                     "als/677_5400.laz", "ground_truth.json", "map.osm", "radar.csv",
                     "sensor.toml"]
    assert not [p for p in scenario_dir.parent.iterdir() if p.name.startswith(".")]
    scn = load_scenario(scenario_dir)
    assert scn.path == scenario_dir
    _assert_same_scenario(make_scenario(), scn)


def test_write_scenario_over_existing_dir(scn_copy: Path) -> None:
    """Rewriting with npz radar and no truth replaces files and removes stale ones."""
    scn = replace(make_scenario(), truth=None)
    write_scenario(scn, scn_copy, radar_format="npz")
    names = sorted(p.name for p in scn_copy.iterdir())
    assert names == ["als", "map.osm", "radar.npz", "sensor.toml"]
    back = load_scenario(scn_copy)
    assert back.truth is None
    np.testing.assert_array_equal(back.radar.xyz, scn.radar.xyz)


def test_load_scenario_crs_from_als(scn_copy: Path) -> None:
    """Without crs in sensor.toml the world CRS comes from the tiles' WKT."""
    write_sensor_toml(scn_copy / "sensor.toml", make_sensor(None))
    scn = load_scenario(scn_copy)
    assert scn.crs == CRS_ and scn.sensor.crs is None


@pytest.mark.parametrize(
    ("remove", "named"),
    [("radar.csv", "radar.csv"), ("als", "als"), ("map.osm", "map.osm"),
     ("sensor.toml", "sensor.toml")],
    ids=["radar", "als", "map", "sensor"],
)
def test_load_scenario_missing_file(scn_copy: Path, remove: str, named: str) -> None:
    target = scn_copy / remove
    shutil.rmtree(target) if target.is_dir() else target.unlink()
    with pytest.raises(InputError) as ei:
        load_scenario(scn_copy)
    assert ei.value.path == scn_copy / named


def test_load_scenario_map_in_other_zone(scn_copy: Path) -> None:
    (scn_copy / "map.osm").write_text(_osm_lanelet(48.5, 15.5))
    with pytest.raises(InputError, match="zone 33.*do not overlap") as ei:
        load_scenario(scn_copy)
    assert ei.value.path == scn_copy / "map.osm"


def test_map_file_is_wgs84_with_ele(scenario_dir: Path) -> None:
    """The written map stores lat/lon near Ingolstadt and world heights (ele = z_L + Z0)."""
    root = ET.parse(scenario_dir / "map.osm").getroot()
    node = root.find("node")
    assert 48.0 < float(node.get("lat")) < 49.5 and 11.0 < float(node.get("lon")) < 12.0
    ele = float(node.find("tag[@k='ele']").get("v"))
    assert ele == pytest.approx(Z0 + 0.25)
