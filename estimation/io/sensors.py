"""Readers of 6-DOF sensor recordings: bonefit sensor CSV, tracker ASCII and NPZ.

Tracker exports are read by :mod:`estimation.io.tracker`, which shares the public helpers
here (``open_text``, ``check_recording`` ...).

Every reader returns a :class:`~estimation.recording.SensorRecording` in metres with unit
scalar-first quaternions (sensor → source frame) and NaN for dropped samples, and raises
:class:`~estimation.errors.InputError` naming the line, column, field or sensor at fault.
The formats are described in ``docs/skeleton-io.md``.
"""

from __future__ import annotations

import codecs
import contextlib
import csv
import io
import math
import mmap
import os
import zipfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..model import SEGMENTS
from ..recording import SensorRecording
from ..vocabulary import SENSOR_FORMATS
from . import limits

if TYPE_CHECKING:
    from .tracker import TrackerLayout

PathLike = str | os.PathLike[str]

UNITS: Final[dict[str, float]] = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
"""Length units accepted by the readers and their size in metres."""

FORMATS: Final[tuple[str, ...]] = SENSOR_FORMATS
"""Recording formats ``read_recording`` understands (besides ``"auto"``)."""

COMPONENTS: Final[tuple[str, ...]] = ("x", "y", "z", "qw", "qx", "qy", "qz")
"""Per-sensor columns of the sensor CSV, in the order they are stored."""

QUATERNION_TOLERANCE: Final[float] = 0.05
"""A quaternion whose norm differs from 1 by more than this is rejected as not a rotation
(wrong column order, angles in quaternion columns); closer ones are normalised."""

MAX_BODY_EXTENT_M: Final[float] = 20.0
"""Median per-frame spread of the sensors above which positions cannot be in the declared
units (a body spans about 2 m; millimetres read as metres give about 1700)."""

MIN_BODY_EXTENT_M: Final[float] = 0.02
"""Median per-frame spread (with three sensors or more) below which positions cannot be in
the declared units (metres read as millimetres)."""

_EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def example_path(name: str = "walk.csv") -> Path:
    """Path of a bundled example recording.

    Parameters
    ----------
    name : str
        File name inside ``estimation/examples`` (default the 15-sensor walk).

    Returns
    -------
    Path
    """
    path = _EXAMPLES / name
    if not path.is_file():
        raise InputError(f"no bundled example {name!r}", field="example")
    return path


def unit_scale(units: str) -> float:
    """Metres per file unit for ``units`` (``m``, ``cm``, ``mm`` or ``in``)."""
    key = units.strip().lower()
    if key not in UNITS:
        raise InputError(f"unknown units {units!r}; use one of {', '.join(UNITS)}",
                         field="units")
    return UNITS[key]


# --------------------------------------------------------------------------- helpers


def open_text(path: PathLike) -> io.TextIOWrapper:
    """Text handle of a recording (UTF-8, BOM dropped, bad bytes as U+FFFD); InputError for a
    directory or an unreadable file."""
    try:
        # undecodable bytes become U+FFFD and then fail as a named column or number
        return open(path, encoding="utf-8-sig", errors="replace", newline="")
    except IsADirectoryError:
        raise InputError(f"{os.fspath(path)} is a directory, not a recording",
                         field="input") from None
    except PermissionError:
        raise InputError(f"cannot read {os.fspath(path)}: permission denied",
                         field="input") from None


def metadata_comment(line: str) -> tuple[str, str] | None:
    """``# key: value`` comment → (key, value); None for other comments."""
    body = line.lstrip("#").strip()
    key, sep, value = body.partition(":")
    if not sep:
        key, sep, value = body.partition("=")
    if not sep:
        return None
    key = key.strip().lower()
    if key in ("units", "fps", "stations"):
        return key, value.strip()
    return None


def parse_fps(value: Any, field: str = "fps") -> float:
    """A positive finite frame rate (Hz) from ``value``; InputError naming ``field``."""
    try:
        fps = float(value)
    except (TypeError, ValueError):
        raise InputError(f"fps must be a number, got {value!r}", field=field) from None
    if not (math.isfinite(fps) and fps > 0):
        raise InputError(f"fps must be positive, got {value!r}", field=field)
    return limits.check_fps(fps, field=field)


def normalise_quaternions(quats: NDArray[np.float64], sensors: tuple[str, ...],
                           lines: NDArray[np.int64] | None) -> NDArray[np.float64]:
    """Unit quaternions; InputError naming the sample whose norm is far from 1."""
    norm = np.linalg.norm(quats, axis=-1)
    bad = np.isfinite(norm) & (np.abs(norm - 1.0) > QUATERNION_TOLERANCE)
    if bad.any():
        frame, s = (int(i) for i in np.argwhere(bad)[0])
        where = f"line {int(lines[frame])}" if lines is not None else f"frame {frame}"
        raise InputError(
            f"quaternion of sensor {sensors[s]!r} at {where} has norm {norm[frame, s]:.4g}, "
            f"not 1 (expected scalar-first w, x, y, z)",
            sensor=sensors[s], line=int(lines[frame]) if lines is not None else None)
    with np.errstate(invalid="ignore"):
        return np.asarray(quats / norm[..., None], dtype=float)


