"""``/v1/jobs/{id}/events``: follow a job as Server-Sent Events."""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import AsyncIterator
from typing import Annotated

from fastapi import APIRouter, Header, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import StreamingResponse

from ..jobs import TERMINAL, JobStore
from ..problems import UNAVAILABLE_RETRY_SECONDS, outage_types, unavailable
from ..schemas import JobOut
from .common import Tenant, find_job, runtime_of

router = APIRouter()

SSE_POLL_SECONDS = 0.5
SSE_KEEPALIVE_SECONDS = 15.0


def _event_version(last_event_id: str | None) -> int:
    """The job version a reconnecting client has seen, -1 for none or for an id this server
    never sent (only event ids it sent, decimal versions, skip anything)."""
    text = (last_event_id or "").strip()
    return int(text) if text.isascii() and text.isdigit() and len(text) <= 18 else -1


def _outage_event(path: str) -> str:
    """The response has started: no 503 any more, but an event the client can act on
    (reconnect with Last-Event-ID after the hinted delay), not a cut stream."""
    problem = unavailable().body(path)
    return (f"retry: {UNAVAILABLE_RETRY_SECONDS * 1000}\nevent: error\n"
            f"data: {json.dumps(problem)}\n\n")


async def _stream(store: JobStore, job_id: str, who: str, seen: int,
                  path: str) -> AsyncIterator[str]:
    """Poll the job, sending an event per new version, until it ends."""
    version, status, quiet_since = seen, None, time.monotonic()
    while True:
        try:
            job = await run_in_threadpool(store.get_job, job_id, who)
        except outage_types():
            yield _outage_event(path)
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


@router.get("/jobs/{job_id}/events", summary="Follow a job (Server-Sent Events)",
            response_class=StreamingResponse,
            responses={200: {"content": {"text/event-stream": {}}}})
async def job_events(request: Request, who: Tenant, job_id: str,
                     last_event_id: Annotated[str | None, Header()] = None
                     ) -> StreamingResponse:
    """``status`` and ``progress`` events (data: the job) until the job ends, then ``end``;
    a reconnecting client's ``Last-Event-ID`` (a job version) skips what it has seen."""
    await find_job(request, who, job_id)
    stream = _stream(runtime_of(request).store, job_id, who, _event_version(last_event_id),
                     request.url.path)
    return StreamingResponse(stream, media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})
