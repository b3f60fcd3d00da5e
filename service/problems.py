"""RFC 9457 problem details: every error the API answers is translated here, in one place."""

from __future__ import annotations

import logging
import uuid
from collections.abc import Mapping
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import ClientDisconnect
from starlette.routing import Match

from bonefit.estimation.errors import BonefitError, EstimationError

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
    if len(loc) == 2 and loc[0] == "header":  # idempotency_key -> Idempotency-Key
        return "-".join(w.capitalize() for w in str(loc[1]).replace("_", "-").split("-"))
    parts = [str(p) for p in loc if p not in ("body", "query", "path", "header")]
    return ".".join(parts) or ".".join(str(p) for p in loc)


def outage_types() -> tuple[type[Exception], ...]:
    """The exceptions that say a back-end (database, queue, storage) failed: 503, not 500.

    The adapters raise :class:`~bonefit.service.errors.BackendError` for their drivers' outages
    (SQLAlchemy, redis, huey's SQLite, botocore) and full disks; the routes that write answer
    a full disk with 507 themselves.
    """
    return (BackendError, ConnectionError, TimeoutError)


def is_outage(exc: BaseException) -> bool:
    """Whether ``exc`` says a back-end is down (answered 503, not 500)."""
    return isinstance(exc, outage_types())


UNAVAILABLE_RETRY_SECONDS = 5


def unavailable() -> Problem:
    """503 for a back-end that is down."""
    return Problem(503, "Service unavailable", "a back-end (database, queue or storage) is "
                   "unreachable; retry later", slug="unavailable",
                   headers={"Retry-After": str(UNAVAILABLE_RETRY_SECONDS)})


def internal(error_id: str) -> Problem:
    """500 for an unexpected error, logged with its traceback under ``error_id`` (never
    shown): the id lets an operator find the log line a client reports."""
    return Problem(500, "Internal server error",
                   f"the server failed to handle the request; it has been logged with error id "
                   f"{error_id}", slug="internal", error_id=error_id)


def error_problem(exc: BaseException, method: str, path: str) -> Problem:
    """Log an exception no handler took, and the 503 (outage) or 500 problem answering it."""
    if is_outage(exc):
        log.error("back-end unavailable on %s %s: %s: %s", method, path, type(exc).__name__,
                  str(exc).splitlines()[0] if str(exc) else "")
        return unavailable()
    error_id = uuid.uuid4().hex
    log.error("unhandled error on %s %s [error id %s]", method, path, error_id, exc_info=exc)
    return internal(error_id)


class BodyTimeout(StarletteHTTPException):
    """The client sent nothing of its request body for too long (408).

    An HTTPException so that FastAPI's body reading passes it on instead of turning it into
    a 400 "error parsing the body"."""

    def __init__(self, seconds: float, *, rate: float | None = None,
                 min_rate: float | None = None) -> None:
        if rate is None:
            detail = f"no byte of the request body arrived for {seconds:g} s"
        else:
            detail = (f"the request body arrived at {rate:.0f} bytes/s, under the minimum of "
                      f"{min_rate:g} bytes/s")
        super().__init__(408, detail)
        self.seconds = seconds


METHODS = ("DELETE", "GET", "HEAD", "OPTIONS", "PATCH", "POST", "PUT")


def allowed_methods(request: Request) -> list[str]:
    """Every method some route answers on the request's path (for a 405's ``Allow``).

    Each method is tried against the routes: routers included in others hide their routes'
    methods, but a route of the path matches the method it answers in full. HEAD goes
    wherever GET does (``app.HeadAsGet``)."""
    routes = request.app.router.routes
    return [method for method in METHODS
            if any(route.matches({**request.scope, "method": "GET" if method == "HEAD"
                                  else method})[0] is Match.FULL for route in routes)]


async def on_problem(request: Request, exc: Exception) -> JSONResponse:
    """A :class:`Problem` raised by a route, as it is."""
    assert isinstance(exc, Problem)
    return response(exc, request)


async def on_bonefit(request: Request, exc: Exception) -> JSONResponse:
    """An estimation input error: 422 naming field, sensor, line and column."""
    assert isinstance(exc, BonefitError)
    return response(from_bonefit_error(exc), request)


