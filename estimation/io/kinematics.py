"""Readers and writers of inertial-suit kinematics for root-translation estimation.

Three inputs give the same :class:`KinematicsRecording` (metres, world frame, Y up):

* **kinematics CSV**, the layout of Hachaj & Ogiela's data: ``Time``, ``<Joint>.Dx/.Dy/.Dz``
  (cm, Y up, global joint positions), ``<Sensor>.ax/.ay/.az`` (accelerometer, g, sensor frame,
  gravity included), optional ``<Foot>.c`` contact flags; every other column is kept and
  written back unchanged;
* **BVH + accelerations CSV** (``time,LeftFoot.ax,...``): positions by forward kinematics with
  the root translation of the BVH ignored;
* **Xsens MVNX** (see :mod:`bonefit.estimation.io.mvnx`).

The writers of a :class:`~bonefit.estimation.translation.TranslationResult` live in
:mod:`bonefit.estimation.io.translation_files` and are importable from here as before. Formats are
described in ``docs/translation.md``.
"""

from __future__ import annotations

import csv
import io
import math
import os
import warnings
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

import numpy as np
from numpy.typing import NDArray

from ..bvh import (
    MAX_NODES,
    BvhMotion,
    forward_kinematics,
    read_bvh,
)
from ..errors import InputError
from ..kinematics import GRAVITY as GRAVITY  # re-exported: callers import it from here
from ..kinematics import KinematicsRecording as KinematicsRecording
from ..vocabulary import KINEMATICS_FORMATS
from . import limits
from .body import (
    Feet,
    find_bvh_feet,
    find_column_feet,
    find_toe,
    leg_length,
    match_sensor,
    parse_length_unit,
    resolve_length_unit,
    varying_root,
)
from .translation_files import OUTPUT_FORMATS as OUTPUT_FORMATS
from .translation_files import translated_bvh as translated_bvh
from .translation_files import translation_to_dict as translation_to_dict
from .translation_files import write_kinematics_csv as write_kinematics_csv
from .translation_files import write_translation as write_translation
from .translation_files import write_translation_files as write_translation_files

if TYPE_CHECKING:
    pass

PathLike = str | os.PathLike[str]

FORMATS: Final[tuple[str, ...]] = KINEMATICS_FORMATS
"""Input formats of :func:`read_kinematics` (besides ``"auto"``)."""


ACCELERATION_UNITS: Final[dict[str, tuple[float, str]]] = {
    "g": (GRAVITY, "sensor"),
    "m/s2": (1.0, "sensor"),
    "free-g": (GRAVITY, "world"),
    "free-m/s2": (1.0, "world"),
    "second-differences": (1.0, "world"),
}
"""Declarable acceleration units: scale to m/s² and frame. ``g`` and ``m/s2`` are
accelerometer readings (sensor frame, gravity included); ``free-*`` are gravity-free world
(Y-up) accelerations; ``second-differences`` are exporter-computed second differences of the
positions (file length unit per frame²), accepted only when declared."""


# --------------------------------------------------------------------------- helpers


def _kinematics_fps(time: NDArray[np.float64]) -> float:
    if time.size < 2:
        raise InputError("need at least two frames", field="Time")
    steps = np.diff(time)
    step = float(np.median(steps))
    if not step > 0 or not np.all(steps > 0):
        bad = int(np.argmax(steps <= 0)) + 2
        raise InputError("time must increase from frame to frame", field="Time", line=bad + 1)
    fps = limits.check_fps(1.0 / step, field="Time")
    return round(fps, 6) if abs(fps - round(fps, 6)) < 1e-6 * fps else fps


def _acceleration_unit_key(units: str | None) -> str | None:
    if units is None:
        return None
    key = units.strip().lower().replace("²", "2").replace("m/s^2", "m/s2")
    if key not in ACCELERATION_UNITS:
        raise InputError(f"unknown acceleration units {units!r}; use one of "
                         f"{', '.join(ACCELERATION_UNITS)}", field="acceleration_units")
    return key


