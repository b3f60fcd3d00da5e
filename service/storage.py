"""A full disk, told apart from an outage: 507 problems naming the storage, and free space."""

from __future__ import annotations

import contextlib
import errno
import shutil
from collections.abc import Iterator
from pathlib import Path

from .problems import Problem

FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})
SQLITE_FULL = "database or disk is full"
POSTGRES_DISK_FULL = "53100"


def is_storage_full(exc: BaseException) -> bool:
    """Whether ``exc`` (or what it wraps) says a disk or quota is full."""
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        seen.add(id(current))
        if isinstance(current, OSError) and current.errno in FULL_ERRNOS:
            return True
        if SQLITE_FULL in str(current):
            return True
        if getattr(current, "sqlstate", None) == POSTGRES_DISK_FULL:
            return True
        current = getattr(current, "orig", None) or current.__cause__ or current.__context__
    return False


def storage_full(storage: str) -> Problem:
    """The 507 problem for a full ``storage`` (a name for clients, never a path)."""
    return Problem(507, "Insufficient storage", f"the {storage} is full; delete recordings or "
                   "retry later", slug="storage-full", storage=storage,
                   headers={"Retry-After": "60"})


@contextlib.contextmanager
def refuse_when_full(storage: str) -> Iterator[None]:
    """Turn a full-disk error raised in the block into the 507 problem naming ``storage``."""
    try:
        yield
    except Problem:
        raise
    except Exception as exc:
        if is_storage_full(exc):
            raise storage_full(storage) from exc
        raise


def free_bytes(path: Path) -> int:
    """Bytes free for unprivileged users on the file system holding ``path``."""
    path.mkdir(parents=True, exist_ok=True)
    return shutil.disk_usage(path).free