def check_recording(rec: SensorRecording, units: str) -> SensorRecording:
    """All-NaN sensors and positions whose size does not fit the declared units."""
    valid = rec.valid()
    for s, name in enumerate(rec.sensors):
        if not valid[:, s].any():
            raise InputError(f"sensor {name!r} has no valid sample (all values missing)",
                             sensor=name)
    if rec.n_frames == 0:
        raise InputError("the recording has no frames", field="frames")
    pos = np.where(valid[..., None], rec.positions, np.nan)
    counts = valid.sum(axis=1)
    rows = counts >= 2
    if rows.any():
        with np.errstate(invalid="ignore"):
            extent = np.linalg.norm(np.nanmax(pos[rows], axis=1) - np.nanmin(pos[rows], axis=1),
                                    axis=-1)
        spread = float(np.median(extent))
        if spread > MAX_BODY_EXTENT_M:
            raise InputError(
                f"sensors are {spread:.3g} m apart if positions are in {units}: a body is about "
                f"2 m; give the file's units (units=mm/cm/in, --units)", field="units")
        if np.median(counts[rows]) >= 3 and spread < MIN_BODY_EXTENT_M:
            raise InputError(
                f"sensors are only {spread * 1000:.3g} mm apart if positions are in {units}; "
                f"give the file's units (units=m/cm, --units)", field="units")
    return rec


def time_from_fps(n_frames: int, fps: float) -> NDArray[np.float64]:
    """Frame times (F,), seconds, from 0 at ``fps``."""
    return np.arange(n_frames, dtype=float) / fps


def fps_from_time(time: NDArray[np.float64], line: int | None = None) -> float:
    """Frame rate (Hz) of increasing frame times (F,) in seconds; InputError otherwise."""
    if time.size < 2:
        raise InputError("one frame only: give fps to set the frame rate", field="fps")
    steps = np.diff(time)
    step = float(np.median(steps))
    if not step > 0:
        raise InputError("time does not increase; give fps instead", field="time", line=line)
    if np.all(np.abs(steps - step) <= 0.05 * step):
        # regular sampling: the overall span is immune to the rounding of single stamps
        rate = float((time.size - 1) / (time[-1] - time[0]))
        # stamps printed to a few decimals: snap to the whole rate they were made from
        rate = float(round(rate)) if abs(rate - round(rate)) < 1e-4 * rate else rate
        return limits.check_fps(rate, field="time", line=line)
    return limits.check_fps(1.0 / step, field="time", line=line)


# --------------------------------------------------------------------------- CSV


