"""Radar detections: ``radar.csv`` (or ``.npz`` / ``.parquet``) <-> :class:`RadarData`.

Columns ``t,x,y,z,doppler`` (required) and ``rcs``, ``frame`` (optional), read by name in any
order. t in s (non-decreasing), x/y/z in m in the sensor frame S, doppler in m/s (range rate,
positive away from the sensor), rcs in dBsm, frame an integer frame index. Unknown columns
are ignored with a ``logging`` warning.
"""

from __future__ import annotations

import logging
import warnings
import zipfile
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from types import ModuleType

import numpy as np

from fgloc.errors import InputError
from fgloc.io.atomic import atomic_path
from fgloc.scenario import RadarData

log = logging.getLogger(__name__)

REQUIRED_COLUMNS: tuple[str, ...] = ("t", "x", "y", "z", "doppler")
OPTIONAL_COLUMNS: tuple[str, ...] = ("rcs", "frame")
RADAR_SUFFIXES: tuple[str, ...] = (".csv", ".npz", ".parquet")
_HEADER_HINT = "expected a header line 't,x,y,z,doppler' (optionally followed by rcs, frame)"
#: printf formats per column: t to 1 us, lengths to 0.1 mm, speeds to 0.1 mm/s.
_CSV_FORMATS: dict[str, str] = {
    "t": "%.6f",
    "x": "%.4f",
    "y": "%.4f",
    "z": "%.4f",
    "doppler": "%.4f",
    "rcs": "%.4f",
    "frame": "%d",
}
_CSV_CHUNK_ROWS = 200_000
#: Rows parsed per np.loadtxt call when reading a CSV.
CSV_READ_ROWS = 500_000
#: Largest magnitude accepted per column (beyond them the file is broken or in wrong units).
PLAUSIBLE_LIMITS: dict[str, tuple[float, str]] = {
    "t": (1e11, "(t is in seconds: nanosecond or microsecond stamps must be converted)"),
    "x": (1e5, "m (sensor frame)"),
    "y": (1e5, "m (sensor frame)"),
    "z": (1e5, "m (sensor frame)"),
    "doppler": (1e3, "m/s"),
    "rcs": (1e3, "dBsm"),
    "frame": (2.0**53, "(frame index)"),
}

RowOf = Callable[[int], int | None]


