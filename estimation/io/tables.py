"""Numeric CSV tables (kinematics and accelerations CSVs): a header line of column names,
then rows of numbers; parsed by ``numpy.loadtxt``, row by row to name a bad value's line
and column, within the limits of :mod:`bonefit.estimation.io.limits`."""

from __future__ import annotations

import csv
import io
import math
import os
import warnings
from collections.abc import Iterator
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from . import limits

PathLike = str | os.PathLike[str]


def open_csv(path: PathLike) -> io.TextIOWrapper:
    """Text handle of a CSV (UTF-8, BOM dropped, bad bytes as U+FFFD, line ends kept);
    InputError for a directory or an unreadable file."""
    try:
        # undecodable bytes become U+FFFD and then fail as a named column or number
        return open(path, encoding="utf-8-sig", errors="replace", newline="")
    except (IsADirectoryError, PermissionError) as exc:
        raise InputError(f"cannot read {os.fspath(path)}: {exc.strerror}",
                         field="input") from None


def table_header(first: str) -> list[str]:
    """Column names of a header line (stripped), within ``MAX_COLUMNS`` and
    ``MAX_NAME_CHARS``; empty for a blank line."""
    header = [h.strip() for h in next(csv.reader([first]), [])] if first.strip() else []
    limits.check_count("columns", len(header), "MAX_COLUMNS", line=1, field="header")
    for h in header:
        limits.check_count("characters in a column name", len(h), "MAX_NAME_CHARS",
                           line=1, field="header")
    return header


def read_table(path: PathLike) -> tuple[list[str], NDArray[np.float64]]:
    """Header and numeric body of a CSV; a fast parse first, a row-by-row one to name the
    line and column of a bad value. Lines, columns and rows are bounded by
    ``bonefit.estimation.io.limits`` before they are read."""
    with open_csv(path) as handle:
        lines = limits.bounded_lines(handle)
        header = table_header(next(lines, ""))
        if not header:
            raise InputError("empty file: no header line", line=1, field="header")
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error")
                body = np.loadtxt(lines, delimiter=",", dtype=float, ndmin=2,
                                  max_rows=limits.max_rows(len(header)) + 1)
        except (ValueError, UserWarning):
            body = None
    if body is not None and body.shape[0] and body.shape[1] == len(header):
        limits.check_rows(body.shape[0], len(header))
        _check_table(body, header)
        return header, body
    return _read_table_slowly(path)


def _read_table_slowly(path: PathLike) -> tuple[list[str], NDArray[np.float64]]:
    with open_csv(path) as handle:
        lines = limits.bounded_lines(handle)
        header = table_header(next(lines, ""))
        if not header:
            raise InputError("empty file: no header line", line=1, field="header")
        reader = csv.reader(lines)
        rows: list[list[float]] = []
        lineno = 1
        for row in csv_records(reader):
            lineno = reader.line_num + 1
            if not row or all(not c.strip() for c in row):
                continue
            if len(rows) == limits.max_rows(len(header)):
                limits.check_rows(len(rows) + 1, len(header), line=lineno)
            if len(row) != len(header):
                raise InputError(f"row has {len(row)} values, the header has {len(header)}",
                                 line=lineno)
            try:
                rows.append([float(c) if c.strip() not in ("", "NA") else math.nan
                             for c in row])
            except ValueError:
                col = next(i for i, c in enumerate(row) if not _is_number(c))
                raise InputError(f"not a number: {row[col][:40]!r} in column {header[col]!r}",
                                 line=lineno, column=col + 1, field=header[col]) from None
    if not rows:
        raise InputError("no data rows", line=2)
    table = np.array(rows, dtype=float)
    _check_table(table, header)
    return header, table


def csv_records(reader: Any, first_line: int = 2) -> Iterator[list[str]]:
    """The rows of a ``csv.reader``; its errors (a NUL byte, an unclosed quote) as
    InputError naming the line. The reader's first line is line ``first_line`` of the file
    (by default the one after a header read before the reader was made)."""
    while True:
        try:
            row = next(reader)
        except StopIteration:
            return
        except csv.Error as exc:
            line = first_line - 1 + reader.line_num
            raise InputError(f"unreadable CSV at line {line}: {exc}", line=line) from None
        yield row


def _check_table(table: NDArray[np.float64], header: list[str]) -> None:
    """Refuse an infinite or absurdly large value (NaN is reported by the readers as a
    missing value), naming its line and column (rows counted from line 2)."""
    bad = limits.first_bad_value(table)
    if bad is not None:
        row, col = bad
        limits.check_value(float(table[row, col]), line=row + 2, column=col + 1,
                           field=header[col])


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return text.strip() in ("", "NA")
    return True
