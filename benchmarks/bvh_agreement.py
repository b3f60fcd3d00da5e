"""Does the skeleton BVH say what the skeleton JSON says, at and between frames?

For every BVH clip under ``<data>/motions`` (the sensor recordings of
``benchmarks/skeleton_accuracy.py``: 15 sensors, the protocol's noise, one seed), estimate a
skeleton with ``method="auto"``, write its BVH, read it back and measure:

- ``key max/med``: joint positions of the BVH (forward kinematics) against the JSON's, at
  the frames (mm, every joint and frame), and ``start``: the largest over the first 10 frames;
- ``half max``: positions at half frames with the channels interpolated linearly, as
  Blender's importer keys them, against the midpoint of the JSON's neighbouring frames (mm);
  ``floor``: the same with every node turned halfway along its shortest path, the least
  any interpolation of rotations can reach (a fast turn's arc bulges off the chord between
  the two frames' positions, and a data jump, a T-pose frame before the take, cannot be
  interpolated at all); ``euler``: the largest distance between the Euler-interpolated and
  the shortest-path half frames, the part the channel orders are to blame for; ``fair``:
  ``half max`` over the joints and frames whose floor is under 5 mm (where 10 mm can be met);
- ``jump``: the largest change of one rotation channel between two frames (degrees) and
  ``turn``: how far that node actually turned between those frames (degrees).

``--order ZXY`` writes every node in one Euler order (the writer before per-node orders) to
compare. Usage::

    .venv/bin/python benchmarks/bvh_agreement.py [--data ../shared/data] [--only salsa]
        [--max-frames 1500] [--order ZXY]

Clips are used at their recorded rate unless ``--max-frames`` decimates them; the
sub-frame error grows with the step between frames.
"""

from __future__ import annotations

import argparse
import io
import sys
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from skeleton_accuracy import (  # noqa: E402
    MAX_FRAMES,
    PROTOCOL_NOISE,
    clips,
    simulation_noise,
    thinned,
)

from bonefit.estimation.bvh import BvhMotion, forward_kinematics, read_bvh  # noqa: E402
from bonefit.estimation.io.skeleton import write_skeleton_bvh  # noqa: E402
from bonefit.estimation.model import JOINTS  # noqa: E402
from bonefit.estimation.results import SkeletonResult  # noqa: E402
from bonefit.estimation.simulate.sensors import simulate_sensors  # noqa: E402
from bonefit.estimation.skeleton import estimate_skeleton  # noqa: E402

START_FRAMES = 10
FAIR_FLOOR_MM = 5.0


def joint_positions_m(motion: BvhMotion) -> NDArray[np.float64]:
    """Positions (F, 16, 3) of the JOINTS nodes, metres (the file is in cm)."""
    positions, _ = forward_kinematics(motion)
    return positions[:, [motion.index(j) for j in JOINTS]] / 100.0


def half_frames(motion: BvhMotion) -> BvhMotion:
    """The motion at t + 1/2: channel values interpolated linearly, as Blender keys them."""
    return motion.with_values((motion.values[:-1] + motion.values[1:]) / 2)


def slerp_half_frames(motion: BvhMotion) -> NDArray[np.float64]:
    """Node positions (F - 1, J, 3) at half frames with every node turned halfway along
    its shortest path: the best any rotation interpolation can do (the arc, not the chord
    between the JSON's neighbouring frames)."""
    from scipy.spatial.transform import Rotation

    local = motion.local_rotations()
    trans = motion.local_translations()
    trans = (trans[:-1] + trans[1:]) / 2
    positions = np.empty_like(trans)
    world: list[Rotation] = []
    for j, parent in enumerate(motion.parents):
        step = (local[j][:-1].inv() * local[j][1:]).as_rotvec()
        halfway = local[j][:-1] * Rotation.from_rotvec(step / 2)
        if parent < 0:
            positions[:, j] = trans[:, j]
            world.append(halfway)
        else:
            positions[:, j] = positions[:, parent] + world[parent].apply(trans[:, j])
            world.append(world[parent] * halfway)
    return positions


