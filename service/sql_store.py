"""The job store in SQLite or PostgreSQL through SQLAlchemy 2 Core: tables, the database's
errors as the service's, and the transitions as compare-and-set updates."""

from __future__ import annotations

import contextlib
import functools
import logging
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import asdict, fields
from typing import Any, Final

import sqlalchemy as sa
from sqlalchemy.engine import Engine

from .errors import (
    BackendError,
    StorageFull,
    StoreUnavailable,
    decorate_methods,
    says_disk_full,
    translate_methods,
)
from .jobs import PURGE_BATCH, Expect, Histogram, Job, JobStore, Recording, Status

log = logging.getLogger("bonefit.service")

_metadata = sa.MetaData()

recordings_table = sa.Table(
    "bonefit_recordings", _metadata,
    sa.Column("id", sa.String(32), primary_key=True),
    sa.Column("tenant", sa.String(200), nullable=False, index=True),
    sa.Column("key", sa.String(500), nullable=False),
    sa.Column("filename", sa.String(500)),
    sa.Column("content_type", sa.String(200)),
    sa.Column("format", sa.String(40), nullable=False),
    sa.Column("size", sa.BigInteger, nullable=False),
    sa.Column("sha256", sa.String(64), nullable=False),
    sa.Column("created_at", sa.Float, nullable=False, index=True),
    sa.Column("summary", sa.JSON, nullable=False),
)

jobs_table = sa.Table(
    "bonefit_jobs", _metadata,
    sa.Column("id", sa.String(32), primary_key=True),
    sa.Column("tenant", sa.String(200), nullable=False, index=True),
    sa.Column("kind", sa.String(40), nullable=False),
    sa.Column("recording_id", sa.String(32), nullable=False),
    sa.Column("params", sa.JSON, nullable=False),
    sa.Column("inputs", sa.JSON, nullable=False),
    sa.Column("created_at", sa.Float, nullable=False),
    sa.Column("updated_at", sa.Float, nullable=False),
    sa.Column("status", sa.String(16), nullable=False, index=True),
    sa.Column("started_at", sa.Float),
    sa.Column("finished_at", sa.Float, index=True),
    sa.Column("attempts", sa.Integer, nullable=False),
    sa.Column("fraction", sa.Float, nullable=False),
    sa.Column("stage", sa.String(100), nullable=False),
    sa.Column("message", sa.Text),
    sa.Column("error", sa.JSON),
    sa.Column("results", sa.JSON, nullable=False),
    sa.Column("worker", sa.String(200)),
    sa.Column("lease_until", sa.Float, index=True),
    sa.Column("cancel_requested", sa.Boolean, nullable=False),
    sa.Column("idempotency_key", sa.String(300)),
    sa.Column("request_hash", sa.String(64)),
    sa.Column("version", sa.Integer, nullable=False),
    sa.UniqueConstraint("tenant", "idempotency_key", name="bonefit_jobs_idempotency"),
)

workers_table = sa.Table(
    "bonefit_workers", _metadata,
    sa.Column("id", sa.String(200), primary_key=True),
    sa.Column("seen_at", sa.Float, nullable=False, index=True),
)

_RECORDING_FIELDS = [f.name for f in fields(Recording)]
_JOB_FIELDS = [f.name for f in fields(Job)]


def _recording(row: sa.Row[Any]) -> Recording:
    return Recording(**{name: getattr(row, name) for name in _RECORDING_FIELDS})


def _job(row: sa.Row[Any]) -> Job:
    job = Job(**{name: getattr(row, name) for name in _JOB_FIELDS})
    job.status = Status(job.status)
    return job


def _conditions(table: sa.Table, expect: Expect) -> list[sa.ColumnElement[bool]]:
    return [table.c[name].in_(value) if isinstance(value, tuple) else table.c[name] == value
            for name, value in expect.items()]


def _held(worker: str | None, lease_until: float | None = None) -> dict[str, Any]:
    """The condition that the job is running on ``worker`` (under that lease, when given)."""
    expect: dict[str, Any] = {"status": Status.RUNNING, "worker": worker}
    if lease_until is not None:
        expect["lease_until"] = lease_until
    return expect


_QUEUED_AGAIN: Final = {"status": Status.QUEUED, "stage": "queued", "worker": None,
                        "lease_until": None}
"""The changes putting a running job back in the queue."""


