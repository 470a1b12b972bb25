"""The rows of a run on disk: an append-only CSV journal, and atomic writes of everything else.

``rows.csv`` is a journal: each finished case is appended as one line, flushed and fsync'ed before
the next, and never rewritten. A run killed at any instant leaves every finished row intact; at most
the line being written is cut short, and :meth:`RowsJournal.open` drops such a partial last line
before appending again. Every other file of a run directory (``results.csv``, ``run.json``, ...) is
written to a temporary file in the same folder and renamed over the old one (atomic on POSIX), so a
reader sees the old version or the new one, never a mix.

Values are written so that reading them back gives the same numbers: floats as ``repr`` (17
significant digits, ``nan`` for undefined scores), integers as decimal text.
"""

from __future__ import annotations

import csv
import io
import math
import os
import tempfile
import warnings
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from ..errors import AngiohullError, InputWarning

__all__ = ["RowsJournal", "read_rows", "format_value", "parse_value", "rows_to_csv", "write_atomic",
           "INT_COLUMNS", "TEXT_COLUMNS"]

INT_COLUMNS = frozenset({"case_id", "tree_index", "tree_seed", "n_views", "n_points", "count"})
STATUSES = ("ok", "empty", "failed", "error")
"""A case's outcome, the ``status`` column (:func:`angiohull.experiments.cases.run_case`)."""
TEXT_COLUMNS = frozenset({"tortuosity", "views", "view_ids", "corruption", "status", "reason"})


def format_value(value: Any) -> str:
    """Text of one cell: exact floats (``repr``), plain integers, text as is."""
    if value is None:
        return ""
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        number = float(value)
        return "nan" if math.isnan(number) else repr(number)
    return str(value)


def parse_value(column: str, text: str) -> Any:
    """The value of one cell of ``column`` (inverse of :func:`format_value`)."""
    if column in TEXT_COLUMNS:
        return text
    if column in INT_COLUMNS:
        return int(text)
    return float(text) if text != "" else math.nan


