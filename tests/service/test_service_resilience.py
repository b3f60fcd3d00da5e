"""Jobs survive restarts, outages and full disks: SIGTERM hand-back, leases under CPU
saturation, idempotent retry after a queue outage, 507 on a full disk, readiness."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import pytest
import sqlalchemy.exc
from huey import MemoryHuey

from bonefit.estimation.progress import Progress
from bonefit.service.app import API_STEPS, create_app
from bonefit.service.errors import BackendError, StorageFull, StoreUnavailable
from bonefit.service.housekeeping import housekeeping
from bonefit.service.jobs import Job, Recording, new_id
from bonefit.service.kinds import Input, Kind, SkeletonParams
from bonefit.service.leases import LeaseKeeper
from bonefit.service.queue import HueyQueue
from bonefit.service.reaper import reap
from bonefit.service.runtime import Runtime, open_runtime
from bonefit.service.settings import Settings
from bonefit.service.sql_store import sql_error
from bonefit.service.worker import Worker, run_worker
from tests.service.helpers import (
    AUTH_A,
    FAKE_KINDS,
    KEYS,
    TestClient,
    drain,
    local_runtime,
    sensor_csv,
    submit,
    upload,
)


def slow_kind(body: Any) -> dict[str, Kind]:
    """A skeleton kind that runs ``body()`` (never reporting progress), then writes a result."""

    def run(inputs: Mapping[str, Input], params: Any, progress: Progress,
            outdir: Path) -> dict[str, Path]:
        body()
        out = outdir / "r.json"
        out.write_text("{}")
        return {"json": out}

    return {"skeleton": Kind("skeleton", SkeletonParams, run)}


def queued_job(runtime: Runtime, tmp: Path) -> str:
    """A recording and a queued skeleton job on it, straight through the back-ends."""
    path = tmp / f"{new_id()}.csv"
    path.write_bytes(sensor_csv())
    rec = Recording(id=new_id(), tenant="alice", key=f"alice/recordings/{path.name}",
                    filename="r.csv", content_type="text/csv", format="sensor-csv",
                    size=path.stat().st_size, sha256="0" * 64, created_at=time.time())
    runtime.artifacts.put_file(rec.key, path)
    runtime.store.add_recording(rec)
    now = time.time()
    job = Job(id=new_id(), tenant="alice", kind="skeleton", recording_id=rec.id, params={},
              inputs={}, created_at=now, updated_at=now)
    runtime.store.add_job(job)
    runtime.queue.enqueue(job.id)
    return job.id


def wait_until(predicate: Any, timeout: float, step: float = 0.05) -> bool:
    """Poll ``predicate`` until true or ``timeout`` s have passed; its last value."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(step)
    return True


def sqlite_settings(tmp_path: Path, **extra: Any) -> Settings:
    return Settings(data_dir=tmp_path / "data", api_keys=KEYS, progress_interval_seconds=0,
                    **extra)


# ----------------------------------------------------------------------- SIGTERM hand-back


def test_sigterm_hands_back_a_job_that_never_reports_progress(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import bonefit.service.worker as worker_module

    settings = sqlite_settings(tmp_path, shutdown_grace_seconds=0.5, lease_seconds=30)
    runtime = open_runtime(settings)
    job_id = queued_job(runtime, tmp_path)
    release = threading.Event()
    seen: dict[str, Any] = {}

    def long_step() -> None:  # one long numerical step: no progress report for a minute
        release.wait(60)

    def terminate_while_running() -> None:
        def running() -> bool:
            job = runtime.store.get_job(job_id)
            return job is not None and job.status == "running"

        assert wait_until(running, 30)
        os.kill(os.getpid(), signal.SIGTERM)  # what `bonefit serve` or Kubernetes sends

        def handed_back() -> bool:
            job = runtime.store.get_job(job_id)
            return job is not None and job.status != "running"

        wait_until(handed_back, 15)  # grace 0.5 s: generous margin for a loaded machine
        seen["job"] = runtime.store.get_job(job_id)
        release.set()

    monkeypatch.setattr(worker_module, "preload", lambda: None)
    handlers = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}
    watcher = threading.Thread(target=terminate_while_running)
    watcher.start()
    try:
        assert run_worker(settings, kinds=slow_kind(long_step)) == 0
    finally:
        release.set()
        watcher.join(60)
        for s, handler in handlers.items():
            signal.signal(s, handler)
    back = seen["job"]
    assert (back.status, back.attempts, back.worker) == ("queued", 0, None)
    assert "shut down" in back.message
    drain(runtime, Worker(runtime, slow_kind(lambda: None), worker_id="next:1"))
    done = runtime.store.get_job(job_id)
    assert done is not None
    assert (done.status, done.attempts) == ("succeeded", 1)


