"""Embedded mode end to end: one `bonefit serve` process with its worker pool, SQLite and disk."""

from __future__ import annotations

import io
import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from tests.e2e.conftest import (
    Launcher,
    ServerProcess,
    submit,
    upload,
    wait_for_job,
    wait_ready,
)

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[2]
LEASE = "3"
LIMIT = 32 * 1024 * 1024
PROBLEM = "application/problem+json"


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    """An embedded server (two workers, 3 s leases), serving loopback only (no API keys)."""
    launcher = Launcher(tmp_path_factory)
    yield launcher.server({"BONEFIT_LEASE_SECONDS": LEASE, "BONEFIT_WORKERS": "2"})
    launcher.close()


@pytest.fixture
def client(server: ServerProcess) -> Iterator[httpx.Client]:
    """A client of the embedded server."""
    with server.client() as c:
        yield c


def events(client: httpx.Client, job_id: str) -> list[tuple[str, dict[str, Any]]]:
    """Every Server-Sent Event of the job until the stream ends."""
    out: list[tuple[str, dict[str, Any]]] = []
    with client.stream("GET", f"/v1/jobs/{job_id}/events", timeout=120) as r:
        assert r.status_code == 200
        assert r.headers["content-type"].startswith("text/event-stream")
        name = ""
        for line in r.iter_lines():
            if line.startswith("event: "):
                name = line.removeprefix("event: ")
            elif line.startswith("data: "):
                out.append((name, json.loads(line.removeprefix("data: "))))
    return out


