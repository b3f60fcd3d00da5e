"""Long takes end to end (issue 19): the CLI and a service job on generated 240 Hz takes.

For each size (default 6k, 36k, 144k and 576k frames) and suit (15 and 11 sensors):

1. **CLI**: ``bonefit skeleton take.csv -o take.json --bvh take.bvh --quiet`` as a subprocess:
   wall time, peak RSS of its process tree, ``read_s`` / ``estimate_s`` / ``write_s`` (the
   JSON's timings document), µs per frame, and the ratio of the wall time to
   ``numpy.loadtxt`` of the same file measured in the same run (the yardstick; target ≤ 3×).
2. **Service job**: ``bonefit serve`` (embedded: SQLite queue and store, local artifacts, 2
   worker processes) on a free port; upload → succeeded → both downloads (JSON, BVH): wall
   time and ratio to loadtxt (target ≤ 4×) and where it went (upload, queued, run, seen by
   the client's poll, JSON and BVH downloads); then two such jobs at once: the wall time and
   the peak RSS of the whole service process tree (target ≤ 3 GB), next to its idle RSS.
   ``--job-formats json,bvh`` sends the jobs' ``formats`` parameter (the files they write;
   default: not sent, so every format, as the service's default).

The takes come from ``bonefit.estimation.simulate`` (``example_motion`` at 240 Hz,
``simulate_sensors``, ``write_sensor_csv``): a base of at most 36,000 frames is simulated and
written, longer takes repeat it forwards and backwards (so the motion stays continuous) with
the time running on.
They are cached in ``--cache`` (default: a ``bonefit-long-take`` folder in the system's
temporary directory), never in the repository. The takes have no dropped samples by default,
so that ``numpy.loadtxt`` parses the very file the run reads (``--drop-fraction`` adds them; the
yardstick then parses a copy with ``nan`` in the empty cells).

    python benchmarks/long_take.py [--frames 6000,36000] [--sensors 15,11] [--repeats 3]
                                   [--no-service] [--no-cli] [--cache DIR]
                                   [--baseline-cli /path/to/base/.venv/bin/bonefit]
                                   [--job-formats json,bvh]

Times are medians of ``--repeats`` runs; RSS the largest of them. Every run happens on the
loaded 2-core machine of its day: the ratios, measured in the same run, are what compares.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from service_common import (
    bonefit_command,
    clean_env,
    machine,
    median,
    running_server,
    status_kib,
    table,
    temp_dir,
    tree,
)

FPS = 240.0
BASE_FRAMES = 36_000
"""Longest take simulated in one piece; longer ones repeat it (memory and time of the
simulation, not of what is measured)."""
SEED = 19
JOB_PHASES = ("upload", "queued", "run", "seen", "json", "bvh")
"""The phases of a job's wall time (:class:`JobRun`), medians in the table."""
MB = 1024**2


# --- the takes -----------------------------------------------------------------------------


def take_path(cache: Path, frames: int, sensors: int, drop: float) -> Path:
    """The cached take (generated on first use)."""
    base = base_take(cache, min(frames, BASE_FRAMES), sensors, drop)
    if frames <= BASE_FRAMES:
        return base
    path = cache / f"take-{frames}f-{sensors}s-drop{drop:g}-seed{SEED}.csv"
    if not path.exists():
        partial = path.with_suffix(".part")
        repeat_take(base, frames, partial)
        partial.replace(path)
    return path


def base_take(cache: Path, frames: int, sensors: int, drop: float) -> Path:
    """``frames`` simulated frames written by ``write_sensor_csv`` (cached)."""
    from bonefit.estimation.io.sensor_csv import write_sensor_csv
    from bonefit.estimation.simulate import example_motion, simulate_sensors

    path = cache / f"base-{frames}f-{sensors}s-drop{drop:g}-seed{SEED}.csv"
    if not path.exists():
        motion = example_motion(frames, fps=FPS, seed=SEED)
        recording, _truth = simulate_sensors(motion, units_m=0.01, n_sensors=sensors,
                                             drop_fraction=drop, seed=SEED)
        partial = path.with_suffix(".part")
        write_sensor_csv(recording, partial)
        partial.replace(path)
    return path


def repeat_take(base: Path, frames: int, out: Path) -> None:
    """``base`` played forwards, backwards, forwards... until ``frames`` rows, times running on."""
    lines = base.read_bytes().splitlines(keepends=True)
    start = next(i for i, line in enumerate(lines) if line.startswith(b"time,")) + 1
    head, rows = lines[:start], lines[start:]
    bodies = [row.split(b",", 1)[1] for row in rows]
    with out.open("wb") as fh:
        fh.writelines(head)
        written = 0
        while written < frames:
            lap = written // len(bodies)
            order = bodies if lap % 2 == 0 else bodies[::-1]
            for body in order[: frames - written]:
                fh.write(b"%.6f," % (written / FPS) + body)
                written += 1


