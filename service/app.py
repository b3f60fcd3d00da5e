"""The FastAPI application factory."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import AsyncIterator, Callable, Mapping

import anyio
from fastapi import FastAPI
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from . import problems, studio
from .housekeeping import housekeeping
from .kinds import Kind, default_kinds
from .metrics import build_registry
from .problems import Problem
from .reaper import reap
from .retention import purge
from .routes import ops, v1
from .runtime import Runtime, open_runtime
from .settings import Settings
from .uploads import clean_spool

log = logging.getLogger("bonefit.service")


def _clean_spool(runtime: Runtime) -> None:
    clean_spool(runtime.settings.data_dir / "uploads")


API_STEPS: Mapping[str, Callable[[Runtime], object]] = {
    "reap": reap, "purge": purge, "spool cleanup": _clean_spool}
"""The API process's housekeeping; each step runs even when another one failed."""


async def _housekeeping(runtime: Runtime) -> None:
    """Re-queue jobs of lost workers, apply the retention and clean the spool, forever."""
    interval = min(runtime.settings.lease_seconds / 2, 30.0)
    while True:
        await run_in_threadpool(housekeeping, runtime, API_STEPS)
        await asyncio.sleep(interval)


MAX_JSON_BYTES = 1024 * 1024
"""Largest body accepted outside uploads (job requests are small)."""


class BodyLimit:
    """ASGI middleware: 413 for a declared body over ``MAX_JSON_BYTES``, except uploads."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Refuse before the body is read."""
        if scope["type"] == "http" and scope["path"] != UPLOAD_PATH:
            length = dict(scope["headers"]).get(b"content-length", b"0")
            if length.isdigit() and int(length) > MAX_JSON_BYTES:
                problem = Problem(413, "Request too large", f"bodies other than uploads are "
                                  f"limited to {MAX_JSON_BYTES} bytes", slug="body-too-large")
                response = JSONResponse(problem.body(scope["path"]), status_code=413,
                                        media_type=problems.MEDIA_TYPE)
                await response(scope, receive, send)
                return
        await self.app(scope, receive, send)


UPLOAD_PATH = "/v1/recordings"


class ErrorBoundary:
    """ASGI middleware just outside the exception handlers: an exception none of them took
    is answered here with the 503 (outage) or 500 problem, and the connection stays usable.

    Starlette's own last resort, ``ServerErrorMiddleware``, re-raises after answering, and the
    server then logs a second traceback and drops the keep-alive connection. An error after
    the response started cannot be answered any more: it goes on up (the server closes)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Run the app; answer what escapes it."""
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = False

        async def tracking_send(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, receive, tracking_send)
        except Exception as exc:
            if started:
                raise
            problem = problems.error_problem(exc, scope["method"], scope["path"])
            response = JSONResponse(problem.body(scope["path"]), status_code=problem.status,
                                    media_type=problems.MEDIA_TYPE, headers=problem.headers)
            await response(scope, receive, send)


class HeadAsGet:
    """ASGI middleware: HEAD on a GET route answers with the headers GET would (RFC 9110
    §9.3.2; FastAPI routes take GET alone, so HEAD was a 405).

    The request runs as GET; once its headers are sent the response ends and the rest of the
    app is cancelled, so a download is not read only to be thrown away."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Run a HEAD request as GET, up to the response's headers."""
        if scope["type"] != "http" or scope["method"] != "HEAD":
            await self.app(scope, receive, send)
            return
        async with anyio.create_task_group() as group:

            async def headers_only(message: Message) -> None:
                if message["type"] == "http.response.start":
                    await send(message)
                    await send({"type": "http.response.body", "body": b"", "more_body": False})
                    group.cancel_scope.cancel()

            async def as_get() -> None:
                await self.app({**scope, "method": "GET"}, receive, headers_only)

            group.start_soon(as_get)


