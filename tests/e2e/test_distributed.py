"""Distributed mode end to end: `bonefit serve --no-worker` API replicas and two `bonefit worker`
processes sharing Redis (queue), PostgreSQL (job store) and a real S3 server (SeaweedFS on
loopback). Every process has its own empty data directory, so whatever crosses between them goes
through the three shared back-ends.

Skipped when a server is missing, failed instead under BONEFIT_TEST_REQUIRE_SERVICES=1 (CI).
"""

from __future__ import annotations

import os
import secrets
import signal
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import httpx
import pytest
import redis
import sqlalchemy

from tests.e2e.conftest import (
    Launcher,
    ManagedProcess,
    ServerProcess,
    submit,
    upload,
    wait_for_job,
    wait_ready,
)

if TYPE_CHECKING:
    from tests.e2e.services import S3Server

pytest_plugins = ["tests.e2e.services"]
pytestmark = [pytest.mark.services, pytest.mark.slow]

KEY = "distributed-key"
AUTH = {"Authorization": f"Bearer {KEY}"}


@dataclass
class Cluster:
    """One API replica (more can be started) and two workers on the shared back-ends."""

    launcher: Launcher
    env: dict[str, str]
    api: ServerProcess
    workers: list[ManagedProcess]
    s3: S3Server
    prefix: str

    def client(self, api: ServerProcess | None = None) -> httpx.Client:
        return (api or self.api).client(headers=AUTH)

    def replica(self) -> ServerProcess:
        """Another API replica with a fresh, empty data directory."""
        return self.launcher.server(self.env, worker=False)

    def worker_for(self, job: dict[str, Any]) -> ManagedProcess:
        """The worker process running ``job`` (its ``worker`` field is host:pid)."""
        pid = int(job["worker"].rsplit(":", 1)[1])
        matches = [w for w in self.workers if w.proc is not None and w.pid == pid]
        assert matches, f"job runs on {job['worker']}, not one of our workers"
        return matches[0]

    def s3_keys(self) -> list[str]:
        listing = self.s3.client().list_objects_v2(  # type: ignore[attr-defined]
            Bucket=self.s3.bucket, Prefix=self.prefix)
        return [item["Key"] for item in listing.get("Contents", [])]


@pytest.fixture(scope="module")
def cluster(tmp_path_factory: pytest.TempPathFactory, distributed_env: dict[str, str],
            s3: S3Server) -> Iterator[Cluster]:
    prefix = f"dist-{secrets.token_hex(4)}"
    env = {
        **distributed_env, **s3.env(prefix),
        "BONEFIT_API_KEYS": f'{{"{KEY}": "studio-a"}}',
        "BONEFIT_LEASE_SECONDS": "4",
        "BONEFIT_MAX_ATTEMPTS": "5",
    }
    launcher = Launcher(tmp_path_factory)
    try:
        api = launcher.server(env, worker=False)
        workers = [launcher.worker(env), launcher.worker(env)]
        yield Cluster(launcher, env, api, workers, s3, prefix)
    finally:
        launcher.close()


