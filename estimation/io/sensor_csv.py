"""The bonefit sensor CSV: ``time,<segment>.x,.y,.z,.qw,.qx,.qy,.qz,...`` (reader and
writer; docs/skeleton-io.md)."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Final

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..model import SEGMENTS
from ..recording import SensorRecording
from . import limits

if TYPE_CHECKING:
    pass

from .sensor_common import (
    PathLike,
    check_recording,
    fps_from_time,
    metadata_comment,
    normalise_quaternions,
    open_text,
    parse_fps,
    time_from_fps,
    unit_scale,
)

COMPONENTS: Final[tuple[str, ...]] = ("x", "y", "z", "qw", "qx", "qy", "qz")
"""Per-sensor columns of the sensor CSV, in the order they are stored."""



def parse_csv_header(header: list[str], line: int) -> tuple[int | None, list[str],
                                                              NDArray[np.int64]]:
    """Time column, sensor names and (S, 7) column indices of a sensor-CSV header."""
    limits.check_count("columns", len(header), "MAX_COLUMNS", line=line, field="header")
    time_col: int | None = None
    seen: dict[str, int] = {}
    columns: dict[str, dict[str, int]] = {}
    for col, raw in enumerate(header):
        name = raw.strip().lower()
        if name in seen:
            raise InputError(f"column {raw.strip()!r} appears twice (columns {seen[name] + 1} "
                             f"and {col + 1})", line=line, column=col + 1, field=raw.strip())
        seen[name] = col
        if name in ("time", "t", "time_s"):
            time_col = col
            continue
        segment, dot, comp = name.rpartition(".")
        if not dot or segment not in SEGMENTS or comp not in COMPONENTS:
            why = (f"unknown segment {segment!r}" if dot and comp in COMPONENTS
                   else "expected time or <segment>.<x|y|z|qw|qx|qy|qz>")
            raise InputError(f"unknown column {_short(raw.strip())} (column {col + 1}): {why}",
                             line=line, column=col + 1, field=raw.strip())
        columns.setdefault(segment, {})[comp] = col
    if not columns:
        raise InputError("the header names no sensor columns", line=line, field="header")
    sensors = list(columns)
    index = np.empty((len(sensors), len(COMPONENTS)), dtype=np.int64)
    for s, segment in enumerate(sensors):
        missing = [c for c in COMPONENTS if c not in columns[segment]]
        if missing:
            cols = ", ".join(f"{segment}.{c}" for c in missing)
            raise InputError(f"sensor {segment!r} lacks column(s) {cols}", sensor=segment,
                             line=line, field=f"{segment}.{missing[0]}")
        index[s] = [columns[segment][c] for c in COMPONENTS]
    return time_col, sensors, index


def csv_header(rows: Iterator[tuple[int, list[str]]],
                meta: dict[str, str]) -> tuple[list[str], int]:
    """The header row and its line, after leading ``# key: value`` comments (into ``meta``)."""
    for line, row in rows:
        if row[0].lstrip().startswith("#"):
            found = metadata_comment(",".join(row))
            if found:
                meta[found[0]] = found[1]
            continue
        return row, line
    raise InputError("the file is empty: no header line", line=1, field="header")


def csv_rows(handle: io.TextIOWrapper) -> Iterator[tuple[int, list[str]]]:
    """(line number, cells) of the non-empty rows, metadata comments excluded; a line longer
    than ``MAX_LINE_CHARS`` is refused before it is read whole."""
    reader = csv.reader(limits.bounded_lines(handle))
    start = 1
    while True:
        try:
            row = next(reader)
        except StopIteration:
            return
        except csv.Error as exc:
            raise InputError(f"unreadable CSV at line {reader.line_num}: {exc}",
                             line=reader.line_num) from None
        line = start
        start = reader.line_num + 1
        if not row or (len(row) == 1 and not row[0].strip()):
            continue
        yield line, row


def _short(text: str, limit: int = 40) -> str:
    """``repr`` of a file snippet, cut so that binary junk cannot flood an error line."""
    return repr(text if len(text) <= limit else text[:limit] + "…")


def _cell(text: str) -> float:
    text = text.strip()
    if not text:
        return math.nan
    return float(text)


