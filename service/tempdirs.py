"""Each worker process's private temporary directory, and the leftovers of dead ones."""

from __future__ import annotations

import logging
import os
import shutil
import socket
from pathlib import Path

log = logging.getLogger("bonefit.worker")


def private_tmp(data_dir: Path) -> Path:
    """This process's own temporary directory, ``data_dir/tmp/<host>-<pid>``, made after
    removing the ones of this host's processes that died without cleaning up (kill -9)."""
    root = data_dir / "tmp"
    root.mkdir(parents=True, exist_ok=True)
    host = socket.gethostname()
    for entry in root.iterdir():
        owner, _, pid = entry.name.rpartition("-")
        if owner == host and pid.isdigit() and not _alive(int(pid)):
            _remove(entry)
    own = root / f"{host}-{os.getpid()}"
    _remove(own)  # a recycled pid's leftovers
    own.mkdir()
    return own


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def _remove(path: Path) -> None:
    """Delete the directory tree at ``path`` if there is one; log (not raise) a failure."""
    try:
        shutil.rmtree(path)
    except FileNotFoundError:
        pass
    except OSError as exc:
        log.warning("could not remove the temporary directory %s: %s", path, exc)