def _resolve_acceleration_units(  # noqa: C901
    raw: Mapping[str, NDArray[np.float64]],
    positions: Mapping[str, NDArray[np.float64]],
    declared: str | None,
    source: str,
) -> tuple[str, str]:
    """Decide the units of raw foot accelerations, or say why they cannot be accepted.

    Returns the unit key and a note. Accelerometer readings have a median magnitude of about
    1 g (gravity); anything else is reported instead of guessed.
    """
    medians = {k: float(np.median(np.linalg.norm(a, axis=1))) for k, a in raw.items()}
    worst = max(medians.values())
    least = min(medians.values())
    names = ", ".join(f"{k} {v:.3g}" for k, v in medians.items())
    d2_like = []
    for foot, acc in raw.items():
        p = positions[foot]
        if p.shape[0] >= 3:
            d2 = p[2:] - 2 * p[1:-1] + p[:-2]
            scale = float(np.linalg.norm(d2)) or 1.0
            d2_like.append(float(np.linalg.norm(acc[1:-1] - d2)) / scale < 0.05
                           or float(np.linalg.norm(acc[2:] - d2)) / scale < 0.05
                           or float(np.linalg.norm(acc[:-2] - d2)) / scale < 0.05)
    if d2_like and all(d2_like):
        if declared == "second-differences":
            return declared, "accelerations declared as second differences of positions"
        raise InputError(
            f"the foot acceleration columns of {source} are second differences of the foot "
            "positions (exporter-computed), not accelerometer readings; declare "
            "acceleration_units='second-differences' to use them anyway", field="acceleration")
    if declared is not None:
        scale, frame = ACCELERATION_UNITS[declared]
        if frame == "sensor":
            in_g = np.array([medians[k] * scale / GRAVITY for k in medians])
            if np.any((in_g < 0.3) | (in_g > 3.0)):
                raise InputError(
                    f"acceleration declared as {declared} but the median |a| per foot is "
                    f"{names}: accelerometer readings at rest are about 1 g; check the units",
                    field="acceleration_units")
        return declared, f"accelerations in {declared} (declared)"
    if least >= 0.6 and worst <= 1.6:
        return "g", f"accelerations in g (median |a| per foot: {names})"
    if least >= 6.0 and worst <= 16.0:
        raise InputError(
            f"the foot accelerations of {source} look like m/s² (median |a| per foot: {names}), "
            "not g; declare acceleration_units='m/s2'", field="acceleration_units")
    if worst < 0.35:
        raise InputError(
            f"the foot accelerations of {source} have no gravity in them (median |a| per foot: "
            f"{names}); declare acceleration_units='free-g' or 'free-m/s2'",
            field="acceleration_units")
    raise InputError(
        f"cannot tell the units of the foot accelerations of {source} (median |a| per foot: "
        f"{names}); declare acceleration_units", field="acceleration_units")


# --------------------------------------------------------------------------- kinematics CSV


def _open_csv(path: PathLike) -> io.TextIOWrapper:
    try:
        # undecodable bytes become U+FFFD and then fail as a named column or number
        return open(path, encoding="utf-8-sig", errors="replace", newline="")
    except (IsADirectoryError, PermissionError) as exc:
        raise InputError(f"cannot read {os.fspath(path)}: {exc.strerror}",
                         field="input") from None


def _table_header(first: str) -> list[str]:
    header = [h.strip() for h in next(csv.reader([first]), [])] if first.strip() else []
    limits.check_count("columns", len(header), "MAX_COLUMNS", line=1, field="header")
    for h in header:
        limits.check_count("characters in a column name", len(h), "MAX_NAME_CHARS",
                           line=1, field="header")
    return header


def _read_table(path: PathLike) -> tuple[list[str], NDArray[np.float64]]:
    """Header and numeric body of a CSV; a fast parse first, a row-by-row one to name the
    line and column of a bad value. Lines, columns and rows are bounded by
    ``bonefit.estimation.io.limits`` before they are read."""
    with _open_csv(path) as handle:
        lines = limits.bounded_lines(handle)
        header = _table_header(next(lines, ""))
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
    with _open_csv(path) as handle:
        lines = limits.bounded_lines(handle)
        header = _table_header(next(lines, ""))
        if not header:
            raise InputError("empty file: no header line", line=1, field="header")
        reader = csv.reader(lines)
        rows: list[list[float]] = []
        lineno = 1
        for row in _csv_records(reader):
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


