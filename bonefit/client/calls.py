"""What the synchronous and asynchronous clients share: request bodies and reading answers."""

from __future__ import annotations

import json
import uuid
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import httpx

from .. import __version__
from .errors import ProblemError, problem_of
from .results import Job, Recording, Result, result_from_dict
from .sse import Event
from .transport import auth_headers

STREAM_READ_SECONDS = 60.0
"""Longest silence on an event stream before reconnecting (the server sends a keep-alive
comment every 15 s)."""

UPLOAD_CHUNK = 1024 * 1024

JobLike = Job | Mapping[str, Any] | str
RecordingLike = Recording | Mapping[str, Any] | str
ProgressCallback = Callable[[Job], object]


def default_headers(api_key: str | None) -> dict[str, str]:
    """Headers of every request: the bearer token (if any) and the user agent."""
    return {"User-Agent": f"bonefit-client/{__version__}", **auth_headers(api_key)}


def id_of(thing: JobLike | RecordingLike) -> str:
    """The id of a job or recording given as its object, its JSON or its id."""
    if isinstance(thing, str):
        return thing
    if isinstance(thing, Job | Recording):
        return thing.id
    return str(thing["id"])


def submit_body(kind: str, recording: RecordingLike, params: Mapping[str, Any] | None,
                inputs: Mapping[str, RecordingLike] | None) -> dict[str, Any]:
    """The ``POST /v1/jobs`` body."""
    return {"kind": kind, "recording_id": id_of(recording), "params": dict(params or {}),
            "inputs": {k: id_of(v) for k, v in (inputs or {}).items()}}


def new_idempotency_key() -> str:
    """A fresh key: one per logical submission, kept across its retries."""
    return str(uuid.uuid4())


def upload_query(source: str | Path | bytes, format: str, filename: str | None
                 ) -> dict[str, str]:
    """The query of ``POST /v1/recordings``: the format and the file's name."""
    if filename is None and not isinstance(source, bytes):
        filename = Path(source).name
    query = {"format": format}
    if filename:
        query["filename"] = filename
    return query


def raise_for_problem(response: httpx.Response) -> None:
    """ProblemError for an error response whose body has been read."""
    if response.status_code >= 400:
        raise ProblemError(problem_of(response.status_code,
                                      response.headers.get("content-type", ""), response.content))


def job_of(response: httpx.Response) -> Job:
    """The job in a JSON answer."""
    return Job.from_json(response.json())


def recording_of(response: httpx.Response) -> Recording:
    """The recording in a JSON answer."""
    return Recording.from_json(response.json())


def result_of(content: bytes) -> Result:
    """The typed result of a result JSON download."""
    return result_from_dict(json.loads(content))


def check_succeeded(job: Job) -> Job:
    """``job`` if it succeeded; otherwise ProblemError with its problem (or a made-up one)."""
    if job.status == "succeeded":
        return job
    problem = dict(job.error or {"type": "about:blank", "title": f"Job {job.status}",
                                 "status": 409, "detail": f"job {job.id} is {job.status}"})
    raise ProblemError(problem, job=job.raw)


def event_job(data: str) -> Job | None:
    """The job carried by a ``status``/``progress`` event, if its data is one."""
    try:
        doc = json.loads(data)
    except ValueError:
        return None
    return Job.from_json(doc) if isinstance(doc, dict) and "id" in doc else None


class StreamCursor:
    """Where a client is in a job's event stream: the ``Last-Event-ID`` to resume from."""

    def __init__(self) -> None:
        self.last_id: str | None = None

    def see(self, event: Event) -> bool:
        """Note the event's id; True for the ``end`` event."""
        if event.id:
            self.last_id = event.id
        return event.event == "end"
