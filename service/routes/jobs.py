"""``/v1/jobs``: submit (idempotent), list, get (with ETag) and cancel jobs."""

from __future__ import annotations

import hashlib
import json
import logging
import time
from typing import Annotated

from fastapi import APIRouter, Body, Header, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse

from ..failures import queue_refused_problem
from ..jobs import Job, Status, new_id
from ..problems import Problem
from ..runtime import Runtime
from ..schemas import JobCreate, JobOut, JobPage
from ..storage import is_storage_full, refuse_when_full, storage_full
from .common import Cursor, Limit, Tenant, find_job, page_cursor, runtime_of

log = logging.getLogger("bonefit.service")

router = APIRouter()


def _job_url(job_id: str) -> str:
    return f"/v1/jobs/{job_id}"


def _job_response(job: Job, status_code: int = 200,
                  headers: dict[str, str] | None = None) -> JSONResponse:
    body = JobOut.of(job).model_dump(mode="json")
    return JSONResponse(body, status_code=status_code,
                        headers={"ETag": f'"{job.id}.{job.version}"', **(headers or {})})


@router.post("/jobs", status_code=202, response_model=JobOut, summary="Submit a job",
             responses={202: {"headers": {"Location": {"schema": {"type": "string"}}}}})
async def create_job(
    request: Request, who: Tenant, body: Annotated[JobCreate, Body()],
    idempotency_key: Annotated[str | None, Header(
        min_length=1, max_length=255, pattern=r"^[\x21-\x7e]([\x20-\x7e]*[\x21-\x7e])?$",
        description="1 to 255 printable ASCII characters, not starting or ending with a "
                    "space.")] = None,
) -> JSONResponse:
    """Validate params for the kind, check the recordings exist, queue the job."""
    runtime = runtime_of(request)
    payload = body.model_dump(mode="json")
    digest = hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()
    await _input_exists(request, who, body.recording_id, "recording_id")
    inputs = {k: v for k, v in payload["inputs"].items() if v is not None}
    for name, rec_id in inputs.items():
        await _input_exists(request, who, rec_id, f"inputs.{name}")
    now = time.time()
    job = Job(id=new_id(), tenant=who, kind=body.kind, recording_id=body.recording_id,
              params=payload["params"], inputs=inputs, created_at=now, updated_at=now,
              idempotency_key=idempotency_key, request_hash=digest if idempotency_key else None)
    with refuse_when_full("job database"):
        stored, refused = await run_in_threadpool(_store_and_enqueue, runtime, job)
    if stored.id != job.id:
        if stored.request_hash != digest:
            raise Problem(422, "Idempotency key reused",
                          "this Idempotency-Key was used with a different request body",
                          slug="idempotency-key-reused", field="Idempotency-Key")
        return _job_response(stored, 202, {"Location": _job_url(stored.id)})
    if refused is not None:
        await _not_queued(runtime, job.id)
        if is_storage_full(refused):
            raise storage_full("job queue") from None
        raise Problem(503, "Queue unavailable", "the job could not be queued; retry later",
                      slug="queue-unavailable", headers={"Retry-After": "5"}) from None
    return _job_response(job, 202, {"Location": _job_url(job.id)})


def _store_and_enqueue(runtime: Runtime, job: Job) -> tuple[Job, Exception | None]:
    """Store the job, then (a new one) queue its id, in one trip to a worker thread (each
    trip waits for a thread and the interpreter lock: milliseconds on a loaded host, all of
    it in the job's queue wait). The stored job (another one for a reused Idempotency-Key,
    not queued again) and the queue's error, if it refused; the store's errors are raised.

    The job is stored without waiting for the disk and made durable after it is queued, so
    that a worker can claim it while the database flushes (on PostgreSQL the flush was most
    of the queue wait); the client hears of it only once it is durable. A worker's claim
    commits durably, which flushes the job's row first.
    """
    stored = runtime.store.add_job(job, durable=False)
    if stored.id == job.id:
        try:
            runtime.queue.enqueue(job.id)
        except Exception as exc:
            return stored, exc  # withdrawn by a durable update, which flushes the row too
    runtime.store.wait_durable()  # another request's job (a reused key) may be as new
    return stored, None


async def _not_queued(runtime: Runtime, job_id: str) -> None:
    """Fail a job the queue refused and free its Idempotency-Key, so that the client's retry
    with the same key runs the job instead of returning this failure. If even that cannot be
    written, the job stays queued with its key: the reaper sends it once the queue is back,
    and the retry gets it."""
    try:
        await run_in_threadpool(runtime.store.withdraw, job_id,
                                queue_refused_problem().body(), time.time())
    except Exception:
        log.exception("job %s: not queued, and could not be marked failed; the reaper will "
                      "send it", job_id)


async def _input_exists(request: Request, who: str, rec_id: str, field: str) -> None:
    rec = await run_in_threadpool(runtime_of(request).store.get_recording, who, rec_id)
    if rec is None:
        raise Problem(422, "Unknown recording", f"no recording {rec_id!r}",
                      slug="unknown-recording", field=field)


@router.get("/jobs", response_model=JobPage, summary="List jobs")
async def list_jobs(request: Request, who: Tenant, *, status: Status | None = None,
                    kind: Annotated[str | None, Query(max_length=40, pattern=r"^[a-z0-9-]+$")]
                    = None,
                    limit: Limit = 50, cursor: Cursor = None) -> JobPage:
    """The tenant's jobs, newest first, filtered by status and kind."""
    jobs = await run_in_threadpool(runtime_of(request).store.list_jobs, who, status=status,
                                   kind=kind, before=cursor, limit=limit)
    return JobPage(items=[JobOut.of(j) for j in jobs], next_cursor=page_cursor(jobs, limit))


@router.get("/jobs/{job_id}", response_model=JobOut, summary="Get a job",
            responses={304: {"description": "Not modified (If-None-Match)"}})
async def get_job(request: Request, who: Tenant, job_id: str,
                  if_none_match: Annotated[str | None, Header()] = None) -> Response:
    """The job with an ETag; 304 when it matches If-None-Match."""
    job = await find_job(request, who, job_id)
    etag = f'"{job.id}.{job.version}"'
    if if_none_match and etag in [t.strip().removeprefix("W/") for t in if_none_match.split(",")]:
        return Response(status_code=304, headers={"ETag": etag})
    return _job_response(job)


@router.post("/jobs/{job_id}/cancel", status_code=202, response_model=JobOut,
             summary="Cancel a job")
async def cancel_job(request: Request, who: Tenant, job_id: str) -> JSONResponse:
    """Cancel a queued job now; a running one stops at its next progress report."""
    store = runtime_of(request).store
    job = await find_job(request, who, job_id)
    if job.status is Status.QUEUED:
        done = await run_in_threadpool(store.cancel_queued, job_id, time.time())
        if done:
            return _job_response(done, 202)
    elif job.status is Status.RUNNING:
        done = await run_in_threadpool(store.request_cancel, job_id)
        if done:
            return _job_response(done, 202)
    job = await find_job(request, who, job_id)
    if job.status is Status.CANCELLED:
        return _job_response(job, 202)
    raise Problem(409, "Job already finished", f"the job is {job.status}; nothing to cancel",
                  slug="job-finished", job_status=job.status)
