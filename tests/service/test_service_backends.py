"""The job store, queue and artifact back-ends, each implementation against one contract."""

from __future__ import annotations

import dataclasses
import errno
import os
import shutil
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, cast

import pytest
import sqlalchemy as sa

from bonefit.service.artifacts import ArtifactStore, LocalArtifactStore, open_artifacts
from bonefit.service.errors import QueueUnavailable, StorageFull, StoreUnavailable
from bonefit.service.jobs import Job, JobStore, Recording, Status, new_id
from bonefit.service.queue import HueyQueue, JobQueue, open_queue
from bonefit.service.runtime import Runtime
from bonefit.service.settings import Settings
from bonefit.service.sql_store import SqlJobStore, open_store
from bonefit.service.wake import Waker
from bonefit.service.worker import Worker
from tests.service.helpers import (
    FAKE_KINDS,
    TestClient,
    local_queue,
    require_services,
    submit,
    upload,
)

POSTGRES_ADMINS = ([os.environ["BONEFIT_TEST_POSTGRES_URL"]]
                   if os.environ.get("BONEFIT_TEST_POSTGRES_URL") else
                   ["postgresql://postgres@127.0.0.1:5432/postgres",
                    "postgresql://root@127.0.0.1:5432/postgres"])
"""Admin connections to try (the same variable as the e2e tests)."""
REDIS_BASE = os.environ.get("BONEFIT_TEST_REDIS_URL", "redis://127.0.0.1:6379").rstrip("/")


def unavailable(reason: str) -> None:
    if require_services():
        pytest.fail(f"{reason} (BONEFIT_TEST_REQUIRE_SERVICES=1)")
    pytest.skip(reason)


@pytest.fixture(scope="module")
def postgres_url() -> Iterator[str]:
    """A fresh PostgreSQL database, dropped afterwards."""
    name = f"bonefit_unit_{uuid.uuid4().hex[:8]}"
    errors = []
    for url in POSTGRES_ADMINS:
        admin = sa.create_engine(url.replace("postgresql://", "postgresql+psycopg://", 1),
                                 isolation_level="AUTOCOMMIT")
        try:
            with admin.connect() as conn:
                conn.execute(sa.text(f"CREATE DATABASE {name}"))
            break
        except sa.exc.SQLAlchemyError as exc:
            errors.append(f"{url}: {type(exc).__name__}")
            admin.dispose()
    else:
        unavailable(f"PostgreSQL not reachable ({'; '.join(errors)})")
    yield admin.url.set(database=name).render_as_string(hide_password=False)
    with admin.connect() as conn:
        conn.execute(sa.text(f"DROP DATABASE IF EXISTS {name} WITH (FORCE)"))
    admin.dispose()


