"""The HTTP API on in-memory back-ends: recordings, jobs, results, problems, auth."""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import httpx
import pytest

from bonefit.service.app import create_app
from bonefit.service.queue import open_queue
from bonefit.service.runtime import Runtime
from bonefit.service.settings import Settings
from bonefit.service.worker import Worker
from tests.service.helpers import (
    AUTH_A,
    AUTH_B,
    FAKE_KINDS,
    KEYS,
    TestClient,
    drain,
    local_runtime,
    sensor_csv,
    submit,
    upload,
)

PROBLEM = "application/problem+json"


def assert_problem(r: httpx.Response, status: int) -> dict[str, object]:
    assert r.status_code == status, r.text
    assert r.headers["content-type"] == PROBLEM
    body: dict[str, object] = r.json()
    assert {"type", "title", "status", "detail", "instance"} <= body.keys()
    assert body["status"] == status
    return body


# ---------------------------------------------------------------------------- recordings


def test_upload_streams_hashes_and_sniffs(client: TestClient, runtime: Runtime) -> None:
    data = sensor_csv(frames=7)
    rec = upload(client, data)
    assert rec["size"] == len(data)
    import hashlib
    assert rec["sha256"] == hashlib.sha256(data).hexdigest()
    assert rec["format"] == "sensor-csv"
    assert rec["summary"]["frames"] == 7
    assert rec["summary"]["sensors"] == ["pelvis", "chest", "head"]
    assert client.get(f"/v1/recordings/{rec['id']}").json() == rec
    assert not list((runtime.settings.data_dir / "uploads").iterdir())  # no temporary left


def test_upload_counts_rows_while_receiving_in_any_chunks(client: TestClient) -> None:
    head, _, rows = sensor_csv(frames=5000).partition(b"\n")
    lines = rows.splitlines(keepends=True)
    data = head + b"\n# units: m\n" + b"".join(lines[:2500]) + b"\n# a pause\n\r\n" + b"".join(
        lines[2500:])
    chunks = (data[i:i + 70_001] for i in range(0, len(data), 70_001))  # lines cut anywhere
    r = client.post("/v1/recordings?format=sensor-csv", content=chunks)
    assert r.status_code == 201, r.text
    assert r.json()["summary"]["frames"] == 5000


def test_multipart_upload(client: TestClient) -> None:
    data = sensor_csv(frames=4)
    r = client.post("/v1/recordings", files={"file": ("walk.csv", data, "text/csv")},
                    data={"note": "ignored"})
    assert r.status_code == 201, r.text
    rec = r.json()
    assert (rec["filename"], rec["content_type"], rec["size"]) == ("walk.csv", "text/csv",
                                                                   len(data))
    assert rec["summary"]["frames"] == 4


def test_multipart_without_file_field(client: TestClient) -> None:
    r = client.post("/v1/recordings", data={"other": "x"}, files={"nope": ("a", b"1")})
    assert assert_problem(r, 422)["field"] == "file"


def test_upload_limit_by_content_length_and_while_streaming(tmp_path: object) -> None:
    runtime = local_runtime(Settings(data_dir=tmp_path, max_upload_bytes=100,
                                      api_keys={"k": "t"}))
    app = create_app(runtime=runtime, kinds=FAKE_KINDS, housekeeping=False)
    with TestClient(app, headers={"Authorization": "Bearer k"}) as c:
        r = c.post("/v1/recordings", content=b"x" * 101)
        assert assert_problem(r, 413)["limit"] == 100

        def chunks() -> object:  # no Content-Length: counted while streaming
            for _ in range(10):
                yield b"y" * 30

        r = c.post("/v1/recordings", content=chunks())  # type: ignore[arg-type]
        assert_problem(r, 413)
    assert not list((runtime.settings.data_dir / "uploads").iterdir())
    assert runtime.store.recording_totals() == (0, 0)


def test_malformed_recording_is_refused_with_its_line(client: TestClient,
                                                      runtime: Runtime) -> None:
    bad = (b"time,pelvis.x,pelvis.y,pelvis.z,pelvis.qw,pelvis.qx,pelvis.qy,bogus.q\n"
           b"0,1,2,3,1,0,0,0\n")
    r = client.post("/v1/recordings", content=bad, params={"format": "sensor-csv"})
    body = assert_problem(r, 422)
    assert body["line"] == 1
    assert runtime.store.recording_totals() == (0, 0)
    r = client.post("/v1/recordings", content=b"\x00\x01garbage", params={"filename": "x.bin"})
    assert_problem(r, 422)
    r = client.post("/v1/recordings", content=b"", params={"format": "sensor-csv"})
    assert_problem(r, 422)