def read_sensor_csv(path: PathLike, *, units: str | None = None,  # noqa: C901, PLR0912, PLR0915
                    fps: float | None = None) -> SensorRecording:
    """Read a bonefit sensor CSV.

    Parameters
    ----------
    path : path
        Text file whose header is ``time,<segment>.x,<segment>.y,<segment>.z,<segment>.qw,
        <segment>.qx,<segment>.qy,<segment>.qz,...`` for any subset of the 15 segments, in any
        column order. Lines starting with ``#`` are comments; ``# units: mm`` and ``# fps: 60``
        before the header set defaults for the parameters below.
    units : {"m", "cm", "mm", "in"}, optional
        Units of the positions (default metres).
    fps : float, optional
        Frame rate, Hz. Required if there is no ``time`` column; otherwise overrides the rate
        measured from the median time step.

    Returns
    -------
    SensorRecording
        Sensors in header order. A sample (one sensor, one frame) with an empty or NaN cell is
        dropped: all seven of its values become NaN.

    Raises
    ------
    InputError
        Unknown or duplicate column, missing component, malformed number (with line and
        column), time missing or not increasing, non-unit quaternion, all-NaN sensor, positions
        whose size does not fit ``units``.
    """
    meta: dict[str, str] = {}
    with open_text(path) as handle:
        rows = csv_rows(handle)
        header, header_line = csv_header(rows, meta)
        time_col, sensors, index = parse_csv_header(header, header_line)
        n_cols = len(header)
        max_rows = limits.max_rows(n_cols)
        data: list[list[float]] = []
        lines: list[int] = []
        for line, row in rows:
            if row[0].lstrip().startswith("#"):
                continue
            if len(data) == max_rows:
                limits.check_rows(len(data) + 1, n_cols, line=line)
            if len(row) != n_cols:
                raise InputError(f"line {line} has {len(row)} cells, the header has {n_cols}",
                                 line=line, column=min(len(row), n_cols) + 1)
            try:
                try:
                    data.append(list(map(float, row)))
                except ValueError:  # empty cells (dropped samples) or a bad number
                    data.append([_cell(c) for c in row])
            except ValueError:
                for col, cell in enumerate(row):
                    try:
                        _cell(cell)
                    except ValueError:
                        name = header[col].strip()
                        raise InputError(f"malformed number {_short(cell.strip())} at line {line}, "
                                         f"column {col + 1} ({name})", line=line,
                                         column=col + 1, field=name) from None
                raise
            lines.append(line)
    if not data:
        raise InputError("the recording has no frames", field="frames", line=header_line + 1)
    units = units if units is not None else meta.get("units", "m")
    scale = unit_scale(units)
    table = np.asarray(data, dtype=float)
    line_arr = np.asarray(lines, dtype=np.int64)
    _check_cells(table, line_arr, header)
    values = table[:, index]  # (F, S, 7)
    values[~np.isfinite(values).all(axis=-1)] = np.nan
    positions = values[..., :3] * scale
    quats = normalise_quaternions(values[..., 3:], tuple(sensors), line_arr)

    if fps is None and "fps" in meta:
        fps = parse_fps(meta["fps"])
    if time_col is not None:
        time = table[:, time_col]
        bad = ~np.isfinite(time)
        if bad.any():
            i = int(np.argmax(bad))
            raise InputError(f"time is missing at line {lines[i]}", line=lines[i],
                             column=time_col + 1, field="time")
        steps = np.diff(time)
        if (steps <= 0).any():
            i = int(np.argmax(steps <= 0)) + 1
            raise InputError(f"time does not increase at line {lines[i]}", line=lines[i],
                             column=time_col + 1, field="time")
        rate = parse_fps(fps) if fps is not None else fps_from_time(time)
    elif fps is not None:
        rate = parse_fps(fps)
        time = time_from_fps(len(data), rate)
    else:
        raise InputError("no time column: give fps (frame rate, Hz)", field="fps")
    rec = SensorRecording(tuple(sensors), positions, quats, rate, np.asarray(time, dtype=float))
    return check_recording(rec, units)


def _check_cells(table: NDArray[np.float64], lines: NDArray[np.int64],
                 header: list[str]) -> None:
    """Refuse an infinite or absurdly large cell (NaN is a dropped sample), naming its line
    and column."""
    bad = limits.first_bad_value(table)
    if bad is not None:
        row, col = bad
        limits.check_value(float(table[row, col]), line=int(lines[row]), column=col + 1,
                           field=header[col].strip())


def write_sensor_csv(recording: SensorRecording, path: PathLike, *, units: str = "m",
                     decimals: int = 6) -> None:
    """Write ``recording`` as a bonefit sensor CSV (dropped samples as empty cells).

    Parameters
    ----------
    recording : SensorRecording
    path : path
    units : {"m", "cm", "mm", "in"}
        Units of the written positions; recorded in a ``# units:`` comment.
    decimals : int
        Decimal places of positions (in ``units``) and quaternion components.
    """
    scale = unit_scale(units)
    header = ["time"] + [f"{s}.{c}" for s in recording.sensors for c in COMPONENTS]
    values = np.concatenate([recording.positions / scale, recording.quaternions], axis=-1)
    table = np.concatenate([recording.time[:, None],
                            values.reshape(recording.n_frames, -1)], axis=1)
    out = io.StringIO()
    out.write(f"# units: {units}\n")
    out.write(",".join(header) + "\n")
    fmt = f"{{:.{decimals}f}}"
    for row in table:
        out.write(",".join("" if not math.isfinite(v) else fmt.format(v) for v in row) + "\n")
    Path(path).write_text(out.getvalue(), encoding="utf-8")


