"""ngbet's tables (results.csv, profile.csv): written whole or appended by complete rows, and the one reader."""

from __future__ import annotations

import contextlib
import csv
import io
import os
from pathlib import Path
from typing import Any

__all__ = ["append_lines", "append_rows", "read_profiles", "read_rows", "write_table"]


def write_table(path: Path, columns: list[str], rows: list[dict[str, Any]]) -> None:
    """Write a CSV table with the header ``columns`` and the ``rows`` (dicts by column)."""
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=columns, lineterminator="\n")
        w.writeheader()
        w.writerows(rows)


def append_rows(path: Path, columns: list[str], rows: list[dict[str, Any]]) -> None:
    """Append complete rows in one write (a reader never sees half a row unless the disk fails)."""
    buf = io.StringIO()
    csv.DictWriter(buf, fieldnames=columns, lineterminator="\n").writerows(rows)
    _append(path, buf.getvalue())


def append_lines(path: Path, lines: list[list[Any]]) -> None:
    """Append complete CSV lines (lists of values) in one write."""
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(lines)
    _append(path, buf.getvalue())


def _append(path: Path, text: str) -> None:
    """Append ``text`` whole or not at all: a write the disk cuts short (full, ``ulimit -f``) is taken back.

    Written to the file descriptor until every byte is taken (a buffered file may report a cut
    write as done); on an OSError the file is truncated to its length before, so that no reader
    sees part of a step's rows (a profile block of fewer points), and the error is raised.
    """
    data = text.encode()
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        size = os.fstat(fd).st_size
        try:
            while data:
                data = data[os.write(fd, data) :]
        except OSError:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, size)
            raise
    finally:
        os.close(fd)


def read_rows(path: str | Path) -> list[dict[str, Any]]:
    """Read a results.csv (or any ngbet table) back as a list of dicts: floats, non-numbers kept as strings.

    The one reader of ngbet's tables. An empty cell stays ``""``. A last line without its line end
    is a row cut short (the run was killed while appending it) and is left out.
    """
    text = Path(path).read_text()
    if text and not text.endswith("\n"):
        text = text[: text.rfind("\n") + 1]
    return [{k: _num(v) for k, v in r.items()} for r in csv.DictReader(text.splitlines())]


def _num(v: str) -> Any:
    try:
        return float(v)
    except (TypeError, ValueError):
        return v


def read_profiles(path: str | Path) -> dict[float, tuple[list[float], list[float]]]:
    """The mid-axis profiles of a profile.csv: {u0 [mm]: (X [mm], u_y [mm])}, in the file's order.

    Read through :func:`read_rows`, so a last line cut short is left out.
    """
    out: dict[float, tuple[list[float], list[float]]] = {}
    for r in read_rows(path):
        X, uy = out.setdefault(float(r["u0_mm"]), ([], []))
        X.append(float(r["X_mm"]))
        uy.append(float(r["uy_mm"]))
    return out