def test_rolling_restarts_never_use_up_a_long_jobs_attempts(tmp_path: Path) -> None:
    runtime = local_runtime(Settings(data_dir=tmp_path, max_attempts=2,
                                      shutdown_grace_seconds=0))
    job_id = queued_job(runtime, tmp_path)
    for restart in range(3):  # more restarts than attempts
        release, ended = threading.Event(), threading.Event()

        def step(release: threading.Event = release, ended: threading.Event = ended) -> None:
            release.wait(10)
            ended.set()

        worker = Worker(runtime, slow_kind(step), worker_id=f"w:{restart}")
        stopper = threading.Timer(0.2, worker.shutdown)
        stopper.start()
        try:
            assert runtime.queue.run_next(worker.run_job)
            assert not ended.is_set()  # handed back during the step, not after it
        finally:
            release.set()
            stopper.join()
        job = runtime.store.get_job(job_id)
        assert job is not None
        assert (job.status, job.attempts) == ("queued", 0)
    drain(runtime, Worker(runtime, slow_kind(lambda: None)))
    job = runtime.store.get_job(job_id)
    assert job is not None
    assert (job.status, job.attempts) == ("succeeded", 1)


# ------------------------------------------------------------- leases with the cores saturated


BUSY_LOOP = "import time\nend = time.time() + {seconds}\nwhile time.time() < end:\n    pass\n"
REAPER = """
import sys, time
from bonefit.service.runtime import open_runtime
from bonefit.service.settings import Settings
from bonefit.service.reaper import reap
runtime = open_runtime(Settings())
end = time.time() + float(sys.argv[1])
reap(runtime)
print("ready", flush=True)
while time.time() < end:
    for job_id in reap(runtime):
        print(job_id, flush=True)
    time.sleep(0.1)
"""


def gil_holding_size(seconds: float) -> int:
    """n such that ``sum(range(n))`` (one C call that never releases the interpreter lock,
    like a long numerical step) takes about ``seconds`` on an idle core."""
    n = 2_000_000
    start = time.perf_counter()
    sum(range(n))
    return int(n * seconds / max(time.perf_counter() - start, 1e-6))


@pytest.fixture
def saturated_cores() -> Iterator[None]:
    """Three busy loops, more than the cores of the CI machine, for at most two minutes."""
    busy = [subprocess.Popen([sys.executable, "-c", BUSY_LOOP.format(seconds=120)])
            for _ in range(max(3, (os.cpu_count() or 2) + 1))]
    try:
        yield
    finally:
        for proc in busy:
            proc.kill()
            proc.wait()


