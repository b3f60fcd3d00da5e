"""The bonefit sensor CSV: ``time,<segment>.x,.y,.z,.qw,.qx,.qy,.qz,...`` (reader and
writer; docs/skeleton-io.md)."""

from __future__ import annotations

import csv
import io
import itertools
import math
import os
import threading
import warnings
from collections import deque
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import IO, TYPE_CHECKING, Final

import numpy as np
from numpy.typing import NDArray

from .. import threads
from ..errors import InputError, LimitError
from ..model import SEGMENTS
from ..numtext import decimal_rows, fixed_blocks, write_text_blocks
from ..progress import Progress, no_progress, scaled
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
from .tables import csv_records

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


def csv_rows(handle: IO[str], start: int = 1) -> Iterator[tuple[int, list[str]]]:
    """(line number, cells) of the non-empty rows, metadata comments excluded; a line longer
    than ``MAX_LINE_CHARS`` is refused before it is read whole. The first line of ``handle``
    is line ``start``."""
    reader = csv.reader(limits.bounded_lines(handle, start=start))
    offset = start - 1
    for row in csv_records(reader, first_line=start):
        line = start
        start = offset + reader.line_num + 1
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


CHUNK_CHARS: Final[int] = 1 << 22
"""Characters of the file parsed per block (4 MB: about 28,000 rows of a 15-sensor suit)."""


@dataclass(frozen=True)
class _Table:
    """What the reader knows of the file once it has read the header."""

    header: list[str]
    header_line: int
    time_col: int | None
    sensors: list[str]
    index: NDArray[np.int64]  # (S, 7) columns of each sensor's x, y, z, qw, qx, qy, qz


@dataclass(frozen=True)
class _Rows:
    """Rows of one block: sensor values (n, S, 7), a dropped sample all NaN; times (n,) or
    None; the line of each row (n,)."""

    values: NDArray[np.float64]
    time: NDArray[np.float64] | None
    lines: NDArray[np.int64]


