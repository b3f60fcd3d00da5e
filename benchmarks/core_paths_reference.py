"""Reference outputs of the numerical core, to check that a refactor changes no number.

Runs a subset of the two accuracy benchmarks and stores every output array:

- translation (``benchmarks/translation_accuracy.py``): hips paths of both methods on a few
  clips at 30 and 100 fps, with and without 2 g saturation, plus the procedural walker
  (``simulate_walker``) and its estimates with contact options changed;
- skeleton (``benchmarks/skeleton_accuracy.py``): joint paths, orientations, bone lengths and
  numeric quality figures of ``auto`` (15 and 11 sensors) and ``reduced`` (least squares,
  11 sensors) on six clips, with the simulated recordings themselves.

Usage, from the project root::

    .venv/bin/python benchmarks/core_paths_reference.py --save /tmp/core_ref.npz
    .venv/bin/python benchmarks/core_paths_reference.py --compare /tmp/core_ref.npz

``--compare`` prints, per array that differs, the largest absolute difference, and exits 1 if
any array is not bit-identical (``np.array_equal``) or is missing.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from skeleton_accuracy import clips, thinned  # noqa: E402
from translation_accuracy import CLIPS as TRANSLATION_CLIPS  # noqa: E402

from bonefit.estimation.bvh import read_bvh  # noqa: E402
from bonefit.estimation.simulate.inertial import simulate_inertial, simulate_walker  # noqa: E402
from bonefit.estimation.simulate.sensors import simulate_sensors  # noqa: E402
from bonefit.estimation.skeleton import estimate_skeleton  # noqa: E402
from bonefit.estimation.translation import estimate_translation  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
TRANSLATION_SUBSET = ("cmu_bvh11/131_01.bvh",
                      "bandai_namco/dataset-2_walk-turn-left_normal_001.bvh",
                      "cmu_acrnn/martial/03.bvh", "cmu_acrnn/salsa/01.bvh")
SKELETON_SUBSET = ("cmu_bvh11/131_01", "bandai_namco/dataset-1_walk_normal_001",
                   "bandai_namco/dataset-1_kick_normal_001", "cmu_acrnn/martial/03",
                   "cmu_acrnn/salsa/01", "bandai_namco/dataset-2_wave-both-hands_normal_001")
SKELETON_RUNS = (("auto", 15, {"method": "auto"}), ("auto", 11, {"method": "auto"}),
                 ("reduced", 11, {"method": "reduced"}))
MAX_FRAMES = 600
Arrays = Iterator[tuple[str, np.ndarray]]


def translation_arrays(data: Path) -> Arrays:
    """Hips paths of both translation methods on simulated clips and the walker."""
    for rel, _category, scale, true_fps in TRANSLATION_CLIPS:
        if rel not in TRANSLATION_SUBSET:
            continue
        motion = read_bvh(data / "motions" / rel)
        for fps in (30.0, 100.0):
            for clip in (None, 2.0):
                rec, truth = simulate_inertial(motion, fps=fps, source_fps=true_fps,
                                               length_units_m=scale, clip_g=clip, seed=1)
                key = f"translation/{rel}/{fps:g}/{clip}"
                yield f"{key}/truth", truth.root
                yield f"{key}/acc", np.stack([rec.accelerations[f]
                                              for f in sorted(rec.accelerations)])
                for method in ("contact", "hachaj2018"):
                    res = estimate_translation(rec, method=method)
                    yield f"{key}/{method}/root", res.root
                    yield f"{key}/{method}/positions", res.positions
        print(f"  translation {rel}", file=sys.stderr, flush=True)
    yield from walker_arrays()


def walker_arrays() -> Arrays:
    for clip in (None, 2.0):
        rec, truth, labels = simulate_walker(fps=60, clip_g=clip)
        key = f"walker/{clip}"
        yield f"{key}/truth", truth.positions
        yield f"{key}/labels", labels.astype("U5")
        for method, options in (("contact", {}), ("hachaj2018", {}),
                                ("hachaj2018", {"window": 40, "eps": 0.03}),
                                ("contact", {"clip_g": 2.0, "floor": "lowest"})):
            try:
                res = estimate_translation(rec, method=method, **options)  # type: ignore[arg-type]
            except Exception as exc:  # a refusal is part of the reference
                yield f"{key}/{method}/{sorted(options.items())}/error", np.array(str(exc))
                continue
            yield f"{key}/{method}/{sorted(options.items())}/root", res.root


def skeleton_arrays(data: Path) -> Arrays:
    """Joint paths, orientations, bone lengths and quality of the skeleton subset."""
    for name, path, units, fps in clips(data):
        if name not in SKELETON_SUBSET:
            continue
        motion, rate = thinned(path, fps, MAX_FRAMES)
        for n in (15, 11):
            rec, truth = simulate_sensors(motion, units_m=units, n_sensors=n, fps=rate, seed=1)
            yield f"skeleton/{name}/{n}/positions", rec.positions
            yield f"skeleton/{name}/{n}/quaternions", rec.quaternions
            yield f"skeleton/{name}/{n}/truth", np.stack(
                [truth.joints[j] for j in sorted(truth.joints)])
            for label, n_sensors, kwargs in SKELETON_RUNS:
                if n_sensors == n:
                    yield from skeleton_result(f"skeleton/{name}/{label}:{n}", rec, kwargs)
        print(f"  skeleton {name}", file=sys.stderr, flush=True)


def skeleton_result(key: str, rec: object, kwargs: dict[str, str]) -> Arrays:
    res = estimate_skeleton(rec, **kwargs)  # type: ignore[arg-type]
    for joint in sorted(res.joints):
        yield f"{key}/joints/{joint}", res.joints[joint]
    for seg in sorted(res.orientations):
        yield f"{key}/orientations/{seg}", res.orientations[seg]
    yield f"{key}/bones", np.array([res.bone_lengths[b] for b in sorted(res.bone_lengths)])
    for joint in sorted(res.quality):
        for k, v in sorted(res.quality[joint].items()):
            yield f"{key}/quality/{joint}/{k}", np.asarray(v)
    yield f"{key}/warnings", np.array(list(res.warnings), dtype=str)


def all_arrays(data: Path) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for key, value in (*translation_arrays(data), *skeleton_arrays(data)):
        out[key] = np.asarray(value)
    return out


def compare(reference: dict[str, np.ndarray], current: dict[str, np.ndarray]) -> int:
    bad = 0
    for key in sorted(set(reference) | set(current)):
        if key not in current or key not in reference:
            print(f"MISSING {'now' if key not in current else 'in reference'}: {key}")
            bad += 1
            continue
        a, b = reference[key], current[key]
        if a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b, equal_nan=(
                a.dtype.kind == "f")):
            continue
        bad += 1
        if a.shape == b.shape and a.dtype.kind in "fc" and b.dtype.kind in "fc":
            print(f"DIFF {key}: max |diff| {np.nanmax(np.abs(a - b)):.3g}")
        else:
            print(f"DIFF {key}: {a.dtype}{a.shape} vs {b.dtype}{b.shape}: {a!r:.80} / {b!r:.80}")
    print(f"{len(reference)} reference arrays, {bad} differ")
    return 1 if bad else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DATA)
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--save", type=Path)
    group.add_argument("--compare", type=Path)
    args = parser.parse_args(argv)
    current = all_arrays(args.data)
    if args.save:
        np.savez_compressed(args.save, **current)  # type: ignore[arg-type]
        print(f"saved {len(current)} arrays to {args.save}")
        return 0
    with np.load(args.compare, allow_pickle=True) as ref:  # a file this script wrote
        reference = {k: ref[k] for k in ref.files}
    return compare(reference, current)


if __name__ == "__main__":
    raise SystemExit(main())
