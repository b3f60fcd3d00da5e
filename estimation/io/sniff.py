"""Sniffing sensor recordings: the format of a file and a quick summary without loading it,
and the row counter the service feeds while it receives an upload."""

from __future__ import annotations

import codecs
import contextlib
import mmap
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

import numpy as np

from ..errors import InputError
from ..vocabulary import KINEMATICS_FORMATS, SENSOR_FORMATS
from . import limits

if TYPE_CHECKING:
    pass

from .sensor_common import PathLike, fps_from_time, open_text, parse_fps
from .sensor_csv import csv_header, csv_rows, parse_csv_header
from .sensor_npz import sniff_npz

ACCELERATIONS_FORMAT: Final[str] = "accelerations-csv"
"""Format name of a CSV of foot accelerations (``time,<Sensor>.ax,.ay,.az,...``)."""

FORMATS: Final[tuple[str, ...]] = SENSOR_FORMATS
"""Recording formats ``read_recording`` understands (besides ``"auto"``)."""


def detect_format(path: PathLike) -> str:
    """Format of a recording file: ``"csv"``, ``"tracker"`` or ``"npz"``.

    By content first (a ZIP archive is NPZ; records whose layout
    :func:`~bonefit.estimation.io.tracker.detect_tracker_layout` recognises are a tracker export; a
    header with ``<segment>.<component>`` columns is CSV), then by
    extension (``.npz``, ``.csv``; ``.txt``/``.dat``/``.asc`` are tracker files).

    Raises
    ------
    InputError
        When neither says what the file is.
    """
    p = Path(path)
    return _format_of_content(_head(p)) or _format_of_extension(p)


def _head(p: Path) -> bytes:
    """The first 64 KiB of the file."""
    try:
        with open(p, "rb") as handle:
            return handle.read(65536)
    except IsADirectoryError:
        raise InputError(f"{p} is a directory, not a recording", field="input") from None
    except PermissionError:
        raise InputError(f"cannot read {p}: permission denied", field="input") from None


def _format_of_content(head: bytes) -> str | None:
    """The format the file's first bytes show (a ZIP archive, a tracker export, a CSV
    header), or None."""
    if head.startswith(b"PK\x03\x04") or head.startswith(b"PK\x05\x06"):
        return "npz"
    text = head.decode("utf-8", errors="replace")
    from .tracker import looks_like_tracker

    if looks_like_tracker(text):
        return "tracker"
    return _format_of_first_row(text)


def _format_of_first_row(text: str) -> str | None:
    """"csv" for a ``<segment>.<component>`` header, "tracker" for a row of 7 or 8 blank
    separated numbers, else None; comments and blank lines are skipped."""
    for raw in text.splitlines():
        line = raw.strip().lstrip("\ufeff")
        if not line or line.startswith("#"):
            continue
        if "." in line and "," in line and any(c.isalpha() for c in line):
            return "csv"
        tokens = line.replace(",", " ").split()
        try:
            [float(t) for t in tokens]
        except ValueError:
            return None
        if "," not in line and len(tokens) in (7, 8):
            return "tracker"
        return None
    return None


FORMAT_OF_EXTENSION: Final[dict[str, str]] = {
    ".npz": "npz", ".csv": "csv", ".txt": "tracker", ".dat": "tracker", ".asc": "tracker",
    ".liberty": "tracker", ".patriot": "tracker"}
"""The format a recording's file extension suggests, when its content does not tell."""


def _format_of_extension(p: Path) -> str:
    """The format of the file's extension; InputError for another one."""
    fmt = FORMAT_OF_EXTENSION.get(p.suffix.lower())
    if fmt is None:
        raise InputError(f"cannot tell the format of {p.name}; give format= csv, tracker or "
                         "npz", field="format")
    return fmt


def resolve_sensor_format(path: PathLike, format: str) -> str:
    """``format`` checked against :data:`FORMATS`, or detected from the file when ``"auto"``."""
    fmt = format.strip().lower()
    if fmt == "auto":
        return detect_format(path)
    if fmt not in FORMATS:
        raise InputError(f"unknown format {format!r}; use auto, {', '.join(FORMATS)}",
                         field="format")
    return fmt


