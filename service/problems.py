"""RFC 9457 problem details: every error the API answers is translated here, in one place."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import ClientDisconnect

from estimation.errors import BonefitError, EstimationError

from .errors import BackendError

log = logging.getLogger("bonefit.service")

PROBLEM_TYPE = "urn:bonefit:problem:"
MEDIA_TYPE = "application/problem+json"


class Problem(Exception):
    """An HTTP error with RFC 9457 members; extra keyword arguments become extension members."""

    def __init__(self, status: int, title: str, detail: str, *, slug: str | None = None,
                 headers: dict[str, str] | None = None,
                 location: Mapping[str, Any] | None = None, **extensions: Any) -> None:
        super().__init__(detail)
        self.status = status
        self.title = title
        self.detail = detail
        self.slug = slug
        self.headers = headers
        self.extensions = {**(location or {}), **extensions}

    def body(self, instance: str | None = None) -> dict[str, Any]:
        """The problem document."""
        doc: dict[str, Any] = {
            "type": PROBLEM_TYPE + self.slug if self.slug else "about:blank",
            "title": self.title, "status": self.status, "detail": self.detail,
        }
        if instance is not None:
            doc["instance"] = instance
        doc.update(self.extensions)
        return doc


def from_bonefit_error(exc: BonefitError, status: int = 422) -> Problem:
    """The problem for an estimation input error, naming field, sensor, line and column."""
    slug = "estimation-error" if isinstance(exc, EstimationError) else "malformed-input"
    return Problem(status, exc.title, exc.detail, slug=slug, location=exc.location())


def not_found(what: str, ident: str) -> Problem:
    """404 for a resource that does not exist or belongs to another tenant."""
    return Problem(404, "Not found", f"no {what} {ident!r}", slug="not-found")


def response(problem: Problem, request: Request) -> JSONResponse:
    """The JSON response carrying ``problem`` for ``request``."""
    return JSONResponse(problem.body(request.url.path), status_code=problem.status,
                        media_type=MEDIA_TYPE, headers=problem.headers)


def _location(loc: tuple[int | str, ...], tags: set[str]) -> str:
    if len(loc) > 1 and loc[0] == "body" and loc[1] in tags:
        loc = loc[:1] + loc[2:]  # the discriminated union's tag is not part of the body
    parts = [str(p) for p in loc if p not in ("body", "query", "path", "header")]
    return ".".join(parts) or ".".join(str(p) for p in loc)


def _is_outage(exc: Exception) -> bool:
    """Whether ``exc`` says a back-end failed (answered 503, not 500): the adapters raise
    :class:`~service.errors.BackendError` for their drivers' outages and full disks (the
    routes that write answer a full disk with 507 themselves)."""
    return isinstance(exc, BackendError | ConnectionError | TimeoutError)


def install(app: FastAPI) -> None:
    """Register the handlers that turn every exception into a problem document."""

    async def on_problem(request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, Problem)
        return response(exc, request)

    async def on_bonefit(request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, BonefitError)
        return response(from_bonefit_error(exc), request)

    async def on_http(request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, StarletteHTTPException)
        titles = {404: "Not found", 405: "Method not allowed"}
        title = titles.get(exc.status_code, "HTTP error")
        detail = exc.detail if isinstance(exc.detail, str) else title
        if exc.status_code == 404 and detail == "Not Found":
            detail = f"no route {request.url.path!r}"
        elif exc.status_code == 405:
            detail = f"{request.method} is not allowed on {request.url.path!r}"
        problem = Problem(exc.status_code, title, detail, headers=dict(exc.headers or {}))
        return response(problem, request)

    async def on_validation(request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, RequestValidationError)
        tags = set(getattr(request.app.state, "kinds", ()))
        errors = []
        for e in exc.errors():
            loc = tuple(e.get("loc", ()))
            if e.get("type") in ("union_tag_invalid", "union_tag_not_found"):
                loc += (str(e.get("ctx", {}).get("discriminator", "kind")).strip("'"),)
            errors.append({"field": _location(loc, tags), "message": e.get("msg", "")})
        first = errors[0] if errors else {"field": "", "message": "invalid request"}
        detail = f"{first['field']}: {first['message']}" if first["field"] else first["message"]
        problem = Problem(422, "Invalid request", detail, slug="invalid-request",
                          field=first["field"], errors=errors)
        return response(problem, request)

    async def on_disconnect(request: Request, exc: Exception) -> JSONResponse:
        log.info("client hung up during %s %s", request.method, request.url.path)
        return response(Problem(400, "Client disconnected", "the request body ended early",
                                slug="client-disconnected"), request)

    async def on_error(request: Request, exc: Exception) -> JSONResponse:
        if _is_outage(exc):
            log.error("back-end unavailable on %s %s: %s", request.method, request.url.path,
                      type(exc).__name__)
            return response(Problem(503, "Service unavailable", "a back-end (database, queue or "
                                    "storage) is unreachable; retry later", slug="unavailable",
                                    headers={"Retry-After": "5"}), request)
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        problem = Problem(500, "Internal server error",
                          "the server failed to handle the request; it has been logged",
                          slug="internal")
        return response(problem, request)

    app.add_exception_handler(Problem, on_problem)
    app.add_exception_handler(BonefitError, on_bonefit)
    app.add_exception_handler(StarletteHTTPException, on_http)
    app.add_exception_handler(RequestValidationError, on_validation)
    app.add_exception_handler(ClientDisconnect, on_disconnect)
    app.add_exception_handler(Exception, on_error)
