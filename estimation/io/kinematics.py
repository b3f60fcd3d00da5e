"""Readers and writers of inertial-suit kinematics for root-translation estimation.

Three inputs give the same :class:`KinematicsRecording` (metres, world frame, Y up):

* **kinematics CSV**, the layout of Hachaj & Ogiela's data: ``Time``, ``<Joint>.Dx/.Dy/.Dz``
  (cm, Y up, global joint positions), ``<Sensor>.ax/.ay/.az`` (accelerometer, g, sensor frame,
  gravity included), optional ``<Foot>.c`` contact flags; every other column is kept and
  written back unchanged;
* **BVH + accelerations CSV** (``time,LeftFoot.ax,...``): positions by forward kinematics with
  the root translation of the BVH ignored;
* **Xsens MVNX** (see :mod:`bonefit.estimation.io.mvnx`).

This module detects the format, dispatches and sniffs; each format and concept has its own
module (:mod:`~bonefit.estimation.io.kinematics_csv`, :mod:`~bonefit.estimation.io.bvh_kinematics`,
:mod:`~bonefit.estimation.io.accelerations`, :mod:`~bonefit.estimation.io.tables`,
:mod:`~bonefit.estimation.io.translation_files` for the writers of a
:class:`~bonefit.estimation.translation.TranslationResult`), and their public names are importable
from here as before. Formats are described in ``docs/translation.md``.
"""

from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass
from typing import Any, Final

from ..bvh import MAX_NODES
from ..errors import InputError
from ..kinematics import GRAVITY as GRAVITY  # re-exported: callers import it from here
from ..kinematics import KinematicsRecording as KinematicsRecording
from ..params import resolved_options
from ..vocabulary import KINEMATICS_FORMATS
from . import limits
from .accelerations import ACCELERATION_UNITS as ACCELERATION_UNITS
from .accelerations import acceleration_header as acceleration_header
from .accelerations import acceleration_sensors as acceleration_sensors
from .accelerations import read_acceleration_csv as read_acceleration_csv
from .body import parse_length_unit
from .bvh_kinematics import (
    bvh_positions_without_root_translation as bvh_positions_without_root_translation,
)
from .bvh_kinematics import read_bvh_kinematics as read_bvh_kinematics
from .kinematics_csv import position_joints
from .kinematics_csv import read_kinematics_csv as read_kinematics_csv
from .tables import csv_records, open_csv, table_header
from .translation_files import OUTPUT_FORMATS as OUTPUT_FORMATS
from .translation_files import translated_bvh as translated_bvh
from .translation_files import translation_to_dict as translation_to_dict
from .translation_files import write_kinematics_csv as write_kinematics_csv
from .translation_files import write_translation as write_translation
from .translation_files import write_translation_files as write_translation_files

PathLike = str | os.PathLike[str]

FORMATS: Final[tuple[str, ...]] = KINEMATICS_FORMATS
"""Input formats of :func:`read_kinematics` (besides ``"auto"``)."""


# --------------------------------------------------------------------------- dispatch


def detect_kinematics_format(path: PathLike) -> str:
    """``"kinematics-csv"``, ``"bvh"`` or ``"mvnx"`` from the file's first bytes."""
    with open(path, "rb") as handle:
        head = handle.read(4096).lstrip(b"\xef\xbb\xbf").lstrip()
    if head.upper().startswith(b"HIERARCHY"):
        return "bvh"
    if head.startswith(b"<?xml") or head.startswith(b"<mvnx"):
        if b"mvnx" in head.lower():
            return "mvnx"
        raise InputError("XML file is not MVNX", field="format")
    first = head.split(b"\n", 1)[0]
    if b".Dx" in first:
        return "kinematics-csv"
    raise InputError("cannot tell the format (expected a kinematics CSV with <Joint>.Dx "
                     "columns, a BVH or an MVNX file); pass format", field="format")


def _kinematics_format(path: PathLike, format: str) -> str:
    if format == "auto":
        return detect_kinematics_format(path)
    if format not in FORMATS:
        raise InputError(f"unknown format {format!r}; use auto, {', '.join(FORMATS)}",
                         field="format")
    return format


