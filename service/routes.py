"""The HTTP endpoints: recordings, jobs, results, and the operational probes."""

from __future__ import annotations

import asyncio
import hashlib
import json
import logging
import math
import re
import shutil
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Body, Depends, Header, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse, StreamingResponse
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from .artifacts import tenant_prefix
from .auth import metrics_guard, tenant
from .jobs import TERMINAL, Job, Recording, new_id
from .kinds import MEDIA_TYPES
from .problems import (
    MEDIA_TYPE,
    UNAVAILABLE_RETRY_SECONDS,
    Problem,
    not_found,
    outage_types,
    unavailable,
)
from .runtime import Runtime
from .schemas import (
    JobCreate,
    JobOut,
    JobPage,
    RecordingOut,
    RecordingPage,
    ResultFormat,
    Status,
    UploadFormat,
)
from .storage import free_bytes, is_storage_full, refuse_when_full, storage_full
from .uploads import UploadSink, cap_summary, receive_multipart, receive_raw, sniff, too_large

log = logging.getLogger("bonefit.service")

Tenant = Annotated[str, Depends(tenant)]
Limit = Annotated[int, Query(ge=1, le=1000, description="Page size.")]
Cursor = Annotated[str | None, Query(max_length=64, pattern=r"^[0-9a-z]+$",
                                     description="next_cursor of the last page.")]
ID = re.compile(r"^[0-9a-z]{1,64}$")
SSE_POLL_SECONDS = 0.5
SSE_KEEPALIVE_SECONDS = 15.0
MULTIPART_OVERHEAD = 64 * 1024

PROBLEM_RESPONSES: dict[int | str, dict[str, Any]] = {
    code: {"description": "Problem details (RFC 9457)",
           "content": {MEDIA_TYPE: {"schema": {"type": "object"}}}}
    for code in (400, 401, 403, 404, 408, 409, 413, 422, 503)}

v1 = APIRouter(prefix="/v1", responses=PROBLEM_RESPONSES)
ops = APIRouter()


def runtime_of(request: Request) -> Runtime:
    """The app's back-ends."""
    runtime: Runtime = request.app.state.runtime
    return runtime


MAX_FILENAME_BYTES = 200
"""Longest stored file name in UTF-8 bytes (file systems allow 255 bytes, not characters)."""
MAX_CONTENT_TYPE_CHARS = 200
"""Longest stored media type (the job store's column)."""


def _clean_filename(name: str | None) -> str | None:
    """The base name without control characters (they break logs and some databases),
    cut to ``MAX_FILENAME_BYTES`` UTF-8 bytes, keeping its extension."""
    if not name:
        return None
    name = "".join(c for c in name if c.isprintable()).replace("\\", "/").rsplit("/", 1)[-1]
    if name in ("", ".", ".."):
        return None
    if len(name.encode()) > MAX_FILENAME_BYTES:
        suffix = _suffix(name)
        stem = name[:len(name) - len(suffix)].encode()[:MAX_FILENAME_BYTES - len(suffix)]
        name = stem.decode("utf-8", "ignore") + suffix  # "ignore": a character cut in two
    return name


def _stored_content_type(value: str, field: str) -> str:
    """``value`` if it can be stored as a recording's media type, else the 422 problem."""
    if len(value) > MAX_CONTENT_TYPE_CHARS or not value.isprintable():
        what = (f"{len(value)} characters" if len(value) > MAX_CONTENT_TYPE_CHARS
                else "a control character")
        raise Problem(422, "Invalid request", f"{field}: expected a media type of at most "
                      f"{MAX_CONTENT_TYPE_CHARS} printable characters, got {what}",
                      slug="invalid-request", field=field)
    return value


def _suffix(filename: str | None) -> str:
    """A safe file extension (``.csv``) of ``filename``, or ""; format sniffing uses it."""
    suffix = Path(filename or "").suffix
    return suffix.lower() if re.fullmatch(r"\.[A-Za-z0-9]{1,10}", suffix) else ""