def _csv_records(reader: Any) -> Iterator[list[str]]:
    """The rows of a ``csv.reader``; its errors (a NUL byte, an unclosed quote) as
    InputError."""
    while True:
        try:
            row = next(reader)
        except StopIteration:
            return
        except csv.Error as exc:
            raise InputError(f"unreadable CSV at line {reader.line_num + 1}: {exc}",
                             line=reader.line_num + 1) from None
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


def _position_joints(header: list[str]) -> tuple[str, ...]:
    joints = tuple(h[:-3] for h in header if h.endswith(".Dx"))
    for j in joints:
        for axis in ("Dy", "Dz"):
            if f"{j}.{axis}" not in header:
                raise InputError(f"joint {j!r} has a .Dx column but no .{axis}",
                                 field=f"{j}.{axis}")
    return joints


def read_kinematics_csv(
    path: PathLike,
    *,
    left_foot: str | None = None,
    right_foot: str | None = None,
    acceleration_units: str | None = None,
    units: str | float | None = "auto",
) -> KinematicsRecording:
    """Read a kinematics CSV (the layout of Hachaj & Ogiela's Shadow exports).

    Parameters
    ----------
    path : path
    left_foot, right_foot : str, optional
        Foot joints (overrides); by default the columns named like a left and a right foot
        (:func:`bonefit.estimation.io.body.find_column_feet`). ``<Foot>.Dx/.Dy/.Dz`` and
        ``<Foot>.ax/.ay/.az`` must exist.
    acceleration_units : str, optional
        One of :data:`ACCELERATION_UNITS`. By default the columns must look like g with
        gravity (median |a| ≈ 1); m/s², gravity-free data and second differences of positions
        are reported as InputError rather than guessed.
    units : str or float, optional
        Length unit of the positions: ``"auto"`` (default: inferred from the hips–feet
        distance, cm for the paper's layout), a name of
        :data:`~bonefit.estimation.io.body.LENGTH_UNITS` or metres per unit; a unit giving legs
        outside a person's range is refused naming the likely one.

    Returns
    -------
    KinematicsRecording

    Raises
    ------
    InputError
        Malformed file, missing foot columns (listing the joints present), units that do
        not look like accelerometer readings in g.
    """
    declared = _acceleration_unit_key(acceleration_units)
    header, table = _read_table(path)
    col = {h: i for i, h in enumerate(header)}
    joints = _position_joints(header)
    if not joints:
        raise InputError("no <Joint>.Dx/.Dy/.Dz position columns", field="header", line=1)
    if np.isnan(table).any():
        r, c = np.argwhere(np.isnan(table))[0]
        raise InputError(f"missing value in column {header[c]!r}", line=int(r) + 2,
                         column=int(c) + 1, field=header[c])
    raw_pos = np.stack([np.stack([table[:, col[f"{j}.D{a}"]] for a in "xyz"], axis=-1)
                        for j in joints], axis=1)
    feet = find_column_feet(joints, np.median(raw_pos[:, :, 1], axis=0), left_foot, right_foot)
    root = _guess_root(joints)
    scale, unit_note = _csv_length_unit(raw_pos, joints, root, feet, units)
    positions = raw_pos * scale
    time_key = next((h for h in header if h.lower() == "time"), None)
    if time_key is None:
        raise InputError("no Time column", field="Time", line=1)
    time = table[:, col[time_key]].copy()
    fps = _kinematics_fps(time)
    raw = _csv_foot_accelerations(header, table, (feet.left, feet.right))
    unit, note = _resolve_acceleration_units(
        raw, {f: raw_pos[:, joints.index(f)] for f in raw}, declared, Path(path).name)
    acc_scale, frame = ACCELERATION_UNITS[unit]
    if unit == "second-differences":
        acc_scale = scale * fps * fps
    accelerations = {f: a * acc_scale for f, a in raw.items()}
    notes = [feet.note(), unit_note, note]
    toes, contacts = _csv_toes_and_contacts(header, table, joints, positions,
                                            (feet.left, feet.right), notes)
    return KinematicsRecording(
        joints=joints, positions=positions, fps=fps, time=time, accelerations=accelerations,
        acceleration_frame=frame, left_foot=feet.left, right_foot=feet.right, toes=toes,
        contacts=contacts, source_format="kinematics-csv", length_scale=scale,
        columns=tuple(header), table=table, root=root, source_path=str(path),
        notes=tuple(notes))