def sniff_recording(path: PathLike, format: str = "auto", *,
                    counted_rows: int | None = None) -> dict[str, Any]:
    """Quick summary of a recording without loading it.

    Parses only the header and the first few time stamps and counts the other lines in large
    binary blocks, so it is cheap on large uploads. It does not validate the data rows.

    Parameters
    ----------
    path : path
    format : {"auto", "csv", "tracker", "npz"}
    counted_rows : int, optional
        The file's rows as a `RowCounter` fed the whole file counted them (a caller that
        received the file in blocks, such as the service, counts while receiving); a CSV is
        then not read past its header and first time stamps.

    Returns
    -------
    dict
        ``format`` (str), ``frames`` (int), ``sensors`` (list of str: segment names; for
        tracker files the station numbers as strings unless the file names them with a
        ``# stations:`` comment), ``fps`` (float or None when the file does not say),
        ``units`` (str or None); for tracker files also ``layout``, the detected
        :class:`~bonefit.estimation.io.tracker.TrackerLayout` spec.

    Raises
    ------
    InputError
        Unreadable header or unknown format.
    """
    fmt = resolve_sensor_format(path, format)
    if fmt == "npz":
        return sniff_npz(path)
    meta: dict[str, str] = {}
    if fmt == "csv":
        return _sniff_csv(path, meta, counted_rows)
    from .tracker import sniff_tracker

    return sniff_tracker(path)


def _sniff_csv(path: PathLike, meta: dict[str, str],
               counted_rows: int | None = None) -> dict[str, Any]:
    with open_text(path) as handle:
        header, header_line = csv_header(csv_rows(handle), meta)
        time_col, sensors, _ = parse_csv_header(header, header_line)
        times: list[float] = []
        frames = 0
        lines = limits.bounded_lines(handle, start=header_line + 1)
        for text in lines:
            if not _sniff_is_row(text):
                continue
            frames += 1
            if time_col is not None and len(times) < 50:
                cells = text.strip().split(",")
                with contextlib.suppress(IndexError, ValueError):
                    times.append(float(cells[time_col]))
            if time_col is None or len(times) >= 50:
                # a header cell with a line break spans lines: count the rest as text then
                one_line = not any("\n" in c or "\r" in c for c in header)
                counted = _sniff_rows_after(path, header_line, counted_rows) if one_line else None
                frames = counted if counted is not None else frames + sum(
                    _sniff_is_row(rest) for rest in lines)
                break
    limits.check_rows(frames, len(header))
    fps: float | None = None
    if "fps" in meta:
        fps = parse_fps(meta["fps"])
    elif len(times) >= 2:
        try:
            fps = fps_from_time(np.asarray(times, dtype=float))
        except InputError:
            fps = None
    return {"format": "csv", "frames": frames, "sensors": sensors, "fps": fps,
            "units": meta.get("units", "m")}


_SNIFF_BLOCK: Final = 1024 * 1024
_SNIFF_PREFIX: Final = 1024 * 1024
# bytes that may start a line that is blank, a comment, or begins with (Unicode) whitespace
_SNIFF_SPECIAL: Final = np.zeros(256, dtype=bool)
_SNIFF_SPECIAL[[9, 10, 11, 12, 13, 28, 29, 30, 31, 32, ord("#")]] = True
_SNIFF_SPECIAL[128:] = True
_SNIFF_SPACE: Final = b" \t\x0b\x0c\x1c\x1d\x1e\x1f"


def _sniff_is_row(text: str) -> bool:
    """Whether a line is a data row (neither blank nor a ``#`` comment)."""
    stripped = text.strip()
    return bool(stripped) and not stripped.startswith("#")


def _sniff_is_row_bytes(line: bytes) -> bool:
    """``_sniff_is_row`` of an undecoded line."""
    return _sniff_is_row(line.decode("utf-8", "replace"))


