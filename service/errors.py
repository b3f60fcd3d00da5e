"""The service's own back-end errors.

Each adapter (the job store, the queue, the artifact storage) turns its driver's exceptions
(SQLAlchemy and its drivers, redis, huey's SQLite, botocore, the file system) into these, the
way httpx maps its transports' errors: the problem handlers and the worker see only them.
An error an adapter does not recognise (a bug) passes unchanged and is answered as a 500.
"""

from __future__ import annotations

import errno
import functools
import inspect
from collections.abc import Callable
from typing import ParamSpec, TypeVar

P = ParamSpec("P")
R = TypeVar("R")
C = TypeVar("C", bound=type)

FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})
SQLITE_FULL = "database or disk is full"
POSTGRES_DISK_FULL = "53100"


class BackendError(Exception):
    """A back-end failed; ``storage`` names it for clients (never a path or a URL)."""

    storage = "back-end"

    def __init__(self, detail: str, *, storage: str | None = None) -> None:
        super().__init__(detail)
        if storage is not None:
            self.storage = storage

    @property
    def cause_name(self) -> str:
        """The type name of the driver's exception behind this one (or of this one)."""
        return type(self.__cause__ or self).__name__


class Unavailable(BackendError):
    """A back-end is unreachable or timed out: the request may be retried later (503)."""


class StoreUnavailable(Unavailable):
    """The job database is unreachable."""

    storage = "job database"


class QueueUnavailable(Unavailable):
    """The job queue is unreachable."""

    storage = "job queue"


class ArtifactsUnavailable(Unavailable):
    """The artifact storage is unreachable."""

    storage = "artifact storage"


class StorageFull(BackendError):
    """A back-end's disk or quota is full (507 naming ``storage``)."""


def chain(exc: BaseException) -> list[BaseException]:
    """``exc`` and what it wraps: a driver's original error, causes and contexts."""
    seen: list[BaseException] = []
    current: BaseException | None = exc
    while current is not None and all(current is not s for s in seen):
        seen.append(current)
        current = getattr(current, "orig", None) or current.__cause__ or current.__context__
    return seen


def says_disk_full(exc: BaseException) -> bool:
    """Whether ``exc`` (or what it wraps) says a disk or quota is full: the errno of a file
    system, SQLite's message or PostgreSQL's SQLSTATE 53100."""
    for e in chain(exc):
        if isinstance(e, OSError) and e.errno in FULL_ERRNOS:
            return True
        if SQLITE_FULL in str(e) or getattr(e, "sqlstate", None) == POSTGRES_DISK_FULL:
            return True
    return False


Translate = Callable[[Exception], BackendError | None]
"""An adapter's mapping: its driver's exception → the service's, or None to let it pass."""


def translated(translate: Translate) -> Callable[[Callable[P, R]], Callable[P, R]]:
    """Decorate a back-end method so that the driver errors ``translate`` knows are raised
    as the service's own (chained to the original, which the log shows)."""

    def decorate(method: Callable[P, R]) -> Callable[P, R]:
        @functools.wraps(method)
        def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
            try:
                return method(*args, **kwargs)
            except BackendError:
                raise
            except Exception as exc:
                mapped = translate(exc)
                if mapped is None:
                    raise
                raise mapped from exc

        return wrapper

    return decorate


def decorate_methods(decorator: Callable[[Callable[..., object]], Callable[..., object]]
                     ) -> Callable[[C], C]:
    """Class decorator: ``decorator`` on every public method defined in the class."""

    def decorate(cls: C) -> C:
        for name, value in list(vars(cls).items()):
            if not name.startswith("_") and inspect.isfunction(value):
                setattr(cls, name, decorator(value))
        return cls

    return decorate


def translate_methods(translate: Translate) -> Callable[[C], C]:
    """Class decorator: :func:`translated` on every public method defined in the class."""
    return decorate_methods(translated(translate))
