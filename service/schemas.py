"""Request and response bodies of the HTTP API (pydantic v2)."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from bonefit.estimation.vocabulary import (
    ResultFormat as ResultFormat,  # re-exported: the API names it here
)

from .jobs import Job, Recording, Status
from .kinds import RecordingFormat, SkeletonParams, TranslationParams
from .uploads import cap_summary

UploadFormat = Literal["auto", RecordingFormat]
RecordingId = Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[0-9a-z]+$")]


def timestamp(seconds: float | None) -> datetime | None:
    """Epoch seconds as an aware UTC datetime."""
    return None if seconds is None else datetime.fromtimestamp(seconds, UTC)


class RecordingOut(BaseModel):
    """An uploaded recording."""

    id: str
    filename: str | None
    content_type: str | None
    size: int
    sha256: str
    format: str
    created_at: datetime
    summary: dict[str, Any] = Field(description="What a quick sniff found: frames, sensors... "
                                    "(at most 16 KiB of JSON; a list cut to its first 256 "
                                    "items has a <key>_total member)")

    @classmethod
    def of(cls, rec: Recording) -> RecordingOut:
        """The representation of ``rec``."""
        return cls(id=rec.id, filename=rec.filename, content_type=rec.content_type,
                   size=rec.size, sha256=rec.sha256, format=rec.format,
                   created_at=datetime.fromtimestamp(rec.created_at, UTC),
                   summary=cap_summary(rec.summary))  # also rows stored before the cap


class RecordingPage(BaseModel):
    """One page of recordings, newest first."""

    items: list[RecordingOut]
    next_cursor: str | None


class _JobCreate(BaseModel):
    model_config = ConfigDict(extra="forbid")

    recording_id: RecordingId


class NoInputs(BaseModel):
    """A kind that takes no extra recordings."""

    model_config = ConfigDict(extra="forbid")


class TranslationInputs(BaseModel):
    """Extra recordings of a translation job."""

    model_config = ConfigDict(extra="forbid")

    accelerations: RecordingId | None = Field(
        None, description="Recording of the feet accelerometers, when not in the kinematics.")


class SkeletonJobCreate(_JobCreate):
    """Estimate a skeleton from a 6-DOF sensor recording."""

    kind: Literal["skeleton"]
    params: SkeletonParams = Field(default_factory=SkeletonParams)
    inputs: NoInputs = Field(default_factory=NoInputs)


class TranslationJobCreate(_JobCreate):
    """Estimate the root translation of an inertial-suit recording."""

    kind: Literal["translation"]
    params: TranslationParams = Field(default_factory=TranslationParams)
    inputs: TranslationInputs = Field(default_factory=TranslationInputs)


JobCreate = Annotated[SkeletonJobCreate | TranslationJobCreate, Field(discriminator="kind")]


class ProgressOut(BaseModel):
    """How far a job is."""

    fraction: float = Field(ge=0, le=1)
    stage: str
    message: str | None


class JobOut(BaseModel):
    """A job, as ``GET /v1/jobs/{id}`` shows it."""

    id: str
    kind: str
    status: Status
    recording_id: str
    params: dict[str, Any]
    inputs: dict[str, str]
    progress: ProgressOut
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    attempts: int
    worker: str | None = Field(description="Host and process id of the worker running it.")
    error: dict[str, Any] | None = Field(description="RFC 9457 problem when it failed.")
    results: dict[str, str] = Field(description="Result format → download URL.")

    @classmethod
    def of(cls, job: Job) -> JobOut:
        """The representation of ``job``."""
        return cls(
            id=job.id, kind=job.kind, status=job.status,
            recording_id=job.recording_id, params=job.params, inputs=job.inputs,
            progress=ProgressOut(fraction=job.fraction, stage=job.stage, message=job.message),
            created_at=datetime.fromtimestamp(job.created_at, UTC),
            started_at=timestamp(job.started_at), finished_at=timestamp(job.finished_at),
            attempts=job.attempts, worker=job.worker if job.status is Status.RUNNING else None,
            error=job.error,
            results={fmt: f"/v1/jobs/{job.id}/result?format={fmt}" for fmt in job.results})


class JobPage(BaseModel):
    """One page of jobs, newest first."""

    items: list[JobOut]
    next_cursor: str | None
