"""In-memory form of an inertial-suit recording: global joint positions and foot accelerations.

The input of :func:`bonefit.estimation.translation.estimate_translation`; the readers of
:mod:`bonefit.estimation.io.kinematics` and :mod:`bonefit.estimation.io.mvnx` build it from files.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Final

import numpy as np
from numpy.typing import NDArray

from .bvh import BvhMotion
from .errors import InputError


def is_end_site_name(name: str) -> bool:
    """Whether a column joint name is an anonymous end site (``EndSite4``, ``Foot_end``)."""
    return bool(re.fullmatch(r"(?i)end\s*site\d*|.*_end_*", name))


GRAVITY: Final[float] = 9.80665
"""Standard gravity, m/s²."""


@dataclass(frozen=True, eq=False)
class KinematicsRecording:
    """Global joint positions of an inertial suit plus its foot accelerometers.

    Attributes
    ----------
    joints : tuple of str
        Joint names, length J, in file order.
    positions : ndarray, shape (F, J, 3)
        Global joint positions, metres, world frame with +Y up. They may or may not contain
        a root translation: both estimators replace it.
    fps : float
        Frame rate, Hz.
    time : ndarray, shape (F,)
        Frame times, seconds.
    accelerations : mapping of str to ndarray, shape (F, 3)
        Foot joint name → acceleration, m/s². Frame given by ``acceleration_frame``.
    acceleration_frame : {"sensor", "world"}
        ``"sensor"``: accelerometer readings (specific force) in the sensor frame, gravity
        included (|a| ≈ 9.81 at rest). ``"world"``: gravity-free acceleration in the world
        frame (+Y up).
    left_foot, right_foot : str
        Names of the foot joints (ankles) in ``joints``.
    toes : mapping of str to str
        Foot joint → toe joint (or toe end site) used for heel/toe contacts, when present.
    contacts : mapping of str to ndarray of bool, shape (F,)
        Foot joint → contact flags read from the file (MVNX footContacts, ``<Foot>.c``
        columns); empty when the file has none.
    source_format : str
        ``"kinematics-csv"``, ``"bvh"`` or ``"mvnx"``.
    length_scale : float
        Metres per length unit of the source file (0.01 for cm).
    columns : tuple of str
        Kinematics CSV: every column of the file, in order (for passthrough).
    table : ndarray, shape (F, C) or None
        Kinematics CSV: every value of the file, in file units.
    bvh : BvhMotion or None
        BVH input: the motion (its root translation is what the writer replaces).
    root : str
        Name of the root joint whose path is reported (hips).
    source_path : str or None
        Path of the file read (the MVNX writer re-streams it).
    notes : tuple of str
        What the reader decided (units, toe joints, contact channels).
    source_subject : int
        MVNX: 0-based number of the ``<subject>`` read (the writer corrects its frames).
    """

    joints: tuple[str, ...]
    positions: NDArray[np.float64]
    fps: float
    time: NDArray[np.float64]
    accelerations: Mapping[str, NDArray[np.float64]]
    acceleration_frame: str = "sensor"
    left_foot: str = "LeftFoot"
    right_foot: str = "RightFoot"
    toes: Mapping[str, str] = field(default_factory=dict)
    contacts: Mapping[str, NDArray[np.bool_]] = field(default_factory=dict)
    source_format: str = "kinematics-csv"
    length_scale: float = 0.01
    columns: tuple[str, ...] = ()
    table: NDArray[np.float64] | None = None
    bvh: BvhMotion | None = None
    root: str = ""
    source_path: str | None = None
    notes: tuple[str, ...] = ()
    source_subject: int = 0

    def __post_init__(self) -> None:
        pos = self.positions
        if pos.ndim != 3 or pos.shape[1] != len(self.joints) or pos.shape[2] != 3:
            raise InputError(f"positions must be (F, {len(self.joints)}, 3), got {pos.shape}",
                             field="positions")
        if self.acceleration_frame not in ("sensor", "world"):
            raise InputError("acceleration_frame must be 'sensor' or 'world'",
                             field="acceleration_frame")
        for foot in (self.left_foot, self.right_foot):
            if foot not in self.joints:
                raise InputError(f"foot joint {foot!r} not found; joints: "
                                 f"{', '.join(self.real_joints())}", field=foot)
            acc = self.accelerations.get(foot)
            if acc is None or acc.shape != (pos.shape[0], 3):
                raise InputError(f"no (F, 3) accelerations for foot {foot!r}", sensor=foot)
        if not self.root:
            object.__setattr__(self, "root", self.joints[0])

    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return int(self.positions.shape[0])

    def index(self, joint: str) -> int:
        """Index of ``joint``; InputError listing the joints present otherwise."""
        try:
            return self.joints.index(joint)
        except ValueError:
            raise InputError(f"joint {joint!r} not found; joints: "
                             f"{', '.join(self.real_joints())}", field=joint) from None

    def real_joints(self) -> tuple[str, ...]:
        """Joint names without end sites (``<joint>_end``, ``EndSite4``), for messages."""
        return tuple(j for j in self.joints if not is_end_site_name(j))
