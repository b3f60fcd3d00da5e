"""Names and topology of the 15-segment body model (docs/architecture.md, "Conventions")."""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise
from typing import Final

SEGMENTS: Final[tuple[str, ...]] = (
    "pelvis", "chest", "head",
    "l_upperarm", "l_forearm", "l_hand",
    "r_upperarm", "r_forearm", "r_hand",
    "l_thigh", "l_shank", "l_foot",
    "r_thigh", "r_shank", "r_foot",
)
"""Segment names; each carries one sensor in the full suit."""

DROPPED_IN_REDUCED: Final[tuple[str, ...]] = ("l_forearm", "r_forearm", "l_shank", "r_shank")
"""Segments whose sensors the reduced (11-sensor) suit leaves out (Miura et al. 2015)."""

REDUCED_SEGMENTS: Final[tuple[str, ...]] = tuple(
    s for s in SEGMENTS if s not in DROPPED_IN_REDUCED
)

@dataclass(frozen=True)
class BodyJoint:
    """One joint of the body model.

    Attributes
    ----------
    name : str
        Joint name.
    parent : str or None
        Parent joint in the kinematic tree (the BVH hierarchy); None for the root.
    segments : (str, str) or None
        The (proximal, distal) segments it connects: their sensors locate it. None for the
        joints derived from others (``root``, ``chest``; Miura et al. 2015, §2.1 and eq. 1).
    drives : str
        The segment (or ``"spine"``, the waist–chest link) whose orientation rotates the
        joint's node in a BVH hierarchy.
    """

    name: str
    parent: str | None
    segments: tuple[str, str] | None
    drives: str


BODY: Final[tuple[BodyJoint, ...]] = (
    BodyJoint("root", None, None, "pelvis"),
    BodyJoint("waist", "root", ("pelvis", "chest"), "spine"),
    BodyJoint("chest", "waist", None, "chest"),
    BodyJoint("neck", "chest", ("chest", "head"), "head"),
    BodyJoint("l_shoulder", "chest", ("chest", "l_upperarm"), "l_upperarm"),
    BodyJoint("r_shoulder", "chest", ("chest", "r_upperarm"), "r_upperarm"),
    BodyJoint("l_elbow", "l_shoulder", ("l_upperarm", "l_forearm"), "l_forearm"),
    BodyJoint("r_elbow", "r_shoulder", ("r_upperarm", "r_forearm"), "r_forearm"),
    BodyJoint("l_wrist", "l_elbow", ("l_forearm", "l_hand"), "l_hand"),
    BodyJoint("r_wrist", "r_elbow", ("r_forearm", "r_hand"), "r_hand"),
    BodyJoint("l_hip", "root", ("pelvis", "l_thigh"), "l_thigh"),
    BodyJoint("r_hip", "root", ("pelvis", "r_thigh"), "r_thigh"),
    BodyJoint("l_knee", "l_hip", ("l_thigh", "l_shank"), "l_shank"),
    BodyJoint("r_knee", "r_hip", ("r_thigh", "r_shank"), "r_shank"),
    BodyJoint("l_ankle", "l_knee", ("l_shank", "l_foot"), "l_foot"),
    BodyJoint("r_ankle", "r_knee", ("r_shank", "r_foot"), "r_foot"),
)
"""The body model, in the order of ``JOINTS``: every other table of this module (and the
bones, limbs and BVH tree of the rest of the package) is derived from it and ``CHAINS``."""

CHAINS: Final[dict[str, tuple[str, str, str]]] = {
    "trunk": ("root", "waist", "neck"),
    "l_arm": ("l_shoulder", "l_elbow", "l_wrist"),
    "r_arm": ("r_shoulder", "r_elbow", "r_wrist"),
    "l_leg": ("l_hip", "l_knee", "l_ankle"),
    "r_leg": ("r_hip", "r_knee", "r_ankle"),
}
"""Chains of joints along which the bones run: each consecutive pair bounds the bone of the
segment that carries the second joint."""

_BY_NAME: Final[dict[str, BodyJoint]] = {j.name: j for j in BODY}

JOINTS: Final[tuple[str, ...]] = tuple(j.name for j in BODY)
"""Joint names in results. ``root`` and ``chest`` are derived (paper eq. 1), the rest sit
between two segments."""

JOINT_SEGMENTS: Final[dict[str, tuple[str, str]]] = {
    j.name: j.segments for j in BODY if j.segments is not None}
"""For each two-segment joint, the (proximal, distal) segments it connects."""

BONES: Final[dict[str, tuple[str, str]]] = {
    JOINT_SEGMENTS[b][0]: (a, b) for chain in CHAINS.values() for a, b in pairwise(chain)}
"""Segment → (proximal joint, distal joint) whose mean distance is the segment's bone length."""


@dataclass(frozen=True)
class Limb:
    """An arm or a leg: three joints and the three segments below the first.

    Attributes
    ----------
    name : str
        ``l_arm``, ``r_arm``, ``l_leg`` or ``r_leg``.
    joints : (str, str, str)
        Proximal, middle and distal joint (shoulder, elbow, wrist).
    segments : (str, str, str)
        Upper, middle and distal segment (upper arm, forearm, hand).
    """

    name: str
    joints: tuple[str, str, str]
    segments: tuple[str, str, str]

    @property
    def is_arm(self) -> bool:
        """Whether it is an arm."""
        return self.name.endswith("arm")

    @property
    def length_keys(self) -> tuple[str, str]:
        """Keys of the upper and middle segments in a table of standard lengths
        (``limbs.standard_lengths``): ``("upperarm", "forearm")`` or ``("thigh", "shank")``."""
        return self.segments[0][2:], self.segments[1][2:]


def _limb(name: str) -> Limb:
    prox, mid, dist = CHAINS[name]
    upper, middle = JOINT_SEGMENTS[mid][0], JOINT_SEGMENTS[dist][0]
    return Limb(name, (prox, mid, dist), (upper, middle, JOINT_SEGMENTS[dist][1]))


LIMBS: Final[dict[str, Limb]] = {name: _limb(name) for name in CHAINS if name != "trunk"}
"""The four limbs, arms first."""


def _preorder(node: str) -> list[str]:
    below = [j.name for j in BODY if j.parent == node]
    return [node, *(n for child in below for n in _preorder(child))]


BVH_TREE: Final[tuple[tuple[str, str | None, str], ...]] = tuple(
    (name, _BY_NAME[name].parent, _BY_NAME[name].drives) for name in _preorder(BODY[0].name))
"""BVH joints as (node, parent node, segment whose orientation drives it), parents first
(depth first, children in the order of ``JOINTS``)."""

HINGE_JOINTS: Final[tuple[str, ...]] = ("l_elbow", "r_elbow", "l_knee", "r_knee")
"""Joints that behave as hinges in human motion (rank-deficient along their axis)."""