# --------------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------------
def read_radar(path: str | Path) -> RadarData:
    """Read detections from a ``.csv``, ``.npz`` or ``.parquet`` file (chosen by suffix).

    Raises :class:`InputError` naming the file, the 1-based row (header = row 1; CSV only)
    and the column for a missing column, a non-numeric, NaN or infinite value, a non-integer
    ``frame``, t going backwards, or a file without data rows.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in RADAR_SUFFIXES:
        raise InputError(p, f"unknown radar format {p.suffix!r} (use {', '.join(RADAR_SUFFIXES)})")
    if not p.is_file():
        raise InputError(p, "radar file not found")
    if suffix == ".csv":
        return _read_csv(p)
    if suffix == ".npz":
        return _read_npz(p)
    return _read_parquet(p)


def _read_csv(path: Path) -> RadarData:
    try:
        return _read_csv_text(path)
    except UnicodeDecodeError as exc:
        raise InputError(path, f"not UTF-8 text: {exc}") from None


def _read_csv_text(path: Path) -> RadarData:
    with path.open("r", encoding="utf-8-sig", newline=None) as fh:
        header = fh.readline()
        if not header.strip():
            raise InputError(path, f"empty file: {_HEADER_HINT}", row=1)
        names = [n.strip().strip('"').strip().lower() for n in header.rstrip("\r\n").split(",")]
        if all(is_number(n) for n in names):
            raise InputError(path, f"header missing: row 1 holds numbers; {_HEADER_HINT}", row=1)
        wanted = _select_columns(path, names, row=1)
        usecols = [names.index(c) for c in wanted]
        # filled chunk by chunk: peak memory is the result plus one chunk, and x, y, z land
        # directly in the (n, 3) array RadarData keeps
        capacity = _count_lines(path)
        xyz = np.empty((capacity, 3))
        other = np.empty((len(wanted) - 3, capacity))
        n = 0
        try:
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", "loadtxt: input contained no data")
                warnings.filterwarnings("ignore", "Input line .* contained no data")
                while True:
                    chunk = np.loadtxt(fh, delimiter=",", comments=None, usecols=usecols,
                                       ndmin=2, dtype=np.float64, max_rows=CSV_READ_ROWS)
                    m = chunk.shape[0]
                    if m == 0:
                        break
                    xyz[n : n + m] = chunk[:, 1:4]
                    other[:, n : n + m] = chunk[:, [0, *range(4, len(wanted))]].T
                    n += m
        except ValueError as exc:
            raise _locate_csv_error(path, names, wanted, str(exc)) from None
    if n == 0:
        raise InputError(path, "no data rows (the file holds only a header)", row=2)
    rest = [c for c in wanted if c not in ("x", "y", "z")]
    columns = {c: other[k, :n] for k, c in enumerate(rest)}
    columns.update(x=xyz[:n, 0], y=xyz[:n, 1], z=xyz[:n, 2])
    return _radar_from_columns(path, columns, lambda i: _csv_line_of(path, i), xyz=xyz[:n])


def _count_lines(path: Path) -> int:
    """Newlines in the file + 1: an upper bound of its data rows (a fast binary scan)."""
    n = 1
    with path.open("rb") as fh:
        while block := fh.read(1 << 24):
            n += block.count(b"\n")
    return n


def _read_npz(path: Path) -> RadarData:
    try:
        with np.load(path, allow_pickle=False) as npz:
            names = list(npz.files)
            wanted = _select_columns(path, names, row=None)
            columns = {c: _numeric_1d(path, c, _npz_array(path, npz, c)) for c in wanted}
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise InputError(path, f"not a readable .npz of numeric arrays: {exc}") from None
    return _radar_from_columns(path, columns, None)


def _npz_array(path: Path, npz: Mapping[str, np.ndarray], name: str) -> np.ndarray:
    try:
        return npz[name]
    except ValueError as exc:  # object arrays: numpy refuses to unpickle them
        raise InputError(path, f"expected a 1-D numeric array ({exc}; fgloc never unpickles "
                         "object arrays)", field=name) from None


def _read_parquet(path: Path) -> RadarData:
    pq = _import_parquet(path)
    try:
        table = pq.read_table(path)
    except Exception as exc:  # pyarrow raises its own ArrowInvalid / OSError family
        raise InputError(path, f"not a readable parquet file: {exc}") from None
    names = [n.strip().lower() for n in table.column_names]
    wanted = _select_columns(path, names, row=None)
    columns = {
        c: _numeric_1d(path, c, table.column(names.index(c)).to_numpy(zero_copy_only=False))
        for c in wanted
    }
    return _radar_from_columns(path, columns, None)


def _import_parquet(path: Path) -> ModuleType:
    """The ``pyarrow.parquet`` module, or an InputError telling how to install it."""
    try:
        import pyarrow.parquet as pq
    except ImportError:
        raise InputError(
            path, "reading/writing parquet needs pyarrow: pip install 'fgloc[parquet]'"
        ) from None
    return pq


def _select_columns(path: Path, names: list[str], row: int | None) -> list[str]:
    """Check the column names; return the known ones present, required first."""
    seen: set[str] = set()
    for n in names:
        if n in seen:
            raise InputError(path, f"duplicate column '{n}'", row=row, field=n)
        seen.add(n)
    for c in REQUIRED_COLUMNS:
        if c not in seen:
            raise InputError(
                path, f"missing column '{c}' (found: {', '.join(names)})", row=row, field=c
            )
    extra = [n for n in names if n not in REQUIRED_COLUMNS + OPTIONAL_COLUMNS]
    if extra:
        log.warning("%s: ignoring unknown radar column(s): %s", path, ", ".join(extra))
    return list(REQUIRED_COLUMNS) + [c for c in OPTIONAL_COLUMNS if c in seen]


def _numeric_1d(path: Path, name: str, arr: np.ndarray) -> np.ndarray:
    a = np.asarray(arr)
    if a.ndim != 1 or not (np.issubdtype(a.dtype, np.number) or a.dtype == bool):
        raise InputError(path, f"column must be a 1-D numeric array, got {a.dtype} {a.shape}",
                         field=name)
    return a.astype(np.float64)


def is_number(text: str) -> bool:
    """True when ``text`` parses as a float (CSV cell check)."""
    try:
        float(text)
    except ValueError:
        return False
    return True


def _csv_data_lines(path: Path) -> Iterator[tuple[int, str]]:
    """(1-based line number, text) of every data line; blank lines are skipped like loadtxt."""
    with path.open("r", encoding="utf-8-sig", newline=None) as fh:
        fh.readline()
        for lineno, line in enumerate(fh, start=2):
            text = line.rstrip("\r\n")
            if text:
                yield lineno, text


def _csv_line_of(path: Path, index: int) -> int | None:
    """Line number of the ``index``-th data row (slow scan, only used to report an error)."""
    for k, (lineno, _) in enumerate(_csv_data_lines(path)):
        if k == index:
            return lineno
    return None


def _locate_csv_error(path: Path, names: list[str], wanted: list[str], reason: str) -> InputError:
    """Find the row and column numpy could not parse (slow scan, error path only)."""
    cols = {c: names.index(c) for c in wanted}
    for lineno, text in _csv_data_lines(path):
        fields = text.split(",")
        if [f.strip().strip('"').strip().lower() for f in fields] == names:
            return InputError(path, "the header line is repeated here (files concatenated?); "
                              "expected a data row of numbers", row=lineno)
        for c, j in cols.items():
            if j >= len(fields):
                return InputError(
                    path, f"row has {len(fields)} fields, the header has {len(names)}",
                    row=lineno, field=c,
                )
            value = fields[j].strip()
            if not is_number(value):
                return InputError(path, f"not a number: {value!r}", row=lineno, field=c)
    return InputError(path, f"cannot parse the CSV body: {reason}")


def _radar_from_columns(
    path: Path, columns: Mapping[str, np.ndarray], row_of: RowOf | None,
    xyz: np.ndarray | None = None,
) -> RadarData:
    """Validate parsed columns (finite, integer frame, non-decreasing t) into RadarData.

    ``row_of(i)`` maps a data index to the file row for error messages (None: no rows).
    ``xyz``: the (n, 3) array whose columns are x, y, z, when the caller has one already.
    """

    def fail(message: str, index: int, column: str) -> InputError:
        if row_of is None:
            return InputError(path, f"{message} (element {index})", field=column)
        return InputError(path, message, row=row_of(index), field=column)

    n = len(columns["t"])
    for c, a in columns.items():
        if len(a) != n:
            raise InputError(path, f"column has {len(a)} values, 't' has {n}", field=c)
    if n == 0:
        raise InputError(path, "no data rows", row=None if row_of is None else 2)
    for c, a in columns.items():
        bad = ~np.isfinite(a)
        if bad.any():
            i = int(np.argmax(bad))
            kind = "NaN" if np.isnan(a[i]) else "infinite value"
            raise fail(f"{kind} ({float(a[i])!r}) is not allowed", i, c)
    for c, a in columns.items():
        limit, hint = PLAUSIBLE_LIMITS.get(c, (np.inf, ""))
        bad = np.abs(a) > limit
        if bad.any():
            i = int(np.argmax(bad))
            raise fail(f"implausible value {float(a[i])!r}: |{c}| must be <= {limit:g} {hint}",
                       i, c)
    frame = None
    if "frame" in columns:
        f = columns["frame"]
        bad = f != np.round(f)
        if bad.any():
            i = int(np.argmax(bad))
            raise fail(f"frame must be an integer, got {float(f[i])!r}", i, "frame")
        frame = f.astype(np.int64)
    t = columns["t"]
    back = np.diff(t) < 0
    if back.any():
        i = int(np.argmax(back)) + 1
        message = f"t goes backwards ({float(t[i])!r} < {float(t[i - 1])!r}); t must not decrease"
        raise fail(message, i, "t")
    return RadarData(
        t=t,
        xyz=np.column_stack([columns["x"], columns["y"], columns["z"]]) if xyz is None else xyz,
        doppler=columns["doppler"],
        rcs=columns.get("rcs"),
        frame=frame,
    )


# --------------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------------
def radar_columns(radar: RadarData) -> dict[str, np.ndarray]:
    """The file columns of ``radar`` in file order (optional ones only when present)."""
    cols = {
        "t": np.asarray(radar.t, dtype=np.float64),
        "x": np.asarray(radar.xyz[:, 0], dtype=np.float64),
        "y": np.asarray(radar.xyz[:, 1], dtype=np.float64),
        "z": np.asarray(radar.xyz[:, 2], dtype=np.float64),
        "doppler": np.asarray(radar.doppler, dtype=np.float64),
    }
    if radar.rcs is not None:
        cols["rcs"] = np.asarray(radar.rcs, dtype=np.float64)
    if radar.frame is not None:
        cols["frame"] = np.asarray(radar.frame, dtype=np.int64)
    return cols


def write_radar(path: str | Path, radar: RadarData) -> None:
    """Write detections atomically; the format follows the suffix (.csv, .npz, .parquet).

    CSV keeps t to 1e-6 s, x/y/z to 1e-4 m, doppler and rcs to 1e-4; NPZ and parquet are
    lossless.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    cols = radar_columns(radar)
    if suffix == ".csv":
        _write_csv(p, cols)
    elif suffix == ".npz":
        with atomic_path(p) as tmp, tmp.open("wb") as fh:
            np.savez(fh, **cols)
    elif suffix == ".parquet":
        pq = _import_parquet(p)
        import pyarrow as pa

        with atomic_path(p) as tmp:
            pq.write_table(pa.table(cols), tmp)
    else:
        raise ValueError(f"unknown radar format {p.suffix!r} (use {', '.join(RADAR_SUFFIXES)})")


def _write_csv(path: Path, cols: dict[str, np.ndarray]) -> None:
    fmt = ",".join(_CSV_FORMATS[c] for c in cols)
    n = len(cols["t"])
    with atomic_path(path) as tmp, tmp.open("w", encoding="utf-8", newline="\n") as fh:
        fh.write(",".join(cols) + "\n")
        for a in range(0, n, _CSV_CHUNK_ROWS):
            rows = zip(*(c[a : a + _CSV_CHUNK_ROWS].tolist() for c in cols.values()))
            fh.write("\n".join(map(fmt.__mod__, rows)))
            fh.write("\n")
