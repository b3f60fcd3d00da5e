"""Speed of the skeleton BVH writer's channel computation on long takes.

Times ``bonefit.estimation.io.skeleton.skeleton_to_bvh`` (hierarchy, rest rotations, Euler orders,
continuous channels; not the text formatting of ``write_bvh``) on synthetic rigid skeleton
results of 36,000 and 144,000 frames (2.5 and 10 minutes at 240 Hz): median of several runs,
each version in its own process. Times are the process's CPU time (``time.process_time``;
BLAS on one thread), which a machine shared with other work does not inflate as it does wall
time. With ``--baseline DIR`` (another checkout of the code, e.g.
``git archive main | tar -x -C DIR``) the same takes are timed with that version, back to
back, and the ratio printed. Usage::

    .venv/bin/python benchmarks/bvh_writer_speed.py [--frames 36000 144000] [--runs 3]
        [--baseline /tmp/bonefit-main] [--jitter 0.003]

BLAS runs on one thread, as in the service's workers.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

ROOT = Path(__file__).resolve().parents[1]


def time_writer(n_frames: int, runs: int, jitter: float = 0.0) -> list[float]:
    """CPU seconds per ``skeleton_to_bvh`` call of an ``n_frames`` take (joints moved by
    ``jitter`` metres of noise off the rigid skeleton), ``runs`` times (in the code found
    first on ``sys.path``)."""
    from bonefit.estimation.io.skeleton import skeleton_to_bvh
    from tests.estimation.test_io_skeleton import rigid_result

    result = rigid_result(n_frames=n_frames, seed=1, yaw_turns=n_frames / 7200,
                          jitter=jitter)
    times = []
    for _ in range(runs):
        start = time.process_time()
        skeleton_to_bvh(result)
        times.append(time.process_time() - start)
    return times


def in_process(code: Path, n_frames: int, runs: int, jitter: float) -> list[float]:
    """:func:`time_writer` run in a child process with ``code`` first on the path."""
    env = {**os.environ, "PYTHONPATH": str(code)}
    run = subprocess.run([sys.executable, __file__, "--child", str(n_frames), "--runs",
                          str(runs), "--jitter", str(jitter)], env=env, cwd=code,
                         capture_output=True, text=True, check=False)
    if run.returncode != 0:
        raise SystemExit(f"timing in {code} failed:\n{run.stderr[-2000:]}")
    times: list[float] = json.loads(run.stdout)
    return times


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, nargs="+", default=[36_000, 144_000])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--baseline", type=Path, default=None,
                        help="another checkout of the code to time the same takes with")
    parser.add_argument("--jitter", type=float, default=0.0,
                        help="noise (m) on the joints: an estimate's non-rigid skeleton "
                             "(default 0: rigid)")
    parser.add_argument("--child", type=int, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child is not None:
        print(json.dumps(time_writer(args.child, args.runs, args.jitter)))
        return 0
    print(f"{'frames':>8s} {'this (CPU s)':>12s} {'baseline (CPU s)':>16s} {'ratio':>7s}   runs")
    for n_frames in args.frames:
        base = (in_process(args.baseline, n_frames, args.runs, args.jitter)
                if args.baseline else [])
        this = in_process(ROOT, n_frames, args.runs, args.jitter)
        ratio = (f"{statistics.median(base) / statistics.median(this):6.1f}x"
                 if base else "")
        print(f"{n_frames:8d} {statistics.median(this):12.2f} "
              f"{statistics.median(base) if base else float('nan'):16.2f} {ratio:>7s}   "
              f"{args.runs}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
