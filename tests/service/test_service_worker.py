"""Workers: claiming, progress, cancel, hand-back on shutdown, crash retries, leases, retention."""

from __future__ import annotations

import errno
import logging
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pytest

from bonefit.estimation.progress import Progress
from bonefit.service.errors import StorageFull, StoreUnavailable
from bonefit.service.jobs import new_id
from bonefit.service.kinds import Input, Kind, SkeletonParams
from bonefit.service.reaper import reap
from bonefit.service.retention import purge
from bonefit.service.runtime import Runtime
from bonefit.service.settings import Settings
from bonefit.service.tempdirs import private_tmp
from bonefit.service.worker import Worker
from tests.service.helpers import TestClient, drain, sensor_csv, submit, upload


def kind_with(body: Any) -> dict[str, Kind]:
    """A registry whose skeleton kind runs ``body(progress)`` then writes one result."""

    def run(inputs: Mapping[str, Input], params: Any, progress: Progress,
            outdir: Path) -> dict[str, Path]:
        body(progress)
        out = outdir / "r.json"
        out.write_text("{}")
        return {"json": out}

    return {"skeleton": Kind("skeleton", SkeletonParams, run)}


def test_progress_reaches_the_store(client: TestClient, runtime: Runtime) -> None:
    job = submit(client, upload(client)["id"])
    seen: list[tuple[float, str]] = []

    def body(progress: Progress) -> None:
        for f in (0.2, 0.1, 0.6):  # a step back is clamped: progress never decreases
            progress(f, "joints")
            stored = runtime.store.get_job(job["id"])
            assert stored is not None
            seen.append((stored.fraction, stored.stage))

    drain(runtime, Worker(runtime, kind_with(body)))
    assert seen == [(0.2, "joints"), (0.2, "joints"), (0.6, "joints")]
    assert client.get(f"/v1/jobs/{job['id']}").json()["status"] == "succeeded"


def test_progress_writes_are_throttled(client: TestClient, runtime: Runtime) -> None:
    runtime.settings.progress_interval_seconds = 60
    job = submit(client, upload(client)["id"])
    versions: list[int] = []

    def body(progress: Progress) -> None:
        for i in range(50):
            progress(i / 50, "fast")
        stored = runtime.store.get_job(job["id"])
        assert stored is not None
        versions.append(stored.version)

    drain(runtime, Worker(runtime, kind_with(body)))
    assert versions == [2]  # only the claim wrote


def test_cancel_stops_a_running_job_at_its_next_report(client: TestClient,
                                                       runtime: Runtime) -> None:
    job = submit(client, upload(client)["id"])
    reports: list[float] = []

    def body(progress: Progress) -> None:
        for i in range(10):
            progress(i / 10, "work")
            reports.append(i / 10)
            if i == 2:
                r = client.post(f"/v1/jobs/{job['id']}/cancel")
                assert r.status_code == 202
                assert r.json()["progress"]["message"] == "cancelling"

    drain(runtime, Worker(runtime, kind_with(body)))
    done = client.get(f"/v1/jobs/{job['id']}").json()
    assert done["status"] == "cancelled"
    assert done["results"] == {}
    assert reports == [0.0, 0.1, 0.2]


def test_a_cancel_is_noticed_between_lease_renewals(client: TestClient,
                                                    runtime: Runtime) -> None:
    # neither a lease renewal (every 200 s) nor a progress write (every 60 s) comes: the
    # heartbeat thread's look for a cancel stops the job at one of its next reports
    runtime.settings.lease_seconds, runtime.settings.progress_interval_seconds = 600, 60
    job = submit(client, upload(client)["id"])
    reports: list[float] = []

    def body(progress: Progress) -> None:
        progress(0.1, "work")
        assert client.post(f"/v1/jobs/{job['id']}/cancel").status_code == 202
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            progress(0.2, "work")
            reports.append(0.2)
            time.sleep(0.05)

    drain(runtime, Worker(runtime, kind_with(body)))
    assert client.get(f"/v1/jobs/{job['id']}").json()["status"] == "cancelled"
    assert reports  # it ran on after the cancel until the watch saw it, then stopped


def test_a_cancel_after_the_last_report_still_wins(client: TestClient,
                                                  runtime: Runtime) -> None:
    # the client asked before the results were kept: the job ends cancelled, without them
    runtime.settings.lease_seconds, runtime.settings.progress_interval_seconds = 600, 60
    job = submit(client, upload(client)["id"])

    def body(progress: Progress) -> None:
        progress(0.9, "writing")
        assert client.post(f"/v1/jobs/{job['id']}/cancel").status_code == 202

    drain(runtime, Worker(runtime, kind_with(body)))
    done = client.get(f"/v1/jobs/{job['id']}").json()
    assert done["status"] == "cancelled"
    assert done["results"] == {}


