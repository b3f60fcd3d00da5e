"""HTTP edge cases (issue 16 §3): odd headers and names, 405s, outages on a kept-alive
connection, slow clients, on the in-memory back-ends and on SQLite and PostgreSQL job stores."""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import redis.exceptions
import sqlalchemy.exc
import uvicorn
from fastapi import FastAPI

from bonefit.service import uploads
from bonefit.service.app import create_app
from bonefit.service.artifacts import LocalArtifactStore
from bonefit.service.queue import queue_error
from bonefit.service.runtime import Runtime
from bonefit.service.settings import Settings
from bonefit.service.sql_store import SqlJobStore, sql_error
from bonefit.service.worker import Worker
from tests.service.helpers import (
    AUTH_A,
    FAKE_KINDS,
    KEYS,
    TestClient,
    drain,
    local_queue,
    local_runtime,
    sensor_csv,
    submit,
    upload,
)
from tests.service.test_service_api import assert_problem
from tests.service.test_service_backends import postgres_url  # noqa: F401  (a fixture)

EMOJI_NAME = "\N{GRINNING FACE}" * 60 + ".csv"  # 244 UTF-8 bytes: over the 200 kept
SECONDS = 30.0  # generous bound on anything a loaded machine should do at once


# --- names and headers ---------------------------------------------------------------------


def test_a_filename_of_64_emoji_is_cut_by_bytes(client: TestClient) -> None:
    r = client.post("/v1/recordings", content=sensor_csv(),
                    params={"filename": "\N{GRINNING FACE}" * 64})  # 256 bytes: ENAMETOOLONG
    assert r.status_code == 201, r.text
    name = r.json()["filename"]
    assert name == "\N{GRINNING FACE}" * 50
    assert len(name.encode()) == 200
    rec = upload(client, filename=EMOJI_NAME)
    assert rec["filename"].endswith(".csv")
    assert len(rec["filename"].encode()) <= 200
    assert rec["filename"] == "\N{GRINNING FACE}" * 49 + ".csv"


def test_a_multipart_filename_is_cut_by_bytes(client: TestClient) -> None:
    r = client.post("/v1/recordings", files={"file": ("\N{SNOWMAN}" * 100, sensor_csv())})
    assert r.status_code == 201, r.text
    assert r.json()["filename"] == "\N{SNOWMAN}" * 66  # 3 bytes each: 198 of 200


