"""Names and topology of the 15-segment body model (docs/architecture.md, "Conventions")."""

from __future__ import annotations

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

JOINTS: Final[tuple[str, ...]] = (
    "root", "waist", "chest", "neck",
    "l_shoulder", "r_shoulder", "l_elbow", "r_elbow", "l_wrist", "r_wrist",
    "l_hip", "r_hip", "l_knee", "r_knee", "l_ankle", "r_ankle",
)
"""Joint names in results. ``root`` and ``chest`` are derived (paper eq. 1), the rest sit
between two segments."""

JOINT_SEGMENTS: Final[dict[str, tuple[str, str]]] = {
    "waist": ("pelvis", "chest"),
    "neck": ("chest", "head"),
    "l_shoulder": ("chest", "l_upperarm"),
    "r_shoulder": ("chest", "r_upperarm"),
    "l_elbow": ("l_upperarm", "l_forearm"),
    "r_elbow": ("r_upperarm", "r_forearm"),
    "l_wrist": ("l_forearm", "l_hand"),
    "r_wrist": ("r_forearm", "r_hand"),
    "l_hip": ("pelvis", "l_thigh"),
    "r_hip": ("pelvis", "r_thigh"),
    "l_knee": ("l_thigh", "l_shank"),
    "r_knee": ("r_thigh", "r_shank"),
    "l_ankle": ("l_shank", "l_foot"),
    "r_ankle": ("r_shank", "r_foot"),
}
"""For each two-segment joint, the (proximal, distal) segments it connects."""

HINGE_JOINTS: Final[tuple[str, ...]] = ("l_elbow", "r_elbow", "l_knee", "r_knee")
"""Joints that behave as hinges in human motion (rank-deficient along their axis)."""