def _csv_foot_accelerations(header: list[str], table: NDArray[np.float64],
                            feet: tuple[str, str]) -> dict[str, NDArray[np.float64]]:
    """Raw ``<Foot>.ax/.ay/.az`` columns (F, 3) of each foot."""
    col = {h: i for i, h in enumerate(header)}
    sensors = tuple(h[:-3] for h in header if h.endswith(".ax"))
    raw: dict[str, NDArray[np.float64]] = {}
    for foot in feet:
        keys = [f"{foot}.a{a}" for a in "xyz"]
        missing = [k for k in keys if k not in col]
        if missing:
            raise InputError(f"no acceleration columns {', '.join(missing)} for foot {foot!r}; "
                             f"sensors with accelerations: {', '.join(sensors) or 'none'}",
                             field=missing[0], sensor=foot)
        raw[foot] = np.stack([table[:, col[k]] for k in keys], axis=-1)
    return raw


def _csv_toes_and_contacts(header: list[str], table: NDArray[np.float64],  # noqa: PLR0917
                           joints: tuple[str, ...], positions: NDArray[np.float64],
                           feet: tuple[str, str], notes: list[str]
                           ) -> tuple[dict[str, str], dict[str, NDArray[np.bool_]]]:
    """Toe of each foot (by name) and contact flags from ``<Foot>.c``/``<Toe>.c`` columns;
    appends what was found to ``notes``."""
    col = {h: i for i, h in enumerate(header)}
    contacts: dict[str, NDArray[np.bool_]] = {}
    toes: dict[str, str] = {}
    for foot in feet:
        toe = find_toe(foot, joints, positions)
        if toe is not None:
            toes[foot] = toe
            notes.append(f"{toe} is the toe of {foot}")
        flags = [k for k in (f"{foot}.c", f"{toe}.c" if toe else "") if k in col]
        if flags:
            contacts[foot] = np.any(np.stack([table[:, col[k]] for k in flags]) > 0.5, axis=0)
            notes.append(f"contacts of {foot} from {', '.join(flags)}")
    return toes, contacts


def _csv_length_unit(raw_pos: NDArray[np.float64], joints: tuple[str, ...], root: str,
                     feet: Feet, units: str | float | None) -> tuple[float, str]:
    """Metres per unit of position columns, from the median root–foot distance."""
    r = joints.index(root)
    legs = [float(np.median(np.linalg.norm(raw_pos[:, joints.index(f)] - raw_pos[:, r],
                                           axis=1))) for f in (feet.left, feet.right)]
    return resolve_length_unit(float(np.mean(legs)), parse_length_unit(units),
                               f"{root} to {feet.left}/{feet.right}, median distance")


def _guess_root(joints: tuple[str, ...]) -> str:
    for name in joints:
        if name.lower() in ("hips", "hip", "pelvis", "root"):
            return name
    return joints[0]


# --------------------------------------------------------------------------- BVH + accelerations


def read_acceleration_csv(
    path: PathLike,
) -> tuple[NDArray[np.float64], dict[str, NDArray[np.float64]], str | None]:
    """Read ``time,<Sensor>.ax,<Sensor>.ay,<Sensor>.az,...``.

    A unit may be declared in the header cells, e.g. ``LeftFoot.ax [g]`` or
    ``LeftFoot.ax (m/s2)``. Returns times (s), sensor → (F, 3) raw values, and the declared
    unit or None.
    """
    header, table = _read_table(path)
    names, unit = acceleration_header(header)
    col = {h: i for i, h in enumerate(names)}
    tkey = next((h for h in names if h.lower() in ("time", "t")), None)
    if tkey is None:
        raise InputError("accelerations file has no time column", field="time", line=1)
    if np.isnan(table).any():
        r, c = np.argwhere(np.isnan(table))[0]
        raise InputError(f"missing value in column {names[c]!r}", line=int(r) + 2,
                         column=int(c) + 1, field=names[c])
    sensors = [h[:-3] for h in names if h.endswith(".ax")]
    out: dict[str, NDArray[np.float64]] = {}
    for s in sensors:
        keys = [f"{s}.a{a}" for a in "xyz"]
        if any(k not in col for k in keys):
            raise InputError(f"sensor {s!r} lacks one of {', '.join(keys)}", sensor=s)
        out[s] = np.stack([table[:, col[k]] for k in keys], axis=-1)
    return table[:, col[tkey]].copy(), out, unit


