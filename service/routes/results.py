"""``/v1/jobs/{id}/result``: download a succeeded job's result file."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import StreamingResponse

from ..jobs import Status
from ..kinds import MEDIA_TYPES
from ..problems import Problem
from ..schemas import ResultFormat
from .common import Tenant, find_job, runtime_of

router = APIRouter()


@router.get("/jobs/{job_id}/result", summary="Download a result",
            responses={200: {"content": {t: {} for t in MEDIA_TYPES.values()}}})
async def job_result(request: Request, who: Tenant, job_id: str,
                     format: ResultFormat = "json") -> StreamingResponse:
    """The result file in ``format``; 409 while the job has not succeeded."""
    runtime = runtime_of(request)
    job = await find_job(request, who, job_id)
    if job.status is not Status.SUCCEEDED:
        raise Problem(409, "No result", f"the job is {job.status}; results exist once it has "
                      "succeeded", slug="job-not-finished", job_status=job.status)
    key = job.results.get(format)
    size = None if key is None else await run_in_threadpool(runtime.artifacts.size, key)
    if key is None or size is None:
        raise Problem(404, "Not found", f"this job has no {format} result", slug="not-found",
                      field="format")
    name = f"{job.kind}-{job.id}.{format}"
    return StreamingResponse(runtime.artifacts.iter_bytes(key), media_type=MEDIA_TYPES[format],
                             headers={"Content-Disposition": f'attachment; filename="{name}"',
                                      "Content-Length": str(size)})