def test_held_back_progress_reaches_the_store(client: TestClient, runtime: Runtime) -> None:
    # a report inside the throttle's interval is written once the interval is over, by the
    # heartbeat thread, although the job reports nothing more
    runtime.settings.lease_seconds, runtime.settings.progress_interval_seconds = 600, 0.5
    job = submit(client, upload(client)["id"])
    stored: list[tuple[float, str]] = []

    def body(progress: Progress) -> None:
        progress(0.6, "writing")
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and (0.6, "writing") not in stored:
            now = runtime.store.get_job(job["id"])
            assert now is not None
            stored.append((now.fraction, now.stage))
            time.sleep(0.05)

    drain(runtime, Worker(runtime, kind_with(body)))
    assert stored[0] == (0.0, "starting")  # held back at first
    assert stored[-1] == (0.6, "writing")


def test_shutdown_hands_the_running_job_back(client: TestClient, runtime: Runtime) -> None:
    job = submit(client, upload(client)["id"])
    worker = Worker(runtime, kind_with(lambda progress: (worker.shutdown(grace=0),
                                                         progress(0.5, "x"))))
    assert runtime.queue.run_next(worker.run_job)
    back = client.get(f"/v1/jobs/{job['id']}").json()
    assert (back["status"], back["attempts"]) == ("queued", 0)
    assert runtime.queue.depth() == 1
    drain(runtime, Worker(runtime, kind_with(lambda progress: None)))
    assert client.get(f"/v1/jobs/{job['id']}").json()["status"] == "succeeded"


def test_crashes_are_retried_then_fail_without_leaking(client: TestClient, runtime: Runtime,
                                                      worker: Worker) -> None:
    job = submit(client, upload(client, sensor_csv() + b"CRASH\n")["id"])
    assert drain(runtime, worker) == 2  # max_attempts = 2
    failed = client.get(f"/v1/jobs/{job['id']}").json()
    assert (failed["status"], failed["attempts"]) == ("failed", 2)
    assert failed["error"]["status"] == 500
    assert "boom" not in str(failed["error"])


def test_a_success_the_store_cannot_record_is_retried(
        client: TestClient, runtime: Runtime, monkeypatch: pytest.MonkeyPatch) -> None:
    job = submit(client, upload(client)["id"])
    succeed = runtime.store.succeed
    calls: list[str] = []

    def down_once(job_id: str, *args: Any) -> Any:
        calls.append(job_id)
        if len(calls) == 1:
            raise StoreUnavailable("the job database is unreachable (OperationalError)")
        return succeed(job_id, *args)

    monkeypatch.setattr(runtime.store, "succeed", down_once)
    worker = Worker(runtime, kind_with(lambda progress: None))
    assert runtime.queue.run_next(worker.run_job)  # never raises into the queue
    again = client.get(f"/v1/jobs/{job['id']}").json()
    assert (again["status"], again["attempts"]) == ("queued", 1)
    assert "StoreUnavailable" in again["progress"]["message"]
    drain(runtime, worker)
    assert client.get(f"/v1/jobs/{job['id']}").json()["status"] == "succeeded"


def test_deleted_recording_fails_the_job(client: TestClient, runtime: Runtime,
                                         worker: Worker) -> None:
    rec = upload(client)
    job = submit(client, rec["id"])
    client.delete(f"/v1/recordings/{rec['id']}")
    drain(runtime, worker)
    failed = client.get(f"/v1/jobs/{job['id']}").json()
    assert failed["status"] == "failed"
    assert failed["error"]["field"] == "recording_id"


def _running(runtime: Runtime, job_id: str, attempts: int, **extra: Any) -> None:
    assert runtime.store.update_job(job_id, {
        "status": "running", "worker": "dead:1", "attempts": attempts,
        "lease_until": time.time() - 1, **extra}, expect={}) is not None


def test_reaper_requeues_then_gives_up(client: TestClient, runtime: Runtime,
                                       worker: Worker) -> None:
    job = submit(client, upload(client)["id"])
    runtime.queue.run_next(lambda _id: None)  # the dead worker took the message
    _running(runtime, job["id"], 1)
    assert reap(runtime) == [job["id"]]
    assert reap(runtime) == []
    queued = client.get(f"/v1/jobs/{job['id']}").json()
    assert (queued["status"], queued["attempts"]) == ("queued", 1)
    assert "worker was lost" in queued["progress"]["message"]
    drain(runtime, worker)
    assert client.get(f"/v1/jobs/{job['id']}").json()["status"] == "succeeded"

    lost = submit(client, upload(client)["id"])
    runtime.queue.run_next(lambda _id: None)
    _running(runtime, lost["id"], 2)
    reap(runtime)
    failed = client.get(f"/v1/jobs/{lost['id']}").json()
    assert failed["status"] == "failed"
    assert failed["error"]["title"] == "Worker lost"

    cancelled = submit(client, upload(client)["id"])
    _running(runtime, cancelled["id"], 1, cancel_requested=True)
    reap(runtime)
    assert client.get(f"/v1/jobs/{cancelled['id']}").json()["status"] == "cancelled"


