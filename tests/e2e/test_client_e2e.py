"""`bonefit.client` against real servers: embedded (one `bonefit serve`) and distributed
(API + worker on Redis, PostgreSQL and S3), with a server restart and a Redis outage while the
client waits, and never a duplicate job."""

from __future__ import annotations

import asyncio
import contextlib
import json
import shutil
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from bonefit.client import AsyncClient, Client, Job, ProblemError, SkeletonResult, TranslationResult
from tests.e2e.conftest import Launcher, ServerProcess, free_port

if TYPE_CHECKING:
    from tests.e2e.services import S3Server

pytest_plugins = ["tests.e2e.services"]
pytestmark = pytest.mark.slow
KEY = "client-key"


@pytest.fixture(scope="module")
def embedded(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    """An embedded server with an API key, one worker and no shutdown grace."""
    launcher = Launcher(tmp_path_factory)
    yield launcher.server({"BONEFIT_API_KEYS": json.dumps({KEY: "studio-a"}),
                           "BONEFIT_WORKERS": "1", "BONEFIT_LEASE_SECONDS": "3",
                           "BONEFIT_SHUTDOWN_GRACE_SECONDS": "0"})
    launcher.close()


def wait_running(client: Client, job: Job, timeout: float = 120) -> Job:
    """Poll until the job runs inside the estimation (progress > 0)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        now = client.job(job)
        if now.status == "running" and now.fraction > 0:
            return now
        assert now.status in ("queued", "running"), now
        time.sleep(0.1)
    raise TimeoutError(f"job {job.id} never ran")


class Waiter(threading.Thread):
    """``client.wait(job)`` in a thread, recording every state it was told about."""

    def __init__(self, client: Client, job: Job) -> None:
        super().__init__(daemon=True)
        self.client, self.job = client, job
        self.states: list[Job] = []
        self.final: Job | None = None
        self.error: BaseException | None = None

    def run(self) -> None:
        try:
            self.final = self.client.wait(self.job, progress=self.states.append, timeout=300)
        except BaseException as exc:
            self.error = exc

    def result(self) -> Job:
        self.join(320)
        assert self.error is None, repr(self.error)
        assert self.final is not None
        return self.final


def jobs_of(client: Client, recording_id: str) -> list[Job]:
    return [j for j in client.jobs(limit=1000) if j.recording_id == recording_id]


def test_run_returns_typed_results(embedded: ServerProcess, sensor_csv_bytes: bytes,
                                   kinematics_csv_bytes: bytes, tmp_path: Path) -> None:
    take = tmp_path / "walk.csv"
    take.write_bytes(sensor_csv_bytes)
    with Client(embedded.base_url, KEY) as client:
        fractions: list[float] = []
        skeleton = client.run(take, "skeleton", {"method": "auto"},
                              progress=lambda j: fractions.append(j.fraction))
        assert isinstance(skeleton, SkeletonResult)
        assert skeleton.n_frames == 240
        assert skeleton.joints["l_knee"].shape == (240, 3)
        assert fractions[-1] == 1.0
        walker = client.run(kinematics_csv_bytes, "translation", {"method": "contact"},
                            format="kinematics-csv")
        assert isinstance(walker, TranslationResult)
        assert walker.root.shape == (walker.n_frames, 3)
        assert walker.positions is None  # the JSON carries the root path, not every joint
        assert set(walker.contacts) <= {"left", "right", "both", "none"}
        job = client.jobs(kind="skeleton", status="succeeded")[0]
        path = client.download(job, "bvh", tmp_path / "walk.bvh")
        assert Path(path).read_text().startswith("HIERARCHY")
        with pytest.raises(ProblemError) as info:
            client.run(b"time,foo\n0,1\n", "skeleton")
        assert info.value.status == 422
        assert info.value.problem["field"] == "format"
        with pytest.raises(ProblemError) as info:
            client.submit("skeleton", client.upload(take), {"method": "nope"})
        assert info.value.status == 422


def test_async_client_runs_and_cancels(embedded: ServerProcess, sensor_csv_bytes: bytes,
                                       long_sensor_csv_bytes: bytes) -> None:
    async def main() -> tuple[SkeletonResult, Job]:
        async with AsyncClient(embedded.base_url, KEY) as client:
            result = await client.run(sensor_csv_bytes, "skeleton")
            assert isinstance(result, SkeletonResult)
            rec = await client.upload(long_sensor_csv_bytes, filename="long.csv")
            job = await client.submit("skeleton", rec)
            await client.cancel(job)
            return result, await client.wait(job, timeout=120)

    result, cancelled = asyncio.run(main())
    assert result.n_frames == 240
    assert cancelled.status == "cancelled"


def test_wait_survives_a_server_restart(embedded: ServerProcess,
                                        long_sensor_csv_bytes: bytes) -> None:
    with Client(embedded.base_url, KEY) as client:
        rec = client.upload(long_sensor_csv_bytes, filename="long.csv")
        job = client.submit("skeleton", rec)
        waiter = Waiter(client, job)
        waiter.start()
        wait_running(client, job)
        embedded.restart(signal.SIGTERM)  # the stream drops; the job is handed back
        final = waiter.result()
        assert final.status == "succeeded", final
        assert [j.id for j in jobs_of(client, rec.id)] == [job.id]  # no duplicate
        assert waiter.states[-1].status == "succeeded"


# --------------------------------------------------- distributed: Redis, PostgreSQL and S3


class RedisServer:
    """A redis-server of our own on a free port, to stop and start again (an outage)."""

    def __init__(self, workdir: Path) -> None:
        binary = shutil.which("redis-server")
        if binary is None:
            from tests.e2e.services import unavailable

            unavailable("no redis-server binary for the outage test")
        self.binary = str(binary)
        self.port = free_port()
        self.workdir = workdir
        self.proc: subprocess.Popen[bytes] | None = None

    @property
    def url(self) -> str:
        return f"redis://127.0.0.1:{self.port}/0"

    def start(self) -> None:
        self.proc = subprocess.Popen(
            [self.binary, "--port", str(self.port), "--bind", "127.0.0.1", "--save", "",
             "--appendonly", "yes", "--dir", str(self.workdir)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            with contextlib.suppress(OSError):
                import socket

                socket.create_connection(("127.0.0.1", self.port), timeout=1).close()
                return
            time.sleep(0.1)
        raise TimeoutError("redis-server did not start")

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            self.proc.wait(30)


@pytest.fixture(scope="module")
def cluster(tmp_path_factory: pytest.TempPathFactory, postgres_url: str,
            s3: S3Server) -> Iterator[tuple[ServerProcess, RedisServer]]:
    redis_server = RedisServer(tmp_path_factory.mktemp("redis"))
    redis_server.start()
    env = {"BONEFIT_QUEUE_URL": redis_server.url, "BONEFIT_DATABASE_URL": postgres_url,
           **s3.env(f"client-{free_port()}"), "BONEFIT_API_KEYS": json.dumps({KEY: "studio-a"}),
           "BONEFIT_LEASE_SECONDS": "4", "BONEFIT_MAX_ATTEMPTS": "5",
           "BONEFIT_SHUTDOWN_GRACE_SECONDS": "0"}
    launcher = Launcher(tmp_path_factory)
    try:
        api = launcher.server(env, worker=False)
        launcher.worker(env)
        yield api, redis_server
    finally:
        launcher.close()
        redis_server.stop()


@pytest.mark.services
def test_distributed_restart_and_redis_outage_during_wait(
        cluster: tuple[ServerProcess, RedisServer], sensor_csv_bytes: bytes,
        long_sensor_csv_bytes: bytes) -> None:
    api, redis_server = cluster
    with Client(api.base_url, KEY) as client:
        quick = client.run(sensor_csv_bytes, "skeleton")
        assert isinstance(quick, SkeletonResult)
        assert quick.n_frames == 240
        rec = client.upload(long_sensor_csv_bytes, filename="long.csv")
        job = client.submit("skeleton", rec)
        waiter = Waiter(client, job)
        waiter.start()
        wait_running(client, job)
        redis_server.stop()  # the queue is gone for a while...
        api.restart(signal.SIGTERM)  # ...and the API restarts meanwhile
        time.sleep(2)
        redis_server.start()
        final = waiter.result()
        assert final.status == "succeeded", final
        assert [j.id for j in jobs_of(client, rec.id)] == [job.id]  # no duplicate
        assert client.result(final).n_frames > 0
        after = client.run(sensor_csv_bytes, "skeleton")  # the queue works again
        assert isinstance(after, SkeletonResult)


@pytest.mark.services
def test_distributed_submit_during_a_redis_outage(
        cluster: tuple[ServerProcess, RedisServer], sensor_csv_bytes: bytes) -> None:
    api, redis_server = cluster
    with Client(api.base_url, KEY) as client:
        rec = client.upload(sensor_csv_bytes, filename="walk.csv")
        redis_server.stop()
        submitted: list[Job] = []
        thread = threading.Thread(target=lambda: submitted.append(
            client.submit("skeleton", rec)), daemon=True)
        thread.start()  # 503 queue-unavailable with Retry-After: the client retries
        time.sleep(3)
        redis_server.start()
        thread.join(120)
        assert submitted, "submit did not return"
        done = client.wait(submitted[0], timeout=120)
        assert done.status == "succeeded", done
        jobs = jobs_of(client, rec.id)
        ran = [j for j in jobs if j.status != "failed"]
        assert [j.id for j in ran] == [done.id]  # one job ran
        refused = [j for j in jobs if j.status == "failed"]
        assert refused, "the outage never refused the submission"
        assert all((j.error or {}).get("type", "").endswith("queue-unavailable") and
                   j.attempts == 0 for j in refused), refused  # the refused tries never ran


def test_the_documented_client_example_runs(start_server: Callable[..., ServerProcess],
                                           tmp_path: Path) -> None:
    import os
    import re
    import sys

    root = Path(__file__).resolve().parents[2]
    server = start_server(worker=True)
    doc = (root / "docs" / "studio.md").read_text()
    section = doc.split("## The Python client", 1)[1]
    code = re.findall(r"```python\n(.*?)```", section, re.S)[0]
    code = code.replace("http://127.0.0.1:8000", server.base_url)
    script = tmp_path / "example.py"
    script.write_text(code)
    done = subprocess.run([sys.executable, str(script)], cwd=root, capture_output=True,
                          text=True, timeout=300,
                          env={k: v for k, v in os.environ.items() if not k.startswith("BONEFIT")})
    assert done.returncode == 0, done.stderr
    assert "succeeded 100%" in done.stdout
    assert "300 (300, 3)" in done.stdout