@pytest.fixture(params=["sqlite", "postgresql"])
def sql_client(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[TestClient]:
    """The app on a SQL job store (a clean one), so column bounds apply."""
    if request.param == "sqlite":
        url = f"sqlite:///{tmp_path / 'jobs.db'}"
    else:
        url = request.getfixturevalue("postgres_url")
    store = SqlJobStore.from_url(url)
    store.init()
    with store.engine.begin() as conn:
        conn.execute(sqlalchemy.text("DELETE FROM bonefit_jobs"))
        conn.execute(sqlalchemy.text("DELETE FROM bonefit_recordings"))
    runtime = Runtime(Settings(data_dir=tmp_path, api_keys=KEYS), store, local_queue(),
                      LocalArtifactStore(tmp_path / "artifacts"))
    app = create_app(runtime=runtime, kinds=FAKE_KINDS, housekeeping=False)
    try:
        with TestClient(app, headers=AUTH_A, raise_server_exceptions=False) as c:
            yield c
    finally:
        store.dispose()


def test_a_long_content_type_is_refused_on_every_store(sql_client: TestClient) -> None:
    longest = "text/csv; x=" + "a" * 188
    rec = sql_client.post("/v1/recordings", content=sensor_csv(),
                          headers={"Content-Type": longest})
    assert rec.status_code == 201, rec.text
    assert sql_client.get(f"/v1/recordings/{rec.json()['id']}").json()["content_type"] == longest
    r = sql_client.post("/v1/recordings", content=sensor_csv(),
                        headers={"Content-Type": longest + "a"})
    body = assert_problem(r, 422)
    assert body["field"] == "Content-Type"
    assert "201 characters" in str(body["detail"])
    assert len(sql_client.get("/v1/recordings").json()["items"]) == 1


@pytest.mark.parametrize("part_type", [b"text/csv\x00x", b"text/" + b"c" * 300, b"a\x7fb"])
def test_a_bad_part_content_type_is_refused_on_every_store(sql_client: TestClient,
                                                           part_type: bytes) -> None:
    body = (b"--b0\r\nContent-Disposition: form-data; name=\"file\"; filename=\"a.csv\"\r\n"
            b"Content-Type: " + part_type + b"\r\n\r\n" + sensor_csv() + b"\r\n--b0--\r\n")
    r = sql_client.post("/v1/recordings", content=body,
                        headers={"Content-Type": "multipart/form-data; boundary=b0"})
    problem = assert_problem(r, 422)
    assert problem["field"] == "file.Content-Type"
    assert sql_client.get("/v1/recordings").json()["items"] == []


def test_a_part_header_is_bounded(client: TestClient) -> None:
    """A guard: the form parser keeps part headers small (they are held in memory)."""
    body = (b"--b0\r\nContent-Disposition: form-data; name=\"file\"\r\nX-Pad: "
            + b"p" * (8192 + 1) + b"\r\n\r\n" + sensor_csv() + b"\r\n--b0--\r\n")
    r = client.post("/v1/recordings", content=body,
                    headers={"Content-Type": "multipart/form-data; boundary=b0"})
    assert assert_problem(r, 400)["type"] == "urn:bonefit:problem:bad-multipart"


@pytest.mark.parametrize("key", ["", " ", " a", "a ", "\x7f"])
def test_an_empty_or_unprintable_idempotency_key_is_refused(client: TestClient,
                                                             key: str) -> None:
    rec = upload(client)
    r = client.post("/v1/jobs", json={"kind": "skeleton", "recording_id": rec["id"]},
                    headers={"Idempotency-Key": key})
    assert assert_problem(r, 422)["field"] == "Idempotency-Key"
    assert client.get("/v1/jobs").json()["items"] == []
    ok = client.post("/v1/jobs", json={"kind": "skeleton", "recording_id": rec["id"]},
                     headers={"Idempotency-Key": "a b"})
    assert ok.status_code == 202, ok.text


@pytest.mark.parametrize(("method", "path", "allowed"), [
    ("PUT", "/v1/recordings", {"GET", "HEAD", "POST"}),
    ("POST", "/v1/recordings/0abc", {"GET", "HEAD", "DELETE"}),
    ("DELETE", "/v1/jobs", {"GET", "HEAD", "POST"}),
    ("GET", "/v1/jobs/0abc/cancel", {"POST"}),
])
def test_a_405_lists_every_allowed_method(client: TestClient, method: str, path: str,
                                          allowed: set[str]) -> None:
    r = client.request(method, path)
    body = assert_problem(r, 405)
    assert {m.strip() for m in r.headers["allow"].split(",")} == allowed
    assert all(m in str(body["detail"]) for m in allowed)


def test_head_answers_with_the_headers_of_get(settings: Settings, runtime: Runtime,
                                              worker: Worker) -> None:
    """HEAD on every kind of GET route (a JSON document, a problem, a download), over HTTP:
    the status and headers GET gives, no body, and the connection stays usable."""
    app = create_app(runtime=runtime, kinds=FAKE_KINDS, housekeeping=False)
    with serving(app) as port, httpx.Client(base_url=f"http://127.0.0.1:{port}",
                                            headers=AUTH_A, timeout=SECONDS) as client:
        job = submit(client, upload(client)["id"])
        drain(runtime, worker)
        for path in (f"/v1/jobs/{job['id']}", "/v1/jobs/nope", "/healthz",
                     f"/v1/jobs/{job['id']}/result?format=json"):
            got, head = client.get(path), client.head(path)
            assert head.status_code == got.status_code, path
            assert head.content == b""
            for name in ("content-type", "content-length", "etag", "content-disposition"):
                assert head.headers.get(name) == got.headers.get(name), (path, name)
        cancel = client.head(f"/v1/jobs/{job['id']}/cancel")  # no GET there
        assert (cancel.status_code, cancel.headers["allow"], cancel.content) == (405, "POST", b"")
        assert client.get("/healthz").status_code == 200  # the same connection goes on


# --- a real server: connections --------------------------------------------------------------


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


@contextlib.contextmanager
def serving(app: FastAPI) -> Iterator[int]:
    """Run ``app`` under uvicorn in a thread, on a free loopback port."""
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=_free_port(),
                                           log_level="warning", access_log=False))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + SECONDS
    while not server.started:
        assert thread.is_alive(), "uvicorn stopped"
        assert time.monotonic() < deadline, "uvicorn did not start"
        time.sleep(0.02)
    try:
        yield server.config.port
    finally:
        server.should_exit = True
        thread.join(SECONDS)


def _raiser(exc: Exception) -> Callable[..., Any]:
    """A back-end method failing as the adapter does when its driver raises ``exc``."""
    raised = sql_error(exc) or queue_error(exc) or exc

    def fail(*args: Any, **kwargs: Any) -> Any:
        raise raised

    return fail