def loadtxt_twin(path: Path) -> Path:
    """``path`` itself, or (dropped samples: empty cells) a copy with ``nan`` in them."""
    head = path.read_bytes()[:1 << 20]
    sample = head.split(b"\ntime,", 1)[-1]
    if b",," not in sample and b",\n" not in sample:
        return path
    twin = path.with_suffix(".nan.csv")
    if not twin.exists():
        text = path.read_bytes()
        while b",," in text:
            text = text.replace(b",,", b",nan,")
        twin.write_bytes(text.replace(b",\n", b",nan\n"))
    return twin


def loadtxt_seconds(path: Path) -> float:
    """``numpy.loadtxt`` of the take (the C parser's time on the same bytes)."""
    twin = loadtxt_twin(path)
    with twin.open("rb") as fh:
        skip = next(i for i, line in enumerate(fh) if line.startswith(b"time,")) + 1
    start = time.perf_counter()
    table_ = np.loadtxt(twin, delimiter=",", skiprows=skip, dtype=np.float64)
    elapsed = time.perf_counter() - start
    del table_
    return elapsed


# --- measuring a process tree --------------------------------------------------------------


class PeakRss:
    """The largest sum of VmRSS over a process tree, sampled every ``interval`` seconds."""

    def __init__(self, pid: int, interval: float = 0.05) -> None:
        self.pid = pid
        self.interval = interval
        self.peak_kib = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)

    def _sample(self) -> None:
        while True:
            self.peak_kib = max(self.peak_kib, tree_rss_kib(self.pid))
            if self._stop.wait(self.interval):
                return

    def __enter__(self) -> PeakRss:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def tree_rss_kib(pid: int) -> int:
    """VmRSS of ``pid`` and its descendants now, KiB."""
    return sum(status_kib(p, "VmRSS") for p in tree(pid))


def timings_of(path: Path) -> dict[str, float]:
    """The ``timings`` object of a result JSON without loading the whole document."""
    key = b'"timings"'
    with path.open("rb") as fh:
        size = fh.seek(0, os.SEEK_END)
        for back in (1 << 16, size):  # writers put it last; else scan the whole file
            fh.seek(max(size - back, 0))
            chunk = fh.read()
            at = chunk.rfind(key)
            if at >= 0:
                text = chunk[at + len(key):].decode().lstrip(" :")
                found: dict[str, float] = json.JSONDecoder().raw_decode(text)[0]
                return found
    raise RuntimeError(f"no timings in {path}")


# --- the runs --------------------------------------------------------------------------------


@dataclass
class CliRun:
    wall: float
    peak_mib: float
    timings: dict[str, float]