def sql_error(exc: Exception) -> BackendError | None:
    """The service's error for a database error (a full disk, an outage); None for others."""
    if says_disk_full(exc):
        return StorageFull(f"the job database is full ({type(exc).__name__})",
                           storage=StoreUnavailable.storage)
    outages = (sa.exc.OperationalError, sa.exc.InterfaceError, sa.exc.TimeoutError,
               ConnectionError, TimeoutError)
    if isinstance(exc, outages):
        return StoreUnavailable(f"the job database is unreachable ({type(exc).__name__})")
    return None


RECYCLE_SECONDS: Final = 1800.0
"""A pooled server connection is replaced after this long (idle timeouts of servers and
firewalls end older ones silently)."""


def resent_once(method: Callable[..., Any]) -> Callable[..., Any]:
    """Decorate a store method so that it runs once more when its connection turned out dead.

    The pool is not pinged before each use (``pool_pre_ping`` costs one more round trip on
    every call, twice on a job's way to its worker); instead a connection the server closed (a
    restart, an idle timeout) fails its first statement, SQLAlchemy invalidates the pool and
    the call is made again on a new connection. That statement never ran, so sending it again
    is safe. Should a connection die after the server committed but before the answer came
    back, a compare-and-set sent again finds its condition false (None, as for any lost race)
    and an insert finds its id taken by its own row, which :meth:`SqlJobStore.add_job` returns.
    """

    @functools.wraps(method)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return method(*args, **kwargs)
        except sa.exc.DBAPIError as exc:
            if not exc.connection_invalidated:
                raise
        return method(*args, **kwargs)

    return wrapper


def create_engine(url: str) -> Engine:
    """An engine for ``url``; SQLite gets WAL mode and a long busy timeout for many processes."""
    if url.startswith("postgresql://"):
        url = "postgresql+psycopg://" + url.removeprefix("postgresql://")
    if not url.startswith("sqlite"):
        return sa.create_engine(url, pool_recycle=RECYCLE_SECONDS)
    if url in ("sqlite://", "sqlite:///:memory:"):
        return sa.create_engine(url, poolclass=sa.pool.StaticPool,
                                connect_args={"check_same_thread": False})
    engine = sa.create_engine(url, connect_args={"timeout": 30, "check_same_thread": False})

    @sa.event.listens_for(engine, "connect")
    def _pragmas(dbapi_connection: Any, _record: Any) -> None:
        cursor = dbapi_connection.cursor()
        cursor.execute("PRAGMA journal_mode=WAL")
        cursor.execute("PRAGMA synchronous=NORMAL")
        cursor.close()

    return engine


def early_engine(engine: Engine) -> Engine:
    """For PostgreSQL, a second pool on the same database whose sessions commit without
    waiting for the disk (``synchronous_commit = off``): a row is visible to all as soon as
    its commit returns, and durable once the log is flushed (within 3 × ``wal_writer_delay``
    at most; at once by a later synchronous commit, see :meth:`SqlJobStore.wait_durable`).
    For SQLite ``engine`` itself: in WAL mode with ``synchronous=NORMAL`` no commit waits
    for the disk, and none is lost when a process crashes."""
    if engine.dialect.name != "postgresql":
        return engine
    early = sa.create_engine(engine.url, pool_recycle=RECYCLE_SECONDS)

    @sa.event.listens_for(early, "connect")
    def _no_wait(dbapi_connection: Any, _record: Any) -> None:
        autocommit, dbapi_connection.autocommit = dbapi_connection.autocommit, True
        cursor = dbapi_connection.cursor()
        cursor.execute("SET synchronous_commit = off")
        cursor.close()
        dbapi_connection.autocommit = autocommit

    return early


