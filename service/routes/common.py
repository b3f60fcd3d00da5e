"""What the resources' routes share: the app's back-ends, the tenant, paging, id checks."""

from __future__ import annotations

import re
from typing import Annotated, Any

from fastapi import Depends, Query, Request
from fastapi.concurrency import run_in_threadpool

from ..auth import tenant
from ..jobs import Job
from ..problems import MEDIA_TYPE, not_found
from ..runtime import Runtime

Tenant = Annotated[str, Depends(tenant)]
Limit = Annotated[int, Query(ge=1, le=1000, description="Page size.")]
Cursor = Annotated[str | None, Query(max_length=64, pattern=r"^[0-9a-z]+$",
                                     description="next_cursor of the last page.")]
ID = re.compile(r"^[0-9a-z]{1,64}$")

PROBLEM_RESPONSES: dict[int | str, dict[str, Any]] = {
    code: {"description": "Problem details (RFC 9457)",
           "content": {MEDIA_TYPE: {"schema": {"type": "object"}}}}
    for code in (400, 401, 403, 404, 408, 409, 413, 422, 503)}


def runtime_of(request: Request) -> Runtime:
    """The app's back-ends."""
    runtime: Runtime = request.app.state.runtime
    return runtime


def page_cursor(items: list[Any], limit: int) -> str | None:
    """The cursor of the next page: the last item's id when the page is full."""
    return items[-1].id if len(items) == limit else None


async def find_job(request: Request, who: str, job_id: str) -> Job:
    """The tenant's job ``job_id``, or the 404 problem."""
    if not ID.match(job_id):
        raise not_found("job", job_id)
    job = await run_in_threadpool(runtime_of(request).store.get_job, job_id, who)
    if job is None:
        raise not_found("job", job_id)
    return job