@pytest.mark.parametrize(("exc", "status"), [
    (sqlalchemy.exc.OperationalError("SELECT 1", {}, Exception("server closed the connection")),
     503),
    (redis.exceptions.ConnectionError("Connection refused"), 503),
    (RuntimeError("a bug"), 500),
])
def test_an_outage_is_answered_on_a_kept_alive_connection(
        settings: Settings, exc: Exception, status: int) -> None:
    runtime = local_runtime(settings)
    runtime.store.list_recordings = _raiser(exc)  # type: ignore[method-assign]
    app = create_app(runtime=runtime, kinds=FAKE_KINDS, housekeeping=False)
    with serving(app) as port, httpx.Client(base_url=f"http://127.0.0.1:{port}",
                                            headers=AUTH_A, timeout=SECONDS) as client:
        answers, ports = [], set()
        for path in ("/v1/recordings", "/v1/recordings", "/healthz"):
            answers.append(client.get(path))
            ports.add(answers[-1].extensions["network_stream"].get_extra_info("client_addr"))
    assert len(ports) == 1, "the server dropped the keep-alive connection"
    for r in answers[:2]:
        body = assert_problem(r, status)
        assert r.headers.get("connection") != "close"
        if status == 503:
            assert body["type"] == "urn:bonefit:problem:unavailable"
            assert r.headers["retry-after"] == "5"
    assert answers[2].status_code == 200


@pytest.mark.parametrize("last_event_id", [b"\xb2", b"9" * 5000, b"-1", b"1.5", b""])
def test_any_last_event_id_is_answered(settings: Settings, last_event_id: bytes) -> None:
    app = create_app(runtime=local_runtime(settings), kinds=FAKE_KINDS, housekeeping=False)
    # over HTTP: the test client re-encodes the header's bytes, a server passes them on
    with serving(app) as port, httpx.Client(base_url=f"http://127.0.0.1:{port}",
                                            headers=AUTH_A, timeout=SECONDS) as client:
        rec = client.post("/v1/recordings", content=sensor_csv(), params={"filename": "a.csv"})
        job = client.post("/v1/jobs", json={"kind": "skeleton", "recording_id": rec.json()["id"]})
        assert client.post(f"/v1/jobs/{job.json()['id']}/cancel").status_code == 202
        r = client.get(f"/v1/jobs/{job.json()['id']}/events",
                       headers={b"Last-Event-ID": last_event_id})
    assert r.status_code == 200, r.text
    assert "event: status" in r.text
    assert r.text.rstrip().endswith('data: {"status": "cancelled"}')


# --- a real server: slow clients -------------------------------------------------------------


def _slow_upload(port: int, declared: int = 100_000, sent: bytes = b"time,") -> socket.socket:
    """An upload that promises ``declared`` bytes, sends a few, then nothing."""
    sock = socket.create_connection(("127.0.0.1", port), timeout=SECONDS)
    sock.sendall(f"POST /v1/recordings?filename=slow.csv HTTP/1.1\r\nHost: x\r\n"
                 f"Authorization: {AUTH_A['Authorization']}\r\n"
                 f"Content-Length: {declared}\r\n\r\n".encode() + sent)
    return sock


def _read_all(sock: socket.socket) -> bytes:
    """Everything the server sends until it closes the connection."""
    chunks = []
    while chunk := sock.recv(65536):
        chunks.append(chunk)
    return b"".join(chunks)


def test_idle_bodies_time_out_and_the_connections_are_shed(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path, api_keys=KEYS, body_timeout_seconds=0.5)
    app = create_app(runtime=local_runtime(settings), kinds=FAKE_KINDS, housekeeping=False)
    with serving(app) as port:
        slow = [_slow_upload(port) for _ in range(3)]
        job = socket.create_connection(("127.0.0.1", port), timeout=SECONDS)  # a JSON body
        job.sendall(f"POST /v1/jobs HTTP/1.1\r\nHost: x\r\nAuthorization: "
                    f"{AUTH_A['Authorization']}\r\nContent-Type: application/json\r\n"
                    f"Content-Length: 100\r\n\r\n{{\"kind\"".encode())
        for sock in [*slow, job]:
            with sock:
                answer = _read_all(sock)  # the server closes: recv ends
            head, _, body = answer.partition(b"\r\n\r\n")
            assert head.startswith(b"HTTP/1.1 408 "), answer[:300]
            assert b"connection: close" in head.lower()
            assert b"urn:bonefit:problem:body-timeout" in body
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", headers=AUTH_A) as client:
            r = client.post("/v1/recordings", content=sensor_csv(), params={"filename": "a.csv"})
            assert r.status_code == 201, r.text
            assert len(client.get("/v1/recordings").json()["items"]) == 1
    assert not list((tmp_path / "uploads").iterdir())


