"""A full disk, told apart from an outage: 507 problems naming the storage, and free space."""

from __future__ import annotations

import contextlib
import shutil
from collections.abc import Iterator
from pathlib import Path

from .errors import FULL_ERRNOS, StorageFull, chain
from .problems import Problem


def is_storage_full(exc: BaseException) -> bool:
    """Whether ``exc`` (or what it wraps) says a back-end (:class:`StorageFull`, raised by
    the adapters) or the local file system (the upload spool: ENOSPC, EDQUOT) is full."""
    return any(isinstance(e, StorageFull) or (isinstance(e, OSError) and e.errno in FULL_ERRNOS)
               for e in chain(exc))


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
