"""Results of skeleton and root-translation estimation (numpy only: the client reads them
from the JSON documents without scipy)."""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, fields
from typing import Any, Final

import numpy as np
from numpy.typing import NDArray

from .errors import InputError

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
class JointQuality(Mapping[str, Any]):
    """Quality figures of one joint (``SkeletonResult.quality[joint]``).

    The figures every located joint may carry are typed attributes (None: not reported for
    this joint); the estimator's own figures are in ``details`` (see ``joints.JointFit`` and
    ``limbs.LimbFit``). It is also a read-only mapping of every reported figure by its JSON
    key (``quality["hinge"]``, ``quality.get("data_sd_m")``), so the JSON document's
    ``quality[joint]`` object keeps its keys: the writer takes ``dict(quality)``, the reader
    and ``SkeletonResult`` build one with :meth:`of`.

    Attributes
    ----------
    estimator : str or None
        How the joint was located (``"llsf"``, ``"llsf-shared-slip"``, ``"gdke"``,
        ``"limb-improved"``, ``"given offset"``, ...).
    reliability : str or None
        ``"data"``, ``"prior-assisted"`` or ``"prior"`` (see ``estimate_skeleton``).
    rms_residual_m : float or None
        RMS distance between the joint's two reconstructions, metres.
    range_of_motion_deg : float or None
        Range of the relative rotation of its two sensors, degrees.
    hinge : bool or None
        Whether the joint behaved as a hinge.
    data_weight : float or None
        The data's share against the priors along their weakest direction.
    data_sd_m : float or None
        How well the recording alone locates the centre, metres (shared slip model).
    details : mapping of str to Any
        Every other figure, by key.
    """

    estimator: str | None = None
    reliability: str | None = None
    rms_residual_m: float | None = None
    range_of_motion_deg: float | None = None
    hinge: bool | None = None
    data_weight: float | None = None
    data_sd_m: float | None = None
    details: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def of(cls, figures: Mapping[str, Any]) -> JointQuality:
        """The quality of a mapping of figures by key (a ``JointQuality`` is returned
        as is)."""
        if isinstance(figures, JointQuality):
            return figures
        typed = {k: figures[k] for k in _TYPED_QUALITY if figures.get(k) is not None}
        rest = {k: v for k, v in figures.items() if k not in typed}
        return cls(**typed, details=rest)

    def __getitem__(self, key: str) -> Any:
        if key in _TYPED_QUALITY:
            value = getattr(self, key)
            if value is not None:
                return value
        return self.details[key]

    def __iter__(self) -> Iterator[str]:
        yield from (k for k in _TYPED_QUALITY if getattr(self, k) is not None)
        yield from (k for k in self.details if k not in _TYPED_QUALITY
                    or getattr(self, k) is None)

    def __len__(self) -> int:
        return sum(1 for _ in self)


_TYPED_QUALITY: Final[tuple[str, ...]] = tuple(
    f.name for f in fields(JointQuality) if f.name != "details")


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
        Global position of each joint of ``bonefit.estimation.model.JOINTS`` per frame, metres,
        source frame. No NaN: gaps are filled.
    offsets : mapping of str to JointOffset
        For each joint located in a sensor frame, that sensor and the local position.
    bone_lengths : mapping of str to float
        Length of each segment between its two joints, metres.
    orientations : mapping of str to ndarray, shape (F, 4)
        Segment frame → source frame rotation per frame, scalar-first quaternions.
        Segment frames: x left, y up (along the bone for limbs), z forward.
    quality : mapping of str to JointQuality
        Per-joint figures (:class:`JointQuality`; any mapping given is converted):
        ``rms_residual_m``, ``singular_value_ratio``, ``range_of_motion_deg``, ``hinge``
        (bool), ``estimator``, and any method-specific ones.
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
    quality: Mapping[str, JointQuality]
    warnings: tuple[str, ...] = ()
    timings: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # typed per joint, whatever mapping the producer (or a JSON reader) gave
        object.__setattr__(self, "quality", {
            name: JointQuality.of(figures) for name, figures in self.quality.items()})

    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return int(next(iter(self.joints.values())).shape[0])


@dataclass(frozen=True, eq=False)
class TranslationResult:
    """A root path estimated for an inertial-suit recording.

    Attributes
    ----------
    root : ndarray, shape (F, 3)
        World position of the root joint (hips) per frame, metres, +Y up.
    translation : ndarray, shape (F, 3)
        Offset added to every joint of the input positions per frame, metres.
    positions : ndarray, shape (F, J, 3), or None
        Corrected global joint positions, metres, in the recording's joint order. None for
        a result read from the translation JSON (``io.translation_from_dict``), which does
        not carry them (J times the size of ``root``; the document has the feet's heights):
        the writers that need them (BVH, kinematics CSV, MVNX) raise InputError then.
    contacts : ndarray of str, shape (F,)
        ``"left"``, ``"right"``, ``"both"`` or ``"none"`` per frame.
    floor : ndarray, shape (F,)
        Height of the floor under the body per frame, metres, in the frame of the foot
        contact points (heel/toe joints, not the sole surface).
    quality : dict
        ``foot_skate_cm_s`` (mean horizontal speed of planted contact points),
        ``floor_penetration_cm`` (deepest contact point below the floor),
        ``max_vertical_jump_cm`` (largest frame-to-frame discontinuity of the hips height:
        |Δy(t) − (Δy(t−1) + Δy(t+1))/2|), ``max_vertical_step_cm``, ``closure_cm``
        (horizontal hips distance first→last frame), ``path_length_m`` (horizontal hips
        path), ``contact_fraction`` and method-specific figures.
    method : str
    fps : float
    timings : dict
        Seconds per stage.

    Notes
    -----
    Estimated by ``bonefit.estimation.translation.estimate_translation`` (Hachaj & Ogiela
    2018, or the contact model; docs/translation.md).
    """

    root: NDArray[np.float64]
    translation: NDArray[np.float64]
    positions: NDArray[np.float64] | None
    contacts: NDArray[np.str_]
    floor: NDArray[np.float64]
    quality: dict[str, Any]
    method: str
    fps: float
    timings: Mapping[str, float] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return int(self.root.shape[0])

    def joint_positions(self, purpose: str) -> NDArray[np.float64]:
        """``positions``, or InputError saying that ``purpose`` needs them (a result read
        from JSON has none)."""
        if self.positions is None:
            raise InputError(f"{purpose} needs every joint's position, which a translation "
                             "read from JSON does not carry; write it from the estimate",
                             field="positions")
        return self.positions