def test_unknown_format_parameter(client: TestClient) -> None:
    r = client.post("/v1/recordings", content=sensor_csv(), params={"format": "xls"})
    assert assert_problem(r, 422)["field"] == "format"


def test_list_paginates_and_delete(client: TestClient, runtime: Runtime) -> None:
    ids = [upload(client)["id"] for _ in range(5)]
    seen: list[str] = []
    cursor = None
    while True:
        page = client.get("/v1/recordings", params={"limit": 2, **(
            {"cursor": cursor} if cursor else {})}).json()
        seen += [r["id"] for r in page["items"]]
        cursor = page["next_cursor"]
        if cursor is None:
            break
    assert seen == ids[::-1]
    key = runtime.store.get_recording("alice", ids[0])
    assert key is not None
    assert runtime.artifacts.size(key.key) is not None
    assert client.delete(f"/v1/recordings/{ids[0]}").status_code == 204
    assert runtime.artifacts.size(key.key) is None
    assert_problem(client.get(f"/v1/recordings/{ids[0]}"), 404)
    assert_problem(client.delete(f"/v1/recordings/{ids[0]}"), 404)


# ---------------------------------------------------------------------------------- auth


def test_tenants_never_see_each_other(client: TestClient) -> None:
    rec = upload(client)
    job = submit(client, rec["id"])
    assert_problem(client.get(f"/v1/recordings/{rec['id']}", headers=AUTH_B), 404)
    assert_problem(client.get(f"/v1/jobs/{job['id']}", headers=AUTH_B), 404)
    assert_problem(client.post(f"/v1/jobs/{job['id']}/cancel", headers=AUTH_B), 404)
    assert client.get("/v1/jobs", headers=AUTH_B).json()["items"] == []
    assert client.get("/v1/recordings", headers=AUTH_B).json()["items"] == []
    r = client.post("/v1/jobs", headers=AUTH_B, json={"kind": "skeleton",
                                                       "recording_id": rec["id"]})
    assert assert_problem(r, 422)["field"] == "recording_id"


def test_missing_or_wrong_key(client: TestClient) -> None:
    r = client.get("/v1/jobs", headers={"Authorization": ""})
    assert_problem(r, 401)
    assert r.headers["www-authenticate"].startswith("Bearer")
    assert_problem(client.get("/v1/jobs", headers={"Authorization": "Bearer nope"}), 401)
    assert client.get("/healthz", headers={"Authorization": ""}).status_code == 200


@pytest.mark.anyio
async def test_without_keys_only_loopback_is_served(tmp_path: object) -> None:
    app = create_app(runtime=local_runtime(Settings(data_dir=tmp_path)), kinds=FAKE_KINDS,
                     housekeeping=False)
    for host, status in (("127.0.0.1", 200), ("::1", 200), ("10.1.2.3", 403)):
        transport = httpx.ASGITransport(app=app, client=(host, 1234))
        async with httpx.AsyncClient(transport=transport, base_url="http://t") as c:
            r = await c.get("/v1/jobs")
            assert r.status_code == status, (host, r.text)
    assert r.json()["type"].endswith("loopback-only")


@pytest.mark.anyio
async def test_metrics_access(tmp_path: object) -> None:
    async def scrape(settings: Settings, host: str, **headers: str) -> httpx.Response:
        app = create_app(runtime=local_runtime(settings), kinds=FAKE_KINDS,
                         housekeeping=False)
        transport = httpx.ASGITransport(app=app, client=(host, 1234))
        async with httpx.AsyncClient(transport=transport, base_url="http://t") as c:
            return await c.get("/metrics", headers=headers)

    # no API keys: loopback scrapers only, as for the API
    keyless = Settings(data_dir=tmp_path)
    assert (await scrape(keyless, "127.0.0.1")).status_code == 200
    r = await scrape(keyless, "10.1.2.3")
    assert r.status_code == 403
    assert r.json()["type"].endswith("loopback-only")
    # API keys: the scraper's network is trusted (no API key needed)
    keyed = Settings(data_dir=tmp_path, api_keys=KEYS)
    r = await scrape(keyed, "10.1.2.3")
    assert r.status_code == 200
    assert "bonefit_jobs" in r.text
    # a metrics token: required from everyone, loopback included; API keys do not open it
    guarded = Settings(data_dir=tmp_path, api_keys=KEYS, metrics_token="scrape-me")
    for host, headers in (("10.1.2.3", {}), ("127.0.0.1", {}),
                          ("10.1.2.3", {"Authorization": "Bearer wrong"}),
                          ("10.1.2.3", AUTH_A)):
        r = await scrape(guarded, host, **headers)
        assert r.status_code == 401, (host, headers)
        assert r.headers["content-type"] == "application/problem+json"
        assert "BONEFIT_METRICS_TOKEN" in r.json()["detail"]
    r = await scrape(guarded, "10.1.2.3", Authorization="Bearer scrape-me")
    assert r.status_code == 200


