"""Accuracy of root translation on synthetic recordings from real clips (docs/benchmarks.md).

For every clip of ``../shared/data/motions`` (walks, turns, karate, dance; not the jump clips)
at 30, 60 and 100 fps, with and without 2 g accelerometer saturation, for each sensor
placement (``instep``: the realistic protocol of issue 20, sensor 3-8 cm ahead of and 2-6 cm
above the ankle, random mounting rotation, bias; ``instep-no-toes``: the same without toe
joints in the kinematics; ``ankle``: the sensor at the ankle joint, the protocol before;
not run by default, ``ankle-no-toes``: the sensor at the ankle without toe joints, with the
instep variants' noise and End Sites, which tells the instep's lever arm from the missing
toe joints) and seed (offsets, rotation, noise 0.01/0.02/0.005 g): strip the root
translation, simulate the foot accelerometers, estimate the path with both methods and
print the medians of the mean horizontal hips error as % of the true path length per
variant and seed, by rate × saturation and by category, with the issue's acceptance figures
(share of recordings where ``contact`` is within 0.5 points of ``hachaj2018``; with
``--before`` the same protocol run on earlier code beside; without toe joints, how often
``choose_toes`` kept the extrapolated toe point). Then closure, foot skate, floor
penetration and vertical jumps on the real Heian Shodan recording (a held-out check:
nothing is tuned on it).

    .venv/bin/python benchmarks/translation_accuracy.py [--data DIR] [--quick] \
        [--variants instep,ankle,ankle-no-toes] [--seeds 1,2,3] [--rates 60] [--category walk] \
        [--json rows.json] [--before rows_before.json] [--rows] [--options JSON] \
        [--no-clips | --no-heian]
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from itertools import product
from pathlib import Path

import numpy as np

from bonefit.estimation.bvh import BvhMotion, read_bvh
from bonefit.estimation.io.kinematics import read_kinematics
from bonefit.estimation.kinematics import KinematicsRecording
from bonefit.estimation.simulate.inertial import (
    ANKLE_MOUNT,
    INSTEP_MOUNT,
    FootMount,
    InertialTruth,
    simulate_inertial,
)
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
VARIANTS: dict[str, FootMount] = {
    "instep": INSTEP_MOUNT,
    "instep-no-toes": replace(INSTEP_MOUNT, keep_toes=False),
    "ankle": ANKLE_MOUNT,
    "ankle-no-toes": replace(ANKLE_MOUNT, keep_toes=False),
}
"""Sensor placements: the realistic protocol with and without toe joints in the kinematics,
the sensor at the ankle joint (the protocol before issue 20), and (not run by default) the
sensor at the ankle without toe joints, which tells the lever arm of an instep sensor from
the missing toe joints."""
DEFAULT_VARIANTS = ("instep", "instep-no-toes", "ankle")
OPT_IN: dict[str, object] = {"lever_arm_prior_m": 0.1, "extrapolate_toes": True}
"""The contact model's lever-arm fit and rolling toe estimate (off by default)."""
NOISE_G = {1: 0.01, 2: 0.02, 3: 0.005}
"""Accelerometer noise per seed, g (the ankle variant keeps 0.01 g, today's protocol)."""


def simulate(motion: BvhMotion, clip: tuple[str, str, float, float | None], fps: float,
             clip_g: float | None, *, variant: str, seed: int
             ) -> tuple[KinematicsRecording, InertialTruth]:
    """One synthetic recording of the protocol."""
    _rel, _category, scale, true_fps = clip
    noise = 0.01 if variant == "ankle" else NOISE_G.get(seed, 0.01)
    return simulate_inertial(motion, fps=fps, source_fps=true_fps, length_units_m=scale,
                             clip_g=clip_g, seed=seed, noise_g=noise, mount=VARIANTS[variant])


