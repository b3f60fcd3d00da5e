"""Numerical core of bonefit: skeletons and root paths from body-worn sensors.

Pure numpy/scipy; knows nothing of HTTP. Arrays are time-first, lengths metres, angles
radians, quaternions scalar-first ``(w, x, y, z)``.
"""

from .bvh import BvhMotion, forward_kinematics, read_bvh, write_bvh
from .errors import BonefitError, EstimationError, InputError
from .model import DROPPED_IN_REDUCED, JOINTS, REDUCED_SEGMENTS, SEGMENTS
from .progress import Progress
from .recording import SensorRecording

__all__ = [
    "DROPPED_IN_REDUCED",
    "JOINTS",
    "REDUCED_SEGMENTS",
    "SEGMENTS",
    "BonefitError",
    "BvhMotion",
    "EstimationError",
    "InputError",
    "Progress",
    "SensorRecording",
    "forward_kinematics",
    "read_bvh",
    "write_bvh",
]
