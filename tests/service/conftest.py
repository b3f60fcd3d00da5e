"""Fixtures: the app on private local back-ends and a worker running fake job kinds."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from bonefit.service.app import create_app
from bonefit.service.runtime import Runtime
from bonefit.service.settings import Settings
from bonefit.service.worker import Worker
from tests.service.helpers import AUTH_A, FAKE_KINDS, KEYS, TestClient, local_runtime


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    """Settings with two tenants, a short lease and unthrottled progress."""
    return Settings(data_dir=tmp_path, api_keys=KEYS, lease_seconds=5,
                    progress_interval_seconds=0, max_attempts=2)


@pytest.fixture
def runtime(settings: Settings) -> Runtime:
    """The production back-ends on private files under ``tmp_path``."""
    return local_runtime(settings)


@pytest.fixture
def client(runtime: Runtime) -> Iterator[TestClient]:
    """A client of the app, authenticated as tenant alice by default."""
    app = create_app(runtime=runtime, kinds=FAKE_KINDS, housekeeping=False)
    with TestClient(app, headers=AUTH_A, raise_server_exceptions=False) as c:
        yield c


@pytest.fixture
def worker(runtime: Runtime) -> Worker:
    """A worker running the fake kinds in this process."""
    return Worker(runtime, FAKE_KINDS, worker_id="test:1")


