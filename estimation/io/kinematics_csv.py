"""The kinematics CSV of Hachaj & Ogiela's Shadow exports: ``Time``, ``<Joint>.Dx/.Dy/.Dz``
(global joint positions), ``<Sensor>.ax/.ay/.az`` (accelerometers), optional ``<Foot>.c``
contact flags; every other column is kept (docs/translation.md)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..kinematics import KinematicsRecording
from . import limits
from .accelerations import acceleration_unit_key, scaled_accelerations
from .body import Feet, find_column_feet, find_toe, parse_length_unit, resolve_length_unit
from .tables import read_table

PathLike = str | os.PathLike[str]


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


def position_joints(header: list[str]) -> tuple[str, ...]:
    """Joints with ``<Joint>.Dx`` columns (in header order); InputError for one lacking its
    ``.Dy`` or ``.Dz``."""
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
    declared = acceleration_unit_key(acceleration_units)
    header, table = read_table(path)
    col = {h: i for i, h in enumerate(header)}
    joints = position_joints(header)
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
    accelerations, frame, note = scaled_accelerations(
        raw, {f: raw_pos[:, joints.index(f)] for f in raw}, declared, Path(path).name,
        length_scale=scale, fps=fps)
    notes = [feet.note(), unit_note, note]
    toes, contacts = _csv_toes_and_contacts(header, table, joints, positions,
                                            feet=(feet.left, feet.right), notes=notes)
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


def _csv_toes_and_contacts(header: list[str], table: NDArray[np.float64],
                           joints: tuple[str, ...], positions: NDArray[np.float64], *,
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
