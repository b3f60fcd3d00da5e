"""Helpers of the service tests: fake job kinds, small recordings, client shortcuts."""

from __future__ import annotations

import os
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import httpx
from huey import MemoryHuey

from bonefit.estimation.errors import InputError
from bonefit.estimation.progress import Progress
from bonefit.service.artifacts import LocalArtifactStore
from bonefit.service.kinds import Input, Kind, SkeletonParams, TranslationParams
from bonefit.service.queue import HueyQueue
from bonefit.service.runtime import Runtime
from bonefit.service.settings import Settings
from bonefit.service.sql_store import SqlJobStore
from bonefit.service.worker import Worker

with warnings.catch_warnings():
    # Starlette 1.x asks for httpx2 in its TestClient; httpx works the same for these tests.
    warnings.simplefilter("ignore", UserWarning)
    from fastapi.testclient import TestClient

__all__ = ["TestClient"]

KEYS = {"key-a": "alice", "key-b": "bob"}
AUTH_A = {"Authorization": "Bearer key-a"}
AUTH_B = {"Authorization": "Bearer key-b"}
SEGMENTS = ("pelvis", "chest", "head")


def require_services() -> bool:
    """Whether CI demands the external servers (fail instead of skip)."""
    return os.environ.get("BONEFIT_TEST_REQUIRE_SERVICES") == "1"


def local_queue() -> HueyQueue:
    """The production queue on huey's in-memory storage: private to this process."""
    return HueyQueue(MemoryHuey("bonefit-test", results=False))


def local_runtime(settings: Settings | None = None) -> Runtime:
    """The production back-ends on private local state, for tests: the SQL job store on a
    SQLite file, huey on its in-memory storage, artifacts as files, all under ``data_dir``."""
    settings = settings or Settings()
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    store = SqlJobStore.from_url(f"sqlite:///{settings.data_dir.resolve() / 'jobs.db'}")
    store.init()
    return Runtime(settings, store, local_queue(),
                   LocalArtifactStore(settings.data_dir / "artifacts"))


def sensor_csv(frames: int = 5, segments: tuple[str, ...] = SEGMENTS) -> bytes:
    """A tiny, well-formed sensor CSV."""
    cols = ["time"] + [f"{s}.{c}" for s in segments for c in ("x", "y", "z", "qw", "qx", "qy",
                                                               "qz")]
    rows = [",".join(cols)]
    for i in range(frames):
        values = [f"{i / 60:.4f}"] + ["0.1", "1.0", "0.2", "1", "0", "0", "0"] * len(segments)
        rows.append(",".join(values))
    return ("\n".join(rows) + "\n").encode()


def fake_run(inputs: Mapping[str, Input], params: Any, progress: Progress,
             outdir: Path) -> dict[str, Path]:
    """A job that reads its input, reports progress and writes three small results."""
    text = inputs["recording"].path.read_text()
    if "BAD" in text:
        raise InputError("bad number 'BAD'", line=3, column=2, field="pelvis.x")
    if "CRASH" in text:
        raise RuntimeError("boom")
    for i in range(5):
        progress(i / 5, "fake")
    out = {}
    for fmt in ("json", "bvh", "csv"):
        out[fmt] = outdir / f"out.{fmt}"
        out[fmt].write_text(f"{fmt}:{len(text)}")
    return out


FAKE_KINDS = {"skeleton": Kind("skeleton", SkeletonParams, fake_run),
              "translation": Kind("translation", TranslationParams, fake_run,
                                  inputs=("accelerations",))}


def upload(client: httpx.Client, data: bytes | None = None,
           **params: str) -> dict[str, Any]:
    """Upload a recording and return its representation."""
    r = client.post("/v1/recordings", content=sensor_csv() if data is None else data,
                    params={"filename": "rec.csv", **params})
    assert r.status_code == 201, r.text
    body: dict[str, Any] = r.json()
    return body


def submit(client: httpx.Client, recording_id: str, **extra: Any) -> dict[str, Any]:
    """Submit a skeleton job and return it."""
    r = client.post("/v1/jobs", json={"kind": "skeleton", "recording_id": recording_id, **extra})
    assert r.status_code == 202, r.text
    body: dict[str, Any] = r.json()
    return body


def drain(runtime: Runtime, worker: Worker) -> int:
    """Run every queued job; how many messages were handled."""
    n = 0
    while runtime.queue.run_next(worker.run_job):
        n += 1
    return n
