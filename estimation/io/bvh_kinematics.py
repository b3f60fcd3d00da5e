"""A BVH motion plus a CSV of foot accelerations as a kinematics recording: positions by
forward kinematics with the root translation frozen (docs/translation.md)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..bvh import BvhMotion, forward_kinematics, read_bvh
from ..errors import InputError
from ..kinematics import KinematicsRecording
from .accelerations import acceleration_unit_key, read_acceleration_csv, scaled_accelerations
from .body import (
    find_bvh_feet,
    leg_length,
    match_sensor,
    parse_length_unit,
    resolve_length_unit,
    varying_root,
)

PathLike = str | os.PathLike[str]


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
    declared = acceleration_unit_key(acceleration_units)
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
    scaled, frame, note = scaled_accelerations(
        raw, {f: raw_pos[:, names.index(f)] for f in raw}, declared, Path(accelerations).name,
        length_scale=scale, fps=motion.fps)
    notes += [note, f"root translation of {names[root]} ignored"]
    return KinematicsRecording(
        joints=names, positions=raw_pos * scale, fps=motion.fps, time=time,
        accelerations=scaled, acceleration_frame=frame,
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