def cli_run(take: Path, out: Path, command: Sequence[str] = ()) -> CliRun:
    """One ``bonefit skeleton`` run as a subprocess (``command``: this checkout's
    ``bonefit`` by default)."""
    args = [*(command or bonefit_command()), "skeleton", str(take), "-o", str(out / "take.json"),
            "--bvh", str(out / "take.bvh"), "--quiet"]
    start = time.perf_counter()
    proc = subprocess.Popen(args, env=clean_env(), stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    with PeakRss(proc.pid) as peak:
        _pid, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    assert proc.stderr is not None
    err = proc.stderr.read().decode(errors="replace")
    proc.stderr.close()
    if proc.returncode != 0:
        raise RuntimeError(f"bonefit skeleton failed ({proc.returncode}): {err[-2000:]}")
    peak_kib = max(peak.peak_kib, usage.ru_maxrss)  # ru_maxrss: KiB on Linux
    return CliRun(wall, peak_kib / 1024, timings_of(out / "take.json"))


@dataclass
class JobRun:
    """One service job's wall time and where it went (seconds): ``upload`` (the POST of the
    file), ``queued`` (submit to ``started_at``), ``run`` (``started_at`` to ``finished_at``:
    read, estimate, writes, artifacts), ``seen`` (to the client's poll seeing it), the two
    downloads."""

    wall: float
    phases: dict[str, float]


def service_job(base_url: str, take: Path, out: Path,
                formats: Sequence[str] | None = None) -> JobRun:
    """Upload → succeeded → JSON and BVH downloaded (``formats``: the job's ``formats``
    parameter; None: the kind's default, every format)."""
    params = {} if formats is None else {"formats": list(formats)}
    start = time.perf_counter()
    marks = {"start": time.time()}
    with httpx.Client(base_url=base_url, timeout=httpx.Timeout(600.0)) as client:
        with take.open("rb") as body:
            r = client.post("/v1/recordings", params={"filename": take.name,
                                                      "format": "sensor-csv"}, content=body)
        r.raise_for_status()
        marks["uploaded"] = time.time()
        r = client.post("/v1/jobs", json={"kind": "skeleton", "recording_id": r.json()["id"],
                                          "params": params})
        r.raise_for_status()
        job_id = r.json()["id"]
        job = wait_succeeded(client, job_id)
        marks["seen"] = time.time()
        for fmt in ("json", "bvh"):
            with client.stream("GET", f"/v1/jobs/{job_id}/result", params={"format": fmt}) \
                    as response, (out / f"{job_id}.{fmt}").open("wb") as fh:
                response.raise_for_status()
                for chunk in response.iter_bytes(MB):
                    fh.write(chunk)
            marks[fmt] = time.time()
    elapsed = time.perf_counter() - start
    for fmt in ("json", "bvh"):
        (out / f"{job_id}.{fmt}").unlink()
    return JobRun(elapsed, job_phases(marks, job))


def job_phases(marks: dict[str, float], job: dict[str, Any]) -> dict[str, float]:
    """The phases of :class:`JobRun` from the client's marks and the job's own times (one
    machine, one clock)."""
    started, finished = (datetime.fromisoformat(job[k]).timestamp()
                         for k in ("started_at", "finished_at"))
    ends = [marks["start"], marks["uploaded"], started, finished, marks["seen"], marks["json"],
            marks["bvh"]]
    return {name: b - a for name, a, b in zip(JOB_PHASES, ends[:-1], ends[1:], strict=True)}


def wait_succeeded(client: httpx.Client, job_id: str, timeout: float = 3600.0
                   ) -> dict[str, Any]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job: dict[str, Any] = client.get(f"/v1/jobs/{job_id}").json()
        if job["status"] == "succeeded":
            return job
        if job["status"] in ("failed", "cancelled"):
            raise RuntimeError(f"job {job_id} {job['status']}: {job.get('error')}")
        time.sleep(0.05)
    raise TimeoutError(f"job {job_id} did not finish in {timeout:.0f} s")


@dataclass
class ServiceRun:
    one: float
    phases: dict[str, float]
    two: float
    peak_two_mib: float
    idle_mib: float


def service_runs(take: Path, work: Path, repeats: int,
                 formats: Sequence[str] | None) -> ServiceRun:
    """One job at a time (median of ``repeats``), then two at once, on a fresh server."""
    with temp_dir("bonefit-bench-service-") as data, \
            running_server(data / "data", workers=2) as server:
        idle = tree_rss_kib(server.pid) / 1024
        runs = [service_job(server.base_url, take, work, formats) for _ in range(repeats)]
        with PeakRss(server.pid) as peak, ThreadPoolExecutor(2) as pool:
            start = time.perf_counter()
            list(pool.map(lambda _: service_job(server.base_url, take, work, formats),
                          range(2)))
            two = time.perf_counter() - start
    phases = {k: median([r.phases[k] for r in runs]) for k in runs[0].phases}
    return ServiceRun(median([r.wall for r in runs]), phases, two, peak.peak_kib / 1024, idle)


# --- the table ---------------------------------------------------------------------------


def measure(take: Path, frames: int, sensors: int, args: argparse.Namespace,
            work: Path) -> list[object]:
    """One row of the table."""
    yard = median([loadtxt_seconds(take) for _ in range(args.repeats)])
    row: list[object] = [f"{frames:,}", sensors, f"{take.stat().st_size / MB:.0f} MB",
                         f"{yard:.2f} s"]
    if args.cli:
        runs, baseline = cli_runs(take, work, args)
        row += cli_columns(runs, yard, frames)
        if baseline:
            row += cli_columns(baseline, yard, frames)[:2]
    if args.service:
        svc = service_runs(take, work, args.repeats, args.job_formats)
        row += [f"{svc.one:.2f} s", f"{svc.one / yard:.2f}×",
                " / ".join(f"{v:.2f}" for v in svc.phases.values()), f"{svc.two:.2f} s",
                f"{svc.peak_two_mib:,.0f} MiB (idle {svc.idle_mib:,.0f})"]
    return row


def cli_runs(take: Path, work: Path, args: argparse.Namespace
             ) -> tuple[list[CliRun], list[CliRun]]:
    """``--repeats`` CLI runs of this checkout and, with ``--baseline-cli``, as many of the
    baseline's, interleaved (the order alternating from run to run)."""
    runs: list[CliRun] = []
    baseline: list[CliRun] = []
    commands: list[tuple[list[CliRun], tuple[str, ...]]] = [(runs, ())]
    if args.baseline_cli:
        commands.append((baseline, tuple(args.baseline_cli)))
    for k in range(args.repeats):
        for into, command in (commands if k % 2 == 0 else commands[::-1]):
            into.append(cli_run(take, work, command))
    (work / "take.json").unlink(missing_ok=True)
    (work / "take.bvh").unlink(missing_ok=True)
    return runs, baseline


def cli_columns(runs: list[CliRun], yard: float, frames: int) -> list[object]:
    """The CLI's columns of a table row: medians of ``runs``, the largest peak RSS."""
    wall = median([r.wall for r in runs])
    stage = {k: median([r.timings.get(k, float("nan")) for r in runs])
             for k in ("read_s", "estimate_s", "write_s")}
    return [f"{wall:.2f} s", f"{wall / yard:.1f}×",
            " / ".join(f"{stage[k]:.2f}" for k in stage),
            f"{stage['estimate_s'] / frames * 1e6:.0f} / {wall / frames * 1e6:.0f}",
            f"{max(r.peak_mib for r in runs):,.0f} MiB"]


def header(args: argparse.Namespace) -> list[str]:
    cols = ["frames", "sensors", "CSV", "loadtxt"]
    if args.cli:
        cols += ["CLI wall", "CLI / loadtxt", "read / estimate / write s",
                 "µs/frame (estimate / wall)", "CLI peak RSS"]
        if args.baseline_cli:
            cols += ["baseline CLI wall", "baseline / loadtxt"]
    if args.service:
        cols += ["job wall", "job / loadtxt", f"{' / '.join(JOB_PHASES)} s", "2 jobs wall",
                 "2 jobs peak RSS (tree)"]
    return cols


def formats_arg(text: str) -> list[str]:
    return [x for x in re.split(r"[,\s]+", text.strip()) if x]


def numbers(text: str, cast: Callable[[str], int]) -> list[int]:
    return [cast(x) for x in re.split(r"[,\s]+", text.strip()) if x]


@contextmanager
def cache_dir(path: str | None) -> Iterator[Path]:
    folder = Path(path) if path else Path(tempfile.gettempdir()) / "bonefit-long-take"
    folder.mkdir(parents=True, exist_ok=True)
    yield folder


def take_arguments(parser: argparse.ArgumentParser, frames: str) -> None:
    """``--frames`` (default ``frames``), ``--sensors`` and ``--cache``: the takes of this
    benchmark and of those that reuse its cache."""
    parser.add_argument("--frames", default=frames,
                        help="take lengths, comma-separated (default %(default)s)")
    parser.add_argument("--sensors", default="15,11", help="suits: 15 and/or 11")
    parser.add_argument("--cache", help="folder of the generated takes (long_take.py's)")


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    take_arguments(parser, "6000,36000,144000,576000")
    parser.add_argument("--repeats", type=int, default=3, help="runs per measure (median)")
    parser.add_argument("--drop-fraction", type=float, default=0.0,
                        help="dropped samples in the takes (default none)")
    parser.add_argument("--no-cli", dest="cli", action="store_false")
    parser.add_argument("--no-service", dest="service", action="store_false")
    parser.add_argument("--baseline-cli", nargs="+", metavar="COMMAND",
                        help="the bonefit command of another checkout (e.g. "
                             "/path/to/base/.venv/bin/bonefit): its CLI runs interleaved "
                             "with this one's, their median wall and ratio in two more "
                             "columns")
    parser.add_argument("--job-formats", type=formats_arg, default=None,
                        help="the jobs' formats parameter, e.g. json,bvh (default: not sent, "
                             "the service's default: every format)")
    args = parser.parse_args(argv)
    print(machine(), flush=True)
    rows = []
    with cache_dir(args.cache) as cache, temp_dir("bonefit-bench-long-") as work:
        for frames in numbers(args.frames, int):
            for sensors in numbers(args.sensors, int):
                take = take_path(cache, frames, sensors, args.drop_fraction)
                rows.append(measure(take, frames, sensors, args, work))
                print(table("so far", header(args), rows[-1:]), flush=True)
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    print(table(f"Long takes at 240 Hz, median of {args.repeats} (load average {load}; "
                f"{time.strftime('%Y-%m-%d')}, python {sys.version.split()[0]})",
                header(args), rows))


if __name__ == "__main__":
    main()