def acceleration_header(header: list[str]) -> tuple[list[str], str | None]:
    """Column names of an accelerations CSV without their unit suffixes (``LeftFoot.ax [g]``
    → ``LeftFoot.ax``), and the unit they declare (None when none does).

    Raises
    ------
    InputError
        An unknown unit, or columns declaring different units.
    """
    unit: str | None = None
    names: list[str] = []
    for h in header:
        base = h
        for open_, close in (("[", "]"), ("(", ")")):
            if open_ in h and h.endswith(close):
                base, _, rest = h.partition(open_)
                found = _acceleration_unit_key(rest[:-1].strip())
                if unit is not None and found != unit:
                    raise InputError("acceleration columns declare different units", field=h)
                unit = found
        names.append(base.strip())
    return names, unit


def acceleration_sensors(names: list[str]) -> list[str]:
    """Sensors with all three of ``<Sensor>.ax/.ay/.az`` among ``names``."""
    present = set(names)
    return [n[:-3] for n in names if n.endswith(".ax")
            and {f"{n[:-3]}.ay", f"{n[:-3]}.az"} <= present]


def bvh_positions_without_root_translation(motion: BvhMotion, root: int | None = None
                                           ) -> tuple[NDArray[np.float64], int]:
    """Forward kinematics with the root's position channels frozen at frame 0.

    Returns positions (F, J, 3) in BVH units and the index of the root node used.
    """
    j = varying_root(motion) if root is None else root
    values = motion.values.copy()
    start = sum(len(c) for c in motion.channels[:j])
    for k, ch in enumerate(motion.channels[j]):
        if ch.endswith("position"):
            values[:, start + k] = values[0, start + k]
    positions, _ = forward_kinematics(motion.with_values(values))
    return positions, j


def read_bvh_kinematics(
    path: PathLike,
    accelerations: PathLike,
    *,
    left_foot: str | None = None,
    right_foot: str | None = None,
    acceleration_units: str | None = None,
    units: str | float | None = "auto",
) -> KinematicsRecording:
    """Read a BVH motion plus a CSV of foot accelerations.

    Parameters
    ----------
    path : path
        BVH file; its root translation, if any, is ignored (frozen at frame 0).
    accelerations : path
        ``time,<Foot>.ax,<Foot>.ay,<Foot>.az,...``; resampled onto the BVH frame times when
        the times differ.
    left_foot, right_foot : str, optional
        Foot joints of the BVH hierarchy (overrides); by default found by name or topology
        (:func:`bonefit.estimation.io.body.find_bvh_feet`). The accelerations file names the sensors
        by these joints, or by the only foot-named sensor of each side.
    acceleration_units : str, optional
        As in :func:`read_kinematics_csv`; a unit in the header cells counts as declared.
    units : str or float, optional
        BVH length unit: ``"auto"`` (default: inferred from the legs' bone lengths), a name
        of :data:`~bonefit.estimation.io.body.LENGTH_UNITS` (``m``, ``cm``, ``mm``, ``in``, ``ft``,
        ``cmu``) or metres per unit; a unit giving legs outside a person's range is refused
        naming the likely one.

    Returns
    -------
    KinematicsRecording
        ``notes`` say which feet, toes and unit were used and how they were found.
    """
    declared = _acceleration_unit_key(acceleration_units)
    motion = read_bvh(path)
    feet = find_bvh_feet(motion, left_foot, right_foot)
    names = motion.names
    scale, unit_note = resolve_length_unit(
        leg_length(motion, names.index(feet.left), names.index(feet.right)),
        parse_length_unit(units), f"hips to {feet.left}/{feet.right} along the bones")
    raw_pos, root = bvh_positions_without_root_translation(motion)
    n = motion.n_frames
    time = np.arange(n, dtype=np.float64) * float(motion.frame_time)
    a_time, a_raw, header_unit = read_acceleration_csv(accelerations)
    if declared is None:
        declared = header_unit
    raw: dict[str, NDArray[np.float64]] = {}
    notes = [feet.note(), unit_note, *motion.notes]
    for foot in (feet.left, feet.right):
        sensor = match_sensor(foot, list(a_raw))
        if sensor is None:
            raise InputError(f"no accelerations for foot {foot!r} in "
                             f"{Path(accelerations).name}; sensors: {', '.join(a_raw) or 'none'}",
                             sensor=foot)
        if sensor != foot:
            notes.append(f"accelerations of {foot} from sensor {sensor}")
        raw[foot] = _on_bvh_frames(a_raw[sensor], a_time, time, motion.fps)
    unit, note = _resolve_acceleration_units(
        raw, {f: raw_pos[:, names.index(f)] for f in raw}, declared, Path(accelerations).name)
    acc_scale, frame = ACCELERATION_UNITS[unit]
    if unit == "second-differences":
        acc_scale = scale * motion.fps ** 2
    notes += [note, f"root translation of {names[root]} ignored"]
    return KinematicsRecording(
        joints=names, positions=raw_pos * scale, fps=motion.fps, time=time,
        accelerations={f: a * acc_scale for f, a in raw.items()}, acceleration_frame=frame,
        left_foot=feet.left, right_foot=feet.right, toes=dict(feet.toes),
        source_format="bvh", length_scale=scale, bvh=motion, root=names[root],
        source_path=str(path), notes=tuple(notes))


