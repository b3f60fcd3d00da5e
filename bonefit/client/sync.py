"""The synchronous client."""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator, Mapping
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
from .sse import events
from .transport import (
    RetryPolicy,
    is_transient_error,
    is_transient_status,
    retry_after,
)


class TransientStatus(Exception):
    """A 429/502/503/504 answer on an event stream or a download: reconnect."""

    def __init__(self, status: int, after: float | None) -> None:
        super().__init__(f"HTTP {status}")
        self.after = after


def _file_chunks(path: Path) -> Iterator[bytes]:
    with path.open("rb") as f:
        while chunk := f.read(UPLOAD_CHUNK):
            yield chunk


class Client:
    """A client of a bonefit server.

    Parameters
    ----------
    base_url : str
        ``http://host:port`` of ``bonefit serve``.
    api_key : str, optional
        Sent as ``Authorization: Bearer <key>``; none for a loopback-only server.
    timeout : float
        Seconds for connecting and for each read of an ordinary request.
    retry : RetryPolicy
        Retries of transient failures (connection errors, 429/502/503/504).
    transport : httpx.BaseTransport, optional
        For tests (``httpx.MockTransport``).
    """

    def __init__(self, base_url: str, api_key: str | None = None, *, timeout: float = 60.0,
                 retry: RetryPolicy | None = None, transport: httpx.BaseTransport | None = None,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.retry = retry or RetryPolicy()
        self._sleep = sleep
        self._timeout = timeout
        self._http = httpx.Client(base_url=base_url, headers=default_headers(api_key),
                                  timeout=timeout, transport=transport)

    def __enter__(self) -> Client:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def close(self) -> None:
        """Close the connections."""
        self._http.close()

    # ------------------------------------------------------------------ plumbing

    def request(self, method: str, url: str, *,
                content: Callable[[], Any] | None = None, **kwargs: Any) -> httpx.Response:
        """Send with retries of transient failures; ProblemError for an error answer.

        ``content`` makes the body afresh for each try (a file is re-read from its start).
        """
        for attempt in range(self.retry.attempts):
            last = attempt == self.retry.attempts - 1
            try:
                if content is not None:
                    kwargs["content"] = content()
                response = self._http.request(method, url, **kwargs)
            except httpx.TransportError as exc:
                if last or not is_transient_error(exc):
                    raise
                self._sleep(self.retry.delay(attempt))
                continue
            if is_transient_status(response.status_code) and not last:
                self._sleep(self.retry.delay(attempt, retry_after(response)))
                continue
            raise_for_problem(response)
            return response
        raise AssertionError("unreachable")  # pragma: no cover

    # ------------------------------------------------------------------ recordings

    def upload(self, source: str | os.PathLike[str] | bytes, *, format: str = "auto",
               filename: str | None = None) -> Recording:
        """Upload a recording from a path or bytes; its summary tells what the server found."""
        if isinstance(source, bytes):
            data = source
            query = upload_query(source, format, filename)
            return recording_of(self.request("POST", "/v1/recordings", params=query,
                                              content=lambda: data))
        path = Path(source)
        size = path.stat().st_size
        query = upload_query(path, format, filename)
        return recording_of(self.request(
            "POST", "/v1/recordings", params=query, content=lambda: _file_chunks(path),
            headers={"Content-Length": str(size), "Content-Type": "application/octet-stream"}))

    def recording(self, recording: RecordingLike) -> Recording:
        """One recording."""
        return recording_of(self.request("GET", f"/v1/recordings/{id_of(recording)}"))

    # ------------------------------------------------------------------ jobs

    def submit(self, kind: str, recording: RecordingLike,
               params: Mapping[str, Any] | None = None, *,
               inputs: Mapping[str, RecordingLike] | None = None,
               idempotency_key: str | None = None) -> Job:
        """Queue a job. Retries reuse one ``Idempotency-Key``, so they never make a second
        job."""
        body = submit_body(kind, recording, params, inputs)
        key = idempotency_key or new_idempotency_key()
        return job_of(self.request("POST", "/v1/jobs", json=body,
                                   headers={"Idempotency-Key": key}))

    def job(self, job: JobLike) -> Job:
        """The job as it is now."""
        return job_of(self.request("GET", f"/v1/jobs/{id_of(job)}"))

    def jobs(self, *, status: str | None = None, kind: str | None = None,
             limit: int = 50) -> list[Job]:
        """The newest jobs of the tenant (one page)."""
        query = {k: v for k, v in (("status", status), ("kind", kind)) if v}
        page = self.request("GET", "/v1/jobs", params={**query, "limit": limit}).json()
        return [Job.from_json(item) for item in page["items"]]

    def cancel(self, job: JobLike) -> Job:
        """Ask the job to stop (a queued job is cancelled at once)."""
        return job_of(self.request("POST", f"/v1/jobs/{id_of(job)}/cancel"))

    def wait(self, job: JobLike, *, progress: ProgressCallback | None = None,
             timeout: float | None = None) -> Job:
        """Follow the job's events until it ends; its final state.

        A dropped stream (server restart, proxy timeout) is reopened with ``Last-Event-ID``
        after a backoff; ``retry.attempts`` failures in a row give up. ``progress`` is called
        with every new state of the job.
        """
        job_id = id_of(job)
        deadline = None if timeout is None else time.monotonic() + timeout
        cursor = StreamCursor()
        failures = 0
        while True:
            try:
                if self._follow(job_id, cursor, progress):
                    return self.job(job_id)
                failures = 0
            except (httpx.TransportError, TransientStatus) as exc:
                if isinstance(exc, httpx.TransportError) and not is_transient_error(exc):
                    raise
                if failures + 1 >= self.retry.attempts:
                    raise
                after = exc.after if isinstance(exc, TransientStatus) else None
                self._sleep(self.retry.delay(failures, after))
                failures += 1
            if deadline is not None and time.monotonic() > deadline:
                raise TimeoutError(f"job {job_id} did not end within {timeout} s")

    def _follow(self, job_id: str, cursor: StreamCursor, progress: ProgressCallback | None
                ) -> bool:
        """Read one connection of the event stream; True when the job ended."""
        headers = {"Last-Event-ID": cursor.last_id} if cursor.last_id else {}
        timeout = httpx.Timeout(self._timeout, read=STREAM_READ_SECONDS)
        with self._http.stream("GET", f"/v1/jobs/{job_id}/events", headers=headers,
                               timeout=timeout) as response:
            if response.status_code >= 400:
                response.read()
                if is_transient_status(response.status_code):
                    raise TransientStatus(response.status_code, retry_after(response))
                raise_for_problem(response)
            for event in events(response.iter_lines()):
                if cursor.see(event):
                    return True
                current = event_job(event.data)
                if current is not None and progress is not None:
                    progress(current)
        return False

    # ------------------------------------------------------------------ results

    def download(self, job: JobLike, format: str = "json",
                 path: str | os.PathLike[str] | None = None) -> bytes | Path:
        """A result file: its bytes, or written to ``path`` (atomically) and that path."""
        url = f"/v1/jobs/{id_of(job)}/result"
        if path is None:
            return self.request("GET", url, params={"format": format}).content
        target = Path(path)
        partial = target.with_name(target.name + ".part")
        for attempt in range(self.retry.attempts):
            try:
                with self._http.stream("GET", url, params={"format": format}) as response:
                    if response.status_code >= 400:
                        response.read()
                        if (is_transient_status(response.status_code)
                                and attempt < self.retry.attempts - 1):
                            self._sleep(self.retry.delay(attempt, retry_after(response)))
                            continue
                        raise_for_problem(response)
                    with partial.open("wb") as out:
                        for chunk in response.iter_bytes():
                            out.write(chunk)
                partial.replace(target)
                return target
            except httpx.TransportError as exc:
                if attempt == self.retry.attempts - 1 or not is_transient_error(exc):
                    raise
                self._sleep(self.retry.delay(attempt))
        raise AssertionError("unreachable")  # pragma: no cover

    def result(self, job: JobLike) -> Result:
        """The job's result JSON, typed (SkeletonResult or TranslationResult)."""
        data = self.download(job, "json")
        assert isinstance(data, bytes)
        return result_of(data)

    def run(self, source: str | os.PathLike[str] | bytes, kind: str,
            params: Mapping[str, Any] | None = None, *, format: str = "auto",
            inputs: Mapping[str, RecordingLike] | None = None,
            progress: ProgressCallback | None = None, timeout: float | None = None) -> Result:
        """Upload, submit, wait and read the result in one call; ProblemError if the job
        failed (its problem) or was cancelled."""
        recording = self.upload(source, format=format)
        job = self.submit(kind, recording, params, inputs=inputs)
        done = check_succeeded(self.wait(job, progress=progress, timeout=timeout))
        return self.result(done)

