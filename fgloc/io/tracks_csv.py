"""``tracks.csv`` (world frame) <-> :class:`fgloc.tracks.TrackSet` (local frame L).

Header ``track_id,t,x,y,v,a,yaw,yawrate,label,r0,...,r19``; one row per track and time step,
written grouped by track and in time order. x, y in m in the world CRS; t in s; v in m/s;
a in m/s^2; yaw in rad CCW from grid east, wrapped to [-pi, pi); yawrate in rad/s; label one
of ``straight``, ``left``, ``right``; ``r_i`` the star-convex contour radius (m) at angle
``2*pi*i/20`` in the vehicle frame (x along the heading), which a rigid transform leaves
unchanged. Covariances and detection indices are not part of the file.

Written precision: t to 1e-6 s, x/y/radii/v/a to 1e-4 (m, m/s, m/s^2), yaw/yawrate to 1e-7
(rad, rad/s). Reading is by column name (any order, unknown columns ignored with a warning).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from fgloc.errors import InputError
from fgloc.geo import LocalFrame, wrap_angle
from fgloc.io.atomic import atomic_path
from fgloc.io.radar import is_number
from fgloc.labels import CODES, label_names
from fgloc.tracks import N_CONTOUR, N_KIN, YAW, Track, TrackSet

log = logging.getLogger(__name__)

RADIUS_COLUMNS: tuple[str, ...] = tuple(f"r{i}" for i in range(N_CONTOUR))
#: file columns in write order; the state columns follow the state layout of fgloc.tracks
STATE_COLUMNS: tuple[str, ...] = ("x", "y", "v", "a", "yaw", "yawrate") + RADIUS_COLUMNS
COLUMNS: tuple[str, ...] = ("track_id", "t", *STATE_COLUMNS[:N_KIN], "label", *RADIUS_COLUMNS)
_FORMATS: dict[str, str] = {
    "track_id": "%d",
    "t": "%.6f",
    "x": "%.4f",
    "y": "%.4f",
    "v": "%.4f",
    "a": "%.4f",
    "yaw": "%.7f",
    "yawrate": "%.7f",
    "label": "%s",
    **{c: "%.4f" for c in RADIUS_COLUMNS},
}
_CHUNK_ROWS = 100_000


# --------------------------------------------------------------------------------------------
# frames
# --------------------------------------------------------------------------------------------
# --------------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------------
def write_tracks_csv(path: str | Path, tracks: TrackSet, frame: LocalFrame) -> None:
    """Write ``tracks`` (any frame with its ``T_frame_to_L``) to ``path`` in world coordinates.

    ``frame`` maps L to the world CRS. The file is replaced atomically; a track set without
    tracks gives a header-only file.
    """
    local = tracks.in_local()
    n_rows = sum(len(tr) for tr in local.tracks)
    states = np.zeros((n_rows, N_KIN + N_CONTOUR))
    ids = np.zeros(n_rows, dtype=np.int64)
    t = np.zeros(n_rows)
    labels = np.zeros(n_rows, dtype=np.int8)
    start = 0
    for tr in local.tracks:
        sl = slice(start, start + len(tr))
        ids[sl], t[sl], states[sl], labels[sl] = tr.id, tr.t, tr.states, tr.labels
        start = sl.stop
    states[:, :2] = frame.to_world(states[:, :2])
    states[:, YAW] = wrap_angle(states[:, YAW])
    cols: dict[str, list] = {"track_id": ids.tolist(), "t": t.tolist()}
    cols.update({c: states[:, k].tolist() for k, c in enumerate(STATE_COLUMNS)})
    cols["label"] = label_names(labels).tolist()
    fmt = ",".join(_FORMATS[c] for c in COLUMNS)
    rows = list(zip(*(cols[c] for c in COLUMNS)))
    with atomic_path(path) as tmp, tmp.open("w", encoding="utf-8", newline="\n") as fh:
        fh.write(",".join(COLUMNS) + "\n")
        for a in range(0, n_rows, _CHUNK_ROWS):
            fh.write("\n".join(map(fmt.__mod__, rows[a : a + _CHUNK_ROWS])) + "\n")


# --------------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------------
def read_tracks_csv(path: str | Path, frame: LocalFrame) -> TrackSet:
    """Read ``tracks.csv`` into a :class:`TrackSet` in L of ``frame`` (frame "L", identity).

    Rows of one track need not be contiguous, but their t must increase in file order. Raises
    :class:`InputError` naming the file, the 1-based row (header = row 1) and the column for a
    missing or duplicate column, a wrong field count, a non-numeric, NaN or infinite value, a
    non-integer track_id, an unknown label, t not increasing within a track or a negative
    radius. A header-only file gives an empty track set.
    """
    p = Path(path)
    try:
        lines = p.read_text(encoding="utf-8-sig").splitlines()
    except FileNotFoundError:
        raise InputError(p, "tracks file not found") from None
    except UnicodeDecodeError as exc:
        raise InputError(p, f"not UTF-8 text: {exc}") from None
    if not lines or not lines[0].strip():
        raise InputError(p, f"empty file: expected the header {','.join(COLUMNS)}", row=1)
    names = [n.strip().strip('"').strip().lower() for n in lines[0].split(",")]
    body = _Body(p, names, [(k, ln) for k, ln in enumerate(lines[1:], start=2) if ln.strip()])
    col = body.parse()
    ids, t = col["track_id"], col["t"]
    body.check(ids != np.round(ids), "track_id", "track_id must be an integer")
    body.check(col["label"] < 0, "label", f"unknown label (expected one of {', '.join(CODES)})")
    neg = np.column_stack([col[c] for c in RADIUS_COLUMNS]) < 0
    if neg.any():
        k = int(np.argmax(neg.any(axis=1)))
        body.fail(k, RADIUS_COLUMNS[int(np.argmax(neg[k]))], "contour radius must not be negative")
    order = np.lexsort((np.arange(len(ids)), ids))  # by track, file order within a track
    same = ids[order][1:] == ids[order][:-1]
    not_increasing = np.zeros(len(ids), dtype=bool)
    not_increasing[order[1:][same & (np.diff(t[order]) <= 0)]] = True
    body.check(not_increasing, "t", "t must increase within a track")
    states = np.column_stack([col[c] for c in STATE_COLUMNS])
    states[:, :2] = frame.to_local(states[:, :2])
    tracks = []
    for tid in np.unique(ids):
        sel = order[ids[order] == tid]
        tracks.append(Track(int(tid), t[sel], states[sel], col["label"][sel].astype(np.int8)))
    return TrackSet(tracks, frame="L", T_frame_to_L=np.eye(3))


class _Body:
    """The data lines of a tracks.csv with their 1-based file rows, for parsing and for
    error messages that name the row, the column and the offending cell."""

    def __init__(self, path: Path, names: list[str], lines: list[tuple[int, str]]) -> None:
        self.path = path
        self.names = names
        self.rows = [r for r, _ in lines]
        self.lines = [ln for _, ln in lines]
        self.index = self._column_index()

    def _column_index(self) -> dict[str, int]:
        """Column name -> position for every known column; errors on duplicates and missing."""
        seen: set[str] = set()
        for n in self.names:
            if n in seen:
                raise InputError(self.path, f"duplicate column '{n}'", row=1, field=n)
            seen.add(n)
        for c in COLUMNS:
            if c not in seen:
                raise InputError(self.path, f"missing column '{c}'", row=1, field=c)
        extra = [n for n in self.names if n not in COLUMNS]
        if extra:
            log.warning("%s: ignoring unknown tracks column(s): %s", self.path, ", ".join(extra))
        return {c: self.names.index(c) for c in COLUMNS}

    def parse(self) -> dict[str, np.ndarray]:
        """Column name -> float64 values (label as its code, -1 when unknown), all finite."""
        if not self.lines:
            return {c: np.zeros(0) for c in COLUMNS}
        usecols = [self.index[c] for c in COLUMNS]
        try:
            data = np.loadtxt(self.lines, delimiter=",", comments=None, usecols=usecols,
                              converters={self.index["label"]: _label_code}, ndmin=2,
                              dtype=np.float64)
        except ValueError as exc:
            raise self._locate_parse_error(str(exc)) from None
        out = {c: data[:, k] for k, c in enumerate(COLUMNS)}
        for c, values in out.items():
            self.check(~np.isfinite(values), c, "NaN or infinite value is not allowed")
        return out

    def check(self, bad: np.ndarray, column: str, message: str) -> None:
        """Raise an InputError at the first True of ``bad`` (file order), quoting its cell."""
        if bad.any():
            self.fail(int(np.argmax(bad)), column, message)

    def fail(self, k: int, column: str, message: str) -> None:
        """Raise an InputError at data line k (0-based), quoting the cell of ``column``."""
        cell = self.lines[k].split(",")[self.index[column]].strip()
        raise InputError(self.path, f"{message}: {cell!r}", row=self.rows[k], field=column)

    def _locate_parse_error(self, reason: str) -> InputError:
        """The first row with a wrong field count or a non-numeric cell (slow, error path)."""
        numeric = [c for c in COLUMNS if c != "label"]
        for row, line in zip(self.rows, self.lines):
            fields = line.split(",")
            if len(fields) != len(self.names):
                return InputError(self.path, f"row has {len(fields)} fields, the header has "
                                  f"{len(self.names)}", row=row)
            for c in numeric:
                if not is_number(fields[self.index[c]]):
                    return InputError(self.path, f"not a number: {fields[self.index[c]]!r}",
                                      row=row, field=c)
        return InputError(self.path, f"cannot parse the CSV body: {reason}")


def _label_code(text: str) -> int:
    """Label code of a label name (case and surrounding blanks ignored); -1 when unknown."""
    return CODES.get(text.strip().lower(), -1)