def _sniff_rows_after(path: PathLike, skip: int, counted_rows: int | None = None) -> int | None:
    """Data rows after the first ``skip`` lines, counted in binary blocks (or taken from
    ``counted_rows``, the rows of the whole file); None when those lines do not fit in the
    first megabyte."""
    with open(path, "rb") as fh:
        prefix = fh.read(_SNIFF_PREFIX)
        lines = prefix.splitlines(keepends=True)  # \n, \r and \r\n, like the text reader
        if len(lines) <= skip:
            return None
        if counted_rows is not None:
            head = RowCounter()
            head.feed(b"".join(lines[:skip]))
            return counted_rows - head.rows
        fh.seek(sum(len(line) for line in lines[:skip]))
        counter = RowCounter()
        # one reused buffer: fresh pages for every block cost more than the counting itself
        buf = bytearray(_SNIFF_BLOCK)
        while n := fh.readinto(buf):
            counter.feed(buf, n)
        return counter.rows


class RowCounter:
    """Counts the data rows of a text file fed to it in blocks of bytes, as they arrive.

    Splits at every \\r and \\n (a \\r\\n then leaves an empty line, which is no row). A
    line whose first byte is ASCII, not whitespace and not ``#`` is a row; only the others
    (blank, comment, leading whitespace, non-ASCII) are decoded and looked at one by one. The
    service feeds it an upload while receiving it, so that the summary needs no second pass.

    Examples
    --------
    >>> counter = RowCounter()
    >>> counter.feed(b"time,a\\n0,1\\n# note\\n\\n1,")
    >>> counter.feed(b"2\\n")
    >>> counter.rows
    3
    """

    def __init__(self) -> None:
        self._rows = 0
        self._carry = b""
        self._is_end = np.empty(0, dtype=bool)
        self._is_cr = np.empty(0, dtype=bool)

    @property
    def rows(self) -> int:
        """Rows so far, the unfinished last line included."""
        return self._rows + (_sniff_is_row_bytes(self._carry) if self._carry else 0)

    def feed(self, block: bytes | bytearray | mmap.mmap, length: int | None = None) -> None:
        """Count the rows that ``block`` (its first ``length`` bytes) completes."""
        n = len(block) if length is None else min(length, len(block))
        if n == 0:
            return
        if self._is_end.size < n:  # reused: fresh pages for every block cost more than counting
            self._is_end = np.empty(n, dtype=bool)
            self._is_cr = np.empty(n, dtype=bool)
        data = np.frombuffer(block, dtype=np.uint8, count=n)
        is_end = self._is_end[:n]
        np.equal(data, 10, out=is_end)
        if block.find(b"\r", 0, n) >= 0:
            np.equal(data, 13, out=self._is_cr[:n])
            np.logical_or(is_end, self._is_cr[:n], out=is_end)
        ends = np.flatnonzero(is_end)
        if ends.size == 0:
            self._carry = _sniff_line_lead(self._carry + bytes(block[:n]))
            return
        self._rows += _sniff_is_row_bytes(self._carry + bytes(block[:ends[0]]))
        starts = ends[:-1] + 1
        nonempty = ends[1:] > starts
        special = _SNIFF_SPECIAL[data[starts]] & nonempty
        self._rows += int(np.count_nonzero(nonempty)) - int(np.count_nonzero(special))
        for i in np.flatnonzero(special).tolist():
            self._rows += _sniff_is_row_bytes(bytes(block[starts[i]:ends[i + 1]]))
        self._carry = _sniff_line_lead(bytes(block[ends[-1] + 1:n]))


def _sniff_line_lead(line: bytes) -> bytes:
    """An unfinished line cut to what decides whether it is a row (its first non-space
    character), so that a huge line does not pile up in memory."""
    if len(line) <= 4096:
        return line
    line = line.lstrip(_SNIFF_SPACE)
    if not line or line[0] < 128:
        return line[:1]
    decoder = codecs.getincrementaldecoder("utf-8")("replace")
    lead = decoder.decode(line).lstrip()
    return lead[0].encode() if lead else decoder.getstate()[0]


