"""Does the skeleton BVH say what the skeleton JSON says, at and between frames?

For every BVH clip under ``<data>/motions`` (the sensor recordings of
``benchmarks/skeleton_accuracy.py``: 15 sensors, the protocol's noise, one seed), estimate a
skeleton with ``method="auto"``, write its BVH, read it back and measure:

- ``key max/med``: joint positions of the BVH (forward kinematics) against the JSON's, at
  the frames (mm, every joint and frame), and ``start``: the largest over the first 10 frames;
- ``jumps``: steps between frames where a segment of the JSON turns by more than
  ``bonefit.estimation.bvh.JUMP_DEG`` (60°; a T-pose frame before the take turns segments 76–180°):
  no interpolation of rotations can follow them, so the half-frame numbers below leave them
  out and this column says how many were left out;
- ``half max`` / ``p95`` / ``median``: positions at half frames with the channels
  interpolated linearly, as Blender's importer keys them, against the midpoint of the
  JSON's neighbouring frames (mm, every joint and step but the jumps); ``all``: the same
  max with the jumps;
  ``floor``: the same with every node turned halfway along its shortest path (a joint under
  a slip chain relative to the chain's parent, its translation moving linearly), the least
  any interpolation of rotations can reach (a fast turn's arc bulges off the chord between
  the two frames' positions); ``euler``: the largest distance between the Euler-interpolated
  and the shortest-path half frames, the part the channels are to blame for; ``fair``:
  ``half max`` over the joints and steps whose floor is under 5 mm (where 10 mm can be met);
- ``jump``: the largest change of one rotation channel between two frames, jumps left out
  (degrees) and ``turn``: how far that node actually turned between those frames (degrees);
- with ``--readers``: ``bvhio`` and ``three.js``, the largest distance of the joints as those
  readers place them at the frames from the JSON's (mm).

``--order ZXY`` writes every node in one Euler order (the writer before per-node orders),
``--rest segment`` every node in its segment frame (the writer before rest rotations) and
``--slip-chains`` the joints exactly where the JSON has them (``skeleton_to_bvh``'s
``slip_chains``; by default the rigid skeleton). ``--cache DIR``
keeps each clip's estimated skeleton (JSON) for the next run; ``--bvh-from DIR`` measures
``DIR/<clip>.bvh`` (clip name with ``/`` as ``__``, written from the cached JSON by another
version of the writer) instead of writing. Usage::

    .venv/bin/python benchmarks/bvh_agreement.py [--data ../shared/data] [--only salsa]
        [--max-frames 1500] [--order ZXY] [--rest segment] [--readers] [--cache DIR]

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

from bonefit.estimation.bvh import (  # noqa: E402
    BvhMotion,
    forward_kinematics,
    is_slip_node,
    jump_steps,
    read_bvh,
)
from bonefit.estimation.io.skeleton import (  # noqa: E402
    read_skeleton_json,
    write_skeleton_bvh,
    write_skeleton_json,
)
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
    between the JSON's neighbouring frames). A joint under a slip chain is taken relative
    to the chain's parent (the chain turned back, its translation moving linearly between
    the frames); the chain's own nodes are NaN."""
    from scipy.spatial.transform import Rotation

    keyed, rotations = forward_kinematics(motion)
    slip = [is_slip_node(name) for name in motion.names]
    positions = np.full((motion.n_frames - 1, len(motion.names), 3), np.nan)
    world: dict[int, Rotation] = {}
    for j, parent in enumerate(motion.parents):
        while parent >= 0 and slip[parent]:
            parent = motion.parents[parent]
        if slip[j]:
            continue
        if parent < 0:
            local, trans = rotations[j], keyed[:, j]
        else:
            local = rotations[parent].inv() * rotations[j]
            trans = rotations[parent].inv().apply(keyed[:, j] - keyed[:, parent])
        step = (local[:-1].inv() * local[1:]).as_rotvec()
        halfway = local[:-1] * Rotation.from_rotvec(step / 2)
        trans = (trans[:-1] + trans[1:]) / 2
        if parent < 0:
            positions[:, j] = trans
            world[j] = halfway
        else:
            positions[:, j] = positions[:, parent] + world[parent].apply(trans)
            world[j] = world[parent] * halfway
    return positions