@translate_methods(sql_error)
@decorate_methods(resent_once)
class SqlJobStore:
    """The job store in SQLite or PostgreSQL through SQLAlchemy 2 Core; its methods raise
    :class:`~bonefit.service.errors.StorageFull` and
    :class:`~bonefit.service.errors.StoreUnavailable`.

    The calls on a job's way from submission to a worker (insert, read, compare-and-set) are
    one statement each, sent in autocommit mode: one round trip, where a transaction costs a
    BEGIN, the statement, a re-read and a COMMIT.
    """

    def __init__(self, engine: Engine) -> None:
        self.engine = engine
        self.early = early_engine(engine)  # for inserts that need not wait for the disk

    def dispose(self) -> None:
        """Close the pooled connections."""
        self.engine.dispose()
        if self.early is not self.engine:
            self.early.dispose()

    @contextlib.contextmanager
    def _single(self, engine: Engine | None = None) -> Iterator[sa.Connection]:
        """A connection for one statement, in autocommit mode (its own transaction)."""
        with (engine or self.engine).connect() as conn:
            yield conn.execution_options(isolation_level="AUTOCOMMIT")

    @classmethod
    def from_url(cls, url: str) -> SqlJobStore:
        """A store on the database at ``url``."""
        return cls(create_engine(url))

    def init(self) -> None:
        """Create the tables if missing (concurrent creators tolerated), and check that
        :meth:`wait_durable` may run here."""
        try:
            _metadata.create_all(self.engine)
        except (sa.exc.IntegrityError, sa.exc.ProgrammingError, sa.exc.OperationalError):
            _metadata.create_all(self.engine)  # another process created them at the same time
        try:
            self.wait_durable()
        except sa.exc.ProgrammingError as exc:  # EXECUTE on pg_logical_emit_message revoked
            log.warning("the job store cannot flush on demand (%s); every submission waits "
                        "for its own commit to reach the disk", str(exc.orig).strip())
            self.early.dispose()
            self.early = self.engine

    def ping(self) -> None:
        """Run a trivial query."""
        with self.engine.connect() as conn:
            conn.execute(sa.text("SELECT 1"))

    def add_recording(self, recording: Recording) -> None:
        """Insert a recording."""
        with self._single() as conn:
            conn.execute(recordings_table.insert().values(**asdict(recording)))

    def get_recording(self, tenant: str, recording_id: str) -> Recording | None:
        """The tenant's recording, or None."""
        t = recordings_table
        with self._single() as conn:
            row = conn.execute(sa.select(t).where(t.c.id == recording_id,
                                                  t.c.tenant == tenant)).first()
        return _recording(row) if row else None

    def list_recordings(self, tenant: str, *, before: str | None, limit: int) -> list[Recording]:
        """The tenant's recordings, newest first."""
        t = recordings_table
        query = sa.select(t).where(t.c.tenant == tenant).order_by(t.c.id.desc()).limit(limit)
        if before is not None:
            query = query.where(t.c.id < before)
        with self.engine.connect() as conn:
            return [_recording(row) for row in conn.execute(query)]

    def delete_recording(self, tenant: str, recording_id: str) -> Recording | None:
        """Delete and return the tenant's recording."""
        t = recordings_table
        with self.engine.begin() as conn:
            row = conn.execute(sa.select(t).where(t.c.id == recording_id,
                                                  t.c.tenant == tenant)).first()
            if row is None:
                return None
            conn.execute(t.delete().where(t.c.id == recording_id))
        return _recording(row)

    def add_job(self, job: Job, *, durable: bool = True) -> Job:
        """Insert a job, or return the one already holding its id (this call's own insert,
        sent again after its connection died) or its idempotency key.

        With ``durable=False`` PostgreSQL commits the insert without waiting for the disk:
        workers see the job at once, and :meth:`wait_durable` must return before anyone is
        told that it exists.
        """
        t = jobs_table
        try:
            with self._single(self.engine if durable else self.early) as conn:
                conn.execute(t.insert().values(**asdict(job)))
            return job
        except sa.exc.IntegrityError:
            same = [t.c.id == job.id]  # at most one row: our own holds our key
            if job.idempotency_key is not None:
                same.append(t.c.idempotency_key == job.idempotency_key)
            with self.engine.connect() as conn:
                row = conn.execute(sa.select(t).where(t.c.tenant == job.tenant,
                                                      sa.or_(*same))).first()
            if row is None:
                raise
            return _job(row)

    def wait_durable(self) -> None:
        """Return once every commit made before the call is on disk.

        On PostgreSQL one synchronous commit of a transaction that wrote to the log (a
        logical-decoding message, which needs no table and no privilege): the server flushes
        the log up to that commit, and so every asynchronous commit before it (a transaction
        that writes nothing, even ``SELECT txid_current()``, commits without a flush).
        SQLite commits are as durable as they get when they return.
        """
        if self.early is not self.engine:
            with self._single() as conn:
                conn.execute(sa.text("SELECT pg_logical_emit_message(true, 'bonefit', '')"))

    def get_job(self, job_id: str, tenant: str | None = None) -> Job | None:
        """The job, or None."""
        t = jobs_table
        query = sa.select(t).where(t.c.id == job_id)
        if tenant is not None:
            query = query.where(t.c.tenant == tenant)
        with self._single() as conn:
            row = conn.execute(query).first()
        return _job(row) if row else None

    def list_jobs(self, tenant: str, *, status: Status | str | None, kind: str | None,
                  before: str | None, limit: int) -> list[Job]:
        """The tenant's jobs, newest first."""
        t = jobs_table
        query = sa.select(t).where(t.c.tenant == tenant).order_by(t.c.id.desc()).limit(limit)
        if status is not None:
            query = query.where(t.c.status == Status(status).value)
        if kind is not None:
            query = query.where(t.c.kind == kind)
        if before is not None:
            query = query.where(t.c.id < before)
        with self.engine.connect() as conn:
            return [_job(row) for row in conn.execute(query)]

    def update_job(self, job_id: str, changes: Mapping[str, Any], *, expect: Expect) -> Job | None:
        """Compare and set in one statement (UPDATE ... RETURNING)."""
        t = jobs_table
        values = {**changes, "version": t.c.version + 1, "updated_at": time.time()}
        with self._single() as conn:
            row = conn.execute(t.update().where(t.c.id == job_id, *_conditions(t, expect))
                               .values(**values).returning(*t.c)).first()
        return _job(row) if row else None

    def claim(self, job_id: str, worker: str, now: float, lease_seconds: float) -> Job | None:
        """Queued → running on ``worker``, one more attempt (counted by the database)."""
        return self.update_job(job_id, {
            "status": Status.RUNNING, "worker": worker, "attempts": jobs_table.c.attempts + 1,
            "started_at": now, "lease_until": now + lease_seconds, "stage": "starting",
            "message": None, "fraction": 0.0,
        }, expect={"status": Status.QUEUED})

    def renew(self, job_id: str, worker: str, lease_until: float, *,
              fraction: float | None = None, stage: str | None = None) -> Job | None:
        """Running on ``worker`` → a new lease end (and progress)."""
        changes: dict[str, Any] = {"lease_until": lease_until}
        if fraction is not None:
            changes["fraction"] = fraction
        if stage is not None:
            changes["stage"] = stage
        return self.update_job(job_id, changes, expect=_held(worker))

    def requeue(self, job_id: str, worker: str | None, message: str, *,
                lease_until: float | None = None) -> Job | None:
        """Running on ``worker`` (with that lease) → queued, the attempt counted."""
        return self.update_job(job_id, {**_QUEUED_AGAIN, "message": message},
                               expect=_held(worker, lease_until))

    def hand_back(self, job: Job, worker: str, message: str) -> Job | None:
        """Running on ``worker`` → queued, the attempt not counted."""
        return self.update_job(job.id, {**_QUEUED_AGAIN, "message": message,
                                        "attempts": job.attempts - 1}, expect=_held(worker))

    def succeed(self, job_id: str, worker: str, results: Mapping[str, str],
                now: float) -> Job | None:
        """Running on ``worker`` → succeeded with ``results``."""
        return self._end(job_id, Status.SUCCEEDED, now, _held(worker), stage="done",
                         fraction=1.0, results=dict(results))

    def fail(self, job_id: str, worker: str | None, error: Mapping[str, Any], now: float, *,
             lease_until: float | None = None) -> Job | None:
        """Running on ``worker`` (with that lease) → failed with ``error``."""
        return self._end(job_id, Status.FAILED, now, _held(worker, lease_until),
                         error=dict(error))

    def cancel(self, job_id: str, worker: str | None, now: float, *,
               lease_until: float | None = None) -> Job | None:
        """Running on ``worker`` (with that lease) → cancelled."""
        return self._end(job_id, Status.CANCELLED, now, _held(worker, lease_until))

    def cancel_queued(self, job_id: str, now: float) -> Job | None:
        """Queued → cancelled."""
        return self._end(job_id, Status.CANCELLED, now, {"status": Status.QUEUED})

    def request_cancel(self, job_id: str) -> Job | None:
        """Running → cancel requested."""
        return self.update_job(job_id, {"cancel_requested": True, "message": "cancelling"},
                               expect={"status": Status.RUNNING})

    def withdraw(self, job_id: str, error: Mapping[str, Any], now: float) -> Job | None:
        """Queued → failed with ``error``, its idempotency key freed for the client's retry."""
        return self._end(job_id, Status.FAILED, now, {"status": Status.QUEUED},
                         error=dict(error), idempotency_key=None)

    def mark_resent(self, job: Job) -> Job | None:
        """Queued and unchanged since read → a new ``updated_at`` (and version)."""
        return self.update_job(job.id, {}, expect={"status": Status.QUEUED,
                                                   "version": job.version})

    def _end(self, job_id: str, status: Status, now: float, expect: Expect,
             **changes: Any) -> Job | None:
        return self.update_job(job_id, {"status": status, "stage": status.value,
                                        "finished_at": now, "worker": None,
                                        "lease_until": None, **changes}, expect=expect)

    def expired_leases(self, now: float) -> list[Job]:
        """Running jobs whose lease ended."""
        t = jobs_table
        return self._jobs_where(t.c.status == Status.RUNNING.value, t.c.lease_until < now)

    def stale_queued(self, before: float) -> list[Job]:
        """Queued jobs not updated since ``before``."""
        t = jobs_table
        return self._jobs_where(t.c.status == Status.QUEUED.value, t.c.updated_at < before)

    def _jobs_where(self, *conditions: sa.ColumnElement[bool]) -> list[Job]:
        with self.engine.connect() as conn:
            return [_job(row) for row in conn.execute(sa.select(jobs_table).where(*conditions))]

    def counts(self) -> dict[tuple[str, str], int]:
        """Jobs per (kind, status)."""
        t = jobs_table
        with self.engine.connect() as conn:
            rows = conn.execute(sa.select(t.c.kind, t.c.status, sa.func.count())
                                .group_by(t.c.kind, t.c.status))
            return {(kind, status): int(n) for kind, status, n in rows}

    def durations(self, buckets: tuple[float, ...]) -> dict[str, Histogram]:
        """Run time of succeeded jobs, counted in the database."""
        t = jobs_table
        seconds = t.c.finished_at - t.c.started_at
        columns = [sa.func.sum(sa.case((seconds <= b, 1), else_=0)) for b in buckets]
        query = (sa.select(t.c.kind, sa.func.count(), sa.func.sum(seconds), *columns)
                 .where(t.c.status == Status.SUCCEEDED.value, t.c.started_at.is_not(None),
                        t.c.finished_at.is_not(None)).group_by(t.c.kind))
        with self.engine.connect() as conn:
            return {row[0]: Histogram([int(c or 0) for c in row[3:]], int(row[1]),
                                      float(row[2] or 0.0)) for row in conn.execute(query)}

    def recording_totals(self) -> tuple[int, int]:
        """Count and bytes of recordings."""
        t = recordings_table
        with self.engine.connect() as conn:
            n, total = conn.execute(sa.select(sa.func.count(), sa.func.sum(t.c.size))).one()
        return int(n), int(total or 0)

    def purge(self, before: float, limit: int = PURGE_BATCH) -> tuple[list[Recording], list[Job]]:
        """Delete at most ``limit`` of each older than ``before`` in one short transaction."""
        r, j = recordings_table, jobs_table
        with self.engine.begin() as conn:
            recs = [_recording(row) for row in conn.execute(
                sa.select(r).where(r.c.created_at < before).limit(limit))]
            jobs = [_job(row) for row in conn.execute(
                sa.select(j).where(j.c.finished_at < before).limit(limit))]
            if recs:
                conn.execute(r.delete().where(r.c.id.in_([x.id for x in recs])))
            if jobs:
                conn.execute(j.delete().where(j.c.id.in_([x.id for x in jobs])))
        return recs, jobs

    def beat_worker(self, worker_id: str, now: float) -> None:
        """Update the worker's row, inserting it the first time.

        On the early pool: an idle worker beats between its looks at the queue, and a beat
        waiting for the disk (a stall of the shared disk: 100 ms and more) would keep a job
        queued meanwhile waiting too; a beat a database crash takes back only makes the
        worker look gone until its next one.
        """
        w = workers_table
        beat = w.update().where(w.c.id == worker_id).values(seen_at=now)
        with self._single(self.early) as conn:
            if conn.execute(beat).rowcount == 1:
                return
            try:
                conn.execute(w.insert().values(id=worker_id, seen_at=now))
            except sa.exc.IntegrityError:  # inserted meanwhile by a duplicate id: just update
                conn.execute(beat)

    def drop_worker(self, worker_id: str) -> None:
        """Delete the worker's row."""
        w = workers_table
        with self.engine.begin() as conn:
            conn.execute(w.delete().where(w.c.id == worker_id))

    def live_workers(self, since: float) -> list[str]:
        """Workers whose row was updated since ``since``."""
        w = workers_table
        with self.engine.connect() as conn:
            return [row[0] for row in conn.execute(
                sa.select(w.c.id).where(w.c.seen_at >= since).order_by(w.c.id))]


def open_store(url: str) -> JobStore:
    """The store for ``url``, any SQLAlchemy URL (SQLite or PostgreSQL)."""
    if url.startswith("memory:"):
        # each worker process would have a store of its own, and never see the API's jobs
        raise ValueError(f"unsupported database URL {url!r}: the job store is shared by "
                         "processes; use sqlite:///path or postgresql://")
    return SqlJobStore.from_url(url)