def read_sensor_csv(path: PathLike, *, units: str | None = None,
                    fps: float | None = None,
                    progress: Progress | None = None) -> SensorRecording:
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
    progress : callable, optional
        ``progress(fraction, "reading")`` after each parsed block (up to 0.9: the share of
        the file's bytes read so far) and between the checks of the whole recording after
        them (below 1).

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

    Notes
    -----
    The rows are parsed a block of :data:`CHUNK_CHARS` characters at a time: plain decimals
    by numpy array operations (``numtext.decimal_rows``: the same bits as loadtxt, outside
    the interpreter lock, so two blocks at once on two cores where loadtxt holds the lock;
    per thread from 0.75× to about 3× loadtxt's speed, by machine), other numbers
    (exponents, ``nan``, spaces) by ``numpy.loadtxt`` (a C parser); a block neither can parse
    (a malformed cell, comments, quotes) is read row by row, which names the line and column
    of a fault.
    """
    meta: dict[str, str] = {}
    with open_text(path, newline=None) as handle:
        header, header_line = csv_header(csv_rows(handle), meta)
        time_col, sensors, index = parse_csv_header(header, header_line)
        table = _Table(header, header_line, time_col, sensors, index)
        report = progress or no_progress
        blocks = list(_row_blocks(handle, table, scaled(report, 0.0, 0.9)))
        values, times, lines = _join_blocks(blocks, table)
    report(0.92, "reading")
    units = units if units is not None else meta.get("units", "m")
    positions = values[..., :3] * unit_scale(units)
    quats = normalise_quaternions(values[..., 3:], tuple(sensors), lines)
    del values
    report(0.95, "reading")
    if fps is None and "fps" in meta:
        fps = parse_fps(meta["fps"])
    time, rate = _frame_times(times, lines, fps, time_col)
    rec = SensorRecording(tuple(sensors), positions, quats, rate, time)
    report(0.96, "reading")
    rec = check_recording(rec, units)
    report(0.99, "reading")
    return rec


def _frame_times(times: NDArray[np.float64] | None, lines: NDArray[np.int64],
                 fps: float | None, time_col: int | None) -> tuple[NDArray[np.float64], float]:
    """Frame times (s) and rate (Hz) from the time column (checked: present and increasing)
    or from ``fps``."""
    if times is not None and time_col is not None:
        bad = ~np.isfinite(times)
        if bad.any():
            line = int(lines[int(np.argmax(bad))])
            raise InputError(f"time is missing at line {line}", line=line,
                             column=time_col + 1, field="time")
        steps = np.diff(times)
        if (steps <= 0).any():
            line = int(lines[int(np.argmax(steps <= 0)) + 1])
            raise InputError(f"time does not increase at line {line}", line=line,
                             column=time_col + 1, field="time")
        return times, parse_fps(fps) if fps is not None else fps_from_time(times)
    if fps is not None:
        rate = parse_fps(fps)
        return time_from_fps(lines.size, rate), rate
    raise InputError("no time column: give fps (frame rate, Hz)", field="fps")


def _join_blocks(blocks: list[_Rows], table: _Table
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64] | None, NDArray[np.int64]]:
    """Values (F, S, 7), times (F,) or None and lines (F,) of all rows (``blocks`` is
    emptied, so that the blocks' copies go once joined); InputError when there are none."""
    if not blocks:
        raise InputError("the recording has no frames", field="frames",
                         line=table.header_line + 1)
    values = np.concatenate([b.values for b in blocks])
    times = None if table.time_col is None else np.concatenate(
        [b.time for b in blocks if b.time is not None])
    lines = np.concatenate([b.lines for b in blocks])
    blocks.clear()
    return values, times, lines


def _row_blocks(handle: io.TextIOWrapper, table: _Table, report: Progress) -> Iterator[_Rows]:
    """The rows after the header, a block of whole lines at a time, checked (cell count,
    numbers, magnitudes, row limit) and laid out by sensor; ``report`` gets the share of the
    file read after each block."""
    size = _file_size(handle)
    n_cols = len(table.header)
    max_rows = limits.max_rows(n_cols)
    count = 0
    for cells, lines in _parsed_blocks(_line_blocks(handle, table.header_line + 1),
                                       table.header):
        if count + lines.size > max_rows:
            limits.check_rows(max_rows + 1, n_cols, line=int(lines[max_rows - count]))
        count += lines.size
        if lines.size:
            yield _by_sensor(cells, lines, table)
        if size:
            # the file's position (a block's read-ahead at most ahead of the parse)
            report(min(os.lseek(handle.fileno(), 0, os.SEEK_CUR) / size, 1.0), "reading")


def _parsed_blocks(blocks: Iterator[tuple[int, str]], header: list[str]
                   ) -> Iterator[tuple[NDArray[np.float64], NDArray[np.int64]]]:
    """``_parse_block`` of each of ``blocks`` (first line, text), in order, what it raises
    raised in turn. On ``threads.workers()`` threads: numpy's parse of a block runs outside
    the interpreter lock, so on two cores two blocks are parsed at once while this thread
    reads the next; at most one block more than the threads is read ahead."""
    n_threads = threads.workers()
    if n_threads == 1:
        yield from (_parse_block(text, first, header) for first, text in blocks)
        return
    ahead: deque[Future[tuple[NDArray[np.float64], NDArray[np.int64]]]] = deque()
    with ThreadPoolExecutor(n_threads, thread_name_prefix="bonefit-read") as pool:
        try:
            for first, text in blocks:
                ahead.append(pool.submit(_parse_block, text, first, header))
                if len(ahead) > n_threads:
                    yield ahead.popleft().result()
            while ahead:
                yield ahead.popleft().result()
        finally:  # a caller that stops early (a limit, an error) leaves nothing running
            for future in ahead:
                future.cancel()


def _file_size(handle: io.TextIOWrapper) -> int:
    """Bytes of the file behind ``handle``; 0 when it has none (a stream)."""
    try:
        return os.fstat(handle.fileno()).st_size
    except (OSError, io.UnsupportedOperation):
        return 0


def _line_blocks(handle: IO[str], first: int) -> Iterator[tuple[int, str]]:
    """(number of its first line, text) of consecutive blocks of whole lines of about
    :data:`CHUNK_CHARS` characters; a line longer than ``MAX_LINE_CHARS`` is refused before
    it is read whole."""
    carry = ""
    while chunk := handle.read(CHUNK_CHARS):
        text = carry + chunk
        cut = text.rfind("\n") + 1
        carry = text[cut:]
        if len(carry) > limits.MAX_LINE_CHARS:
            line = first + text.count("\n", 0, cut)
            raise LimitError(f"line {line} is longer than {limits.MAX_LINE_CHARS} characters "
                             "(MAX_LINE_CHARS)", limit="MAX_LINE_CHARS", line=line)
        if cut:
            yield first, text[:cut]
            first += text.count("\n", 0, cut)
    if carry:
        yield first, carry + "\n"


def _parse_block(text: str, first: int, header: list[str]
                 ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Cells (n, C) and line numbers (n,) of the data rows of ``text``, whose first line is
    ``first``: by ``numtext.decimal_rows`` when every line is a row of plain decimals (the
    common case), else by ``numpy.loadtxt`` when every line is a row of numbers (a second
    try with empty cells written ``nan`` when there are some), else row by row (naming the
    line and column of a fault). Both fast parsers give the same bits; loadtxt refuses a
    comment, a quote or a malformed cell and skips a blank line (one row short): either
    sends the block to the row-by-row parse."""
    cells = _decimal_rows(text, len(header))
    if cells is not None:
        return cells, np.arange(first, first + cells.shape[0], dtype=np.int64)
    n_lines = text.count("\n")
    cells = _loadtxt(text)
    if cells is None and (",," in text or ",\n" in text or "\n," in text
                          or text.startswith(",")):
        cells = _loadtxt(_empty_cells_as_nan(text))
    if cells is not None and cells.shape == (n_lines, len(header)):
        return cells, np.arange(first, first + n_lines, dtype=np.int64)
    return _parse_rows(text, first, header)


def _decimal_rows(text: str, n_cols: int) -> NDArray[np.float64] | None:
    """``numtext.decimal_rows`` of ``text``; None when it is not ASCII or not plain
    decimals."""
    try:
        data = text.encode("ascii")
    except UnicodeEncodeError:
        return None
    return decimal_rows(data, n_cols)


_WARNINGS_LOCK: Final = threading.Lock()


def _loadtxt(text: str) -> NDArray[np.float64] | None:
    """``numpy.loadtxt`` of comma-separated numbers (n, C); None where it refuses the text
    (an empty cell among them: a block without dropped samples, the common case, is parsed
    in one pass, and only the others are rewritten with ``nan``)."""
    try:
        # the filters are global: one block's at a time (``_parsed_blocks``' threads)
        with _WARNINGS_LOCK, warnings.catch_warnings():
            warnings.simplefilter("error")
            cells: NDArray[np.float64] = np.loadtxt(io.StringIO(text), delimiter=",",
                                                    dtype=float, ndmin=2, comments=None,
                                                    quotechar=None)
    except (ValueError, UserWarning):
        return None
    return cells


def _empty_cells_as_nan(text: str) -> str:
    """``text`` with every empty cell (a dropped sample) written ``nan``."""
    # a run of empty cells needs two passes: ",,," → ",nan,," → ",nan,nan,"
    text = text.replace(",,", ",nan,").replace(",,", ",nan,")
    text = text.replace(",\n", ",nan\n").replace("\n,", "\nnan,")
    return "nan" + text if text.startswith(",") else text


def _parse_rows(text: str, first: int, header: list[str]
                ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The data rows of ``text`` one by one (comments and blank lines skipped); InputError
    naming the line (and column) of a row of the wrong length or a malformed number."""
    rows = csv_rows(io.StringIO(text), start=first)
    data: list[list[float]] = []
    lines: list[int] = []
    for line, row in rows:
        if row[0].lstrip().startswith("#"):
            continue
        if len(row) != len(header):
            raise InputError(f"line {line} has {len(row)} cells, the header has {len(header)}",
                             line=line, column=min(len(row), len(header)) + 1)
        try:
            data.append([_cell(c) for c in row])
        except ValueError:
            col = next(i for i, c in enumerate(row) if not _is_number(c))
            name = header[col].strip()
            raise InputError(f"malformed number {_short(row[col].strip())} at line {line}, "
                             f"column {col + 1} ({name})", line=line, column=col + 1,
                             field=name) from None
        lines.append(line)
    return (np.asarray(data, dtype=float).reshape(len(data), len(header)),
            np.asarray(lines, dtype=np.int64))


def _is_number(cell: str) -> bool:
    try:
        _cell(cell)
    except ValueError:
        return False
    return True


def _by_sensor(cells: NDArray[np.float64], lines: NDArray[np.int64], table: _Table) -> _Rows:
    """Checked cells (no infinite or absurd value) laid out as (n, S, 7), a sample with any
    non-finite value all NaN, and the time column."""
    _check_cells(cells, lines, table.header)
    values = cells[:, table.index]
    values[~np.isfinite(values).all(axis=-1)] = np.nan
    time = None if table.time_col is None else cells[:, table.time_col].copy()
    return _Rows(values, time, lines)


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
    head = f"# units: {units}\n" + ",".join(header) + "\n"
    write_text_blocks(itertools.chain([head], fixed_blocks(table, decimals, nan="")), path)


