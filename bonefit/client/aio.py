"""The asynchronous client: the same calls as :class:`bonefit.client.Client`, awaited."""

from __future__ import annotations

import asyncio
import os
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Mapping
from pathlib import Path
from types import TracebackType
from typing import Any

import httpx

from .calls import (
    STREAM_READ_SECONDS,
    UPLOAD_CHUNK,
    JobLike,
    ProgressCallback,
    RecordingLike,
    StreamCursor,
    check_succeeded,
    default_headers,
    event_job,
    id_of,
    job_of,
    new_idempotency_key,
    raise_for_problem,
    recording_of,
    result_of,
    submit_body,
    upload_query,
)
from .results import Job, Recording, Result
from .sse import aevents
from .sync import TransientStatus
from .transport import RetryPolicy, is_transient_error, is_transient_status, retry_after


async def _file_chunks(path: Path) -> AsyncIterator[bytes]:
    with path.open("rb") as f:
        while chunk := await asyncio.to_thread(f.read, UPLOAD_CHUNK):
            yield chunk


class AsyncClient:
    """An asynchronous client of a bonefit server (see :class:`bonefit.client.Client`)."""

    def __init__(self, base_url: str, api_key: str | None = None, *, timeout: float = 60.0,
                 retry: RetryPolicy | None = None,
                 transport: httpx.AsyncBaseTransport | None = None,
                 sleep: Callable[[float], Awaitable[None]] = asyncio.sleep) -> None:
        self.retry = retry or RetryPolicy()
        self._sleep = sleep
        self._timeout = timeout
        self._http = httpx.AsyncClient(base_url=base_url, headers=default_headers(api_key),
                                       timeout=timeout, transport=transport)

    async def __aenter__(self) -> AsyncClient:
        return self

    async def __aexit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                        tb: TracebackType | None) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        """Close the connections."""
        await self._http.aclose()

    async def request(self, method: str, url: str, *,
                      content: Callable[[], Any] | None = None, **kwargs: Any) -> httpx.Response:
        """Send with retries of transient failures; ProblemError for an error answer."""
        for attempt in range(self.retry.attempts):
            last = attempt == self.retry.attempts - 1
            try:
                if content is not None:
                    kwargs["content"] = content()
                response = await self._http.request(method, url, **kwargs)
            except httpx.TransportError as exc:
                if last or not is_transient_error(exc):
                    raise
                await self._sleep(self.retry.delay(attempt))
                continue
            if is_transient_status(response.status_code) and not last:
                await self._sleep(self.retry.delay(attempt, retry_after(response)))
                continue
            raise_for_problem(response)
            return response
        raise AssertionError("unreachable")  # pragma: no cover

    async def upload(self, source: str | os.PathLike[str] | bytes, *, format: str = "auto",
                     filename: str | None = None) -> Recording:
        """Upload a recording from a path or bytes."""
        if isinstance(source, bytes):
            data = source
            return recording_of(await self.request(
                "POST", "/v1/recordings", params=upload_query(source, format, filename),
                content=lambda: data))
        path = Path(source)
        size = path.stat().st_size
        return recording_of(await self.request(
            "POST", "/v1/recordings", params=upload_query(path, format, filename),
            content=lambda: _file_chunks(path),
            headers={"Content-Length": str(size), "Content-Type": "application/octet-stream"}))

    async def recording(self, recording: RecordingLike) -> Recording:
        """One recording."""
        return recording_of(await self.request("GET", f"/v1/recordings/{id_of(recording)}"))

    async def submit(self, kind: str, recording: RecordingLike,
                     params: Mapping[str, Any] | None = None, *,
                     inputs: Mapping[str, RecordingLike] | None = None,
                     idempotency_key: str | None = None) -> Job:
        """Queue a job; retries reuse one ``Idempotency-Key``."""
        body = submit_body(kind, recording, params, inputs)
        key = idempotency_key or new_idempotency_key()
        return job_of(await self.request("POST", "/v1/jobs", json=body,
                                         headers={"Idempotency-Key": key}))

    async def job(self, job: JobLike) -> Job:
        """The job as it is now."""
        return job_of(await self.request("GET", f"/v1/jobs/{id_of(job)}"))

    async def jobs(self, *, status: str | None = None, kind: str | None = None,
                   limit: int = 50) -> list[Job]:
        """The newest jobs of the tenant (one page)."""
        query = {k: v for k, v in (("status", status), ("kind", kind)) if v}
        page = (await self.request("GET", "/v1/jobs", params={**query, "limit": limit})).json()
        return [Job.from_json(item) for item in page["items"]]

    async def cancel(self, job: JobLike) -> Job:
        """Ask the job to stop."""
        return job_of(await self.request("POST", f"/v1/jobs/{id_of(job)}/cancel"))

    async def wait(self, job: JobLike, *, progress: ProgressCallback | None = None,
                   timeout: float | None = None) -> Job:
        """Follow the job's events until it ends (reconnecting with ``Last-Event-ID``)."""
        job_id = id_of(job)
        deadline = None if timeout is None else time.monotonic() + timeout
        cursor = StreamCursor()
        failures = 0
        while True:
            try:
                if await self._follow(job_id, cursor, progress):
                    return await self.job(job_id)
                failures = 0
            except (httpx.TransportError, TransientStatus) as exc:
                if isinstance(exc, httpx.TransportError) and not is_transient_error(exc):
                    raise
                if failures + 1 >= self.retry.attempts:
                    raise
                after = exc.after if isinstance(exc, TransientStatus) else None
                await self._sleep(self.retry.delay(failures, after))
                failures += 1
            if deadline is not None and time.monotonic() > deadline:
                raise TimeoutError(f"job {job_id} did not end within {timeout} s")

    async def _follow(self, job_id: str, cursor: StreamCursor,
                      progress: ProgressCallback | None) -> bool:
        headers = {"Last-Event-ID": cursor.last_id} if cursor.last_id else {}
        timeout = httpx.Timeout(self._timeout, read=STREAM_READ_SECONDS)
        async with self._http.stream("GET", f"/v1/jobs/{job_id}/events", headers=headers,
                                     timeout=timeout) as response:
            if response.status_code >= 400:
                await response.aread()
                if is_transient_status(response.status_code):
                    raise TransientStatus(response.status_code, retry_after(response))
                raise_for_problem(response)
            async for event in aevents(response.aiter_lines()):
                if cursor.see(event):
                    return True
                current = event_job(event.data)
                if current is not None and progress is not None:
                    progress(current)
        return False

    async def download(self, job: JobLike, format: str = "json",
                       path: str | os.PathLike[str] | None = None) -> bytes | Path:
        """A result file: its bytes, or written to ``path`` and that path."""
        data = (await self.request("GET", f"/v1/jobs/{id_of(job)}/result",
                                   params={"format": format})).content
        if path is None:
            return data
        target = Path(path)
        partial = target.with_name(target.name + ".part")
        await asyncio.to_thread(partial.write_bytes, data)
        partial.replace(target)
        return target

    async def result(self, job: JobLike) -> Result:
        """The job's result JSON, typed."""
        data = await self.download(job, "json")
        assert isinstance(data, bytes)
        return result_of(data)

    async def run(self, source: str | os.PathLike[str] | bytes, kind: str,
                  params: Mapping[str, Any] | None = None, *, format: str = "auto",
                  inputs: Mapping[str, RecordingLike] | None = None,
                  progress: ProgressCallback | None = None,
                  timeout: float | None = None) -> Result:
        """Upload, submit, wait and read the result; ProblemError if the job failed."""
        recording = await self.upload(source, format=format)
        job = await self.submit(kind, recording, params, inputs=inputs)
        done = check_succeeded(await self.wait(job, progress=progress, timeout=timeout))
        return await self.result(done)