def http_problem(request: Request, exc: StarletteHTTPException) -> Problem:
    """The problem for Starlette's own HTTP errors: an unknown route (404), a method the path
    does not answer (405, with ``Allow``), others with their status."""
    titles = {404: "Not found", 405: "Method not allowed"}
    title = titles.get(exc.status_code, "HTTP error")
    detail = exc.detail if isinstance(exc.detail, str) else title
    headers = dict(exc.headers or {})
    if exc.status_code == 404 and detail == "Not Found":
        detail = f"no route {request.url.path!r}"
    elif exc.status_code == 405:
        allowed = allowed_methods(request)
        headers["Allow"] = ", ".join(allowed)
        detail = (f"{request.method} is not allowed on {request.url.path!r}; allowed: "
                  f"{', '.join(allowed)}")
    return Problem(exc.status_code, title, detail, headers=headers)


async def on_http(request: Request, exc: Exception) -> JSONResponse:
    """Starlette's HTTP errors (unknown route, method not allowed, ...)."""
    assert isinstance(exc, StarletteHTTPException)
    return response(http_problem(request, exc), request)


async def on_body_timeout(request: Request, exc: Exception) -> JSONResponse:
    """A request body that stopped or trickled: 408, and the connection closed."""
    assert isinstance(exc, BodyTimeout)
    log.info("request body too slow on %s %s: %s; answered 408", request.method,
             request.url.path, exc.detail)
    problem = Problem(408, "Request body timeout", str(exc.detail), slug="body-timeout",
                      headers={"Connection": "close"}, timeout_seconds=exc.seconds)
    return response(problem, request)


async def on_outage(request: Request, exc: Exception) -> JSONResponse:
    """A back-end outage: 503 (registered per type so it answers from
    ExceptionMiddleware: ServerErrorMiddleware, the Exception handler, re-raises, and the
    server then drops the connection)."""
    return response(error_problem(exc, request.method, request.url.path), request)


def validation_problem(request: Request, exc: RequestValidationError) -> Problem:
    """422 naming the first invalid field as the client wrote it; ``errors`` lists all."""
    tags = set(getattr(request.app.state, "kinds", ()))
    errors = []
    for e in exc.errors():
        loc = tuple(e.get("loc", ()))
        if e.get("type") in ("union_tag_invalid", "union_tag_not_found"):
            loc += (str(e.get("ctx", {}).get("discriminator", "kind")).strip("'"),)
        errors.append({"field": _location(loc, tags), "message": e.get("msg", "")})
    first = errors[0] if errors else {"field": "", "message": "invalid request"}
    detail = f"{first['field']}: {first['message']}" if first["field"] else first["message"]
    return Problem(422, "Invalid request", detail, slug="invalid-request",
                   field=first["field"], errors=errors)


async def on_validation(request: Request, exc: Exception) -> JSONResponse:
    """A request that does not match its schema."""
    assert isinstance(exc, RequestValidationError)
    return response(validation_problem(request, exc), request)


async def on_disconnect(request: Request, exc: Exception) -> JSONResponse:
    """The client hung up while sending its body."""
    log.info("client hung up during %s %s", request.method, request.url.path)
    return response(Problem(400, "Client disconnected", "the request body ended early",
                            slug="client-disconnected"), request)


async def on_error(request: Request, exc: Exception) -> JSONResponse:
    """Last resort (ServerErrorMiddleware): errors raised outside the ErrorBoundary."""
    return response(error_problem(exc, request.method, request.url.path), request)


def install(app: FastAPI) -> None:
    """Register the handlers that turn every exception into a problem document."""
    app.add_exception_handler(Problem, on_problem)
    app.add_exception_handler(BonefitError, on_bonefit)
    app.add_exception_handler(StarletteHTTPException, on_http)
    app.add_exception_handler(BodyTimeout, on_body_timeout)
    for outage in outage_types():
        app.add_exception_handler(outage, on_outage)
    app.add_exception_handler(RequestValidationError, on_validation)
    app.add_exception_handler(ClientDisconnect, on_disconnect)
    app.add_exception_handler(Exception, on_error)
