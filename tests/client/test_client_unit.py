"""The client without a server: retries, problems, event streams, typed results, batch
parameters, and what importing it loads."""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from bonefit.client import (
    AsyncClient,
    Client,
    ProblemError,
    SkeletonResult,
    TranslationResult,
    result_from_dict,
)
from bonefit.client.batch import collect_takes, parse_params, summary
from bonefit.client.sse import events
from bonefit.client.transport import RetryPolicy, retry_after
from bonefit.estimation import results
from bonefit.estimation.errors import InputError
from bonefit.estimation.io import offsets_to_dict

ROOT = Path(__file__).resolve().parents[2]
JOB = {"id": "j1", "kind": "skeleton", "status": "queued", "recording_id": "r1", "params": {},
       "inputs": {}, "progress": {"fraction": 0.0, "stage": "queued", "message": None},
       "created_at": "2026-01-01T00:00:00Z", "started_at": None, "finished_at": None,
       "attempts": 0, "worker": None, "error": None, "results": {}}


class FlakyServer:
    """A fake API: POST /v1/jobs fails ``failures`` times (each a callable making the failure)
    before it answers; jobs are stored by Idempotency-Key like the real server does."""

    def __init__(self, failures: list[Callable[[httpx.Request], httpx.Response]]) -> None:
        self.failures = list(failures)
        self.keys: list[str] = []
        self.jobs: dict[str, dict[str, Any]] = {}

    def __call__(self, request: httpx.Request) -> httpx.Response:
        key = request.headers.get("idempotency-key", "")
        self.keys.append(key)
        if key not in self.jobs:
            self.jobs[key] = {**JOB, "id": f"job{len(self.jobs) + 1}"}  # the work is done...
        if self.failures:
            return self.failures.pop(0)(request)  # ...but the answer is lost
        return httpx.Response(202, json=self.jobs[key])


def reset(request: httpx.Request) -> httpx.Response:
    raise httpx.ReadError("connection reset by peer", request=request)


def unavailable(request: httpx.Request) -> httpx.Response:
    return httpx.Response(503, json={"type": "about:blank", "title": "Unavailable",
                                     "status": 503, "detail": "try later"})


def throttled(request: httpx.Request) -> httpx.Response:
    return httpx.Response(429, headers={"Retry-After": "7"}, text="slow down")


def test_transient_failures_are_retried_with_one_idempotency_key() -> None:
    server = FlakyServer([reset, unavailable, throttled,
                          lambda r: httpx.Response(502, text="bad gateway"),
                          lambda r: httpx.Response(504, text="gateway timeout")])
    slept: list[float] = []
    with Client("http://test", transport=httpx.MockTransport(server), sleep=slept.append) as c:
        job = c.submit("skeleton", "r1")
    assert job.id == "job1"
    assert len(server.keys) == 6, server.keys
    assert len(set(server.keys)) == 1, server.keys
    assert len(server.jobs) == 1  # no second job
    assert slept[2] == 7.0  # Retry-After obeyed
    assert all(0 < s <= 8.0 * 1.25 for s in slept)


def test_each_submission_has_its_own_key() -> None:
    server = FlakyServer([])
    with Client("http://test", transport=httpx.MockTransport(server)) as c:
        c.submit("skeleton", "r1")
        c.submit("skeleton", "r1")
    assert len(set(server.keys)) == 2


def test_retries_give_up_after_the_policy_attempts() -> None:
    server = FlakyServer([unavailable] * 10)
    with Client("http://test", transport=httpx.MockTransport(server), sleep=lambda s: None,
                retry=RetryPolicy(attempts=3)) as c, pytest.raises(ProblemError) as info:
        c.submit("skeleton", "r1")
    assert info.value.status == 503
    assert info.value.detail == "try later"
    assert len(server.keys) == 3


