"""Upload throughput of `bonefit serve` against writing the same bytes to disk, and the server's
peak memory during a 1 GiB upload.

Per run: build a valid sensor CSV of SIZE bytes in memory (the example walk repeated, 60 Hz time
stamps), write it to a file in the server's data directory and time that (the disk baseline:
write + close, no fsync, as the server does; the page cache is synced before each measurement;
timed before and again after the upload, and averaged, so that a burst of CPU steal on a shared
host hits both sides alike; also with fsync), POST it to a bare uvicorn app that discards the
body (the HTTP stack's ceiling), then POST the file to ``/v1/recordings`` over loopback with
``socket.sendfile`` (a client that costs next to no CPU, so the server is what is measured) and
time it until the 201 arrives; meanwhile sample the RSS of the server's process tree every
20 ms; after it, for context only, time writing the same bytes to a new file while the others
are kept (as the upload's spool). The server runs in its default mode (embedded workers,
SQLite, local artifacts), started and idle before anything is timed. Median of RUNS runs; the
share of CPU time the host stole meanwhile is printed with the table.

    python benchmarks/service_upload.py [--size-mib 1024] [--runs 5]

Acceptance (issue 4): upload ≥ 50 % of the disk baseline; API process RSS < 200 MB.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import socket
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import httpx
from service_common import (
    EXAMPLE,
    clean_env,
    cpu_ticks,
    free_port,
    machine,
    median,
    running_server,
    spawn,
    status_kib,
    steal_note,
    table,
    temp_dir,
    tree,
)

BLOCK = 1024 * 1024


def sensor_csv_blocks(size: int) -> list[bytes]:
    """About ``size`` bytes of a valid sensor CSV (the example's rows, re-timed), in blocks."""
    lines = EXAMPLE.read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("time,"))
    head = "\n".join(lines[: start + 1]) + "\n"
    rows = [line.split(",", 1)[1] for line in lines[start + 1:] if line.strip()]
    blocks, pending, pending_size, total, frame = [head.encode()], [], 0, len(head), 0
    while total < size:
        text = f"{frame / 60:.6f},{rows[frame % len(rows)]}\n"
        pending.append(text)
        pending_size += len(text)
        total += len(text)
        frame += 1
        if pending_size >= BLOCK:
            blocks.append("".join(pending).encode())
            pending, pending_size = [], 0
    if pending:
        blocks.append("".join(pending).encode())
    return blocks


def write_baseline(path: Path, blocks: list[bytes], *, fsync: bool = False) -> float:
    """Seconds to write ``blocks`` to ``path`` (write + close, and fsync if asked)."""
    start = time.perf_counter()
    with path.open("wb") as fh:
        for block in blocks:
            fh.write(block)
        if fsync:
            fh.flush()
            os.fsync(fh.fileno())
    return time.perf_counter() - start


CEILING_APP = """
import sys, uvicorn

async def app(scope, receive, send):
    if scope["type"] != "http":
        return
    while (await receive()).get("more_body"):
        pass
    await send({"type": "http.response.start", "status": 201, "headers": []})
    await send({"type": "http.response.body", "body": b"{}"})

uvicorn.run(app, host="127.0.0.1", port=int(sys.argv[1]), log_level="warning")
"""


def transport_ceiling(path: Path) -> float:
    """Seconds to POST ``path`` to a bare uvicorn app that discards the body: the HTTP stack's
    own ceiling on this machine, whatever the service does with the bytes."""
    port = free_port()
    log = path.parent / "ceiling.log"
    proc = spawn([sys.executable, "-c", CEILING_APP, str(port)], clean_env(), log)
    try:
        base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port)):
                break
            time.sleep(0.1)
        _, elapsed, _ = upload(base, path)
        return elapsed
    finally:
        proc.stop()


class RssSampler(threading.Thread):
    """Samples VmRSS of a process tree (sum, and the main process alone) until stopped."""

    def __init__(self, pid: int, interval: float = 0.02) -> None:
        super().__init__(daemon=True)
        self.pid = pid
        self.interval = interval
        self.peak_tree_kib = 0
        self.peak_main_kib = 0
        self._stop_event = threading.Event()

    def run(self) -> None:
        while not self._stop_event.is_set():
            pids = tree(self.pid)
            self.peak_tree_kib = max(self.peak_tree_kib,
                                     sum(status_kib(p, "VmRSS") for p in pids))
            self.peak_main_kib = max(self.peak_main_kib, status_kib(self.pid, "VmRSS"))
            self._stop_event.wait(self.interval)

    def stop(self) -> None:
        self._stop_event.set()
        self.join()


def upload(base_url: str, path: Path) -> tuple[float, float, dict[str, object]]:
    """POST ``path`` as the raw body with sendfile: seconds until the last byte was handed to
    the socket, seconds until the response, and the response's JSON."""
    host, port = base_url.removeprefix("http://").split(":")
    size = path.stat().st_size
    head = (f"POST /v1/recordings?filename=upload.csv&format=sensor-csv HTTP/1.1\r\n"
            f"Host: {host}:{port}\r\nContent-Type: text/csv\r\n"
            f"Content-Length: {size}\r\nConnection: close\r\n\r\n").encode()
    start = time.perf_counter()
    with socket.create_connection((host, int(port))) as sock, path.open("rb") as fh:
        sock.sendall(head)
        sock.sendfile(fh)
        sent = time.perf_counter() - start
        chunks = []
        while data := sock.recv(65536):
            chunks.append(data)
    elapsed = time.perf_counter() - start
    raw = b"".join(chunks)
    status_line, _, rest = raw.partition(b"\r\n")
    body = rest.partition(b"\r\n\r\n")[2]
    parsed: dict[str, object] = {"status_line": status_line.decode(errors="replace")}
    try:
        parsed.update(json.loads(body))
    except ValueError:
        parsed["body"] = body[:300].decode(errors="replace")
    return sent, elapsed, parsed


