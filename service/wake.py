"""Wake idle workers when a job is queued: a local notification beside the embedded queue.

The embedded queue (huey on SQLite) cannot block a reader, so an idle worker would poll it.
Instead each idle worker process binds a Unix datagram socket and lists itself in a
directory next to the queue file (``queue.db.wake/<pid>``); ``notify`` (the enqueuing
process: the API, a worker handing a job back, the reaper) sends one byte to every listed
worker. Every listener wakes, drains its own socket and races for the job: the queue's
compare-and-set dequeue gives it to one. A worker waits with a timeout, so a lost
notification costs one poll interval, never a job.

On Linux the sockets live in the abstract namespace (no path length limit, nothing to clean
up); their names carry the directory's device and inode, so every process that opens the
same queue file agrees on them. Elsewhere the socket files sit in the directory itself.
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import socket
import sys
from pathlib import Path

log = logging.getLogger("bonefit.worker")

ABSTRACT = sys.platform == "linux"
"""Abstract socket names (Linux); elsewhere socket files in the directory."""


class Waker:
    """The notification channel of one queue file: ``notify`` on enqueue, ``wait`` when idle."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        self.sock: socket.socket | None = None
        self.entry: Path | None = None
        directory.mkdir(parents=True, exist_ok=True)
        info = directory.stat()
        self._prefix = f"\0bonefit-wake/{info.st_dev:x}/{info.st_ino:x}/"

    def _address(self, name: str) -> str:
        return self._prefix + name if ABSTRACT else str(self.directory / name)

    def notify(self) -> None:
        """Wake every listening worker (a worker gone without unregistering is dropped)."""
        try:
            entries = list(os.scandir(self.directory))
        except OSError:
            return  # no directory: nobody listens (the queued job waits for a poll)
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sender:
            sender.setblocking(False)
            for entry in entries:
                try:
                    sender.sendto(b"!", self._address(entry.name))
                except (ConnectionRefusedError, FileNotFoundError):
                    with contextlib.suppress(OSError):  # its process is gone
                        os.unlink(entry.path)
                except OSError:
                    pass  # a full buffer: that worker has wake-ups pending already

    def listen(self) -> None:
        """Bind this process's socket and list it (once; a failure leaves only the poll)."""
        if self.sock is not None:
            return
        name = str(os.getpid())
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        try:
            if not ABSTRACT:
                Path(self._address(name)).unlink(missing_ok=True)
            sock.bind(self._address(name))
            sock.setblocking(False)
            entry = self.directory / name
            entry.touch()
        except OSError as exc:
            sock.close()
            log.warning("no wake-up socket in %s (%s): idle workers poll", self.directory, exc)
            self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)  # waits time out
            return
        self.sock, self.entry = sock, entry

    def drain(self) -> None:
        """Forget the wake-ups received so far (before looking at the queue)."""
        if self.sock is None:
            return
        with contextlib.suppress(OSError):
            while self.sock.recv(64):
                pass

    def wait(self, timeout: float) -> None:
        """Block until a notification arrives or ``timeout`` seconds pass; the first call
        starts listening and returns at once (look at the queue again: what was queued
        before that sent no notification here)."""
        if self.sock is None:
            self.listen()
            return
        select.select([self.sock], [], [], timeout)

    def interrupt(self) -> None:
        """End this process's :meth:`wait` now (shutdown; safe in a signal handler)."""
        if self.sock is not None and self.entry is not None:
            with contextlib.suppress(OSError):
                self.sock.sendto(b"!", self._address(self.entry.name))

    def close(self) -> None:
        """Unlist and close this process's socket."""
        if self.entry is not None:
            self.entry.unlink(missing_ok=True)
            if not ABSTRACT:
                Path(self._address(self.entry.name)).unlink(missing_ok=True)
        if self.sock is not None:
            self.sock.close()
        self.sock = self.entry = None
