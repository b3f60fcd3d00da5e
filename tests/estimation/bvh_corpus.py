"""A generated corpus of BVH layouts and quirks: one walking body, named and written the way
suits and exporters do, in any length unit.

``body_motion(names, unit_m=..., toes=..., hip_joints=...)`` builds the same motion (same
world positions in metres) under another naming convention, unit or topology variant;
``bvh_text(motion, ...)`` writes it with a quirk (BOM, CRLF, tabs, braces on the name line,
a ``Frames:`` count larger than the rows).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from bonefit.estimation.bvh import BvhMotion
from bonefit.estimation.io.kinematics import GRAVITY
from bonefit.estimation.simulate.inertial import simulate_inertial

ROT = ("Zrotation", "Xrotation", "Yrotation")
ROOT_CHANNELS = ("Xposition", "Yposition", "Zposition", *ROT)

# role, parent role, offset in metres (+Y up, facing +Z, left = +X)
UPPER: tuple[tuple[str, str, tuple[float, float, float]], ...] = (
    ("spine", "hips", (0.0, 0.10, 0.0)),
    ("chest", "spine", (0.0, 0.20, 0.0)),
    ("neck", "chest", (0.0, 0.20, 0.0)),
    ("head", "neck", (0.0, 0.10, 0.0)),
    ("l_shoulder", "chest", (0.04, 0.15, 0.0)),
    ("l_arm", "l_shoulder", (0.12, 0.0, 0.0)),
    ("l_forearm", "l_arm", (0.28, 0.0, 0.0)),
    ("l_hand", "l_forearm", (0.25, 0.0, 0.0)),
    ("r_shoulder", "chest", (-0.04, 0.15, 0.0)),
    ("r_arm", "r_shoulder", (-0.12, 0.0, 0.0)),
    ("r_forearm", "r_arm", (-0.28, 0.0, 0.0)),
    ("r_hand", "r_forearm", (-0.25, 0.0, 0.0)),
)
END_SITES = {"head": (0.0, 0.15, 0.0), "l_hand": (0.08, 0.0, 0.0), "r_hand": (-0.08, 0.0, 0.0)}

CANONICAL: dict[str, str] = {
    "hips": "Hips", "l_hipjoint": "LHipJoint", "l_upleg": "LeftUpLeg", "l_leg": "LeftLeg",
    "l_foot": "LeftFoot", "l_toe": "LeftToeBase", "r_hipjoint": "RHipJoint",
    "r_upleg": "RightUpLeg", "r_leg": "RightLeg", "r_foot": "RightFoot",
    "r_toe": "RightToeBase", "spine": "Spine", "chest": "Spine1", "neck": "Neck",
    "head": "Head", "l_shoulder": "LeftShoulder", "l_arm": "LeftArm",
    "l_forearm": "LeftForeArm", "l_hand": "LeftHand", "r_shoulder": "RightShoulder",
    "r_arm": "RightArm", "r_forearm": "RightForeArm", "r_hand": "RightHand",
}


def legs(left: tuple[str, str, str, str], right: tuple[str, str, str, str]) -> dict[str, str]:
    """Names of thigh, shank, foot, toe of each side over the canonical names."""
    out = dict(CANONICAL)
    for side, names in (("l", left), ("r", right)):
        for role, name in zip(("upleg", "leg", "foot", "toe"), names, strict=True):
            out[f"{side}_{role}"] = name
    return out


CONVENTIONS: dict[str, dict[str, str]] = {
    "xsens-mvn": legs(("LeftHip", "LeftKnee", "LeftAnkle", "LeftToe"),
                      ("RightHip", "RightKnee", "RightAnkle", "RightToe")),
    "motion-shadow": legs(("LeftThigh", "LeftLeg", "LeftFoot", "LeftToe"),
                          ("RightThigh", "RightLeg", "RightFoot", "RightToe")),
    "perception-neuron": legs(("LeftUpLeg", "LeftLeg", "LeftFoot", "LeftToe"),
                              ("RightUpLeg", "RightLeg", "RightFoot", "RightToe")),
    "rokoko": legs(("LeftThigh", "LeftShin", "LeftFoot", "LeftToe"),
                   ("RightThigh", "RightShin", "RightFoot", "RightToe")),
    "mixamo": {k: f"mixamorig:{v}" for k, v in CANONICAL.items()},
    "cmu-131": legs(("LeftHip", "LeftKnee", "LeftAnkle", "LeftToe"),
                    ("RightHip", "RightKnee", "RightAnkle", "RightToe")),
    "bandai-namco": legs(("UpperLeg_L", "LowerLeg_L", "Foot_L", "Toes_L"),
                         ("UpperLeg_R", "LowerLeg_R", "Foot_R", "Toes_R")),
    "daz": legs(("lThigh", "lShin", "lFoot", "lToe"), ("rThigh", "rShin", "rFoot", "rToe")),
    "3ds-max-biped": legs(("Bip01 L Thigh", "Bip01 L Calf", "Bip01 L Foot", "Bip01 L Toe0"),
                          ("Bip01 R Thigh", "Bip01 R Calf", "Bip01 R Foot", "Bip01 R Toe0")),
}
"""Suits' and exporters' leg names (the upper body keeps the canonical names)."""


def anonymous() -> dict[str, str]:
    """Names that say nothing: feet must be found by topology."""
    return {role: f"node{k}" for k, role in enumerate(CANONICAL)}


def _roles(toes: bool, hip_joints: bool) -> list[tuple[str, str, tuple[float, float, float]]]:
    roles: list[tuple[str, str, tuple[float, float, float]]] = []
    for side, x in (("l", 0.09), ("r", -0.09)):
        top = "hips"
        if hip_joints:
            roles.append((f"{side}_hipjoint", "hips", (0.0, 0.0, 0.0)))
            top = f"{side}_hipjoint"
        roles += [(f"{side}_upleg", top, (x, -0.05, 0.0)),
                  (f"{side}_leg", f"{side}_upleg", (0.0, -0.42, 0.0)),
                  (f"{side}_foot", f"{side}_leg", (0.0, -0.40, 0.0))]
        if toes:
            roles.append((f"{side}_toe", f"{side}_foot", (0.0, -0.06, 0.13)))
    return roles + list(UPPER)


def _end_offset(role: str, toes: bool) -> tuple[float, float, float] | None:
    if role in END_SITES:
        return END_SITES[role]
    if toes and role.endswith("_toe"):
        return (0.0, 0.0, 0.05)
    if not toes and role.endswith("_foot"):
        return (0.0, -0.06, 0.18)
    return None


def _channel_values(role: str, t: NDArray[np.float64]) -> NDArray[np.float64]:
    """Z, X, Y rotation angles (degrees) of one joint over time: a walk at 1 step/s."""
    phase = 0.0 if role.startswith("l_") else np.pi
    w = 2 * np.pi * 1.0 * t + phase
    z = np.zeros_like(t)
    if role.endswith("upleg"):
        return np.column_stack([z, 25 * np.sin(w), z])
    if role.endswith("_leg"):
        return np.column_stack([z, 20 * (1 - np.cos(w)), z])
    if role.endswith("_foot"):
        return np.column_stack([z, -10 * np.sin(w), z])
    if role.endswith("_arm"):
        down = -60.0 if role.startswith("l_") else 60.0  # A-pose: hands by the hips
        return np.column_stack([down + 0 * t, -20 * np.sin(w), z])
    return np.column_stack([z, z, z])


def body_motion(names: Mapping[str, str] | None = None, *, unit_m: float = 0.01,
                toes: bool = True, hip_joints: bool = False, n_frames: int = 240,
                fps: float = 60.0) -> BvhMotion:
    """The walking body in ``unit_m`` metres per unit under ``names`` (role → name)."""
    names = CANONICAL if names is None else names
    t = np.arange(n_frames) / fps
    node_names, parents, offsets, channels, columns = ["Hips"], [-1], [(0.0, 0.0, 0.0)], \
        [ROOT_CHANNELS], []
    node_names[0] = names["hips"]
    root = np.column_stack([0.1 * np.sin(0.5 * t), 0.93 + 0.02 * np.sin(4 * np.pi * t),
                            1.0 * t]) / unit_m
    columns.append(np.column_stack([root, np.zeros_like(t), np.zeros_like(t),
                                    10 * np.sin(0.7 * t)]))
    index = {"hips": 0}
    for role, parent, offset in _roles(toes, hip_joints):
        index[role] = len(node_names)
        node_names.append(names[role])
        parents.append(index[parent])
        offsets.append(offset)
        channels.append(ROT)
        columns.append(_channel_values(role, t))
        end = _end_offset(role, toes)
        if end is not None:
            node_names.append(f"{names[role]}_end")
            parents.append(index[role])
            offsets.append(end)
            channels.append(())
    return BvhMotion(tuple(node_names), tuple(parents), np.array(offsets) / unit_m,
                     tuple(channels), 1.0 / fps, np.concatenate(columns, axis=1))


def bvh_text(motion: BvhMotion, *, newline: str = "\n", indent: str = "  ",
             bom: bool = False, brace_on_name_line: bool = False,
             frames: int | None = None) -> str:
    """BVH text of ``motion`` with the quirks asked for."""
    lines = ["HIERARCHY"]
    children: dict[int, list[int]] = {}
    for j, p in enumerate(motion.parents):
        children.setdefault(p, []).append(j)

    def node(j: int, depth: int) -> None:
        pad = indent * depth
        if motion.parents[j] < 0:
            head = f"ROOT {motion.names[j]}"
        elif motion.is_end_site(j):
            head = "End Site"
        else:
            head = f"JOINT {motion.names[j]}"
        if brace_on_name_line:
            lines.append(f"{pad}{head} {{")
        else:
            lines.extend([f"{pad}{head}", f"{pad}{{"])
        lines.append(f"{pad}{indent}OFFSET " + " ".join(f"{v:.9g}" for v in motion.offsets[j]))
        if not motion.is_end_site(j):
            chans = motion.channels[j]
            lines.append(f"{pad}{indent}CHANNELS {len(chans)} {' '.join(chans)}")
        for c in children.get(j, []):
            node(c, depth + 1)
        lines.append(f"{pad}}}")

    node(0, 0)
    lines += ["MOTION", f"Frames:{indent}{motion.n_frames if frames is None else frames}",
              f"Frame Time:{indent}{motion.frame_time:.9g}"]
    lines += [" ".join(f"{v:.9g}" for v in row) for row in motion.values]
    return ("\ufeff" if bom else "") + newline.join(lines) + newline


def accelerations_csv(path: Path, left: str, right: str, seed: int = 1) -> Path:
    """Foot accelerometers (g) of the canonical body, the columns named ``left``/``right``."""
    motion = body_motion()
    rec, _ = simulate_inertial(motion, length_units_m=0.01, left_foot="LeftFoot",
                               right_foot="RightFoot", seed=seed)
    cols = [rec.time]
    for foot in ("LeftFoot", "RightFoot"):
        cols += [rec.accelerations[foot][:, k] / GRAVITY for k in range(3)]
    header = "time," + ",".join(f"{f}.a{a}" for f in (left, right) for a in "xyz")
    np.savetxt(path, np.column_stack(cols), delimiter=",", header=header, comments="",
               fmt="%.9g")
    return path
