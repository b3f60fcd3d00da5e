"""Numerical core of bonefit: skeletons and root paths from body-worn sensors.

Pure numpy/scipy; knows nothing of HTTP. Arrays are time-first, lengths metres, angles
radians, quaternions scalar-first ``(w, x, y, z)``.

Skeleton (magnetic 6-DOF trackers, Miura et al. 2015): `estimate_skeleton`, built from
`estimate_joint` (LLSF/GDKE with hinge handling), `estimate_slip` (every sensor's soft-tissue
slip from all joints at once), `estimate_limb` (limbs without forearm and lower-leg sensors)
and `estimate_orientations`. Root translation (inertial suits, Hachaj &
Ogiela): `estimate_translation`. File formats live in `bonefit.estimation.io`, synthetic recordings
with exact ground truth in `bonefit.estimation.simulate`.
"""

from typing import TYPE_CHECKING

if __name__ != "bonefit.estimation":  # one name only: two would make two BonefitError classes
    raise ImportError(f"import bonefit.estimation, not {__name__} (the package is installed "
                      "only inside the bonefit namespace)")

from ._lazy import lazy_attributes

if TYPE_CHECKING:
    from .bvh import BvhMotion, forward_kinematics, read_bvh, write_bvh
    from .errors import BonefitError, EstimationError, InputError, LimitError
    from .gaps import fill_gaps
    from .joints import JointFit, estimate_joint
    from .kinematics import KinematicsRecording
    from .limbs import LimbFit, estimate_limb, standard_lengths, torso_length
    from .model import DROPPED_IN_REDUCED, JOINTS, REDUCED_SEGMENTS, SEGMENTS
    from .orientations import estimate_orientations
    from .progress import Progress
    from .recording import SensorRecording
    from .results import (
        JointOffset,
        JointQuality,
        SkeletonResult,
        TranslationQuality,
        TranslationResult,
    )
    from .skeleton import (
        AutoOptions,
        GdkeOptions,
        LlsfOptions,
        ReducedOptions,
        estimate_chest,
        estimate_root,
        estimate_skeleton,
        estimate_skeleton_from_offsets,
    )
    from .slip import SlipFit, estimate_slip, rotation_noise_variance
    from .translation import ContactOptions, HachajOptions, estimate_translation

__all__ = [
    "DROPPED_IN_REDUCED",
    "JOINTS",
    "REDUCED_SEGMENTS",
    "SEGMENTS",
    "AutoOptions",
    "BonefitError",
    "BvhMotion",
    "ContactOptions",
    "EstimationError",
    "GdkeOptions",
    "HachajOptions",
    "InputError",
    "JointFit",
    "JointOffset",
    "JointQuality",
    "KinematicsRecording",
    "LimbFit",
    "LimitError",
    "LlsfOptions",
    "Progress",
    "ReducedOptions",
    "SensorRecording",
    "SkeletonResult",
    "SlipFit",
    "TranslationQuality",
    "TranslationResult",
    "estimate_chest",
    "estimate_joint",
    "estimate_limb",
    "estimate_orientations",
    "estimate_root",
    "estimate_skeleton",
    "estimate_skeleton_from_offsets",
    "estimate_slip",
    "estimate_translation",
    "fill_gaps",
    "forward_kinematics",
    "read_bvh",
    "rotation_noise_variance",
    "standard_lengths",
    "torso_length",
    "write_bvh",
]

# names above are imported from their submodule on first use (see _lazy)
__getattr__, __dir__ = lazy_attributes(__name__, {
    "bvh": ("BvhMotion", "forward_kinematics", "read_bvh", "write_bvh"),
    "errors": ("BonefitError", "EstimationError", "InputError", "LimitError"),
    "gaps": ("fill_gaps",),
    "kinematics": ("KinematicsRecording",),
    "joints": ("JointFit", "estimate_joint"),
    "limbs": ("LimbFit", "estimate_limb", "standard_lengths", "torso_length"),
    "model": ("DROPPED_IN_REDUCED", "JOINTS", "REDUCED_SEGMENTS", "SEGMENTS"),
    "orientations": ("estimate_orientations",),
    "progress": ("Progress",),
    "recording": ("SensorRecording",),
    "results": ("JointOffset", "JointQuality", "SkeletonResult", "TranslationQuality",
                "TranslationResult"),
    "skeleton": ("AutoOptions", "GdkeOptions", "LlsfOptions", "ReducedOptions",
                 "estimate_chest", "estimate_root", "estimate_skeleton",
                 "estimate_skeleton_from_offsets"),
    "slip": ("SlipFit", "estimate_slip", "rotation_noise_variance"),
    "translation": ("ContactOptions", "HachajOptions", "estimate_translation"),
})
