"""Crash a throwaway PostgreSQL under the job store and see which jobs survive.

The API stores a job without waiting for the disk (``add_job(durable=False)``), queues it,
and answers 202 only after ``wait_durable``. This script checks that on a real server: it
creates a private cluster (``initdb``, as user ``postgres`` when run as root) on a free port,
keeps its WAL writer from flushing on its own (SIGSTOP), and kills every process of the
cluster (SIGKILL: the WAL buffers in shared memory are lost, what was written to the kernel
is not) at three points:

1. after the early insert alone: the job is gone after the restart (and a worker's message
   for it finds no job: the worker logs it and drops the message);
2. after the early insert and ``wait_durable`` (the API's 202 comes after this): kept;
3. after the early insert and a worker's claim (a synchronous commit): kept, and running.

A process kill, not a power cut: it shows what the commits wait for, not that the disk
keeps what ``fsync`` returned for. Needs PostgreSQL's server binaries (``pg_config
--bindir``, or /usr/lib/postgresql/*/bin).

    .venv/bin/python scripts/pg_crash_check.py
"""

from __future__ import annotations

import glob
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path

import psycopg

from bonefit.service.jobs import Job, Status, new_id
from bonefit.service.sql_store import SqlJobStore


def bindir() -> Path:
    """The directory of ``initdb`` and ``postgres``."""
    found = shutil.which("pg_config")
    if found:
        return Path(subprocess.check_output([found, "--bindir"], text=True).strip())
    candidates = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"))
    if not candidates:
        raise SystemExit("no PostgreSQL server binaries (initdb) found")
    return Path(candidates[-1]).parent


def as_owner(args: list[str]) -> list[str]:
    """``args`` run as user postgres when this is root (initdb refuses root)."""
    return ["runuser", "-u", "postgres", "--", *args] if os.geteuid() == 0 else args


class Cluster:
    """A private PostgreSQL cluster in ``root`` on ``port``."""

    def __init__(self, root: Path) -> None:
        self.bin, self.data, self.port = bindir(), root / "data", free_port()
        self.proc: subprocess.Popen[bytes] | None = None
        subprocess.run(as_owner([str(self.bin / "initdb"), "-D", str(self.data), "-U",
                                 "postgres", "--auth=trust"]), check=True,
                       stdout=subprocess.DEVNULL)

    @property
    def url(self) -> str:
        return f"postgresql://postgres@127.0.0.1:{self.port}/postgres"

    def start(self) -> None:
        self.proc = subprocess.Popen(as_owner([
            str(self.bin / "postgres"), "-D", str(self.data), "-p", str(self.port),
            "-c", "listen_addresses=127.0.0.1", "-c", f"unix_socket_directories={self.data}",
            "-c", "wal_writer_delay=10s", "-c", "wal_writer_flush_after=1GB"]),
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:  # accepting connections, and past its recovery
            try:
                psycopg.connect(self.url, connect_timeout=5).close()
                return
            except psycopg.OperationalError:
                time.sleep(0.2)
        raise SystemExit("the private PostgreSQL did not start")

    def postmaster(self) -> int:
        for proc in Path("/proc").iterdir():
            try:
                cmd = (proc / "cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            if cmd[:3] == [str(self.bin / "postgres").encode(), b"-D", str(self.data).encode()]:
                return int(proc.name)
        raise SystemExit("the private postmaster is not running")

    def children(self) -> dict[int, str]:
        """The postmaster's children: pid → process title."""
        pids = subprocess.check_output(["pgrep", "-P", str(self.postmaster())], text=True)
        return {int(pid): Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace")
                for pid in pids.split()}

    def hold_wal_writer(self) -> None:
        """Stop the WAL writer, so that only a synchronous commit flushes the log."""
        (pid,) = [pid for pid, title in self.children().items() if "walwriter" in title]
        os.kill(pid, signal.SIGSTOP)

    def crash(self) -> None:
        """SIGKILL the postmaster and every child at once (shared memory is lost)."""
        for pid in [self.postmaster(), *self.children()]:
            os.kill(pid, signal.SIGKILL)
        assert self.proc is not None
        self.proc.wait()
        time.sleep(0.5)


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def new_job() -> Job:
    now = time.time()
    return Job(id=new_id(), tenant="crash", kind="skeleton", recording_id="r", params={},
               inputs={}, created_at=now, updated_at=now)


def scenario(cluster: Cluster, name: str, after_insert: str) -> str:
    """Early insert, then ``after_insert`` ("nothing", "wait_durable", "claim"), crash,
    restart: what the store holds of the job."""
    cluster.start()
    store = SqlJobStore.from_url(cluster.url)
    store.init()
    store.wait_durable()  # the tables themselves
    cluster.hold_wal_writer()
    job = store.add_job(new_job(), durable=False)
    assert store.get_job(job.id) is not None, "the early insert is not visible"
    if after_insert == "wait_durable":
        store.wait_durable()
    elif after_insert == "claim":
        assert store.claim(job.id, "worker", time.time(), 30.0) is not None
    store.dispose()
    cluster.crash()
    cluster.start()
    store = SqlJobStore.from_url(cluster.url)
    found = store.get_job(job.id)
    store.dispose()
    cluster.crash()  # just to stop it; the next scenario starts it again
    kept = "lost" if found is None else f"kept ({Status(found.status).value})"
    print(f"{name:<52} {kept}", flush=True)
    return kept


def main() -> None:
    root = Path(tempfile.mkdtemp(prefix="bonefit-pg-crash-"))
    os.chmod(root, 0o777)  # initdb as postgres writes here
    cluster: Cluster | None = None
    try:
        cluster = Cluster(root)
        results = [
            scenario(cluster, "early insert, crash", "nothing"),
            scenario(cluster, "early insert, wait_durable (then 202), crash", "wait_durable"),
            scenario(cluster, "early insert, a worker's claim, crash", "claim"),
        ]
    finally:
        if cluster is not None and cluster.proc is not None and cluster.proc.poll() is None:
            cluster.crash()  # a scenario failed half-way: stop its server
        shutil.rmtree(root, ignore_errors=True)
    expected = ["lost", "kept (queued)", "kept (running)"]
    if results != expected:
        raise SystemExit(f"expected {expected}, got {results}")
    print("as expected: only a job the client was not told about can be lost")


if __name__ == "__main__":
    main()
