"""Job params are validated at submission; the worker classes errors as the input's (422,
one attempt), the machine's (retried) or over the job's memory limit (507)."""

from __future__ import annotations

import dataclasses
import logging
import math
import resource
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bonefit.estimation.errors import InputError
from bonefit.estimation.params import CONTACT_OPTION_RANGES
from bonefit.estimation.progress import Progress
from bonefit.estimation.recording import SensorRecording
from bonefit.estimation.translation import ContactOptions
from bonefit.service.kinds import (
    ContactOptionsIn,
    Hachaj2018OptionsIn,
    Input,
    Kind,
    SkeletonParams,
    TranslationParams,
    default_kinds,
)
from bonefit.service.runtime import Runtime
from bonefit.service.worker import Worker
from tests.service.helpers import TestClient, drain, submit, upload

PROBLEM = "application/problem+json"


def post_job(client: TestClient, kind: str, params: dict[str, Any]) -> Any:
    rec = upload(client)
    return client.post("/v1/jobs", json={"kind": kind, "recording_id": rec["id"],
                                         "params": params})


def refused(r: Any, field: str) -> dict[str, Any]:
    assert r.status_code == 422, r.text
    assert r.headers["content-type"] == PROBLEM
    body: dict[str, Any] = r.json()
    assert body["field"] == field, body
    return body


# ----------------------------------------------------------------- validation at POST


def test_a_denormal_frame_rate_is_refused_at_submission(client: TestClient) -> None:
    body = refused(post_job(client, "skeleton", {"fps": 5e-324}), "params.fps")
    assert "greater than or equal to 1" in body["detail"]
    refused(post_job(client, "skeleton", {"fps": 1e9}), "params.fps")


@pytest.mark.parametrize("key", ["method", "recording", "progress", "bogus"])
def test_option_keys_that_are_not_the_methods_options_are_refused(client: TestClient,
                                                                  key: str) -> None:
    for method in ("contact", "hachaj2018"):
        r = post_job(client, "translation", {"method": method, "options": {key: 1}})
        refused(r, f"params.options.{key}")


@pytest.mark.parametrize("window", [0, -5, 2.5, 1e9, True, "x"])
def test_hachaj2018_window_must_be_a_sane_number_of_samples(client: TestClient,
                                                            window: Any) -> None:
    r = post_job(client, "translation", {"method": "hachaj2018", "options": {"window": window}})
    refused(r, "params.options.window")


@pytest.mark.parametrize("eps", ["x", 0, -0.1, 5.0])
def test_hachaj2018_eps_must_be_a_positive_length(client: TestClient, eps: Any) -> None:
    r = post_job(client, "translation", {"method": "hachaj2018", "options": {"eps": eps}})
    refused(r, "params.options.eps")


def test_options_are_validated_by_the_model_of_the_method(client: TestClient) -> None:
    refused(post_job(client, "translation", {"options": {"window": 50}}),
            "params.options.window")  # a hachaj2018 option, default method contact
    refused(post_job(client, "translation", {"method": "hachaj2018",
                                             "options": {"switch_cost": 2}}),
            "params.options.switch_cost")
    refused(post_job(client, "translation", {"options": {"switch_cost": -1}}),
            "params.options.switch_cost")
    refused(post_job(client, "translation", {"options": {"use_toes": "maybe"}}),
            "params.options.use_toes")


@pytest.mark.parametrize(("params", "field"), [
    ({"up": [0, 0, 0]}, "params.up"), ({"w_s": -1}, "params.w_s"),
    ({"anthropometry": {"torso": 1, "thigh": 0}}, "params.anthropometry.thigh"),
    ({"anthropometry": {"femur": 1}}, "params.anthropometry.femur.[key]"),
    ({"anthropometry": "nasa"}, "params.anthropometry"), ({"smooth": "yes"}, "params.smooth")])
def test_skeleton_params_are_bounded(client: TestClient, params: dict[str, Any],
                                     field: str) -> None:
    refused(post_job(client, "skeleton", params), field)


def test_valid_options_reach_the_run_function_typed(client: TestClient,
                                                    runtime: Runtime) -> None:
    seen: list[Any] = []

    def run(inputs: Mapping[str, Input], params: Any, progress: Progress,
            outdir: Path) -> dict[str, Path]:
        seen.append(params)
        (outdir / "r.json").write_text("{}")
        return {"json": outdir / "r.json"}

    r = post_job(client, "translation", {"method": "hachaj2018",
                                         "options": {"window": 50.0, "eps": 0.1}})
    assert r.status_code == 202, r.text
    assert r.json()["params"]["options"] == {"window": 50, "eps": 0.1}
    drain(runtime, Worker(runtime, {"translation": Kind("translation", TranslationParams,
                                                        run)}))
    assert seen[0].options == Hachaj2018OptionsIn(window=50, eps=0.1)