def test_the_lease_outlives_a_job_that_holds_the_cpu(tmp_path: Path,
                                                     saturated_cores: None) -> None:
    lease = 2.0
    settings = sqlite_settings(tmp_path, lease_seconds=lease)
    runtime = open_runtime(settings)
    n = gil_holding_size(2 * lease)  # starves this process's heartbeat thread for 2 leases
    worker = Worker(runtime, slow_kind(lambda: sum(range(n))), worker_id="busy:1")
    worker.keeper = LeaseKeeper(settings, worker.id)
    worker.keeper.start()
    env = {**os.environ, **settings.to_env()}
    reaper = subprocess.Popen([sys.executable, "-c", REAPER, "600"], env=env,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert reaper.stdout is not None
        assert reaper.stdout.readline() == "ready\n"
        # queued only now: a reaper slow to start on the loaded cores would otherwise find the
        # job queued for longer than the lost-message delay and send it again
        job_id = queued_job(runtime, tmp_path)
        assert runtime.queue.run_next(worker.run_job)
    finally:
        reaper.terminate()
        reaped = reaper.communicate(timeout=30)[0]
        worker.keeper.close()
    job = runtime.store.get_job(job_id)
    assert job is not None
    assert reaped.split() == []  # the reaper, in another process, never saw the lease lapse
    assert (job.status, job.attempts) == ("succeeded", 1)


def test_the_lease_keeper_stops_renewing_when_its_worker_dies(tmp_path: Path) -> None:
    settings = sqlite_settings(tmp_path, lease_seconds=0.6)
    runtime = open_runtime(settings)
    job_id = queued_job(runtime, tmp_path)
    runtime.store.update_job(job_id, {"status": "running", "worker": "gone:1", "attempts": 1,
                                      "lease_until": time.time() + 0.6}, expect={})
    keeper = LeaseKeeper(settings, "gone:1")
    keeper.start()
    keeper.hold(job_id)

    def lease() -> float:
        job = runtime.store.get_job(job_id)
        assert job is not None
        assert job.lease_until is not None
        return job.lease_until

    first = lease()
    assert wait_until(lambda: lease() > first, 30)  # renewed by the keeper alone
    keeper.close()  # what the kernel does to the pipe when the worker is killed
    assert keeper.proc is not None
    assert keeper.proc.returncode == 0
    last = lease()
    assert wait_until(lambda: time.time() > last + 0.1, 30)
    assert reap(runtime) == [job_id]


# ------------------------------------------------------------ idempotent retry after an outage


class FlakyQueue(HueyQueue):
    """A queue whose storage refuses messages while ``down`` (Redis is unreachable)."""

    def __init__(self, error: Exception) -> None:
        super().__init__(MemoryHuey("bonefit-test", results=False))
        self.error = error
        self.down = True
        send = self.huey.storage.enqueue

        def enqueue(data: bytes, priority: int | None = None) -> None:
            if self.down:
                raise self.error
            send(data, priority)

        self.huey.storage.enqueue = enqueue


@pytest.fixture
def store_runtime(tmp_path: Path) -> Runtime:
    """A runtime with a queue that starts down."""
    settings = Settings(data_dir=tmp_path, api_keys=KEYS, lease_seconds=5,
                        progress_interval_seconds=0)
    runtime = open_runtime(settings)
    import redis.exceptions

    runtime.queue = FlakyQueue(redis.exceptions.ConnectionError("Connection refused"))
    return runtime


def flaky(runtime: Runtime) -> FlakyQueue:
    assert isinstance(runtime.queue, FlakyQueue)
    return runtime.queue


@pytest.mark.parametrize("attempt", range(5))
def test_a_retry_after_a_queue_outage_runs_the_job(store_runtime: Runtime, attempt: int) -> None:
    runtime = store_runtime
    app = create_app(runtime=runtime, kinds=FAKE_KINDS, housekeeping=False)
    with TestClient(app, headers=AUTH_A, raise_server_exceptions=False) as client:
        flaky(runtime).down = False
        rec = upload(client)
        flaky(runtime).down = True
        body = {"kind": "skeleton", "recording_id": rec["id"]}
        key = {"Idempotency-Key": f"outage-{attempt}"}
        refused = client.post("/v1/jobs", json=body, headers=key)
        assert refused.status_code == 503, refused.text
        assert refused.json()["title"] == "Queue unavailable"
        flaky(runtime).down = False  # Redis is back: the client retries
        retried = client.post("/v1/jobs", json=body, headers=key)
        assert retried.status_code == 202, retried.text
        assert retried.json()["status"] == "queued"
        again = client.post("/v1/jobs", json=body, headers=key)  # and retries once more
        assert again.json()["id"] == retried.json()["id"]
        drain(runtime, Worker(runtime, FAKE_KINDS))
        assert client.get(f"/v1/jobs/{retried.json()['id']}").json()["status"] == "succeeded"


def disk_full_error() -> BackendError:
    """What the job store raises when SQLite's disk is full (tests patch its methods)."""
    import sqlite3

    error = sql_error(sqlalchemy.exc.OperationalError(
        "UPDATE bonefit_jobs", {}, sqlite3.OperationalError("database or disk is full")))
    assert isinstance(error, StorageFull)
    return error


def test_a_job_the_full_disk_kept_from_queueing_is_never_stuck(tmp_path: Path) -> None:
    runtime = local_runtime(Settings(data_dir=tmp_path, api_keys=KEYS, lease_seconds=5))
    runtime.queue = FlakyQueue(OSError(errno.ENOSPC, "No space left on device"))
    store = runtime.store
    update = store.update_job
    app = create_app(runtime=runtime, kinds=FAKE_KINDS, housekeeping=False)
    with TestClient(app, headers=AUTH_A, raise_server_exceptions=False) as client:
        flaky(runtime).down = False
        rec = upload(client)
        flaky(runtime).down = True

        def full(*args: Any, **kwargs: Any) -> Any:
            raise disk_full_error()

        store.update_job = full  # type: ignore[method-assign]
        r = client.post("/v1/jobs", json={"kind": "skeleton", "recording_id": rec["id"]},
                        headers={"Idempotency-Key": "full"})
        assert r.status_code == 507, r.text
        assert r.json()["storage"] == "job queue"
        assert r.headers["content-type"] == "application/problem+json"
        # the job could not even be marked failed: it waits, queued, without a message ...
        assert reap(runtime, now=time.time() + 6) == []  # ... while the disk is still full
        store.update_job = update  # type: ignore[method-assign]
        flaky(runtime).down = False  # space again
        [job] = client.get("/v1/jobs").json()["items"]
        assert reap(runtime, now=time.time() + 6) == [job["id"]]  # sent again
        drain(runtime, Worker(runtime, FAKE_KINDS))
        assert client.get(f"/v1/jobs/{job['id']}").json()["status"] == "succeeded"


def test_reap_handles_each_job_on_its_own(tmp_path: Path) -> None:
    runtime = local_runtime(Settings(data_dir=tmp_path, lease_seconds=5))
    ids = [queued_job(runtime, tmp_path) for _ in range(2)]
    while runtime.queue.run_next(lambda _id: None):
        pass  # a worker took both messages, then died
    for job_id in ids:
        runtime.store.update_job(job_id, {"status": "running", "worker": "dead:1",
                                          "attempts": 1, "lease_until": time.time() - 1},
                                 expect={})
    update = runtime.store.update_job

    def first_is_unwritable(job_id: str, changes: Any, *, expect: Any) -> Any:
        if job_id == ids[0]:
            raise disk_full_error()
        return update(job_id, changes, expect=expect)

    runtime.store.update_job = first_is_unwritable  # type: ignore[method-assign]
    assert reap(runtime) == [ids[1]]
    runtime.store.update_job = update  # type: ignore[method-assign]
    assert reap(runtime) == [ids[0]]


# ------------------------------------------------------------------------------ full disks


def no_space(*args: Any, **kwargs: Any) -> Any:
    raise OSError(errno.ENOSPC, "No space left on device")


def test_an_upload_meeting_a_full_disk_is_a_507_naming_the_storage(
        client: TestClient, runtime: Runtime, monkeypatch: pytest.MonkeyPatch,
        settings: Settings) -> None:
    with monkeypatch.context() as m:
        m.setattr(os, "pwrite", no_space)  # the spool's file system is full
        r = client.post("/v1/recordings", content=sensor_csv(), params={"filename": "a.csv"})
    assert r.status_code == 507, r.text
    body = r.json()
    assert (body["title"], body["storage"]) == ("Insufficient storage", "upload spool")
    assert "full" in body["detail"]
    assert str(settings.data_dir) not in r.text  # named, never located
    with monkeypatch.context() as m:
        m.setattr(runtime.artifacts, "put_file", no_space)
        r = client.post("/v1/recordings", content=sensor_csv(), params={"filename": "a.csv"})
    assert (r.status_code, r.json()["storage"]) == (507, "artifact storage")

    def database_full(*args: Any) -> None:
        raise disk_full_error()

    with monkeypatch.context() as m:
        m.setattr(runtime.store, "add_recording", database_full)
        r = client.post("/v1/recordings", content=sensor_csv(), params={"filename": "a.csv"})
    assert (r.status_code, r.json()["storage"]) == (507, "job database")
    assert client.get("/v1/recordings").json()["items"] == []  # nothing half-stored
    assert not any((settings.data_dir / "uploads").iterdir())
    assert not any(p.is_file() for p in (settings.data_dir / "artifacts").rglob("*"))


def test_a_job_submitted_on_a_full_database_is_a_507(client: TestClient, runtime: Runtime,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    rec = upload(client)

    def database_full(*args: Any, **kwargs: Any) -> None:
        raise disk_full_error()

    monkeypatch.setattr(runtime.store, "add_job", database_full)
    r = client.post("/v1/jobs", json={"kind": "skeleton", "recording_id": rec["id"]})
    assert (r.status_code, r.json()["storage"]) == (507, "job database")


def test_a_job_is_acknowledged_only_once_durable(client: TestClient, runtime: Runtime,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """The job is queued before its row reaches the disk (a worker may start meanwhile), but
    the 202 waits for ``wait_durable``: a database that dies in between is a 503 problem."""
    rec = upload(client)
    queued_first: list[set[str]] = []

    def database_gone() -> None:
        queued_first.append(runtime.queue.pending())
        raise StoreUnavailable("the job database is unreachable (OperationalError)")

    monkeypatch.setattr(runtime.store, "wait_durable", database_gone)
    r = client.post("/v1/jobs", json={"kind": "skeleton", "recording_id": rec["id"]})
    assert r.status_code == 503, r.text
    assert r.headers["content-type"] == "application/problem+json"
    assert len(queued_first) == 1
    assert len(queued_first[0]) == 1  # the id was queued before the flush was asked for


def test_deleting_works_on_a_full_disk(client: TestClient, runtime: Runtime,
                                       monkeypatch: pytest.MonkeyPatch) -> None:
    rec = upload(client)
    disk = {"full": True}
    delete_row, delete_bytes = runtime.store.delete_recording, runtime.artifacts.delete

    def row(tenant: str, rec_id: str) -> Any:
        if disk["full"]:  # SQLite cannot write its journal until something is freed
            raise disk_full_error()
        return delete_row(tenant, rec_id)

    def blob(key: str) -> None:
        delete_bytes(key)
        disk["full"] = False

    monkeypatch.setattr(runtime.store, "delete_recording", row)
    monkeypatch.setattr(runtime.artifacts, "delete", blob)
    r = client.delete(f"/v1/recordings/{rec['id']}")
    assert r.status_code == 204, r.text
    assert client.get(f"/v1/recordings/{rec['id']}").status_code == 404


@pytest.fixture
def small_tmpfs(tmp_path: Path) -> Iterator[Path]:
    """A 2 MiB tmpfs (a really full disk); skipped where mounting is not permitted."""
    mount = tmp_path / "small"
    mount.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mount)],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip() or done.returncode}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


