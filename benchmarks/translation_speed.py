"""Speed of root translation: both methods on 10,000 frames × 25 joints, against a plain
transcription of the paper's pseudocode loop (O(N²): each correction rewrites every later
frame) as the baseline, in the same run; then linearity (1×, 2×, 4× the frames).

    .venv/bin/python benchmarks/translation_speed.py [--frames 10000] [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from bonefit.estimation.io.kinematics import GRAVITY, KinematicsRecording
from bonefit.estimation.translation import HACHAJ_EPS_M, estimate_translation, hachaj_smooth


def synthetic(n_frames: int, n_joints: int = 25, seed: int = 0) -> KinematicsRecording:
    """A random-walk body of ``n_joints`` with two feet and g-like foot accelerometers."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames) / 100.0
    base = rng.normal(0, 0.3, (n_joints, 3))
    wobble = np.cumsum(rng.normal(0, 0.002, (n_frames, n_joints, 3)), axis=0)
    positions = base[None] + wobble
    positions[:, 1, 1] = 0.08 + 0.05 * np.clip(np.sin(2 * np.pi * 0.8 * t), 0, None)
    positions[:, 2, 1] = 0.08 + 0.05 * np.clip(-np.sin(2 * np.pi * 0.8 * t), 0, None)
    acc = {}
    for k, name in ((1, "LeftFoot"), (2, "RightFoot")):
        a = rng.normal(0, 0.3, (n_frames, 3))
        a[:, 1] += 1.0 + 0.8 * np.clip((-1) ** k * np.sin(2 * np.pi * 0.8 * t), 0, None)
        acc[name] = a * GRAVITY
    joints = ("Hips", "LeftFoot", "RightFoot", *(f"J{j}" for j in range(3, n_joints)))
    return KinematicsRecording(joints=joints, positions=positions, fps=100.0, time=t,
                               accelerations=acc, root="Hips")


def quadratic_baseline(rec: KinematicsRecording) -> NDArray[np.float64]:
    """The paper's Pseudocode 1.1–1.3 as written: every correction shifts all later frames."""
    p = rec.positions.copy()
    n = p.shape[0]
    li, ri = rec.index("LeftFoot"), rec.index("RightFoot")
    z_r = hachaj_smooth(np.linalg.norm(rec.accelerations["RightFoot"], axis=1))
    z_l = hachaj_smooth(np.linalg.norm(rec.accelerations["LeftFoot"], axis=1))
    for a in range(n - 1):
        if z_r[a] > z_l[a] and z_r[a + 1] > z_l[a + 1]:
            p[a + 1:] -= p[a + 1, li] - p[a, li]
        elif z_r[a] < z_l[a] and z_r[a + 1] < z_l[a + 1]:
            p[a + 1:] -= p[a + 1, ri] - p[a, ri]
    z_r = hachaj_smooth(p[:, ri, 1])
    z_l = hachaj_smooth(p[:, li, 1])
    for a in range(n - 1):
        if abs(z_r[a] - z_l[a]) > HACHAJ_EPS_M:
            if z_r[a] > z_l[a] and z_r[a + 1] > z_l[a + 1]:
                p[a + 1:] -= p[a + 1, li] - p[a, li]
            elif z_r[a] < z_l[a] and z_r[a + 1] < z_l[a + 1]:
                p[a + 1:] -= p[a + 1, ri] - p[a, ri]
    ground = p[0, ri, 1]
    for a in range(n):
        lower = li if z_r[a] >= z_l[a] else ri
        p[a, :, 1] -= p[a, lower, 1] - ground
    return p


def timed(fn: Callable[[], object], repeats: int, best: bool = False) -> float:
    """Median (or best, less sensitive to other processes) wall time of ``repeats`` runs."""
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        runs.append(time.perf_counter() - start)
    return min(runs) if best else statistics.median(runs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--baseline-repeats", type=int, default=3)
    args = parser.parse_args()
    rec = synthetic(args.frames)
    fast = estimate_translation(rec, method="hachaj2018").positions
    slow_p = quadratic_baseline(rec)
    agree = float(np.abs(fast - slow_p).max())
    t_base = timed(lambda: quadratic_baseline(rec), args.baseline_repeats)
    t_h = timed(lambda: estimate_translation(rec, method="hachaj2018"), args.repeats)
    t_c = timed(lambda: estimate_translation(rec, method="contact"), args.repeats)
    print(f"{args.frames} frames × 25 joints, median of {args.repeats} runs "
          f"(baseline {args.baseline_repeats})")
    print()
    print("| method | time s | speed-up vs O(N²) baseline |")
    print("|---|---|---|")
    print(f"| O(N²) pseudocode loop (baseline) | {t_base:.3f} | 1× |")
    print(f"| hachaj2018 (cumulative sums) | {t_h:.4f} | {t_base / t_h:,.0f}× |")
    print(f"| contact | {t_c:.4f} | {t_base / t_c:,.0f}× |")
    print()
    print(f"hachaj2018 equals the baseline to {agree:.1e} m")
    print()
    print(f"Linearity (best of {args.repeats} runs)")
    print()
    print("| frames | hachaj2018 s | per frame µs | contact s | per frame µs |")
    print("|---|---|---|---|---|")
    for mult in (1, 2, 4):
        r = synthetic(args.frames * mult, seed=mult)
        th = timed(lambda r=r: estimate_translation(r, method="hachaj2018"), args.repeats, True)
        tc = timed(lambda r=r: estimate_translation(r, method="contact"), args.repeats, True)
        n = args.frames * mult
        print(f"| {n} | {th:.4f} | {th / n * 1e6:.2f} | {tc:.4f} | {tc / n * 1e6:.2f} |")


if __name__ == "__main__":
    main()
