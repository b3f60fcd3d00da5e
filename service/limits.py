"""Per-job resource limits of a worker process.

A job runs with the process's address space capped at what it used before the job plus
``job_memory_mb`` (``RLIMIT_AS``): an allocation past it raises ``MemoryError`` in the job,
which the worker turns into a failed job, instead of the kernel's OOM killer taking the whole
worker (and the job being retried on the next one). Address space, not resident memory, is
what the kernel can refuse at allocation time; it overcounts memory that is mapped but not
touched, which for numpy arrays is little.
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
from collections.abc import Iterator

log = logging.getLogger("bonefit.worker")

try:
    import resource
except ImportError:  # pragma: no cover - not on Windows
    resource = None  # type: ignore[assignment]


class MemoryLimitExceeded(Exception):
    """The job tried to allocate more than ``job_memory_mb``."""

    def __init__(self, limit_mb: int) -> None:
        super().__init__(f"over {limit_mb} MiB")
        self.limit_mb = limit_mb


_lock = threading.Lock()
_active = 0
_saved: tuple[int, int] | None = None


def address_space_bytes() -> int | None:
    """This process's current virtual memory size, bytes (None where /proc is missing)."""
    try:
        with open("/proc/self/statm", encoding="ascii") as f:
            pages = int(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return None
    return pages * os.sysconf("SC_PAGE_SIZE")


@contextlib.contextmanager
def memory_limit(limit_mb: int) -> Iterator[None]:
    """Cap the process's address space at its current size plus ``limit_mb`` MiB.

    A ``MemoryError`` inside becomes :class:`MemoryLimitExceeded`. ``limit_mb`` 0, a
    platform without ``RLIMIT_AS`` or /proc: no limit. Jobs running at the same time in one
    process (tests, embedded use) share the first one's cap; the last to leave restores the
    previous limit.
    """
    global _active, _saved
    applied = False
    if limit_mb > 0 and resource is not None:
        with _lock:
            applied = _apply(limit_mb) if _active == 0 else _saved is not None
            _active += applied
    try:
        yield
    except MemoryError:
        if limit_mb > 0:
            raise MemoryLimitExceeded(limit_mb) from None
        raise
    finally:
        if applied:
            with _lock:
                _active -= 1
                if _active == 0 and _saved is not None:
                    resource.setrlimit(resource.RLIMIT_AS, _saved)
                    _saved = None


def _apply(limit_mb: int) -> bool:
    """Set the cap (under ``_lock``); whether it was set."""
    global _saved
    used = address_space_bytes()
    if used is None:
        return False
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = used + limit_mb * 1024 * 1024
    if hard != resource.RLIM_INFINITY:
        cap = min(cap, hard)
    if soft != resource.RLIM_INFINITY and soft <= cap:
        return False  # a tighter limit is already in place
    try:
        resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    except (ValueError, OSError):
        log.warning("could not set a memory limit of %d MiB", limit_mb)
        return False
    _saved = (soft, hard)
    return True