def test_a_problem_becomes_one_exception_with_the_document() -> None:
    problem = {"type": "urn:bonefit:problem:malformed-input", "title": "Malformed input",
               "status": 422, "detail": "unknown column 'foo'", "field": "foo", "line": 1}

    def answer(request: httpx.Request) -> httpx.Response:
        return httpx.Response(422, json=problem,
                              headers={"content-type": "application/problem+json"})

    with Client("http://test", transport=httpx.MockTransport(answer)) as c, \
            pytest.raises(ProblemError) as info:
        c.upload(b"time,foo\n1,2\n", filename="bad.csv")
    assert info.value.problem == problem
    assert "unknown column 'foo'" in str(info.value)
    assert "line 1" in str(info.value)


def test_the_async_client_retries_too() -> None:
    server = FlakyServer([reset, unavailable])

    async def sleep(seconds: float) -> None:
        return None

    async def main() -> str:
        async with AsyncClient("http://test", transport=httpx.MockTransport(server),
                               sleep=sleep) as c:
            return (await c.submit("skeleton", "r1")).id

    assert asyncio.run(main()) == "job1"
    assert len(set(server.keys)) == 1
    assert len(server.jobs) == 1


def test_wait_reconnects_with_last_event_id() -> None:
    seen: list[str | None] = []
    done = {**JOB, "status": "succeeded", "progress": {"fraction": 1.0, "stage": "done",
                                                        "message": None}}

    def answer(request: httpx.Request) -> httpx.Response:
        if request.url.path.endswith("/events"):
            seen.append(request.headers.get("last-event-id"))
            if len(seen) == 1:  # the stream drops after one event
                return httpx.Response(200, text=f"id: 3\nevent: status\ndata: {json.dumps(JOB)}"
                                      "\n\n", headers={"content-type": "text/event-stream"})
            if len(seen) == 2:
                return httpx.Response(503, headers={"Retry-After": "0"})
            return httpx.Response(200, text=f"id: 5\nevent: status\ndata: {json.dumps(done)}\n\n"
                                  "event: end\ndata: {}\n\n")
        return httpx.Response(200, json=done)

    states: list[str] = []
    with Client("http://test", transport=httpx.MockTransport(answer), sleep=lambda s: None) as c:
        job = c.wait("j1", progress=lambda j: states.append(j.status))
    assert job.status == "succeeded"
    assert seen == [None, "3", "3"]
    assert states == ["queued", "succeeded"]


def test_event_stream_parsing() -> None:
    lines = [": keep-alive", "", "id: 7", "event: progress", "data: {\"a\":", "data: 1}", "",
             "event: end", "data: {}", ""]
    got = list(events(lines))
    assert [(e.event, e.data, e.id) for e in got] == [("progress", '{"a":\n1}', "7"),
                                                      ("end", "{}", "7")]


def test_retry_after_as_an_http_date() -> None:
    response = httpx.Response(429, headers={"Retry-After": "Wed, 21 Oct 2015 07:28:00 GMT"})
    assert retry_after(response) == 0.0
    assert retry_after(httpx.Response(429, headers={"Retry-After": "12"})) == 12.0
    assert retry_after(httpx.Response(503)) is None


def test_typed_skeleton_result_is_the_librarys() -> None:
    doc = {"kind": "skeleton", "method": "auto", "fps": 60.0, "frames": 2, "units": "m",
           "joints": {"root": [[0, 1, 0], [0, 1.1, 0]], "l_knee": [[0.1, 0.5, 0], [0.1, 0.5, 0]]},
           "offsets": {"l_knee": {"sensor": "l_thigh", "local": [0, -0.4, 0]}},
           "bone_lengths": {"l_thigh": 0.42},
           "orientations": {"pelvis": [[1, 0, 0, 0], [1, 0, 0, 0]]},
           "quality": {"l_knee": {"reliability": "data", "data_sd_m": 0.002, "hinge": True,
                                  "rms_residual_m": None, "singular_value_ratio": 0.1}},
           "warnings": ["w"], "timings": {"read_s": 0.1}}
    result = result_from_dict(doc)
    assert type(result) is results.SkeletonResult  # one class: the library's
    assert isinstance(result, SkeletonResult)
    assert result.n_frames == 2
    assert result.joints["root"].shape == (2, 3)
    assert result.joints["root"][1, 1] == 1.1
    assert result.orientations["pelvis"].shape == (2, 4)
    assert result.quality["l_knee"].hinge is True
    assert result.quality["l_knee"].rms_residual_m is None
    assert result.quality["l_knee"]["singular_value_ratio"] == 0.1
    assert dict(result.quality["l_knee"]) == doc["quality"]["l_knee"]  # every member kept
    np.testing.assert_array_equal(result.offsets["l_knee"].local, [0.0, -0.4, 0.0])
    # the calibration of this result, as the `offsets` parameter of the next jobs
    param = offsets_to_dict(result.offsets)
    assert json.loads(json.dumps(param)) == {"l_knee": {"sensor": "l_thigh",
                                                        "local": [0.0, -0.4, 0.0]}}


