"""Fixtures for end-to-end tests against real `bonefit serve` / `bonefit worker` processes.

``start_server(env, worker=True)`` runs ``bonefit serve --host 127.0.0.1 --port <free>
--data-dir <tmp>`` as a subprocess with ``env`` added to a clean environment (no inherited
``BONEFIT_*``), waits for ``/healthz`` and returns a :class:`ServerProcess`; ``start_worker(env)``
runs ``bonefit worker``. Everything started is stopped at teardown (the whole process group).
"""

from __future__ import annotations

import contextlib
import io
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

BONEFIT = Path(sys.executable).with_name("bonefit")
STARTUP_SECONDS = 60.0


def free_port() -> int:
    """A TCP port nobody listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def clean_env(extra: dict[str, str]) -> dict[str, str]:
    """The test process's environment without BONEFIT_* variables, plus ``extra``."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("BONEFIT_")}
    env.update(extra)
    return env


def children(pid: int) -> list[int]:
    """Direct child process ids of ``pid``, started by any of its threads (Linux /proc)."""
    found: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        with contextlib.suppress(OSError):
            found += [int(p) for p in (task / "children").read_text().split()]
    return sorted(found)


def _stop_group(proc: subprocess.Popen[bytes], grace: float) -> None:
    """SIGTERM the process group, wait ``grace`` s, then SIGKILL whatever is left."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGTERM)
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(grace)
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(5)


class ManagedProcess:
    """A `bonefit` sub-command in its own process group, logging to a file."""

    def __init__(self, args: list[str], env: dict[str, str], log_path: Path) -> None:
        self.args = args
        self.env = env
        self.log_path = log_path
        self.proc: subprocess.Popen[bytes] | None = None
        self.groups: list[subprocess.Popen[bytes]] = []

    def start(self) -> None:
        """Start (again) with the same arguments and environment."""
        log = self.log_path.open("ab")
        self.proc = subprocess.Popen([str(BONEFIT), *self.args], env=self.env, stdout=log,
                                     stderr=subprocess.STDOUT, start_new_session=True)
        log.close()
        self.groups.append(self.proc)

    @property
    def pid(self) -> int:
        """Process id of the command."""
        assert self.proc is not None
        return self.proc.pid

    def kill(self, sig: int = signal.SIGKILL, *, wait: float = 30.0) -> int | None:
        """Send ``sig`` to the command itself (not its children); wait for it to exit."""
        assert self.proc is not None
        with contextlib.suppress(ProcessLookupError):
            self.proc.send_signal(sig)
        try:
            return self.proc.wait(wait)
        except subprocess.TimeoutExpired:
            return None

    def log(self) -> str:
        """Everything the process printed so far."""
        return self.log_path.read_text(errors="replace") if self.log_path.exists() else ""

    def stop(self, grace: float = 15.0) -> None:
        """Stop every process group this object started."""
        for proc in self.groups:
            if proc.poll() is None or children(proc.pid):
                _stop_group(proc, grace)
            else:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)  # orphaned workers, if any


class ServerProcess(ManagedProcess):
    """A running `bonefit serve`."""

    def __init__(self, args: list[str], env: dict[str, str], log_path: Path, port: int,
                 data_dir: Path) -> None:
        super().__init__(args, env, log_path)
        self.port = port
        self.data_dir = data_dir

    @property
    def base_url(self) -> str:
        """``http://127.0.0.1:<port>``."""
        return f"http://127.0.0.1:{self.port}"

    def wait_healthy(self, timeout: float = STARTUP_SECONDS) -> None:
        """Poll /healthz until it answers 200."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            assert self.proc is not None
            if self.proc.poll() is not None:
                raise RuntimeError(f"bonefit serve exited with {self.proc.returncode}:\n"
                                   f"{self.log()[-3000:]}")
            with contextlib.suppress(httpx.HTTPError):
                if httpx.get(f"{self.base_url}/healthz", timeout=2).status_code == 200:
                    return
            time.sleep(0.2)
        raise TimeoutError(f"bonefit serve not healthy in {timeout} s:\n{self.log()[-3000:]}")

    def worker_pids(self) -> list[int]:
        """Process ids of the embedded worker processes."""
        return children(self.pid)

    def restart(self, sig: int = signal.SIGTERM) -> None:
        """Stop the server with ``sig`` (workers too), start it again on the same port and data."""
        workers = self.worker_pids()
        if self.proc is not None and self.proc.poll() is None:
            self.kill(sig)
        for pid in workers:  # after kill -9 of the API, its workers notice and exit by themselves
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGTERM)
        self.start()
        self.wait_healthy()

    def client(self, **kwargs: Any) -> httpx.Client:
        """An httpx client on the server."""
        return httpx.Client(base_url=self.base_url, timeout=30, **kwargs)


class Launcher:
    """Starts servers and workers under a temporary directory and stops them all in close()."""

    def __init__(self, tmp_path_factory: pytest.TempPathFactory) -> None:
        self.tmp = tmp_path_factory
        self.started: list[ManagedProcess] = []

    def server(self, env: dict[str, str] | None = None, *, worker: bool = True,
               data_dir: Path | None = None, args: tuple[str, ...] = ()) -> ServerProcess:
        """Run `bonefit serve` on a free loopback port and wait until it is healthy."""
        data_dir = data_dir or self.tmp.mktemp("bonefit-data")
        port = free_port()
        cmd = ["serve", "--host", "127.0.0.1", "--port", str(port), "--data-dir", str(data_dir),
               *([] if worker else ["--no-worker"]), *args]
        server = ServerProcess(cmd, clean_env(env or {}), data_dir / f"serve-{port}.log", port,
                               data_dir)
        self.started.append(server)
        server.start()
        server.wait_healthy()
        return server

    def worker(self, env: dict[str, str] | None = None, *, data_dir: Path | None = None,
               concurrency: int = 1) -> ManagedProcess:
        """Run `bonefit worker`."""
        data_dir = data_dir or self.tmp.mktemp("bonefit-worker")
        cmd = ["worker", "--concurrency", str(concurrency), "--data-dir", str(data_dir)]
        worker = ManagedProcess(cmd, clean_env(env or {}),
                                data_dir / f"worker-{len(self.started)}.log")
        self.started.append(worker)
        worker.start()
        return worker

    def close(self) -> None:
        """Stop everything started."""
        for process in reversed(self.started):
            process.stop()


@pytest.fixture
def start_server(tmp_path_factory: pytest.TempPathFactory
                 ) -> Iterator[Callable[..., ServerProcess]]:
    """Factory: ``start_server(env, *, worker=True, data_dir=None, args=())``."""
    launcher = Launcher(tmp_path_factory)
    yield launcher.server
    launcher.close()


@pytest.fixture
def start_worker(tmp_path_factory: pytest.TempPathFactory
                 ) -> Iterator[Callable[..., ManagedProcess]]:
    """Factory: ``start_worker(env, *, data_dir=None, concurrency=1)`` runs `bonefit worker`."""
    launcher = Launcher(tmp_path_factory)
    yield launcher.worker
    launcher.close()


def upload(client: httpx.Client, data: bytes, **params: str) -> dict[str, Any]:
    """Upload ``data`` as a recording; its JSON (asserts 201)."""
    r = client.post("/v1/recordings", content=data, params=params)
    assert r.status_code == 201, r.text
    body: dict[str, Any] = r.json()
    return body


def submit(client: httpx.Client, body: dict[str, Any], **headers: str) -> dict[str, Any]:
    """Submit a job; its JSON (asserts 202 and the Location header)."""
    r = client.post("/v1/jobs", json=body, headers=headers)
    assert r.status_code == 202, r.text
    assert r.headers["location"] == f"/v1/jobs/{r.json()['id']}"
    job: dict[str, Any] = r.json()
    return job


def wait_for_job(client: httpx.Client, job_id: str, *, timeout: float = 90.0,
                 until: tuple[str, ...] = ("succeeded", "failed", "cancelled"),
                 ) -> dict[str, Any]:
    """Poll the job until its status is in ``until``; its last representation."""
    deadline = time.monotonic() + timeout
    while True:
        job: dict[str, Any] = client.get(f"/v1/jobs/{job_id}").raise_for_status().json()
        if job["status"] in until:
            return job
        if time.monotonic() > deadline:
            raise TimeoutError(f"job {job_id} still {job['status']} after {timeout} s: {job}")
        time.sleep(0.2)


def wait_ready(client: httpx.Client, timeout: float = 120) -> httpx.Response:
    """/readyz once it answers 200 (the workers register after loading), or its last answer."""
    deadline = time.monotonic() + timeout
    while (r := client.get("/readyz")).status_code != 200 and time.monotonic() < deadline:
        time.sleep(0.5)
    return r


def _sensor_csv(n_frames: int, seed: int) -> bytes:
    from bonefit.estimation.io.sensors import write_sensor_csv
    from bonefit.estimation.simulate.sensors import example_motion, simulate_sensors

    recording, _ = simulate_sensors(example_motion(n_frames=n_frames, fps=60.0, seed=seed),
                                    units_m=0.01, seed=seed)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "recording.csv"
        write_sensor_csv(recording, path)
        return path.read_bytes()


@pytest.fixture(scope="session")
def sensor_csv_bytes() -> bytes:
    """A small synthetic 15-sensor recording (CSV, 240 frames) the skeleton job solves."""
    return _sensor_csv(240, seed=1)


@pytest.fixture(scope="session")
def long_sensor_csv_bytes() -> bytes:
    """A recording whose skeleton job runs for seconds (about 6 s on an idle 2-core machine, so
    that a test can act on it while it runs): 2,400 frames repeated 16 times."""
    lines = _sensor_csv(2400, seed=2).decode().splitlines()
    header_end = next(i for i, line in enumerate(lines) if line.startswith("time"))
    head, rows = lines[:header_end + 1], lines[header_end + 1:]
    period = 2400 / 60.0
    out = list(head)
    times = [float(row.split(",", 1)[0]) for row in rows]
    rests = [",".join(v and f"{float(v):.4f}" for v in row.split(",")[1:])  # 0.1 mm: < 32 MiB
             for row in rows]
    for k in range(16):
        out.extend(f"{t + k * period:.6f},{rest}" for t, rest in zip(times, rests, strict=True))
    return ("\n".join(out) + "\n").encode()


@pytest.fixture(scope="session")
def kinematics_csv_bytes() -> bytes:
    """An inertial-suit kinematics CSV (Shadow layout: cm positions, foot accelerations in g)."""
    from bonefit.estimation.io.kinematics import write_kinematics_csv
    from bonefit.estimation.simulate.inertial import simulate_walker

    rec, _, _ = simulate_walker(fps=60.0, seed=0)
    text = io.StringIO()
    write_kinematics_csv(rec, text)
    return text.getvalue().encode()


@pytest.fixture(scope="session")
def bvh_and_accelerations() -> tuple[bytes, bytes, tuple[str, str]]:
    """A BVH clip, its foot accelerations CSV (g, sensor frame) and the two foot joints."""
    from bonefit.estimation.bvh import write_bvh
    from bonefit.estimation.simulate.inertial import simulate_inertial
    from bonefit.estimation.simulate.sensors import example_motion

    motion = example_motion(n_frames=300, fps=60.0, seed=0)
    rec, _ = simulate_inertial(motion)
    left, right = rec.accelerations
    lines = ["time," + ",".join(f"{f}.{a}" for f in (left, right) for a in ("ax", "ay", "az"))]
    for i in range(len(rec.time)):
        values = [f"{v / 9.80665:.6f}" for f in (left, right) for v in rec.accelerations[f][i]]
        lines.append(f"{rec.time[i]:.6f}," + ",".join(values))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "clip.bvh"
        write_bvh(motion, path)
        return path.read_bytes(), ("\n".join(lines) + "\n").encode(), (left, right)
