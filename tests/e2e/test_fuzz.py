"""Fuzzing the HTTP API: no request makes the service answer 500 or stop answering.

Hypothesis drives arbitrary methods, paths, query parameters, headers and bodies (random bytes,
mutated CSV recordings, multipart forms, job documents with arbitrary params) at the real app:
in process (SQLite job store and queue, local artifacts; an unhandled exception is raised by the
test client), then over HTTP at a real `bonefit serve` process, together with malformed HTTP and
uploads cut off mid-body; the process must still answer afterwards. Any 5xx fails. The example
counts are bounded so the whole file runs in well under a minute.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import socket
import time
from collections.abc import AsyncIterator, Callable, Iterator
from pathlib import Path
from typing import Any
from urllib.parse import quote

import httpx
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from benchmarks.service_fuzz import Ids, run_schemathesis
from bonefit.service.app import create_app
from bonefit.service.jobs import JobStore
from bonefit.service.settings import Settings
from bonefit.service.sql_store import SqlJobStore
from tests.e2e.conftest import Launcher, ServerProcess

EXAMPLE = Path(__file__).resolve().parents[2] / "estimation" / "examples" / "walk.csv"
KEY, OTHER_KEY = "fuzz-key", "other-tenant-key"
MAX_UPLOAD = 512 * 1024  # above the example recording (about 300 kB)
FUZZ = settings(max_examples=300, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def seed(request: Callable[..., httpx.Response]) -> list[str]:
    """A recording and a cancelled job (so /events on it ends: nothing runs it); their ids."""
    auth = {"Authorization": f"Bearer {KEY}"}
    rec = request("POST", "/v1/recordings?filename=walk.csv&format=sensor-csv",
                  content=EXAMPLE.read_bytes(), headers=auth)
    assert rec.status_code == 201, rec.text
    rec_id = rec.json()["id"]
    job = request("POST", "/v1/jobs", headers=auth,
                  json={"kind": "skeleton", "recording_id": rec_id})
    assert job.status_code == 202, job.text
    job_id = job.json()["id"]
    cancel = request("POST", f"/v1/jobs/{job_id}/cancel", headers=auth)
    assert cancel.status_code == 202, cancel.text
    return [rec_id, job_id]


class Fixture:
    """The app under test (driven through httpx's ASGI transport) and ids that exist in it."""

    def __init__(self, loop: asyncio.AbstractEventLoop, client: httpx.AsyncClient) -> None:
        self.loop = loop
        self.client = client
        self.ids: list[str] = []

    def request(self, method: str, url: str, **kwargs: Any) -> httpx.Response:
        """One request; an exception escaping the app is raised here (raise_app_exceptions)."""
        return self.loop.run_until_complete(self.client.request(method, url, **kwargs))


def worker_elsewhere(store: JobStore) -> None:
    """A worker heartbeat that stays fresh for the session: /readyz is ready without workers
    running jobs here (they would change what the fuzzed requests find)."""
    store.beat_worker("fuzz:elsewhere", time.time() + 86400)


@pytest.fixture(scope="module")
def api(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Fixture]:
    data = tmp_path_factory.mktemp("fuzz-data")
    app = create_app(Settings(data_dir=data, api_keys={KEY: "fuzz", OTHER_KEY: "other"},
                              max_upload_bytes=MAX_UPLOAD, workers=0), housekeeping=False)
    worker_elsewhere(app.state.runtime.store)
    loop = asyncio.new_event_loop()
    transport = httpx.ASGITransport(app=app, raise_app_exceptions=True)
    client = httpx.AsyncClient(transport=transport, base_url="http://bonefit.test")
    fixture = Fixture(loop, client)
    try:
        fixture.ids = seed(fixture.request)
        yield fixture
    finally:
        loop.run_until_complete(client.aclose())
        loop.close()


# --- strategies ----------------------------------------------------------------------------

header_text = st.text(st.characters(min_codepoint=32, max_codepoint=126), max_size=60)
json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=12), inner,
                                                                 max_size=4),
    max_leaves=12)
skeleton_params = st.dictionaries(
    st.sampled_from(["method", "optimizer", "torso", "anthropometry", "w_s", "w_l", "smooth",
                     "up", "i0", "units", "fps", "stations", "bogus"]),
    json_values | st.sampled_from(["auto", "llsf", "gdke", "reduced", "winter", "cm"]),
    max_size=5)
