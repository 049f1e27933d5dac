"""fgloc import rosbag: bags written with rosbags itself (MCAP and sqlite3 storage)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")
from rosbags.rosbag2 import StoragePlugin, Writer  # noqa: E402
from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # noqa: E402

from fgloc.cli import main  # noqa: E402
from fgloc.config import from_dict  # noqa: E402
from fgloc.errors import InputError  # noqa: E402
from fgloc.io import load_scenario, read_radar, write_scenario  # noqa: E402
from fgloc.io.rosbag import read_rosbag_radar  # noqa: E402
from fgloc.scenario import RadarData  # noqa: E402
from fgloc.sim import SimConfig, simulate  # noqa: E402

STORAGES = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
#: An ARS548-style detection list (field names of the Continental ARS548 ROS 2 drivers).
DETECTION_MSG = """\
float32 f_azimuthangle
float32 f_azimuthanglestd
uint8 u_invalidflags
float32 f_elevationangle
float32 f_elevationanglestd
float32 f_range
float32 f_rangestd
float32 f_rangerate
float32 f_rangeratestd
int8 s_rcs
uint16 u_measurementid
"""
DETECTION_LIST_MSG = """\
std_msgs/Header header
uint32 list_numofdetections
ars548_msgs/Detection[] detection_array
"""


def _frames(radar: RadarData):
    ids = radar.frame_ids()
    for f in np.unique(ids):
        sel = ids == f
        yield float(radar.t[sel][0]), sel


def _header(store, t: float, frame_id: str = "radar"):
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    sec = int(np.floor(t))
    return Header(stamp=Time(sec=sec, nanosec=int(round((t - sec) * 1e9))), frame_id=frame_id)


def write_pointcloud_bag(path: Path, radar: RadarData, storage: str, *,
                         doppler_name: str = "doppler", with_doppler: bool = True) -> None:
    """One PointCloud2 per radar frame: float32 x, y, z, <doppler_name>, rcs (+ padding)."""
    store = get_typestore(Stores.LATEST)
    PointCloud2 = store.types["sensor_msgs/msg/PointCloud2"]
    PointField = store.types["sensor_msgs/msg/PointField"]
    names = ["x", "y", "z"] + ([doppler_name] if with_doppler else []) + ["rcs"]
    fields = [PointField(name=n, offset=4 * k, datatype=7, count=1) for k, n in enumerate(names)]
    step = 4 * len(names) + 4  # 4 padding bytes, as drivers often have
    with Writer(path, version=9, storage_plugin=STORAGES[storage]) as w:
        conn = w.add_connection("/radar/points", PointCloud2.__msgtype__, typestore=store)
        for t, sel in _frames(radar):
            cols = [radar.xyz[sel, 0], radar.xyz[sel, 1], radar.xyz[sel, 2]]
            cols += [radar.doppler[sel]] if with_doppler else []
            cols += [radar.rcs[sel]]
            buf = np.zeros((int(sel.sum()), step // 4), dtype="<f4")
            buf[:, : len(cols)] = np.column_stack(cols)
            msg = PointCloud2(header=_header(store, t), height=1, width=int(sel.sum()),
                              fields=fields, is_bigendian=False, point_step=step,
                              row_step=step * int(sel.sum()),
                              data=buf.view(np.uint8).reshape(-1), is_dense=True)
            w.write(conn, int(t * 1e9) + 5_000_000, store.serialize_cdr(msg, conn.msgtype))


def _detection_store():
    store = get_typestore(Stores.LATEST)
    types = get_types_from_msg(DETECTION_MSG, "ars548_msgs/msg/Detection")
    types.update(get_types_from_msg(DETECTION_LIST_MSG, "ars548_msgs/msg/DetectionList"))
    store.register(types)
    return store


def write_detection_bag(path: Path, radar: RadarData, storage: str, *,
                        embed_definition: bool = True) -> None:
    """One ARS548-style DetectionList per frame (range, azimuth, elevation, range rate)."""
    store = _detection_store()
    Det = store.types["ars548_msgs/msg/Detection"]
    DetList = store.types["ars548_msgs/msg/DetectionList"]
    x, y, z = radar.xyz.T
    rng = np.sqrt(x * x + y * y + z * z)
    az, el = np.arctan2(y, x), np.arcsin(z / rng)
    with Writer(path, version=9, storage_plugin=STORAGES[storage]) as w:
        extra = {} if embed_definition else {"msgdef": "", "rihs01": "RIHS01_" + "0" * 64}
        conn = w.add_connection("/ars548/detections", DetList.__msgtype__, typestore=store,
                                **extra)
        for t, sel in _frames(radar):
            dets = [Det(f_azimuthangle=a, f_azimuthanglestd=0.0, u_invalidflags=0,
                        f_elevationangle=e, f_elevationanglestd=0.0, f_range=r, f_rangestd=0.0,
                        f_rangerate=v, f_rangeratestd=0.0, s_rcs=int(np.clip(round(c), -128, 127)),
                        u_measurementid=k)
                    for k, (a, e, r, v, c) in enumerate(zip(
                        az[sel], el[sel], rng[sel], radar.doppler[sel], radar.rcs[sel]))]
            msg = DetList(header=_header(store, t), list_numofdetections=len(dets),
                          detection_array=dets)
            w.write(conn, int(t * 1e9), store.serialize_cdr(msg, conn.msgtype))


@pytest.fixture(scope="module")
def scenario(tmp_path_factory) -> Path:
    small = {"als": {"extent": 200.0, "density": 1.0, "buildings": 1, "trees": 4, "poles": 1},
             "road": {"arm_length": 80.0},
             "radar": {"max_range": 90.0, "clutter_per_frame": 20.0, "rate_hz": 10.0}}
    d = tmp_path_factory.mktemp("ros") / "scn"
    scn = simulate("intersection", 5, duration=3.0, vehicles=2,
                   config=from_dict(SimConfig, small, None))
    scn.radar.t = scn.radar.t + 1.7e9  # epoch stamps, as recorded (a zero stamp means none)
    write_scenario(scn, d)
    return d


def _close(a: RadarData, b: RadarData, atol: float) -> None:
    assert len(a) == len(b)
    np.testing.assert_allclose(a.t, b.t, atol=2e-6)
    np.testing.assert_allclose(a.xyz, b.xyz, atol=atol)
    np.testing.assert_allclose(a.doppler, b.doppler, atol=atol)
    np.testing.assert_array_equal(a.frame_ids(), b.frame_ids())


@pytest.mark.parametrize("storage", sorted(STORAGES))
def test_pointcloud2_bag_to_scenario(scenario: Path, tmp_path: Path, storage: str, capsys):
    truth = read_radar(scenario / "radar.csv")
    bag = tmp_path / "bag"
    write_pointcloud_bag(bag, truth, storage)
    out = tmp_path / "imported"
    args = ["-q", "import", "rosbag", str(bag), "--topic", "/radar/points", "--out", str(out),
            "--als", str(scenario / "als"), "--map", str(scenario / "map.osm"),
            "--sensor", str(scenario / "sensor.toml"),
            "--ground-truth", str(scenario / "ground_truth.json")]
    assert main(args) == 0
    assert "still needed" not in capsys.readouterr().out
    got = read_radar(out / "radar.csv")
    _close(got, truth, atol=1e-4)  # float32 in the bag, 0.1 mm in the CSV
    np.testing.assert_allclose(got.rcs, truth.rcs, atol=1e-4)
    scn = load_scenario(out)  # a complete, valid scenario
    assert len(scn.als) > 0 and scn.truth is not None
    assert main(["-q", "info", str(out)]) == 0


@pytest.mark.parametrize("storage", sorted(STORAGES))
def test_detection_list_bag(scenario: Path, tmp_path: Path, storage: str):
    truth = read_radar(scenario / "radar.csv")
    bag = tmp_path / "bag"
    write_detection_bag(bag, truth, storage)
    got = read_rosbag_radar(bag, "/ars548/detections")
    _close(got, truth, atol=1e-4)  # float32 range/angles: ~1e-5 m at 100 m
    np.testing.assert_allclose(got.rcs, np.clip(np.round(truth.rcs), -128, 127))
    flipped = read_rosbag_radar(bag, "/ars548/detections", negate_doppler=True)
    np.testing.assert_allclose(flipped.doppler, -got.doppler)


def test_detection_list_without_definition_needs_msg_def(scenario: Path, tmp_path: Path):
    truth = read_radar(scenario / "radar.csv")
    bag = tmp_path / "bag"
    write_detection_bag(bag, truth, "sqlite3", embed_definition=False)
    with pytest.raises(InputError, match="--msg-def"):
        read_rosbag_radar(bag, "/ars548/detections")
    defs = tmp_path / "defs" / "ars548_msgs" / "msg"
    defs.mkdir(parents=True)
    (defs / "Detection.msg").write_text(DETECTION_MSG)
    (defs / "DetectionList.msg").write_text(DETECTION_LIST_MSG)
    got = read_rosbag_radar(bag, "/ars548/detections",
                            msg_defs=[defs / "Detection.msg", defs / "DetectionList.msg"])
    _close(got, truth, atol=1e-4)


def test_pointcloud2_field_names(scenario: Path, tmp_path: Path):
    truth = read_radar(scenario / "radar.csv")
    bag = tmp_path / "v"
    write_pointcloud_bag(bag, truth, "mcap", doppler_name="Range_Rate")
    _close(read_rosbag_radar(bag, "/radar/points"), truth, atol=1e-4)
    bag = tmp_path / "custom"
    write_pointcloud_bag(bag, truth, "mcap", doppler_name="vrad_ms")
    with pytest.raises(InputError) as info:
        read_rosbag_radar(bag, "/radar/points")
    msg = str(info.value)
    assert "x, y, z, vrad_ms, rcs" in msg and "--doppler-field" in msg and "/radar/points" in msg
    _close(read_rosbag_radar(bag, "/radar/points", doppler_field="vrad_ms"), truth, atol=1e-4)


def test_import_errors(scenario: Path, tmp_path: Path, capsys):
    truth = read_radar(scenario / "radar.csv")
    bag = tmp_path / "nodop"
    write_pointcloud_bag(bag, truth, "sqlite3", with_doppler=False)
    out = tmp_path / "o"
    base = ["-q", "import", "rosbag", str(bag), "--out", str(out)]
    assert main(base + ["--topic", "/radar/points"]) == 2
    err = capsys.readouterr().err
    assert "PointCloud2 has fields x, y, z, rcs" in err and "range-rate" in err
    assert main(base + ["--topic", "/nope"]) == 2
    assert "/radar/points (sensor_msgs/msg/PointCloud2)" in capsys.readouterr().err
    assert main(base + ["--topic", "/radar/points", "--sensor", str(tmp_path / "x.toml")]) == 2
    (tmp_path / "notabag.mcap").write_bytes(b"\x89MCAP0\r\n garbage")
    assert main(["-q", "import", "rosbag", str(tmp_path / "notabag.mcap"), "--topic", "/r",
                 "--out", str(out)]) == 2
    assert "not a readable ROS 2 bag" in capsys.readouterr().err
    assert not out.exists()