def _parse_csv_header(header: list[str], line: int) -> tuple[int | None, list[str],
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


def _csv_header(rows: Iterator[tuple[int, list[str]]],
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


def _csv_rows(handle: io.TextIOWrapper) -> Iterator[tuple[int, list[str]]]:
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


def read_sensor_csv(path: PathLike, *, units: str | None = None,
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
        rows = _csv_rows(handle)
        header, header_line = _csv_header(rows, meta)
        time_col, sensors, index = _parse_csv_header(header, header_line)
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


# --------------------------------------------------------------------------- NPZ


def read_sensor_npz(path: PathLike, *, units: str | None = None,
                    fps: float | None = None) -> SensorRecording:
    """Read a recording saved with ``numpy.savez``.

    Parameters
    ----------
    path : path
        Archive with ``positions`` (F, S, 3), ``quaternions`` (F, S, 4) scalar-first,
        ``sensors`` (S,) strings and ``fps`` (scalar); optionally ``time`` (F,) seconds and
        ``units`` (string). Loaded with ``allow_pickle=False``: object arrays are refused.
    units : {"m", "cm", "mm", "in"}, optional
        Overrides the archive's ``units`` (default metres).
    fps : float, optional
        Overrides the archive's ``fps``.

    Returns
    -------
    SensorRecording

    Raises
    ------
    InputError
        Missing array, wrong shape, unknown sensor name, non-unit quaternion, all-NaN sensor.
    """
    with limits.open_npz(path) as archive:
        _npz_frames(archive)
        positions = _npz_floats(archive, "positions")
        quats = _npz_floats(archive, "quaternions")
        sensors = tuple(_npz_sensor_names(_npz_small(archive, "sensors", "US")))
        names = set(archive.namelist())
        if fps is None:
            if "fps.npy" not in names:
                raise InputError("NPZ archive lacks the array 'fps' (or give fps)", field="fps")
            fps = _npz_scalar(_npz_small(archive, "fps", "biuf"), "fps")
        time = _npz_floats(archive, "time") if "time.npy" in names else None
        if units is None and "units.npy" in names:
            units = _npz_units(_npz_small(archive, "units", "US"))
    for name in sensors:
        if name not in SEGMENTS:
            raise InputError(f"unknown sensor {name!r}; segments are {', '.join(SEGMENTS)}",
                             sensor=name, field="sensors")
    if positions.ndim != 3 or positions.shape[-1] != 3:
        raise InputError(f"positions must have shape (F, S, 3), got {positions.shape}",
                         field="positions")
    if quats.shape != (*positions.shape[:2], 4):
        raise InputError(f"quaternions must have shape {(*positions.shape[:2], 4)}, "
                         f"got {quats.shape}", field="quaternions")
    units = units or "m"
    rate = parse_fps(fps)
    for key, array in (("positions", positions), ("quaternions", quats)):
        bad = limits.first_bad_value(array)
        if bad is not None:
            limits.check_value(float(array[bad]), field=key, sensor=sensors[bad[1]]
                               if len(bad) > 1 and bad[1] < len(sensors) else None)
    if time is not None:
        if time.shape != positions.shape[:1]:
            raise InputError(f"time must have shape {positions.shape[:1]}, got {time.shape}",
                             field="time")
        bad = limits.first_bad_value(time, nan_ok=False)
        if bad is not None:
            limits.check_value(float(time[bad]), field="time", nan_ok=False)
    values = np.concatenate([positions * unit_scale(units), quats], axis=-1)
    values[~np.isfinite(values).all(axis=-1)] = np.nan
    quats_n = normalise_quaternions(values[..., 3:], sensors, None)
    if time is None:
        time = time_from_fps(positions.shape[0], rate)
    rec = SensorRecording(sensors, values[..., :3], quats_n, rate, time)
    return check_recording(rec, units)


def _npz_floats(archive: zipfile.ZipFile, key: str) -> NDArray[np.float64]:
    """A numeric member as float64, after its declared shape and size are checked."""
    return np.asarray(limits.load_npy(archive, key), dtype=np.float64)


def write_sensor_npz(recording: SensorRecording, path: PathLike) -> None:
    """Save ``recording`` as an NPZ archive readable by :func:`read_sensor_npz` (metres)."""
    np.savez_compressed(path, positions=recording.positions,
                        quaternions=recording.quaternions,
                        sensors=np.array(recording.sensors, dtype=str),
                        fps=np.float64(recording.fps), time=recording.time,
                        units=np.str_("m"))


# --------------------------------------------------------------------------- dispatch


def detect_format(path: PathLike) -> str:
    """Format of a recording file: ``"csv"``, ``"tracker"`` or ``"npz"``.

    By content first (a ZIP archive is NPZ; records whose layout
    :func:`~estimation.io.tracker.detect_tracker_layout` recognises are a tracker export; a
    header with ``<segment>.<component>`` columns is CSV), then by
    extension (``.npz``, ``.csv``; ``.txt``/``.dat``/``.asc`` are tracker files).

    Raises
    ------
    InputError
        When neither says what the file is.
    """
    p = Path(path)
    try:
        with open(p, "rb") as handle:
            head = handle.read(65536)
    except IsADirectoryError:
        raise InputError(f"{p} is a directory, not a recording", field="input") from None
    except PermissionError:
        raise InputError(f"cannot read {p}: permission denied", field="input") from None
    if head.startswith(b"PK\x03\x04") or head.startswith(b"PK\x05\x06"):
        return "npz"
    text = head.decode("utf-8", errors="replace")
    from .tracker import looks_like_tracker

    if looks_like_tracker(text):
        return "tracker"
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
            break
        if "," not in line and len(tokens) in (7, 8):
            return "tracker"
        break
    ext = p.suffix.lower()
    if ext == ".npz":
        return "npz"
    if ext == ".csv":
        return "csv"
    if ext in (".txt", ".dat", ".asc", ".liberty", ".patriot"):
        return "tracker"
    raise InputError(f"cannot tell the format of {p.name}; give format= csv, tracker or npz",
                     field="format")


def _sensor_format(path: PathLike, format: str) -> str:
    fmt = format.strip().lower()
    if fmt == "auto":
        return detect_format(path)
    if fmt not in FORMATS:
        raise InputError(f"unknown format {format!r}; use auto, {', '.join(FORMATS)}",
                         field="format")
    return fmt


def read_recording(path: PathLike, *, format: str = "auto", units: str | None = None,
                   fps: float | None = None,
                   stations: Mapping[Any, Any] | str | None = None,
                   tracker_layout: str | TrackerLayout | None = None) -> SensorRecording:
    """Read a sensor recording in any supported format.

    Parameters
    ----------
    path : path
    format : {"auto", "csv", "tracker", "npz"}
        ``"auto"`` detects it with :func:`detect_format`.
    units : {"m", "cm", "mm", "in"}, optional
        Units of the file's positions; default metres (inches for tracker files).
    fps : float, optional
        Frame rate, Hz; required for tracker files and CSV files without a ``time`` column.
    stations : mapping or str, optional
        Station → segment mapping of tracker files (see
        :func:`~estimation.io.tracker.parse_stations`).
    tracker_layout : str, optional
        Column layout of a tracker file (see :func:`~estimation.io.tracker.parse_tracker_layout`);
        detected from the file when omitted.

    Returns
    -------
    SensorRecording
        Positions in metres, unit quaternions, NaN for dropped samples.

    Raises
    ------
    InputError
        See the format-specific readers.
    FileNotFoundError
        If ``path`` does not exist.
    """
    fmt = _sensor_format(path, format)
    if units is not None:
        unit_scale(units)
    if fmt == "csv":
        return read_sensor_csv(path, units=units, fps=fps)
    if fmt == "tracker":
        from .tracker import read_tracker_ascii

        return read_tracker_ascii(path, stations=stations, units=units, fps=fps,
                                  layout=tracker_layout)
    return read_sensor_npz(path, units=units, fps=fps)


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
        :class:`~estimation.io.tracker.TrackerLayout` spec.

    Raises
    ------
    InputError
        Unreadable header or unknown format.
    """
    fmt = _sensor_format(path, format)
    if fmt == "npz":
        return _sniff_npz(path)
    meta: dict[str, str] = {}
    if fmt == "csv":
        return _sniff_csv(path, meta, counted_rows)
    from .tracker import sniff_tracker

    return sniff_tracker(path)


def _sniff_csv(path: PathLike, meta: dict[str, str],
               counted_rows: int | None = None) -> dict[str, Any]:
    with open_text(path) as handle:
        header, header_line = _csv_header(_csv_rows(handle), meta)
        time_col, sensors, _ = _parse_csv_header(header, header_line)
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


def _sniff_npz(path: PathLike) -> dict[str, Any]:
    """Shapes from the NPY headers, names and scalars from the small members: nothing is
    decompressed before its declared size is checked (``estimation.io.limits``)."""
    with limits.open_npz(path) as archive:
        frames = _npz_frames(archive)
        names = set(archive.namelist())
        sensors = (_npz_sensor_names(_npz_small(archive, "sensors", "US"))
                   if "sensors.npy" in names else [])
        fps = (_npz_scalar(_npz_small(archive, "fps", "biuf"), "fps")
               if "fps.npy" in names else None)
        units = (_npz_units(_npz_small(archive, "units", "US"))
                 if "units.npy" in names else "m")
    return {"format": "npz", "frames": frames, "sensors": sensors, "fps": fps, "units": units}


def _npz_small(archive: zipfile.ZipFile, key: str, kinds: str) -> NDArray[Any]:
    """A member holding names or a scalar, within ``MAX_NPZ_SMALL_BYTES``."""
    return limits.load_npy(archive, key, kinds=kinds, small=True)


def _npz_frames(archive: zipfile.ZipFile) -> int:
    """Frames that ``positions`` declares, within ``MAX_FRAMES`` (its header only)."""
    shape, _ = limits.check_npy(archive, "positions")
    frames = shape[0] if shape else 0
    limits.check_count("frames", frames, "MAX_FRAMES", field="positions")
    return frames


def _npz_sensor_names(names: NDArray[Any]) -> list[str]:
    """The ``sensors`` array as names, within ``MAX_SENSORS`` and ``MAX_NAME_CHARS``."""
    flat = names.reshape(-1)
    limits.check_count("sensors", flat.size, "MAX_SENSORS", field="sensors")
    out = [str(s) for s in flat]
    for name in out:
        limits.check_count("characters in a sensor name", len(name), "MAX_NAME_CHARS",
                           field="sensors")
    return out


def _npz_scalar(value: NDArray[Any], key: str) -> float:
    if value.size != 1:
        raise InputError(f"{key} must be one number, got an array of shape {value.shape}",
                         field=key)
    number = float(value.reshape(-1)[0])
    limits.check_value(number, field=key, nan_ok=False)
    return number


def _npz_units(value: NDArray[Any]) -> str:
    if value.size != 1:
        raise InputError(f"units must be one string, got an array of shape {value.shape}",
                         field="units")
    text = str(value.reshape(-1)[0])
    limits.check_count("characters in units", len(text), "MAX_NAME_CHARS", field="units")
    return text