translation_params = st.dictionaries(
    st.sampled_from(["method", "left_foot", "right_foot", "acceleration_units", "options",
                     "bogus"]),
    json_values | st.sampled_from(["contact", "hachaj2018", "g", "LeftFoot"]), max_size=4)

ROUTES = [  # (method, path template, body kind)
    ("POST", "/v1/recordings", "upload"), ("GET", "/v1/recordings", None),
    ("GET", "/v1/recordings/{id}", None), ("DELETE", "/v1/recordings/{id}", None),
    ("POST", "/v1/jobs", "job"), ("POST", "/v1/jobs", "job"), ("GET", "/v1/jobs", None),
    ("GET", "/v1/jobs/{id}", None), ("POST", "/v1/jobs/{id}/cancel", None),
    ("GET", "/v1/jobs/{id}/result", None), ("GET", "/v1/jobs/{id}/events", None),
    ("GET", "/healthz", None), ("GET", "/readyz", None), ("GET", "/metrics", None),
    ("GET", "/openapi.json", None),
]
METHODS = ["GET", "POST", "DELETE", "PUT", "PATCH", "HEAD", "OPTIONS"]
QUERY_NAMES = ["filename", "format", "status", "kind", "limit", "cursor", "x"]
CONTENT_TYPES = ["application/json", "application/octet-stream", "text/csv",
                 "multipart/form-data; boundary=fuzz", "multipart/form-data",
                 "application/x-www-form-urlencoded"]


@st.composite
def identifiers(draw: st.DrawFn, known: list[str]) -> str:
    return draw(st.sampled_from(known) | st.from_regex(r"[0-9a-z]{1,40}", fullmatch=True)
                | st.text(max_size=80))


@st.composite
def routes(draw: st.DrawFn, known: list[str]) -> tuple[str, str, str | None]:
    """Mostly the API's own routes with fuzzed ids; sometimes any method on any path."""
    if draw(st.integers(0, 9)) < 8:
        method, template, body = draw(st.sampled_from(ROUTES))
    else:
        method, body = draw(st.sampled_from(METHODS)), draw(st.sampled_from(["upload", None]))
        template = draw(st.sampled_from([r[1] for r in ROUTES] + ["/", "/v1", "/docs"])
                        | st.text(max_size=60).map(lambda t: "/" + quote(t, safe="/")))
    while "{id}" in template:
        template = template.replace("{id}", quote(draw(identifiers(known)), safe=""), 1)
    return method, template, body


@st.composite
def csv_bodies(draw: st.DrawFn) -> bytes:
    """The example recording cut short and with cells, lines or bytes damaged."""
    lines = EXAMPLE.read_text().splitlines()[: draw(st.integers(0, 12))]
    for _ in range(draw(st.integers(0, 4))):
        if not lines:
            break
        i = draw(st.integers(0, len(lines) - 1))
        cells = lines[i].split(",")
        j = draw(st.integers(0, len(cells) - 1))
        cells[j] = draw(st.sampled_from(["", "nan", "inf", "-1e309", "x", "1e308", "0,0"])
                        | st.text(max_size=8))
        lines[i] = ",".join(cells)
    return "\n".join(lines).encode() + draw(st.binary(max_size=16))


@st.composite
def multipart_bodies(draw: st.DrawFn) -> bytes:
    name = draw(st.sampled_from(["file", "other", ""]))
    payload = draw(csv_bodies() | st.binary(max_size=200))
    filename = draw(st.sampled_from(["walk.csv", "x.bvh", "", "../../etc/passwd"]))
    body = (b"--fuzz\r\nContent-Disposition: form-data; name=\"" + name.encode()
            + b"\"; filename=\"" + filename.encode() + b"\"\r\n\r\n" + payload + b"\r\n")
    return body + draw(st.sampled_from([b"--fuzz--\r\n", b"", b"--fuzz"]))


@st.composite
def job_bodies(draw: st.DrawFn, known: list[str]) -> bytes:
    doc: dict[str, Any] = {}
    kind = draw(st.sampled_from(["skeleton", "translation"]) | st.text(max_size=12))
    if draw(st.booleans()):
        doc["kind"] = kind
    if draw(st.integers(0, 5)):
        doc["recording_id"] = draw(identifiers(known) | json_values)
    if draw(st.booleans()):
        doc["params"] = draw(translation_params if kind == "translation" else skeleton_params)
    if draw(st.integers(0, 3)) == 0:
        doc["inputs"] = draw(st.dictionaries(st.sampled_from(["accelerations", "x"]),
                                             identifiers(known) | json_values, max_size=2))
    if draw(st.integers(0, 5)) == 0:
        doc[draw(st.text(max_size=8))] = draw(json_values)
    return json.dumps(doc).encode()


