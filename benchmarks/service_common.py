"""Shared helpers of the service benchmarks: run `bonefit serve`/`worker`, measure RSS, tables.

Not a benchmark itself (running it prints nothing). Everything stays on loopback.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "estimation" / "examples" / "walk.csv"
THREADS_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def bonefit_command() -> list[str]:
    """``bonefit`` next to this Python, else on PATH, else ``python -m bonefit``."""
    beside = Path(sys.executable).parent / "bonefit"
    if beside.is_file():
        return [str(beside)]
    found = shutil.which("bonefit")
    return [found] if found else [sys.executable, "-m", "bonefit"]


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def clean_env(extra: dict[str, str] | None = None) -> dict[str, str]:
    """This environment without BONEFIT_* settings, plus single-threaded BLAS and ``extra``."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("BONEFIT_")}
    env.update(THREADS_ENV)
    env.update(extra or {})
    return env


@dataclass
class Process:
    """A child process in its own session (so its whole tree can be stopped)."""

    proc: subprocess.Popen[bytes]
    log: Path

    @property
    def pid(self) -> int:
        return self.proc.pid

    def stop(self, grace: float = 15.0) -> None:
        if self.proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.proc.pid, signal.SIGTERM)
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.proc.wait(grace)
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.proc.pid, signal.SIGKILL)
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.proc.wait(5)


def spawn(args: Sequence[str], env: dict[str, str], log: Path) -> Process:
    handle = log.open("wb")
    try:
        proc = subprocess.Popen(list(args), env=env, stdout=handle, stderr=subprocess.STDOUT,
                                start_new_session=True, cwd=log.parent)
    finally:
        handle.close()
    return Process(proc, log)


@dataclass
class Server(Process):
    """``bonefit serve`` on a free loopback port."""

    base_url: str = ""
    workers: list[Process] = field(default_factory=list)

    def stop(self, grace: float = 15.0) -> None:
        for worker in self.workers:
            worker.stop(grace)
        super().stop(grace)


def wait_healthy(base_url: str, proc: Process, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.proc.poll() is not None:
            raise RuntimeError(f"the server exited: {proc.log.read_text()[-2000:]}")
        with contextlib.suppress(httpx.HTTPError):
            if httpx.get(f"{base_url}/healthz", timeout=1).status_code == 200:
                return
        time.sleep(0.1)
    raise RuntimeError(f"the server never became healthy: {proc.log.read_text()[-2000:]}")


def wait_settled(pids: Sequence[int], timeout: float = 60.0) -> None:
    """Wait until the processes ``pids`` (and their descendants) are idle: less than 5 % of a
    CPU over half a second, so that workers still importing numpy do not share the CPU with
    what is measured next."""
    deadline = time.monotonic() + timeout
    def everything() -> list[int]:
        return [p for pid in pids for p in tree(pid)]
    while time.monotonic() < deadline:
        before = cpu_seconds(everything())
        time.sleep(0.5)
        if cpu_seconds(everything()) - before < 0.025:
            return
    raise RuntimeError(f"the server processes never became idle within {timeout:.0f} s")


@contextlib.contextmanager
def running_server(data_dir: Path, *, workers: int = 2, no_worker: bool = False,
                   extra_env: dict[str, str] | None = None,
                   external_workers: int = 0) -> Iterator[Server]:
    """``bonefit serve`` (and ``external_workers`` × ``bonefit worker``) until the block ends."""
    port = free_port()
    env = clean_env({"BONEFIT_DATA_DIR": str(data_dir), **(extra_env or {})})
    args = [*bonefit_command(), "serve", "--host", "127.0.0.1", "--port", str(port),
            "--data-dir", str(data_dir), "--workers", str(workers)]
    if no_worker:
        args.append("--no-worker")
    data_dir.mkdir(parents=True, exist_ok=True)
    base = spawn(args, env, data_dir / "server.log")
    server = Server(base.proc, base.log, base_url=f"http://127.0.0.1:{port}")
    try:
        wait_healthy(server.base_url, server)
        for i in range(external_workers):  # each with a data directory of its own
            own = data_dir / f"worker-{i}"
            own.mkdir()
            server.workers.append(spawn([*bonefit_command(), "worker", "--data-dir", str(own)],
                                        {**env, "BONEFIT_DATA_DIR": str(own)},
                                        own / "worker.log"))
        wait_settled([server.pid, *(w.pid for w in server.workers)])
        yield server
    finally:
        server.stop()


@contextlib.contextmanager
def temp_dir(prefix: str) -> Iterator[Path]:
    path = Path(tempfile.mkdtemp(prefix=prefix))
    try:
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)


# --- memory --------------------------------------------------------------------------------


def children(pid: int) -> list[int]:
    """Direct children of ``pid`` (from /proc/<pid>/task/*/children)."""
    found: list[int] = []
    with contextlib.suppress(OSError):
        for task in Path(f"/proc/{pid}/task").iterdir():
            with contextlib.suppress(OSError):
                found.extend(int(c) for c in (task / "children").read_text().split())
    return found


def tree(pid: int) -> list[int]:
    """``pid`` and all its descendants."""
    pids, todo = [], [pid]
    while todo:
        current = todo.pop()
        pids.append(current)
        todo.extend(children(current))
    return pids


def status_kib(pid: int, key: str) -> int:
    """A ``/proc/<pid>/status`` field in KiB (0 when the process is gone)."""
    with contextlib.suppress(OSError):
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1])
    return 0


def cpu_seconds(pids: Sequence[int]) -> float:
    """User + system CPU time of ``pids`` so far (from /proc/<pid>/stat)."""
    total = 0.0
    tick = os.sysconf("SC_CLK_TCK")
    for pid in pids:
        with contextlib.suppress(OSError, IndexError, ValueError):
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / tick
    return total


# --- statistics and tables -----------------------------------------------------------------


def percentile(values: Sequence[float], q: float) -> float:
    ordered = sorted(values)
    if not ordered:
        return float("nan")
    index = min(len(ordered) - 1, max(0, round(q / 100 * (len(ordered) - 1))))
    return ordered[index]


def median(values: Sequence[float]) -> float:
    return statistics.median(values) if values else float("nan")


def machine() -> str:
    """CPU count and load average: the context every number here needs."""
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    return f"machine: {os.cpu_count()} CPUs, load average {load} (1, 5, 15 min) at start"


def cpu_ticks() -> tuple[int, int]:
    """(stolen, total) CPU ticks since boot, from /proc/stat: a virtual machine's host takes
    "steal" time when it is busy, which slows whatever is measured then."""
    try:
        fields = [int(x) for x in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    except (OSError, ValueError):
        return 0, 0
    return (fields[7] if len(fields) > 7 else 0), sum(fields[:8])


def steal_note(start: tuple[int, int]) -> str:
    """The share of CPU time stolen by the host since ``start`` (from `cpu_ticks`)."""
    stolen, total = cpu_ticks()
    share = (stolen - start[0]) / max(total - start[1], 1)
    return f"CPU steal during the measurement: {share:.0%} of CPU time (0 on a quiet host)"


def table(title: str, header: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    """A Markdown table (pastes into docs/deployment.md and the README as is)."""
    cells = [[str(c) for c in header], *[[str(c) for c in row] for row in rows]]
    widths = [max(len(row[i]) for row in cells) for i in range(len(header))]
    lines = [f"### {title}", ""]
    for n, row in enumerate(cells):
        lines.append("| " + " | ".join(c.ljust(w) for c, w in zip(row, widths, strict=True))
                     + " |")
        if n == 0:
            lines.append("|" + "|".join("-" * (w + 2) for w in widths) + "|")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    pass