class BodyGuard:
    """ASGI middleware: an idle timeout on request bodies, and a cap on concurrent uploads.

    While a request's body is incomplete, each wait for its next chunk is limited to
    ``body_timeout`` seconds, and after the first ``body_timeout`` seconds the body must have
    arrived at ``min_rate`` bytes per second on average (else :class:`problems.BodyTimeout`, a
    408 problem, and the connection is closed: a client trickling a byte a second is shed).
    Past ``max_uploads`` uploads in progress, another is answered 503 with ``Retry-After``
    before its body is read, so slow clients cannot pile up threads, buffers and file
    descriptors."""

    def __init__(self, app: ASGIApp, *, body_timeout: float, min_rate: float,
                 max_uploads: int) -> None:
        self.app = app
        self.body_timeout = body_timeout
        self.min_rate = min_rate
        self.max_uploads = max_uploads
        self.uploads = 0

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Guard one request."""
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        receive = self._timed(receive)
        if scope["method"] != "POST" or scope["path"] != UPLOAD_PATH:
            await self.app(scope, receive, send)
            return
        if self.uploads >= self.max_uploads:
            await self._busy(scope, receive, send)
            return
        self.uploads += 1
        try:
            await self.app(scope, receive, send)
        finally:
            self.uploads -= 1

    def _timed(self, receive: Receive) -> Receive:
        complete = False
        started, received = time.monotonic(), 0

        async def timed_receive() -> Message:
            nonlocal complete, received
            if complete:  # e.g. waiting for the client to disconnect: no limit
                return await receive()
            try:
                with anyio.fail_after(self.body_timeout):
                    message = await receive()
            except TimeoutError:
                raise problems.BodyTimeout(self.body_timeout) from None
            complete = message["type"] != "http.request" or not message.get("more_body")
            received += len(message.get("body", b""))
            elapsed = time.monotonic() - started
            if (not complete and elapsed > self.body_timeout
                    and received < self.min_rate * elapsed):
                raise problems.BodyTimeout(self.body_timeout, rate=received / elapsed,
                                           min_rate=self.min_rate)
            return message

        return timed_receive

    async def _busy(self, scope: Scope, receive: Receive, send: Send) -> None:
        log.warning("%d uploads in progress: refusing another with 503", self.uploads)
        problem = Problem(503, "Too many uploads", f"{self.max_uploads} uploads are in "
                          "progress, the most this server takes at once; retry later",
                          slug="too-many-uploads", headers={"Retry-After": "5",
                                                            "Connection": "close"},
                          max_concurrent_uploads=self.max_uploads)
        response = JSONResponse(problem.body(scope["path"]), status_code=503,
                                media_type=problems.MEDIA_TYPE, headers=problem.headers)
        await response(scope, receive, send)


def create_app(settings: Settings | None = None, *, runtime: Runtime | None = None,
               kinds: Mapping[str, Kind] | None = None, housekeeping: bool = True) -> FastAPI:
    """The API for ``settings`` (or an already opened ``runtime``, e.g. in memory for tests)."""
    if runtime is None:
        runtime = open_runtime(settings or Settings())
    kinds = dict(kinds or default_kinds())

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        task = asyncio.create_task(_housekeeping(runtime)) if housekeeping else None
        try:
            yield
        finally:
            if task is not None:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task

    app = FastAPI(
        title="bonefit", version="0.1.0", lifespan=lifespan, docs_url=None, redoc_url=None,
        description="Skeletons and root paths from body-worn motion-capture sensors: upload "
                    "recordings, run estimation jobs, download JSON, BVH and CSV results.")
    app.state.runtime = runtime
    app.state.kinds = kinds
    app.state.registry, app.state.upload_bytes = build_registry(runtime, sorted(kinds))
    problems.install(app)
    app.add_middleware(ErrorBoundary)  # innermost: right outside the exception handlers
    app.add_middleware(BodyGuard, body_timeout=runtime.settings.body_timeout_seconds,
                       min_rate=runtime.settings.body_min_bytes_per_second,
                       max_uploads=runtime.settings.max_concurrent_uploads)
    app.add_middleware(BodyLimit)
    app.add_middleware(HeadAsGet)
    app.include_router(v1)
    app.include_router(ops)
    studio.install(app)
    return app
