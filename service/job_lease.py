"""A running job's lease, held by its worker: renewed by a heartbeat thread (and the lease
keeper process, ``leases.py``) and by progress reports, which also stop the job when it must.

Progress reaches the store at most every ``progress_interval_seconds``: a report inside the
interval is written by the heartbeat thread once the interval is over (so the last stage of a
job shows even when it reports only once). The heartbeat thread also looks for a cancel every
:data:`WATCH_SECONDS`, so that the job stops at its next report after that, not at the next
lease renewal.

The lease raises the signals that end a job early: :class:`Cancelled` (the client asked),
:class:`Requeue` (the worker shuts down), :class:`LeaseLost` (another worker or the reaper owns
the job) and :class:`TimedOut` (``job_timeout_seconds``).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Protocol

from .jobs import Job
from .leases import LeaseKeeper
from .runtime import Runtime

log = logging.getLogger("bonefit.worker")

WATCH_SECONDS = 0.5
"""How often the heartbeat thread writes pending progress or looks for a cancel."""


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
        self.stage: str | None = None
        self.written: tuple[float, str | None] = (0.0, None)
        self._write = threading.Lock()  # one progress write at a time: never a step back
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

    def _renew(self, *, report: bool = False) -> None:
        """Extend the lease (with the latest progress when ``report``); note a lost lease
        and a requested cancel."""
        w = self.worker
        with self._write:
            progress = (self.fraction, self.stage) if report else (None, None)
            job = w.runtime.store.renew(self.job.id, w.id,
                                        w.clock() + w.runtime.settings.lease_seconds,
                                        fraction=progress[0], stage=progress[1])
            if report:
                self.written, self.last_write = (self.fraction, self.stage), w.clock()
        self._note(job)

    def _note(self, job: Job | None) -> None:
        if job is None:
            self.lost.set()
        elif job.cancel_requested:
            self.cancelled.set()

    def _beat(self) -> None:
        """Renew every third of the lease; in between, write progress the throttle held
        back and look for a cancel."""
        lease = self.worker.runtime.settings.lease_seconds
        renew_at = time.monotonic() + lease / 3
        while not self.done.wait(min(WATCH_SECONDS, lease / 3)):
            try:
                if time.monotonic() >= renew_at:
                    renew_at = time.monotonic() + lease / 3
                    self._renew(report=self._held_back())
                else:
                    self._watch()
            except Exception:
                log.exception("job %s: heartbeat failed", self.job.id)

    def _held_back(self) -> bool:
        """Whether the latest progress report is not in the store yet."""
        return self.written != (self.fraction, self.stage)

    def _watch(self) -> None:
        """Between renewals: write held-back progress once its interval is over, or else
        look for a cancel."""
        w = self.worker
        if self._held_back() and (w.clock() - self.last_write
                                  >= w.runtime.settings.progress_interval_seconds):
            self._renew(report=True)
        elif not self.cancelled.is_set():
            job = w.runtime.store.get_job(self.job.id)
            if job is not None and job.cancel_requested:
                self.cancelled.set()

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

    def check_finished(self) -> None:
        """Raise if the finished job must not keep its results: a cancel asked for up to now
        wins (the heartbeat looks for one only every :data:`WATCH_SECONDS`), the time limit
        does not."""
        self._note(self.worker.runtime.store.get_job(self.job.id))
        self.check(timeout=False)

    def progress(self, fraction: float, stage: str) -> None:
        """The estimation callback: store progress at most every interval; stop if asked."""
        self.check()
        self.fraction = max(self.fraction, min(max(float(fraction), 0.0), 1.0))
        self.stage = stage[:100]
        now = self.worker.clock()
        if now - self.last_write < self.worker.runtime.settings.progress_interval_seconds:
            return
        self._renew(report=True)
        self.check()