@dataclass(frozen=True)
class KinematicsReadOptions:
    """How :func:`read_kinematics` interprets a file (its keywords of the same names).

    Attributes
    ----------
    left_foot, right_foot : str, optional
        Foot joint names, overriding the ones found by name (and, in a BVH, topology); MVNX:
        segment names, default ``LeftFoot``/``RightFoot``.
    acceleration_units : str, optional
        See :data:`ACCELERATION_UNITS`.
    units : str or float, optional
        Length unit of a BVH or kinematics CSV: ``"auto"`` (inferred from the legs), ``m``,
        ``cm``, ``mm``, ``in``, ``ft``, ``cmu`` or metres per unit. MVNX is in metres.
    subject : str, optional
        MVNX: label or 1-based number of the subject to read (default the first).

    Examples
    --------
    >>> KinematicsReadOptions(units="cm", acceleration_units="g").left_foot is None
    True
    """

    left_foot: str | None = None
    right_foot: str | None = None
    acceleration_units: str | None = None
    units: str | float | None = "auto"
    subject: str | None = None


def read_kinematics(
    path: PathLike,
    *,
    format: str = "auto",
    accelerations: PathLike | None = None,
    options: KinematicsReadOptions | None = None,
    **read_options: Any,
) -> KinematicsRecording:
    """Read an inertial-suit recording for root-translation estimation.

    Parameters
    ----------
    path : path
        Kinematics CSV, BVH or MVNX file.
    format : {"auto", "kinematics-csv", "bvh", "mvnx"}
    accelerations : path, optional
        Foot accelerations CSV; required with a BVH.
    options : KinematicsReadOptions, optional
        Feet, units and subject as one object; default: from ``read_options``.
    **read_options
        Instead of ``options``, its fields: ``left_foot``, ``right_foot``,
        ``acceleration_units``, ``units``, ``subject``.

    Returns
    -------
    KinematicsRecording

    Raises
    ------
    InputError
        Unreadable file, missing foot (listing the joints present), unrecognised units, a
        length unit that does not give a person's legs, an unknown keyword (``field`` names
        it).
    """
    opt = resolved_options("read_kinematics", {"read_kinematics": KinematicsReadOptions},
                           options, read_options)
    left_foot, right_foot, units = opt.left_foot, opt.right_foot, opt.units
    acceleration_units = opt.acceleration_units
    fmt = _kinematics_format(path, format)
    if fmt == "kinematics-csv":
        return read_kinematics_csv(path, left_foot=left_foot, right_foot=right_foot,
                                   acceleration_units=acceleration_units, units=units)
    if fmt == "bvh":
        if accelerations is None:
            raise InputError("a BVH input needs an accelerations CSV "
                             "(time,<Foot>.ax,<Foot>.ay,<Foot>.az,...)", field="accelerations")
        return read_bvh_kinematics(path, accelerations, left_foot=left_foot,
                                   right_foot=right_foot, acceleration_units=acceleration_units,
                                   units=units)
    from .mvnx import read_mvnx

    if parse_length_unit(units) not in (None, 1.0):
        raise InputError(f"MVNX positions are in metres; units {units!r} does not apply",
                         field="units")
    return read_mvnx(path, left_foot=left_foot or "LeftFoot",
                     right_foot=right_foot or "RightFoot", subject=opt.subject)


def sniff_kinematics(path: PathLike, format: str = "auto") -> dict[str, Any]:
    """Quick summary of a recording without loading it.

    Returns
    -------
    dict
        ``format``, ``frames``, ``joints`` (list), ``fps``; streams the file.
    """
    fmt = _kinematics_format(path, format)
    if fmt == "mvnx":
        from .mvnx import sniff_mvnx

        return sniff_mvnx(path)
    if fmt == "bvh":
        return _sniff_bvh(path)
    return _sniff_kinematics_csv(path)


