"""The retention: recordings, results and job records older than ``retention_seconds`` go."""

from __future__ import annotations

import logging
import time

from .jobs import PURGE_BATCH
from .runtime import Runtime

log = logging.getLogger("bonefit.worker")


def purge(runtime: Runtime, now: float | None = None) -> int:
    """Delete recordings, results and job records older than the retention; how many.

    Rows go in batches of ``PURGE_BATCH`` (each its own transaction, its artifacts deleted
    right after it), so any number of expired rows is purged and a failure keeps what is done.
    """
    ttl = runtime.settings.retention_seconds
    if ttl <= 0:
        return 0
    before = (time.time() if now is None else now) - ttl
    total = 0
    while True:
        recordings, jobs = runtime.store.purge(before, PURGE_BATCH)
        for key in [r.key for r in recordings] + [k for j in jobs for k in j.results.values()]:
            try:
                runtime.artifacts.delete(key)
            except Exception:
                log.exception("could not delete artifact %s", key)
        total += len(recordings) + len(jobs)
        if len(recordings) < PURGE_BATCH and len(jobs) < PURGE_BATCH:
            return total