def _on_bvh_frames(a: NDArray[np.float64], a_time: NDArray[np.float64],
                   time: NDArray[np.float64], fps: float) -> NDArray[np.float64]:
    """Accelerations resampled onto the BVH frame times when their times differ."""
    if a.shape[0] == time.shape[0] and np.allclose(a_time - a_time[0], time, atol=0.25 / fps):
        return a
    if a_time[0] > time[0] + 1.0 / fps or a_time[-1] < time[-1] - 1.0 / fps:
        raise InputError(f"accelerations cover {a_time[0]:.3f}–{a_time[-1]:.3f} s, the BVH "
                         f"0–{time[-1]:.3f} s", field="time")
    return np.stack([np.interp(time, a_time, a[:, k]) for k in range(3)], axis=-1)


# --------------------------------------------------------------------------- dispatch


def detect_format(path: PathLike) -> str:
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
        return detect_format(path)
    if format not in FORMATS:
        raise InputError(f"unknown format {format!r}; use auto, {', '.join(FORMATS)}",
                         field="format")
    return format


def read_kinematics(  # noqa: PLR0913
    path: PathLike,
    *,
    format: str = "auto",
    accelerations: PathLike | None = None,
    left_foot: str | None = None,
    right_foot: str | None = None,
    acceleration_units: str | None = None,
    units: str | float | None = "auto",
    subject: str | None = None,
) -> KinematicsRecording:
    """Read an inertial-suit recording for root-translation estimation.

    Parameters
    ----------
    path : path
        Kinematics CSV, BVH or MVNX file.
    format : {"auto", "kinematics-csv", "bvh", "mvnx"}
    accelerations : path, optional
        Foot accelerations CSV; required with a BVH.
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

    Returns
    -------
    KinematicsRecording

    Raises
    ------
    InputError
        Unreadable file, missing foot (listing the joints present), unrecognised units, a
        length unit that does not give a person's legs.
    """
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
                     right_foot=right_foot or "RightFoot", subject=subject)


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
    with _open_csv(path) as handle:
        lines = limits.bounded_lines(handle)
        header = _table_header(next(lines, ""))
        if not header:
            raise InputError("empty file: no header line", line=1, field="header")
        joints = _position_joints(header)
        if not joints:
            raise InputError("not a kinematics CSV: the header has no <Joint>.Dx/.Dy/.Dz "
                             "position columns", field="header", line=1)
        limits.check_count("joints", len(joints), "MAX_JOINTS", line=1, field="header")
        tcol = next((i for i, h in enumerate(header) if h.lower() == "time"), None)
        reader = csv.reader(lines)
        frames, t0, t1 = 0, math.nan, math.nan
        for row in _csv_records(reader):
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

