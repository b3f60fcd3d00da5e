"""Foot accelerations: the declarable units, deciding the units of raw readings, and the
accelerations CSV (``time,<Sensor>.ax,<Sensor>.ay,<Sensor>.az,...``)."""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Final

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..kinematics import GRAVITY
from .tables import read_table

PathLike = str | os.PathLike[str]

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


def acceleration_unit_key(units: str | None) -> str | None:
    if units is None:
        return None
    key = units.strip().lower().replace("²", "2").replace("m/s^2", "m/s2")
    if key not in ACCELERATION_UNITS:
        raise InputError(f"unknown acceleration units {units!r}; use one of "
                         f"{', '.join(ACCELERATION_UNITS)}", field="acceleration_units")
    return key


def resolve_acceleration_units(
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
    if _second_differences(raw, positions):
        if declared == "second-differences":
            return declared, "accelerations declared as second differences of positions"
        raise InputError(
            f"the foot acceleration columns of {source} are second differences of the foot "
            "positions (exporter-computed), not accelerometer readings; declare "
            "acceleration_units='second-differences' to use them anyway", field="acceleration")
    if declared is not None:
        _check_declared(declared, medians, names)
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


def _second_differences(raw: Mapping[str, NDArray[np.float64]],
                        positions: Mapping[str, NDArray[np.float64]]) -> bool:
    """Every foot's raw accelerations equal (within 5 %) the second differences of its
    positions, at any of three alignments (an exporter's computed column)."""
    d2_like = []
    for foot, acc in raw.items():
        p = positions[foot]
        if p.shape[0] >= 3:
            d2 = p[2:] - 2 * p[1:-1] + p[:-2]
            scale = float(np.linalg.norm(d2)) or 1.0
            d2_like.append(float(np.linalg.norm(acc[1:-1] - d2)) / scale < 0.05
                           or float(np.linalg.norm(acc[2:] - d2)) / scale < 0.05
                           or float(np.linalg.norm(acc[:-2] - d2)) / scale < 0.05)
    return bool(d2_like) and all(d2_like)


def _check_declared(declared: str, medians: Mapping[str, float], names: str) -> None:
    """Refuse declared accelerometer units whose median reading per foot is not about 1 g."""
    scale, frame = ACCELERATION_UNITS[declared]
    if frame == "sensor":
        in_g = np.array([medians[k] * scale / GRAVITY for k in medians])
        if np.any((in_g < 0.3) | (in_g > 3.0)):
            raise InputError(
                f"acceleration declared as {declared} but the median |a| per foot is "
                f"{names}: accelerometer readings at rest are about 1 g; check the units",
                field="acceleration_units")


def scaled_accelerations(raw: Mapping[str, NDArray[np.float64]],
                         positions: Mapping[str, NDArray[np.float64]], declared: str | None,
                         source: str, *, length_scale: float, fps: float
                         ) -> tuple[dict[str, NDArray[np.float64]], str, str]:
    """Raw foot accelerations in m/s², their frame and a note, once their units are decided
    (:func:`resolve_acceleration_units`; second differences of positions in file length units
    per frame² are scaled by ``length_scale * fps**2``)."""
    unit, note = resolve_acceleration_units(raw, positions, declared, source)
    scale, frame = ACCELERATION_UNITS[unit]
    if unit == "second-differences":
        scale = length_scale * fps * fps
    return {f: a * scale for f, a in raw.items()}, frame, note


def read_acceleration_csv(
    path: PathLike,
) -> tuple[NDArray[np.float64], dict[str, NDArray[np.float64]], str | None]:
    """Read ``time,<Sensor>.ax,<Sensor>.ay,<Sensor>.az,...``.

    A unit may be declared in the header cells, e.g. ``LeftFoot.ax [g]`` or
    ``LeftFoot.ax (m/s2)``. Returns times (s), sensor → (F, 3) raw values, and the declared
    unit or None.
    """
    header, table = read_table(path)
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
                found = acceleration_unit_key(rest[:-1].strip())
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
