"""tracks.csv: world-frame round trip to the written precision and row-precise input errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fgloc.errors import InputError
from fgloc.geo import LocalFrame, se2, wrap_angle
from fgloc.io.tracks_csv import COLUMNS, read_tracks_csv, write_tracks_csv
from fgloc.tracks import N_STATE, YAW, Track, TrackSet

FRAME = LocalFrame.around(677000.4, 5400000.6)
T_C_TO_L = se2(12.5, -40.25, np.deg2rad(130.0))


def _track_set(seed: int = 0) -> TrackSet:
    """Three tracks in frame C with a non-identity C -> L transform."""
    rng = np.random.default_rng(seed)
    tracks = []
    for tid, n in ((3, 40), (7, 25), (12, 60)):
        s = np.zeros((n, N_STATE))
        s[:, :2] = rng.uniform(-80.0, 80.0, 2) + np.cumsum(rng.normal(0.0, 0.5, (n, 2)), axis=0)
        s[:, 2:4] = rng.normal(8.0, 2.0, (n, 2))
        s[:, YAW] = rng.uniform(-6.0, 6.0) + np.cumsum(rng.normal(0.0, 0.2, n))
        s[:, 5] = rng.normal(0.0, 0.3, n)
        s[:, 6:] = rng.uniform(0.5, 2.5, (n, N_STATE - 6))
        s[0, 6] = 0.0  # a zero radius is valid
        t = 100.0 + np.cumsum(rng.uniform(0.04, 0.06, n))
        tracks.append(Track(tid, t, s, rng.integers(0, 3, n).astype(np.int8)))
    return TrackSet(tracks, frame="C", T_frame_to_L=T_C_TO_L)


def test_round_trip_world_frame_exact_to_precision(tmp_path: Path):
    ts = _track_set()
    path = tmp_path / "tracks.csv"
    write_tracks_csv(path, ts, FRAME)

    lines = path.read_text().splitlines()
    assert lines[0] == ",".join(COLUMNS)
    assert len(lines) == 1 + sum(len(tr) for tr in ts.tracks)
    # the first row, computed independently: C -> L by the 3x3 matrix, then + origin
    first = lines[1].split(",")
    tr0 = ts.tracks[0]
    xy_w = (T_C_TO_L @ np.r_[tr0.states[0, :2], 1.0])[:2] + FRAME.origin[:2]
    assert int(first[0]) == 3
    assert float(first[2]) == pytest.approx(xy_w[0], abs=5e-5)
    assert float(first[3]) == pytest.approx(xy_w[1], abs=5e-5)
    assert float(first[2]) > 676_000 and float(first[3]) > 5_399_000
    yaw_w = float(first[6])
    assert -np.pi <= yaw_w < np.pi
    assert wrap_angle(yaw_w - tr0.states[0, YAW] - np.deg2rad(130.0)) == pytest.approx(0, abs=1e-7)
    assert first[8] in {"straight", "left", "right"}

    back = read_tracks_csv(path, FRAME)
    assert back.frame == "L" and np.array_equal(back.T_frame_to_L, np.eye(3))
    ref = ts.in_local()
    assert [tr.id for tr in back.tracks] == [3, 7, 12]
    for a, b in zip(back.tracks, ref.tracks):
        np.testing.assert_allclose(a.t, b.t, rtol=0, atol=5.1e-7)
        np.testing.assert_allclose(a.states[:, :2], b.states[:, :2], rtol=0, atol=5.1e-5)
        np.testing.assert_allclose(a.states[:, 2:4], b.states[:, 2:4], rtol=0, atol=5.1e-5)
        dyaw = wrap_angle(a.states[:, YAW] - b.states[:, YAW])
        np.testing.assert_allclose(dyaw, 0.0, atol=5.1e-8)
        np.testing.assert_allclose(a.states[:, 5], b.states[:, 5], rtol=0, atol=5.1e-8)
        np.testing.assert_allclose(a.states[:, 6:], b.states[:, 6:], rtol=0, atol=5.1e-5)
        np.testing.assert_array_equal(a.labels, b.labels)
        assert a.labels.dtype == np.int8

    # writing what was read reproduces the file byte for byte
    again = tmp_path / "again.csv"
    write_tracks_csv(again, back, FRAME)
    assert again.read_bytes() == path.read_bytes()


def test_reader_accepts_reordered_columns_interleaved_rows_and_empty(tmp_path: Path):
    path = tmp_path / "tracks.csv"
    write_tracks_csv(path, _track_set(), FRAME)
    header, *rows = path.read_text().splitlines()
    names = header.split(",")
    perm = list(reversed(range(len(names))))
    t_col = names.index("t")
    rows.sort(key=lambda r: float(r.split(",")[t_col]))  # tracks interleaved in time
    shuffled = tmp_path / "shuffled.csv"
    shuffled.write_text("\n".join(
        ",".join(f[i] for i in perm) + ",extra" for f in [names, *[r.split(",") for r in rows]]
    ) + "\n\n")
    a, b = read_tracks_csv(path, FRAME), read_tracks_csv(shuffled, FRAME)
    for ta, tb in zip(a.tracks, b.tracks):
        np.testing.assert_array_equal(ta.t, tb.t)
        np.testing.assert_array_equal(ta.states, tb.states)

    empty = tmp_path / "empty.csv"
    write_tracks_csv(empty, TrackSet([], frame="L"), FRAME)
    assert empty.read_text() == ",".join(COLUMNS) + "\n"
    assert len(read_tracks_csv(empty, FRAME)) == 0


def test_to_local_frame_rotates_centres_yaw_and_covariances():
    s = np.zeros((1, N_STATE))
    s[0, :2], s[0, YAW], s[0, 6:] = (1.0, 0.0), 0.25, 1.5
    cov = np.diag(np.r_[4.0, 1.0, np.full(N_STATE - 2, 0.5)])[None]
    ts = TrackSet([Track(1, np.zeros(1), s, np.zeros(1, np.int8), cov)], frame="C",
                  T_frame_to_L=se2(10.0, 20.0, np.pi / 2))
    out = ts.in_local().tracks[0]
    np.testing.assert_allclose(out.states[0, :2], [10.0, 21.0], atol=1e-12)
    assert out.states[0, YAW] == pytest.approx(0.25 + np.pi / 2)
    np.testing.assert_allclose(out.covariances[0, :2, :2], np.diag([1.0, 4.0]), atol=1e-12)
    np.testing.assert_array_equal(out.covariances[0, 2:, 2:], cov[0, 2:, 2:])
    np.testing.assert_array_equal(out.states[0, 6:], s[0, 6:])
    assert ts.tracks[0].states[0, 0] == 1.0  # the input is not modified


def test_t_is_checked_per_track(tmp_path: Path):
    # the first row of track 7 may lie before the last row of track 3
    back = read_tracks_csv(_mutate(tmp_path, 42, "t", "1.0"), FRAME)
    assert back.tracks[1].id == 7 and back.tracks[1].t[0] == 1.0


def _mutate(tmp_path: Path, row: int, column: str, value: str) -> Path:
    """A valid file with the cell (1-based file row, column name) replaced."""
    path = tmp_path / "tracks.csv"
    write_tracks_csv(path, _track_set(), FRAME)
    lines = path.read_text().splitlines()
    fields = lines[row - 1].split(",")
    fields[COLUMNS.index(column)] = value
    lines[row - 1] = ",".join(fields)
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize(
    ("row", "column", "value", "message"),
    [
        (4, "yaw", "nan", "NaN or infinite"),
        (5, "x", "inf", "NaN or infinite"),
        (6, "v", "fast", "not a number"),
        (3, "label", "uturn", "unknown label"),
        (7, "track_id", "3.5", "must be an integer"),
        (9, "r5", "-0.1", "must not be negative"),
        (10, "t", "100.0", "t must increase"),
        (43, "t", "1.0", "t must increase"),  # 2nd row of track 7 (track 3 is rows 2-41)
    ],
)
def test_bad_cells_name_file_row_and_column(tmp_path, row, column, value, message):
    path = _mutate(tmp_path, row, column, value)
    with pytest.raises(InputError, match=message) as exc:
        read_tracks_csv(path, FRAME)
    assert exc.value.path == path and exc.value.row == row and exc.value.field == column
    assert str(path) in str(exc.value)


def test_missing_column_duplicate_column_and_field_count(tmp_path: Path):
    path = tmp_path / "tracks.csv"
    write_tracks_csv(path, _track_set(), FRAME)
    lines = path.read_text().splitlines()
    k = COLUMNS.index("r7")
    drop = [",".join(f for i, f in enumerate(ln.split(",")) if i != k) for ln in lines]
    bad = tmp_path / "missing.csv"
    bad.write_text("\n".join(drop) + "\n")
    with pytest.raises(InputError, match="missing column 'r7'") as exc:
        read_tracks_csv(bad, FRAME)
    assert exc.value.row == 1 and exc.value.field == "r7"

    dup = tmp_path / "dup.csv"
    dup.write_text("\n".join([lines[0] + ",yaw", *lines[1:]]) + "\n")
    with pytest.raises(InputError, match="duplicate column 'yaw'"):
        read_tracks_csv(dup, FRAME)

    short = tmp_path / "short.csv"
    short.write_text("\n".join([*lines[:5], lines[5].rsplit(",", 1)[0], *lines[6:]]) + "\n")
    with pytest.raises(InputError, match="fields") as exc:
        read_tracks_csv(short, FRAME)
    assert exc.value.row == 6

    with pytest.raises(InputError, match="empty file"):
        (tmp_path / "blank.csv").write_text("")
        read_tracks_csv(tmp_path / "blank.csv", FRAME)