def test_contact_options_mirror_the_library() -> None:
    library = {f.name: f.default for f in dataclasses.fields(ContactOptions)}
    service = {name: f.default for name, f in ContactOptionsIn.model_fields.items()}
    assert service == library
    for name, (low, high, low_open) in CONTACT_OPTION_RANGES.items():
        schema = ContactOptionsIn.model_json_schema()["properties"][name]
        bounds = next((s for s in schema.get("anyOf", [schema]) if "maximum" in s), schema)
        assert bounds["maximum"] == high
        assert bounds["exclusiveMinimum" if low_open else "minimum"] == low


# ----------------------------------------------------------------- the worker's classes


def kind_running(body: Callable[[], None]) -> dict[str, Kind]:
    def run(inputs: Mapping[str, Input], params: Any, progress: Progress,
            outdir: Path) -> dict[str, Path]:
        body()
        (outdir / "r.json").write_text("{}")
        return {"json": outdir / "r.json"}

    return {"skeleton": Kind("skeleton", SkeletonParams, run)}


def test_a_reader_error_fails_the_real_skeleton_job_once_naming_line_and_column(
        client: TestClient, runtime: Runtime, monkeypatch: pytest.MonkeyPatch) -> None:
    import bonefit.estimation.io.sensors

    def bad(*args: object, **kwargs: object) -> SensorRecording:
        raise InputError("pelvis.x is 1e308: not a position", line=7, column=3,
                         field="pelvis.x")

    monkeypatch.setattr(bonefit.estimation.io.sensors, "read_recording", bad)
    job = submit(client, upload(client)["id"])
    assert drain(runtime, Worker(runtime, default_kinds())) == 1
    failed = client.get(f"/v1/jobs/{job['id']}").json()
    assert (failed["status"], failed["attempts"]) == ("failed", 1)
    error = failed["error"]
    assert (error["status"], error["line"], error["column"]) == (422, 7, 3)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # overflow warnings, as in production
def test_a_1e308_cell_fails_the_real_skeleton_job_once_as_the_inputs_fault(
        client: TestClient, runtime: Runtime, monkeypatch: pytest.MonkeyPatch,
        caplog: pytest.LogCaptureFixture) -> None:
    """Were the reader to let a huge value through, scipy's cho_factor raises ValueError
    ("array must not contain infs"): the input's fault, not an internal error retried."""
    import bonefit.estimation.io.sensors
    from bonefit.estimation.simulate.sensors import example_motion, simulate_sensors

    rec, _ = simulate_sensors(example_motion(), units_m=0.01, seed=0)
    positions = rec.positions.copy()
    positions[5, 0, 0] = 1e308
    huge = dataclasses.replace(rec, positions=positions)
    monkeypatch.setattr(bonefit.estimation.io.sensors, "read_recording",
                        lambda *args, **kwargs: huge)
    job = submit(client, upload(client)["id"])
    with caplog.at_level(logging.ERROR, logger="bonefit.worker"):
        assert drain(runtime, Worker(runtime, default_kinds())) == 1
    failed = client.get(f"/v1/jobs/{job['id']}").json()
    assert (failed["status"], failed["attempts"]) == ("failed", 1)
    assert failed["error"]["status"] == 422
    if "error_id" in failed["error"]:  # a numerical error no check caught: logged
        assert any(failed["error"]["error_id"] in r.getMessage() and r.exc_info
                   for r in caplog.records)


@pytest.mark.parametrize("error", [ValueError("array must not contain infs or NaNs"),
                                   FloatingPointError("overflow"),
                                   ZeroDivisionError("float division by zero")])
def test_a_numerical_error_is_the_inputs_fault_and_not_retried(
        client: TestClient, runtime: Runtime, caplog: pytest.LogCaptureFixture,
        error: Exception) -> None:
    def body() -> None:
        raise error

    job = submit(client, upload(client)["id"])
    with caplog.at_level(logging.ERROR, logger="bonefit.worker"):
        assert drain(runtime, Worker(runtime, kind_running(body))) == 1
    failed = client.get(f"/v1/jobs/{job['id']}").json()
    assert (failed["status"], failed["attempts"]) == ("failed", 1)
    problem = failed["error"]
    assert (problem["status"], problem["type"]) == (422, "urn:bonefit:problem:estimation-error")
    assert type(error).__name__ in problem["detail"]
    logged = [r for r in caplog.records if problem["error_id"] in r.getMessage()]
    assert logged
    assert logged[0].exc_info is not None


def test_an_internal_error_is_retried_and_its_final_problem_carries_the_logged_id(
        client: TestClient, runtime: Runtime, caplog: pytest.LogCaptureFixture) -> None:
    def body() -> None:
        raise KeyError("a bug")

    job = submit(client, upload(client)["id"])
    with caplog.at_level(logging.ERROR, logger="bonefit.worker"):
        assert drain(runtime, Worker(runtime, kind_running(body))) == 2  # max_attempts
    failed = client.get(f"/v1/jobs/{job['id']}").json()
    assert (failed["status"], failed["attempts"]) == ("failed", 2)
    problem = failed["error"]
    assert (problem["status"], problem["type"]) == (500, "urn:bonefit:problem:internal")
    assert problem["error_id"] in problem["detail"]
    assert "a bug" not in str(problem)
    crashes = [r for r in caplog.records if "[error id " in r.getMessage()]
    assert len(crashes) == 2
    assert problem["error_id"] in crashes[-1].getMessage()
    assert crashes[-1].exc_info is not None


