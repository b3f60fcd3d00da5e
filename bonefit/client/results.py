"""Typed views of the service's JSON: recordings, jobs and the result documents.

The results are the library's own dataclasses (``SkeletonResult``, ``TranslationResult`` of
``bonefit.estimation.results``), read from the JSON contract (README "The skeleton JSON",
docs/skeleton-io.md, docs/translation.md) by the library's readers
(``bonefit.estimation.io.result_json``): modules that need numpy only, so the client loads
neither scipy nor the estimators.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from bonefit.estimation.io.result_json import result_from_dict as result_from_dict
from bonefit.estimation.results import JointOffset as JointOffset
from bonefit.estimation.results import JointQuality as JointQuality
from bonefit.estimation.results import SkeletonResult as SkeletonResult
from bonefit.estimation.results import TranslationQuality as TranslationQuality
from bonefit.estimation.results import TranslationResult as TranslationResult

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


Result = SkeletonResult | TranslationResult
"""A job's result: a skeleton or a translation."""
