"""Speed of skeleton estimation on a recording the size of the paper's RT1 (6,283 frames, 30 fps).

Builds synthetic 15- and 11-sensor recordings (``bonefit.estimation.simulate.sensors``,
docs/benchmarks.md's noise protocol) from a real clip in ``../shared/data/motions``, played
forwards and backwards until it has the wanted number of frames, and times
``estimate_skeleton`` per method by its own ``timings["estimate_s"]`` (median of several runs,
every method in the same process).

Run from the project root::

    .venv/bin/python benchmarks/skeleton_speed.py            # RT1 size, 3 runs
    .venv/bin/python benchmarks/skeleton_speed.py --runs 5 --scales 1 4 16

The process is configured as the CLI's estimating commands and the service's workers configure
theirs: BLAS on one thread (``OPENBLAS_NUM_THREADS=1`` and its siblings, unless already set;
threaded BLAS on these thin arrays adds noise, not speed) and glibc's malloc keeping freed
memory for the next estimate (``memory.retain_freed_memory``: in a process that estimates a
recording it loaded, each default estimate at RT1 size otherwise faults in about 2,700 pages
anew; here the recordings simulated first have usually raised malloc's dynamic thresholds
already, and the estimates take almost no faults either way). ``--default-malloc`` leaves
malloc's own thresholds, as before 2026-11-27.

Prints four tables: time per method (with its stages: gap filling, torso joints, limbs,
orientations, from the progress reports); Nelder–Mead against the default least-squares
optimizer of the paper's reduced method (whole estimate and limb stage alone, as a ratio of
medians and as the median of alternating pairs; cost evaluations and E per limb); and the
default reduced method at 1×, 4×, 16× the frames (it should grow linearly); and the
Nelder–Mead / least-squares ratio of the reduced method on held-out recordings (other clips
and seeds, 11 and 15 sensors, with slip) next to the benchmark recording
(``--held-out-only``: that table alone), of wall time and of the process's CPU time (on a
shared machine a 30 ms estimate is preempted at random; the CPU time counts the work).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any, NamedTuple

from bonefit.estimation.memory import retain_freed_memory
from bonefit.estimation.threads import limit_blas_threads

limit_blas_threads()  # before numpy loads BLAS
if "--default-malloc" not in sys.argv:
    retain_freed_memory()

import numpy as np  # noqa: E402

from bonefit.estimation.bvh import BvhMotion, read_bvh  # noqa: E402
from bonefit.estimation.recording import SensorRecording  # noqa: E402
from bonefit.estimation.simulate.sensors import simulate_sensors  # noqa: E402
from bonefit.estimation.skeleton import estimate_skeleton  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "motions"
DEFAULT_CLIP = "cmu_acrnn/martial/03.bvh"  # karate, 120 fps, cm
RT1_FRAMES = 6283
RT1_FPS = 30.0
LIMB_JOINTS = ("l_knee", "r_knee", "l_elbow", "r_elbow")


def resampled(motion: BvhMotion, fps: float, n_frames: int) -> BvhMotion:
    """The clip at ``fps`` (every k-th frame), played forwards then backwards (no jumps at the
    seams) until it has ``n_frames`` frames."""
    step = max(1, round(motion.fps / fps))
    values = motion.values[::step]
    cycle = np.concatenate([values, values[-2:0:-1]])
    reps = int(np.ceil(n_frames / len(cycle)))
    out = np.tile(cycle, (reps, 1))[:n_frames]
    return BvhMotion(motion.names, motion.parents, motion.offsets, motion.channels,
                     1.0 / fps, out)


def recordings(clip: Path, n_frames: int, units_m: float, seed: int = 1
               ) -> tuple[SensorRecording, SensorRecording]:
    motion = resampled(read_bvh(clip), RT1_FPS, n_frames)
    full, _ = simulate_sensors(motion, units_m=units_m, n_sensors=15, seed=seed, fps=RT1_FPS)
    reduced, _ = simulate_sensors(motion, units_m=units_m, n_sensors=11, seed=seed,
                                  fps=RT1_FPS)
    return full, reduced


STAGES = ("gaps", "slip", "torso", "limbs", "orientations")
# held-out inputs for the Nelder–Mead / least-squares ratio: other clips (cm), other seeds
HELD_OUT_CLIPS = ("cmu_acrnn/salsa/01.bvh", "cmu_acrnn/indian/04.bvh", "cmu_acrnn/martial/06.bvh")
HELD_OUT_SEEDS = (2, 3)


class StageClock:
    """Progress callback that records when each stage is first reported, and the last call."""

    def __init__(self) -> None:
        self.first: dict[str, float] = {}
        self.last = 0.0

    def __call__(self, fraction: float, stage: str) -> None:
        now = time.perf_counter()
        self.first.setdefault(stage, now)
        self.last = now

    def limbs_s(self) -> float:
        return self.first["orientations"] - self.first["limbs"]

    def stages_s(self) -> dict[str, float]:
        """Seconds from each stage's first report to the next stage's (the last: to the
        final report)."""
        marks = [(s, self.first[s]) for s in STAGES if s in self.first]
        ends = [t for _, t in marks[1:]] + [self.last]
        return {s: end - start for (s, start), end in zip(marks, ends, strict=True)}


class Timing(NamedTuple):
    median_s: float
    runs_s: list[float]
    result: Any
    limbs_s: float
    stages_s: dict[str, float]


def timed(recording: SensorRecording, runs: int, **options: Any) -> Timing:
    """Median estimate_s over runs, the runs, the last result, median limb-stage seconds and
    median seconds per stage."""
    times, limb_times = [], []
    stages: dict[str, list[float]] = {}
    result = None
    for _ in range(runs):
        clock = StageClock()
        result = estimate_skeleton(recording, progress=clock, **options)
        times.append(float(result.timings["estimate_s"]))
        if "limbs" in clock.first and "orientations" in clock.first:
            limb_times.append(clock.limbs_s())
        for stage, seconds in clock.stages_s().items():
            stages.setdefault(stage, []).append(seconds)
    limbs = statistics.median(limb_times) if limb_times else float("nan")
    return Timing(statistics.median(times), times, result, limbs,
                  {s: statistics.median(v) for s, v in stages.items()})


def table(header: list[str], rows: list[list[str]]) -> str:
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(header)]
    lines = ["| " + " | ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)) + " |",
             "|" + "|".join("-" * (w + 2) for w in widths) + "|"]
    lines += ["| " + " | ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) + " |"
              for r in rows]
    return "\n".join(lines)


class PairRatio(NamedTuple):
    """Medians over alternating pairs: seconds of each path, and the per-pair ratios of
    wall time (``estimate_s``) and of the process's CPU time."""

    nm_s: float
    ls_s: float
    ratio: float
    cpu_ratio: float


