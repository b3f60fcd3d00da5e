"""Job plumbing of `bonefit serve` (embedded mode: SQLite queue and store, local artifacts).

1. Job overhead: submit → succeeded for a tiny skeleton job (the example walk cut to 60 frames),
   one at a time, polling the job every 10 ms; median, with the estimation's own time measured
   in this process for comparison.
2. Status endpoint: GET /v1/jobs/{id} from 50 concurrent keep-alive clients (bare asyncio
   HTTP/1.1, one connection each) for a fixed time; requests/s and p50/p99 latency.
3. Throughput: jobs/minute for a batch of skeleton jobs on the full example walk (300 frames)
   with 1 and with 2 worker processes; with ``--distributed`` also with 1 and 2 `bonefit worker`
   processes behind `bonefit serve --no-worker`, on the Redis, PostgreSQL and S3 named by the
   BONEFIT_* variables of the environment.

    python benchmarks/service_jobs.py [--tiny-jobs 15] [--clients 50] [--seconds 5] [--batch 16]
                                      [--distributed]

Everything runs on loopback; numbers depend on the machine (2 shared cores where measured).
"""

from __future__ import annotations

import argparse
import asyncio
import os
import time
from datetime import datetime
from pathlib import Path

import httpx
from service_common import (
    EXAMPLE,
    cpu_seconds,
    machine,
    median,
    percentile,
    running_server,
    table,
    temp_dir,
    tree,
)

POLL = 0.01
TERMINAL = {"succeeded", "failed", "cancelled"}


def tiny_recording(path: Path, frames: int = 60) -> Path:
    lines = EXAMPLE.read_text().splitlines(keepends=True)
    start = next(i for i, line in enumerate(lines) if line.startswith("time,"))
    path.write_text("".join(lines[: start + 1 + frames]))
    return path


def upload(client: httpx.Client, path: Path) -> str:
    response = client.post("/v1/recordings", params={"filename": path.name, "format": "sensor-csv"},
                           content=path.read_bytes())
    response.raise_for_status()
    rec_id: str = response.json()["id"]
    return rec_id


def submit(client: httpx.Client, rec_id: str) -> str:
    response = client.post("/v1/jobs", json={"kind": "skeleton", "recording_id": rec_id})
    response.raise_for_status()
    job_id: str = response.json()["id"]
    return job_id


def wait(client: httpx.Client, job_id: str, timeout: float = 300.0) -> str:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = client.get(f"/v1/jobs/{job_id}").json()
        status: str = job["status"]
        if status in TERMINAL:
            if status != "succeeded":
                print(f"job {job_id} {status}: {job.get('error')}", flush=True)
            return status
        time.sleep(POLL)
    raise TimeoutError(f"job {job_id} did not finish in {timeout} s")


def estimation_seconds(path: Path, repeats: int = 5) -> float:
    """The skeleton estimation alone on ``path``, in this process (median)."""
    from bonefit.estimation.io.sensors import read_recording
    from bonefit.estimation.skeleton import estimate_skeleton

    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        estimate_skeleton(read_recording(path))
        times.append(time.perf_counter() - start)
    return float(median(times))


