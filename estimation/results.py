"""Result of skeleton estimation."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
from numpy.typing import NDArray

TIMING_STAGES: Final[tuple[str, ...]] = ("read_s", "estimate_s", "write_s")
"""Stages every JSON result's ``timings`` names, in seconds (``docs/skeleton-io.md``)."""


def timings_document(timings: Mapping[str, float]) -> dict[str, float]:
    """The ``timings`` of a JSON result: ``read_s``, ``estimate_s``, ``write_s`` first, then
    any finer stage the producer measured (e.g. ``contacts_s``).

    Parameters
    ----------
    timings : mapping of str to float
        Seconds per stage, as measured; a stage missing from it did not happen in the
        producer (a recording built in memory is not read) and is written as 0.0.

    Returns
    -------
    dict of str to float
        Finite seconds (a non-finite value becomes 0.0).
    """
    def seconds(value: float) -> float:
        number = float(value)
        return number if math.isfinite(number) else 0.0

    out = {stage: seconds(timings.get(stage, 0.0)) for stage in TIMING_STAGES}
    out.update({str(k): seconds(v) for k, v in timings.items() if k not in out})
    return out


@dataclass(frozen=True, eq=False)
class JointOffset:
    """Where a joint sits in one sensor's frame.

    Attributes
    ----------
    sensor : str
        Segment name of the sensor the offset is expressed in.
    local : ndarray, shape (3,)
        Joint centre in that sensor's frame, metres.
    """

    sensor: str
    local: NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class SkeletonResult:
    """Joint centres, bone lengths and segment orientations of one recording.

    Attributes
    ----------
    method : str
        Estimator used (``"llsf"``, ``"gdke"``, ``"reduced"``, ``"auto"``...).
    fps : float
        Frame rate, Hz.
    joints : mapping of str to ndarray, shape (F, 3)
        Global position of each joint of ``estimation.model.JOINTS`` per frame, metres,
        source frame. No NaN: gaps are filled.
    offsets : mapping of str to JointOffset
        For each joint located in a sensor frame, that sensor and the local position.
    bone_lengths : mapping of str to float
        Length of each segment between its two joints, metres.
    orientations : mapping of str to ndarray, shape (F, 4)
        Segment frame → source frame rotation per frame, scalar-first quaternions.
        Segment frames: x left, y up (along the bone for limbs), z forward.
    quality : mapping of str to mapping
        Per-joint figures: ``rms_residual_m``, ``singular_value_ratio``, ``range_of_motion_deg``,
        ``hinge`` (bool), ``estimator``, and any method-specific ones.
    warnings : tuple of str
        Human-readable warnings (small range of motion, ill-conditioned joints, filled gaps).
    timings : mapping of str to float
        Seconds spent per stage (``read_s``, ``estimate_s``, ``write_s``; see
        :func:`timings_document`). ``estimate_skeleton`` measures ``estimate_s``; whoever
        reads and writes adds the others (``io.write_skeleton_files``, the CLI, the service).
    """

    method: str
    fps: float
    joints: Mapping[str, NDArray[np.float64]]
    offsets: Mapping[str, JointOffset]
    bone_lengths: Mapping[str, float]
    orientations: Mapping[str, NDArray[np.float64]]
    quality: Mapping[str, Mapping[str, Any]]
    warnings: tuple[str, ...] = ()
    timings: Mapping[str, float] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return int(next(iter(self.joints.values())).shape[0])
