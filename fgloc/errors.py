"""Exceptions that carry what a user needs to fix bad input.

The CLI turns every :class:`FglocError` into a one-line message on stderr and exit code 2.
"""

from __future__ import annotations

from pathlib import Path


class FglocError(Exception):
    """Base class of every error fgloc raises on purpose (bad input, failed localization)."""


class InputError(FglocError):
    """Invalid input: names the file, optionally the row or field, and what was expected.

    Rows are 1-based and count the header line as row 1, so ``row=2`` is the first data line.
    """

    def __init__(
        self,
        path: str | Path | None,
        message: str,
        *,
        row: int | None = None,
        field: str | None = None,
    ) -> None:
        self.path = None if path is None else Path(path)
        self.row = row
        self.field = field
        self.detail = message
        where = [str(self.path)] if self.path is not None else []
        if row is not None:
            where.append(f"row {row}")
        if field is not None:
            where.append(f"field '{field}'")
        prefix = ", ".join(where)
        super().__init__(f"{prefix}: {message}" if prefix else message)


class LocalizationError(FglocError):
    """The data are valid but do not support a localization (too few points, no overlap...)."""
