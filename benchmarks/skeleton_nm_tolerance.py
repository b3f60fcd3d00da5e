"""How far Nelder–Mead must converge to be compared fairly with the least-squares optimizer.

The paper minimises its limb cost E (eqs. 2–5) with the simplex method but gives no stopping
rule. ``estimate_limb(optimizer="nelder-mead")`` stops where the default least-squares path does
(``limbs._NM_XATOL_M``, ``limbs._NM_RTOL``); this script re-runs every limb fit of the accuracy
benchmark's 11-sensor recordings (all clips under ``<data>/motions``, same simulation protocol
and seed as ``skeleton_accuracy.py``) with several Nelder–Mead tolerances and prints, per
setting, the evaluations spent and how far above the least-squares E it ends.

Usage::

    .venv/bin/python benchmarks/skeleton_nm_tolerance.py [--data ../shared/data] [--only walk]

About a minute on two cores. A setting whose worst ``(E_NM − E_LS)/E_LS`` is far below the
least-squares path's own distance to the minimum (~1e-10, seen as negative values: Nelder–Mead
run further finds E that much lower) converges further than the comparison can use, and
inflates the speed-up reported by ``skeleton_speed.py``; one far above it compares a less
converged Nelder–Mead with a converged least-squares fit.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from skeleton_accuracy import MAX_FRAMES, clips, thinned  # noqa: E402

import bonefit.estimation.limbs as limbs  # noqa: E402
from bonefit.estimation.gaps import fill_gaps  # noqa: E402
from bonefit.estimation.simulate.sensors import simulate_sensors  # noqa: E402
from bonefit.estimation.skeleton import estimate_skeleton  # noqa: E402

# (proximal joint, upper sensor, distal sensor, standard-length keys)
LIMBS = (("l_hip", "l_thigh", "l_foot", ("thigh", "shank")),
         ("r_hip", "r_thigh", "r_foot", ("thigh", "shank")),
         ("l_shoulder", "l_upperarm", "l_hand", ("upperarm", "forearm")),
         ("r_shoulder", "r_upperarm", "r_hand", ("upperarm", "forearm")))
# (simplex size in metres, relative spread of E and restart gain)
SETTINGS = ((1e-10, 1e-13), (1e-6, 1e-9), (1e-5, 1e-8), (1e-4, 1e-7))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--max-frames", type=int, default=MAX_FRAMES)
    parser.add_argument("--only", default="", help="substring filter on clip names")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    if not (args.data / "motions").is_dir():
        print(f"no motions under {args.data}", file=sys.stderr)
        return 2
    evaluations = dict.fromkeys(SETTINGS, 0)
    seconds = dict.fromkeys(SETTINGS, 0.0)
    worst = dict.fromkeys(SETTINGS, -math.inf)
    best = dict.fromkeys(SETTINGS, math.inf)
    fits = 0
    current = (limbs._NM_XATOL_M, limbs._NM_RTOL)
    for name, path, units, fps in clips(args.data):
        if args.only and args.only not in name:
            continue
        motion, rate = thinned(path, fps, args.max_frames)
        rec, _ = simulate_sensors(motion, units_m=units, n_sensors=11, fps=rate,
                                  seed=args.seed)
        result = estimate_skeleton(rec, method="reduced")
        joints = result.joints
        std = limbs.standard_lengths(limbs.torso_length(joints["waist"], joints["l_hip"],
                                                        joints["r_hip"], joints["chest"]))
        pos, quat, _ = fill_gaps(rec.positions, rec.quaternions, time=rec.time)
        line = []
        for prox, upper, distal, (key_up, key_low) in LIMBS:
            ku, kd = rec.index(upper), rec.index(distal)
            inputs = (joints[prox], pos[:, ku], Rotation.from_quat(quat[:, ku], scalar_first=True),
                      pos[:, kd], Rotation.from_quat(quat[:, kd], scalar_first=True))
            lengths = (std[key_up], std[key_low])
            ls = limbs.estimate_limb(*inputs, standard_lengths=lengths, method="paper")
            fits += 1
            for setting in SETTINGS:
                limbs._NM_XATOL_M, limbs._NM_RTOL = setting
                started = time.perf_counter()
                nm = limbs.estimate_limb(*inputs, standard_lengths=lengths, method="paper",
                                         optimizer="nelder-mead")
                seconds[setting] += time.perf_counter() - started
                gap = (nm.cost - ls.cost) / ls.cost
                evaluations[setting] += nm.n_evaluations
                worst[setting] = max(worst[setting], gap)
                best[setting] = min(best[setting], gap)
                line.append(f"{nm.n_evaluations}:{gap:+.0e}")
        limbs._NM_XATOL_M, limbs._NM_RTOL = current
        print(f"{name:50s} {' '.join(line[:len(SETTINGS)])} ...", flush=True)

    print(f"\n{fits} limb fits (paper's E, 11 sensors); (E_NM − E_LS)/E_LS over all fits\n")
    print("| simplex m | spread and restart gain (relative) | evaluations | seconds | worst | "
          "lowest |")
    print("|---|---|---:|---:|---:|---:|")
    for setting in SETTINGS:
        mark = " (current)" if setting == current else ""
        print(f"| {setting[0]:g}{mark} | {setting[1]:g} | {evaluations[setting]:,} | "
              f"{seconds[setting]:.1f} | {worst[setting]:+.1e} | {best[setting]:+.1e} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