def test_a_job_over_its_time_limit_fails_at_its_next_report(client: TestClient,
                                                             runtime: Runtime) -> None:
    runtime.settings.job_timeout_seconds = 100.0
    now = [1_000.0]
    reports: list[float] = []

    def body(progress: Progress) -> None:
        for i in range(10):
            progress(i / 10, "work")
            reports.append(i / 10)
            now[0] += 40.0  # each step takes 40 s on the worker's clock

    slow = submit(client, upload(client)["id"])
    drain(runtime, Worker(runtime, kind_with(body), clock=lambda: now[0]))
    done = client.get(f"/v1/jobs/{slow['id']}").json()
    assert done["status"] == "failed"
    assert reports == [0.0, 0.1, 0.2]  # the report at 120 s stopped it
    assert done["results"] == {}
    error = done["error"]
    assert (error["status"], error["title"], error["limit_seconds"]) == (
        504, "Job timed out", 100.0)
    assert "job_timeout_seconds" in error["detail"]
    assert error["instance"] == f"/v1/jobs/{slow['id']}"
    # a job that ends over the limit without another report keeps its results, and a
    # limit of 0 means none
    for limit, steps in ((100.0, 1), (0.0, 10)):
        runtime.settings.job_timeout_seconds = limit
        job = submit(client, upload(client)["id"])

        def quick(progress: Progress, steps: int = steps) -> None:
            for i in range(steps):
                progress(i / steps, "work")
                now[0] += 150.0

        drain(runtime, Worker(runtime, kind_with(quick), clock=lambda: now[0]))
        assert client.get(f"/v1/jobs/{job['id']}").json()["status"] == "succeeded"


def test_heartbeat_keeps_a_long_job_alive(client: TestClient, runtime: Runtime) -> None:
    runtime.settings.lease_seconds = 0.3
    job = submit(client, upload(client)["id"])
    reaped: list[str] = []

    def body(progress: Progress) -> None:
        for _ in range(8):  # 0.8 s without any progress report: only the heartbeat renews
            time.sleep(0.1)
            reaped.extend(reap(runtime))

    drain(runtime, Worker(runtime, kind_with(body)))
    assert reaped == []
    assert client.get(f"/v1/jobs/{job['id']}").json()["status"] == "succeeded"


def test_a_worker_that_lost_its_lease_stops(client: TestClient, runtime: Runtime) -> None:
    job = submit(client, upload(client)["id"])

    def body(progress: Progress) -> None:
        runtime.store.update_job(job["id"], {"worker": "other:2"}, expect={})
        progress(0.5, "x")
        raise AssertionError("not reached")

    drain(runtime, Worker(runtime, kind_with(body)))
    stolen = runtime.store.get_job(job["id"])
    assert stolen is not None
    assert (stolen.status, stolen.worker) == ("running", "other:2")


def test_retention_purges_old_records_and_artifacts(client: TestClient, runtime: Runtime,
                                                    worker: Worker) -> None:
    rec = upload(client)
    job = submit(client, rec["id"])
    drain(runtime, worker)
    assert purge(runtime) == 0  # retention 0 keeps everything
    runtime.settings.retention_seconds = 10
    assert purge(runtime) == 0
    stored = runtime.store.get_job(job["id"])
    assert stored is not None
    keys = [*stored.results.values()]
    assert purge(runtime, now=time.time() + 11) == 2
    assert client.get(f"/v1/jobs/{job['id']}").status_code == 404
    assert client.get(f"/v1/recordings/{rec['id']}").status_code == 404
    assert all(runtime.artifacts.size(k) is None for k in keys)


def test_a_lost_queue_message_is_sent_again(client: TestClient, runtime: Runtime,
                                            worker: Worker) -> None:
    job = submit(client, upload(client)["id"])
    waiting = submit(client, upload(client)["id"])
    runtime.queue.run_next(lambda _id: None)  # a worker took the message and died unclaimed
    assert reap(runtime) == []  # not stale yet
    later = time.time() + runtime.settings.lease_seconds + 1
    assert reap(runtime, now=later) == [job["id"]]  # the other still has its message
    assert reap(runtime, now=later) == []  # touched: no duplicate on the next pass
    drain(runtime, worker)
    assert client.get(f"/v1/jobs/{job['id']}").json()["status"] == "succeeded"
    assert client.get(f"/v1/jobs/{waiting['id']}").json()["status"] == "succeeded"


