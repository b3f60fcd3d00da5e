"""Hostile uploads against `bonefit serve`: time to the answer and the API process's RSS growth.

Each bomb is built in a temporary directory and POSTed to ``/v1/recordings`` of a server
started with no workers; meanwhile the RSS of the server process is sampled every 20 ms. Then
``GET /v1/recordings`` is timed and its size measured (a refused upload must leave nothing
behind; an accepted one must not re-serve bulk data).

Bombs (issue 16 §1):

* ``npz-sensors``: a ~200 KB NPZ whose ``sensors.npy`` declares 50 M one-character entries
  (200 MB of deflated zeros);
* ``npz-positions``: a ~250 KB NPZ whose ``positions.npy`` declares 50 M × 15 × 3 float64s of
  which only 4 MB of zeros are stored (a truncated, lying member);
* ``csv-line``: a 50 MB accelerations CSV that is a single header line of 12.5 M columns;
* ``bvh-random``: 1 MB of random bytes declared ``format=bvh``;
* ``csv-wide``: a valid 800 KB accelerations-CSV header (1,300 sensors, 3,900 columns of 200
  characters), accepted: its stored summary is what the listing re-serves.

    python benchmarks/upload_bombs.py [--timeout 30]

Acceptance (issue 16): each refused in under 1 s with the API's RSS growing by < 50 MB, and
the listing stays small.
"""

from __future__ import annotations

import argparse
import os
import threading
import time
import zipfile
from collections.abc import Callable
from pathlib import Path

import httpx
import numpy as np
from service_common import running_server, status_kib, temp_dir

CHUNK = 1 << 20


def _npy_header(dtype: str, shape: tuple[int, ...]) -> bytes:
    header = {"descr": dtype, "fortran_order": False, "shape": shape}
    import io

    out = io.BytesIO()
    np.lib.format.write_array_header_1_0(out, header)
    return out.getvalue()


def _write_member(archive: zipfile.ZipFile, name: str, header: bytes, zeros: int) -> None:
    with archive.open(name, "w", force_zip64=True) as member:
        member.write(header)
        block = bytes(CHUNK)
        while zeros > 0:
            member.write(block[:min(zeros, CHUNK)])
            zeros -= CHUNK


def npz_sensors(path: Path) -> tuple[Path, str]:
    """sensors.npy: 50 M entries of <U1 (200 MB of zeros, deflated to about 200 KB)."""
    out = path / "sensors-bomb.npz"
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        _write_member(archive, "positions.npy", _npy_header("<f8", (10, 1, 3)), 240)
        _write_member(archive, "quaternions.npy", _npy_header("<f8", (10, 1, 4)), 320)
        _write_member(archive, "sensors.npy", _npy_header("<U1", (50_000_000,)), 200_000_000)
        _write_member(archive, "fps.npy", _npy_header("<f8", ()), 8)
    return out, "npz"


def npz_positions(path: Path) -> tuple[Path, str]:
    """positions.npy declaring 50 M × 15 × 3 float64 (18 GB) with 256 MB of zeros stored."""
    out = path / "positions-bomb.npz"
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        _write_member(archive, "positions.npy", _npy_header("<f8", (50_000_000, 15, 3)),
                      1 << 28)
    return out, "npz"


def csv_line(path: Path) -> tuple[Path, str]:
    """A 50 MB accelerations CSV: one header line of 12.5 M three-character columns."""
    out = path / "line.csv"
    with out.open("wb") as fh:
        fh.write(b"time")
        cell = b",a.x" * (CHUNK // 4)
        for _ in range(50):
            fh.write(cell)
    return out, "accelerations-csv"


def csv_wide(path: Path) -> tuple[Path, str]:
    """A valid accelerations CSV within the limits whose header is 800 KB: 1,300 sensors of
    three 200-character columns (accepted; its summary must stay small)."""
    out = path / "wide.csv"
    names = [f"{'s' * 190}{i:05d}" for i in range(1300)]
    header = ["time", *(f"{n}.a{a}" for n in names for a in "xyz")]
    row = ",".join(["0"] + ["1"] * (len(header) - 1))
    out.write_text(",".join(header) + "\n" + row + "\n")
    return out, "accelerations-csv"


def bvh_random(path: Path) -> tuple[Path, str]:
    """1 MB of random bytes declared as a BVH."""
    out = path / "random.bvh"
    out.write_bytes(np.random.default_rng(1).bytes(1 << 20))
    return out, "bvh"


BOMBS: dict[str, Callable[[Path], tuple[Path, str]]] = {
    "npz-sensors": npz_sensors, "npz-positions": npz_positions, "csv-line": csv_line,
    "bvh-random": bvh_random, "csv-wide": csv_wide}


def measure(base_url: str, pid: int, path: Path, fmt: str, timeout: float) -> dict[str, object]:
    """POST ``path``; status, seconds, RSS growth (MB) of ``pid``, problem detail."""
    before = status_kib(pid, "VmRSS")
    peak = [before]
    done = threading.Event()

    def sample() -> None:
        while not done.is_set():
            peak[0] = max(peak[0], status_kib(pid, "VmRSS"))
            time.sleep(0.02)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    start = time.perf_counter()
    try:
        with path.open("rb") as fh:
            reply = httpx.post(f"{base_url}/v1/recordings",
                               params={"filename": path.name, "format": fmt},
                               content=fh, timeout=timeout)
        status: object = reply.status_code
        detail = reply.json().get("detail", "") if reply.status_code != 201 else "accepted"
    except httpx.TimeoutException:
        status, detail = "timeout", f"no answer within {timeout:.0f} s"
    elapsed = time.perf_counter() - start
    done.set()
    sampler.join()
    return {"status": status, "seconds": elapsed, "rss_mb": (peak[0] - before) / 1024,
            "detail": str(detail)[:120]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--timeout", type=float, default=30.0,
                        help="seconds to wait for each answer (the old code took minutes)")
    parser.add_argument("--only", nargs="*", choices=list(BOMBS), default=list(BOMBS))
    args = parser.parse_args()
    with temp_dir("bonefit-bombs-") as tmp, running_server(tmp / "data", workers=0,
                                                           no_worker=True) as server:
        rows = []
        for name in args.only:
            path, fmt = BOMBS[name](tmp)
            size = os.path.getsize(path)
            row = measure(server.base_url, server.pid, path, fmt, args.timeout)
            path.unlink()
            rows.append((name, size, row))
            print(f"{name:14} {size / 1e6:8.2f} MB  {row['status']!s:8} "
                  f"{row['seconds']:7.2f} s  RSS +{row['rss_mb']:7.1f} MB  {row['detail']}",
                  flush=True)
        start = time.perf_counter()
        listing = httpx.get(f"{server.base_url}/v1/recordings", timeout=args.timeout)
        print(f"GET /v1/recordings: {listing.status_code}, {len(listing.content)} bytes, "
              f"{time.perf_counter() - start:.3f} s")


if __name__ == "__main__":
    main()
