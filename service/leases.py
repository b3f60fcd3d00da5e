"""The lease keeper: a small process that renews a worker's job lease while the worker lives.

A job's heartbeat thread shares its process, and the interpreter lock, with the numerical work;
a long call that holds the lock (or a machine whose cores are saturated) can starve it past the
lease, and the reaper then takes a healthy job away. The keeper does no numerical work: it
sleeps, renews the lease every third of it, and stops renewing as soon as its worker is gone
(its standard input reaches end-of-file when the worker process dies, even by kill -9), so a
dead worker's job is still re-queued after one lease.

Protocol on standard input, one command a line: ``hold <job id>`` (renew this job's lease for
worker ``<worker id>``, given on the command line) and ``drop`` (stop renewing).
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import signal
import subprocess
import sys
import time
from collections.abc import Sequence

from .jobs import JobStore
from .settings import Settings
from .sql_store import open_store

log = logging.getLogger("bonefit.leases")


class LeaseKeeper:
    """The worker's side: start the keeper process and tell it which job to hold."""

    def __init__(self, settings: Settings, worker_id: str) -> None:
        self.settings = settings
        self.worker_id = worker_id
        self.proc: subprocess.Popen[bytes] | None = None
        self.job_id: str | None = None

    def start(self) -> None:
        """Start (or restart) the keeper process."""
        env = {**os.environ, **self.settings.to_env()}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "bonefit.service.leases", self.worker_id, str(os.getpid())],
            stdin=subprocess.PIPE, env=env)

    def _send(self, line: str) -> None:
        for _ in range(2):  # a keeper that died is started again once
            if self.proc is None or self.proc.poll() is not None:
                log.warning("lease keeper of %s is not running; starting it", self.worker_id)
                self.start()
            assert self.proc is not None
            assert self.proc.stdin is not None
            try:
                self.proc.stdin.write(line.encode() + b"\n")
                self.proc.stdin.flush()
                return
            except (BrokenPipeError, OSError):
                self.proc.wait()
        log.error("lease keeper of %s cannot be reached", self.worker_id)

    def hold(self, job_id: str) -> None:
        """Renew ``job_id``'s lease until :meth:`drop`."""
        self.job_id = job_id
        self._send(f"hold {job_id}")

    def drop(self) -> None:
        """Stop renewing."""
        self.job_id = None
        self._send("drop")

    def close(self) -> None:
        """Stop the keeper process."""
        if self.proc is None:
            return
        if self.proc.stdin is not None:
            with contextlib.suppress(OSError):
                self.proc.stdin.close()
        try:
            self.proc.wait(5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


def _commands(fd: int, buffer: bytearray) -> tuple[list[str], bool]:
    """The complete lines readable now on ``fd``, and whether it reached end-of-file."""
    data = os.read(fd, 4096)
    if not data:
        return [], True
    buffer += data
    *lines, rest = bytes(buffer).split(b"\n")
    buffer[:] = rest
    return [line.decode().strip() for line in lines], False


def keep(settings: Settings, worker_id: str, parent_pid: int) -> int:
    """The keeper's loop: renew the held job's lease every third of a lease, until EOF."""
    store = open_store(settings.resolved_database_url)
    interval = settings.lease_seconds / 3
    fd, buffer = sys.stdin.fileno(), bytearray()
    job_id: str | None = None
    due = time.monotonic() + interval
    while True:
        ready, _, _ = select.select([fd], [], [], max(due - time.monotonic(), 0.0))
        if ready:
            lines, eof = _commands(fd, buffer)
            if eof:
                return 0  # the worker closed its end or died: stop renewing
            for line in lines:
                command, _, arg = line.partition(" ")
                job_id = arg if command == "hold" and arg else None
            if job_id is not None:
                due = time.monotonic()  # renew at once: the keeper may have started late
            continue
        due = time.monotonic() + interval
        if os.getppid() != parent_pid:
            return 0
        if job_id is not None:
            job_id = _renew(store, job_id, worker_id, settings.lease_seconds)


def _renew(store: JobStore, job_id: str, worker_id: str, lease: float) -> str | None:
    """Extend the lease; the job id while it is still this worker's, else None."""
    try:
        job = store.renew(job_id, worker_id, time.time() + lease)
    except Exception:
        log.exception("job %s: the lease keeper could not renew the lease", job_id)
        return job_id
    return job_id if job is not None else None


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m bonefit.service.leases WORKER_ID PARENT_PID`` (started by
    :class:`LeaseKeeper`)."""
    worker_id, parent = list(sys.argv[1:] if argv is None else argv)
    # the keeper lives exactly as long as its worker's end of the pipe: a SIGTERM to the
    # process group must not stop the renewals of a job the worker is still finishing
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    logging.basicConfig(level=logging.WARNING,
                        format="%(asctime)s %(levelname)s %(name)s[%(process)d]: %(message)s")
    return keep(Settings(), worker_id, int(parent))


if __name__ == "__main__":
    sys.exit(main())