def test_serve_loop_runs_jobs_until_shutdown(client: TestClient, runtime: Runtime,
                                             worker: Worker) -> None:
    import threading

    job = submit(client, upload(client)["id"])
    thread = threading.Thread(target=worker.serve, kwargs={"poll": 0.01})
    thread.start()
    try:
        deadline = time.monotonic() + 10
        while client.get(f"/v1/jobs/{job['id']}").json()["status"] != "succeeded":
            assert time.monotonic() < deadline
            time.sleep(0.01)
    finally:
        worker.shutdown(grace=0)
        thread.join(5)
    assert not thread.is_alive()


def test_private_tmp_removes_what_dead_processes_of_this_host_left(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    dead = int(done.stdout)
    host = socket.gethostname()
    for name in (f"{host}-{dead}", f"{host}-1", f"elsewhere-{dead}"):
        (tmp_path / "tmp" / name / "job").mkdir(parents=True)
    own = private_tmp(tmp_path)
    assert own == tmp_path / "tmp" / f"{host}-{os.getpid()}"
    assert own.is_dir()
    assert sorted(p.name for p in (tmp_path / "tmp").iterdir()) == sorted(
        [f"{host}-1", f"elsewhere-{dead}", own.name])  # alive, or another machine's


def test_a_worker_stopped_while_loading_never_says_it_is_ready(
        settings: Settings, monkeypatch: pytest.MonkeyPatch,
        caplog: pytest.LogCaptureFixture) -> None:
    import bonefit.service.worker as worker_module

    # SIGTERM arrives while the estimation code is still being imported
    monkeypatch.setattr(worker_module, "preload", lambda: os.kill(os.getpid(), signal.SIGTERM))
    handlers = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        with caplog.at_level(logging.INFO, logger=worker_module.log.name):
            assert worker_module.run_worker(settings) == 0
    finally:
        for s, handler in handlers.items():
            signal.signal(s, handler)
    messages = [r.getMessage() for r in caplog.records]
    assert any("shutting down" in m for m in messages)
    assert not any(" ready " in m for m in messages)


def test_a_worker_keeps_freed_memory_as_the_estimating_commands_do(
        settings: Settings, monkeypatch: pytest.MonkeyPatch) -> None:
    import bonefit.service.worker as worker_module
    from bonefit.estimation import memory

    calls: list[bool] = []
    monkeypatch.setattr(memory, "retain_freed_memory", lambda: calls.append(True) or True)
    monkeypatch.setattr(worker_module, "preload", lambda: os.kill(os.getpid(), signal.SIGTERM))
    handlers = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        assert worker_module.run_worker(settings) == 0
    finally:
        for s, handler in handlers.items():
            signal.signal(s, handler)
    assert calls == [True]


def test_a_message_for_a_job_not_in_the_store_is_dropped_with_a_log_line(
        runtime: Runtime, worker: Worker, caplog: pytest.LogCaptureFixture) -> None:
    """As when the database crashed after the job was queued but before it became durable
    (its client got a problem, not 202): the worker says so and takes the next message."""
    runtime.queue.enqueue(new_id())
    with caplog.at_level(logging.INFO, logger="bonefit.worker"):
        assert runtime.queue.run_next(worker.run_job)
    assert "not in the job store; message dropped" in caplog.text
    assert runtime.queue.depth() == 0


@pytest.mark.parametrize(("full", "storage"), [
    (OSError(errno.ENOSPC, "No space left on device"), "worker's scratch disk"),
    (StorageFull("the artifact storage is full (OSError)", storage="artifact storage"),
     "artifact storage"),
])
def test_a_full_disk_fails_the_job_with_a_507_at_once(client: TestClient, runtime: Runtime,
                                                      full: Exception, storage: str) -> None:
    """Writing results on a full disk: a 507 problem naming the storage, not retried (the
    next attempt would meet the same disk) and not a 500."""
    job = submit(client, upload(client)["id"])

    def body(_progress: Progress) -> None:
        raise full

    assert drain(runtime, Worker(runtime, kind_with(body))) == 1
    done = client.get(f"/v1/jobs/{job['id']}").json()
    assert done["status"] == "failed"
    assert done["attempts"] == 1
    assert (done["error"]["status"], done["error"]["storage"]) == (507, storage)