def test_invalid_stored_params_fail_the_job_naming_the_field(client: TestClient,
                                                             runtime: Runtime,
                                                             worker: Worker) -> None:
    job = submit(client, upload(client)["id"])
    runtime.store.update_job(job["id"], {"params": {"fps": math.inf}}, expect={})
    drain(runtime, worker)
    failed = client.get(f"/v1/jobs/{job['id']}").json()
    assert (failed["status"], failed["attempts"]) == ("failed", 1)
    assert failed["error"]["field"] == "params.fps"


def test_a_job_over_its_memory_limit_fails_once_and_the_worker_lives_on(
        client: TestClient, runtime: Runtime) -> None:
    runtime.settings.job_memory_mb = 64
    before = resource.getrlimit(resource.RLIMIT_AS)

    def hog() -> None:
        blocks = [np.ones(16 * 1024 * 1024) for _ in range(64)]  # 64 × 128 MiB
        assert not blocks  # never reached

    hungry = submit(client, upload(client)["id"])
    worker = Worker(runtime, kind_running(hog))
    assert drain(runtime, worker) == 1
    failed = client.get(f"/v1/jobs/{hungry['id']}").json()
    assert (failed["status"], failed["attempts"]) == ("failed", 1)
    problem = failed["error"]
    assert (problem["status"], problem["title"]) == (507, "Job exceeded its memory limit")
    assert problem["limit_mb"] == 64
    assert resource.getrlimit(resource.RLIMIT_AS) == before
    worker.kinds = kind_running(lambda: None)
    fine = submit(client, upload(client)["id"])
    drain(runtime, worker)
    assert client.get(f"/v1/jobs/{fine['id']}").json()["status"] == "succeeded"


# ----------------------------------------------------------------- the timings contract


def csv_bytes(write: Callable[[Any, Path], None], recording: Any, tmp_path: Path) -> bytes:
    path = tmp_path / "rec.csv"
    write(recording, path)
    return path.read_bytes()


def test_service_results_carry_the_three_timings(client: TestClient, runtime: Runtime,
                                                 tmp_path: Path) -> None:
    from bonefit.estimation.io.kinematics import write_kinematics_csv
    from bonefit.estimation.io.sensors import write_sensor_csv
    from bonefit.estimation.simulate.inertial import simulate_walker
    from bonefit.estimation.simulate.sensors import example_motion, simulate_sensors

    sensors, _ = simulate_sensors(example_motion(), units_m=0.01, seed=0)
    walker, _, _ = simulate_walker(fps=30)
    skeleton = submit(client, upload(client, csv_bytes(write_sensor_csv, sensors,
                                                       tmp_path))["id"])
    rec = upload(client, csv_bytes(write_kinematics_csv, walker, tmp_path))
    r = client.post("/v1/jobs", json={"kind": "translation", "recording_id": rec["id"],
                                      "params": {"left_foot": walker.left_foot,
                                                 "right_foot": walker.right_foot}})
    assert r.status_code == 202, r.text
    drain(runtime, Worker(runtime, default_kinds()))
    for job in (skeleton, r.json()):
        done = client.get(f"/v1/jobs/{job['id']}").json()
        assert done["status"] == "succeeded", done
        timings = client.get(f"/v1/jobs/{job['id']}/result?format=json").json()["timings"]
        assert list(timings)[:3] == ["read_s", "estimate_s", "write_s"]
        assert all(timings[k] > 0 for k in ("read_s", "estimate_s", "write_s")), timings


def test_a_job_has_the_results_its_formats_ask_for(client: TestClient, runtime: Runtime,
                                                   tmp_path: Path) -> None:
    from bonefit.estimation.io.sensors import example_path

    rec = upload(client, example_path().read_bytes())
    some = submit(client, rec["id"], params={"formats": ["json", "bvh"]})
    every = submit(client, rec["id"])
    assert some["params"]["formats"] == ["json", "bvh"]
    assert every["params"]["formats"] == ["json", "bvh", "csv", "npz"]
    r = client.post("/v1/jobs", json={"kind": "skeleton", "recording_id": rec["id"],
                                      "params": {"formats": ["bvh"]}})
    assert r.status_code == 422
    assert r.json()["field"] == "params.formats"
    drain(runtime, Worker(runtime, default_kinds()))
    done = client.get(f"/v1/jobs/{some['id']}").json()
    assert (done["status"], set(done["results"])) == ("succeeded", {"json", "bvh"})
    assert set(client.get(f"/v1/jobs/{every['id']}").json()["results"]) == {
        "json", "bvh", "csv", "npz"}
    missing = client.get(f"/v1/jobs/{some['id']}/result", params={"format": "csv"})
    assert (missing.status_code, missing.json()["field"]) == (404, "format")
    bvh = client.get(f"/v1/jobs/{some['id']}/result", params={"format": "bvh"})
    assert bvh.content == client.get(f"/v1/jobs/{every['id']}/result",
                                     params={"format": "bvh"}).content