# ---------------------------------------------------------------------------------- jobs


def test_job_lifecycle(client: TestClient, runtime: Runtime, worker: Worker) -> None:
    rec = upload(client)
    r = client.post("/v1/jobs", json={"kind": "skeleton", "recording_id": rec["id"],
                                      "params": {"method": "reduced", "i0": 2}})
    assert r.status_code == 202
    job = r.json()
    assert r.headers["location"] == f"/v1/jobs/{job['id']}"
    assert (job["status"], job["attempts"], job["results"]) == ("queued", 0, {})
    assert job["params"]["method"] == "reduced"
    assert_problem(client.get(f"/v1/jobs/{job['id']}/result"), 409)
    assert drain(runtime, worker) == 1
    done = client.get(f"/v1/jobs/{job['id']}").json()
    assert done["status"] == "succeeded", done
    assert done["attempts"] == 1
    assert done["progress"]["fraction"] == 1.0
    assert done["started_at"]
    assert done["finished_at"]
    assert set(done["results"]) == {"json", "bvh", "csv"}
    for fmt, ctype in (("json", "application/json"), ("bvh", "application/x-bvh"),
                       ("csv", "text/csv; charset=utf-8")):
        r = client.get(done["results"][fmt])
        assert r.status_code == 200
        assert r.headers["content-type"] == ctype
        assert r.headers["content-disposition"] == (
            f'attachment; filename="skeleton-{job["id"]}.{fmt}"')
        assert int(r.headers["content-length"]) == len(r.content)  # clients can show progress
        assert r.text.startswith(fmt)
    assert_problem(client.get(f"/v1/jobs/{job['id']}/result", params={"format": "xml"}), 422)


def test_params_are_validated_per_kind(client: TestClient) -> None:
    rec = upload(client)
    cases = [
        ({"kind": "skeleton", "recording_id": rec["id"], "params": {"method": "magic"}},
         "params.method"),
        ({"kind": "skeleton", "recording_id": rec["id"], "params": {"left_foot": "x"}},
         "params.left_foot"),
        ({"kind": "skeleton", "recording_id": rec["id"], "params": {"i0": -1}}, "params.i0"),
        ({"kind": "translation", "recording_id": rec["id"], "params": {"method": "llsf"}},
         "params.method"),
        ({"kind": "nope", "recording_id": rec["id"]}, "kind"),
        ({"kind": "skeleton"}, "recording_id"),
        ({"kind": "skeleton", "recording_id": rec["id"], "inputs": {"accelerations": "x"}},
         "inputs.accelerations"),
    ]
    for body, field in cases:
        problem = assert_problem(client.post("/v1/jobs", json=body), 422)
        assert str(problem["field"]).startswith(field.split(".")[0]), (body, problem)
        assert field in json.dumps(problem), (body, problem)
    r = client.post("/v1/jobs", content=b"{not json", headers={"content-type": "application/json"})
    assert_problem(r, 422)


def test_translation_inputs_must_exist(client: TestClient) -> None:
    rec = upload(client)
    r = client.post("/v1/jobs", json={"kind": "translation", "recording_id": rec["id"],
                                      "inputs": {"accelerations": "0000missing"}})
    assert assert_problem(r, 422)["field"] == "inputs.accelerations"
    acc = upload(client, b"time,LeftFoot.ax,LeftFoot.ay,LeftFoot.az\n0,1,2,3\n",
                 format="accelerations-csv")
    assert acc["format"] == "accelerations-csv"
    assert acc["summary"]["frames"] == 1
    r = client.post("/v1/jobs", json={"kind": "translation", "recording_id": rec["id"],
                                      "inputs": {"accelerations": acc["id"]}})
    assert r.status_code == 202
    assert r.json()["inputs"] == {"accelerations": acc["id"]}


