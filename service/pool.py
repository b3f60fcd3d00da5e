"""The worker pool: ``bonefit worker --concurrency N`` and ``bonefit serve``'s embedded workers."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import threading
import time

from bonefit.estimation.threads import BLAS_LIMITS  # one per worker: the pool uses the cores

from .settings import Settings

log = logging.getLogger("bonefit.worker")


class WorkerPool:
    """Worker processes (``bonefit worker --concurrency 1``) kept alive by a supervisor thread."""

    def __init__(self, settings: Settings, size: int) -> None:
        self.settings = settings
        self.size = size
        self.procs: list[subprocess.Popen[bytes]] = []
        self._stopping = threading.Event()
        self._supervisor = threading.Thread(target=self._supervise, name="worker-pool",
                                            daemon=True)

    def _spawn(self) -> subprocess.Popen[bytes]:
        env = {**os.environ, **self.settings.to_env(), **BLAS_LIMITS}
        cmd = [sys.executable, "-m", "bonefit", "worker", "--concurrency", "1",
               "--parent-pid", str(os.getpid())]
        return subprocess.Popen(cmd, env=env)

    def start(self) -> None:
        """Start the processes and the supervisor."""
        self.procs = [self._spawn() for _ in range(self.size)]
        self._supervisor.start()

    @property
    def pids(self) -> list[int]:
        """Process ids of the live workers."""
        return [p.pid for p in self.procs if p.poll() is None]

    def _supervise(self) -> None:
        started = [time.monotonic()] * len(self.procs)
        failures = [0] * len(self.procs)
        respawn_at: list[float | None] = [None] * len(self.procs)
        while not self._stopping.wait(1.0):
            for i, proc in enumerate(self.procs):
                if proc.poll() is None or self._stopping.is_set():
                    continue
                now = time.monotonic()
                if respawn_at[i] is None:  # a worker dying right after its start backs off
                    quick = now - started[i] < 10
                    failures[i] = failures[i] + 1 if quick else 0
                    respawn_at[i] = now + (min(2.0 ** failures[i], 60.0) if quick else 0.0)
                    log.warning("worker %d exited with %s; starting another", proc.pid,
                                proc.returncode)
                if now >= (respawn_at[i] or 0.0):
                    self.procs[i] = self._spawn()
                    started[i], respawn_at[i] = time.monotonic(), None

    def stop(self, timeout: float | None = None) -> None:
        """SIGTERM every worker (they finish or hand back their job), then wait; kill late ones."""
        self._stopping.set()
        timeout = self.settings.shutdown_grace_seconds + 5 if timeout is None else timeout
        for proc in self.procs:
            if proc.poll() is None:
                proc.terminate()
        end = time.monotonic() + timeout
        for proc in self.procs:
            try:
                proc.wait(max(end - time.monotonic(), 0.1))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if self._supervisor.is_alive():
            self._supervisor.join()
