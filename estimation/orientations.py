"""Segment orientations from joint centres and sensor orientations (Miura et al. 2015, §2.2).

Segment frames: x left, y up, z forward in an upright posture; limb segments have y along the
bone, pointing from the distal to the proximal joint. Every function is vectorised over frames.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from . import _rows as rows
from . import quaternions as quat
from .errors import EstimationError, InputError
from .model import JOINTS

__all__ = ["estimate_orientations"]

Float = NDArray[np.float64]

# (upper segment, lower segment, distal segment, proximal, middle, distal joint, sign of x)
_LIMBS = (
    ("l_thigh", "l_shank", "l_foot", "l_hip", "l_knee", "l_ankle", 1.0),
    ("r_thigh", "r_shank", "r_foot", "r_hip", "r_knee", "r_ankle", 1.0),
    ("l_upperarm", "l_forearm", "l_hand", "l_shoulder", "l_elbow", "l_wrist", -1.0),
    ("r_upperarm", "r_forearm", "r_hand", "r_shoulder", "r_elbow", "r_wrist", -1.0),
)
_EPS = 1e-12


def _unit(v: Float) -> Float:
    n = rows.norms(v)[..., None]
    return np.asarray(v / np.where(n > _EPS, n, 1.0))


def _cross(a: Float, b: Float) -> Float:
    """Row-wise cross product of (F, 3) arrays (1.5× faster than np.cross here)."""
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx], axis=-1)


def _canonical(q: Float) -> Float:
    """The same rotations with ``w ≥ 0`` (as ``quaternions.from_matrix`` returns them)."""
    return np.asarray(q * np.where(q[..., :1] < 0, -1.0, 1.0))


def _frame(x: Float, y: Float, z: Float) -> Float:
    """Matrices (F,3,3) with columns x, y, z."""
    return np.stack([x, y, z], axis=-1)


def _frame_from_yz(y: Float, z: Float) -> Float:
    """Eqs. 8–9: normalised y, z and x = y × z (y and z are orthogonal by construction;
    z is re-orthogonalised so that rounding never leaves a skewed frame)."""
    y = _unit(y)
    z = _unit(z - rows.dots(z, y)[:, None] * y)
    return _frame(_cross(y, z), y, z)


def _quat_from_xy(x: Float, y: Float) -> Float:
    """The frame with y (a unit vector: the bone) kept exactly, x made orthogonal to it and
    z = x × y, as quaternions (F, 4)."""
    x = _unit(x - rows.dots(x, y)[:, None] * y)
    return quat.from_axes(x, y, _cross(x, y))


def _align_y(frames: Float, frames_q: Float, target_y: Float) -> Float:
    """Eq. 10: ``R · R(θ, n)``, the minimal rotation about an axis fixed in the frame that
    turns its y axis onto ``target_y``; scalar-first quaternions (F, 4).

    ``frames`` (F, 3, 3) and ``frames_q`` (F, 4) are the same rotations ``R``. The minimal
    rotation taking e_y to the unit vector ``l`` is the half-way quaternion
    ``(1 + e_y·l, e_y × l)`` normalised."""
    local = _unit(np.einsum("fji,fj->fi", frames, target_y))  # R⁻¹ target
    half = np.stack([1.0 + local[:, 1], local[:, 2], np.zeros(local.shape[0]), -local[:, 0]],
                    axis=-1)
    norm = rows.norms(half)
    # at θ = π the axis is undefined: any axis ⟂ y will do (z)
    flip = norm <= _EPS
    half = half / np.where(flip, 1.0, norm)[:, None]
    half[flip] = [0.0, 0.0, 0.0, 1.0]
    return _canonical(quat.multiply(frames_q, half))


def _flexion_axis(upper_bone: Float, lower_bone: Float, sensor: Float | None,
                  fallback: Float) -> Float:
    """Eq. 6: the instantaneous flexion axis I_m × I_{m+1} blended, by the flexion angle θ,
    with its θ-weighted mean direction fixed in the upper segment's sensor frame (``sensor``:
    its rotation matrices, (F, 3, 3))."""
    cross = _cross(upper_bone, lower_bone)
    sin = rows.norms(cross)
    cos = rows.dots(upper_bone, lower_bone)
    theta = np.arctan2(sin, cos)
    inst = cross / np.where(sin > _EPS, sin, 1.0)[:, None]
    steady = fallback
    if sensor is not None:
        mean_local = np.einsum("fji,fj->i", sensor, inst * theta[:, None])
        if np.linalg.norm(mean_local) > _EPS:
            steady = rows.apply(sensor, mean_local / np.linalg.norm(mean_local))
    return np.asarray(steady * (np.pi - theta)[:, None] + inst * theta[:, None])


def _as_joint(joints: Mapping[str, ArrayLike], name: str, n: int | None) -> Float:
    if name not in joints:
        raise InputError(f"joint {name!r} is missing", field=name)
    arr = np.asarray(joints[name], dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3 or (n is not None and arr.shape[0] != n):
        raise InputError(f"joint {name!r} must have shape (F, 3), got {arr.shape}", field=name)
    if not np.isfinite(arr).all():
        raise EstimationError(f"joint {name!r} has NaN; fill gaps first", field=name)
    return arr


def estimate_orientations(joints: Mapping[str, ArrayLike],
                          sensor_rotations: Mapping[str, Rotation], *, i0: int = 0,
                          up: ArrayLike = (0.0, 1.0, 0.0),
                          calibration: str | Mapping[str, Rotation] = "pelvis",
                          ) -> dict[str, Float]:
    """Orientation of every segment from the joint centres and the sensors.

    Parameters
    ----------
    joints : mapping of str to array_like, shape (F, 3)
        World positions (metres) of the 16 joints of ``estimation.model.JOINTS``.
    sensor_rotations : mapping of str to Rotation
        Sensor → world rotation (length F) of the sensors present, by segment name. The hand,
        foot and head sensors give those segments' orientations (eq. 7); the thigh and upper-arm
        sensors anchor the flexion axis (eq. 6). Missing ones fall back to the parent segment.
    i0 : int, default 0
        Calibration frame of eq. 7.
    up : array_like, shape (3,), default (0, 1, 0)
        World up, used by ``calibration="upright"``.
    calibration : {"pelvis", "upright"} or mapping of str to Rotation
        Orientation of the hands, feet and head at frame ``i0`` (the paper's only manual
        input): ``"pelvis"`` (default) aligns them with the pelvis frame, ``"upright"`` with a
        frame whose y is ``up`` and whose z is the pelvis' forward direction made horizontal;
        a mapping gives a single rotation (segment → world) per segment.

    Returns
    -------
    dict of str to ndarray, shape (F, 4)
        Segment frame → world rotation, scalar-first unit quaternions, for the 15 segments of
        ``estimation.model.SEGMENTS`` plus ``"spine"`` (waist–chest) and ``"cervical"``
        (chest–neck).

    Raises
    ------
    InputError
        A joint is missing or has the wrong shape, ``i0`` is out of range.
    EstimationError
        NaN in the joints.

    Notes
    -----
    Miura et al., "Sensor Number Reduction in Skeleton Estimation from Magnetic Motion
    Capture Data", J. Inf. Process. 23(5):704–707, 2015, §2.2, eqs. 6–10:

    - pelvis: y = W − (LH + RH)/2, z = (RH − W) × (LH − W), x = y × z (eq. 8);
    - chest: y = (LS + RS)/2 − W, z = (LS − W) × (RS − W), x = y × z (eq. 9);
    - spine (W–C) and cervical (C–N): the chest frame turned by the minimal rotation that puts
      its y on the segment (eq. 10);
    - thigh/shank and upper arm: y along the bone; x from eq. 6,
      ``x = P_k x̄_k (π − θ) + (I_m × I_{m+1})/|I_m × I_{m+1}| θ`` with x̄_k the θ-weighted
      mean of the normalised cross product in the upper segment's sensor frame (−x for arms);
      z = x × y;
    - hands, feet, head: ``R(i) = P(i) P(i0)⁻¹ R(i0)`` (eq. 7);
    - forearm: the hand frame turned by the minimal rotation that puts its y on the forearm
      (the elbow twist of the paper's Fig. 4).
    """
    n: int | None = None
    pos: dict[str, Float] = {}
    for name in JOINTS:
        pos[name] = _as_joint(joints, name, n)
        n = pos[name].shape[0]
    assert n is not None
    if not -n <= i0 < n:
        raise InputError(f"calibration frame i0={i0} is outside 0..{n - 1}", field="i0")
    for seg, rot in sensor_rotations.items():
        if len(rot) != n:
            raise InputError(f"sensor {seg!r} has {len(rot)} rotations for {n} frames",
                             sensor=seg)

    # Frames are built as matrices where they come from axes, and composed as quaternion
    # arrays elsewhere: Rotation.__mul__ on 6,283 rotations costs 3–5 ms in scipy 1.17,
    # quaternions.multiply 0.1 ms (see estimation.quaternions).
    w, lh, rh = pos["waist"], pos["l_hip"], pos["r_hip"]
    ls, rs = pos["l_shoulder"], pos["r_shoulder"]
    mats: dict[str, Float] = {}
    quats: dict[str, Float] = {}
    mats["pelvis"] = _frame_from_yz(w - 0.5 * (lh + rh), _cross(rh - w, lh - w))
    mats["chest"] = _frame_from_yz(0.5 * (ls + rs) - w, _cross(ls - w, rs - w))
    quats["pelvis"] = quat.from_matrix(mats["pelvis"])
    quats["chest"] = quat.from_matrix(mats["chest"])
    quats["spine"] = _align_y(mats["chest"], quats["chest"], pos["chest"] - w)
    quats["cervical"] = _align_y(mats["chest"], quats["chest"], pos["neck"] - pos["chest"])

    pelvis_i0 = quat.from_matrix(mats["pelvis"][i0])
    ends = ("head", "l_hand", "r_hand", "l_foot", "r_foot")
    if isinstance(calibration, str):
        if calibration == "pelvis":
            reference = dict.fromkeys(ends, pelvis_i0)
        elif calibration == "upright":
            y = _unit(np.asarray(up, dtype=float).reshape(1, 3))
            z = mats["pelvis"][i0, :, 2][None]
            upright = quat.from_matrix(_frame_from_yz(y, z)[0])
            reference = dict.fromkeys(ends, upright)
        else:
            raise InputError(f"unknown calibration {calibration!r}; use 'pelvis', 'upright' "
                             "or a mapping of rotations", field="calibration")
    else:
        reference = {s: calibration[s].as_quat(scalar_first=True) if s in calibration
                     else pelvis_i0 for s in ends}
    for seg, ref in reference.items():
        sensor = sensor_rotations.get(seg)
        if sensor is not None:
            q = sensor.as_quat(scalar_first=True)
            quats[seg] = _canonical(quat.multiply(q, quat.relative(q[i0], ref)))

    for upper, lower, distal, prox, mid, end, sign in _LIMBS:
        upper_bone = _unit(pos[prox] - pos[mid])
        lower_bone = _unit(pos[mid] - pos[end])
        parent = mats["pelvis"] if upper.endswith("thigh") else mats["chest"]
        sensor = sensor_rotations.get(upper)
        x = sign * _flexion_axis(upper_bone, lower_bone,
                                 None if sensor is None else sensor.as_matrix(),
                                 sign * parent[:, :, 0])
        quats[upper] = _quat_from_xy(x, upper_bone)
        if distal not in quats:
            quats[lower] = _quat_from_xy(x, lower_bone)
            quats[distal] = quats[lower]
        elif sign < 0:
            quats[lower] = _align_y(quat.as_matrix(quats[distal]), quats[distal], lower_bone)
        else:
            quats[lower] = _quat_from_xy(x, lower_bone)
    return quats
