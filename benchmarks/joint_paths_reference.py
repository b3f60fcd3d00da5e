"""Every joint path of a subset of the accuracy benchmark, saved or compared bit for bit.

A guard for behaviour-identical refactors of the skeleton estimator: simulate a few clips of
different kinds exactly as ``skeleton_accuracy.py`` does, run every method (and the offsets
path, and ``auto`` without the shared slip model), and either save all joint paths, bone
lengths and offsets (``--save FILE``, an ``.npz``) or compare them with a saved run
(``--compare FILE``): bit-identical (``np.array_equal``) or the largest difference in metres.

Usage::

    .venv/bin/python benchmarks/joint_paths_reference.py --save /tmp/before.npz
    .venv/bin/python benchmarks/joint_paths_reference.py --compare /tmp/before.npz
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from skeleton_accuracy import PROTOCOL_NOISE, clips, simulation_noise, thinned  # noqa: E402

import bonefit.estimation.skeleton as skeleton  # noqa: E402
from bonefit.estimation.results import SkeletonResult  # noqa: E402
from bonefit.estimation.simulate.sensors import simulate_sensors  # noqa: E402

# one or two clips of each source and kind of motion
CLIPS = ("cmu_bvh11/131_01", "cmu_fairmotion/01_01", "cmu_acrnn/indian/04",
         "cmu_acrnn/martial/03", "cmu_acrnn/salsa/01", "bandai_namco/dataset-1_kick_normal_001",
         "bandai_namco/dataset-1_walk_normal_001",
         "bandai_namco/dataset-2_wave-both-hands_normal_001")
# (label, n_sensors, estimate_skeleton kwargs)
RUNS: list[tuple[str, int, dict[str, Any]]] = [
    ("auto", 15, {"method": "auto"}),
    ("auto-noslip", 15, {"method": "auto", "slip_hz": 0.0}),
    ("llsf", 15, {"method": "llsf"}),
    ("gdke", 15, {"method": "gdke"}),
    ("reduced", 15, {"method": "reduced"}),
    ("auto", 11, {"method": "auto"}),
    ("reduced", 11, {"method": "reduced"}),
    ("reduced-gdke", 11, {"method": "reduced", "torso": "gdke"}),
]


def at_offsets(rec: Any, calibration: SkeletonResult) -> SkeletonResult:
    """The offsets path: every joint at the offsets of an earlier estimate."""
    from_offsets = getattr(skeleton, "estimate_skeleton_from_offsets", None)
    if from_offsets is not None:
        return from_offsets(rec, calibration.offsets)  # type: ignore[no-any-return]
    return skeleton.estimate_skeleton(rec, offsets=calibration.offsets)


def arrays_of(key: str, result: SkeletonResult) -> dict[str, np.ndarray]:
    """Everything numeric of a result, by ``key/kind/name``."""
    out = {f"{key}/joint/{j}": np.asarray(p) for j, p in result.joints.items()}
    out.update({f"{key}/offset/{j}": np.asarray(o.local) for j, o in result.offsets.items()})
    out[f"{key}/bones"] = np.array([result.bone_lengths[b] for b in sorted(result.bone_lengths)])
    out.update({f"{key}/orientation/{s}": np.asarray(q)
                for s, q in result.orientations.items()})
    out[f"{key}/warnings"] = np.array(result.warnings, dtype=str)
    out.update({f"{key}/quality/{j}": np.array(json.dumps(quality_dict(q), sort_keys=True))
                for j, q in result.quality.items()})
    return out


def quality_dict(quality: Any) -> dict[str, Any]:
    """A joint's quality as the JSON writer sees it (a dict, or a typed record's fields)."""
    as_dict = getattr(quality, "as_dict", None)
    return dict(quality) if as_dict is None else dict(as_dict())


def run(data: Path, max_frames: int, seed: int) -> dict[str, np.ndarray]:
    found = {name: (path, units, fps) for name, path, units, fps in clips(data)}
    out: dict[str, np.ndarray] = {}
    for name in CLIPS:
        path, units, fps = found[name]
        motion, rate = thinned(path, fps, max_frames)
        t0 = time.perf_counter()
        for n in (15, 11):
            rec, _ = simulate_sensors(motion, units_m=units, n_sensors=n, fps=rate, seed=seed,
                                      **simulation_noise(PROTOCOL_NOISE))
            for label, n_sensors, kwargs in RUNS:
                if n_sensors != n:
                    continue
                key = f"{name}/{label}:{n}"
                result = skeleton.estimate_skeleton(rec, **kwargs)
                out.update(arrays_of(key, result))
                if label == "auto":
                    out.update(arrays_of(f"{name}/offsets:{n}", at_offsets(rec, result)))
        print(f"{name:55s} {motion.n_frames:5d} fr  {time.perf_counter() - t0:5.1f} s",
              flush=True)
    return out


def compare(now: dict[str, np.ndarray], saved: dict[str, np.ndarray]) -> int:
    """Print every array that differs; 0 when all are bit-identical."""
    missing = sorted(set(saved) ^ set(now))
    worst = 0.0
    differ = 0
    for key in sorted(set(saved) & set(now)):
        a, b = saved[key], now[key]
        if a.shape != b.shape:
            print(f"  shape {key}: {a.shape} -> {b.shape}")
            differ += 1
        elif not np.array_equal(a, b):
            diff = float(np.max(np.abs(a - b))) if a.dtype.kind == "f" else np.inf
            worst = max(worst, diff)
            differ += 1
            print(f"  differs {key}: max |diff| {diff:.3g}")
    for key in missing:
        print(f"  only in {'saved' if key in saved else 'this run'}: {key}")
    print(f"{len(saved)} arrays: {differ} differ (max {worst:.3g}), {len(missing)} missing")
    return 0 if differ == 0 and not missing else 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--max-frames", type=int, default=1500)
    parser.add_argument("--seed", type=int, default=1)
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--save", type=Path)
    group.add_argument("--compare", type=Path)
    args = parser.parse_args(argv)
    now = run(args.data, args.max_frames, args.seed)
    if args.save:
        np.savez_compressed(args.save, **now)
        print(f"saved {len(now)} arrays to {args.save}")
        return 0
    with np.load(args.compare, allow_pickle=False) as saved:
        return compare(now, dict(saved))


if __name__ == "__main__":
    raise SystemExit(main())
