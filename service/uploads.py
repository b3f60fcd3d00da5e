"""Streaming uploads: request body (raw or multipart) → temporary file, hashed and size-limited."""

from __future__ import annotations

import hashlib
import json
import mmap
import os
import queue
import shutil
import threading
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import anyio.to_thread
from python_multipart.multipart import MultipartParser, MultipartState, parse_options_header

from bonefit.estimation.errors import BonefitError, InputError
from bonefit.estimation.io.sniff import RowCounter, sniff_file

from .kinds import KINEMATICS_FORMATS, SENSOR_FORMATS
from .problems import Problem

BLOCK_BYTES = 2 * 1024 * 1024
POOL_BLOCKS = 6
DIRECT_ALIGN = 4096  # O_DIRECT writes: whole blocks of the file system at aligned offsets
_DONE = None
SUMMARY_BYTES = 16 * 1024
"""Hard cap on a recording's stored summary, as JSON (documented in docs/service.md)."""
SUMMARY_ITEMS = 256
SUMMARY_STRING = 256


def _open_direct(path: Path) -> int | None:
    """A second descriptor of ``path`` that bypasses the page cache, or None where the
    platform or file system has no O_DIRECT (tmpfs, macOS)."""
    flag = getattr(os, "O_DIRECT", 0)
    if not flag:
        return None
    try:
        return os.open(path, os.O_WRONLY | flag)
    except OSError:
        return None


def _pwrite_all(fd: int, view: memoryview, offset: int) -> None:
    while view:
        written = os.pwrite(fd, view, offset)
        offset += written
        view = view[written:]


def too_large(limit: int) -> Problem:
    """413 for an upload over ``limit`` bytes."""
    return Problem(413, "Upload too large", f"the upload exceeds the limit of {limit} bytes",
                   slug="upload-too-large", limit=limit)


class UploadSink:
    """Hashes, counts the rows of, and writes chunks to a file off the event loop, refusing
    more than ``limit``.

    Chunks are copied into a small pool of ``BLOCK_BYTES`` buffers that pass through a
    pipeline of threads, one per stage (hash, count rows, write: each releases the GIL), while
    the event loop keeps receiving; the loop waits only when every buffer is in use. Copying
    frees each received chunk at once, so its memory is reused for the next one instead of a
    stream of fresh pages. Counting rows as they arrive (``count_rows``: when the file may be
    a sensor CSV) spares the summary a second pass.
    Whole blocks are written with ``O_DIRECT`` where the file system allows it: an upload is
    read once, later, by a worker, so copying it into the page cache would only cost CPU
    (a third of a second per GiB here) and evict what is worth caching.
    """

    def __init__(self, path: Path, limit: int, *, count_rows: bool = True) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self.limit = limit
        self.size = 0
        self.sha256 = hashlib.sha256()
        self.rows = RowCounter() if count_rows else None
        self._pending: list[bytes] = []
        self._buf: mmap.mmap | None = None
        self._fill = 0
        self._free: queue.SimpleQueue[mmap.mmap] = queue.SimpleQueue()
        self._blocks = 0
        self._error: BaseException | None = None
        self._stopped = False
        self._fd = -1
        self._direct: int | None = None
        self._offset = 0
        stages = [self._hash, *([self._count] if count_rows else []), self._write]
        self._queues: list[queue.SimpleQueue[tuple[mmap.mmap, int] | None]] = [
            queue.SimpleQueue() for _ in stages]
        self._threads = [
            threading.Thread(target=self._run_stage, args=(i, stage), daemon=True,
                             name=f"upload{stage.__name__}")
            for i, stage in enumerate(stages)]

    def _start(self) -> None:
        """Open the file and start the threads, once there is a block to hand on (an upload
        still waiting for its first ``BLOCK_BYTES``, e.g. a slow client, holds neither)."""
        if self._fd >= 0 or self._threads[0].is_alive():
            return
        self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        self._direct = _open_direct(self.path)
        for thread in self._threads:
            thread.start()

    def feed(self, data: bytes) -> None:
        """Accept a chunk (raises the 413 problem past the limit)."""
        self.size += len(data)
        if self.size > self.limit:
            raise too_large(self.limit)
        self._pending.append(data)

    def _hash(self, buf: mmap.mmap, length: int) -> None:
        self.sha256.update(memoryview(buf)[:length])

    def _count(self, buf: mmap.mmap, length: int) -> None:
        assert self.rows is not None
        self.rows.feed(buf, length)

    def _write(self, buf: mmap.mmap, length: int) -> None:
        view = memoryview(buf)[:length]
        if self._direct is not None:
            aligned = length - length % DIRECT_ALIGN
            try:
                _pwrite_all(self._direct, view[:aligned], self._offset)
            except OSError:  # opened with O_DIRECT but refuses such writes: write buffered
                os.close(self._direct)
                self._direct = None
            else:
                self._offset += aligned
                view = view[aligned:]
        _pwrite_all(self._fd, view, self._offset)
        self._offset += len(view)

    def _close_files(self) -> None:
        for fd in (self._fd, self._direct):
            if fd is not None and fd >= 0:
                os.close(fd)
        self._fd, self._direct = -1, None

    def _run_stage(self, index: int, stage: Callable[[mmap.mmap, int], None]) -> None:
        source = self._queues[index]
        last = index == len(self._queues) - 1
        while (item := source.get()) is not _DONE:
            if self._error is None and not self._stopped:
                try:
                    stage(*item)
                except BaseException as exc:  # reported to the request by drain or close
                    self._error = exc
            if last:
                self._free.put(item[0])
            else:
                self._queues[index + 1].put(item)
        if not last:
            self._queues[index + 1].put(_DONE)

    async def _take(self) -> mmap.mmap:
        try:
            return self._free.get_nowait()
        except queue.Empty:
            if self._blocks < POOL_BLOCKS:  # the pool grows as the upload does
                self._blocks += 1
                return mmap.mmap(-1, BLOCK_BYTES)  # page-aligned, as O_DIRECT needs
            # backpressure: the disk is behind the network
            return await anyio.to_thread.run_sync(self._free.get)

    def _hand_over(self) -> None:
        if self._error is not None:
            raise self._error
        if self._buf is not None and self._fill:
            self._start()
            self._queues[0].put((self._buf, self._fill))
            self._buf, self._fill = None, 0

    async def drain(self, *, force: bool = False) -> None:
        """Copy what was fed into the buffers, handing on full ones (the last too with
        ``force``)."""
        for data in self._pending:
            view = memoryview(data)
            while view:
                if self._buf is None:
                    self._buf = await self._take()
                n = min(len(view), BLOCK_BYTES - self._fill)
                self._buf[self._fill:self._fill + n] = view[:n]
                self._fill += n
                view = view[n:]
                if self._fill == BLOCK_BYTES:
                    self._hand_over()
        self._pending.clear()
        if force:
            self._hand_over()

    async def close(self) -> None:
        """Flush, wait for the threads, and close the file."""
        await self.drain(force=True)
        self._start()  # an empty upload still makes an (empty) file
        self._queues[0].put(_DONE)
        for thread in self._threads:
            await anyio.to_thread.run_sync(thread.join)
        self._close_files()
        if self._error is not None:
            raise self._error

    def discard(self) -> None:
        """Stop the threads, close and delete the file."""
        if self._threads[0].is_alive():
            self._stopped = True  # the threads skip what is still queued
            self._queues[0].put(_DONE)
        for thread in self._threads:
            if thread.ident is not None:  # started
                thread.join()
        self._close_files()
        self.path.unlink(missing_ok=True)


