"""Speed and memory of the sensor-CSV reader and the skeleton writers on long takes.

Generates 240 Hz takes of the synthetic example motion (``bonefit.estimation.simulate``) with
15 and 11 sensors into a scratch directory outside the repository (default
``/tmp/bonefit-io``), then times, each in a fresh process so that its peak RSS is its own:

* ``loadtxt``: ``numpy.loadtxt`` of the same table (the C parser; the yardstick), from a copy
  whose empty cells (dropped samples) say ``nan`` because loadtxt refuses empty cells,
* ``read``: ``bonefit.estimation.io.sensor_csv.read_sensor_csv``,
* ``bvh_text``: ``bonefit.estimation.bvh.write_bvh`` alone (the text of a ready BVH motion),
* ``json``/``bvh``/``csv``/``npz``: the skeleton writers on a result of the take's size (the
  estimate of the first 6,000 frames, its arrays repeated to the take's length: the writers'
  cost depends on the sizes only).

Each figure is the median of ``--runs`` runs, the runs of all ops interleaved (a shared
machine's load moves them alike); ``peak MB`` is the child's peak RSS minus its RSS once its
input was loaded (so the reader's figure includes its output arrays). ``--compare DIR`` also
runs every op on the code under ``DIR`` (e.g. ``git archive main bonefit estimation | tar -x
-C DIR``: the ``bonefit.estimation`` layout),
interleaved, as ``<op> (before)`` (an op that code lacks, like ``npz``, is left out)::

    .venv/bin/python benchmarks/io_speed.py --frames 6000 36000 144000 --runs 3 \\
        --compare /tmp/main-code
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import statistics
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

SEED = 19
FPS = 240.0
BASE_FRAMES = 6000


def _status_mb(key: str) -> float:
    with open("/proc/self/status") as handle:
        line = next(ln for ln in handle if ln.startswith(key))
    return int(line.split()[1]) / 1024.0


def _rss_mb() -> float:
    """The current RSS, MB, after resetting the peak (Linux: ``clear_refs`` 5)."""
    with open("/proc/self/clear_refs", "w") as handle:
        handle.write("5")
    return _status_mb("VmRSS:")


def _peak_mb() -> float:
    return _status_mb("VmHWM:")


def take_path(scratch: Path, frames: int, sensors: int) -> Path:
    """The generated take (written once)."""
    path = scratch / f"take-{frames}-{sensors}.csv"
    if not path.exists():
        from bonefit.estimation.io.sensor_csv import write_sensor_csv
        from bonefit.estimation.simulate import example_motion, simulate_sensors

        motion = example_motion(frames, fps=FPS, seed=SEED)
        rec, _ = simulate_sensors(motion, units_m=0.01, n_sensors=sensors, seed=SEED + sensors)
        started = time.perf_counter()
        write_sensor_csv(rec, path.with_suffix(".tmp"))
        print(f"# wrote {path.name} in {time.perf_counter() - started:.1f} s", file=sys.stderr)
        path.with_suffix(".tmp").rename(path)
    nan_copy(path)
    return path


def result_path(scratch: Path, frames: int) -> Path:
    """A pickled SkeletonResult of ``frames`` frames (the 6,000-frame estimate, repeated)."""
    path = scratch / f"result-{frames}.pkl"
    if not path.exists():
        from bonefit.estimation.io.sensor_csv import read_sensor_csv
        from bonefit.estimation.skeleton import estimate_skeleton

        base = estimate_skeleton(read_sensor_csv(take_path(scratch, BASE_FRAMES, 15)))

        def grow(a: Any) -> Any:
            return np.resize(np.asarray(a), (frames, *np.shape(a)[1:]))

        result = replace(base, joints={k: grow(v) for k, v in base.joints.items()},
                         orientations={k: grow(v) for k, v in base.orientations.items()})
        path.write_bytes(pickle.dumps(result))
    return path


def motion_path(scratch: Path, frames: int) -> Path:
    """A pickled BvhMotion of ``frames`` frames: the BVH of the 6,000-frame result, its
    channel values repeated (for the BVH text writer alone)."""
    path = scratch / f"motion-{frames}.pkl"
    if not path.exists():
        from bonefit.estimation.io.skeleton import skeleton_to_bvh

        base = skeleton_to_bvh(pickle.loads(result_path(scratch, BASE_FRAMES).read_bytes()))
        path.write_bytes(pickle.dumps(base.with_values(
            np.resize(base.values, (frames, base.values.shape[1])))))
    return path


def run_one(op: str, path: Path, out: Path) -> dict[str, float]:
    """Time ``op`` once in this process; seconds and peak RSS above the loaded input."""
    if op == "loadtxt":
        copy = nan_copy(path)
        base = _rss_mb()
        started = time.perf_counter()
        table = np.loadtxt(copy, delimiter=",", skiprows=2)
        seconds = time.perf_counter() - started
        del table
    elif op == "read":
        from bonefit.estimation.io.sensor_csv import read_sensor_csv

        base = _rss_mb()
        started = time.perf_counter()
        rec = read_sensor_csv(path)
        seconds = time.perf_counter() - started
        del rec
    elif op == "bvh_text":
        from bonefit.estimation.bvh import write_bvh

        motion = pickle.loads(path.read_bytes())
        base = _rss_mb()
        started = time.perf_counter()
        write_bvh(motion, out)
        seconds = time.perf_counter() - started
    else:
        from bonefit.estimation.io import skeleton as writers

        result = pickle.loads(path.read_bytes())
        base = _rss_mb()
        write = {"json": writers.write_skeleton_json, "bvh": writers.write_skeleton_bvh,
                 "csv": writers.write_skeleton_csv,
                 "npz": getattr(writers, "write_skeleton_npz", None)}[op]
        if write is None:
            return {}
        started = time.perf_counter()
        write(result, out)
        seconds = time.perf_counter() - started
    return {"s": seconds, "peak_mb": _peak_mb() - base,
            "size_mb": out.stat().st_size / 1e6 if out.exists() else 0.0}


def nan_copy(path: Path) -> Path:
    """The take with its empty cells (dropped samples) written as ``nan``: ``numpy.loadtxt``
    refuses empty cells, and a converter for them would make it a Python-speed parse."""
    copy = path.with_name(path.stem + "-nan.csv")
    if not copy.exists():
        text = path.read_text()
        for _ in range(2):  # ",,," needs two passes
            text = text.replace(",,", ",nan,")
        copy.write_text(text.replace(",\n", ",nan\n"))
    return copy


def child(op: str, path: Path, out: Path, base: Path | None) -> dict[str, float]:
    """One run of ``op`` in a fresh process (the code under ``base`` when given)."""
    env = dict(os.environ)
    if base is not None:
        env["PYTHONPATH"] = str(base)
    proc = subprocess.run([sys.executable, __file__, "--one", op, str(path), str(out)],
                          check=True, capture_output=True, text=True, env=env)
    found: dict[str, float] = json.loads(proc.stdout)
    return found


def tasks(args: argparse.Namespace, frames: int, sensors: int
          ) -> list[tuple[str, str, Path, Path, Path | None]]:
    """(label, op, input, output, code) of one take: each op on this code, and on the
    ``--compare`` code when given."""
    take = take_path(args.scratch, frames, sensors)
    out: list[tuple[str, str, Path, Path, Path | None]] = []
    for op in args.ops:
        if op in ("loadtxt", "read"):
            source, target = take, take
        elif sensors == args.sensors[0]:  # the writers depend on frames only
            source = (motion_path if op == "bvh_text" else result_path)(args.scratch, frames)
            target = args.scratch / f"out-{frames}.{op.replace('_text', '')}"
        else:
            continue
        if args.compare is not None and op != "loadtxt":
            out.append((f"{op} (before)", op, source, target, args.compare))
        out.append((op, op, source, target, None))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, nargs="+", default=[6000, 36000, 144000])
    parser.add_argument("--sensors", type=int, nargs="+", default=[15, 11])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--scratch", type=Path, default=Path("/tmp/bonefit-io"))
    parser.add_argument("--compare", type=Path, default=None, metavar="DIR",
                        help="also run each op on the code under DIR (PYTHONPATH), "
                             "interleaved with this code's runs")
    parser.add_argument("--ops", nargs="+", default=["loadtxt", "read", "json", "bvh_text",
                                                     "csv", "npz", "bvh"])
    parser.add_argument("--one", nargs=3, metavar=("OP", "PATH", "OUT"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        op, path, out = args.one
        print(json.dumps(run_one(op, Path(path), Path(out))))
        return
    args.scratch.mkdir(parents=True, exist_ok=True)
    print(f"# {time.strftime('%Y-%m-%d %H:%M')} load {os.getloadavg()[0]:.1f} on "
          f"{os.cpu_count()} cores; numpy {np.__version__}; median of {args.runs}, "
          "the ops' runs interleaved")
    print("| frames | sensors | op | s | x loadtxt | peak MB | size MB |")
    print("|---:|---:|---|---:|---:|---:|---:|")
    for frames in args.frames:
        for sensors in args.sensors:
            todo = tasks(args, frames, sensors)
            runs: dict[str, list[dict[str, float]]] = {t[0]: [] for t in todo}
            for _ in range(args.runs):
                for label, op, source, target, base in todo:
                    runs[label].append(child(op, source, target, base))
            report(frames, sensors, runs, take_path(args.scratch, frames, sensors))
            print(f"# load {os.getloadavg()[0]:.1f}", flush=True)


def report(frames: int, sensors: int, runs: dict[str, list[dict[str, float]]],
           take: Path) -> None:
    """Table rows of one take: median seconds, ratio to loadtxt, largest peak, size."""
    seconds = {k: statistics.median(r["s"] for r in v) for k, v in runs.items() if v[0]}
    yard = seconds.get("loadtxt")
    for label, found in runs.items():
        if not found[0]:
            continue
        ratio = f"{seconds[label] / yard:.2f}" if yard else ""
        peak = max(r["peak_mb"] for r in found)
        size = take.stat().st_size / 1e6 if label.startswith(("loadtxt", "read")) else found[-1][
            "size_mb"]
        print(f"| {frames} | {sensors} | {label} | {seconds[label]:.2f} | {ratio} | {peak:.0f} | "
              f"{size:.1f} |", flush=True)


if __name__ == "__main__":
    main()