def test_a_real_full_disk(small_tmpfs: Path) -> None:
    settings = Settings(data_dir=small_tmpfs, api_keys=KEYS, min_free_bytes=1024 * 1024)
    runtime = open_runtime(settings)
    app = create_app(runtime=runtime, kinds=FAKE_KINDS, housekeeping=False)
    worker = Worker(runtime, FAKE_KINDS)
    worker.beat()
    with TestClient(app, headers=AUTH_A, raise_server_exceptions=False) as client:
        assert client.get("/readyz").status_code == 200
        kept = []
        for _ in range(40):  # 128 KiB each: the 2 MiB fill up
            r = client.post("/v1/recordings", content=sensor_csv(1200),
                            params={"filename": "big.csv"})
            if r.status_code != 201:
                break
            kept.append(r.json()["id"])
        assert r.status_code == 507, r.text
        assert r.json()["storage"] in ("upload spool", "artifact storage", "job database")
        ready = client.get("/readyz")
        assert ready.status_code == 503
        assert "disk" in ready.json()["failed"]
        for rec_id in kept:  # clients can make room
            assert client.delete(f"/v1/recordings/{rec_id}").status_code == 204
        rec = upload(client)
        job = submit(client, rec["id"])
        drain(runtime, worker)
        assert client.get(f"/v1/jobs/{job['id']}").json()["status"] == "succeeded"


