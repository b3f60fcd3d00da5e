"""The FastAPI application factory."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator, Callable, Mapping

from fastapi import FastAPI
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Receive, Scope, Send

from . import problems
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
        if scope["type"] == "http" and scope["path"] != "/v1/recordings":
            length = dict(scope["headers"]).get(b"content-length", b"0")
            if length.isdigit() and int(length) > MAX_JSON_BYTES:
                problem = Problem(413, "Request too large", f"bodies other than uploads are "
                                  f"limited to {MAX_JSON_BYTES} bytes", slug="body-too-large")
                response = JSONResponse(problem.body(scope["path"]), status_code=413,
                                        media_type=problems.MEDIA_TYPE)
                await response(scope, receive, send)
                return
        await self.app(scope, receive, send)


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
        title="bonefit", version="0.1.0", lifespan=lifespan,
        description="Skeletons and root paths from body-worn motion-capture sensors: upload "
                    "recordings, run estimation jobs, download JSON, BVH and CSV results.")
    app.state.runtime = runtime
    app.state.kinds = kinds
    app.state.registry, app.state.upload_bytes = build_registry(runtime, sorted(kinds))
    problems.install(app)
    app.add_middleware(BodyLimit)
    app.include_router(v1)
    app.include_router(ops)
    return app
