"""Labelled point clouds as binary little-endian PLY.

Coordinates are written as ``double`` because UTM northings (~5e6 m) lose decimetres in float32.
Properties: x, y, z (double), label (uchar, codes of :mod:`fgloc.labels`, named in a header
comment), optional lanelet_id (int) and any extra per-point columns (written as double unless
their dtype maps to a PLY integer type).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from fgloc.errors import InputError
from fgloc.labels import NAMES

#: numpy dtype -> PLY type name (little-endian).
_PLY_TYPES: dict[str, str] = {
    "<f8": "double",
    "<f4": "float",
    "|u1": "uchar",
    "|i1": "char",
    "<u2": "ushort",
    "<i2": "short",
    "<u4": "uint",
    "<i4": "int",
}
_NUMPY_TYPES: dict[str, str] = {v: k for k, v in _PLY_TYPES.items()}
_NUMPY_TYPES.update({"float64": "<f8", "float32": "<f4", "uint8": "|u1", "int8": "|i1",
                     "uint16": "<u2", "int16": "<i2", "uint32": "<u4", "int32": "<i4"})


def _column_dtype(values: np.ndarray) -> str:
    """PLY-compatible little-endian dtype string for an extra column."""
    dt = np.asarray(values).dtype
    if dt.kind in "iu" and dt.itemsize <= 4:
        return dt.newbyteorder("<").str
    if dt.kind in "iu":
        return "<i4"
    return "<f8"


def write_labelled_ply(
    path: str | Path,
    xyz_world: np.ndarray,
    label: np.ndarray,
    lanelet_id: np.ndarray | None = None,
    extra: dict[str, np.ndarray] | None = None,
) -> Path:
    """Write points (N, 3) float64 world coordinates with labels to ``path``, atomically.

    The file is written next to ``path`` under a temporary name and moved into place with
    :func:`os.replace`, so readers never see a half-written file. Returns the path.
    """
    xyz = np.asarray(xyz_world, dtype=np.float64)
    n = xyz.shape[0]
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"xyz_world must be (N, 3), got {xyz.shape}")
    cols: list[tuple[str, str, np.ndarray]] = [
        ("x", "<f8", xyz[:, 0]), ("y", "<f8", xyz[:, 1]), ("z", "<f8", xyz[:, 2]),
        ("label", "|u1", np.asarray(label)),
    ]
    if lanelet_id is not None:
        cols.append(("lanelet_id", "<i4", np.asarray(lanelet_id)))
    for name, values in (extra or {}).items():
        cols.append((name, _column_dtype(values), np.asarray(values)))
    for name, _, values in cols:
        if values.shape != (n,):
            raise ValueError(f"column {name!r} has shape {values.shape}, expected ({n},)")
    rec = np.empty(n, dtype=[(name, dt) for name, dt, _ in cols])
    for name, _, values in cols:
        rec[name] = values
    codes = ", ".join(f"{k}={v}" for k, v in sorted(NAMES.items()))
    header = ["ply", "format binary_little_endian 1.0", f"comment fgloc label codes: {codes}",
              f"element vertex {n}"]
    header += [f"property {_PLY_TYPES[dt]} {name}" for name, dt, _ in cols]
    header.append("end_header")
    out = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(("\n".join(header) + "\n").encode("ascii"))
            fh.write(rec.tobytes())
        os.replace(tmp, out)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return out


def read_ply(path: str | Path) -> dict[str, np.ndarray]:
    """Read a binary little-endian PLY vertex element into ``{property: (N,) array}``.

    Supports what :func:`write_labelled_ply` writes (scalar properties, one vertex element).
    """
    p = Path(path)
    with p.open("rb") as fh:
        if fh.readline().strip() != b"ply":
            raise InputError(p, "not a PLY file")
        n, fields = 0, []
        while True:
            line = fh.readline()
            if not line:
                raise InputError(p, "PLY header has no end_header")
            words = line.decode("ascii").split()
            if not words or words[0] == "comment":
                continue
            if words[0] == "format" and words[1] != "binary_little_endian":
                raise InputError(p, f"unsupported PLY format {words[1]}")
            if words[0] == "element":
                if words[1] != "vertex":
                    raise InputError(p, f"unsupported PLY element {words[1]}")
                n = int(words[2])
            elif words[0] == "property":
                if words[1] == "list" or words[1] not in _NUMPY_TYPES:
                    raise InputError(p, f"unsupported PLY property {' '.join(words[1:])}")
                fields.append((words[2], _NUMPY_TYPES[words[1]]))
            elif words[0] == "end_header":
                break
        data = np.frombuffer(fh.read(), dtype=fields, count=n)
    return {name: np.array(data[name]) for name, _ in fields}
