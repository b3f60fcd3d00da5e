"""Accuracy of root translation on synthetic recordings from real clips (docs/benchmarks.md).

For every clip of ``../shared/data/motions`` (walks, turns, karate, dance; not the jump clips)
at 30, 60 and 100 fps, with and without 2 g accelerometer saturation: strip the root
translation, simulate the foot accelerometers, estimate the path with both methods and print
the mean and final horizontal hips error as % of the true path length, then the medians over
clips. Then closure, foot skate, floor penetration and vertical jumps on the real Heian Shodan
recording.

    .venv/bin/python benchmarks/translation_accuracy.py [--data DIR] [--quick]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from bonefit.estimation.bvh import read_bvh
from bonefit.estimation.io.kinematics import read_kinematics
from bonefit.estimation.simulate.inertial import simulate_inertial
from bonefit.estimation.translation import estimate_translation

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"

# (path under motions/, category, metres per unit, true fps if the header is wrong)
CLIPS: list[tuple[str, str, float, float | None]] = [
    ("cmu_bvh11/131_01.bvh", "walk", 0.05644, None),
    ("cmu_bvh11/131_02.bvh", "walk", 0.05644, None),
    ("bandai_namco/dataset-1_walk_normal_001.bvh", "walk", 0.01, None),
    ("bandai_namco/dataset-1_walk_old_001.bvh", "walk", 0.01, None),
    ("bandai_namco/dataset-1_walk_not-confident_001.bvh", "walk", 0.01, None),
    ("bandai_namco/dataset-1_walk-back_normal_001.bvh", "walk", 0.01, None),
    ("bandai_namco/dataset-1_walk-left_normal_001.bvh", "walk", 0.01, None),
    ("bandai_namco/dataset-1_walk-right_normal_001.bvh", "walk", 0.01, None),
    ("bandai_namco/dataset-2_walk_normal_001.bvh", "walk", 0.01, None),
    ("bandai_namco/dataset-2_walk_elderly_001.bvh", "walk", 0.01, None),
    ("bandai_namco/dataset-2_walk_exhausted_001.bvh", "walk", 0.01, None),
    ("bandai_namco/dataset-2_walk-turn-left_normal_001.bvh", "turn", 0.01, None),
    ("bandai_namco/dataset-2_walk-turn-right_normal_001.bvh", "turn", 0.01, None),
    ("bandai_namco/dataset-2_walk-turn-left_elderly_001.bvh", "turn", 0.01, None),
    ("cmu_acrnn/martial/03.bvh", "karate", 0.01, None),
    ("cmu_acrnn/martial/04.bvh", "karate", 0.01, None),
    ("cmu_acrnn/martial/06.bvh", "karate", 0.01, None),
    ("cmu_acrnn/martial/07.bvh", "karate", 0.01, None),
    ("cmu_acrnn/martial/09.bvh", "karate", 0.01, None),
    ("bandai_namco/dataset-1_kick_normal_001.bvh", "karate", 0.01, None),
    ("bandai_namco/dataset-1_punch_normal_001.bvh", "karate", 0.01, None),
    ("cmu_acrnn/salsa/01.bvh", "dance", 0.01, 60.0),
    ("cmu_acrnn/salsa/09.bvh", "dance", 0.01, 60.0),
    ("cmu_acrnn/salsa/16.bvh", "dance", 0.01, 60.0),
    ("cmu_acrnn/salsa/24.bvh", "dance", 0.01, 60.0),
    ("cmu_acrnn/indian/04.bvh", "dance", 0.01, None),
    ("cmu_acrnn/indian/14.bvh", "dance", 0.01, None),
    ("bandai_namco/dataset-1_dance-short_normal_001.bvh", "dance", 0.01, None),
]
QUICK = {"cmu_bvh11/131_01.bvh", "bandai_namco/dataset-1_walk_normal_001.bvh",
         "bandai_namco/dataset-2_walk-turn-left_normal_001.bvh", "cmu_acrnn/martial/03.bvh",
         "cmu_acrnn/salsa/01.bvh"}
RATES = (30.0, 60.0, 100.0)
METHODS = ("contact", "hachaj2018")


def run_clips(motions: Path, quick: bool,
              options: dict[str, object] | None = None) -> list[dict[str, object]]:
    rows: list[dict[str, object]] = []
    for rel, category, scale, true_fps in CLIPS:
        if quick and rel not in QUICK:
            continue
        path = motions / rel
        if not path.is_file():
            print(f"  (missing {rel})", file=sys.stderr)
            continue
        motion = read_bvh(path)
        for fps in RATES:
            for clip in (None, 2.0):
                rec, truth = simulate_inertial(motion, fps=fps, source_fps=true_fps,
                                               length_units_m=scale, clip_g=clip, seed=1)
                row: dict[str, object] = {"clip": rel, "category": category, "fps": fps,
                                          "clip_g": clip, "path_m": 0.0}
                for method in METHODS:
                    extra = options or {} if method == "contact" else {}
                    res = estimate_translation(rec, method=method, **extra)
                    err = truth.horizontal_errors(res.root)
                    row[f"{method}_mean"] = err["mean_pct"]
                    row[f"{method}_final"] = err["final_pct"]
                    row["path_m"] = err["path_m"]
                rows.append(row)
        print(f"  done {rel}", file=sys.stderr)
    return rows


def print_tables(rows: list[dict[str, object]]) -> None:
    print("| clip | cat | fps | clip | path m | contact mean % | contact final % "
          "| hachaj2018 mean % | hachaj2018 final % |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {Path(str(r['clip'])).stem} | {r['category']} | {r['fps']:.0f} | "
              f"{'2 g' if r['clip_g'] else '-'} | {float(str(r['path_m'])):.1f} | "
              f"{float(str(r['contact_mean'])):.1f} | {float(str(r['contact_final'])):.1f} | "
              f"{float(str(r['hachaj2018_mean'])):.1f} | "
              f"{float(str(r['hachaj2018_final'])):.1f} |")
    print()
    print("Medians over clips (mean / final horizontal hips error, % of path length)")
    print()
    print("| fps | saturation | contact mean | contact final | hachaj2018 mean "
          "| hachaj2018 final | ratio (contact/hachaj, mean) |")
    print("|---|---|---|---|---|---|---|")
    groups: list[tuple[str, str, list[dict[str, object]]]] = []
    for fps in RATES:
        for clip in (None, 2.0):
            sel = [r for r in rows if r["fps"] == fps and r["clip_g"] == clip]
            groups.append((f"{fps:.0f}", "2 g" if clip else "none", sel))
    groups.append(("all", "all", rows))
    for fps_s, sat, sel in groups:
        if not sel:
            continue
        med = {k: statistics.median(float(str(r[k])) for r in sel)
               for k in ("contact_mean", "contact_final", "hachaj2018_mean",
                         "hachaj2018_final")}
        print(f"| {fps_s} | {sat} | {med['contact_mean']:.1f} | {med['contact_final']:.1f} | "
              f"{med['hachaj2018_mean']:.1f} | {med['hachaj2018_final']:.1f} | "
              f"{med['contact_mean'] / med['hachaj2018_mean']:.2f} |")
    print()
    print("Medians by category (all rates and saturation)")
    print()
    print("| category | contact mean | hachaj2018 mean |")
    print("|---|---|---|")
    for cat in dict.fromkeys(str(r["category"]) for r in rows):
        sel = [r for r in rows if r["category"] == cat]
        print(f"| {cat} | {statistics.median(float(str(r['contact_mean'])) for r in sel):.1f} | "
              f"{statistics.median(float(str(r['hachaj2018_mean'])) for r in sel):.1f} |")


def heian_shodan(shadow: Path, options: dict[str, object] | None = None) -> None:
    path = shadow / "heian_shodan.csv"
    if not path.is_file():
        print(f"(no {path})")
        return
    rec = read_kinematics(path)
    print()
    print("Heian Shodan (real Shadow recording, 2600 frames at 100 Hz)")
    print()
    print("| method | closure cm | path m | foot skate cm/s | floor penetration cm "
          "| max vertical jump cm | max vertical step cm | time s |")
    print("|---|---|---|---|---|---|---|---|")
    hips = rec.positions[:, rec.index(rec.root)]
    closure_in = float(np.linalg.norm(hips[-1, [0, 2]] - hips[0, [0, 2]]) * 100)
    length_in = float(np.linalg.norm(np.diff(hips[:, [0, 2]], axis=0), axis=1).sum())
    print(f"| input (Shadow's own) | {closure_in:.1f} | {length_in:.2f} | | | | | |")
    for method in METHODS:
        t = time.perf_counter()
        extra = options or {} if method == "contact" else {}
        res = estimate_translation(rec, method=method, **extra)
        dt = time.perf_counter() - t
        q = res.quality
        print(f"| {method} | {q['closure_cm']:.1f} | {q['path_length_m']:.2f} | "
              f"{q['foot_skate_cm_s']:.1f} | {q['floor_penetration_cm']:.2f} | "
              f"{q['max_vertical_jump_cm']:.2f} | {q['max_vertical_step_cm']:.2f} | {dt:.3f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--quick", action="store_true", help="five clips only")
    parser.add_argument("--no-clips", action="store_true", help="Heian Shodan only")
    parser.add_argument("--options", default="{}",
                        help="JSON of contact-model options (ContactOptions fields)")
    args = parser.parse_args()
    options = json.loads(args.options)
    if not args.no_clips:
        rows = run_clips(args.data / "motions", args.quick, options)
        print_tables(rows)
    heian_shodan(args.data / "shadow", options)


if __name__ == "__main__":
    main()