def test_idempotency_key(client: TestClient, runtime: Runtime) -> None:
    rec = upload(client)
    body = {"kind": "skeleton", "recording_id": rec["id"]}
    first = client.post("/v1/jobs", json=body, headers={"Idempotency-Key": "k1"})
    again = client.post("/v1/jobs", json=body, headers={"Idempotency-Key": "k1"})
    assert first.status_code == again.status_code == 202
    assert first.json()["id"] == again.json()["id"]
    assert runtime.queue.depth() == 1
    other = client.post("/v1/jobs", json={**body, "params": {"method": "gdke"}},
                        headers={"Idempotency-Key": "k1"})
    assert assert_problem(other, 422)["field"] == "Idempotency-Key"
    assert client.post("/v1/jobs", json=body).json()["id"] != first.json()["id"]


def test_etag_and_not_modified(client: TestClient, runtime: Runtime, worker: Worker) -> None:
    job = submit(client, upload(client)["id"])
    r = client.get(f"/v1/jobs/{job['id']}")
    etag = r.headers["etag"]
    assert client.get(f"/v1/jobs/{job['id']}", headers={"If-None-Match": etag}).status_code == 304
    drain(runtime, worker)
    r = client.get(f"/v1/jobs/{job['id']}", headers={"If-None-Match": etag})
    assert r.status_code == 200
    assert r.headers["etag"] != etag


def test_list_jobs_filters_and_paginates(client: TestClient, runtime: Runtime,
                                         worker: Worker) -> None:
    rec = upload(client)
    ids = [submit(client, rec["id"])["id"] for _ in range(3)]
    client.post(f"/v1/jobs/{ids[0]}/cancel")
    assert [j["id"] for j in client.get("/v1/jobs", params={"status": "cancelled"}).json()[
        "items"]] == [ids[0]]
    page = client.get("/v1/jobs", params={"limit": 2}).json()
    assert [j["id"] for j in page["items"]] == ids[:0:-1]
    rest = client.get("/v1/jobs", params={"limit": 2, "cursor": page["next_cursor"]}).json()
    assert [j["id"] for j in rest["items"]] == [ids[0]]
    assert rest["next_cursor"] is None
    assert client.get("/v1/jobs", params={"kind": "translation"}).json()["items"] == []
    assert_problem(client.get("/v1/jobs", params={"status": "weird"}), 422)


def test_cancel(client: TestClient, runtime: Runtime, worker: Worker) -> None:
    rec = upload(client)
    job = submit(client, rec["id"])
    r = client.post(f"/v1/jobs/{job['id']}/cancel")
    assert r.status_code == 202
    assert r.json()["status"] == "cancelled"
    assert client.post(f"/v1/jobs/{job['id']}/cancel").status_code == 202  # idempotent
    drain(runtime, worker)  # the worker skips the cancelled job
    assert client.get(f"/v1/jobs/{job['id']}").json()["status"] == "cancelled"
    done = submit(client, rec["id"])
    drain(runtime, worker)
    assert assert_problem(client.post(f"/v1/jobs/{done['id']}/cancel"), 409)[
        "job_status"] == "succeeded"


def test_failed_job_names_the_cause_and_keeps_the_recording(client: TestClient,
                                                            runtime: Runtime,
                                                            worker: Worker) -> None:
    rec = upload(client, sensor_csv() + b"BAD\n")
    job = submit(client, rec["id"])
    drain(runtime, worker)
    failed = client.get(f"/v1/jobs/{job['id']}").json()
    assert failed["status"] == "failed"
    assert failed["error"]["status"] == 422
    assert (failed["error"]["line"], failed["error"]["column"]) == (3, 2)
    assert failed["error"]["field"] == "pelvis.x"
    assert failed["error"]["instance"] == f"/v1/jobs/{job['id']}"
    assert client.get(f"/v1/recordings/{rec['id']}").status_code == 200
    assert_problem(client.get(f"/v1/jobs/{job['id']}/result"), 409)


def test_events_stream_until_the_end(client: TestClient, runtime: Runtime,
                                     worker: Worker) -> None:
    job = submit(client, upload(client)["id"])
    drain(runtime, worker)
    with client.stream("GET", f"/v1/jobs/{job['id']}/events") as r:
        assert r.headers["content-type"].startswith("text/event-stream")
        text = "".join(r.iter_text())
    events = [block for block in text.split("\n\n") if block.strip()]
    names = [line.split(": ", 1)[1] for block in events for line in block.splitlines()
             if line.startswith("event: ")]
    assert names[0] == "status"
    assert names[-1] == "end"
    last = json.loads(events[-2].split("data: ", 1)[1])
    assert last["status"] == "succeeded"