def test_typed_translation_result_and_bad_documents() -> None:
    doc = {"kind": "translation", "method": "contact", "fps": 100.0, "frames": 2, "units": "m",
           "up": "+Y", "root_joint": "Hips", "root": [[0, 1, 0], [0.01, 1, 0]],
           "translation": [[0, 0, 0], [0.01, 0, 0]], "floor": [0.0, 0.0],
           "contacts": ["left", "both"], "quality": {"closure_cm": None}, "timings": {},
           "time": [0.0, 0.01]}
    result = result_from_dict(doc)
    assert type(result) is results.TranslationResult
    assert isinstance(result, TranslationResult)
    assert result.n_frames == 2
    np.testing.assert_array_equal(result.root[:, 0], [0.0, 0.01])
    assert list(result.contacts) == ["left", "both"]
    assert result.positions is None  # not in the document
    assert result.quality == {"closure_cm": None}
    for bad, field in (({**doc, "root": [[0, 1], [0, 1]]}, "root"),
                       ({**doc, "contacts": ["left"]}, "contacts"),
                       ({**doc, "floor": [0.0]}, "floor"),
                       ({**doc, "units": "cm"}, "units"),
                       ({"kind": "other"}, "kind")):
        with pytest.raises(ValueError, match=field) as info:  # InputError is a ValueError
            result_from_dict(bad)
        assert isinstance(info.value, InputError)
        assert info.value.field == field


def test_batch_params_and_names(tmp_path: Path) -> None:
    assert parse_params(["method=llsf", "fps=120", "up=[0,0,1]", "smooth=true"]) == {
        "method": "llsf", "fps": 120, "up": [0, 0, 1], "smooth": True}
    with pytest.raises(ValueError, match="expected KEY=VALUE"):
        parse_params(["fps"])
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    for d in ("a", "b"):
        (tmp_path / d / "walk.csv").write_text(d)
    takes = collect_takes([tmp_path / "a" / "walk.csv", tmp_path / "b" / "walk.csv"])
    assert [t.name for t in takes] == ["walk", "walk-2"]
    assert takes[0].sha256 != takes[1].sha256
    assert "0 done, 0 already done, 0 failed" in summary([])


def test_importing_the_client_loads_no_service_stack_and_no_scipy() -> None:
    # run in a new interpreter: this one has loaded everything already
    code = ("import sys, bonefit.client\n"
            "heavy = {'fastapi', 'starlette', 'pydantic', 'sqlalchemy', 'scipy', 'uvicorn'}\n"
            "loaded = heavy & {m.split('.')[0] for m in sys.modules}\n"
            "loaded |= {m for m in sys.modules if m.startswith('bonefit.service')}\n"
            "assert not loaded, sorted(loaded)\n"
            "from bonefit.estimation import results\n"
            "assert bonefit.client.SkeletonResult is results.SkeletonResult\n"
            "assert bonefit.client.TranslationResult is results.TranslationResult\n"
            "assert 'scipy' not in sys.modules\n")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def test_the_client_extra_is_light() -> None:
    import tomllib

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    # the base dependencies and the client extra
    names = {req.split(">")[0].split("[")[0].strip()
             for req in project["dependencies"] + project["optional-dependencies"]["client"]}
    assert names == {"httpx", "numpy"}
