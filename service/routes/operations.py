"""The operational probes: liveness, readiness and Prometheus metrics (outside ``/v1``)."""

from __future__ import annotations

import asyncio
import time

from fastapi import APIRouter, Depends, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from ..auth import metrics_guard
from ..errors import BackendError
from ..problems import Problem
from ..runtime import Runtime
from ..storage import free_bytes
from .common import PROBLEM_RESPONSES, runtime_of

router = APIRouter()


@router.get("/healthz", summary="Liveness")
async def healthz() -> dict[str, str]:
    """The process is up."""
    return {"status": "ok"}


@router.get("/readyz", summary="Readiness", responses={503: PROBLEM_RESPONSES[503]})
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
        except BackendError as exc:
            results[name] = f"unavailable: {exc.cause_name}"  # the driver's error says more
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


@router.get("/metrics", summary="Prometheus metrics", dependencies=[Depends(metrics_guard)],
            responses={200: {"content": {CONTENT_TYPE_LATEST: {}}}, 401: PROBLEM_RESPONSES[401],
                       403: PROBLEM_RESPONSES[403]})
async def metrics(request: Request) -> Response:
    """Prometheus text exposition."""
    data = await run_in_threadpool(generate_latest, request.app.state.registry)
    return Response(data, media_type=CONTENT_TYPE_LATEST)
