"""The benches' resumable result files: one JSON object a line, appended as each case finishes.

A rerun reads what is there and skips those cases. A last line cut short (the process killed
while writing it) is not a result: it is dropped, and that case runs again.
"""

from __future__ import annotations

import json
from pathlib import Path


def read_rows(path: Path, key) -> dict:
    """``{key(row): row}`` of the complete lines of ``path`` (empty when there is no file)."""
    rows = {}
    if not path.exists():
        return rows
    lines = path.read_text().splitlines()
    for number, line in enumerate(lines, 1):
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            if number == len(lines):  # a write cut short: that case runs again
                break
            raise SystemExit(f"error: {path}:{number}: not a JSON line; delete the file to start again") from None
        rows[key(row)] = row
    return rows


def append_row(path: Path, row: dict) -> None:
    """Append ``row`` to ``path`` as one line (flushed when the file closes)."""
    with path.open("a") as fh:
        fh.write(json.dumps(row) + "\n")