def largest_jump(motion: BvhMotion, skip: NDArray[np.bool_]) -> tuple[float, float, str]:
    """Largest rotation-channel change between frames (degrees) outside the steps ``skip``,
    the turn of that node between those frames (degrees) and the node's name."""
    local = motion.local_rotations()
    best = (0.0, 0.0, "")
    for j, chans in enumerate(motion.channels):
        rot = [k for k, c in enumerate(chans) if c.endswith("rotation")]
        if not rot:
            continue
        steps = np.abs(np.diff(motion.channel_values(j)[:, rot], axis=0)).max(axis=1)
        steps[skip] = 0.0
        t = int(np.argmax(steps))
        if steps[t] > best[0]:
            turn = float(np.degrees((local[j][t].inv() * local[j][t + 1]).magnitude()))
            best = (float(steps[t]), turn, motion.names[j])
    return best


def written(result: SkeletonResult, args: argparse.Namespace, name: str) -> BvhMotion:
    """The BVH of ``result`` as the writer writes it (or as ``--bvh-from`` has it)."""
    if args.bvh_from is not None:
        return read_bvh(args.bvh_from / f"{name.replace('/', '__')}.bvh")
    buf = io.StringIO()
    write_skeleton_bvh(result, buf, euler_order=args.order, rest=args.rest,
                       slip_chains=args.slip_chains)
    return read_bvh(io.StringIO(buf.getvalue()))


def measure(result: SkeletonResult, motion: BvhMotion) -> dict[str, float | str]:
    """The agreement numbers of one result and its BVH (see the module docstring)."""
    from scipy.spatial.transform import Rotation

    skip = jump_steps([Rotation.from_quat(q, scalar_first=True)
                       for q in result.orientations.values()])
    truth = np.stack([result.joints[j] for j in JOINTS], axis=1)
    key = np.linalg.norm(joint_positions_m(motion) - truth, axis=-1) * 1000
    mid = (truth[:-1] + truth[1:]) / 2
    euler = joint_positions_m(half_frames(motion))
    half = np.linalg.norm(euler - mid, axis=-1) * 1000
    arc = slerp_half_frames(motion)[:, [motion.index(j) for j in JOINTS]] / 100.0
    floor = np.linalg.norm(arc - mid, axis=-1) * 1000
    excess = np.linalg.norm(euler - arc, axis=-1) * 1000
    kept = half[~skip]
    jump, turn, node = largest_jump(motion, skip)
    return {"key_max": float(key.max()), "key_med": float(np.median(key)),
            "start": float(key[:START_FRAMES].max()), "jumps": int(skip.sum()),
            "half_all": float(half.max(initial=0.0)), "half_max": float(kept.max(initial=0.0)),
            "half_p95": float(np.percentile(kept, 95)) if kept.size else 0.0,
            "half_med": float(np.median(kept)) if kept.size else 0.0,
            "half_node": JOINTS[int(np.argmax(kept.max(axis=0)))] if kept.size else "",
            "floor": float(floor[~skip].max(initial=0.0)),
            "excess": float(excess[~skip].max(initial=0.0)),
            "half_fair": float(half[~skip][floor[~skip] < FAIR_FLOOR_MM].max(initial=0.0)),
            "jump": jump, "turn": turn, "jump_node": node}


def reader_errors(result: SkeletonResult, motion: BvhMotion) -> dict[str, float]:
    """Largest joint distance (mm) at the frames between the JSON and bvhio's and three.js's
    reading of ``motion`` written to a file (NaN for a reader that is not available)."""
    import tempfile

    from _pytest.outcomes import Skipped

    from bonefit.estimation.bvh import write_bvh
    from tests.estimation.bvh_readers import bvhio_positions, install_three, threejs_positions

    truth = np.stack([result.joints[j] for j in JOINTS], axis=1)
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "clip.bvh"
        write_bvh(motion, path)
        for reader in ("bvhio", "three.js"):
            try:
                got = (bvhio_positions(path) if reader == "bvhio"
                       else threejs_positions(install_three(), path))
            except Skipped:
                out[reader] = float("nan")
                continue
            pos = np.stack([got[j] for j in JOINTS], axis=1) / 100.0
            out[reader] = float(np.linalg.norm(pos - truth, axis=-1).max() * 1000)
    return out


