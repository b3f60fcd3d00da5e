"""The HTTP endpoints, a module per resource: recordings, jobs, a job's events, a job's
result, and the operational probes (``ops``: health, readiness, metrics)."""

from __future__ import annotations

from fastapi import APIRouter

from . import events, jobs, operations, recordings, results
from .common import PROBLEM_RESPONSES

v1 = APIRouter(prefix="/v1", responses=PROBLEM_RESPONSES)
for resource in (recordings, jobs, events, results):
    v1.include_router(resource.router)

ops = operations.router

__all__ = ["ops", "v1"]