def _plain(value: Any) -> Any:
    """JSON-ready: numpy scalars and paths as plain values, NaN and infinities as null."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, bool | int | str) or value is None:
        return value
    try:
        number = float(value)
    except (TypeError, ValueError):
        return str(value)
    return number if math.isfinite(number) else None


def _job_url(job_id: str) -> str:
    return f"/v1/jobs/{job_id}"


def _page_cursor(items: list[Any], limit: int) -> str | None:
    return items[-1].id if len(items) == limit else None


# ---------------------------------------------------------------------------- recordings


@v1.post("/recordings", status_code=201, response_model=RecordingOut, summary="Upload a recording",
         openapi_extra={"requestBody": {"required": True, "content": {
             "application/octet-stream": {"schema": {"type": "string", "format": "binary"}},
             "multipart/form-data": {"schema": {"type": "object", "properties": {
                 "file": {"type": "string", "format": "binary"}}}}}}})
async def upload_recording(
    request: Request, who: Tenant,
    filename: Annotated[str | None, Query(max_length=255)] = None,
    format: Annotated[UploadFormat, Query()] = "auto",
) -> JSONResponse:
    """Stream the body (or the form's ``file`` field) to storage, hash it, and sniff it."""
    runtime = runtime_of(request)
    settings = runtime.settings
    limit = settings.max_upload_bytes
    content_type = _stored_content_type(
        request.headers.get("content-type", "application/octet-stream"), "Content-Type")
    multipart = content_type.lower().startswith("multipart/form-data")
    length = request.headers.get("content-length")
    if length and length.isdigit() and int(length) > limit + (MULTIPART_OVERHEAD if multipart
                                                               else 0):
        raise too_large(limit)
    rec_id = new_id()
    filename = _clean_filename(filename)
    suffix = _suffix(filename)
    spool = settings.data_dir / "uploads" / rec_id
    # only a sensor CSV's summary uses the row count
    with refuse_when_full("upload spool"):
        sink = UploadSink(spool / "upload.part", limit,
                          count_rows=format in ("auto", "sensor-csv"))
    storage = "upload spool"  # where a full disk is named (507) if one stops the upload
    try:
        if multipart:
            part_name, part_type = await receive_multipart(request.stream(), content_type, sink)
            filename = filename or _clean_filename(part_name)
            content_type = (_stored_content_type(part_type, "file.Content-Type") if part_type
                            else "application/octet-stream")
        else:
            await receive_raw(request.stream(), sink)
        await sink.close()
        request.app.state.upload_bytes.inc(sink.size)
        if content_type.startswith("application/x-www-form-urlencoded"):
            content_type = "application/octet-stream"  # curl --data-binary's default: not a form
        suffix = suffix or _suffix(filename)
        # the readers name the file in their messages: give it the client's name
        path = sink.path.rename(spool / (filename or f"recording{suffix}"))
        sink.path = path
        fmt, summary = await run_in_threadpool(sniff, path, format, filename,
                                                 sink.rows.rows if sink.rows else None)
        key = f"{tenant_prefix(who)}/recordings/{rec_id}{suffix}"
        rec = Recording(id=rec_id, tenant=who, key=key,
                        filename=filename, content_type=content_type, format=fmt,
                        size=sink.size, sha256=sink.sha256.hexdigest(), created_at=time.time(),
                        summary=cap_summary(_plain(summary)))
        storage = "artifact storage"
        await run_in_threadpool(runtime.artifacts.put_file, rec.key, path)
        try:
            storage = "job database"
            await run_in_threadpool(runtime.store.add_recording, rec)
        except Exception:
            await run_in_threadpool(runtime.artifacts.delete, rec.key)
            raise
    except Exception as exc:
        if is_storage_full(exc):
            raise storage_full(storage) from exc
        raise
    finally:
        sink.discard()  # a malformed, partial or refused upload leaves nothing behind
        shutil.rmtree(spool, ignore_errors=True)
    body = RecordingOut.of(rec).model_dump(mode="json")
    return JSONResponse(body, status_code=201,
                        headers={"Location": f"/v1/recordings/{rec.id}"})


@v1.get("/recordings", response_model=RecordingPage, summary="List recordings")
async def list_recordings(request: Request, who: Tenant, limit: Limit = 50,
                          cursor: Cursor = None) -> RecordingPage:
    """The tenant's recordings, newest first."""
    recs = await run_in_threadpool(runtime_of(request).store.list_recordings, who,
                                   before=cursor, limit=limit)
    return RecordingPage(items=[RecordingOut.of(r) for r in recs],
                         next_cursor=_page_cursor(recs, limit))


async def _recording(request: Request, who: str, rec_id: str) -> Recording:
    if not ID.match(rec_id):
        raise not_found("recording", rec_id)
    rec = await run_in_threadpool(runtime_of(request).store.get_recording, who, rec_id)
    if rec is None:
        raise not_found("recording", rec_id)
    return rec


@v1.get("/recordings/{recording_id}", response_model=RecordingOut, summary="Get a recording")
async def get_recording(request: Request, who: Tenant, recording_id: str) -> RecordingOut:
    """Metadata of one recording."""
    return RecordingOut.of(await _recording(request, who, recording_id))


@v1.delete("/recordings/{recording_id}", status_code=204, summary="Delete a recording")
async def delete_recording(request: Request, who: Tenant, recording_id: str) -> Response:
    """Delete the recording and its bytes (jobs and their results stay)."""
    runtime = runtime_of(request)
    rec = await _recording(request, who, recording_id)
    # the bytes first: on a full disk that frees the space the database needs to record the
    # deletion (a failure after it leaves a record without bytes, which a retry deletes)
    await run_in_threadpool(runtime.artifacts.delete, rec.key)
    if await run_in_threadpool(runtime.store.delete_recording, who, recording_id) is None:
        raise not_found("recording", recording_id)
    return Response(status_code=204)


# ---------------------------------------------------------------------------------- jobs


def _job_response(job: Job, status_code: int = 200,
                  headers: dict[str, str] | None = None) -> JSONResponse:
    body = JobOut.of(job).model_dump(mode="json")
    return JSONResponse(body, status_code=status_code,
                        headers={"ETag": f'"{job.id}.{job.version}"', **(headers or {})})


@v1.post("/jobs", status_code=202, response_model=JobOut, summary="Submit a job",
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
        stored = await run_in_threadpool(runtime.store.add_job, job)
    if stored.id != job.id:
        if stored.request_hash != digest:
            raise Problem(422, "Idempotency key reused",
                          "this Idempotency-Key was used with a different request body",
                          slug="idempotency-key-reused", field="Idempotency-Key")
        return _job_response(stored, 202, {"Location": _job_url(stored.id)})
    try:
        await run_in_threadpool(runtime.queue.enqueue, job.id)
    except Exception as exc:
        await _not_queued(runtime, job.id)
        if is_storage_full(exc):
            raise storage_full("job queue") from None
        raise Problem(503, "Queue unavailable", "the job could not be queued; retry later",
                      slug="queue-unavailable", headers={"Retry-After": "5"}) from None
    return _job_response(job, 202, {"Location": _job_url(job.id)})


async def _not_queued(runtime: Runtime, job_id: str) -> None:
    """Fail a job the queue refused and free its Idempotency-Key, so that the client's retry
    with the same key runs the job instead of returning this failure. If even that cannot be
    written, the job stays queued with its key: the reaper sends it once the queue is back,
    and the retry gets it."""
    try:
        await run_in_threadpool(runtime.store.update_job, job_id, {
            "status": "failed", "finished_at": time.time(), "stage": "failed",
            "idempotency_key": None,
            "error": {"type": "urn:bonefit:problem:queue-unavailable", "title": "Queue "
                      "unavailable", "status": 503, "detail": "the job could not be queued"}},
            expect={"status": "queued"})
    except Exception:
        log.exception("job %s: not queued, and could not be marked failed; the reaper will "
                      "send it", job_id)


async def _input_exists(request: Request, who: str, rec_id: str, field: str) -> None:
    rec = await run_in_threadpool(runtime_of(request).store.get_recording, who, rec_id)
    if rec is None:
        raise Problem(422, "Unknown recording", f"no recording {rec_id!r}",
                      slug="unknown-recording", field=field)


async def _job(request: Request, who: str, job_id: str) -> Job:
    if not ID.match(job_id):
        raise not_found("job", job_id)
    job = await run_in_threadpool(runtime_of(request).store.get_job, job_id, who)
    if job is None:
        raise not_found("job", job_id)
    return job


@v1.get("/jobs", response_model=JobPage, summary="List jobs")
async def list_jobs(request: Request, who: Tenant, status: Status | None = None,
                    kind: Annotated[str | None, Query(max_length=40, pattern=r"^[a-z0-9-]+$")]
                    = None,
                    limit: Limit = 50, cursor: Cursor = None) -> JobPage:
    """The tenant's jobs, newest first, filtered by status and kind."""
    jobs = await run_in_threadpool(runtime_of(request).store.list_jobs, who, status=status,
                                   kind=kind, before=cursor, limit=limit)
    return JobPage(items=[JobOut.of(j) for j in jobs], next_cursor=_page_cursor(jobs, limit))


@v1.get("/jobs/{job_id}", response_model=JobOut, summary="Get a job",
        responses={304: {"description": "Not modified (If-None-Match)"}})
async def get_job(request: Request, who: Tenant, job_id: str,
                  if_none_match: Annotated[str | None, Header()] = None) -> Response:
    """The job with an ETag; 304 when it matches If-None-Match."""
    job = await _job(request, who, job_id)
    etag = f'"{job.id}.{job.version}"'
    if if_none_match and etag in [t.strip().removeprefix("W/") for t in if_none_match.split(",")]:
        return Response(status_code=304, headers={"ETag": etag})
    return _job_response(job)


@v1.post("/jobs/{job_id}/cancel", status_code=202, response_model=JobOut, summary="Cancel a job")
async def cancel_job(request: Request, who: Tenant, job_id: str) -> JSONResponse:
    """Cancel a queued job now; a running one stops at its next progress report."""
    store = runtime_of(request).store
    job = await _job(request, who, job_id)
    if job.status == "queued":
        done = await run_in_threadpool(store.update_job, job_id, {
            "status": "cancelled", "finished_at": time.time(), "stage": "cancelled"},
            expect={"status": "queued"})
        if done:
            return _job_response(done, 202)
    elif job.status == "running":
        done = await run_in_threadpool(store.update_job, job_id, {
            "cancel_requested": True, "message": "cancelling"}, expect={"status": "running"})
        if done:
            return _job_response(done, 202)
    job = await _job(request, who, job_id)
    if job.status == "cancelled":
        return _job_response(job, 202)
    raise Problem(409, "Job already finished", f"the job is {job.status}; nothing to cancel",
                  slug="job-finished", job_status=job.status)


def _event_version(last_event_id: str | None) -> int:
    """The job version a reconnecting client has seen, -1 for none or for an id this server
    never sent (only event ids it sent, decimal versions, skip anything)."""
    text = (last_event_id or "").strip()
    return int(text) if text.isascii() and text.isdigit() and len(text) <= 18 else -1


@v1.get("/jobs/{job_id}/events", summary="Follow a job (Server-Sent Events)",
        response_class=StreamingResponse,
        responses={200: {"content": {"text/event-stream": {}}}})
async def job_events(request: Request, who: Tenant, job_id: str,
                     last_event_id: Annotated[str | None, Header()] = None
                     ) -> StreamingResponse:
    """``status`` and ``progress`` events (data: the job) until the job ends, then ``end``;
    a reconnecting client's ``Last-Event-ID`` (a job version) skips what it has seen."""
    await _job(request, who, job_id)
    store = runtime_of(request).store
    seen = _event_version(last_event_id)

    async def stream() -> AsyncIterator[str]:
        version, status, quiet_since = seen, None, time.monotonic()
        while True:
            try:
                job = await run_in_threadpool(store.get_job, job_id, who)
            except outage_types():
                # the response has started: no 503 any more, but an event the client can act
                # on (reconnect with Last-Event-ID after the hinted delay), not a cut stream
                problem = unavailable().body(request.url.path)
                yield f"retry: {UNAVAILABLE_RETRY_SECONDS * 1000}\nevent: error\n" \
                      f"data: {json.dumps(problem)}\n\n"
                return
            if job is None:
                yield "event: end\ndata: {}\n\n"
                return
            if job.version == seen and status is None:
                status = job.status  # the client saw this version: no event for it
            if job.version != version:
                event = "status" if job.status != status else "progress"
                data = json.dumps(JobOut.of(job).model_dump(mode="json"))
                yield f"id: {job.version}\nevent: {event}\ndata: {data}\n\n"
                version, status, quiet_since = job.version, job.status, time.monotonic()
            if job.status in TERMINAL:
                yield f"event: end\ndata: {json.dumps({'status': job.status})}\n\n"
                return
            if time.monotonic() - quiet_since > SSE_KEEPALIVE_SECONDS:
                yield ": keep-alive\n\n"
                quiet_since = time.monotonic()
            await asyncio.sleep(SSE_POLL_SECONDS)

    return StreamingResponse(stream(), media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})


@v1.get("/jobs/{job_id}/result", summary="Download a result",
        responses={200: {"content": {t: {} for t in MEDIA_TYPES.values()}}})
async def job_result(request: Request, who: Tenant, job_id: str,
                     format: ResultFormat = "json") -> StreamingResponse:
    """The result file in ``format``; 409 while the job has not succeeded."""
    runtime = runtime_of(request)
    job = await _job(request, who, job_id)
    if job.status != "succeeded":
        raise Problem(409, "No result", f"the job is {job.status}; results exist once it has "
                      "succeeded", slug="job-not-finished", job_status=job.status)
    key = job.results.get(format)
    if key is None or not await run_in_threadpool(runtime.artifacts.exists, key):
        raise Problem(404, "Not found", f"this job has no {format} result", slug="not-found",
                      field="format")
    name = f"{job.kind}-{job.id}.{format}"
    return StreamingResponse(runtime.artifacts.iter_bytes(key), media_type=MEDIA_TYPES[format],
                             headers={"Content-Disposition": f'attachment; filename="{name}"'})


# ---------------------------------------------------------------------------- operations


@ops.get("/healthz", summary="Liveness")
async def healthz() -> dict[str, str]:
    """The process is up."""
    return {"status": "ok"}


@ops.get("/readyz", summary="Readiness", responses={503: PROBLEM_RESPONSES[503]})
async def readyz(request: Request) -> JSONResponse:
    """Database, queue and storage answer, the data directory has room, and a worker is alive;
    else 503 naming the checks that failed."""
    runtime = runtime_of(request)
    checks = {"database": runtime.store.ping, "queue": runtime.queue.ping,
              "storage": runtime.artifacts.ping, "disk": lambda: _disk_check(runtime),
              "workers": lambda: _workers_check(runtime)}
    results: dict[str, str] = {}
    for name, check in checks.items():
        try:
            await asyncio.wait_for(run_in_threadpool(check), timeout=5.0)
            results[name] = "ok"
        except NotReady as exc:
            results[name] = str(exc)
        except Exception as exc:
            results[name] = f"unavailable: {type(exc).__name__}"
    failed = {k: v for k, v in results.items() if v != "ok"}
    if failed:
        detail = "; ".join(f"{k}: {v}" for k, v in failed.items())
        raise Problem(503, "Not ready", detail, slug="not-ready", checks=results,
                      failed=sorted(failed))
    return JSONResponse({"status": "ok", "checks": results})


class NotReady(Exception):
    """A readiness check failed; the message says why."""


MIB = 1024 * 1024


def _disk_check(runtime: Runtime) -> None:
    minimum = runtime.settings.min_free_bytes
    if minimum <= 0:
        return
    free = free_bytes(runtime.settings.data_dir)
    if free < minimum:
        raise NotReady(f"low space: {free / MIB:.0f} MiB free in the data directory "
                       f"(BONEFIT_MIN_FREE_BYTES: {minimum / MIB:.0f} MiB)")


def _workers_check(runtime: Runtime) -> None:
    window = runtime.settings.worker_stale_seconds
    if not runtime.store.live_workers(time.time() - window):
        raise NotReady(f"no worker alive: none has reported in the last {window:.0f} s "
                       "(start `bonefit worker`, or `bonefit serve` with workers)")


@ops.get("/metrics", summary="Prometheus metrics", dependencies=[Depends(metrics_guard)],
         responses={200: {"content": {CONTENT_TYPE_LATEST: {}}}, 401: PROBLEM_RESPONSES[401],
                    403: PROBLEM_RESPONSES[403]})
async def metrics(request: Request) -> Response:
    """Prometheus text exposition."""
    data = await run_in_threadpool(generate_latest, request.app.state.registry)
    return Response(data, media_type=CONTENT_TYPE_LATEST)