def wait_running(client: httpx.Client, job_id: str, timeout: float = 60) -> dict[str, Any]:
    """Wait until the job runs and has reported progress (it is inside the estimation)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job: dict[str, Any] = client.get(f"/v1/jobs/{job_id}").json()
        if job["status"] == "running" and job["progress"]["fraction"] > 0:
            return job
        assert job["status"] in ("queued", "running"), job
        time.sleep(0.1)
    raise TimeoutError(f"job {job_id} never ran")


def test_skeleton_flow(client: httpx.Client, sensor_csv_bytes: bytes) -> None:
    rec = upload(client, sensor_csv_bytes, filename="walk.csv")
    assert rec["format"] == "sensor-csv"
    assert rec["summary"]["frames"] == 240
    assert len(rec["summary"]["sensors"]) == 15
    job = submit(client, {"kind": "skeleton", "recording_id": rec["id"],
                          "params": {"method": "auto"}})
    stream = events(client, job["id"])
    names = [name for name, _ in stream]
    assert names[-1] == "end"
    assert stream[-1][1] == {"status": "succeeded"}
    statuses = [data["status"] for name, data in stream if name in ("status", "progress")]
    assert statuses[-1] == "succeeded"
    fractions = [data["progress"]["fraction"] for name, data in stream if name != "end"]
    assert fractions == sorted(fractions)
    done = wait_for_job(client, job["id"])
    assert done["status"] == "succeeded", done["error"]
    assert set(done["results"]) == {"json", "bvh", "csv", "npz"}
    r = client.get(done["results"]["json"])
    assert r.headers["content-type"] == "application/json"
    assert "root" in json.dumps(r.json())
    document = r.json()
    r = client.get(done["results"]["npz"])
    assert r.headers["content-type"] == "application/x-npz"
    with np.load(io.BytesIO(r.content)) as npz:  # the JSON's names, arrays at full precision
        np.testing.assert_allclose(npz["joints/root"], document["joints"]["root"], atol=5e-7)
    r = client.get(f"/v1/jobs/{job['id']}/result", params={"format": "bvh"})
    assert r.status_code == 200
    assert r.headers["content-disposition"] == f'attachment; filename="skeleton-{job["id"]}.bvh"'
    assert r.text.startswith("HIERARCHY")
    assert "MOTION" in r.text
    r = client.get(done["results"]["csv"])
    assert r.headers["content-type"].startswith("text/csv")
    assert r.text.count("\n") > 240


def test_a_calibration_applied_to_another_take(client: httpx.Client,
                                               sensor_csv_bytes: bytes) -> None:
    rec = upload(client, sensor_csv_bytes, filename="walk.csv")
    calibration = wait_for_job(client, submit(client, {"kind": "skeleton",
                                                       "recording_id": rec["id"]})["id"])
    assert calibration["status"] == "succeeded", calibration["error"]
    fitted = client.get(calibration["results"]["json"]).json()
    job = submit(client, {"kind": "skeleton", "recording_id": rec["id"],
                          "params": {"offsets": fitted["offsets"]}})
    done = wait_for_job(client, job["id"])
    assert done["status"] == "succeeded", done["error"]
    applied = client.get(done["results"]["json"]).json()
    assert applied["method"] == "offsets"
    assert applied["offsets"] == fitted["offsets"]
    # an incomplete calibration fails the job, naming the joint as the client sent it
    partial = {k: v for k, v in fitted["offsets"].items() if k != "r_wrist"}
    job = submit(client, {"kind": "skeleton", "recording_id": rec["id"],
                          "params": {"offsets": partial}})
    failed = wait_for_job(client, job["id"])
    assert failed["status"] == "failed"
    assert failed["error"]["status"] == 422
    assert failed["error"]["field"] == "params.offsets.r_wrist"
    r = client.post("/v1/jobs", json={"kind": "skeleton", "recording_id": rec["id"],
                                      "params": {"offsets": {"neck": {"sensor": "chest",
                                                                      "local": [0, 1]}}}})
    assert r.status_code == 422
    assert r.json()["field"].startswith("params.offsets.neck")


def test_multipart_upload_and_reduced_suit(client: httpx.Client, sensor_csv_bytes: bytes) -> None:
    r = client.post("/v1/recordings", files={"file": ("walk.csv", sensor_csv_bytes, "text/csv")})
    assert r.status_code == 201, r.text
    assert r.json()["size"] == len(sensor_csv_bytes)
    job = submit(client, {"kind": "skeleton", "recording_id": r.json()["id"],
                          "params": {"method": "reduced"}})
    assert wait_for_job(client, job["id"])["status"] == "succeeded"


def test_translation_flow(client: httpx.Client, kinematics_csv_bytes: bytes) -> None:
    rec = upload(client, kinematics_csv_bytes, filename="walker.csv", format="kinematics-csv")
    assert rec["summary"]["joints"][0] == "Hips"
    job = submit(client, {"kind": "translation", "recording_id": rec["id"],
                          "params": {"method": "contact"}})
    done = wait_for_job(client, job["id"])
    assert done["status"] == "succeeded", done["error"]
    assert set(done["results"]) == {"json", "bvh", "csv", "npz"}
    assert client.get(done["results"]["bvh"]).text.startswith("HIERARCHY")
    corrected = client.get(done["results"]["csv"]).text.splitlines()
    assert corrected[0] == kinematics_csv_bytes.decode().splitlines()[0]
    faithful = submit(client, {"kind": "translation", "recording_id": rec["id"],
                               "params": {"method": "hachaj2018"}})
    done = wait_for_job(client, faithful["id"])
    assert done["status"] == "succeeded", done["error"]


def test_translation_of_a_bvh_with_accelerations(
        client: httpx.Client, bvh_and_accelerations: tuple[bytes, bytes, tuple[str, str]]) -> None:
    bvh, accelerations, (left, right) = bvh_and_accelerations
    clip = upload(client, bvh, filename="clip.bvh")
    assert clip["format"] == "bvh"
    acc = upload(client, accelerations, filename="feet.csv", format="accelerations-csv")
    body = {"kind": "translation", "recording_id": clip["id"],
            "params": {"left_foot": left, "right_foot": right, "acceleration_units": "g"}}
    without = submit(client, body)
    failed = wait_for_job(client, without["id"])
    assert failed["status"] == "failed"
    assert failed["error"]["field"] == "accelerations"  # a BVH needs its accelerations
    job = submit(client, {**body, "inputs": {"accelerations": acc["id"]}})
    done = wait_for_job(client, job["id"])
    assert done["status"] == "succeeded", done["error"]
    assert set(done["results"]) == {"json", "bvh", "npz"}
    assert client.get(done["results"]["bvh"]).text.startswith("HIERARCHY")


def test_cancel_a_running_job(client: httpx.Client, long_sensor_csv_bytes: bytes) -> None:
    rec = upload(client, long_sensor_csv_bytes, filename="long.csv")
    job = submit(client, {"kind": "skeleton", "recording_id": rec["id"]})
    wait_running(client, job["id"])
    r = client.post(f"/v1/jobs/{job['id']}/cancel")
    assert r.status_code == 202
    done = wait_for_job(client, job["id"], timeout=30)
    assert done["status"] == "cancelled"
    assert done["results"] == {}
    r = client.get(f"/v1/jobs/{job['id']}/result")
    assert r.status_code == 409
    assert r.headers["content-type"] == PROBLEM


def test_job_survives_kill_9_of_its_worker(server: ServerProcess, client: httpx.Client,
                                           long_sensor_csv_bytes: bytes) -> None:
    rec = upload(client, long_sensor_csv_bytes, filename="long.csv")
    job = submit(client, {"kind": "skeleton", "recording_id": rec["id"]})
    running = wait_running(client, job["id"])
    pid = int(running["worker"].rsplit(":", 1)[1])
    assert pid in server.worker_pids()
    os.kill(pid, signal.SIGKILL)
    done = wait_for_job(client, job["id"], timeout=120)
    assert done["status"] == "succeeded", done["error"]
    assert done["attempts"] == 2
    deadline = time.monotonic() + 20
    while len(server.worker_pids()) < 2 and time.monotonic() < deadline:
        time.sleep(0.2)
    assert len(server.worker_pids()) == 2  # the pool replaced the dead worker
    assert pid not in server.worker_pids()
    # the killed worker's job folder went with it: the replacement removed it at start
    left = sorted(p.name.rpartition("-")[2] for p in (server.data_dir / "tmp").iterdir())
    assert str(pid) not in left
    assert set(left) <= {str(p) for p in server.worker_pids()}


def test_malformed_recordings_and_params(client: httpx.Client, sensor_csv_bytes: bytes) -> None:
    bad = b"time,pelvis.x,pelvis.y\n0,1,2\n"
    r = client.post("/v1/recordings", content=bad, params={"format": "sensor-csv"})
    assert r.status_code == 422
    assert r.headers["content-type"] == PROBLEM
    problem = r.json()
    assert problem["line"] == 1
    assert problem["status"] == 422
    assert "pelvis" in problem["detail"]
    rec = upload(client, sensor_csv_bytes, filename="walk.csv")
    r = client.post("/v1/jobs", json={"kind": "skeleton", "recording_id": rec["id"],
                                      "params": {"method": "magic", "extra": 1}})
    assert r.status_code == 422
    assert r.json()["field"] in ("params.method", "params.extra")
    # well-formed but not estimable: three sensors only → a failed job naming the sensor
    lines = sensor_csv_bytes.decode().splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("time"))
    few = "\n".join(",".join(line.split(",")[:22]) for line in lines[start:]) + "\n"
    rec3 = upload(client, few.encode(), filename="three.csv")
    assert rec3["summary"]["sensors"] == ["pelvis", "chest", "head"]
    job = submit(client, {"kind": "skeleton", "recording_id": rec3["id"]})
    failed = wait_for_job(client, job["id"])
    assert failed["status"] == "failed"
    assert failed["error"]["status"] == 422
    assert "sensor" in failed["error"]
    assert client.get(f"/v1/recordings/{rec3['id']}").status_code == 200


def test_idempotent_retry(client: httpx.Client, sensor_csv_bytes: bytes) -> None:
    rec = upload(client, sensor_csv_bytes, filename="walk.csv")
    body = {"kind": "skeleton", "recording_id": rec["id"]}
    key = f"retry-{time.time_ns()}"
    first = submit(client, body, **{"Idempotency-Key": key})
    second = submit(client, body, **{"Idempotency-Key": key})
    assert second["id"] == first["id"]
    r = client.post("/v1/jobs", json={**body, "params": {"method": "gdke"}},
                    headers={"Idempotency-Key": key})
    assert r.status_code == 422
    assert wait_for_job(client, first["id"])["status"] == "succeeded"


def test_probes_and_metrics(client: httpx.Client) -> None:
    assert client.get("/healthz").json() == {"status": "ok"}
    assert wait_ready(client).json()["status"] == "ok"
    text = client.get("/metrics").text
    assert 'bonefit_jobs{kind="skeleton",status="succeeded"}' in text
    assert "bonefit_queue_depth" in text
    assert "bonefit_upload_bytes_total" in text


# ------------------------------------------- a server with API keys: tenants, limits, restart


@pytest.fixture(scope="module")
def keyed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    """A server with two tenants, a 32 MiB upload limit and no shutdown grace."""
    launcher = Launcher(tmp_path_factory)
    yield launcher.server({"BONEFIT_LEASE_SECONDS": LEASE, "BONEFIT_WORKERS": "1",
                           "BONEFIT_API_KEYS": json.dumps({"ka": "alice", "kb": "bob"}),
                           "BONEFIT_MAX_UPLOAD_BYTES": str(LIMIT),
                           "BONEFIT_SHUTDOWN_GRACE_SECONDS": "0"})
    launcher.close()


def test_tenant_isolation(keyed: ServerProcess, sensor_csv_bytes: bytes) -> None:
    with keyed.client(headers={"Authorization": "Bearer ka"}) as alice, \
            keyed.client(headers={"Authorization": "Bearer kb"}) as bob:
        rec = upload(alice, sensor_csv_bytes, filename="walk.csv")
        job = submit(alice, {"kind": "skeleton", "recording_id": rec["id"]})
        assert bob.get(f"/v1/recordings/{rec['id']}").status_code == 404
        assert bob.get(f"/v1/jobs/{job['id']}").status_code == 404
        assert bob.get(f"/v1/jobs/{job['id']}/result").status_code == 404
        assert bob.get("/v1/jobs").json()["items"] == []
        assert bob.delete(f"/v1/recordings/{rec['id']}").status_code == 404
        assert wait_for_job(alice, job["id"])["status"] == "succeeded"
        with keyed.client() as anonymous:
            r = anonymous.get("/v1/jobs")
            assert r.status_code == 401
            assert r.headers["content-type"] == PROBLEM


def test_upload_limit(keyed: ServerProcess) -> None:
    # A declared Content-Length over the limit is refused before any byte of the body is sent.
    with socket.create_connection(("127.0.0.1", keyed.port), timeout=10) as sock:
        sock.sendall(b"POST /v1/recordings HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer ka\r\n"
                     b"Content-Length: %d\r\n\r\n" % (LIMIT + 1))
        head = sock.recv(65536).decode()
    assert head.startswith("HTTP/1.1 413")
    assert "application/problem+json" in head
    with keyed.client(headers={"Authorization": "Bearer ka"}) as c:
        before = c.get("/v1/recordings").json()["items"]

        def chunks() -> Iterator[bytes]:  # chunked: no Content-Length, counted while streaming
            for _ in range(LIMIT // (1024 * 1024) + 2):
                yield b"y" * 1024 * 1024

        try:
            r = c.post("/v1/recordings", content=chunks())
            assert r.status_code == 413
            assert r.headers["content-type"] == PROBLEM
        except httpx.HTTPError:
            pass  # the server may close the connection before the client finished sending
        assert c.get("/v1/recordings").json()["items"] == before
    assert not list((keyed.data_dir / "uploads").glob("*"))


def test_api_restart_loses_nothing(keyed: ServerProcess, sensor_csv_bytes: bytes,
                                   long_sensor_csv_bytes: bytes) -> None:
    auth = {"Authorization": "Bearer ka"}
    with keyed.client(headers=auth) as c:
        rec = upload(c, sensor_csv_bytes, filename="walk.csv")
        done = submit(c, {"kind": "skeleton", "recording_id": rec["id"]})
        wait_for_job(c, done["id"])
    keyed.restart(signal.SIGKILL)  # kill -9 of the API (its workers exit by themselves)
    with keyed.client(headers=auth) as c:
        assert c.get(f"/v1/recordings/{rec['id']}").json()["sha256"] == rec["sha256"]
        assert c.get(f"/v1/jobs/{done['id']}").json()["status"] == "succeeded"
        assert c.get(f"/v1/jobs/{done['id']}/result", params={"format": "bvh"}).status_code == 200
        long = upload(c, long_sensor_csv_bytes, filename="long.csv")
        running = submit(c, {"kind": "skeleton", "recording_id": long["id"]})
        queued = submit(c, {"kind": "skeleton", "recording_id": rec["id"]})
        wait_running(c, running["id"])
    keyed.restart(signal.SIGTERM)  # graceful: the running job is handed back, nothing is lost
    assert f"job {running['id']}: handed back to the queue" in keyed.log()
    with keyed.client(headers=auth) as c:
        handed_back = wait_for_job(c, running["id"], timeout=120)
        assert handed_back["status"] == "succeeded"
        assert handed_back["attempts"] == 1  # a hand-back is not a failed attempt
        assert wait_for_job(c, queued["id"])["status"] == "succeeded"
        listed = {j["id"] for j in c.get("/v1/jobs").json()["items"]}
        assert listed >= {done["id"], running["id"], queued["id"]}


def test_the_documented_httpx_flow_runs(server: ServerProcess, tmp_path: Path) -> None:
    doc = (ROOT / "docs" / "service.md").read_text()
    script = doc.split("```python\n", 1)[1].split("```", 1)[0]
    (tmp_path / "flow.py").write_text(script)
    example = ROOT / "estimation" / "examples" / "walk.csv"
    done = subprocess.run([sys.executable, "flow.py", str(example)], cwd=tmp_path,
                          env={**os.environ, "BONEFIT_URL": server.base_url},
                          capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "succeeded" in done.stdout
    assert sorted(p.suffix for p in tmp_path.glob("skeleton-*")) == [".bvh", ".csv", ".json",
                                                                      ".npz"]