def test_a_trickling_body_is_shed(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path, api_keys=KEYS, body_timeout_seconds=0.5,
                        body_min_bytes_per_second=1000)
    app = create_app(runtime=local_runtime(settings), kinds=FAKE_KINDS, housekeeping=False)
    with serving(app) as port, _slow_upload(port) as sock:
        sock.setblocking(False)
        answer = b""
        deadline = time.monotonic() + SECONDS
        while not answer:  # a byte every 50 ms: never idle for 0.5 s, but 20 bytes/s
            assert time.monotonic() < deadline, "the trickling client was never shed"
            with contextlib.suppress(BlockingIOError, ConnectionError):
                sock.send(b"0")
            time.sleep(0.05)
            with contextlib.suppress(BlockingIOError):
                answer = sock.recv(65536)
        sock.settimeout(SECONDS)
        answer += _read_all(sock)
    head, _, body = answer.partition(b"\r\n\r\n")
    assert head.startswith(b"HTTP/1.1 408 "), answer[:300]
    assert b"under the minimum of 1000 bytes/s" in body
    assert not list((tmp_path / "uploads").iterdir())


def _until(what: Callable[[], httpx.Response], status: int) -> httpx.Response:
    """Repeat ``what`` until it answers ``status`` (the server handles the slow clients'
    requests concurrently, so it may not have started them yet)."""
    deadline = time.monotonic() + SECONDS
    while (r := what()).status_code != status:
        assert time.monotonic() < deadline, (r.status_code, r.text)
        time.sleep(0.05)
    return r


def test_uploads_over_the_cap_are_refused_until_one_ends(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path, api_keys=KEYS, max_concurrent_uploads=2)
    app = create_app(runtime=local_runtime(settings), kinds=FAKE_KINDS, housekeeping=False)
    with serving(app) as port, httpx.Client(base_url=f"http://127.0.0.1:{port}",
                                            headers=AUTH_A, timeout=SECONDS) as client:

        def post() -> httpx.Response:
            return client.post("/v1/recordings", content=sensor_csv(),
                               params={"filename": "a.csv"})

        slow = [_slow_upload(port) for _ in range(2)]
        r = _until(post, 503)
        body = assert_problem(r, 503)
        assert body["type"] == "urn:bonefit:problem:too-many-uploads"
        assert r.headers["retry-after"] == "5"
        assert client.get("/v1/recordings").status_code == 200  # other requests still served
        slow.pop().close()  # one client gives up: its slot is freed
        _until(post, 201)
        for sock in slow:
            sock.close()
    assert not list((tmp_path / "uploads").iterdir())


def _upload_threads() -> int:
    return sum(t.name.startswith("upload") for t in threading.enumerate())


@pytest.mark.anyio
async def test_an_upload_holds_no_thread_until_its_first_block(tmp_path: Path) -> None:
    before = _upload_threads()
    sinks = [uploads.UploadSink(tmp_path / f"{i}.part", 1 << 20) for i in range(4)]
    for sink in sinks:
        sink.feed(b"t")
        await sink.drain()
    assert _upload_threads() == before
    await sinks[0].close()
    assert sinks[0].path.read_bytes() == b"t"
    for sink in sinks:
        sink.discard()
    assert _upload_threads() == before


def test_serve_passes_the_connection_limits_to_uvicorn(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from bonefit.cli import main
    from bonefit.service import cli

    configs: list[uvicorn.Config] = []

    class Server:
        def __init__(self, config: uvicorn.Config) -> None:
            configs.append(config)

        def run(self) -> None:
            """Serve nothing."""

    monkeypatch.setattr(uvicorn, "Server", Server)
    monkeypatch.setattr(cli.signal, "signal", lambda *args: None)
    monkeypatch.setenv("BONEFIT_MAX_CONNECTIONS", "7")
    monkeypatch.setenv("BONEFIT_KEEP_ALIVE_SECONDS", "3")
    assert main(["serve", "--no-worker", "--data-dir", str(tmp_path)]) == 0
    assert configs[0].limit_concurrency == 7
    assert configs[0].timeout_keep_alive == 3


def test_an_outage_while_following_a_job_ends_the_stream_with_an_error_event(
        client: TestClient, runtime: Runtime) -> None:
    rec = upload(client)
    job = client.post("/v1/jobs", json={"kind": "skeleton", "recording_id": rec["id"]}).json()
    get_job = runtime.store.get_job
    calls = []

    def flaky(*args: Any, **kwargs: Any) -> Any:
        calls.append(args)
        if len(calls) > 2:  # the route's check and the first poll pass, then the outage
            return _raiser(sqlalchemy.exc.OperationalError(
                "SELECT", {}, Exception("connection lost")))()
        return get_job(*args, **kwargs)

    runtime.store.get_job = flaky  # type: ignore[method-assign]
    r = client.get(f"/v1/jobs/{job['id']}/events")
    assert r.status_code == 200
    events = r.text.strip().split("\n\n")
    assert events[0].startswith("id: 1\nevent: status")
    assert events[-1].startswith("retry: 5000\nevent: error\ndata: ")
    assert '"urn:bonefit:problem:unavailable"' in events[-1]
