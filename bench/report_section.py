"""Replace (or append) a generated section of docs/benchmarks.md between the markers
``<!-- BEGIN <name> -->`` and ``<!-- END <name> -->``; written atomically."""

from __future__ import annotations

from pathlib import Path

from fgloc.io.atomic import write_text_atomic


def replace_section(path: str | Path, name: str, body: str) -> None:
    """Put ``body`` between the ``name`` markers of ``path``: replaces the block if present,
    appends it at the end of the file otherwise."""
    p = Path(path)
    begin, end = f"<!-- BEGIN {name} -->", f"<!-- END {name} -->"
    text = p.read_text() if p.exists() else ""
    block = f"{begin}\n{body.strip()}\n{end}"
    if begin in text and end in text:
        head, rest = text.split(begin, 1)
        tail = rest.split(end, 1)[1]
        new = head + block + tail
    else:
        new = text.rstrip("\n") + ("\n\n" if text else "") + block + "\n"
    write_text_atomic(p, new)