# ------------------------------------------------------------------------------ readiness


def test_readyz_needs_a_live_worker(client: TestClient, runtime: Runtime) -> None:
    r = client.get("/readyz")  # `bonefit serve --workers 0` and no `bonefit worker`
    assert r.status_code == 503
    body = r.json()
    assert body["failed"] == ["workers"]
    assert "no worker alive" in body["detail"]
    assert body["checks"]["database"] == "ok"
    worker = Worker(runtime, FAKE_KINDS, worker_id="w:1")
    worker.beat()
    assert client.get("/readyz").status_code == 200
    stale = time.time() - runtime.settings.worker_stale_seconds - 1
    runtime.store.beat_worker("w:1", stale)  # stopped reporting (killed, hung)
    assert client.get("/readyz").json()["failed"] == ["workers"]
    thread = threading.Thread(target=worker.serve, kwargs={"poll": 0.01})
    thread.start()
    try:
        assert wait_until(lambda: client.get("/readyz").status_code == 200, 30)
    finally:
        worker.shutdown(grace=0)
        thread.join(30)
    assert client.get("/readyz").json()["failed"] == ["workers"]  # it unregistered


def test_a_worker_counts_as_alive_once_loaded_and_until_it_stops(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import bonefit.service.worker as worker_module

    settings = sqlite_settings(tmp_path, lease_seconds=3)
    runtime = open_runtime(settings)
    seen: dict[str, list[str]] = {}

    def loading() -> None:  # the ~20 s import of the estimation code
        seen["loading"] = runtime.store.live_workers(0)

    def stop_once_alive() -> None:
        wait_until(lambda: bool(runtime.store.live_workers(0)), 30)
        seen["serving"] = runtime.store.live_workers(0)
        os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(worker_module, "preload", loading)
    handlers = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}
    watcher = threading.Thread(target=stop_once_alive)
    watcher.start()
    try:
        assert run_worker(settings) == 0
    finally:
        watcher.join(60)
        for s, handler in handlers.items():
            signal.signal(s, handler)
    assert seen["loading"] == []
    assert len(seen["serving"]) == 1
    assert runtime.store.live_workers(0) == []