@st.composite
def requests(draw: st.DrawFn, known: list[str]) -> dict[str, Any]:
    method, url, body_kind = draw(routes(known))
    headers: dict[str, str] = {}
    auth = draw(st.sampled_from(["key", "key", "key", "other", "none", "junk"]))
    if auth in ("key", "other"):
        headers["Authorization"] = f"Bearer {KEY if auth == 'key' else OTHER_KEY}"
    elif auth == "junk":
        headers["Authorization"] = draw(header_text)
    headers.update(draw(st.dictionaries(
        st.sampled_from(["Idempotency-Key", "If-None-Match", "Accept", "X-Anything",
                         "Accept-Encoding"]), header_text, max_size=3)))
    body: bytes | None = None
    content_type = draw(st.sampled_from(CONTENT_TYPES) | header_text)
    if body_kind == "job" and draw(st.integers(0, 9)) < 8:
        body, content_type = draw(job_bodies(known)), "application/json"
    elif body_kind == "upload" and draw(st.integers(0, 9)) < 4:
        body, content_type = draw(multipart_bodies()), "multipart/form-data; boundary=fuzz"
    elif body_kind is not None or draw(st.integers(0, 9)) == 0:
        body = draw(csv_bodies() | st.binary(max_size=512) | job_bodies(known))
    if body is not None:
        headers["Content-Type"] = content_type
    params = draw(st.dictionaries(
        st.sampled_from(QUERY_NAMES) | st.text(max_size=8),
        st.sampled_from(["auto", "sensor-csv", "tracker", "npz", "bvh", "json", "csv", "queued",
                         "skeleton", "walk.csv", "0", "1000", "-1"])
        | st.text(max_size=40) | st.integers().map(str), max_size=4))
    return {"method": method, "url": url, "params": params, "headers": headers,
            "content": body}


# --- properties ----------------------------------------------------------------------------


def test_no_request_gets_a_server_error(api: Fixture) -> None:
    @FUZZ
    @given(request=requests(api.ids))
    def check(request: dict[str, Any]) -> None:
        response = api.request(**request)
        assert response.status_code < 500, (request, response.status_code, response.text[:500])
        if response.status_code >= 400 and request["method"] != "HEAD":
            assert response.headers["content-type"].startswith("application/problem+json")

    check()
    assert api.request("GET", "/healthz").json() == {"status": "ok"}
    assert api.request("GET", "/readyz").status_code == 200


def test_oversized_uploads_are_refused_without_a_server_error(api: Fixture) -> None:
    auth = {"Authorization": f"Bearer {KEY}"}

    async def chunks(payload: bytes) -> AsyncIterator[bytes]:
        for start in range(0, len(payload), 8192):
            yield payload[start:start + 8192]

    @settings(max_examples=12, deadline=None, derandomize=True, database=None)
    @given(extra=st.integers(1, 4096), how=st.sampled_from(["length", "chunked", "multipart"]))
    def check(extra: int, how: str) -> None:
        payload = b"x" * (MAX_UPLOAD + extra)
        if how == "multipart":
            response = api.request("POST", "/v1/recordings", headers=auth,
                                   files={"file": ("big.csv", payload)})
        elif how == "chunked":  # no Content-Length: the limit holds while streaming
            response = api.request("POST", "/v1/recordings", headers=auth,
                                   content=chunks(payload))
        else:
            response = api.request("POST", "/v1/recordings", headers=auth, content=payload)
        assert response.status_code == 413, response.text

    before = api.request("GET", "/v1/recordings", headers=auth).json()["items"]
    check()
    after = api.request("GET", "/v1/recordings", headers=auth).json()["items"]
    assert after == before, "a refused upload was kept"

    check()


# --- a real server process -----------------------------------------------------------------


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[ServerProcess, list[str]]]:
    """`bonefit serve --no-worker` with API keys and a small upload limit, seeded with ids."""
    launcher = Launcher(tmp_path_factory)
    try:
        server = launcher.server({"BONEFIT_API_KEYS": json.dumps({KEY: "fuzz", OTHER_KEY: "o"}),
                                  "BONEFIT_MAX_UPLOAD_BYTES": str(MAX_UPLOAD)}, worker=False)
        store = SqlJobStore.from_url(f"sqlite:///{server.data_dir / 'jobs.db'}")
        worker_elsewhere(store)
        store.dispose()
        with server.client() as client:
            ids = seed(client.request)
        yield server, ids
    finally:
        launcher.close()


