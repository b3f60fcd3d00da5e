"""The shared back-ends of one process: job store, queue and artifact storage."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

from .artifacts import ArtifactStore, open_artifacts
from .errors import BackendError
from .jobs import JobStore
from .queue import JobQueue, open_queue
from .settings import Settings
from .sql_store import open_store

log = logging.getLogger("bonefit.service")


@dataclass
class Runtime:
    """Settings plus the three back-ends built from them."""

    settings: Settings
    store: JobStore
    queue: JobQueue
    artifacts: ArtifactStore


def open_runtime(settings: Settings, *, wait_seconds: float = 30.0) -> Runtime:
    """Connect to the back-ends the settings name, creating tables and directories.

    The database may still be starting (containers start together): retry for
    ``wait_seconds`` before giving up.
    """
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    store = open_store(settings.resolved_database_url)
    deadline = time.monotonic() + wait_seconds
    while True:
        try:
            store.init()
            break
        except Exception as exc:
            if time.monotonic() >= deadline:
                raise
            cause = exc.cause_name if isinstance(exc, BackendError) else type(exc).__name__
            log.warning("job store not reachable yet (%s); retrying", cause)
            time.sleep(1.0)
    return Runtime(settings, store, open_queue(settings.resolved_queue_url),
                   open_artifacts(settings))