async def receive_raw(chunks: AsyncIterator[bytes], sink: UploadSink) -> None:
    """The whole body is the file."""
    async for chunk in chunks:
        sink.feed(chunk)
        await sink.drain()


def bad_multipart(detail: str, field: str | None = None) -> Problem:
    """400 for a multipart body that cannot be parsed."""
    return Problem(400, "Bad multipart body", detail, slug="bad-multipart",
                   location=None if field is None else {"field": field})


class FilePart:
    """The multipart parser's callbacks: collect each part's headers, feed the first part
    named ``file`` to ``sink``, and keep its filename and media type."""

    def __init__(self, sink: UploadSink) -> None:
        self.sink = sink
        self.headers: dict[str, bytes] = {}
        self.field = b""
        self.value = b""
        self.in_file = False
        self.found = False
        self.filename: str | None = None
        self.type: str | None = None

    def callbacks(self) -> Any:
        """The callbacks by the parser's names."""
        return {"on_part_begin": self.on_part_begin, "on_header_field": self.on_header_field,
                "on_header_value": self.on_header_value, "on_header_end": self.on_header_end,
                "on_headers_finished": self.on_headers_finished,
                "on_part_data": self.on_part_data}

    def on_part_begin(self) -> None:
        """A new part: forget the last one's headers."""
        self.headers = {}
        self.in_file = False

    def on_header_field(self, data: bytes, start: int, end: int) -> None:
        """A piece of a header's name."""
        self.field += data[start:end]  # bounded by the parser (max_header_size)

    def on_header_value(self, data: bytes, start: int, end: int) -> None:
        """A piece of a header's value."""
        self.value += data[start:end]

    def on_header_end(self) -> None:
        """A complete header."""
        self.headers[self.field.decode("latin-1").lower()] = self.value
        self.field, self.value = b"", b""

    def on_headers_finished(self) -> None:
        """The part's headers are complete: is it the ``file`` field?"""
        _, disp = parse_options_header(self.headers.get("content-disposition", b""))
        if disp.get(b"name") == b"file" and not self.found:
            self.in_file = self.found = True
            name = disp.get(b"filename")
            self.filename = name.decode("utf-8", "replace") if name else None
            ctype = self.headers.get("content-type")
            self.type = ctype.decode("latin-1") if ctype else None

    def on_part_data(self, data: bytes, start: int, end: int) -> None:
        """A piece of a part's body: the file's go to the sink."""
        if self.in_file:
            self.sink.feed(data[start:end])