def raw_exchange(port: int, data: bytes, timeout: float = 10.0) -> bytes:
    """Send ``data`` on a fresh connection, close our side, read whatever comes back."""
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as sock:
        with contextlib.suppress(OSError):
            sock.sendall(data)
            sock.shutdown(socket.SHUT_WR)
        chunks = []
        with contextlib.suppress(OSError):
            while chunk := sock.recv(65536):
                chunks.append(chunk)
    return b"".join(chunks)


def assert_alive(server: ServerProcess) -> None:
    assert server.proc is not None
    assert server.proc.poll() is None, server.log()[-3000:]
    with server.client() as client:
        assert client.get("/healthz").status_code == 200
        assert client.get("/readyz").status_code == 200


def test_a_real_server_never_answers_5xx(live: tuple[ServerProcess, list[str]]) -> None:
    server, ids = live

    @settings(max_examples=60, deadline=None, derandomize=True, database=None,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
    @given(request=requests(ids))
    def check(request: dict[str, Any]) -> None:
        with server.client() as client:
            response = client.request(**request)
        assert response.status_code < 500, (request, response.status_code, response.text[:500])

    check()
    assert_alive(server)
    assert "Traceback" not in server.log()


def test_schemathesis_gets_no_server_error(live: tuple[ServerProcess, list[str]],
                                           tmp_path: Path) -> None:
    """A bounded run of the harness `benchmarks/service_fuzz.py` runs in full."""
    server, (rec_id, job_id) = live
    with server.client(headers={"Authorization": f"Bearer {KEY}"}) as client:
        deletable = seed(client.request)[:1]
    ids = Ids(recordings=(rec_id,), jobs=(job_id,), deletable=tuple(deletable))
    runs = [run_schemathesis(server.base_url, tmp_path / "key", ids, key=KEY, max_examples=5,
                             timeout=600),
            run_schemathesis(server.base_url, tmp_path / "none", ids, key=None, max_examples=8,
                             phases="fuzzing", timeout=600)]
    for run in runs:
        assert run.requests > 0, run.output[-3000:]
        assert run.ok, (run.server_errors[:10], run.output[-3000:])
    assert runs[0].statuses[200] > 0
    assert runs[1].statuses[401] > 0  # no key: refused (the probes and /metrics answer)
    assert_alive(server)
    assert "Traceback" not in server.log()


def test_malformed_http_and_cut_off_uploads_leave_it_answering(
        live: tuple[ServerProcess, list[str]]) -> None:
    server, _ = live
    auth = f"Authorization: Bearer {KEY}\r\n"

    @settings(max_examples=30, deadline=None, derandomize=True, database=None)
    @given(kind=st.sampled_from(["garbage", "truncated", "header-junk"]),
           payload=st.binary(max_size=2048), declared=st.integers(1, MAX_UPLOAD))
    def check(kind: str, payload: bytes, declared: int) -> None:
        if kind == "garbage":
            data = payload
        elif kind == "truncated":  # promise more body than is sent, then hang up
            data = (f"POST /v1/recordings?format=sensor-csv HTTP/1.1\r\nHost: x\r\n{auth}"
                    f"Content-Length: {declared + len(payload)}\r\n\r\n").encode() + payload
        else:
            data = (b"GET /v1/jobs HTTP/1.1\r\nHost: x\r\n" + auth.encode()
                    + payload.replace(b"\r\n", b"\n") + b"\r\n\r\n")
        answer = raw_exchange(server.port, data)
        status = answer[9:12]
        assert not status.startswith(b"5"), answer[:300]

    check()
    assert_alive(server)
    leftovers = list((server.data_dir / "uploads").glob("*")) if (
        server.data_dir / "uploads").exists() else []
    assert leftovers == [], "a cut-off upload left a partial file behind"


def test_a_client_hanging_up_mid_upload_is_not_a_server_error(
        live: tuple[ServerProcess, list[str]]) -> None:
    server, _ = live
    before = server.log().count("unhandled error")
    for sent in (0, 10, 70_000):
        raw_exchange(server.port, (
            f"POST /v1/recordings?format=sensor-csv HTTP/1.1\r\nHost: x\r\n"
            f"Authorization: Bearer {KEY}\r\nContent-Length: {MAX_UPLOAD}\r\n\r\n"
        ).encode() + b"0" * sent)
    assert_alive(server)
    log = server.log()
    assert log.count("unhandled error") == before, log[log.rfind("unhandled error") - 200:][:3000]