def _sniff_kinematics_csv(path: PathLike) -> dict[str, Any]:
    with open_csv(path) as handle:
        lines = limits.bounded_lines(handle)
        header = table_header(next(lines, ""))
        if not header:
            raise InputError("empty file: no header line", line=1, field="header")
        joints = position_joints(header)
        if not joints:
            raise InputError("not a kinematics CSV: the header has no <Joint>.Dx/.Dy/.Dz "
                             "position columns", field="header", line=1)
        limits.check_count("joints", len(joints), "MAX_JOINTS", line=1, field="header")
        tcol = next((i for i, h in enumerate(header) if h.lower() == "time"), None)
        reader = csv.reader(lines)
        frames, t0, t1 = 0, math.nan, math.nan
        for row in csv_records(reader):
            if not row:
                continue
            frames += 1
            if tcol is not None and frames <= 2:
                try:
                    t0, t1 = (float(row[tcol]), t0) if frames == 1 else (t0, float(row[tcol]))
                except (ValueError, IndexError):
                    raise InputError("bad Time value", line=reader.line_num + 1,
                                     column=tcol + 1, field=header[tcol]) from None
    limits.check_rows(frames, len(header))
    fps = 1.0 / (t1 - t0) if frames >= 2 and t1 > t0 else None
    return {"format": "kinematics-csv", "frames": frames, "joints": list(joints),
            "fps": fps if fps is not None and math.isfinite(fps) else None,
            "sensors": acceleration_sensors(header)}


def _sniff_bvh(path: PathLike) -> dict[str, Any]:
    """Joints, fps and frames (the rows present, at most the header's count) of a BVH;
    InputError when the file is not a BVH at all (no ``HIERARCHY`` first, no ``ROOT``, no
    ``MOTION`` section with ``Frames:`` and ``Frame Time:``)."""
    joints: list[str] = []
    frames: int | None = None
    fps: float | None = None
    seen = {"HIERARCHY": False, "MOTION": False, "FRAME": False}
    with open(path, encoding="utf-8-sig", errors="replace") as handle:
        lines = limits.bounded_lines(handle)
        for line, text in enumerate(lines, 1):
            parts = text.split()
            if not parts:
                continue
            key = parts[0].upper()
            if not seen["HIERARCHY"] and key != "HIERARCHY":
                raise InputError(f"not a BVH file: line {line} should be HIERARCHY, "
                                 f"got {_snippet(text)}", line=line, field="format")
            if key in seen:
                seen[key] = True
            if key in ("ROOT", "JOINT") and len(parts) > 1:
                joints.append(" ".join(p for p in parts[1:] if p != "{")[:limits.MAX_NAME_CHARS])
                if len(joints) > MAX_NODES:
                    raise InputError(f"more than {MAX_NODES} joints in the hierarchy",
                                     line=line)
            elif key == "FRAMES:" and seen["MOTION"]:
                frames = _bvh_number(parts, 1, line, int)
            elif key == "FRAME" and seen["MOTION"]:
                step = _bvh_number(parts, 2, line, float)
                fps = (limits.check_fps(1.0 / step, field="Frame Time", line=line)
                       if step > 0 and math.isfinite(step) else None)
                break
        rows = sum(1 for text in lines if not text.isspace())
    if not joints or frames is None or not seen["FRAME"]:
        missing = ("a ROOT joint in the HIERARCHY" if not joints else
                   "Frames: line in the MOTION section" if frames is None else
                   "Frame Time: line in the MOTION section")
        raise InputError(f"not a BVH file: no {missing}", field="format")
    frames = min(frames, rows)  # a header may declare any count: the rows present are read
    limits.check_count("frames", frames, "MAX_FRAMES")
    return {"format": "bvh", "frames": frames, "joints": joints, "fps": fps}


def _bvh_number(parts: list[str], index: int, line: int, kind: type[int] | type[float]) -> Any:
    try:
        value = kind(parts[index])
    except (ValueError, IndexError, OverflowError):
        raise InputError(f"bad {parts[0]} line: {' '.join(parts)[:60]!r}", line=line,
                         field=parts[0].rstrip(":")) from None
    if kind is int and value < 0:
        raise InputError(f"bad {parts[0]} line: a negative count", line=line,
                         field=parts[0].rstrip(":"))
    return value


def _snippet(text: str, limit: int = 40) -> str:
    text = text.strip()
    return repr(text if len(text) <= limit else text[:limit] + "…")
