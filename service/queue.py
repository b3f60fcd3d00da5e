"""The job queue: job ids travel through huey (SQLite embedded, Redis distributed)."""

from __future__ import annotations

import functools
import sqlite3
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol
from urllib.parse import urlsplit

from .errors import BackendError, QueueUnavailable, StorageFull, says_disk_full, translate_methods
from .wake import Waker

Handler = Callable[[str], None]
TASK_NAME = "bonefit.run_job"


class JobQueue(Protocol):
    """Delivers job ids to workers; a lost message is recovered by the lease reaper."""

    def enqueue(self, job_id: str) -> None:
        """Ask a worker to run ``job_id``."""

    def run_next(self, handler: Handler) -> bool:
        """Take one job id, call ``handler`` with it; False when the queue was empty."""

    def idle(self, timeout: float) -> None:
        """After an empty :meth:`run_next`: block until a job id may have arrived, at most
        ``timeout`` seconds (at once when ``run_next`` itself blocks, as on Redis)."""

    def interrupt(self) -> None:
        """End a running :meth:`idle` now (a worker shutting down; safe in a signal handler)."""

    def close(self) -> None:
        """Release what this process holds to be woken (a worker exiting)."""

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
    :class:`~bonefit.service.errors.QueueUnavailable`.

    Idle workers are woken on enqueue: on Redis the dequeue itself blocks (BRPOP); with a
    ``waker`` (the SQLite queue) by its notification; otherwise only within this process.
    """

    def __init__(self, huey: Any, waker: Waker | None = None) -> None:
        self.huey = huey
        self.waker = waker
        self._handler: Handler | None = None
        self._task = huey.task(name=TASK_NAME)(self._dispatch)
        self._wake = threading.Event()

    def _dispatch(self, job_id: str) -> None:
        if self._handler is None:
            raise RuntimeError("no job handler in this process")
        self._handler(job_id)

    def enqueue(self, job_id: str) -> None:
        """Send the task and wake the idle workers."""
        self._task(job_id)
        self._wake.set()
        if self.waker is not None:
            self.waker.notify()

    def run_next(self, handler: Handler) -> bool:
        """Dequeue one task and execute it through huey (signals, logging)."""
        self._wake.clear()
        if self.waker is not None:
            self.waker.drain()  # before looking: a later enqueue still wakes this process
        task = self.huey.dequeue()
        if task is None:
            return False
        self._handler = handler
        try:
            self.huey.execute(task)
        finally:
            self._handler = None
        return True

    def idle(self, timeout: float) -> None:
        """Wait for a notification (or ``timeout``); nothing when the dequeue blocks."""
        if getattr(self.huey.storage, "blocking", False):
            return
        if self.waker is not None:
            self.waker.wait(timeout)  # the first call only starts listening
        else:
            self._wake.wait(timeout)

    def interrupt(self) -> None:
        """Wake this process's :meth:`idle`."""
        self._wake.set()
        if self.waker is not None:
            self.waker.interrupt()

    def close(self) -> None:
        """Stop listening for notifications."""
        if self.waker is not None:
            self.waker.close()

    def depth(self) -> int:
        """huey's pending count."""
        return int(self.huey.pending_count())

    def pending(self) -> set[str]:
        """Job ids of the pending tasks."""
        return {str(task.args[0]) for task in self.huey.pending() if task.args}

    def ping(self) -> None:
        """Count pending tasks (touches the storage)."""
        self.huey.pending_count()


@functools.cache
def sqlite_storage() -> type:
    """huey's SQLite storage with ``synchronous=NORMAL``, as the job store's SQLite: in WAL
    mode a commit then waits for no fsync (huey's default, FULL, made every enqueue and
    dequeue wait for the disk: 12 ms median on the loaded 2-core host), and only a power
    loss, not a crash, can take back the last commits (the reaper re-sends a lost message)."""
    from huey.storage import SqliteStorage

    class NormalSyncStorage(SqliteStorage):  # type: ignore[misc]
        def _create_connection(self) -> Any:
            conn = super()._create_connection()
            conn.execute("pragma synchronous=NORMAL")
            return conn

    return NormalSyncStorage


def open_queue(url: str) -> JobQueue:
    """The queue for ``url``: ``sqlite:///path`` or ``redis://...``."""
    from huey import RedisHuey, SqliteHuey  # keep importing this module free of side effects

    scheme = urlsplit(url).scheme
    if scheme == "sqlite":
        path = Path(url.removeprefix("sqlite:///"))  # SQLAlchemy style: 4 slashes = absolute
        path.parent.mkdir(parents=True, exist_ok=True)
        return HueyQueue(SqliteHuey("bonefit", filename=str(path), results=False, timeout=30,
                                    storage_class=sqlite_storage()),
                         Waker(path.with_name(path.name + ".wake")))
    if scheme in ("redis", "rediss", "unix"):
        return HueyQueue(RedisHuey("bonefit", url=url, results=False, blocking=True,
                                   read_timeout=1))
    raise ValueError(f"unsupported queue URL {url!r} (use sqlite:/// or redis://)")