def largest_jump(motion: BvhMotion) -> tuple[float, float, str]:
    """Largest rotation-channel change between frames (degrees), the turn of that node
    between those frames (degrees) and the node's name."""
    local = motion.local_rotations()
    best = (0.0, 0.0, "")
    for j, chans in enumerate(motion.channels):
        rot = [k for k, c in enumerate(chans) if c.endswith("rotation")]
        if not rot:
            continue
        steps = np.abs(np.diff(motion.channel_values(j)[:, rot], axis=0)).max(axis=1)
        t = int(np.argmax(steps))
        if steps[t] > best[0]:
            turn = float(np.degrees((local[j][t].inv() * local[j][t + 1]).magnitude()))
            best = (float(steps[t]), turn, motion.names[j])
    return best


def measure(result: SkeletonResult, order: str | None) -> dict[str, float | str]:
    """The agreement numbers of one result (see the module docstring)."""
    buf = io.StringIO()
    if order is None:
        write_skeleton_bvh(result, buf)
    else:
        write_skeleton_bvh(result, buf, euler_order=order)
    motion = read_bvh(io.StringIO(buf.getvalue()))
    truth = np.stack([result.joints[j] for j in JOINTS], axis=1)
    key = np.linalg.norm(joint_positions_m(motion) - truth, axis=-1) * 1000
    mid = (truth[:-1] + truth[1:]) / 2
    half = np.linalg.norm(joint_positions_m(half_frames(motion)) - mid, axis=-1) * 1000
    arc = slerp_half_frames(motion)[:, [motion.index(j) for j in JOINTS]] / 100.0
    floor = np.linalg.norm(arc - mid, axis=-1) * 1000
    euler = joint_positions_m(half_frames(motion))
    excess = np.linalg.norm(euler - arc, axis=-1) * 1000
    jump, turn, node = largest_jump(motion)
    return {"key_max": float(key.max()), "key_med": float(np.median(key)),
            "start": float(key[:START_FRAMES].max()), "half_max": float(half.max()),
            "half_node": JOINTS[int(np.argmax(half.max(axis=0)))],
            "floor": float(floor.max()), "excess": float(excess.max()),
            "half_fair": float(half[floor < FAIR_FLOOR_MM].max(initial=0.0)),
            "jump": jump, "turn": turn, "jump_node": node}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--only", default="", help="substring filter on clip names")
    parser.add_argument("--max-frames", type=int, default=100_000,
                        help="decimate longer clips (default: every frame, as recorded; "
                             f"the accuracy benchmark uses {MAX_FRAMES})")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--order", default=None,
                        help="one Euler order for every node (e.g. ZXY) instead of per node")
    args = parser.parse_args(argv)
    print(f"{'clip':44s} {'frames':>6s} {'key max':>8s} {'key med':>8s} {'start':>7s} "
          f"{'half max':>9s} {'(joint)':10s} {'floor':>6s} {'euler':>6s} {'fair':>6s} "
          f"{'jump':>6s} {'turn':>6s} (node)")
    rows = []
    for name, path, units, fps in clips(args.data):
        if args.only and args.only not in name:
            continue
        motion, rate = thinned(path, fps, args.max_frames)
        rec, _ = simulate_sensors(motion, units_m=units, n_sensors=15, fps=rate,
                                  seed=args.seed, **simulation_noise(PROTOCOL_NOISE))
        result = estimate_skeleton(rec, method="auto")
        m = measure(result, args.order)
        rows.append(m)
        print(f"{name:44s} {result.n_frames:6d} {m['key_max']:8.2f} {m['key_med']:8.2f} "
              f"{m['start']:7.2f} {m['half_max']:9.2f} {m['half_node']!s:10s} "
              f"{m['floor']:6.1f} {m['excess']:6.1f} {m['half_fair']:6.1f} "
              f"{m['jump']:6.1f} {m['turn']:6.1f} {m['jump_node']}", flush=True)
    if rows:
        worst = {k: max(float(r[k]) for r in rows)
                 for k in ("key_max", "start", "half_max", "floor", "excess", "half_fair",
                           "jump")}
        print(f"worst over {len(rows)} clips: key {worst['key_max']:.2f} mm, start "
              f"{worst['start']:.2f} mm, half frame {worst['half_max']:.2f} mm (floor "
              f"{worst['floor']:.2f}, Euler vs shortest path {worst['excess']:.2f}, where the "
              f"floor is under {FAIR_FLOOR_MM:g} mm {worst['half_fair']:.2f}), channel jump "
              f"{worst['jump']:.1f} deg")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