def run_clips(motions: Path, quick: bool, variants: list[str], seeds: list[int], *,
              options: dict[str, object] | None = None, rates: tuple[float, ...] = RATES,
              category: str | None = None) -> list[dict[str, object]]:
    """Errors of both methods on every clip × rate × saturation × variant × seed."""
    rows: list[dict[str, object]] = []
    for clip in CLIPS:
        rel, cat = clip[0], clip[1]
        if (quick and rel not in QUICK) or (category and cat != category):
            continue
        path = motions / rel
        if not path.is_file():
            print(f"  (missing {rel})", file=sys.stderr)
            continue
        motion = read_bvh(path)
        for variant, seed, fps, clip_g in product(variants, seeds, rates, (None, 2.0)):
            rec, truth = simulate(motion, clip, fps, clip_g, variant=variant, seed=seed)
            row: dict[str, object] = {"clip": rel, "category": cat, "fps": fps,
                                      "clip_g": clip_g, "variant": variant, "seed": seed}
            for method in METHODS:
                extra = options or {} if method == "contact" else {}
                result = estimate_translation(rec, method=method, **extra)
                err = truth.horizontal_errors(result.root)
                if method == "contact" and "toe_model" in result.quality:
                    row["toe_model"] = result.quality["toe_model"]
                row[f"{method}_mean"] = err["mean_pct"]
                row[f"{method}_final"] = err["final_pct"]
                row["path_m"] = err["path_m"]
            rows.append(row)
        print(f"  done {rel}", file=sys.stderr)
    return rows


def _median(rows: list[dict[str, object]], key: str) -> float:
    return statistics.median(float(str(r[key])) for r in rows) if rows else math.nan


def print_rows(rows: list[dict[str, object]]) -> None:
    """One line per recording."""
    print("| variant | seed | clip | cat | fps | clip | path m | contact mean % "
          "| contact final % | hachaj2018 mean % | hachaj2018 final % |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['variant']} | {r['seed']} | {Path(str(r['clip'])).stem} | "
              f"{r['category']} | {float(str(r['fps'])):.0f} | "
              f"{'2 g' if r['clip_g'] else '-'} | {float(str(r['path_m'])):.1f} | "
              f"{float(str(r['contact_mean'])):.1f} | {float(str(r['contact_final'])):.1f} | "
              f"{float(str(r['hachaj2018_mean'])):.1f} | "
              f"{float(str(r['hachaj2018_final'])):.1f} |")
    print()


def print_tables(rows: list[dict[str, object]],
                 before: list[dict[str, object]] | None = None) -> None:
    """Per variant and seed: medians by rate × saturation and by category, and the issue's
    acceptance figures; with ``before`` (the same protocol run on the earlier code) its
    ``contact`` medians beside."""
    for variant in dict.fromkeys(str(r["variant"]) for r in rows):
        for seed in dict.fromkeys(int(str(r["seed"])) for r in rows):
            sel = [r for r in rows if r["variant"] == variant and r["seed"] == seed]
            old = [r for r in before or [] if r["variant"] == variant and r["seed"] == seed]
            if sel:
                _print_variant(variant, seed, sel, old)


def _print_variant(variant: str, seed: int, sel: list[dict[str, object]],
                   old: list[dict[str, object]]) -> None:
    print(f"### {variant}, seed {seed} ({len(sel)} recordings; mean horizontal hips error, "
          "% of path, medians)")
    print()
    print("| group | contact | hachaj2018 | contact before | contact − hachaj |")
    print("|---|---|---|---|---|")
    groups: list[tuple[str, Callable[[dict[str, object]], bool]]] = [
        (f"{fps:.0f} fps {'2 g' if clip_g else 'none'}",
         lambda r, f=fps, c=clip_g: r["fps"] == f and r["clip_g"] == c)
        for fps, clip_g in product(RATES, (None, 2.0))]
    groups += [(cat, lambda r, c=cat: r["category"] == c)
               for cat in dict.fromkeys(str(r["category"]) for r in sel)]
    groups.append(("**all**", lambda r: True))
    for name, keep in groups:
        now = [r for r in sel if keep(r)]
        if not now:
            continue
        c, h = _median(now, "contact_mean"), _median(now, "hachaj2018_mean")
        b = _median([r for r in old if keep(r)], "contact_mean")
        before = "" if math.isnan(b) else f"{b:.2f}"
        print(f"| {name} | {c:.2f} | {h:.2f} | {before} | {c - h:+.2f} |")
    close = [float(str(r["contact_mean"])) <= float(str(r["hachaj2018_mean"])) + 0.5
             for r in sel]
    worst = max(float(str(r["contact_mean"])) - float(str(r["hachaj2018_mean"])) for r in sel)
    print()
    print(f"contact within 0.5 points of hachaj2018 (or better) on {sum(close)}/{len(close)} "
          f"= {100 * sum(close) / len(close):.0f} % of recordings; worst "
          f"contact − hachaj {worst:+.1f} points")
    chosen = [r["toe_model"] for r in sel if "toe_model" in r]
    if chosen:
        print(f"extrapolated toe point kept (choose_toes) on "
              f"{chosen.count('extrapolated')}/{len(chosen)} recordings")
    if old:
        pairs = {_key(r): float(str(r["contact_mean"])) for r in old}
        diffs = [float(str(r["contact_mean"])) - pairs[_key(r)] for r in sel if _key(r) in pairs]
        if diffs:
            print(f"contact now − before: median {statistics.median(diffs):+.2f}, worse by > "
                  f"0.5 points on {sum(d > 0.5 for d in diffs)}/{len(diffs)}")
    print()


