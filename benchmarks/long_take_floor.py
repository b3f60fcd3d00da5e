"""What a long take's run must spend at least, against ``numpy.loadtxt`` (issue 19's yardstick).

Issue 19 asks for the whole CLI run on a 144,000-frame take (read, default estimate, JSON and
BVH written) in at most 3× the time ``numpy.loadtxt`` takes to parse the same file. This
benchmark times the run's parts on their own, in one process and one run, each as a multiple
of ``loadtxt`` measured alternately with them:

- ``loadtxt``: the yardstick (one thread of C);
- ``read``: bonefit's reader (``read_recording``: parse, checks, layout by sensor);
- ``pyarrow``: ``pyarrow.csv.read_csv`` of the same rows into one float64 array, when
  pyarrow is installed (it is not a dependency): the fastest CSV parser at hand, on every core;
- ``imports``: a new interpreter importing what the estimating CLI imports, less a bare
  interpreter's start (the CLI overlaps it with the parse);
- ``estimate``: ``estimate_skeleton`` with the default method (``estimate_s``);
- ``json`` / ``orjson``: bonefit's JSON writer, and ``orjson.dumps`` of the same arrays
  (rounded as the JSON rounds them) when orjson is installed (not a dependency);
- ``bvh``: bonefit's BVH writer.

The estimate needs every row, so a run takes at least ``parse + estimate`` before it writes
anything, however the reading and writing overlap on two cores. The last two columns give that
bound with the fastest parser measured, and with the fastest JSON writer added.

    python benchmarks/long_take_floor.py [--frames 144000] [--sensors 15,11] [--repeats 3]
                                         [--cache DIR]

Takes come from ``long_take.take_path`` (the same cache). Times are medians of ``--repeats``.
"""

from __future__ import annotations

import argparse
import importlib
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from bonefit.estimation.memory import retain_freed_memory
from bonefit.estimation.threads import limit_blas_threads

limit_blas_threads()  # as the CLI: before numpy loads BLAS
retain_freed_memory()

import numpy as np  # noqa: E402
from long_take import (  # noqa: E402
    cache_dir,
    loadtxt_seconds,
    numbers,
    take_arguments,
    take_path,
)
from service_common import machine, table  # noqa: E402

from bonefit.estimation.io.sensors import read_recording  # noqa: E402
from bonefit.estimation.io.skeleton import (  # noqa: E402
    skeleton_document,
    write_skeleton_bvh,
    write_skeleton_json,
)
from bonefit.estimation.results import SkeletonResult  # noqa: E402
from bonefit.estimation.skeleton import estimate_skeleton  # noqa: E402

CLI_MODULES = ("bonefit.estimation.skeleton", "bonefit.estimation.io.skeleton",
               "bonefit.estimation.pipeline")
"""What a new ``bonefit skeleton`` process imports before it estimates."""


def optional(module: str) -> Any:
    """``module`` if installed, else None (pyarrow and orjson are not dependencies)."""
    try:
        return importlib.import_module(module)
    except ImportError:
        return None


def seconds(work: Callable[[], object]) -> float:
    start = time.perf_counter()
    work()
    return time.perf_counter() - start


def import_seconds() -> float:
    """A new interpreter importing ``CLI_MODULES``, less a bare interpreter."""
    def run(code: str) -> float:
        return seconds(lambda: subprocess.run([sys.executable, "-c", code], check=True))
    return run("import " + ", ".join(CLI_MODULES)) - run("pass")


def pyarrow_seconds(path: Path) -> float | None:
    """``pyarrow.csv.read_csv`` of the take's rows into one (F, C) float64 array."""
    csv = optional("pyarrow.csv")
    if csv is None:
        return None
    with path.open("rb") as fh:
        skip = next(i for i, line in enumerate(fh) if line.startswith(b"time,"))

    def parse() -> object:
        table_ = csv.read_csv(path, read_options=csv.ReadOptions(skip_rows=skip))
        return np.column_stack([column.to_numpy() for column in table_.columns])
    return seconds(parse)


def orjson_seconds(result: SkeletonResult) -> float | None:
    """``orjson.dumps`` of the result's joints and orientations, rounded as the JSON is."""
    orjson = optional("orjson")
    if orjson is None:
        return None
    document = skeleton_document(result)
    arrays = {"joints": {k: np.round(v, 6) for k, v in result.joints.items()},
              "orientations": {k: np.round(v, 6) for k, v in result.orientations.items()}}
    return seconds(lambda: orjson.dumps({**{k: v for k, v in document.items()
                                            if k not in arrays}, **arrays},
                                        option=orjson.OPT_SERIALIZE_NUMPY,
                                        default=str))


PARTS = ("read", "pyarrow", "imports", "estimate", "json", "orjson", "bvh")


def one_round(path: Path, work: Path) -> dict[str, float | None]:
    """Seconds of each part once (None: its library is not installed)."""
    started = time.perf_counter()
    recording = read_recording(path)
    read = time.perf_counter() - started
    result = estimate_skeleton(recording)
    del recording
    return {"read": read, "pyarrow": pyarrow_seconds(path), "imports": import_seconds(),
            "estimate": float(result.timings["estimate_s"]),
            "json": seconds(lambda: write_skeleton_json(result, work / "t.json")),
            "orjson": orjson_seconds(result),
            "bvh": seconds(lambda: write_skeleton_bvh(result, work / "t.bvh"))}


def measure(path: Path, work: Path, repeats: int) -> tuple[float, dict[str, float | None]]:
    """Median seconds of ``loadtxt`` and of each part, alternating with it."""
    yard: list[float] = []
    parts: dict[str, list[float]] = {p: [] for p in PARTS}
    for _ in range(repeats):
        yard.append(loadtxt_seconds(path))
        for name, value in one_round(path, work).items():
            if value is not None:
                parts[name].append(value)
    return statistics.median(yard), {p: statistics.median(v) if v else None
                                     for p, v in parts.items()}


def row(frames: int, sensors: int, yard: float, parts: dict[str, float | None]
        ) -> list[object]:
    def cell(value: float | None) -> str:
        return "not installed" if value is None else f"{value:.2f} s = {value / yard:.1f}×"

    estimate = parts["estimate"] or 0.0
    parse = min(v for v in (parts["read"], parts["pyarrow"]) if v is not None)
    write = min(v for v in (parts["json"], parts["orjson"]) if v is not None)
    return [f"{frames:,}", sensors, f"{yard:.2f} s", *(cell(parts[p]) for p in PARTS),
            f"{(parse + estimate) / yard:.1f}×", f"{(parse + estimate + write) / yard:.1f}×"]


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    take_arguments(parser, "144000")
    parser.add_argument("--repeats", type=int, default=3, help="runs per measure (median)")
    args = parser.parse_args(argv)
    print(machine())
    rows = []
    with cache_dir(args.cache) as cache, tempfile.TemporaryDirectory() as work:
        for frames in numbers(args.frames, int):
            for sensors in numbers(args.sensors, int):
                path = take_path(cache, frames, sensors, 0.0)
                yard, parts = measure(path, Path(work), args.repeats)
                rows.append(row(frames, sensors, yard, parts))
                print("  " + " | ".join(str(c) for c in rows[-1]), flush=True)
    print()
    print(table(f"Parts of a long take's run against numpy.loadtxt, median of {args.repeats}",
                ["frames", "sensors", "loadtxt", *PARTS, "parse + estimate",
                 "+ fastest JSON"], rows))


if __name__ == "__main__":
    main()
