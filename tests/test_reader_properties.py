"""Property-based tests (hypothesis) of the CSV and TOML readers: valid files round-trip,
arbitrary text never escapes as anything but an InputError naming the file."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fgloc.config import Config, dumps_toml, load_config
from fgloc.errors import InputError
from fgloc.geo import LocalFrame
from fgloc.io import read_radar, read_sensor_toml, read_tracks_csv, write_radar, write_sensor_toml
from fgloc.io.radar import PLAUSIBLE_LIMITS
from fgloc.scenario import RadarData, SensorConfig

R = TypeVar("R")

SETTINGS = settings(max_examples=40, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])
FRAME = LocalFrame((677000.0, 5400000.0, 380.0), "EPSG:25832")


_DIR: list[Path] = []


@pytest.fixture(scope="module", autouse=True)
def _workdir(tmp_path_factory):
    """One directory for every generated file (module-scoped: hypothesis reruns a test body
    many times within one function-scoped fixture)."""
    _DIR.append(tmp_path_factory.mktemp("prop"))
    yield
    _DIR.pop()


def _file(name: str, data: str | bytes) -> Path:
    p = _DIR[-1] / name
    if isinstance(data, bytes):
        p.write_bytes(data)
    else:
        p.write_text(data, encoding="utf-8", newline="")
    return p


def _read_or_named_error(read: Callable[[Path], R], p: Path) -> R | None:
    """``read(p)``, or None after checking that the InputError it raised starts with the file."""
    try:
        return read(p)
    except InputError as exc:
        assert str(exc).startswith(str(p))
        return None


def _finite(limit: float) -> st.SearchStrategy[float]:
    return st.floats(-limit, limit, allow_nan=False, allow_infinity=False)


@st.composite
def radar_tables(draw) -> RadarData:
    n = draw(st.integers(1, 40))
    t0 = draw(_finite(2e9))
    steps = draw(st.lists(st.sampled_from([0.0, 0.0, 0.001, 0.05, 1.5]), min_size=n, max_size=n))
    xyz = np.array(draw(st.lists(st.tuples(_finite(300.0), _finite(300.0), _finite(50.0)),
                                 min_size=n, max_size=n)))
    doppler = np.array(draw(st.lists(_finite(90.0), min_size=n, max_size=n)))
    rcs = np.array(draw(st.lists(_finite(60.0), min_size=n, max_size=n))) if draw(
        st.booleans()) else None
    frame = np.cumsum(draw(st.lists(st.integers(0, 2), min_size=n, max_size=n))) if draw(
        st.booleans()) else None
    return RadarData(t=t0 + np.cumsum(steps), xyz=xyz, doppler=doppler, rcs=rcs, frame=frame)


@SETTINGS
@given(radar_tables(), st.sampled_from([".csv", ".npz"]))
def test_radar_round_trip(radar: RadarData, suffix: str) -> None:
    p = _file("radar" + suffix, "")
    write_radar(p, radar)
    back = read_radar(p)
    atol = {"t": 1e-6, "v": 1e-4} if suffix == ".csv" else {"t": 0.0, "v": 0.0}
    np.testing.assert_allclose(back.t, radar.t, rtol=0, atol=atol["t"] + 1e-15 * abs(radar.t[0]))
    np.testing.assert_allclose(back.xyz, radar.xyz, rtol=0, atol=atol["v"])
    np.testing.assert_allclose(back.doppler, radar.doppler, rtol=0, atol=atol["v"])
    assert (back.rcs is None) == (radar.rcs is None)
    assert (back.frame is None) == (radar.frame is None)
    if radar.frame is not None:
        np.testing.assert_array_equal(back.frame, radar.frame)


@SETTINGS
@given(radar_tables(), st.permutations(range(7)), st.booleans(), st.booleans(),
       st.sampled_from(["\n", "\r\n"]))
def test_radar_csv_layout_does_not_matter(radar, perm, upper, bom, newline) -> None:
    """Column order, header case and spaces, a BOM and CRLF give the same detections."""
    radar.rcs = np.zeros(len(radar)) if radar.rcs is None else radar.rcs
    radar.frame = np.arange(len(radar)) if radar.frame is None else radar.frame
    cols = {"t": radar.t, "x": radar.xyz[:, 0], "y": radar.xyz[:, 1], "z": radar.xyz[:, 2],
            "doppler": radar.doppler, "rcs": radar.rcs, "frame": radar.frame}
    names = [list(cols)[k] for k in perm]
    head = ",".join(f" {n.upper() if upper else n} " for n in names)
    rows = [",".join(repr(float(cols[n][i])) if n != "frame" else str(int(cols[n][i]))
                     for n in names) for i in range(len(radar))]
    text = ("\ufeff" if bom else "") + newline.join([head, *rows]) + newline
    back = read_radar(_file("radar.csv", text))
    np.testing.assert_array_equal(back.t, radar.t)
    np.testing.assert_array_equal(back.xyz, radar.xyz)
    np.testing.assert_array_equal(back.frame, radar.frame)


CELLS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-10**20, 10**20).map(str),
    st.text(alphabet="0123456789.eE+-naifNAIF x\"',;\t", max_size=8),
)


@st.composite
def csv_texts(draw) -> str:
    names = draw(st.lists(st.sampled_from(["t", "x", "y", "z", "doppler", "rcs", "frame", "q",
                                           "T", ""]), min_size=0, max_size=8))
    n_rows = draw(st.integers(0, 6))
    rows = [",".join(draw(st.lists(CELLS, min_size=0, max_size=len(names) + 1)))
            for _ in range(n_rows)]
    return "\n".join([",".join(names), *rows]) + draw(st.sampled_from(["", "\n", "\n\n"]))


def _check_radar(radar: RadarData) -> None:
    """Invariants of anything read_radar returns."""
    assert len(radar) >= 1 and np.all(np.diff(radar.t) >= 0)
    for a in (radar.t, radar.xyz, radar.doppler):
        assert np.isfinite(a).all()
    assert np.all(np.abs(radar.xyz) <= PLAUSIBLE_LIMITS["x"][0])
    assert radar.frame is None or radar.frame.dtype == np.int64


@SETTINGS
@given(csv_texts())
def test_radar_csv_arbitrary_text(text: str) -> None:
    radar = _read_or_named_error(read_radar, _file("radar.csv", text))
    if radar is not None:
        _check_radar(radar)


@SETTINGS
@given(st.binary(max_size=300))
def test_radar_csv_arbitrary_bytes(data: bytes) -> None:
    radar = _read_or_named_error(read_radar, _file("radar.csv", b"t,x,y,z,doppler\n" + data))
    if radar is not None:
        _check_radar(radar)


@SETTINGS
@given(csv_texts(), st.booleans())
def test_tracks_csv_arbitrary_text(text: str, with_header: bool) -> None:
    from fgloc.io.tracks_csv import COLUMNS

    if with_header:
        text = ",".join(COLUMNS) + "\n" + text
    tracks = _read_or_named_error(lambda q: read_tracks_csv(q, FRAME), _file("tracks.csv", text))
    if tracks is not None:
        for tr in tracks.tracks:
            assert np.isfinite(tr.states).all() and np.all(np.diff(tr.t) > 0)


# --- TOML ---------------------------------------------------------------------------------
TOML_SCALARS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**12, 10**12),
    st.booleans(), st.text(max_size=12),
)
TOML_VALUES = st.one_of(TOML_SCALARS, st.lists(TOML_SCALARS, max_size=3),
                        st.lists(st.floats(-1e7, 1e7), min_size=2, max_size=2))
SENSOR_KEYS = ["approx_position", "approx_height", "yaw_guess_deg", "hfov_deg", "vfov_deg",
               "max_range", "range"]


@st.composite
def sensor_docs(draw) -> dict:
    table = draw(st.dictionaries(st.sampled_from(SENSOR_KEYS), TOML_VALUES, max_size=7))
    doc: dict = {"sensor": table} if draw(st.booleans()) or table else {}
    if draw(st.booleans()):
        doc["crs"] = draw(st.sampled_from(["EPSG:25832", "EPSG:4326", "EPSG:3857", "nonsense",
                                           "EPSG:25832+7837"]))
    return doc


@SETTINGS
@given(sensor_docs())
def test_sensor_toml_arbitrary_documents(doc: dict) -> None:
    s = _read_or_named_error(read_sensor_toml, _file("sensor.toml", dumps_toml(doc)))
    if s is not None:
        assert len(s.approx_position) == 2
        assert all(math.isfinite(v) and abs(v) <= 1e8 for v in s.approx_position)
        assert 0 < s.hfov_deg <= 360 and 0 < s.vfov_deg <= 180 and s.max_range > 0


@SETTINGS
@given(st.tuples(_finite(1e7), _finite(1e7)), st.none() | _finite(100.0),
       st.none() | _finite(180.0), st.floats(1.0, 360.0), st.floats(1.0, 180.0),
       st.floats(1.0, 1000.0), st.sampled_from([None, "EPSG:25832", "EPSG:32633"]))
def test_sensor_toml_round_trip(pos, height, yaw, hfov, vfov, max_range, crs) -> None:
    s = SensorConfig(pos, crs, height, yaw, hfov, vfov, max_range)
    p = _file("sensor.toml", "")
    write_sensor_toml(p, s)
    assert read_sensor_toml(p) == s


@SETTINGS
@given(st.text(max_size=200))
def test_toml_arbitrary_text(text: str) -> None:
    """Any text as sensor.toml or as a fgloc config: a result or an InputError."""
    for name, read in (("sensor.toml", read_sensor_toml), ("config.toml", load_config)):
        out = _read_or_named_error(read, _file(name, text))
        assert out is None or isinstance(out, (SensorConfig, Config))


@SETTINGS
@given(st.dictionaries(st.sampled_from(["seed", "map", "coarse", "sicp", "bogus"]),
                       st.one_of(TOML_VALUES, st.dictionaries(
                           st.sampled_from(["voxel_size", "gamma", "doppler_min", "min_points",
                                            "icp_ranges", "nope"]), TOML_VALUES, max_size=3)),
                       max_size=4))
def test_config_arbitrary_documents(doc: dict) -> None:
    cfg = _read_or_named_error(load_config, _file("config.toml", dumps_toml(doc)))
    assert cfg is None or isinstance(cfg, Config)
