"""Writers of a root-translation result: the input's own format (kinematics CSV, BVH, MVNX),
a BVH with the root path in the root's position channels, or JSON (docs/translation.md)."""

from __future__ import annotations

import io
import math
import os
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

import numpy as np
from numpy.typing import NDArray

from ..bvh import (
    BvhMotion,
    fold_position_channels,
    forward_kinematics,
    point_joint_bvh,
    write_bvh,
)
from ..errors import InputError
from ..kinematics import GRAVITY, KinematicsRecording
from ..numtext import JsonArray, json_blocks, plain, write_text_blocks
from ..results import timings_document
from ..vocabulary import TRANSLATION_OUTPUT_FORMATS
from .result_npz import write_document_npz

if TYPE_CHECKING:
    from ..translation import TranslationResult

PathLike = str | os.PathLike[str]


OUTPUT_FORMATS: Final[tuple[str, ...]] = TRANSLATION_OUTPUT_FORMATS
"""Output formats of :func:`write_translation`."""



def translation_to_dict(result: TranslationResult, recording: KinematicsRecording | None = None,
                        *, decimals: int = 5) -> dict[str, Any]:
    """JSON-ready dict (:func:`translation_document` with its arrays as lists)."""
    return dict(plain(translation_document(result, recording, decimals=decimals)))


def translation_document(result: TranslationResult,
                         recording: KinematicsRecording | None = None, *,
                         decimals: int = 5) -> dict[str, Any]:
    """The JSON document: root path (m), translation, contacts, floor, quality, timings; with
    the recording, its frame times, the feet and toes used, the corrected feet's heights (m,
    +Y, per frame), the input's length unit (metres per unit) and the reader's notes. Its
    per-frame arrays are :class:`~bonefit.estimation.numtext.JsonArray` (written in bulk)."""
    out: dict[str, Any] = {
        "kind": "translation",
        "method": result.method,
        "fps": result.fps,
        "frames": int(result.root.shape[0]),
        "units": "m",
        "up": "+Y",
        "root_joint": recording.root if recording is not None else None,
        "root": JsonArray(result.root, decimals),
        "translation": JsonArray(result.translation, decimals),
        "floor": np.round(result.floor, decimals).tolist(),
        "contacts": [str(c) for c in result.contacts],
        "quality": {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                    for k, v in result.quality.items()},
        "timings": timings_document(result.timings),
    }
    if recording is not None:
        positions = result.joint_positions("the feet's heights")
        out["time"] = JsonArray(recording.time, 6)
        out["feet"] = {"left": recording.left_foot, "right": recording.right_foot,
                       "toes": dict(recording.toes)}
        out["foot_heights"] = {
            side: JsonArray(positions[:, recording.index(foot), 1], decimals)
            for side, foot in (("left", recording.left_foot), ("right", recording.right_foot))}
        out["input_length_unit_m"] = recording.length_scale
        out["notes"] = list(recording.notes)
    return out


def _point_joint_bvh(result: TranslationResult, recording: KinematicsRecording,
                     scale: float) -> BvhMotion:
    """The corrected positions as a BVH of rotation channels under a moving root (see
    :func:`bonefit.estimation.bvh.point_joint_bvh`), for inputs without a rotation hierarchy."""
    return point_joint_bvh(recording.joints, result.joint_positions("a point-joint BVH") / scale,
                           recording.index(recording.root), 1.0 / result.fps)


def translated_bvh(result: TranslationResult, recording: KinematicsRecording) -> BvhMotion:
    """The BVH of a translation result, written so that every BVH reader agrees.

    A BVH input comes back with the estimated root path in the root's position channels and
    its position channels folded (:func:`bonefit.estimation.bvh.fold_position_channels`: constant
    ones into OFFSETs, moving ones over a zero OFFSET). Other inputs (and a BVH whose root
    has no position channels) become a point-joint BVH in centimetres (the BVH's unit) of
    the corrected positions.
    """
    motion = recording.bvh
    if motion is None:
        return _point_joint_bvh(result, recording, 0.01)
    j = motion.names.index(recording.root)
    values = motion.values.copy()
    start = sum(len(c) for c in motion.channels[:j])
    axes = {"Xposition": 0, "Yposition": 1, "Zposition": 2}
    chans = motion.channels[j]
    if not any(c in axes for c in chans):
        return _point_joint_bvh(result, recording, recording.length_scale)
    shift = result.translation / recording.length_scale
    # The root's world position is its parents' transform applied to its channels; parents
    # here are static dummies at most (Bandai's joint_Root), so shifting the channels by the
    # world translation rotated into the parent frame is exact.
    parent = motion.parents[j]
    if parent >= 0:
        _, rots = forward_kinematics(motion)
        shift = rots[parent].inv().apply(shift)
    for k, ch in enumerate(chans):
        if ch in axes:
            values[:, start + k] = values[0, start + k] + shift[:, axes[ch]]
    return fold_position_channels(motion.with_values(values))


