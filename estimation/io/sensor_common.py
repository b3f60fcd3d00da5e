"""What the sensor-recording readers share: length units, frame rates, text opening,
quaternion and body-extent checks, the bundled example (CSV, NPZ and tracker ASCII)."""

from __future__ import annotations

import io
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..recording import SensorRecording
from . import limits

if TYPE_CHECKING:
    pass


PathLike = str | os.PathLike[str]

UNITS: Final[dict[str, float]] = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
"""Length units accepted by the readers and their size in metres."""

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


def open_text(path: PathLike, newline: str | None = "") -> io.TextIOWrapper:
    """Text handle of a recording (UTF-8, BOM dropped, bad bytes as U+FFFD; line ends kept
    as they are, or translated to ``\\n`` with ``newline=None``); InputError for a directory
    or an unreadable file."""
    try:
        # undecodable bytes become U+FFFD and then fail as a named column or number
        return open(path, encoding="utf-8-sig", errors="replace", newline=newline)
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
    counts = valid.sum(axis=1)
    rows = counts >= 2
    if rows.any():
        spread = float(np.median(_extents(rec.positions, valid, rows)))
        if spread > MAX_BODY_EXTENT_M:
            raise InputError(
                f"sensors are {spread:.3g} m apart if positions are in {units}: a body is about "
                f"2 m; give the file's units (units=mm/cm/in, --units)", field="units")
        if np.median(counts[rows]) >= 3 and spread < MIN_BODY_EXTENT_M:
            raise InputError(
                f"sensors are only {spread * 1000:.3g} mm apart if positions are in {units}; "
                f"give the file's units (units=m/cm, --units)", field="units")
    return rec


def _extents(positions: NDArray[np.float64], valid: NDArray[np.bool_],
             rows: NDArray[np.bool_]) -> NDArray[np.float64]:
    """Diagonal of the box around the valid positions (F, S, 3) of each frame of ``rows``
    (R,), m."""
    if valid.all():  # the common case: no NaN-aware copies (the same values)
        box = positions.max(axis=1) - positions.min(axis=1)
    else:
        pos = np.where(valid[rows][..., None], positions[rows], np.nan)
        with np.errstate(invalid="ignore"):
            box = np.nanmax(pos, axis=1) - np.nanmin(pos, axis=1)
    extent: NDArray[np.float64] = np.linalg.norm(box, axis=-1)
    return extent


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