def multipart_parser(content_type: str, part: FilePart) -> MultipartParser:
    """A parser for the form's boundary calling ``part``; 400 without a usable boundary."""
    _, options = parse_options_header(content_type)
    boundary = options.get(b"boundary")
    if not boundary:
        raise bad_multipart("the Content-Type has no boundary", field="Content-Type")
    try:
        return MultipartParser(boundary, part.callbacks())
    except Exception as exc:
        raise bad_multipart(f"bad boundary: {exc}", field="Content-Type") from None


async def receive_multipart(chunks: AsyncIterator[bytes], content_type: str,
                            sink: UploadSink) -> tuple[str | None, str | None]:
    """Stream the ``file`` field of a multipart form into ``sink``; its filename and type."""
    part = FilePart(sink)
    parser = multipart_parser(content_type, part)
    async for chunk in chunks:
        try:
            parser.write(chunk)
        except Problem:
            raise
        except Exception as exc:
            raise bad_multipart(f"cannot parse the form: {exc}") from None
        await sink.drain()
    parser.finalize()
    if parser.state != MultipartState.END:
        raise bad_multipart("the form ends before its closing boundary")
    if not part.found:
        raise Problem(422, "Missing file", "the multipart form has no 'file' field",
                      slug="invalid-request", field="file")
    return part.filename, part.type


def clean_spool(spool: Path, max_age: float = 3600.0) -> int:
    """Remove uploads left behind by a killed process (untouched for ``max_age`` s); how many."""
    removed = 0
    if not spool.is_dir():
        return 0
    for entry in spool.iterdir():
        try:
            paths = [entry, *entry.iterdir()] if entry.is_dir() else [entry]
            if time.time() - max(p.stat().st_mtime for p in paths) > max_age:
                shutil.rmtree(entry) if entry.is_dir() else entry.unlink()
                removed += 1
        except OSError:
            continue  # vanished or being finished by its request
    return removed


def sniff(path: Path, fmt: str, filename: str | None,
          counted_rows: int | None = None) -> tuple[str, dict[str, Any]]:
    """The API format name and quick summary of the file (``counted_rows``: its rows, counted
    while it was received); InputError when it is unreadable or is not the declared ``fmt``
    (its detail then names the format)."""
    try:
        return _sniff(path, fmt, filename, counted_rows)
    except BonefitError as exc:
        if fmt != "auto" and not exc.detail.startswith("format="):
            exc.detail = f"format={fmt}: {exc.detail}"
            exc.args = (exc.detail,)
        raise
    except Exception as exc:  # whatever a reader trips on in a client's file, the file is bad
        raise InputError(f"cannot read the file as {fmt}: {type(exc).__name__}",
                         field="file") from None


def cap_summary(summary: dict[str, Any], limit: int = SUMMARY_BYTES) -> dict[str, Any]:
    """``summary`` cut to at most ``limit`` bytes of JSON, so that a listing never re-serves
    bulk data whatever a file declares: strings keep their first ``SUMMARY_STRING``
    characters and lists their first ``SUMMARY_ITEMS`` items, then fewer until it fits; a cut
    list's ``<key>_total`` member gives its length."""
    if _json_size(summary) <= limit:
        return summary
    items = SUMMARY_ITEMS
    while True:
        out: dict[str, Any] = {}
        for key, value in summary.items():
            if isinstance(value, list):
                out[key] = [_cap_scalar(v) for v in value[:items]]
                if len(value) > items:
                    out[f"{key}_total"] = len(value)
            else:
                out[key] = _cap_scalar(value)
        if _json_size(out) <= limit:
            return out
        if items == 0:
            return {"truncated": True}
        items //= 4


def _cap_scalar(value: Any) -> Any:
    if isinstance(value, str) and len(value) > SUMMARY_STRING:
        return value[:SUMMARY_STRING] + "…"
    if isinstance(value, dict | list):
        return None if _json_size(value) > SUMMARY_STRING else value
    return value


def _json_size(value: Any) -> int:
    return len(json.dumps(value, separators=(",", ":"), default=str).encode())


def _sniff(path: Path, fmt: str, filename: str | None,
           counted_rows: int | None) -> tuple[str, dict[str, Any]]:
    to_library = {**SENSOR_FORMATS, **KINEMATICS_FORMATS}
    found, summary = sniff_file(path, to_library.get(fmt, fmt), filename=filename,
                                counted_rows=counted_rows)
    to_api = {v: k for k, v in to_library.items()}
    return to_api.get(found, found), summary
