"""The default estimate on a long take with its pieces on one thread and on two (issue 19).

``estimate_skeleton`` (method ``auto``) on a cached take of ``long_take.py`` (240 Hz, read once
per suit), alternating ``threads.MAX_WORKERS`` = 1 and 2 in the same process, ``--pairs``
times: wall and CPU seconds, µs per frame, the longest silence of the progress callback per
stage and the number of its reports, the growth of the peak RSS over the loaded recording, and
whether the joint paths of the two are bit-identical. On a loaded machine the two threads
only share this process's share of the cores: compare on an idle one, and record the load.

    python benchmarks/estimate_threads.py [--frames 144000] [--sensors 15,11] [--pairs 3]
                                          [--cache DIR]
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass

from bonefit.estimation.threads import limit_blas_threads

limit_blas_threads()  # as the CLI and the workers run

import numpy as np  # noqa: E402
from long_take import cache_dir, numbers, take_arguments, take_path  # noqa: E402
from numpy.typing import NDArray  # noqa: E402
from service_common import machine, median, table  # noqa: E402

from bonefit.estimation import threads  # noqa: E402
from bonefit.estimation.io.sensor_csv import read_sensor_csv  # noqa: E402
from bonefit.estimation.recording import SensorRecording  # noqa: E402
from bonefit.estimation.skeleton import estimate_skeleton  # noqa: E402


@dataclass
class Run:
    wall: float
    cpu: float
    silence: dict[str, float]  # stage -> longest time before one of its reports, s
    reports: dict[str, int]
    joints: dict[str, NDArray[np.float64]]


def estimate(rec: SensorRecording, workers: int) -> Run:
    """One ``estimate_skeleton`` with ``workers`` threads."""
    vars(threads)["MAX_WORKERS"] = workers  # a Final constant of the library; here the variable
    stamps: list[tuple[float, str]] = []
    cpu, start = time.process_time(), time.perf_counter()
    result = estimate_skeleton(rec, progress=lambda f, s: stamps.append((time.perf_counter(),
                                                                          s)))
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    silence: dict[str, float] = {}
    reports: dict[str, int] = {}
    last = start
    for at, stage in stamps:
        silence[stage] = max(silence.get(stage, 0.0), at - last)
        reports[stage] = reports.get(stage, 0) + 1
        last = at
    return Run(wall, cpu, silence, reports, dict(result.joints))


def rows_for(rec: SensorRecording, frames: int, sensors: int, pairs: int) -> list[list[object]]:
    """Both variants, alternating, ``pairs`` times: one table row each."""
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    runs: dict[int, list[Run]] = {1: [], 2: []}
    for _ in range(pairs):
        for workers in (1, 2):
            runs[workers].append(estimate(rec, workers))
    grown = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - base) / 1024
    same = all(np.array_equal(a.joints[j], b.joints[j])
               for a, b in zip(runs[1], runs[2], strict=True) for j in a.joints)
    rows = []
    for workers, done in runs.items():
        wall = median([r.wall for r in done])
        stages = list(done[0].silence)
        rows.append([f"{frames:,}", sensors, workers, f"{wall:.2f} s",
                     f"{median([r.cpu for r in done]):.2f} s",
                     f"{wall / frames * 1e6:.0f}",
                     ", ".join(f"{s} {max(r.silence[s] for r in done):.2f}" for s in stages),
                     ", ".join(f"{s} {done[0].reports[s]}" for s in stages),
                     f"{grown:,.0f} MiB" if workers == 2 else "",
                     "yes" if same else "NO"])
    speedup = median([r.wall for r in runs[1]]) / median([r.wall for r in runs[2]])
    rows[-1][3] = f"{rows[-1][3]} ({speedup:.2f}×)"
    return rows


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    take_arguments(parser, "144000")
    parser.add_argument("--pairs", type=int, default=3, help="alternating 1/2-thread pairs")
    args = parser.parse_args(argv)
    print(machine(), flush=True)
    header = ["frames", "sensors", "threads", "wall (median)", "CPU", "µs/frame",
              "longest silence per stage, s", "reports per stage",
              "peak RSS over the recording (all runs)", "bit-identical"]
    rows: list[list[object]] = []
    with cache_dir(args.cache) as cache:
        for frames in numbers(args.frames, int):
            for sensors in numbers(args.sensors, int):
                rec = read_sensor_csv(take_path(cache, frames, sensors, 0.0))
                rows += rows_for(rec, frames, sensors, args.pairs)
                print(table("so far", header, rows[-2:]), flush=True)
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    print(table(f"estimate_skeleton (auto), 1 and 2 threads, median of {args.pairs} "
                f"(load average {load}; {time.strftime('%Y-%m-%d')}, "
                f"python {sys.version.split()[0]}, {os.cpu_count()} CPUs)", header, rows))


if __name__ == "__main__":
    main()
