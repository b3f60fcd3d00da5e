"""Typed views of the service's JSON: recordings, jobs and the result documents.

Built from the JSON contract (README "The skeleton JSON", docs/skeleton-io.md,
docs/translation.md) with numpy only: the client never imports the estimation code.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

TERMINAL = frozenset({"succeeded", "failed", "cancelled"})
"""Job statuses that do not change any more."""


@dataclass(frozen=True)
class Recording:
    """An uploaded recording (``POST /v1/recordings``)."""

    id: str
    filename: str | None
    size: int
    sha256: str
    format: str
    summary: Mapping[str, Any]

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> Recording:
        """From the API's representation."""
        return cls(id=doc["id"], filename=doc.get("filename"), size=int(doc["size"]),
                   sha256=doc["sha256"], format=doc["format"], summary=doc.get("summary") or {})


@dataclass(frozen=True)
class Job:
    """A job (``GET /v1/jobs/{id}``); ``raw`` keeps the whole document."""

    id: str
    kind: str
    status: str
    recording_id: str
    params: Mapping[str, Any]
    fraction: float
    stage: str
    message: str | None
    attempts: int
    error: Mapping[str, Any] | None
    results: Mapping[str, str]
    raw: Mapping[str, Any] = field(repr=False, compare=False)

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> Job:
        """From the API's representation."""
        progress = doc.get("progress") or {}
        return cls(id=doc["id"], kind=doc["kind"], status=doc["status"],
                   recording_id=doc["recording_id"], params=doc.get("params") or {},
                   fraction=float(progress.get("fraction", 0.0)),
                   stage=str(progress.get("stage", "")), message=progress.get("message"),
                   attempts=int(doc.get("attempts", 0)), error=doc.get("error"),
                   results=doc.get("results") or {}, raw=doc)

    @property
    def done(self) -> bool:
        """Whether the job has ended (succeeded, failed or cancelled)."""
        return self.status in TERMINAL


@dataclass(frozen=True)
class JointOffset:
    """Where a joint sits in one sensor's frame: ``local`` (3,), metres."""

    sensor: str
    local: tuple[float, float, float]

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> JointOffset:
        """From one ``offsets`` entry."""
        x, y, z = (float(v) for v in doc["local"])
        return cls(str(doc["sensor"]), (x, y, z))


@dataclass(frozen=True)
class JointQuality:
    """How well one joint is determined (the skeleton result's ``quality[joint]``).

    ``rms_residual_m`` and ``data_sd_m`` in metres, ``range_of_motion_deg`` in degrees;
    ``None`` where the document has no finite value. ``extra`` holds every other member.
    """

    reliability: str | None
    data_sd_m: float | None
    rms_residual_m: float | None
    range_of_motion_deg: float | None
    hinge: bool | None
    estimator: str | None
    extra: Mapping[str, Any]

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> JointQuality:
        """From one ``quality`` entry."""
        known = ("reliability", "data_sd_m", "rms_residual_m", "range_of_motion_deg", "hinge",
                 "estimator")
        return cls(reliability=doc.get("reliability"), data_sd_m=_number(doc.get("data_sd_m")),
                   rms_residual_m=_number(doc.get("rms_residual_m")),
                   range_of_motion_deg=_number(doc.get("range_of_motion_deg")),
                   hinge=doc.get("hinge"), estimator=doc.get("estimator"),
                   extra={k: v for k, v in doc.items() if k not in known})


def _number(value: Any) -> float | None:
    return None if value is None else float(value)