def job_overhead(tmp: Path, count: int) -> list[list[object]]:
    tiny = tiny_recording(tmp / "tiny.csv")
    with running_server(tmp / "overhead", workers=1) as server, \
            httpx.Client(base_url=server.base_url, timeout=30) as client:
        rec_id = upload(client, tiny)
        if wait(client, submit(client, rec_id)) != "succeeded":  # warm the worker
            raise SystemExit("the warm-up job failed")
        latencies, queued, ran = [], [], []
        for _ in range(count):
            start = time.perf_counter()
            job_id = submit(client, rec_id)
            status = wait(client, job_id)
            latencies.append(time.perf_counter() - start)
            if status != "succeeded":
                raise SystemExit(f"a tiny job ended {status}")
            job = client.get(f"/v1/jobs/{job_id}").json()
            queued.append(seconds(job["started_at"]) - seconds(job["created_at"]))
            ran.append(seconds(job["finished_at"]) - seconds(job["started_at"]))
    compute = estimation_seconds(tiny)

    def ms(value: float) -> str:
        return f"{value * 1000:.0f} ms"

    return [
        ["submit → succeeded (median)", ms(median(latencies)),
         f"min {ms(min(latencies))}, max {ms(max(latencies))}, n={count}"],
        ["  queued: created → started (median)", ms(median(queued)),
         "the worker polls an empty queue every 0.2 s"],
        ["  running: started → finished (median)", ms(median(ran)),
         "fetch input, estimate, write 3 results, store updates"],
        ["estimation alone (same file, in process)", ms(compute), ""],
        ["overhead (median − estimation)", ms(median(latencies) - compute),
         "queue, worker, store, artifacts, client polling (10 ms)"],
    ]


async def hammer(base_url: str, path: str, clients: int, seconds: float) -> list[float]:
    """``clients`` keep-alive connections sending GET ``path`` back to back for ``seconds``.

    A bare asyncio HTTP/1.1 client: httpx's connection pool, not the server, was the limit at
    50 concurrent requests on the 2-core machine measured (about 100 req/s even on /healthz).
    """
    host, port = base_url.removeprefix("http://").split(":")
    request = f"GET {path} HTTP/1.1\r\nHost: {host}:{port}\r\n\r\n".encode()
    latencies: list[float] = []
    deadline = time.perf_counter() + seconds

    async def one_client() -> None:
        reader, writer = await asyncio.open_connection(host, int(port))
        try:
            while time.perf_counter() < deadline:
                start = time.perf_counter()
                writer.write(request)
                head = await reader.readuntil(b"\r\n\r\n")
                length = 0
                for line in head.split(b"\r\n"):
                    if line.lower().startswith(b"content-length:"):
                        length = int(line.split(b":", 1)[1])
                await reader.readexactly(length)
                latencies.append(time.perf_counter() - start)
                if not head.startswith(b"HTTP/1.1 200"):
                    raise RuntimeError(f"{path} answered {head[:40]!r}")
        finally:
            writer.close()

    await asyncio.gather(*(one_client() for _ in range(clients)))
    return latencies


def status_endpoint(tmp: Path, clients: int, seconds: float) -> list[list[object]]:
    tiny = tiny_recording(tmp / "tiny.csv")
    rows: list[list[object]] = []
    with running_server(tmp / "status", workers=1) as server:
        with httpx.Client(base_url=server.base_url, timeout=30) as client:
            job_id = submit(client, upload(client, tiny))
            wait(client, job_id)
        for label, path in (("GET /v1/jobs/{id}", f"/v1/jobs/{job_id}"),
                            ("GET /healthz (reference: no store access)", "/healthz")):
            asyncio.run(hammer(server.base_url, path, clients, 1.0))  # warm-up
            start = time.perf_counter()
            latencies = asyncio.run(hammer(server.base_url, path, clients, seconds))
            elapsed = time.perf_counter() - start
            rows.append([f"{label}, {clients} concurrent clients",
                         f"{len(latencies) / elapsed:.0f} req/s",
                         f"p50 {percentile(latencies, 50) * 1000:.0f} ms, "
                         f"p99 {percentile(latencies, 99) * 1000:.0f} ms, n={len(latencies)}"])
    return rows


def seconds(stamp: str) -> float:
    return datetime.fromisoformat(stamp).timestamp()


def distributed_env() -> dict[str, str]:
    """The BONEFIT_* settings of this environment (queue, store, storage, S3 credentials)."""
    env = {k: v for k, v in os.environ.items() if k.startswith("BONEFIT_")}
    missing = {"BONEFIT_QUEUE_URL", "BONEFIT_DATABASE_URL", "BONEFIT_STORAGE_URL"} - set(env)
    if missing:
        raise SystemExit(f"--distributed needs {', '.join(sorted(missing))} in the environment")
    return env