def test_events_resume_after_the_last_event_id(client: TestClient, runtime: Runtime,
                                               worker: Worker) -> None:
    job = submit(client, upload(client)["id"])
    drain(runtime, worker)
    url = f"/v1/jobs/{job['id']}/events"
    with client.stream("GET", url) as r:
        first = "".join(r.iter_text())
    ids = [line.split(": ", 1)[1] for line in first.splitlines() if line.startswith("id: ")]
    assert ids
    # a client that saw the final version gets only the end; one with an older (or a
    # malformed) id gets the job again
    with client.stream("GET", url, headers={"Last-Event-ID": ids[-1]}) as r:
        resumed = "".join(r.iter_text())
    assert [line for line in resumed.splitlines() if line.startswith("event: ")] == [
        "event: end"]
    for stale in ("0", "x"):
        with client.stream("GET", url, headers={"Last-Event-ID": stale}) as r:
            again = "".join(r.iter_text())
        assert f"id: {ids[-1]}" in again
        assert again.splitlines()[1] == "event: status"


# -------------------------------------------------------------------------- problems/ops


def test_every_error_is_a_problem(client: TestClient) -> None:
    body = assert_problem(client.get("/v1/nowhere"), 404)
    assert body["type"] == "about:blank"
    assert_problem(client.put("/v1/jobs"), 405)
    assert_problem(client.get("/v1/jobs/unknown"), 404)


def test_internal_errors_do_not_leak(runtime: Runtime,
                                    caplog: pytest.LogCaptureFixture) -> None:
    def broken(*args: object, **kwargs: object) -> None:
        raise RuntimeError("secret traceback detail")

    runtime.store.list_jobs = broken  # type: ignore[method-assign]
    app = create_app(runtime=runtime, kinds=FAKE_KINDS, housekeeping=False)
    with caplog.at_level(logging.ERROR), TestClient(
            app, raise_server_exceptions=False, headers={"Authorization": "Bearer key-a"}) as c:
        first, second = c.get("/v1/jobs"), c.get("/v1/jobs")
    body = assert_problem(first, 500)
    assert "secret" not in first.text
    assert "Traceback" not in first.text
    assert body["title"] == "Internal server error"
    # an id per error, in the answer and in the log line that carries the traceback
    ids = [body["error_id"], second.json()["error_id"]]
    assert ids[0] != ids[1]
    assert ids[0] in body["detail"]
    logged = [r for r in caplog.records if r.exc_info and ids[0] in r.getMessage()]
    assert len(logged) == 1


def test_health_ready_and_metrics(client: TestClient, runtime: Runtime, worker: Worker) -> None:
    assert client.get("/healthz").json() == {"status": "ok"}
    worker.beat()  # what its serve loop does
    assert client.get("/readyz").json()["checks"] == {"database": "ok", "queue": "ok",
                                                      "storage": "ok", "disk": "ok",
                                                      "workers": "ok"}
    job = submit(client, upload(client)["id"])
    submit(client, upload(client)["id"])
    drain(runtime, worker)
    submit(client, upload(client)["id"])
    text = client.get("/metrics").text
    assert 'bonefit_jobs{kind="skeleton",status="succeeded"} 2.0' in text
    assert 'bonefit_jobs{kind="skeleton",status="queued"} 1.0' in text
    assert 'bonefit_job_duration_seconds_count{kind="skeleton"} 2.0' in text
    assert "bonefit_queue_depth 1.0" in text
    assert "bonefit_recordings 3.0" in text
    assert f"bonefit_upload_bytes_total {3.0 * len(sensor_csv())}" in text
    assert job


def test_readyz_reports_what_is_down(client: TestClient, runtime: Runtime,
                                     worker: Worker) -> None:
    def down() -> None:
        raise ConnectionError("no")

    worker.beat()
    runtime.queue.ping = down  # type: ignore[method-assign]
    body = assert_problem(client.get("/readyz"), 503)
    assert body["checks"] == {"database": "ok", "queue": "unavailable: ConnectionError",
                              "storage": "ok", "disk": "ok", "workers": "ok"}
    assert body["failed"] == ["queue"]