def _key(r: dict[str, object]) -> tuple[object, ...]:
    return (r["clip"], r["fps"], r["clip_g"], r["variant"], r["seed"])


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
    runs: list[tuple[str, str, dict[str, object]]] = [
        ("contact", "contact", options or {}), ("hachaj2018", "hachaj2018", {}),
        ("contact + toe estimate (extrapolate_toes, opt-in)", "contact",
         {"extrapolate_toes": True, **(options or {})}),
        ("contact + lever arm + toe estimate (opt-in)", "contact", {**OPT_IN, **(options or {})})]
    for label, method, extra in runs:
        t = time.perf_counter()
        res = estimate_translation(rec, method=method, **extra)  # type: ignore[arg-type]
        dt = time.perf_counter() - t
        q = res.quality
        print(f"| {label} | {q['closure_cm']:.1f} | {q['path_length_m']:.2f} | "
              f"{q['foot_skate_cm_s']:.1f} | {q['floor_penetration_cm']:.2f} | "
              f"{q['max_vertical_jump_cm']:.2f} | {q['max_vertical_step_cm']:.2f} | {dt:.3f} |")
        if method == "contact":
            checks = [("closure ≤ 16.4 cm (the paper's)", q["closure_cm"] <= 16.4),
                      ("floor penetration ≤ 1 cm", q["floor_penetration_cm"] <= 1.0),
                      ("vertical jump ≤ 1 cm", q["max_vertical_jump_cm"] <= 1.0)]
            print("|  | " + "; ".join(f"{name}: {'yes' if ok else 'NO'}" for name, ok in checks)
                  + " | | | | | | |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--quick", action="store_true", help="five clips only")
    parser.add_argument("--no-clips", action="store_true", help="Heian Shodan only")
    parser.add_argument("--no-heian", action="store_true",
                        help="synthetic clips only (keep the held-out check unseen while tuning)")
    parser.add_argument("--variants", default=",".join(DEFAULT_VARIANTS),
                        help=f"comma-separated of {', '.join(VARIANTS)}")
    parser.add_argument("--seeds", default="1,2,3")
    parser.add_argument("--rates", default=",".join(f"{r:g}" for r in RATES))
    parser.add_argument("--category", help="one clip category only (walk, turn, ...)")
    parser.add_argument("--rows", action="store_true", help="print one line per recording")
    parser.add_argument("--json", type=Path, help="write the rows to this JSON file")
    parser.add_argument("--before", type=Path,
                        help="JSON rows of the same protocol run on earlier code, printed beside")
    parser.add_argument("--options", default="{}",
                        help="JSON of contact-model options (ContactOptions fields)")
    args = parser.parse_args()
    options = json.loads(args.options)
    if not args.no_clips:
        rows = run_clips(args.data / "motions", args.quick, args.variants.split(","),
                         [int(s) for s in args.seeds.split(",")], options=options,
                         rates=tuple(float(r) for r in args.rates.split(",")),
                         category=args.category)
        if args.json:
            args.json.write_text(json.dumps(rows))
        if args.rows:
            print_rows(rows)
        before = json.loads(args.before.read_text()) if args.before else None
        print_tables(rows, before)
    if not args.no_heian:
        heian_shodan(args.data / "shadow", options)


if __name__ == "__main__":
    main()
