"""What the resources' routes share: the app's back-ends, the tenant, paging, id checks."""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import Annotated, Any, TypeVar

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
T = TypeVar("T")

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


async def fetch_or_404(what: str, ident: str, fetch: Callable[..., T | None],
                       *args: str) -> T:
    """``fetch(*args)`` (run off the event loop), or the 404 problem naming ``what`` when
    ``ident`` is not an id or nothing is found."""
    if not ID.match(ident):
        raise not_found(what, ident)
    found = await run_in_threadpool(fetch, *args)
    if found is None:
        raise not_found(what, ident)
    return found


async def find_job(request: Request, who: str, job_id: str) -> Job:
    """The tenant's job ``job_id``, or the 404 problem."""
    return await fetch_or_404("job", job_id, runtime_of(request).store.get_job, job_id, who)
