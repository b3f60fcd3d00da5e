"""Results of skeleton and root-translation estimation (numpy only: the client reads them
from the JSON documents without scipy)."""

from __future__ import annotations

import functools
import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, fields
from typing import Any, Final, Self

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


class Figures(Mapping[str, Any]):
    """Quality figures with typed attributes: the base of :class:`JointQuality` and
    :class:`TranslationQuality` (frozen dataclasses whose fields are the typed figures,
    None when not reported, and ``details``, every other figure by key).

    It is a read-only mapping of every reported figure by its JSON key, typed ones first, so
    the JSON documents keep their keys: the writers take ``dict(quality)`` or ``.items()``,
    the readers build one with :meth:`of`.
    """

    details: Mapping[str, Any]

    @classmethod
    def typed_figures(cls) -> tuple[str, ...]:
        """The names of the typed figures (every field but ``details``), in order."""
        return _typed_figures(cls)

    @classmethod
    def of(cls, figures: Mapping[str, Any]) -> Self:
        """The figures of a mapping by key (an instance of this class is returned as is)."""
        if isinstance(figures, cls):
            return figures
        typed = {k: figures[k] for k in cls.typed_figures() if figures.get(k) is not None}
        rest = {k: v for k, v in figures.items() if k not in typed}
        return cls(**typed, details=rest)  # type: ignore[call-arg]  # the dataclass's fields

    def __getitem__(self, key: str) -> Any:
        if key in self.typed_figures():
            value = getattr(self, key)
            if value is not None:
                return value
        return self.details[key]

    def __iter__(self) -> Iterator[str]:
        typed = self.typed_figures()
        yield from (k for k in typed if getattr(self, k) is not None)
        yield from (k for k in self.details if k not in typed or getattr(self, k) is None)

    def __len__(self) -> int:
        return sum(1 for _ in self)


@functools.cache
def _typed_figures(cls: type[Figures]) -> tuple[str, ...]:
    return tuple(f.name for f in fields(cls) if f.name != "details")  # type: ignore[arg-type]


@dataclass(frozen=True, eq=False)
class JointQuality(Figures):
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
class TranslationQuality(Figures):
    """Quality figures of a root path (``TranslationResult.quality``; see :class:`Figures`
    for the mapping by JSON key).

    Attributes
    ----------
    foot_skate_cm_s, foot_skate_p95_cm_s : float or None
        Mean and 95th percentile of the horizontal speed of planted contact points, cm/s.
    floor_penetration_cm, floor_penetration_p99_cm : float or None
        Deepest contact point below the floor, and the 99th percentile, cm.
    max_vertical_jump_cm : float or None
        Largest frame-to-frame discontinuity of the hips height,
        |Δy(t) − (Δy(t−1) + Δy(t+1))/2|, cm.
    max_vertical_step_cm : float or None
        Largest frame-to-frame change of the hips height, cm.
    closure_cm : float or None
        Horizontal hips distance from the first to the last frame, cm.
    path_length_m : float or None
        Length of the horizontal hips path, m.
    contact_fraction : float or None
        Share of frames with a foot in contact.
    flight_frames : int or None
        Frames with no foot in contact.
    details : mapping of str to Any
        The method's own figures (``contacts_source``, ``floor_levels``, ``ground_m``, ...).
    """

    foot_skate_cm_s: float | None = None
    foot_skate_p95_cm_s: float | None = None
    floor_penetration_cm: float | None = None
    floor_penetration_p99_cm: float | None = None
    max_vertical_jump_cm: float | None = None
    max_vertical_step_cm: float | None = None
    closure_cm: float | None = None
    path_length_m: float | None = None
    contact_fraction: float | None = None
    flight_frames: int | None = None
    details: Mapping[str, Any] = field(default_factory=dict)


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
    quality : TranslationQuality
        The path's figures (``closure_cm``, ``floor_penetration_cm``, ...) and the method's
        own ones; any mapping given is converted.
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
    quality: TranslationQuality
    method: str
    fps: float
    timings: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # typed, whatever mapping the producer (or a JSON reader) gave
        object.__setattr__(self, "quality", TranslationQuality.of(self.quality))

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