def write_translation(result: TranslationResult, recording: KinematicsRecording,
                      path: PathLike | io.TextIOBase, *, format: str) -> None:
    """Write a translation result.

    Parameters
    ----------
    result : TranslationResult
    recording : KinematicsRecording
        The input the result was estimated from.
    path : path or text stream
    format : {"kinematics-csv", "bvh", "mvnx", "json", "npz"}
        ``kinematics-csv``: every column of the input CSV in its order, positions corrected
        (input must be a kinematics CSV); ``bvh``: the input BVH with the root path in the
        root's position channels (a point-joint BVH in cm for other inputs); ``mvnx``: the
        input MVNX with corrected segment positions; ``json``: root path, contacts, quality;
        ``npz``: the JSON's names, its arrays binary (:mod:`bonefit.estimation.io.result_npz`).
    """
    if format not in OUTPUT_FORMATS:
        raise InputError(f"unknown output format {format!r}; use {', '.join(OUTPUT_FORMATS)}",
                         field="format")
    if format in ("json", "npz"):
        started = time.perf_counter()
        document = translation_document(result, recording)
        if "write_s" not in result.timings:  # the time to build it; the dump is not timed
            document["timings"]["write_s"] = time.perf_counter() - started
        if format == "npz":
            if isinstance(path, io.TextIOBase):
                raise InputError("NPZ output needs a file path", field="format")
            write_document_npz(document, path)
        else:
            write_text_blocks(json_blocks(document, separators=(",", ":")), path)
    elif format == "bvh":
        write_bvh(translated_bvh(result, recording), path)
    elif format == "kinematics-csv":
        if recording.table is None:
            raise InputError(f"cannot write a kinematics CSV for a {recording.source_format} "
                             "input; use bvh or json", field="format")
        _emit(path, _kinematics_csv_text(result, recording))
    else:
        from .mvnx import write_mvnx

        if isinstance(path, io.TextIOBase):
            raise InputError("MVNX output needs a file path", field="format")
        write_mvnx(result, recording, path)


def write_translation_files(result: TranslationResult, recording: KinematicsRecording,
                            outputs: Sequence[tuple[str, PathLike]]) -> TranslationResult:
    """Write every output, the JSON last with a ``timings.write_s`` covering them all.

    Parameters
    ----------
    result : TranslationResult
        With ``read_s`` in its timings when the caller measured it.
    recording : KinematicsRecording
    outputs : sequence of (format, path)
        Formats of :func:`write_translation` and where to write them.

    Returns
    -------
    TranslationResult
        ``result`` with ``timings["write_s"]``, seconds spent writing.
    """
    started = time.perf_counter()
    for fmt, path in sorted(outputs, key=lambda item: item[0] == "json"):
        if fmt == "json":
            result = replace(result, timings={**result.timings,
                                              "write_s": time.perf_counter() - started})
        write_translation(result, recording, path, format=fmt)
    return replace(result, timings={**result.timings, "write_s": time.perf_counter() - started})


def _emit(path: PathLike | io.TextIOBase, text: str) -> None:
    if isinstance(path, io.TextIOBase):
        path.write(text)
    else:
        Path(path).write_text(text, encoding="utf-8")


def _kinematics_csv_text(result: TranslationResult, recording: KinematicsRecording) -> str:
    assert recording.table is not None
    table = recording.table.copy()
    col = {h: i for i, h in enumerate(recording.columns)}
    corrected = result.joint_positions("a kinematics CSV") / recording.length_scale
    for j, name in enumerate(recording.joints):
        for k, a in enumerate("xyz"):
            table[:, col[f"{name}.D{a}"]] = corrected[:, j, k]
    out = io.StringIO()
    out.write(",".join(recording.columns) + "\n")
    np.savetxt(out, table, fmt="%.10g", delimiter=",")
    return out.getvalue()


def write_kinematics_csv(recording: KinematicsRecording, path: PathLike | io.TextIOBase, *,
                         positions: NDArray[np.float64] | None = None,
                         length_units_m: float = 0.01) -> None:
    """Write a recording in the kinematics-CSV layout (``Time``, ``<Joint>.Dx/.Dy/.Dz`` in
    cm, ``<Foot>.ax/.ay/.az`` in g for sensor-frame accelerations).

    Parameters
    ----------
    recording : KinematicsRecording
    path : path or text stream
    positions : ndarray, shape (F, J, 3), optional
        Positions to write instead of the recording's (metres).
    length_units_m : float
        Metres per written length unit (0.01: cm).
    """
    pos = recording.positions if positions is None else positions
    names = ["Time"]
    cols = [recording.time[:, None]]
    for k, axis in enumerate("xyz"):
        names += [f"{j}.D{axis}" for j in recording.joints]
        cols.append(pos[:, :, k] / length_units_m)
    scale = GRAVITY if recording.acceleration_frame == "sensor" else 1.0
    for axis_k, axis in enumerate("xyz"):
        for foot, acc in recording.accelerations.items():
            names.append(f"{foot}.a{axis}")
            cols.append(acc[:, axis_k:axis_k + 1] / scale)
    for foot, flags in recording.contacts.items():
        names.append(f"{foot}.c")
        cols.append(flags[:, None].astype(float))
    out = io.StringIO()
    out.write(",".join(names) + "\n")
    np.savetxt(out, np.concatenate(cols, axis=1), fmt="%.10g", delimiter=",")
    _emit(path, out.getvalue())