def test_readyz_reports_low_disk_space(client: TestClient, runtime: Runtime,
                                       monkeypatch: pytest.MonkeyPatch) -> None:
    import shutil

    import bonefit.service.storage

    Worker(runtime, FAKE_KINDS).beat()
    real = shutil.disk_usage
    monkeypatch.setattr(bonefit.service.storage.shutil, "disk_usage",
                        lambda path: real(path)._replace(free=10 * 1024 * 1024))
    body = client.get("/readyz").json()
    assert body["failed"] == ["disk"]
    assert body["checks"]["disk"].startswith("low space: 10 MiB free")
    runtime.settings.min_free_bytes = 0
    assert client.get("/readyz").status_code == 200


# ---------------------------------------------------------------------------- housekeeping


def test_housekeeping_steps_are_independent(tmp_path: Path,
                                            caplog: pytest.LogCaptureFixture) -> None:
    runtime = local_runtime(Settings(data_dir=tmp_path, retention_seconds=10))
    old = Recording(id=new_id(), tenant="t", key="t/recordings/x", filename=None,
                    content_type=None, format="sensor-csv", size=1, sha256="0" * 64,
                    created_at=time.time() - 100)
    runtime.store.add_recording(old)
    abandoned = tmp_path / "uploads" / "abandoned"
    abandoned.mkdir(parents=True)
    (abandoned / "upload.part").write_bytes(b"x")
    os.utime(abandoned / "upload.part", (0, 0))
    os.utime(abandoned, (0, 0))

    def down(now: float) -> list[Job]:
        raise disk_full_error()

    runtime.store.expired_leases = down  # type: ignore[method-assign]
    assert housekeeping(runtime, API_STEPS) == ["reap"]
    assert runtime.store.get_recording("t", old.id) is None  # the retention still ran
    assert not abandoned.exists()  # and so did the spool cleanup
    assert "housekeeping: reap failed" in caplog.text
