"""Read → estimate → write: the one pipeline behind ``bonefit skeleton``, ``bonefit translate``
and the service's jobs.

Each run reads a recording, estimates, writes the requested files and returns the result with
the three timings of the timings contract (``read_s``, ``estimate_s``, ``write_s``; see
docs/skeleton-io.md). The callers differ only in how they report: the CLI draws a progress bar
and prints what the reader detected, a worker reports stages to its job.

The estimators (and scipy) are imported on the first run, so that importing this module, the
CLI's ``--help`` and the service's API process stay light.
"""

from __future__ import annotations

import importlib
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

from .io.outputs import SkeletonOutputs as SkeletonOutputs  # the skeleton run's outputs
from .progress import Progress, no_progress, scaled
from .recording import SensorRecording
from .results import JointOffset, SkeletonResult

if TYPE_CHECKING:
    from .io.tracker import TrackerLayout
    from .kinematics import KinematicsRecording
    from .translation import TranslationResult

PathLike = str | Path

READ_SHARE: Final[float] = 0.1
"""Share of a run's ``progress`` the read takes (0 to it), on a long take about its share of
the time."""

WRITE_SHARE: Final[float] = 0.2
"""Share of a run's ``progress`` the writes take (the last one); the estimate has the rest."""

SAME_AS_INPUT: Final[str] = "input"
"""Output format of a translation meaning "the recording's own format"."""


@dataclass(frozen=True)
class SensorSource:
    """A 6-DOF sensor recording and how to read it (``io.sensors.read_recording``)."""

    path: PathLike
    format: str = "auto"
    units: str | None = None
    fps: float | None = None
    stations: Mapping[Any, Any] | str | None = None
    tracker_layout: str | TrackerLayout | None = None


@dataclass(frozen=True)
class SkeletonRunOptions:
    """Options of :func:`bonefit.estimation.skeleton.estimate_skeleton` a run passes on (its
    defaults), as the CLI's flags and a job's params give them: every one, whatever the
    method. The run passes the method those its options class takes
    (``skeleton.METHOD_OPTIONS[method]``) and ignores the others (``optimizer`` of ``auto``).
    ``up`` is the source frame's up direction; ``smooth`` None the method's default;
    ``offsets`` a calibration: the run then calls ``estimate_skeleton_from_offsets`` (``up``,
    ``i0`` and ``smooth`` only)."""

    method: str = "auto"
    optimizer: str = "least-squares"
    torso: str = "llsf"
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    i0: int = 0
    anthropometry: str | Mapping[str, float] = "aist"
    w_s: float = 0.01
    w_l: float = 0.01
    smooth: bool | None = None
    offsets: Mapping[str, JointOffset] | None = None


@dataclass(frozen=True)
class SkeletonRun:
    """What a skeleton run produced: the result (timings with read_s, estimate_s, write_s)
    and the recording it was estimated from."""

    result: SkeletonResult
    recording: SensorRecording


def run_skeleton(source: SensorSource, options: SkeletonRunOptions, outputs: SkeletonOutputs,
                 *, progress: Progress | None = None,
                 on_read: Callable[[SensorRecording], None] | None = None) -> SkeletonRun:
    """Read a sensor recording, estimate its skeleton, write the requested files.

    Parameters
    ----------
    source : SensorSource
    options : SkeletonRunOptions
    outputs : SkeletonOutputs
    progress : callable, optional
        ``progress(fraction, stage)`` of the whole run, from the calling thread, fraction
        non-decreasing: stage ``reading`` from 0 to :data:`READ_SHARE` (per parsed block of a
        sensor CSV), the estimate's stages, then ``writing`` from ``1 -``
        :data:`WRITE_SHARE` to 1 (per block of JSON numbers and per file).
    on_read : callable, optional
        Called with the recording before estimating (a caller's own checks or messages;
        it may raise).

    Returns
    -------
    SkeletonRun

    Raises
    ------
    BonefitError
        Bad input (from the reader, the estimator or ``on_read``).
    OSError
        A file could not be read or written.
    """
    report = progress or no_progress
    report(0.0, "reading")
    from .io.sensors import read_recording

    import_meanwhile(SKELETON_MODULES)
    started = time.perf_counter()
    recording = read_recording(source.path, format=source.format, units=source.units,
                               fps=source.fps, stations=source.stations,
                               tracker_layout=source.tracker_layout,
                               progress=_share(progress, 0.0, READ_SHARE))
    read_s = time.perf_counter() - started
    # waits for the imports begun above if they are not done
    from .io.skeleton import write_skeleton_files
    report(READ_SHARE, "reading")
    from .skeleton import estimate_skeleton, estimate_skeleton_from_offsets

    if on_read is not None:
        on_read(recording)
    estimating = _share(progress, READ_SHARE, 1.0 - WRITE_SHARE)
    if options.offsets is None:
        result = estimate_skeleton(recording, method=options.method, progress=estimating,
                                   **_method_values(options))
    else:
        # a calibration's offsets leave nothing to fit: the method's options do not apply
        result = estimate_skeleton_from_offsets(recording, options.offsets, up=options.up,
                                                i0=options.i0, smooth=bool(options.smooth),
                                                progress=estimating)
    result = replace(result, timings={**result.timings, "read_s": read_s})
    result = write_skeleton_files(result, outputs,
                                  progress=_share(progress, 1.0 - WRITE_SHARE, 1.0))
    return SkeletonRun(result, recording)


