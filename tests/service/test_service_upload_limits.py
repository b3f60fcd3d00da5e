"""Hostile uploads get a named 422 fast and leave nothing behind; listings stay small
(issue 16 §1)."""

from __future__ import annotations

import importlib
import io
import json
import time
import tracemalloc
import zipfile
from pathlib import Path

import numpy as np
import pytest

from bonefit.estimation.errors import InputError, LimitError
from bonefit.estimation.pipeline import SKELETON_MODULES
from bonefit.service.jobs import Recording
from bonefit.service.kinds import Input, SkeletonParams, run_skeleton
from bonefit.service.problems import from_bonefit_error
from bonefit.service.runtime import Runtime
from bonefit.service.uploads import SUMMARY_BYTES, SUMMARY_ITEMS, cap_summary
from tests.service.helpers import TestClient, sensor_csv, upload
from tests.service.test_service_api import assert_problem

MB = 1024 * 1024


def npy_header(dtype: str, shape: tuple[int, ...]) -> bytes:
    out = io.BytesIO()
    np.lib.format.write_array_header_1_0(out, {"descr": dtype, "fortran_order": False,
                                               "shape": shape})
    return out.getvalue()


def sensors_bomb() -> bytes:
    """About 200 KB whose sensors.npy inflates to 50 M entries (200 MB)."""
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
        for key, dtype, shape in (("positions", "<f8", (10, 1, 3)),
                                  ("quaternions", "<f8", (10, 1, 4)), ("fps", "<f8", ())):
            zf.writestr(f"{key}.npy", npy_header(dtype, shape)
                        + bytes(8 * int(np.prod(shape))))
        with zf.open("sensors.npy", "w", force_zip64=True) as member:
            member.write(npy_header("<U1", (50_000_000,)))
            for _ in range(200):
                member.write(bytes(1_000_000))
    return out.getvalue()


def listing_bytes(client: TestClient) -> int:
    r = client.get("/v1/recordings")
    assert r.status_code == 200
    return len(r.content)


@pytest.mark.parametrize("fmt", ["auto", "npz"])
def test_npz_bomb_is_a_422_naming_the_limit_and_leaves_nothing(client: TestClient,
                                                                fmt: str) -> None:
    before = listing_bytes(client)
    r = client.post("/v1/recordings", content=sensors_bomb(),
                    params={"filename": "bomb.npz", "format": fmt})
    body = assert_problem(r, 422)
    assert body["limit"] == "MAX_NPZ_SMALL_BYTES"
    assert body["field"] == "sensors"
    assert "MAX_NPZ_SMALL_BYTES" in str(body["detail"])
    assert listing_bytes(client) == before


def test_a_single_line_accelerations_csv_is_a_422(client: TestClient) -> None:
    """8 MB here (the 50 MB file of the issue is read by the reader tests)."""
    data = b"time" + b",a.x" * (8 * MB // 4)
    r = client.post("/v1/recordings", content=data,
                    params={"filename": "feet.csv", "format": "accelerations-csv"})
    body = assert_problem(r, 422)
    assert (body["limit"], body["line"]) == ("MAX_LINE_CHARS", 1)
    assert str(body["detail"]).startswith("format=accelerations-csv: line 1 is longer")


@pytest.mark.parametrize("data", [np.random.default_rng(5).bytes(4096), sensor_csv()],
                         ids=["random-bytes", "sensor-csv"])
def test_content_that_contradicts_a_declared_bvh_is_a_422_naming_it(client: TestClient,
                                                                     data: bytes) -> None:
    r = client.post("/v1/recordings", content=data,
                    params={"filename": "take.bvh", "format": "bvh"})
    body = assert_problem(r, 422)
    assert str(body["detail"]).startswith("format=bvh: not a BVH file")


@pytest.mark.parametrize("fmt", ["kinematics-csv", "accelerations-csv"])
def test_a_sensor_csv_declared_as_another_csv_is_a_422(client: TestClient, fmt: str) -> None:
    r = client.post("/v1/recordings", content=sensor_csv(),
                    params={"filename": "rec.csv", "format": fmt})
    body = assert_problem(r, 422)
    assert str(body["detail"]).startswith(f"format={fmt}: not a")


def test_accepted_upload_lists_are_capped() -> None:
    summary = {"format": "accelerations-csv", "frames": 3,
               "columns": [f"c{i}.ax" for i in range(100_000)], "sensors": ["LeftFoot"]}
    capped = cap_summary(summary)
    assert len(json.dumps(capped)) <= SUMMARY_BYTES
    assert capped["columns"] == summary["columns"][:SUMMARY_ITEMS]
    assert capped["columns_total"] == 100_000
    assert (capped["frames"], capped["sensors"]) == (3, ["LeftFoot"])
    small = {"format": "npz", "frames": 10, "sensors": ["pelvis"]}
    assert cap_summary(small) is small


def test_a_huge_stored_summary_is_not_re_served(client: TestClient, runtime: Runtime) -> None:
    """Rows stored before the cap (the issue's 150 MB summary) are cut when listed."""
    rec = upload(client)
    stored = runtime.store.get_recording("alice", rec["id"])
    assert stored is not None
    runtime.store.add_recording(Recording(
        id="0legacy", tenant=stored.tenant, key=stored.key, filename="old.npz",
        content_type=None, format="npz", size=1, sha256="0" * 64, created_at=time.time(),
        summary={"format": "npz", "frames": 10, "sensors": [""] * 2_000_000}))
    assert listing_bytes(client) < 3 * SUMMARY_BYTES
    one = client.get("/v1/recordings/0legacy").json()
    assert one["summary"]["sensors_total"] == 2_000_000


def test_the_worker_refuses_a_positions_bomb_before_inflating_it(tmp_path: Path) -> None:
    """The real skeleton kind reads with the same guards: a named LimitError (a 422 job
    error), with under 2 MB allocated, for a positions.npy that inflates to 64 MB and
    declares 50 M frames."""
    path = tmp_path / "bomb.npz"
    with (zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as zf,
          zf.open("positions.npy", "w", force_zip64=True) as member):
        member.write(npy_header("<f8", (50_000_000, 15, 3)))
        for _ in range(64):
            member.write(bytes(MB))
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(InputError):  # imports what the kind needs outside the measurement
        run_skeleton({"recording": Input(junk, "npz")}, SkeletonParams(),
                     lambda fraction, stage: None, tmp_path / "out")
    # the run imports the estimators in a thread while it reads; wait for that thread's
    # imports (module locks) so that none of its allocations fall in the measurement
    for name in SKELETON_MODULES:
        importlib.import_module(name)
    tracemalloc.start()
    try:
        with pytest.raises(LimitError) as caught:
            run_skeleton({"recording": Input(path, "npz")}, SkeletonParams(),
                         lambda fraction, stage: None, tmp_path / "out")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert caught.value.limit == "MAX_VALUES"
    assert caught.value.field == "positions"
    assert peak < 2 * MB
    assert from_bonefit_error(caught.value).status == 422


def test_long_names_cut_lists_further_but_keep_what_fits() -> None:
    names = ["x" * 250 + f"{i:04d}" for i in range(3900)]
    capped = cap_summary({"format": "accelerations-csv", "frames": 1, "columns": names})
    assert len(json.dumps(capped)) <= SUMMARY_BYTES
    assert 0 < len(capped["columns"]) < SUMMARY_ITEMS
    assert capped["columns"] == [n[:256] + "…" if len(n) > 256 else n
                                 for n in names[:len(capped["columns"])]]
    assert capped["columns_total"] == 3900
    assert capped["frames"] == 1
