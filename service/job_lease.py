"""A running job's lease, held by its worker: renewed by a heartbeat thread (and the lease
keeper process, ``leases.py``) and by progress reports, which also stop the job when it must.

The lease raises the signals that end a job early: :class:`Cancelled` (the client asked),
:class:`Requeue` (the worker shuts down), :class:`LeaseLost` (another worker or the reaper owns
the job) and :class:`TimedOut` (``job_timeout_seconds``).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Protocol

from .jobs import Job
from .leases import LeaseKeeper
from .runtime import Runtime

log = logging.getLogger("bonefit.worker")


class Cancelled(Exception):
    """The client cancelled the job."""


class Requeue(Exception):
    """The worker is shutting down: hand the job back to the queue."""


class LeaseLost(Exception):
    """Another worker or the reaper took the job over."""


class TimedOut(Exception):
    """The job ran longer than ``job_timeout_seconds``."""


class Holder(Protocol):
    """What a lease needs of the worker holding it (a :class:`~bonefit.service.worker.Worker`)."""

    id: str
    runtime: Runtime
    clock: Callable[[], float]
    keeper: LeaseKeeper | None
    deadline: float | None


class JobLease:
    """A running job's lease: a heartbeat thread and the throttled progress callback."""

    def __init__(self, worker: Holder, job: Job) -> None:
        self.worker = worker
        self.job = job
        self.lost = threading.Event()
        self.cancelled = threading.Event()
        self.done = threading.Event()
        self.started = self.last_write = worker.clock()
        self.fraction = 0.0
        self.thread = threading.Thread(target=self._beat, name=f"lease-{job.id}", daemon=True)

    def start(self) -> None:
        """Start renewing the lease (here and, when there is one, in the lease keeper)."""
        if self.worker.keeper is not None:
            self.worker.keeper.hold(self.job.id)
        self.thread.start()

    def stop(self) -> None:
        """Stop renewing it."""
        self.done.set()
        if self.worker.keeper is not None:
            self.worker.keeper.drop()
        self.thread.join()

    def _renew(self, fraction: float | None = None, stage: str | None = None) -> None:
        w = self.worker
        job = w.runtime.store.renew(self.job.id, w.id,
                                    w.clock() + w.runtime.settings.lease_seconds,
                                    fraction=fraction, stage=stage)
        if job is None:
            self.lost.set()
        elif job.cancel_requested:
            self.cancelled.set()

    def _beat(self) -> None:
        interval = self.worker.runtime.settings.lease_seconds / 3
        while not self.done.wait(interval):
            try:
                self._renew()
            except Exception:
                log.exception("job %s: heartbeat failed", self.job.id)

    def check(self, *, timeout: bool = True) -> None:
        """Raise if the job must stop: lease lost, cancelled, shutdown grace or (with
        ``timeout``) the job's time limit over."""
        w = self.worker
        if self.lost.is_set():
            raise LeaseLost
        if self.cancelled.is_set():
            raise Cancelled
        now = w.clock()
        if w.deadline is not None and now >= w.deadline:
            raise Requeue
        limit = w.runtime.settings.job_timeout_seconds
        if timeout and limit > 0 and now - self.started >= limit:
            raise TimedOut

    def progress(self, fraction: float, stage: str) -> None:
        """The estimation callback: store progress at most every interval; stop if asked."""
        self.check()
        self.fraction = max(self.fraction, min(max(float(fraction), 0.0), 1.0))
        now = self.worker.clock()
        if now - self.last_write < self.worker.runtime.settings.progress_interval_seconds:
            return
        self.last_write = now
        self._renew(self.fraction, stage[:100])
        self.check()
