"""The upload sink: every byte lands in the file, hashed and counted, by whichever write path
the file system allows."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import anyio
import pytest

from bonefit.service import uploads
from bonefit.service.problems import Problem
from bonefit.service.uploads import BLOCK_BYTES, UploadSink


def body(size: int) -> bytes:
    line = b"0.5,1.0,2.0,3.0,1,0,0,0\n"
    data = b"time,pelvis.x,pelvis.y,pelvis.z,pelvis.qw,pelvis.qx,pelvis.qy,pelvis.qz\n"
    return (data + line * (size // len(line) + 1))[:size]


def sink_through(path: Path, data: bytes, chunk: int, limit: int | None = None,
                 count_rows: bool = True) -> UploadSink:
    sink = UploadSink(path, limit or len(data), count_rows=count_rows)

    async def run() -> None:
        for start in range(0, len(data), chunk):
            sink.feed(data[start:start + chunk])
            await sink.drain()
        await sink.close()

    try:
        anyio.run(run)
    except BaseException:
        sink.discard()  # as the route does: a refused upload leaves no file
        raise
    return sink


@pytest.mark.parametrize("direct", ["available", "absent", "refuses-writes"])
def test_every_byte_lands_hashed_and_counted(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                             direct: str) -> None:
    if direct == "absent":
        monkeypatch.setattr(uploads, "_open_direct", lambda path: None)
    refused: list[int] = []
    if direct == "refuses-writes":  # as some file systems do: O_DIRECT opens, writes fail
        opened: set[int] = set()
        real_pwrite = os.pwrite

        def open_direct(path: Path) -> int:
            fd = os.open(path, os.O_WRONLY)
            opened.add(fd)
            return fd

        def pwrite(fd: int, data: memoryview, offset: int) -> int:
            if fd in opened:
                refused.append(fd)
                raise OSError(22, "Invalid argument")
            return real_pwrite(fd, data, offset)

        monkeypatch.setattr(uploads, "_open_direct", open_direct)
        monkeypatch.setattr(uploads.os, "pwrite", pwrite)
    data = body(2 * BLOCK_BYTES + 12_345)  # two whole blocks and an unaligned tail
    path = tmp_path / "up.csv"
    sink = sink_through(path, data, chunk=100_003)
    assert path.read_bytes() == data
    assert sink.size == len(data)
    assert sink.sha256.hexdigest() == hashlib.sha256(data).hexdigest()
    assert sink.rows is not None
    assert sink.rows.rows == data.count(b"\n") + (not data.endswith(b"\n"))
    assert bool(refused) == (direct == "refuses-writes")


def test_over_the_limit_is_refused_and_leaves_nothing(tmp_path: Path) -> None:
    data = body(BLOCK_BYTES + 10)
    path = tmp_path / "up.csv"
    with pytest.raises(Problem) as caught:
        sink_through(path, data, chunk=65_536, limit=BLOCK_BYTES)
    assert caught.value.status == 413
    assert not path.exists()


def test_rows_are_not_counted_when_the_file_cannot_be_a_sensor_csv(tmp_path: Path) -> None:
    data = body(BLOCK_BYTES + 99)
    path = tmp_path / "up.npz"
    sink = sink_through(path, data, chunk=65_536, count_rows=False)
    assert sink.rows is None
    assert len(sink._threads) == 2  # hash and write only
    assert path.read_bytes() == data
    assert sink.sha256.hexdigest() == hashlib.sha256(data).hexdigest()