def _array(rows: Any, width: int, what: str) -> NDArray[np.float64]:
    """``rows`` as a float array (F, width); ValueError naming ``what`` otherwise."""
    array = np.asarray(rows, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != width:
        raise ValueError(f"{what}: expected F rows of {width} numbers, got shape {array.shape}")
    return array


@dataclass(frozen=True)
class SkeletonResult:
    """A skeleton job's result (``kind: skeleton``).

    Attributes
    ----------
    joints : dict of str to ndarray, shape (F, 3)
        Global joint positions, metres, in the recording's frame.
    orientations : dict of str to ndarray, shape (F, 4)
        Segment → world rotation per frame, quaternions ``w, x, y, z``.
    offsets : dict of str to JointOffset
        Each joint's centre in a sensor's frame: a calibration for later jobs.
    bone_lengths : dict of str to float
        Metres.
    """

    method: str
    fps: float
    frames: int
    joints: Mapping[str, NDArray[np.float64]]
    offsets: Mapping[str, JointOffset]
    bone_lengths: Mapping[str, float]
    orientations: Mapping[str, NDArray[np.float64]]
    quality: Mapping[str, JointQuality]
    warnings: tuple[str, ...]
    timings: Mapping[str, float]

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> SkeletonResult:
        """From the skeleton JSON document."""
        joints = {name: _array(rows, 3, f"joints.{name}") for name, rows in doc["joints"].items()}
        return cls(
            method=str(doc.get("method", "")), fps=float(doc["fps"]), frames=int(doc["frames"]),
            joints=joints,
            offsets={name: JointOffset.from_json(o)
                     for name, o in (doc.get("offsets") or {}).items()},
            bone_lengths={k: float(v) for k, v in (doc.get("bone_lengths") or {}).items()},
            orientations={name: _array(rows, 4, f"orientations.{name}")
                          for name, rows in (doc.get("orientations") or {}).items()},
            quality={k: JointQuality.from_json(v) for k, v in (doc.get("quality") or {}).items()},
            warnings=tuple(str(w) for w in doc.get("warnings") or ()),
            timings={k: float(v) for k, v in (doc.get("timings") or {}).items()})

    def offsets_param(self) -> dict[str, dict[str, Any]]:
        """The ``offsets`` job parameter that reuses this result as a calibration."""
        return {k: {"sensor": o.sensor, "local": list(o.local)} for k, o in self.offsets.items()}


@dataclass(frozen=True)
class TranslationResult:
    """A translation job's result (``kind: translation``).

    Attributes
    ----------
    root : ndarray, shape (F, 3)
        World position of the root joint per frame, metres, +Y up.
    translation : ndarray, shape (F, 3)
        Offset added to every joint per frame, metres.
    floor : ndarray, shape (F,)
        Floor height under the body per frame, metres.
    contacts : tuple of str, length F
        ``left``, ``right``, ``both`` or ``none`` per frame.
    time : ndarray, shape (F,) or None
        Seconds, when the document has it.
    """

    method: str
    fps: float
    frames: int
    root_joint: str | None
    root: NDArray[np.float64]
    translation: NDArray[np.float64]
    floor: NDArray[np.float64]
    contacts: tuple[str, ...]
    quality: Mapping[str, Any]
    timings: Mapping[str, float]
    time: NDArray[np.float64] | None

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> TranslationResult:
        """From the translation JSON document."""
        time = doc.get("time")
        return cls(
            method=str(doc.get("method", "")), fps=float(doc["fps"]), frames=int(doc["frames"]),
            root_joint=doc.get("root_joint"), root=_array(doc["root"], 3, "root"),
            translation=_array(doc["translation"], 3, "translation"),
            floor=np.asarray(doc.get("floor") or [], dtype=np.float64),
            contacts=tuple(str(c) for c in doc.get("contacts") or ()),
            quality=dict(doc.get("quality") or {}),
            timings={k: float(v) for k, v in (doc.get("timings") or {}).items()},
            time=None if time is None else np.asarray(time, dtype=np.float64))


Result = SkeletonResult | TranslationResult


def parse_result(doc: Mapping[str, Any]) -> Result:
    """The typed result of a result JSON document, by its ``kind``."""
    kind = doc.get("kind")
    if kind == "skeleton":
        return SkeletonResult.from_json(doc)
    if kind == "translation":
        return TranslationResult.from_json(doc)
    raise ValueError(f"result document of kind {kind!r}: expected 'skeleton' or 'translation'")