def wall_and_cpu(recording: SensorRecording, **options: Any) -> tuple[float, float]:
    """``estimate_s`` of one estimate and the CPU seconds the process spent in it: with one
    BLAS thread, the work done, which other jobs on a shared machine do not change."""
    cpu = time.process_time()
    result = estimate_skeleton(recording, progress=StageClock(), **options)
    return float(result.timings["estimate_s"]), time.process_time() - cpu


def pair_ratio(rec: SensorRecording, runs: int) -> PairRatio:
    """The reduced method by Nelder–Mead and by least squares, run alternately (both see
    the same load)."""
    nm_s, ls_s, ratios, cpu_ratios = [], [], [], []
    for _ in range(runs):
        nm, nm_cpu = wall_and_cpu(rec, method="reduced", optimizer="nelder-mead")
        ls, ls_cpu = wall_and_cpu(rec, method="reduced")
        nm_s.append(nm)
        ls_s.append(ls)
        ratios.append(nm / ls)
        cpu_ratios.append(nm_cpu / ls_cpu)
    return PairRatio(statistics.median(nm_s), statistics.median(ls_s),
                     statistics.median(ratios), statistics.median(cpu_ratios))


def held_out_ratios(args: argparse.Namespace) -> None:
    """The reduced method's Nelder–Mead / least-squares ratio on recordings the optimizers
    were not tuned on: other clips and seeds, with the protocol's slip (5 mm), 11 and 15
    sensors (``reduced`` uses the 11 of the reduced suit either way; the draws differ)."""
    rows = []
    worst, worst_cpu = float("inf"), float("inf")
    for clip in (DEFAULT_CLIP, *HELD_OUT_CLIPS):
        for seed in (1,) if clip == DEFAULT_CLIP else HELD_OUT_SEEDS:
            full, reduced = recordings(DATA / clip, args.frames, args.units, seed)
            for sensors, rec in (("11", reduced), ("15", full)):
                pair = pair_ratio(rec, args.runs)
                if clip != DEFAULT_CLIP:
                    worst = min(worst, pair.ratio)
                    worst_cpu = min(worst_cpu, pair.cpu_ratio)
                rows.append([clip, f"{seed}", sensors, f"{pair.nm_s:.3f}", f"{pair.ls_s:.3f}",
                             f"{pair.ratio:.1f}", f"{pair.cpu_ratio:.1f}"])
                print("  " + " | ".join(rows[-1]), flush=True)  # a slow table: rows as they come
    print("\nReduced method, Nelder–Mead vs least-squares (default) on the benchmark recording "
          f"and held-out ones ({args.frames} frames at {RT1_FPS:g} fps, 5 mm slip; median of "
          f"{args.runs} alternating pairs; NM / LS of estimate_s and of the process's CPU "
          "time)\n")
    print(table(["clip", "seed", "sensors", "NM s", "LS s", "NM / LS", "NM / LS CPU"], rows))
    print(f"smallest held-out ratio: {worst:.1f}× (CPU time: {worst_cpu:.1f}×)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--clip", default=DEFAULT_CLIP, help="BVH under ../shared/data/motions")
    parser.add_argument("--units", type=float, default=0.01, help="metres per BVH unit")
    parser.add_argument("--frames", type=int, default=RT1_FRAMES)
    parser.add_argument("--runs", type=int, default=3, help="runs per method (median)")
    parser.add_argument("--scales", type=int, nargs="+", default=[1, 4, 16])
    parser.add_argument("--held-out-only", action="store_true",
                        help="only the Nelder–Mead / least-squares ratios on held-out inputs")
    parser.add_argument("--default-malloc", action="store_true",
                        help="leave glibc malloc's thresholds (see above; read at import)")
    args = parser.parse_args()
    if args.held_out_only:
        held_out_ratios(args)
        return

    clip = DATA / args.clip
    started = time.perf_counter()
    full, reduced = recordings(clip, args.frames, args.units)
    print(f"clip {args.clip}: {args.frames} frames at {RT1_FPS:g} fps "
          f"(built in {time.perf_counter() - started:.1f} s); median of {args.runs} runs; "
          f"OPENBLAS_NUM_THREADS={os.environ['OPENBLAS_NUM_THREADS']}\n")

    cases = [
        ("llsf", "15", full, {"method": "llsf"}),
        ("gdke", "15", full, {"method": "gdke"}),
        ("auto", "15", full, {"method": "auto"}),
        ("reduced, nelder-mead (paper)", "11", reduced,
         {"method": "reduced", "optimizer": "nelder-mead"}),
        ("reduced, least-squares (default)", "11", reduced, {"method": "reduced"}),
        ("auto", "11", reduced, {"method": "auto"}),
    ]
    rows = []
    results: dict[str, Timing] = {}
    for label, sensors, rec, options in cases:
        results[f"{label}/{sensors}"] = out = timed(rec, args.runs, **options)
        rows.append([label, sensors, f"{out.median_s:.3f}", f"{out.limbs_s:.3f}",
                     " ".join(f"{out.stages_s.get(s, float('nan')):.3f}" for s in STAGES),
                     " ".join(f"{t:.3f}" for t in out.runs_s)])
    print("Time per method (estimate_s and its stages, seconds; stages: "
          + ", ".join(STAGES) + ")\n")
    print(table(["method", "sensors", "median s", "limb stage s", "stages s", "runs s"], rows))

    nm = results["reduced, nelder-mead (paper)/11"]
    ls = results["reduced, least-squares (default)/11"]
    limb_rows = []
    for joint in LIMB_JOINTS:
        qn, ql = nm.result.quality[joint], ls.result.quality[joint]
        rel = abs(qn["cost"] - ql["cost"]) / ql["cost"]
        limb_rows.append([joint.split("_")[1] + (" (L)" if joint[0] == "l" else " (R)"),
                          f"{qn['n_evaluations']}", f"{ql['n_evaluations']}",
                          f"{ql['cost']:.6e}", f"{rel:.1e}"])
    # The machine may be shared: alternate the two paths so that both see the same load,
    # and report the median of the per-pair ratios next to the ratio of medians.
    pair_total, pair_limbs = [], []
    for _ in range(args.runs):
        a = timed(reduced, 1, method="reduced", optimizer="nelder-mead")
        b = timed(reduced, 1, method="reduced")
        pair_total.append(a.median_s / b.median_s)
        pair_limbs.append(a.limbs_s / b.limbs_s)
    print(f"\nNelder–Mead vs least-squares, same run: estimate_s {nm.median_s:.3f} s / "
          f"{ls.median_s:.3f} s = {nm.median_s / ls.median_s:.1f}×; limb stage "
          f"{nm.limbs_s:.3f} s / {ls.limbs_s:.3f} s = {nm.limbs_s / ls.limbs_s:.1f}×")
    print(f"alternating pairs, median of per-pair ratios: estimate_s "
          f"{statistics.median(pair_total):.1f}×, limb stage {statistics.median(pair_limbs):.1f}×"
          f" (pairs: {' '.join(f'{r:.1f}' for r in pair_total)} / "
          f"{' '.join(f'{r:.1f}' for r in pair_limbs)})")
    print("(paper's Table 2, RT1: LLSF 6 s, LLSF + present 27 s)\n")
    print(table(["limb", "NM evaluations", "LS evaluations", "E (LS)", "|ΔE|/E"], limb_rows))

    scale_rows = []
    base = None
    for scale in args.scales:
        n = args.frames * scale
        _, rec = recordings(clip, n, args.units) if scale != 1 else (full, reduced)
        red = timed(rec, args.runs, method="reduced")
        auto = timed(rec, args.runs, method="auto").median_s
        base = base or red.median_s / n
        scale_rows.append([f"{scale}×", f"{n}", f"{red.median_s:.3f}", f"{red.limbs_s:.3f}",
                           f"{red.median_s / n * 1e6:.1f}", f"{red.median_s / n / base:.2f}",
                           f"{auto:.3f}"])
    print("\nDefault reduced method (least-squares) against recording length, 11 sensors\n")
    print(table(["scale", "frames", "reduced s", "limb stage s", "µs / frame",
                 "per-frame vs 1×", "auto s"], scale_rows))
    held_out_ratios(args)


if __name__ == "__main__":
    main()