def estimated(name: str, path: Path, units: float, fps: float | None,
              args: argparse.Namespace) -> SkeletonResult:
    """The clip's estimated skeleton (from ``--cache`` when it holds it)."""
    cached = args.cache / f"{name.replace('/', '__')}.json" if args.cache else None
    if cached is not None and cached.exists():
        return read_skeleton_json(cached)
    motion, rate = thinned(path, fps, args.max_frames)
    rec, _ = simulate_sensors(motion, units_m=units, n_sensors=15, fps=rate,
                              seed=args.seed, **simulation_noise(PROTOCOL_NOISE))
    result = estimate_skeleton(rec, method="auto")
    if cached is not None:
        cached.parent.mkdir(parents=True, exist_ok=True)
        write_skeleton_json(result, cached)
    return result


COLUMNS = (("frames", 6, "d"), ("key_max", 8, ".2f"), ("start", 7, ".2f"), ("jumps", 5, "d"),
           ("half_max", 8, ".2f"), ("half_p95", 8, ".2f"), ("half_med", 8, ".2f"),
           ("half_all", 8, ".1f"),
           ("half_node", 9, "s"), ("floor", 6, ".1f"), ("excess", 6, ".1f"),
           ("half_fair", 6, ".1f"), ("jump", 6, ".1f"), ("turn", 6, ".1f"),
           ("jump_node", 10, "s"))
"""Printed columns as (key, width, format)."""


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--only", default="", help="substring filter on clip names")
    parser.add_argument("--max-frames", type=int, default=100_000,
                        help="decimate longer clips (default: every frame, as recorded; "
                             f"the accuracy benchmark uses {MAX_FRAMES})")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--order", default=None,
                        help="one Euler order for every node (e.g. ZXY) instead of per node")
    parser.add_argument("--rest", default="auto", help="rest pose: auto or segment")
    parser.add_argument("--slip-chains", action="store_true",
                        help="write slip chains: every joint where the JSON has it")
    parser.add_argument("--readers", action="store_true",
                        help="also read every BVH with bvhio and three.js")
    parser.add_argument("--cache", type=Path, default=None,
                        help="directory keeping the estimated skeletons between runs")
    parser.add_argument("--bvh-from", type=Path, default=None,
                        help="measure DIR/<clip>.bvh instead of writing")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    heads = {"key_max": "key max", "half_max": "half max", "half_p95": "p95", "half_med": "median",
             "half_all": "all", "half_node": "(joint)", "excess": "euler",
             "half_fair": "fair", "jump_node": "(node)"}
    readers = ("bvhio", "three.js") if args.readers else ()
    print(f"{'clip':44s} " + " ".join(f"{heads.get(k, k):>{w}s}" for k, w, _ in COLUMNS)
          + "".join(f" {r:>8s}" for r in readers))
    rows = []
    for name, path, units, fps in clips(args.data):
        if args.only and args.only not in name:
            continue
        result = estimated(name, path, units, fps, args)
        motion = written(result, args, name)
        m: dict[str, float | str] = {"frames": result.n_frames, **measure(result, motion)}
        if readers:
            m.update(reader_errors(result, motion))
        rows.append(m)
        print(f"{name:44s} " + " ".join(f"{m[k]:>{w}{f}}" for k, w, f in COLUMNS)
              + "".join(f" {float(m[r]):8.3f}" for r in readers), flush=True)
    if rows:
        worst = {k: max(float(r[k]) for r in rows)
                 for k in ("key_max", "start", "half_max", "half_p95", "half_all", "floor",
                           "excess", "half_fair", "jump", *readers)}
        print(f"worst over {len(rows)} clips: key {worst['key_max']:.2f} mm, start "
              f"{worst['start']:.2f} mm, half frame {worst['half_max']:.2f} mm (p95 "
              f"{worst['half_p95']:.2f}; {sum(int(r['jumps']) for r in rows)} jump steps left "
              f"out, with them {worst['half_all']:.2f}; floor {worst['floor']:.2f}, Euler vs "
              f"shortest path {worst['excess']:.2f}, where the floor is under "
              f"{FAIR_FLOOR_MM:g} mm {worst['half_fair']:.2f}), channel jump "
              f"{worst['jump']:.1f} deg"
              + "".join(f", {r} {worst[r]:.3f} mm" for r in readers))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
