"""Reading JSON documents with errors that name the file and the line."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from fgloc.errors import InputError


def read_json(path: str | Path) -> Any:
    """Parse a UTF-8 JSON file. A missing file, bad encoding or bad syntax is an
    :class:`InputError`; syntax errors carry the line (as ``row``) and column. Values are not
    checked here (NaN literals parse; callers validate fields)."""
    p = Path(path)
    try:
        return json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(p, "file not found") from None
    except UnicodeDecodeError as exc:
        raise InputError(p, f"not UTF-8 text: {exc}") from None
    except json.JSONDecodeError as exc:
        raise InputError(
            p, f"invalid JSON: {exc.msg} (column {exc.colno})", row=exc.lineno
        ) from None
