"""The job queue: job ids travel through huey (SQLite embedded, Redis distributed)."""

from __future__ import annotations

import sqlite3
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol
from urllib.parse import urlsplit

from .errors import BackendError, QueueUnavailable, StorageFull, says_disk_full, translate_methods

Handler = Callable[[str], None]
TASK_NAME = "bonefit.run_job"


class JobQueue(Protocol):
    """Delivers job ids to workers; a lost message is recovered by the lease reaper."""

    def enqueue(self, job_id: str) -> None:
        """Ask a worker to run ``job_id``."""

    def run_next(self, handler: Handler) -> bool:
        """Take one job id, call ``handler`` with it; False when the queue was empty."""

    def depth(self) -> int:
        """Number of job ids waiting."""

    def pending(self) -> set[str]:
        """The job ids waiting."""

    def ping(self) -> None:
        """Raise if the queue is unreachable."""


def queue_error(exc: Exception) -> BackendError | None:
    """The service's error for a huey storage error (a full disk, an outage); None for others."""
    if says_disk_full(exc):
        return StorageFull(f"the job queue is full ({type(exc).__name__})",
                           storage=QueueUnavailable.storage)
    outages: tuple[type[Exception], ...] = (sqlite3.OperationalError, ConnectionError,
                                            TimeoutError)
    redis = sys.modules.get("redis.exceptions")  # not loaded: not a redis error
    if redis is not None:
        outages += (redis.ConnectionError, redis.TimeoutError)
    if isinstance(exc, outages):
        return QueueUnavailable(f"the job queue is unreachable ({type(exc).__name__})")
    return None


@translate_methods(queue_error)
class HueyQueue:
    """huey as the transport: one task, ``bonefit.run_job(job_id)``, executed by our workers;
    its methods raise :class:`~bonefit.service.errors.StorageFull` and
    :class:`~bonefit.service.errors.QueueUnavailable`."""

    def __init__(self, huey: Any) -> None:
        self.huey = huey
        self._handler: Handler | None = None
        self._task = huey.task(name=TASK_NAME)(self._dispatch)

    def _dispatch(self, job_id: str) -> None:
        if self._handler is None:
            raise RuntimeError("no job handler in this process")
        self._handler(job_id)

    def enqueue(self, job_id: str) -> None:
        """Send the task."""
        self._task(job_id)

    def run_next(self, handler: Handler) -> bool:
        """Dequeue one task and execute it through huey (signals, logging)."""
        task = self.huey.dequeue()
        if task is None:
            return False
        self._handler = handler
        try:
            self.huey.execute(task)
        finally:
            self._handler = None
        return True

    def depth(self) -> int:
        """huey's pending count."""
        return int(self.huey.pending_count())

    def pending(self) -> set[str]:
        """Job ids of the pending tasks."""
        return {str(task.args[0]) for task in self.huey.pending() if task.args}

    def ping(self) -> None:
        """Count pending tasks (touches the storage)."""
        self.huey.pending_count()


def open_queue(url: str) -> JobQueue:
    """The queue for ``url``: ``sqlite:///path`` or ``redis://...``."""
    from huey import RedisHuey, SqliteHuey  # keep importing this module free of side effects

    scheme = urlsplit(url).scheme
    if scheme == "sqlite":
        path = Path(url.removeprefix("sqlite:///"))  # SQLAlchemy style: 4 slashes = absolute
        path.parent.mkdir(parents=True, exist_ok=True)
        return HueyQueue(SqliteHuey("bonefit", filename=str(path), results=False, timeout=30))
    if scheme in ("redis", "rediss", "unix"):
        return HueyQueue(RedisHuey("bonefit", url=url, results=False, blocking=True,
                                   read_timeout=1))
    raise ValueError(f"unsupported queue URL {url!r} (use sqlite:/// or redis://)")