def throughput(tmp: Path, workers: int, batch: int,
               distributed: bool = False) -> tuple[float, float, float]:
    """Jobs/minute for ``batch`` jobs submitted at once, the mean number running at once, and
    the CPU seconds the worker processes spent per job."""
    if distributed:  # `serve --no-worker` + `workers` × `bonefit worker` on the shared back-ends
        launch = running_server(tmp / f"throughput-d{workers}", no_worker=True,
                                extra_env=distributed_env(), external_workers=workers)
    else:
        launch = running_server(tmp / f"throughput-{workers}", workers=workers)
    with launch as server, httpx.Client(base_url=server.base_url, timeout=30) as client:
        rec_id = upload(client, EXAMPLE)
        if wait(client, submit(client, rec_id)) != "succeeded":  # warm the workers
            raise SystemExit("the warm-up job failed")
        pool = [pid for pid in tree(server.pid) if pid != server.pid]
        pool += [pid for worker in server.workers for pid in tree(worker.pid)]
        cpu_before = cpu_seconds(pool)
        start = time.perf_counter()
        jobs = [submit(client, rec_id) for _ in range(batch)]
        statuses = [wait(client, job) for job in jobs]
        elapsed = time.perf_counter() - start
        cpu = cpu_seconds(pool) - cpu_before
        done = [client.get(f"/v1/jobs/{job}").json() for job in jobs]
    if set(statuses) != {"succeeded"}:
        raise SystemExit(f"batch jobs ended {sorted(set(statuses))}")
    busy = sum(seconds(j["finished_at"]) - seconds(j["started_at"]) for j in done)
    return batch / elapsed * 60, busy / elapsed, cpu / batch


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tiny-jobs", type=int, default=15)
    parser.add_argument("--clients", type=int, default=50)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--distributed", action="store_true",
                        help="also measure jobs/minute with `bonefit worker` processes on the "
                             "BONEFIT_QUEUE_URL / DATABASE_URL / STORAGE_URL (and S3) of the "
                             "environment")
    args = parser.parse_args()
    print(machine(), flush=True)
    with temp_dir("bonefit-bench-jobs-") as tmp:
        print(table("Job overhead (tiny skeleton job, 60 frames, 1 embedded worker)",
                    ["measure", "value", "note"], job_overhead(tmp, args.tiny_jobs)), flush=True)
        print(table("Status endpoint under load", ["measure", "throughput", "latency"],
                    status_endpoint(tmp, args.clients, args.seconds)), flush=True)
        results = {n: throughput(tmp, n, args.batch) for n in (1, 2)}
        load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
        print(table(f"Throughput ({args.batch} skeleton jobs on the 300-frame example walk; "
                    f"load average {load})",
                    ["worker processes", "jobs/minute", "vs 1 worker", "jobs running at once",
                     "worker CPU per job"],
                    [[n, f"{rate:.0f}", f"{rate / results[1][0]:.2f}×", f"{busy:.2f}",
                      f"{cpu:.2f} s"] for n, (rate, busy, cpu) in results.items()]), flush=True)
        if args.distributed:
            spread = {n: throughput(tmp, n, args.batch, distributed=True) for n in (1, 2)}
            print(table(f"Throughput, distributed ({args.batch} jobs; `serve --no-worker` and "
                        "`bonefit worker` processes on Redis, PostgreSQL, S3)",
                        ["bonefit worker processes", "jobs/minute", "vs 1 worker",
                         "jobs running at once", "worker CPU per job"],
                        [[n, f"{rate:.0f}", f"{rate / spread[1][0]:.2f}×", f"{busy:.2f}",
                          f"{cpu:.2f} s"] for n, (rate, busy, cpu) in spread.items()]))


if __name__ == "__main__":
    main()