def sniff_accelerations(path: PathLike) -> dict[str, Any]:
    """Columns, sensors and rows of an accelerations CSV, reading one bounded line at a
    time; InputError unless the header has a time column and a ``.ax/.ay/.az`` sensor."""
    from .kinematics import acceleration_header, acceleration_sensors

    header: list[str] | None = None
    header_line = 0
    frames = 0
    with open(path, encoding="utf-8-sig", errors="replace", newline="") as fh:
        for line, text in enumerate(limits.bounded_lines(fh), 1):
            stripped = text.strip()
            if not stripped or stripped.startswith("#"):
                continue
            if header is None:
                header, header_line = acceleration_columns(stripped, line), line
                continue
            frames += 1
    if header is None:
        raise InputError("empty file: no header line", line=1, field="header")
    limits.check_rows(frames, len(header))
    names, _ = acceleration_header(header)
    if not any(n.lower() in ("time", "t") for n in names):
        raise InputError("not an accelerations CSV: the header has no time column",
                         line=header_line, field="time")
    sensors = acceleration_sensors(names)
    if not sensors:
        raise InputError("not an accelerations CSV: the header has no <Sensor>.ax,.ay,.az "
                         "columns", line=header_line, field="header")
    return {"format": "accelerations-csv", "frames": frames, "columns": header,
            "sensors": sensors}


def acceleration_columns(line_text: str, line: int) -> list[str]:
    """The column names of an accelerations CSV's header line, their count and length bounded."""
    header = [c.strip() for c in line_text.split(",")]
    limits.check_count("columns", len(header), "MAX_COLUMNS", line=line, field="header")
    if len(header) < 2 or not any(c[:1].isalpha() for c in header):
        raise InputError("expected a header line of column names", line=line, field="header")
    for name in header:
        limits.check_count("characters in a column name", len(name), "MAX_NAME_CHARS",
                           line=line, field="header")
    return header


def sniff_file(path: PathLike, format: str = "auto", *, filename: str | None = None,
               counted_rows: int | None = None) -> tuple[str, dict[str, Any]]:
    """The format of any recording bonefit reads and a quick summary of it.

    Parameters
    ----------
    path : path
    format : str
        ``"auto"``, a sensor format (``"csv"``, ``"tracker"``, ``"npz"``), a kinematics format
        (``"kinematics-csv"``, ``"bvh"``, ``"mvnx"``) or ``"accelerations-csv"``.
    filename : str, optional
        The file's original name: a ``.bvh`` or ``.mvnx`` suffix is read as kinematics.
    counted_rows : int, optional
        As in :func:`sniff_recording`.

    Returns
    -------
    (str, dict)
        The format found (``format`` itself when given) and the summary of
        :func:`sniff_recording`, ``sniff_kinematics`` or :func:`sniff_accelerations`.

    Raises
    ------
    InputError
        The file is not in ``format`` (or, with ``"auto"``, in any: the sensor readers' error).
    """
    from .kinematics import sniff_kinematics

    if format == ACCELERATIONS_FORMAT:
        return format, sniff_accelerations(path)
    if format in SENSOR_FORMATS:
        return format, sniff_recording(path, format, counted_rows=counted_rows)
    if format in KINEMATICS_FORMATS:
        return format, dict(sniff_kinematics(path, format))
    suffix = Path(filename or "").suffix.lower()
    if suffix in (".bvh", ".mvnx"):
        summary = dict(sniff_kinematics(path, "auto"))
        return _kinematics_name(summary, suffix[1:]), summary
    try:
        summary = sniff_recording(path, "auto", counted_rows=counted_rows)
        return str(summary["format"]), summary
    except InputError as first:
        try:
            summary = dict(sniff_kinematics(path, "auto"))
        except InputError:
            raise first from None
        return _kinematics_name(summary, "kinematics-csv"), summary


def _kinematics_name(summary: dict[str, Any], default: str) -> str:
    found = str(summary.get("format"))
    return found if found in KINEMATICS_FORMATS else default