@dataclass
class Run:
    disk_s: float
    fsync_s: float
    ceiling_s: float
    send_s: float
    upload_s: float
    status: str
    peak_main_mb: float
    peak_tree_mb: float
    hwm_main_mb: float
    fresh_s: float


def one_run(data_dir: Path, blocks: list[bytes]) -> Run:
    with running_server(data_dir / "server") as server:
        baseline_file = data_dir / "server" / "baseline.csv"
        os.sync()  # every measurement starts with no dirty pages pending
        fsync_s = write_baseline(baseline_file, blocks, fsync=True)
        os.sync()
        disk_s = write_baseline(baseline_file, blocks)
        os.sync()
        ceiling_s = transport_ceiling(baseline_file)
        os.sync()
        sampler = RssSampler(server.pid)
        sampler.start()
        try:
            send_s, upload_s, answer = upload(server.base_url, baseline_file)
        finally:
            sampler.stop()
        hwm = status_kib(server.pid, "VmHWM")
        # the baseline again, right after: on a shared host (CPU steal) the mean of the writes
        # before and after the upload is what the upload competed with
        rec_id = answer.get("id")
        if isinstance(rec_id, str):  # its file and page cache go before the second baseline
            httpx.delete(f"{server.base_url}/v1/recordings/{rec_id}", timeout=60)
        os.sync()
        disk_s = (disk_s + write_baseline(baseline_file, blocks)) / 2
        # not the baseline: a new file, as the server's spool, measured after the upload so
        # that it cannot free memory for it (on a VM, fresh page-cache pages can cost a lot)
        fresh_file = data_dir / "server" / "fresh.csv"
        os.sync()
        fresh_s = write_baseline(fresh_file, blocks)
        fresh_file.unlink()
        baseline_file.unlink()
    return Run(disk_s, fsync_s, ceiling_s, send_s, upload_s, str(answer.get("status_line", "")),
               sampler.peak_main_kib / 1024, sampler.peak_tree_kib / 1024, hwm / 1024, fresh_s)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size-mib", type=int, default=1024)
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    print(machine(), flush=True)
    ticks = cpu_ticks()
    blocks = sensor_csv_blocks(args.size_mib * BLOCK)
    size = sum(len(b) for b in blocks)
    runs = []
    with temp_dir("bonefit-bench-upload-") as tmp:
        for i in range(args.runs):
            run = one_run(tmp / f"run{i}", blocks)
            print(f"run {i + 1}: disk {size / run.disk_s / 1e6:.0f} MB/s, with fsync "
                  f"{size / run.fsync_s / 1e6:.0f} MB/s, HTTP ceiling "
                  f"{size / run.ceiling_s / 1e6:.0f} MB/s, upload "
                  f"{size / run.upload_s / 1e6:.0f} MB/s ({run.status}; body sent after "
                  f"{run.send_s:.2f} s, 201 after {run.upload_s:.2f} s), API RSS peak "
                  f"{run.peak_main_mb:.0f} MB, tree {run.peak_tree_mb:.0f} MB; new-file write "
                  f"{size / run.fresh_s / 1e6:.0f} MB/s", flush=True)
            runs.append(run)
    def rate(seconds: float) -> str:
        return f"{size / seconds / 1e6:.0f} MB/s"

    ratio = median([r.disk_s / r.upload_s for r in runs])
    rows = [
        ["disk write (baseline: write + close, as the server)",
         rate(median([r.disk_s for r in runs])), ""],
        ["disk write + fsync", rate(median([r.fsync_s for r in runs])), ""],
        ["disk write of a new file, after the upload (not the baseline)",
         rate(median([r.fresh_s for r in runs])),
         "the baseline rewrites a file it just truncated; the upload's spool is a new file"],
        ["bare uvicorn app discarding the body (HTTP ceiling)",
         rate(median([r.ceiling_s for r in runs])),
         f"{median([r.disk_s / r.ceiling_s for r in runs]):.0%} of disk"],
        ["upload, POST /v1/recordings", rate(median([r.upload_s for r in runs])),
         f"{ratio:.0%} of disk (≥ 50 %: {'yes' if ratio >= 0.5 else 'NO'}), "
         f"{median([r.fsync_s / r.upload_s for r in runs]):.0%} of disk + fsync, "
         f"{median([r.ceiling_s / r.upload_s for r in runs]):.0%} of the HTTP ceiling"],
        ["  of which: body received", f"{median([r.send_s for r in runs]):.2f} s",
         "until the client's last byte left"],
        ["  of which: after the body (sniff, store, record)",
         f"{median([r.upload_s - r.send_s for r in runs]):.2f} s", ""],
        ["API process RSS peak (sampled)", f"{median([r.peak_main_mb for r in runs]):.0f} MB",
         f"< 200 MB: {'yes' if max(r.peak_main_mb for r in runs) < 200 else 'NO'}"],
        ["API process VmHWM", f"{median([r.hwm_main_mb for r in runs]):.0f} MB", ""],
        ["server tree RSS peak (API + embedded workers)",
         f"{median([r.peak_tree_mb for r in runs]):.0f} MB", ""],
    ]
    print()
    print(table(f"Upload of {args.size_mib} MiB, median of {len(runs)} runs",
                ["measure", "value", "note"], rows))
    print(steal_note(ticks))
    statuses = {r.status for r in runs}
    if statuses != {"HTTP/1.1 201 Created"}:
        raise SystemExit(f"unexpected answers: {statuses}")


if __name__ == "__main__":
    main()