def rows_to_csv(columns: Sequence[str], rows: Iterable[dict[str, Any]]) -> str:
    """CSV text of ``rows`` (header first; every row must have exactly ``columns``)."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(columns)
    for row in rows:
        writer.writerow([format_value(row[c]) for c in columns])
    return buffer.getvalue()


def write_atomic(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file in the same folder and a rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, temp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as handle:
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(temp, path)
    except BaseException:
        try:
            os.unlink(temp)
        except OSError:
            pass
        raise
    return path


_DAMAGED = ("the file was changed by hand or is damaged: restore it, or delete that line to run its case again "
            "(rows.csv), or choose a new RUN_DIR")


def _where_bad_byte(data: bytes, offset: int) -> str:
    """``line N, column 'name'`` of the byte at ``offset`` of a CSV file (the header names the columns)."""
    line_start = data.rfind(b"\n", 0, offset) + 1
    line = data[:offset].count(b"\n") + 1
    header = data[: data.find(b"\n")].decode("utf-8", "replace").split(",") if b"\n" in data else []
    index = data[line_start:offset].count(b",")  # quoted commas aside: good enough to point at the cell
    name = f", column {header[index]!r}" if 0 <= index < len(header) and line > 1 else ""
    return f"line {line}{name}"


def read_rows(path: str | Path, columns: Sequence[str] | None = None) -> tuple[list[str], list[dict[str, Any]]]:
    """The header and the complete rows of a rows file (a partial last line is ignored, with a warning).

    Rows with a repeated ``case_id`` keep the first occurrence. With ``columns``, the header must
    equal it (else :class:`~angiohull.errors.AngiohullError`). A last line without its line end, the
    one a run killed while writing it leaves, is left out with an
    :class:`~angiohull.errors.InputWarning` that names it (:meth:`RowsJournal.open` drops it before
    appending again, so resuming the run runs its case again).
    """
    path = Path(path)
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        data = data[: data.rfind(b"\n") + 1]
        line = data.count(b"\n") + 1
        ignored = ("line 1 (the header)", "the file is read as holding no rows") if line == 1 else (
            f"line {line}", "that row is ignored, and resuming the run into this folder runs its case again")
        warnings.warn(f"{path}: {ignored[0]} is cut short (no line end: the run was stopped while writing it, or is "
                      f"writing it now); {ignored[1]}", InputWarning, stacklevel=2)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise AngiohullError(f"{path}: {_where_bad_byte(data, exc.start)} is not UTF-8 text (byte "
                             f"0x{data[exc.start]:02x}); {_DAMAGED}") from None
    try:
        records = list(csv.reader(io.StringIO(text)))
    except csv.Error as exc:
        raise AngiohullError(f"{path}: not a CSV file ({exc}); {_DAMAGED}") from None
    if not records:
        return (list(columns) if columns is not None else []), []
    header = records[0]
    if columns is not None and header != list(columns):
        raise AngiohullError(
            f"{path}: its columns ({', '.join(header)}) differ from this experiment's ({', '.join(columns)}); it was "
            f"written by another configuration or version; use a new run directory")
    rows, seen = [], set()
    for number, record in enumerate(records[1:], start=2):
        if len(record) != len(header):
            raise AngiohullError(f"{path}: line {number} has {len(record)} fields, expected {len(header)} (one per "
                                 f"column of the header); {_DAMAGED}")
        row = {}
        for column, cell in zip(header, record):
            try:
                row[column] = parse_value(column, cell)
            except ValueError:
                kind = "an integer" if column in INT_COLUMNS else "a number (or empty, or nan)"
                raise AngiohullError(f"{path}: line {number}, column {column!r}: {cell!r} is not {kind}; "
                                     f"{_DAMAGED}") from None
        if "status" in row and row["status"] not in STATUSES:
            raise AngiohullError(f"{path}: line {number}, column 'status': {row['status']!r} is not one of "
                                 f"{', '.join(STATUSES)}; {_DAMAGED}")
        if row["case_id"] not in seen:
            seen.add(row["case_id"])
            rows.append(row)
    return header, rows


class RowsJournal:
    """Append-only ``rows.csv``: one fsync'ed line per finished case."""

    def __init__(self, path: str | Path, columns: Sequence[str]):
        self.path = Path(path)
        self.columns = list(columns)
        self._handle = None
        self._writer = None

    def open(self) -> list[dict[str, Any]]:
        """Open for appending; returns the rows already there (after dropping a partial last line)."""
        rows: list[dict[str, Any]] = []
        if self.path.exists() and self.path.stat().st_size > 0:
            data = self.path.read_bytes()
            if not data.endswith(b"\n"):
                keep = data.rfind(b"\n") + 1
                with open(self.path, "r+b") as handle:  # drop the cut-short line of an interrupted write
                    handle.truncate(keep)
                    handle.flush()
                    os.fsync(handle.fileno())
            _, rows = read_rows(self.path, self.columns)
        self._handle = open(self.path, "a", encoding="utf-8", newline="")
        self._writer = csv.writer(self._handle, lineterminator="\n")
        if self._handle.tell() == 0:
            self._write(self.columns)
        return rows

    def _write(self, cells: Sequence[str]) -> None:
        size = os.fstat(self._handle.fileno()).st_size  # everything before is flushed: the end of the file
        try:
            self._writer.writerow(cells)
            self._handle.flush()
            os.fsync(self._handle.fileno())
        except OSError:  # e.g. a full disk: drop what got out of the line, keep every whole row
            handle, self._handle, self._writer = self._handle, None, None
            try:
                handle.close()
            except OSError:
                pass
            try:
                os.truncate(self.path, size)
            except OSError:
                pass
            raise

    def append(self, row: dict[str, Any]) -> None:
        """Write one row (exactly the journal's columns) and make it durable."""
        missing = [c for c in self.columns if c not in row]
        extra = [c for c in row if c not in self.columns]
        if missing or extra:
            raise AngiohullError(f"row of case {row.get('case_id')}: missing columns {missing}, unexpected {extra}")
        self._write([format_value(row[c]) for c in self.columns])

    def close(self) -> None:
        if self._handle is not None:
            self._handle.close()
            self._handle = None

    def __enter__(self) -> "RowsJournal":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
