"""Recordings and jobs: their records, a job's statuses, and the job store's Protocol (its
SQL implementation is ``bonefit.service.sql_store``)."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, Final, Protocol


class Status(StrEnum):
    """A job's place in its life cycle; the values are the API's and the database's strings.

    ``queued`` → (``claim``) ``running`` → ``succeeded`` | ``failed`` | ``cancelled``, and back
    to ``queued`` when a worker hands the job back or is lost; a queued job can be cancelled.
    """

    QUEUED = "queued"
    RUNNING = "running"
    SUCCEEDED = "succeeded"
    FAILED = "failed"
    CANCELLED = "cancelled"


TERMINAL: Final = frozenset({Status.SUCCEEDED, Status.FAILED, Status.CANCELLED})
"""The statuses of a job that has ended: nothing changes it any more."""
_CROCKFORD = "0123456789abcdefghjkmnpqrstvwxyz"


_last_id = [0]
_id_lock = threading.Lock()


def new_id() -> str:
    """A 26-character, time-ordered, random identifier (monotonic ULID, lower case)."""
    with _id_lock:
        value = (time.time_ns() // 1_000_000) << 80 | int.from_bytes(os.urandom(10), "big")
        if value >> 80 == _last_id[0] >> 80:  # same millisecond: keep the order of creation
            value = _last_id[0] + 1 + int.from_bytes(os.urandom(2), "big")
        _last_id[0] = value
    return "".join(_CROCKFORD[(value >> (5 * i)) & 31] for i in reversed(range(26)))


@dataclass
class Recording:
    """An uploaded file: its metadata and where its bytes are stored."""

    id: str
    tenant: str
    key: str
    filename: str | None
    content_type: str | None
    format: str
    size: int
    sha256: str
    created_at: float
    summary: dict[str, Any] = field(default_factory=dict)


@dataclass
class Job:
    """One estimation run and everything the API reports about it."""

    id: str
    tenant: str
    kind: str
    recording_id: str
    params: dict[str, Any]
    inputs: dict[str, str]
    created_at: float
    updated_at: float
    status: Status = Status.QUEUED
    started_at: float | None = None
    finished_at: float | None = None
    attempts: int = 0
    fraction: float = 0.0
    stage: str = "queued"
    message: str | None = None
    error: dict[str, Any] | None = None
    results: dict[str, str] = field(default_factory=dict)
    worker: str | None = None
    lease_until: float | None = None
    cancel_requested: bool = False
    idempotency_key: str | None = None
    request_hash: str | None = None
    version: int = 1


@dataclass
class Histogram:
    """Cumulative counts per upper bound, number and sum of observations."""

    counts: list[int]
    count: int
    total: float


PURGE_BATCH: Final = 1000
"""Rows deleted per transaction by the retention: PostgreSQL takes at most 65,535 bound
parameters in one statement, and a short transaction keeps the table available."""

Expect = Mapping[str, Any]
"""Compare-and-set conditions: column → value, or a tuple of accepted values."""


class JobStore(Protocol):
    """Persistent state shared by API replicas and workers."""

    def init(self) -> None:
        """Create tables if missing."""

    def ping(self) -> None:
        """Raise if the store is unreachable."""

    def add_recording(self, recording: Recording) -> None:
        """Insert a recording."""

    def get_recording(self, tenant: str, recording_id: str) -> Recording | None:
        """The tenant's recording, or None."""

    def list_recordings(self, tenant: str, *, before: str | None, limit: int) -> list[Recording]:
        """The tenant's recordings, newest first, ids below ``before``."""

    def delete_recording(self, tenant: str, recording_id: str) -> Recording | None:
        """Delete and return the tenant's recording, or None."""

    def add_job(self, job: Job, *, durable: bool = True) -> Job:
        """Insert a job; with an idempotency key already used, return that job instead.
        With ``durable=False`` the job may reach the disk only later: it is visible to
        workers at once, but no one may be told of it before :meth:`wait_durable`."""

    def wait_durable(self) -> None:
        """Return once everything stored before the call survives a crash of the store."""

    def get_job(self, job_id: str, tenant: str | None = None) -> Job | None:
        """The job (of ``tenant`` when given), or None."""

    def list_jobs(self, tenant: str, *, status: Status | str | None, kind: str | None,
                  before: str | None, limit: int) -> list[Job]:
        """The tenant's jobs, newest first, filtered."""

    def update_job(self, job_id: str, changes: Mapping[str, Any], *, expect: Expect) -> Job | None:
        """Apply ``changes`` if every ``expect`` condition holds; the updated job or None.

        The compare-and-set primitive under the transitions below; the service changes jobs
        only through those, which own their preconditions.
        """

    def claim(self, job_id: str, worker: str, now: float, lease_seconds: float) -> Job | None:
        """Run the job on ``worker`` under a lease, counting an attempt, if it is queued; the
        running job, or None (cancelled, finished, running elsewhere: a duplicate message).
        One compare-and-set, with no read before it: the worker's way from a queue message to
        a started job is a single round trip to the store."""

    def renew(self, job_id: str, worker: str, lease_until: float, *,
              fraction: float | None = None, stage: str | None = None) -> Job | None:
        """Extend ``worker``'s lease, storing its progress; None once the job is not its own."""

    def requeue(self, job_id: str, worker: str | None, message: str, *,
                lease_until: float | None = None) -> Job | None:
        """Queue again the job ``worker`` ran, its attempt counted (a crash, a lost worker);
        with ``lease_until``, only while the lease is still that one."""

    def hand_back(self, job: Job, worker: str, message: str) -> Job | None:
        """Queue again the job ``worker`` runs without counting its attempt (a shutdown)."""

    def succeed(self, job_id: str, worker: str, results: Mapping[str, str],
                now: float) -> Job | None:
        """End the job ``worker`` runs with its result keys (format → artifact key)."""

    def fail(self, job_id: str, worker: str | None, error: Mapping[str, Any], now: float, *,
             lease_until: float | None = None) -> Job | None:
        """End the job ``worker`` runs with the problem document ``error``."""

    def cancel(self, job_id: str, worker: str | None, now: float, *,
               lease_until: float | None = None) -> Job | None:
        """End as cancelled the job ``worker`` runs (its client asked)."""

    def cancel_queued(self, job_id: str, now: float) -> Job | None:
        """End as cancelled a job still waiting in the queue."""

    def request_cancel(self, job_id: str) -> Job | None:
        """Ask the worker running the job to stop at its next progress report."""

    def withdraw(self, job_id: str, error: Mapping[str, Any], now: float) -> Job | None:
        """Fail a queued job the queue refused and free its idempotency key."""

    def mark_resent(self, job: Job) -> Job | None:
        """Note that the queued ``job`` (as read) was sent again; None if it changed since."""

    def expired_leases(self, now: float) -> list[Job]:
        """Running jobs whose lease ended before ``now``."""

    def stale_queued(self, before: float) -> list[Job]:
        """Queued jobs not updated since ``before`` (their queue message may be lost)."""

    def counts(self) -> dict[tuple[str, str], int]:
        """Number of jobs per (kind, status)."""

    def durations(self, buckets: tuple[float, ...]) -> dict[str, Histogram]:
        """Per kind, the run time (start to finish) of succeeded jobs as a histogram."""

    def recording_totals(self) -> tuple[int, int]:
        """Number of stored recordings and their total bytes."""

    def purge(self, before: float, limit: int = PURGE_BATCH) -> tuple[list[Recording], list[Job]]:
        """Delete at most ``limit`` recordings created and ``limit`` finished jobs ended before
        ``before``; return them (call again until both lists are empty)."""

    def beat_worker(self, worker_id: str, now: float) -> None:
        """Record that worker ``worker_id`` is alive and taking jobs at ``now``."""

    def drop_worker(self, worker_id: str) -> None:
        """Forget worker ``worker_id`` (it stopped taking jobs)."""

    def live_workers(self, since: float) -> list[str]:
        """Ids of the workers seen alive at or after ``since``."""