@pytest.fixture(params=["sqlite", "postgresql"])
def store(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[JobStore]:
    """The job store on each database."""
    if request.param == "sqlite":
        sql = SqlJobStore.from_url(f"sqlite:///{tmp_path / 'jobs.db'}")
    else:
        sql = SqlJobStore.from_url(request.getfixturevalue("postgres_url"))
    sql.init()
    sql.init()  # idempotent
    with sql.engine.begin() as conn:  # the PostgreSQL database is shared by the module's tests
        conn.execute(sa.text("DELETE FROM bonefit_jobs"))
        conn.execute(sa.text("DELETE FROM bonefit_recordings"))
        conn.execute(sa.text("DELETE FROM bonefit_workers"))
    yield sql
    sql.dispose()


def job(tenant: str = "t", **extra: object) -> Job:
    now = time.time()
    fields: dict[str, object] = {"kind": "skeleton", **extra}
    return Job(id=new_id(), tenant=tenant, recording_id="r", params={"a": 1}, inputs={},
               created_at=now, updated_at=now, **fields)  # type: ignore[arg-type]


def recording(tenant: str = "t", created_at: float | None = None) -> Recording:
    return Recording(id=new_id(), tenant=tenant, key=f"{tenant}/x", filename="a.csv",
                     content_type="text/csv", format="sensor-csv", size=10, sha256="0" * 64,
                     created_at=time.time() if created_at is None else created_at,
                     summary={"frames": 3, "sensors": ["pelvis"]})


def test_ids_are_time_ordered_and_unique() -> None:
    ids = [new_id() for _ in range(1000)]
    assert len(set(ids)) == 1000
    assert all(len(i) == 26 for i in ids)
    first = new_id()
    time.sleep(0.002)
    assert new_id() > first


def test_recordings(store: JobStore) -> None:
    recs = [recording() for _ in range(3)]
    for r in recs:
        store.add_recording(r)
    store.add_recording(recording("other"))
    got = store.get_recording("t", recs[0].id)
    assert got is not None
    assert got.summary == recs[0].summary
    assert store.get_recording("other", recs[0].id) is None
    page = store.list_recordings("t", before=None, limit=2)
    assert [r.id for r in page] == [recs[2].id, recs[1].id]
    assert [r.id for r in store.list_recordings("t", before=recs[1].id, limit=2)] == [recs[0].id]
    assert store.recording_totals() == (4, 40)
    assert store.delete_recording("other", recs[0].id) is None
    assert store.delete_recording("t", recs[0].id) is not None
    assert store.get_recording("t", recs[0].id) is None


def test_jobs_compare_and_set(store: JobStore) -> None:
    j = store.add_job(job())
    assert store.get_job(j.id, "nobody") is None
    running = store.update_job(j.id, {"status": "running", "worker": "w1", "attempts": 1},
                               expect={"status": "queued"})
    assert running is not None
    assert running.version == 2
    assert running.worker == "w1"
    assert store.update_job(j.id, {"status": "running"}, expect={"status": "queued"}) is None
    assert store.update_job(j.id, {"fraction": 0.5}, expect={"worker": "w2"}) is None
    done = store.update_job(j.id, {"status": "succeeded", "results": {"json": "k"}},
                            expect={"status": ("queued", "running"), "worker": "w1"})
    assert done is not None
    assert done.results == {"json": "k"}
    assert done.version == 3


def claimed(store: JobStore, worker: str = "w1", now: float = 100.0) -> Job:
    """A new job, claimed by ``worker`` at ``now`` with a 30 s lease."""
    j = store.add_job(job())
    running = store.claim(j.id, worker, now, 30.0)
    assert running is not None
    return running


def test_a_claim_is_won_once_and_counts_an_attempt(store: JobStore) -> None:
    j = store.add_job(job())
    running = store.claim(j.id, "w1", 100.0, 30.0)
    assert running is not None
    assert (running.status, running.worker, running.attempts) == (Status.RUNNING, "w1", 1)
    assert (running.started_at, running.lease_until, running.stage) == (100.0, 130.0,
                                                                         "starting")
    assert store.claim(j.id, "w2", 101.0, 30.0) is None  # running: the second claim loses
    back = store.requeue(j.id, "w1", "again")
    assert back is not None
    again = store.claim(j.id, "w2", 101.0, 30.0)  # queued again: claimed, attempt 2
    assert again is not None
    assert (again.worker, again.attempts) == ("w2", 2)
    assert store.claim(j.id, "w1", 102.0, 30.0) is None
    assert store.claim("no-such-job", "w1", 102.0, 30.0) is None
    cancelled = store.add_job(job())
    assert store.cancel_queued(cancelled.id, 103.0) is not None
    assert store.claim(cancelled.id, "w1", 104.0, 30.0) is None


def test_only_the_holder_renews_its_lease(store: JobStore) -> None:
    j = claimed(store)
    renewed = store.renew(j.id, "w1", 200.0, fraction=0.5, stage="solving")
    assert renewed is not None
    assert (renewed.lease_until, renewed.fraction, renewed.stage) == (200.0, 0.5, "solving")
    kept = store.renew(j.id, "w1", 210.0)
    assert kept is not None
    assert (kept.lease_until, kept.fraction, kept.stage) == (210.0, 0.5, "solving")
    assert store.renew(j.id, "w2", 300.0) is None


def test_a_requeue_counts_the_attempt_and_a_hand_back_does_not(store: JobStore) -> None:
    j = claimed(store)
    again = store.requeue(j.id, "w1", "crashed")
    assert again is not None
    assert (again.status, again.attempts, again.worker, again.lease_until, again.message) == (
        Status.QUEUED, 1, None, None, "crashed")
    j = store.claim(again.id, "w1", 100.0, 30.0)
    assert j is not None
    assert store.hand_back(j, "w2", "shut down") is None  # not its job
    back = store.hand_back(j, "w1", "shut down")
    assert back is not None
    assert (back.status, back.attempts, back.worker) == (Status.QUEUED, 1, None)


def test_the_reaper_takes_a_job_only_under_the_expired_lease(store: JobStore) -> None:
    j = claimed(store)
    assert store.renew(j.id, "w1", 500.0) is not None  # renewed after the reaper read it
    assert store.requeue(j.id, "w1", "lost", lease_until=130.0) is None
    assert store.fail(j.id, "w1", {"status": 503}, 140.0, lease_until=130.0) is None
    assert store.cancel(j.id, "w1", 140.0, lease_until=130.0) is None
    assert store.requeue(j.id, "w1", "lost", lease_until=500.0) is not None


def test_a_job_ends_once_and_only_by_its_worker(store: JobStore) -> None:
    j = claimed(store)
    assert store.succeed(j.id, "w2", {"json": "k"}, 150.0) is None
    done = store.succeed(j.id, "w1", {"json": "k"}, 150.0)
    assert done is not None
    assert (done.status, done.stage, done.fraction, done.results) == (
        Status.SUCCEEDED, "done", 1.0, {"json": "k"})
    assert (done.finished_at, done.worker, done.lease_until) == (150.0, None, None)
    assert store.fail(j.id, "w1", {"status": 500}, 151.0) is None
    assert store.cancel(j.id, "w1", 151.0) is None
    failed = store.fail(claimed(store).id, "w1", {"status": 422}, 150.0)
    assert failed is not None
    assert (failed.status, failed.stage, failed.error) == (Status.FAILED, "failed",
                                                           {"status": 422})
    cancelled = store.cancel(claimed(store).id, "w1", 150.0)
    assert cancelled is not None
    assert (cancelled.status, cancelled.stage, cancelled.finished_at) == (
        Status.CANCELLED, "cancelled", 150.0)


def test_cancelling_a_queued_job_ends_it_and_a_running_one_asks(store: JobStore) -> None:
    queued = store.add_job(job())
    assert store.request_cancel(queued.id) is None  # nothing runs it
    cancelled = store.cancel_queued(queued.id, 150.0)
    assert cancelled is not None
    assert (cancelled.status, cancelled.finished_at) == (Status.CANCELLED, 150.0)
    assert store.cancel_queued(queued.id, 151.0) is None
    running = claimed(store)
    assert store.cancel_queued(running.id, 150.0) is None
    asked = store.request_cancel(running.id)
    assert asked is not None
    assert (asked.status, asked.cancel_requested, asked.message) == (Status.RUNNING, True,
                                                                     "cancelling")


def test_a_withdrawn_job_frees_its_idempotency_key(store: JobStore) -> None:
    refused = store.add_job(job(idempotency_key="k", request_hash="h"))
    assert store.withdraw(claimed(store).id, {"status": 503}, 150.0) is None  # not queued
    withdrawn = store.withdraw(refused.id, {"status": 503}, 150.0)
    assert withdrawn is not None
    assert (withdrawn.status, withdrawn.idempotency_key, withdrawn.error) == (
        Status.FAILED, None, {"status": 503})
    assert store.add_job(job(idempotency_key="k", request_hash="h")).id != refused.id


def test_a_resent_job_is_marked_once(store: JobStore) -> None:
    j = store.add_job(job())
    resent = store.mark_resent(j)
    assert resent is not None
    assert resent.version == j.version + 1
    assert store.mark_resent(j) is None  # another process resent it meanwhile


def test_statuses_are_stored_as_their_values(store: JobStore) -> None:
    # the database holds the API's strings, whichever driver writes the enum
    j = claimed(store)
    assert isinstance(store, SqlJobStore)
    with store.engine.connect() as conn:
        stored = conn.execute(sa.text("SELECT status FROM bonefit_jobs WHERE id = :id"),
                              {"id": j.id}).scalar_one()
    assert stored == "running"
    assert [x.id for x in store.list_jobs("t", status=Status.RUNNING, kind=None, before=None,
                                          limit=10)] == [j.id]
    assert store.counts() == {("skeleton", "running"): 1}


def test_a_full_database_is_storage_full(tmp_path: Path) -> None:
    # SQLite answers SQLITE_FULL ("database or disk is full") past max_page_count
    store = SqlJobStore.from_url(f"sqlite:///{tmp_path / 'jobs.db'}")
    store.init()
    with store.engine.connect() as conn:
        pages = conn.execute(sa.text("PRAGMA page_count")).scalar_one()

    @sa.event.listens_for(store.engine, "connect")
    def _cap(dbapi_connection: Any, _record: Any) -> None:
        dbapi_connection.execute(f"PRAGMA max_page_count = {pages}")

    def fill() -> None:
        for _ in range(100):
            store.add_job(job(message="x" * 10_000))

    store.dispose()
    with pytest.raises(StorageFull, match="job database is full") as caught:
        fill()
    assert (caught.value.storage, caught.value.cause_name) == ("job database",
                                                               "OperationalError")
    store.dispose()


def test_an_unreachable_database_is_unavailable(tmp_path: Path) -> None:
    store = SqlJobStore.from_url(f"sqlite:///{tmp_path / 'missing' / 'jobs.db'}")
    with pytest.raises(StoreUnavailable) as caught:
        store.ping()
    assert caught.value.cause_name == "OperationalError"
    with pytest.raises(StoreUnavailable):
        store.get_job("x")
    store.dispose()


def test_a_connection_the_server_closed_is_replaced_within_the_call(postgres_url: str) -> None:
    """No ping before each use: a pooled connection the server dropped (a restart) fails its
    first statement, and the store makes the call again on a new connection."""
    store = SqlJobStore.from_url(postgres_url)
    store.init()
    stored = store.add_job(job())
    pids = set()
    for _ in range(3):  # fill the pool with connections of this engine
        with store.engine.connect() as conn:
            pids.add(conn.execute(sa.text("SELECT pg_backend_pid()")).scalar_one())
    admin = sa.create_engine(postgres_url, isolation_level="AUTOCOMMIT")
    with admin.connect() as conn:
        for pid in pids:
            conn.execute(sa.text("SELECT pg_terminate_backend(:pid)"), {"pid": pid})
    admin.dispose()
    found = store.get_job(stored.id)
    assert found is not None
    assert found.id == stored.id
    claimed = store.claim(stored.id, "w", time.time(), 30.0)  # a write after the outage
    assert claimed is not None
    assert claimed.status is Status.RUNNING
    store.dispose()


def test_an_early_insert_is_seen_at_once_and_durable_after_the_wait(store: JobStore) -> None:
    """``add_job(durable=False)``: the row is visible to other connections when the call
    returns; on PostgreSQL it was committed without waiting for the disk, and
    ``wait_durable`` returns only once the log is flushed past it."""
    stored = store.add_job(job(), durable=False)
    found = store.get_job(stored.id)  # another pool's connection on PostgreSQL
    assert found is not None
    assert found.status is Status.QUEUED
    assert isinstance(store, SqlJobStore)
    if store.engine.dialect.name != "postgresql":
        assert store.early is store.engine
        store.wait_durable()
        return
    with store.early.connect() as early, store.engine.connect() as main:
        assert early.execute(sa.text("SHOW synchronous_commit")).scalar_one() == "off"
        assert main.execute(sa.text("SHOW synchronous_commit")).scalar_one() == "on"
        written = main.execute(sa.text("SELECT pg_current_wal_insert_lsn()")).scalar_one()
    store.wait_durable()
    with store.engine.connect() as main:
        assert main.execute(sa.text("SELECT pg_current_wal_flush_lsn() >= CAST(:lsn AS pg_lsn)"),
                            {"lsn": written}).scalar_one()


def test_without_the_flush_function_every_insert_waits_for_the_disk(
        postgres_url: str, caplog: pytest.LogCaptureFixture) -> None:
    """A database where EXECUTE on pg_logical_emit_message was revoked: ``init`` says so and
    the store falls back to durable inserts, instead of a 500 on every submission."""
    role = f"bonefit_plain_{uuid.uuid4().hex[:8]}"
    admin = sa.create_engine(postgres_url, isolation_level="AUTOCOMMIT")
    with admin.connect() as conn:
        conn.execute(sa.text(f"CREATE ROLE {role} LOGIN"))
        conn.execute(sa.text(f"GRANT ALL ON SCHEMA public TO {role}"))
        conn.execute(sa.text(f"GRANT ALL ON ALL TABLES IN SCHEMA public TO {role}"))
        conn.execute(sa.text("REVOKE EXECUTE ON FUNCTION pg_logical_emit_message(boolean, text, "
                             "text) FROM PUBLIC"))
    store = SqlJobStore.from_url(sa.make_url(postgres_url).set(username=role, password=None)
                                 .render_as_string(hide_password=False))
    try:
        store.init()
        assert store.early is store.engine
        assert "cannot flush on demand" in caplog.text
        stored = store.add_job(job(), durable=False)
        store.wait_durable()
        assert store.get_job(stored.id) is not None
    finally:
        store.dispose()
        with admin.connect() as conn:
            conn.execute(sa.text("GRANT EXECUTE ON FUNCTION pg_logical_emit_message(boolean, "
                                 "text, text) TO PUBLIC"))
            conn.execute(sa.text(f"DROP OWNED BY {role}"))
            conn.execute(sa.text(f"DROP ROLE {role}"))
        admin.dispose()


@pytest.mark.parametrize("durable", [True, False])
def test_an_insert_sent_again_after_its_commit_finds_its_own_row(postgres_url: str,
                                                                durable: bool) -> None:
    """The server committed the insert but the connection died before its answer: the store
    sends it again on a new connection, meets its own id, and returns its own row (not the
    tenant's first job without an idempotency key, nor an integrity error)."""
    import psycopg

    store = SqlJobStore.from_url(postgres_url)
    store.init()
    older = store.add_job(job("lost-answer"))  # a job without a key, as the new one
    lost: list[str] = []

    def lose_the_answer(conn: sa.Connection, _cursor: Any, statement: str, *_: Any) -> None:
        if statement.startswith("INSERT INTO bonefit_jobs") and not lost:
            lost.append(statement)  # autocommit: the row is committed already
            dbapi = conn.connection.dbapi_connection
            assert dbapi is not None
            dbapi.close()
            raise psycopg.OperationalError("server closed the connection unexpectedly")

    for engine in {store.engine, store.early}:
        sa.event.listen(engine, "after_cursor_execute", lose_the_answer)
    new = job("lost-answer")
    try:
        stored = store.add_job(new, durable=durable)
    finally:
        store.dispose()
    assert lost
    assert stored.id == new.id != older.id
    assert stored.created_at == new.created_at


def test_an_unreachable_queue_is_unavailable() -> None:
    queue = open_queue("redis://127.0.0.1:1/0")  # nothing listens on port 1
    with pytest.raises(QueueUnavailable) as caught:
        queue.enqueue("x")
    assert caught.value.cause_name == "ConnectionError"
    with pytest.raises(QueueUnavailable):
        queue.ping()


def test_a_full_artifact_disk_is_storage_full(tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    store = LocalArtifactStore(tmp_path / "artifacts")
    src = tmp_path / "src.bin"
    src.write_bytes(b"x")

    def no_space(*args: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(shutil, "move", no_space)
    with pytest.raises(StorageFull) as caught:
        store.put_file("t/recordings/a.bin", src)
    assert caught.value.storage == "artifact storage"
    with pytest.raises(FileNotFoundError):  # absent keys stay FileNotFoundError
        b"".join(store.iter_bytes("t/recordings/a.bin"))


def test_idempotency_keys_are_per_tenant(store: JobStore) -> None:
    a = store.add_job(job(idempotency_key="k", request_hash="h"))
    again = store.add_job(job(idempotency_key="k", request_hash="h2"))
    assert again.id == a.id
    assert again.request_hash == "h"
    assert store.add_job(job("other", idempotency_key="k")).id != a.id


def test_a_freed_idempotency_key_takes_a_new_job(store: JobStore) -> None:
    refused = store.add_job(job(idempotency_key="k", request_hash="h"))
    assert store.update_job(refused.id, {"status": "failed", "idempotency_key": None},
                            expect={"status": "queued"}) is not None
    retried = store.add_job(job(idempotency_key="k", request_hash="h"))
    assert retried.id != refused.id
    assert store.add_job(job(idempotency_key="k", request_hash="h")).id == retried.id


def test_worker_heartbeats(store: JobStore) -> None:
    now = time.time()
    assert store.live_workers(now - 10) == []
    store.beat_worker("a:1", now - 60)
    store.beat_worker("b:2", now)
    assert store.live_workers(now - 10) == ["b:2"]
    store.beat_worker("a:1", now)  # an update, not a second row
    assert store.live_workers(now - 10) == ["a:1", "b:2"]
    store.drop_worker("a:1")
    store.drop_worker("gone:3")
    assert store.live_workers(0) == ["b:2"]


def _expired_jobs(store: JobStore, n: int, finished_at: float) -> None:
    """``n`` finished jobs; on PostgreSQL in one INSERT ... SELECT (a few hundred ms)."""
    if isinstance(store, SqlJobStore) and store.engine.dialect.name == "postgresql":
        with store.engine.begin() as conn:
            conn.execute(sa.text(
                "INSERT INTO bonefit_jobs (id, tenant, kind, recording_id, params, inputs, "
                "created_at, updated_at, status, finished_at, attempts, fraction, stage, "
                "results, cancel_requested, version) SELECT 'old' || g, 't', 'skeleton', 'r', "
                "'{}', '{}', 0, 0, 'succeeded', :at, 1, 1, 'done', "
                "'{\"json\": \"t/jobs/x\"}', false, 1 FROM generate_series(1, :n) AS g"),
                {"at": finished_at, "n": n})
        return
    for _ in range(n):
        store.add_job(job(status="succeeded", finished_at=finished_at,
                          results={"json": "t/jobs/x"}))


def test_retention_purges_any_number_of_rows_in_batches(store: JobStore,
                                                        tmp_path: Path) -> None:
    from bonefit.service.jobs import PURGE_BATCH
    from bonefit.service.retention import purge
    from bonefit.service.runtime import Runtime

    postgres = isinstance(store, SqlJobStore) and store.engine.dialect.name == "postgresql"
    n = 70_000 if postgres else 2 * PURGE_BATCH + 5  # over PostgreSQL's 65,535 parameters
    now = time.time()
    _expired_jobs(store, n, now - 100)
    kept = store.add_job(job(status="succeeded", finished_at=now))
    store.add_recording(recording(created_at=now - 100))
    runtime = Runtime(Settings(data_dir=tmp_path, retention_seconds=50), store, local_queue(),
                      LocalArtifactStore(tmp_path / "artifacts"))
    assert purge(runtime, now=now) == n + 1
    assert store.counts() == {("skeleton", "succeeded"): 1}
    assert store.get_job(kept.id) is not None


def test_concurrent_claims_have_one_winner(store: JobStore) -> None:
    j = store.add_job(job())
    winners: list[str] = []

    def claim(name: str) -> None:
        if store.update_job(j.id, {"status": "running", "worker": name},
                            expect={"status": "queued"}):
            winners.append(name)

    threads = [threading.Thread(target=claim, args=(f"w{i}",)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(winners) == 1


def test_listing_leases_counts_and_purge(store: JobStore) -> None:
    now = time.time()
    a = store.add_job(job())
    b = store.add_job(job(kind="translation"))
    c = store.add_job(job())
    store.update_job(a.id, {"status": "running", "lease_until": now - 1}, expect={})
    store.update_job(b.id, {"status": "succeeded", "started_at": now - 3, "finished_at": now - 1},
                     expect={})
    store.update_job(c.id, {"status": "running", "lease_until": now + 60}, expect={})
    assert [x.id for x in store.expired_leases(now)] == [a.id]
    assert store.counts() == {("skeleton", "running"): 2, ("translation", "succeeded"): 1}
    hist = store.durations((1.0, 2.5, 10.0))
    assert list(hist) == ["translation"]
    assert hist["translation"].counts == [0, 1, 1]
    assert hist["translation"].count == 1
    assert hist["translation"].total == pytest.approx(2.0)
    assert [x.id for x in store.list_jobs("t", status="running", kind=None, before=None,
                                          limit=10)] == [c.id, a.id]
    assert [x.id for x in store.list_jobs("t", status=None, kind="translation", before=None,
                                          limit=10)] == [b.id]
    old = recording(created_at=now - 100)
    store.add_recording(old)
    store.add_recording(recording())
    recs, jobs = store.purge(now - 50)
    assert [r.id for r in recs] == [old.id]
    assert jobs == []
    recs, jobs = store.purge(now)
    assert recs == []
    assert [j.id for j in jobs] == [b.id]
    store.ping()


# ---------------------------------------------------------------------------------- queue


def redis_queues(count: int) -> Iterator[list[HueyQueue]]:
    """``count`` connections to one Redis queue of this test's own (other sessions may use
    the same database); flushed afterwards."""
    import redis
    from huey import RedisHuey

    url = f"{REDIS_BASE}/0"
    client = redis.Redis.from_url(url)
    try:
        client.ping()
    except redis.exceptions.ConnectionError:
        unavailable(f"Redis not reachable at {url}")
    finally:
        client.close()
    name = f"bonefit-test-{uuid.uuid4().hex[:8]}"
    hueys = [RedisHuey(name, url=url, results=False) for _ in range(count)]
    yield [HueyQueue(huey) for huey in hueys]
    hueys[0].flush()


@pytest.fixture(params=["memory-huey", "sqlite", "redis"])
def queue(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[JobQueue]:
    """The queue on each huey storage."""
    if request.param == "memory-huey":
        yield local_queue()
    elif request.param == "sqlite":
        yield open_queue(f"sqlite:///{tmp_path / 'queue.db'}")
    else:
        for (one,) in redis_queues(1):
            yield one


def test_queue_delivers_each_id_once(queue: JobQueue) -> None:
    queue.ping()
    for i in range(3):
        queue.enqueue(f"job{i}")
    assert queue.depth() == 3
    assert queue.pending() == {"job0", "job1", "job2"}
    got: list[str] = []
    while queue.run_next(got.append):
        pass
    assert got == ["job0", "job1", "job2"]
    assert queue.depth() == 0


def test_sqlite_queue_is_shared_between_instances(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'q.db'}"
    open_queue(url).enqueue("x")
    got: list[str] = []
    assert open_queue(url).run_next(got.append)
    assert got == ["x"]


@pytest.fixture(params=["sqlite", "redis"])
def two_ends(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[list[HueyQueue]]:
    """Two connections to one shared queue: the enqueuing process's and a worker's."""
    if request.param == "sqlite":
        url = f"sqlite:///{tmp_path / 'queue.db'}"
        yield [cast(HueyQueue, open_queue(url)), cast(HueyQueue, open_queue(url))]
    else:
        yield from redis_queues(2)


def test_an_idle_worker_is_woken_on_enqueue(two_ends: list[HueyQueue], client: TestClient,
                                            runtime: Runtime) -> None:
    # the worker looks at the queue every 60 s: only the wake-up on enqueue can start the job
    api, worker_end = two_ends
    runtime.queue = api
    worker = Worker(dataclasses.replace(runtime, queue=worker_end), FAKE_KINDS,
                    worker_id="test:wake")
    idle_calls = []
    real_idle = worker_end.idle
    worker_end.idle = lambda timeout: (idle_calls.append(timeout), real_idle(timeout))[1]
    thread = threading.Thread(target=worker.serve, kwargs={"poll": 60.0})
    thread.start()
    try:
        until(lambda: len(idle_calls) >= 2, "the worker never went idle")  # now it waits
        job = submit(client, upload(client)["id"])
        until(lambda: client.get(f"/v1/jobs/{job['id']}").json()["status"] == "succeeded",
              "the queued job was not taken")
    finally:
        worker.shutdown()
        thread.join(30)
    assert not thread.is_alive(), "shutdown did not end the worker's 60 s wait"


def until(condition: Callable[[], bool], failure: str, timeout: float = 30.0) -> None:
    """Wait for ``condition`` (a generous deadline far below the 60 s poll); fail if never."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            pytest.fail(failure)
        time.sleep(0.02)


def test_a_notification_to_a_gone_worker_unlists_it(tmp_path: Path) -> None:
    waker = Waker(tmp_path / "queue.db.wake")
    (waker.directory / "999999999").touch()  # listed, but no process listens there
    waker.listen()
    waker.notify()
    assert sorted(p.name for p in waker.directory.iterdir()) == [str(os.getpid())]
    waker.drain()
    waker.close()
    assert list(waker.directory.iterdir()) == []


def test_bad_urls_are_refused() -> None:
    with pytest.raises(ValueError, match="unsupported queue"):
        open_queue("amqp://x")


def test_in_memory_back_ends_are_refused(tmp_path: Path) -> None:
    # several worker processes would each have a store and a queue of their own
    with pytest.raises(ValueError, match="unsupported database URL 'memory://'"):
        open_store("memory://")
    with pytest.raises(ValueError, match="unsupported queue URL 'memory://'"):
        open_queue("memory://")
    with pytest.raises(ValueError, match="unsupported storage URL 'memory://'"):
        open_artifacts(Settings(data_dir=tmp_path, storage_url="memory://"))


# ------------------------------------------------------------------------------ artifacts


@pytest.fixture
def artifacts(tmp_path: Path) -> ArtifactStore:
    """The local artifact store (S3 runs in the distributed e2e tests)."""
    return LocalArtifactStore(tmp_path / "artifacts")


def test_artifacts_round_trip(artifacts: ArtifactStore, tmp_path: Path) -> None:
    src = tmp_path / "src.bin"
    data = os.urandom(3 * 1024 * 1024 + 5)
    src.write_bytes(data)
    artifacts.ping()
    artifacts.put_file("t/recordings/a.bin", src)
    assert artifacts.size("t/recordings/a.bin") == len(data)
    assert b"".join(artifacts.iter_bytes("t/recordings/a.bin")) == data
    with artifacts.as_file("t/recordings/a.bin") as path:
        assert path.read_bytes() == data
    artifacts.delete("t/recordings/a.bin")
    artifacts.delete("t/recordings/a.bin")
    assert artifacts.size("t/recordings/a.bin") is None
    with pytest.raises(FileNotFoundError):
        b"".join(artifacts.iter_bytes("t/recordings/a.bin"))


def test_local_keys_cannot_escape(tmp_path: Path) -> None:
    store = LocalArtifactStore(tmp_path / "root")
    with pytest.raises(ValueError, match="bad artifact key"):
        store.size("../outside")