def wait_running(client: httpx.Client, job_id: str, *, not_on: int | None = None,
                 timeout: float = 120) -> dict[str, Any]:
    """Wait until the job runs inside the estimation (progress > 0), on a worker ≠ ``not_on``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job: dict[str, Any] = client.get(f"/v1/jobs/{job_id}").json()
        if job["status"] == "succeeded":
            return job
        assert job["status"] in ("queued", "running"), job
        if (job["status"] == "running" and job["progress"]["fraction"] > 0 and job["worker"]
                and int(job["worker"].rsplit(":", 1)[1]) != not_on):
            return job
        time.sleep(0.1)
    raise TimeoutError(f"job {job_id} never ran")


# ---------------------------------------------------------------------------------- tests


def test_external_servers_answer(redis_url: str, postgres_url: str, s3: S3Server) -> None:
    client = redis.Redis.from_url(redis_url)
    assert client.ping()
    client.close()
    engine = sqlalchemy.create_engine(postgres_url)
    with engine.connect() as conn:
        assert conn.execute(sqlalchemy.text("select 1")).scalar() == 1
    engine.dispose()
    s3c = s3.client()
    s3c.put_object(Bucket=s3.bucket, Key="probe", Body=b"ok")  # type: ignore[attr-defined]
    body = s3c.get_object(Bucket=s3.bucket, Key="probe")["Body"].read()  # type: ignore[attr-defined]
    assert body == b"ok"


def test_ready_on_redis_postgres_and_s3(cluster: Cluster, postgres_url: str) -> None:
    with cluster.client() as client:
        r = wait_ready(client)
    assert r.status_code == 200, r.text
    assert r.json()["checks"] == {"database": "ok", "queue": "ok", "storage": "ok",
                                  "disk": "ok", "workers": "ok"}
    engine = sqlalchemy.create_engine(postgres_url)
    try:
        tables = sqlalchemy.inspect(engine).get_table_names()
    finally:
        engine.dispose()
    assert tables, "the job store made no tables in PostgreSQL"


def test_skeleton_flow(cluster: Cluster, sensor_csv_bytes: bytes) -> None:
    before = set(cluster.s3_keys())
    with cluster.client() as client:
        rec = upload(client, sensor_csv_bytes, filename="walk.csv")
        assert rec["format"] == "sensor-csv"
        job = submit(client, {"kind": "skeleton", "recording_id": rec["id"]})
        done = wait_for_job(client, job["id"], timeout=120)
        assert done["status"] == "succeeded", done
        assert set(done["results"]) == {"json", "bvh", "csv", "npz"}
        bvh = client.get(f"/v1/jobs/{job['id']}/result", params={"format": "bvh"})
        assert bvh.status_code == 200
        assert bvh.text.startswith("HIERARCHY")
        assert "root" in client.get(done["results"]["json"]).text
        assert client.get(done["results"]["csv"]).text.count("\n") > 240
    new = set(cluster.s3_keys()) - before
    assert len(new) >= 5, new  # the recording and the four results live in the bucket


def test_translation_flow(cluster: Cluster, kinematics_csv_bytes: bytes) -> None:
    with cluster.client() as client:
        rec = upload(client, kinematics_csv_bytes, filename="walker.csv", format="kinematics-csv")
        job = submit(client, {"kind": "translation", "recording_id": rec["id"],
                              "params": {"method": "contact"}})
        done = wait_for_job(client, job["id"], timeout=120)
        assert done["status"] == "succeeded", done
        assert set(done["results"]) >= {"json", "bvh"}
        assert client.get(done["results"]["bvh"]).text.startswith("HIERARCHY")


def test_kill_9_of_the_worker_mid_job(cluster: Cluster, long_sensor_csv_bytes: bytes) -> None:
    with cluster.client() as client:
        rec = upload(client, long_sensor_csv_bytes, filename="long.csv")
        job = submit(client, {"kind": "skeleton", "recording_id": rec["id"]})
        running = wait_running(client, job["id"])
        assert running["status"] == "running", "the job finished before it could be killed"
        victim = cluster.worker_for(running)
        survivor = next(w for w in cluster.workers if w is not victim)
        victim.kill(signal.SIGKILL)
        # After the lease (4 s) expires, the API's reaper re-queues it; the survivor takes it.
        again = wait_running(client, job["id"], not_on=victim.pid, timeout=120)
        if again["status"] == "running":
            assert cluster.worker_for(again) is survivor
        done = wait_for_job(client, job["id"], timeout=180)
        assert done["status"] == "succeeded", done
        assert done["attempts"] >= 2
        assert client.get(done["results"]["bvh"]).text.startswith("HIERARCHY")
    victim.start()  # back to two workers for the next tests


def test_cancel_reaches_the_worker_through_the_store(cluster: Cluster,
                                                     long_sensor_csv_bytes: bytes) -> None:
    replica = cluster.replica()
    try:
        with cluster.client() as client, cluster.client(replica) as other:
            rec = upload(client, long_sensor_csv_bytes, filename="long.csv")
            job = submit(client, {"kind": "skeleton", "recording_id": rec["id"]})
            running = wait_running(client, job["id"])
            assert running["status"] == "running"
            r = other.post(f"/v1/jobs/{job['id']}/cancel")  # through another replica
            assert r.status_code == 202, r.text
            done = wait_for_job(client, job["id"], timeout=60)
            assert done["status"] == "cancelled", done
            assert client.get(f"/v1/jobs/{job['id']}/result").status_code == 409
    finally:
        replica.stop()


def test_api_restart_and_other_replicas_lose_nothing(cluster: Cluster,
                                                     sensor_csv_bytes: bytes) -> None:
    with cluster.client() as client:
        rec = upload(client, sensor_csv_bytes, filename="walk.csv")
        jobs = [submit(client, {"kind": "skeleton", "recording_id": rec["id"]})
                for _ in range(3)]
    cluster.api.kill(signal.SIGKILL)  # kill -9 of the API while its jobs are queued or running
    replica = cluster.replica()  # a new API on an empty data directory
    try:
        with cluster.client(replica) as client:
            assert client.get(f"/v1/recordings/{rec['id']}").json()["sha256"] == rec["sha256"]
            for job in jobs:
                done = wait_for_job(client, job["id"], timeout=120)
                assert done["status"] == "succeeded", done
            listed = {j["id"] for j in client.get("/v1/jobs", params={"limit": 1000})
                      .json()["items"]}
            assert {j["id"] for j in jobs} <= listed
        cluster.api.restart()  # the original API comes back and sees the same
        with cluster.client() as client:
            for job in jobs:
                again = client.get(f"/v1/jobs/{job['id']}").json()
                assert again["status"] == "succeeded"
                r = client.get(again["results"]["bvh"])
                assert r.status_code == 200
                assert r.text.startswith("HIERARCHY")
    finally:
        replica.stop()


def test_idempotent_retry_across_replicas(cluster: Cluster, sensor_csv_bytes: bytes) -> None:
    key = f"retry-{os.getpid()}-{secrets.token_hex(4)}"
    replica = cluster.replica()
    try:
        with cluster.client() as first, cluster.client(replica) as second:
            rec = upload(first, sensor_csv_bytes, filename="walk.csv")
            body = {"kind": "skeleton", "recording_id": rec["id"]}
            one = submit(first, body, **{"Idempotency-Key": key})
            two = submit(second, body, **{"Idempotency-Key": key})  # the retry, elsewhere
            assert two["id"] == one["id"]
            changed = second.post("/v1/jobs", headers={"Idempotency-Key": key},
                                  json={**body, "params": {"method": "gdke"}})
            assert changed.status_code == 422
            assert changed.headers["content-type"] == "application/problem+json"
            assert wait_for_job(first, one["id"], timeout=120)["status"] == "succeeded"
            mine = [j for j in first.get("/v1/jobs", params={"limit": 1000}).json()["items"]
                    if j["recording_id"] == rec["id"]]
            assert len(mine) == 1
    finally:
        replica.stop()