def test_readyz_names_the_drivers_error_of_an_unreachable_back_end(
        client: TestClient, runtime: Runtime, worker: Worker) -> None:
    worker.beat()
    runtime.queue = open_queue("redis://127.0.0.1:1/0")  # nothing listens on port 1
    body = assert_problem(client.get("/readyz"), 503)
    assert body["checks"]["queue"] == "unavailable: ConnectionError"  # redis's, not ours
    assert body["failed"] == ["queue"]


def test_openapi_documents_the_kinds(client: TestClient) -> None:
    schema = client.get("/openapi.json").json()
    names = set(schema["components"]["schemas"])
    assert {"SkeletonJobCreate", "TranslationJobCreate", "SkeletonParams"} <= names
    assert client.get("/docs").status_code == 200


@pytest.mark.parametrize("delay", [0.0])
def test_created_at_is_recent(client: TestClient, delay: float) -> None:
    rec = upload(client)
    from datetime import datetime
    created = datetime.fromisoformat(rec["created_at"].replace("Z", "+00:00")).timestamp()
    assert abs(created - time.time()) < 60 + delay


def test_odd_names_and_ids_are_harmless(client: TestClient, runtime: Runtime) -> None:
    rec = upload(client, filename="../../etc/pass\x00wd.\x01csv")
    assert rec["filename"] == "passwd.csv"
    stored = runtime.store.get_recording("alice", rec["id"])
    assert stored is not None
    assert stored.key.startswith("alice/recordings/")
    assert upload(client, filename="..")["filename"] is None
    r = client.post("/v1/recordings", content=b"\x00\x01", params={"filename": "mine.bin"})
    assert "mine.bin" in assert_problem(r, 422)["detail"]  # named as the client named it
    assert_problem(client.get("/v1/jobs/bad%00id"), 404)
    assert_problem(client.delete("/v1/recordings/..%2F..%2Fx"), 404)
    assert_problem(client.get("/v1/jobs", params={"kind": "a\x00b"}), 422)
    assert_problem(client.get("/v1/jobs", params={"cursor": "ZZ"}), 422)


def test_a_database_outage_is_a_503(runtime: Runtime) -> None:
    import sqlalchemy.exc

    def down(*args: object, **kwargs: object) -> None:
        raise sqlalchemy.exc.OperationalError("SELECT 1", {}, Exception("connection refused"))

    runtime.store.engine.connect = down  # type: ignore[attr-defined,method-assign]
    app = create_app(runtime=runtime, kinds=FAKE_KINDS, housekeeping=False)
    with TestClient(app, raise_server_exceptions=False,
                    headers={"Authorization": "Bearer key-a"}) as c:
        r = c.get("/v1/jobs/abc")
    assert_problem(r, 503)
    assert r.headers["retry-after"] == "5"
    assert "refused" not in r.text


def test_non_finite_numbers_and_broken_forms_are_refused(client: TestClient) -> None:
    rec = upload(client)
    body = json.dumps({"kind": "skeleton", "recording_id": rec["id"],
                       "params": {"fps": float("inf")}})  # json writes Infinity
    r = client.post("/v1/jobs", content=body, headers={"content-type": "application/json"})
    assert assert_problem(r, 422)["field"] == "params.fps"
    r = client.post("/v1/recordings", content=b"--xyz\r\nContent-Disposition: form-data; "
                    b'name="file"\r\n\r\nabc', headers={"content-type": "multipart/form-data; "
                                                                         "boundary=xyz"})
    assert assert_problem(r, 400)["title"] == "Bad multipart body"
    r = client.post("/v1/recordings", content=b"abc",
                    headers={"content-type": "multipart/form-data"})
    assert_problem(r, 400)


def test_large_json_bodies_are_refused_early(client: TestClient) -> None:
    r = client.post("/v1/jobs", content=b"{" + b" " * (1024 * 1024 + 1) + b"}",
                    headers={"content-type": "application/json"})
    assert_problem(r, 413)


def test_abandoned_upload_spools_are_cleaned(tmp_path: Path) -> None:
    import os

    from bonefit.service.uploads import clean_spool

    old, fresh = tmp_path / "old", tmp_path / "fresh"
    for d in (old, fresh):
        d.mkdir()
        (d / "upload.part").write_bytes(b"x")
    for p in (old, old / "upload.part"):
        os.utime(p, (time.time() - 7200, time.time() - 7200))
    assert clean_spool(tmp_path) == 1
    assert [p.name for p in tmp_path.iterdir()] == ["fresh"]
    assert clean_spool(tmp_path / "missing") == 0
