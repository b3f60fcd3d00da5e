"""Where a job's queue wait goes: store, enqueue, wake-up and claim, step by step.

The submitting side runs here, with the service's own store and queue: stamp ``created_at``,
store the job, queue its id, (make it durable); a worker process (``--serve``, started by
this script) takes the id from the queue as `bonefit worker` does (``run_next``, then
``idle`` when empty), stamps ``started_at`` and claims. Each job is sent after a random pause,
to an idle worker. Two submission paths alternate job by job in the same run:

- ``durable``: the insert waits for the disk, then the id is queued (main before issue 19's
  last change);
- ``early``: the insert commits without waiting for the disk (PostgreSQL), the id is queued,
  then ``wait_durable`` (the API answers 202 only after it).

The queue wait is ``started_at - created_at``; "claimed" is when the worker's claim returned
(the job can run from then on). Everything in milliseconds, median / p95 / max.

    python benchmarks/queue_breakdown.py [--jobs 50] [--distributed]

``--distributed`` uses BONEFIT_DATABASE_URL (PostgreSQL) and BONEFIT_QUEUE_URL (Redis) of the
environment; otherwise SQLite files in a temporary directory (the embedded mode).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import subprocess
import sys
import time
from pathlib import Path

from service_common import machine, median, percentile, table, temp_dir

from bonefit.service.jobs import Job, JobStore, new_id
from bonefit.service.queue import JobQueue, open_queue
from bonefit.service.sql_store import open_store

STEPS = ("store", "enqueue", "durable", "wake", "queue wait", "claim", "created → claimed")


def serve(database_url: str, queue_url: str) -> None:
    """The worker side: report when each job id arrived and when its claim returned."""
    store, queue = open_store(database_url), open_queue(queue_url)

    def handler(job_id: str) -> None:
        started = time.time()
        claimed = store.claim(job_id, "breakdown", started, 30.0)
        done = time.time()
        print(json.dumps({"id": job_id, "started": started, "claimed": done,
                          "ok": claimed is not None}), flush=True)

    print("ready", flush=True)
    while True:
        if not queue.run_next(handler):
            queue.idle(1.0)


def submit(store: JobStore, queue: JobQueue, path: str) -> tuple[str, dict[str, float]]:
    """Store and queue one job along ``path``; its id and the stamps of each step."""
    now = time.time()
    job = Job(id=new_id(), tenant="bench", kind="skeleton", recording_id="r", params={},
              inputs={}, created_at=now, updated_at=now)
    stamps = {"created": now}
    store.add_job(job, durable=path == "durable")
    stamps["stored"] = time.time()
    queue.enqueue(job.id)
    stamps["queued"] = time.time()
    if path == "early":
        store.wait_durable()
    stamps["durable"] = time.time()
    return job.id, stamps


def steps(sent: dict[str, float], seen: dict[str, float]) -> dict[str, float]:
    return {"store": sent["stored"] - sent["created"], "enqueue": sent["queued"] - sent["stored"],
            "durable": sent["durable"] - sent["queued"], "wake": seen["started"] - sent["queued"],
            "queue wait": seen["started"] - sent["created"],
            "claim": seen["claimed"] - seen["started"],
            "created → claimed": seen["claimed"] - sent["created"]}


def measure(database_url: str, queue_url: str, jobs: int) -> dict[str, list[dict[str, float]]]:
    store, queue = open_store(database_url), open_queue(queue_url)
    store.init()
    worker = subprocess.Popen([sys.executable, __file__, "--serve", database_url, queue_url],
                              stdout=subprocess.PIPE, text=True, cwd=Path(__file__).parent)
    assert worker.stdout is not None
    try:
        if worker.stdout.readline().strip() != "ready":
            raise SystemExit("the worker did not start")
        pauses = random.Random(19)
        results: dict[str, list[dict[str, float]]] = {"durable": [], "early": []}
        for i in range(2 * jobs + 2):
            path = ("durable", "early")[i % 2]
            time.sleep(pauses.uniform(0.05, 0.5))  # the worker is idle, at a random phase
            job_id, sent = submit(store, queue, path)
            seen = json.loads(worker.stdout.readline())
            if seen.pop("id") != job_id or not seen.pop("ok"):
                raise SystemExit(f"unexpected claim {seen}")
            if i >= 2:  # the first of each path warms the connections
                results[path].append(steps(sent, seen))
        return results
    finally:
        worker.terminate()
        worker.wait()


def rows(results: dict[str, list[dict[str, float]]]) -> list[list[object]]:
    out: list[list[object]] = []
    for step in STEPS:
        row: list[object] = [step]
        for path in ("durable", "early"):
            values = [r[step] * 1000 for r in results[path]]
            row.append(f"{median(values):.1f} / {percentile(values, 95):.1f} / "
                       f"{max(values):.1f}")
        out.append(row)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--jobs", type=int, default=50, help="jobs per submission path")
    parser.add_argument("--distributed", action="store_true")
    parser.add_argument("--serve", nargs=2, metavar=("DATABASE_URL", "QUEUE_URL"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve:
        serve(*args.serve)
        return
    print(machine(), flush=True)
    with temp_dir("bonefit-bench-breakdown-") as tmp:
        if args.distributed:
            urls = (os.environ["BONEFIT_DATABASE_URL"], os.environ["BONEFIT_QUEUE_URL"])
            mode = "Redis + PostgreSQL"
        else:
            urls = (f"sqlite:///{tmp / 'jobs.db'}", f"sqlite:///{tmp / 'queue.db'}")
            mode = "embedded (SQLite)"
        results = measure(*urls, args.jobs)
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    print(table(f"Queue wait step by step, {mode}, {args.jobs} jobs per path, alternating "
                f"(ms, median / p95 / max; load average at the end {load})",
                ["step", "durable insert, then queue", "early insert, queue, then durable"],
                rows(results)), flush=True)


if __name__ == "__main__":
    main()