@dataclass(frozen=True)
class KinematicsSource:
    """An inertial-suit recording and how to read it (``io.kinematics.read_kinematics``)."""

    path: PathLike
    format: str = "auto"
    accelerations: PathLike | None = None
    left_foot: str | None = None
    right_foot: str | None = None
    acceleration_units: str | None = None
    units: str | float = "auto"
    subject: str | None = None


@dataclass(frozen=True)
class TranslationRunOptions:
    """The method of :func:`bonefit.estimation.translation.estimate_translation` and its options
    (``ContactOptions`` fields, or ``window`` and ``eps``); empty: the method's defaults."""

    method: str = "contact"
    options: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class TranslationRun:
    """What a translation run produced: the result (timings with read_s, estimate_s,
    write_s) and the recording it was estimated from."""

    result: TranslationResult
    recording: KinematicsRecording


def run_translation(source: KinematicsSource, options: TranslationRunOptions,
                    outputs: Sequence[tuple[str, PathLike]], *,
                    progress: Progress | None = None,
                    on_read: Callable[[KinematicsRecording], None] | None = None,
                    ) -> TranslationRun:
    """Read kinematics (and foot accelerations), estimate the root path, write the outputs.

    Parameters
    ----------
    source : KinematicsSource
    options : TranslationRunOptions
    outputs : sequence of (format, path)
        Formats of ``io.kinematics.write_translation`` or :data:`SAME_AS_INPUT`; the JSON is
        written last, its ``write_s`` covering the others.
    progress, on_read
        As in :func:`run_skeleton` (the read and the writes report only their start and
        end).

    Returns
    -------
    TranslationRun

    Raises
    ------
    BonefitError
        Bad input (from the reader, the estimator or ``on_read``).
    OSError
        A file could not be read or written.
    """
    report = progress or no_progress
    report(0.0, "reading")
    from .io.kinematics import read_kinematics
    from .io.translation_files import write_translation_files
    from .translation import estimate_translation

    started = time.perf_counter()
    recording = read_kinematics(
        source.path, format=source.format, accelerations=source.accelerations,
        left_foot=source.left_foot, right_foot=source.right_foot,
        acceleration_units=source.acceleration_units, units=source.units,
        subject=source.subject)
    read_s = time.perf_counter() - started
    report(READ_SHARE, "reading")
    if on_read is not None:
        on_read(recording)
    result = estimate_translation(recording, method=options.method,
                                  left_foot=recording.left_foot, right_foot=recording.right_foot,
                                  progress=_share(progress, READ_SHARE, 1.0 - WRITE_SHARE),
                                  **options.options)
    report(1.0 - WRITE_SHARE, "writing")
    result = replace(result, timings={**result.timings, "read_s": read_s})
    files = [(recording.source_format if fmt == SAME_AS_INPUT else fmt, path)
             for fmt, path in outputs]
    result = write_translation_files(result, recording, files)
    report(1.0, "writing")
    return TranslationRun(result, recording)


SKELETON_MODULES: Final[tuple[str, ...]] = (f"{__package__}.skeleton",
                                            f"{__package__}.io.skeleton")
"""What a skeleton run needs after the read: the estimators and writers (and scipy)."""


def import_meanwhile(modules: Sequence[str]) -> threading.Thread:
    """Import ``modules`` in a thread (daemon), so that they load while the caller parses a
    file: the parse is numpy array operations, which release the interpreter lock, and an
    import is about a second of the start of a run. A failed import is left to the
    caller's own import of the module, which raises it."""

    def load() -> None:
        for name in modules:
            try:
                importlib.import_module(name)
            except ImportError:
                return

    thread = threading.Thread(target=load, name="bonefit-import", daemon=True)
    thread.start()
    return thread


def _method_values(options: SkeletonRunOptions) -> dict[str, Any]:
    """The run's values of the fields its method's options class has (none for an unknown
    method, which ``estimate_skeleton`` then refuses; ``smooth`` None: the method's
    default)."""
    from .skeleton import METHOD_OPTIONS

    cls = METHOD_OPTIONS.get(options.method)
    names = {f.name for f in fields(cls)} if cls is not None else set()
    return {f.name: getattr(options, f.name) for f in fields(options)
            if f.name in names}


def _share(progress: Progress | None, start: float, stop: float) -> Progress | None:
    """``progress`` mapped onto [start, stop] of the run; None without one."""
    return None if progress is None else scaled(progress, start, stop)

