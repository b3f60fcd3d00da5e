"""Segment orientations from joint centres and sensor orientations (Miura et al. 2015, §2.2).

Segment frames: x left, y up, z forward in an upright posture; limb segments have y along the
bone, pointing from the distal to the proximal joint. Every function is vectorised over frames.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

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

# Vectors are (3, F) arrays, a row per component: numpy runs its loops over the last axis, so
# per-frame arithmetic on (F, 3) rows runs F loops of 3 and costs 5-10x the same over (3, F).
# Quaternions stay (F, 4), scalar-first, as returned. Fresh intermediate arrays are updated in
# place: allocating a new array costs about as much as the arithmetic.


def _dot(a: Float, b: Float) -> Float:
    return np.asarray(np.einsum("i...,i...->...", a, b))


def _normalise(v: Float) -> Float:
    """``v`` (3, F), a fresh array, scaled in place to unit length (zero vectors stay zero)."""
    n = np.sqrt(_dot(v, v))
    n[n <= _EPS] = 1.0
    v /= n
    return v


def _cross(a: Float, b: Float) -> Float:
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        np.multiply(a[j], b[k], out=out[i])
        out[i] -= a[k] * b[j]
    return out


def _canonical(q: Float) -> Float:
    """``q`` (a fresh (F, 4) array, changed in place) with ``w ≥ 0``, as
    ``quaternions.from_matrix`` returns rotations."""
    sign = np.where(q[:, 0] < 0, -1.0, 1.0)
    for k in range(4):
        q[:, k] *= sign
    return q


Axes = tuple[Float, Float, Float]
"""A frame's x, y, z axes in the world, each (3, F): the columns of its rotation matrices."""


def _frame_from_yz(y: Float, z: Float) -> Axes:
    """Eqs. 8–9: normalised y, z and x = y × z (y and z are orthogonal by construction;
    z is re-orthogonalised so that rounding never leaves a skewed frame). ``y`` and ``z``
    are fresh arrays, changed in place."""
    y = _normalise(y)
    z -= _dot(z, y) * y
    z = _normalise(z)
    return _cross(y, z), y, z


def _quat(axes: Axes) -> Float:
    x, y, z = axes
    return quat.from_axes(x.T, y.T, z.T)


def _quat_from_xy(x: Float, y: Float) -> Float:
    """The frame with y (a unit vector: the bone) kept exactly, x made orthogonal to it and
    z = x × y, as quaternions (F, 4)."""
    x = _normalise(x - _dot(x, y) * y)
    return _quat((x, y, _cross(x, y)))


def _local(q: Float, v: Float) -> Float:
    """``R(q)⁻¹ v`` for quaternions ``q`` (F, 4) and vectors ``v`` (3, F):
    ``v − w t + u × t`` with ``t = 2 u × v`` and ``u`` the vector part of ``q``."""
    u = q[:, 1:].T
    t = _cross(u, v)
    t *= 2.0
    out = _cross(u, t)
    out -= q[:, 0] * t
    out += v
    return out


def _align_y(frames_q: Float, target_y: Float) -> Float:
    """Eq. 10: ``R · R(θ, n)``, the minimal rotation about an axis fixed in the frame that
    turns its y axis onto ``target_y`` (3, F); scalar-first quaternions (F, 4).

    ``frames_q`` (F, 4) are the rotations ``R``. The minimal rotation taking e_y to the unit
    vector ``l = R⁻¹ target`` is the half-way quaternion ``(1 + e_y·l, e_y × l)``
    ``= (1 + l_y, l_z, 0, −l_x)`` normalised."""
    lx, ly, lz = _normalise(_local(frames_q, target_y))
    hw, hx, hz = 1.0 + ly, lz, -lx
    norm = np.sqrt(hw * hw + hx * hx + hz * hz)
    # at θ = π the axis is undefined: any axis ⟂ y will do (z)
    flip = norm <= _EPS
    norm[flip] = 1.0
    hw, hx, hz = hw / norm, hx / norm, hz / norm
    hw[flip], hx[flip], hz[flip] = 0.0, 0.0, 1.0
    # R ⊗ h, h's y component being zero
    qw, qx, qy, qz = frames_q.T
    out = np.empty_like(frames_q)
    out[:, 0] = qw * hw - qx * hx - qz * hz
    out[:, 1] = qw * hx + qx * hw + qy * hz
    out[:, 2] = qy * hw - qx * hz + qz * hx
    out[:, 3] = qw * hz - qy * hx + qz * hw
    return _canonical(out)


def _flexion_axis(upper_bone: Float, lower_bone: Float, sensor: Float | None,
                  fallback: Float) -> Float:
    """Eq. 6: the instantaneous flexion axis I_m × I_{m+1} blended, by the flexion angle θ,
    with its θ-weighted mean direction fixed in the upper segment's sensor frame (``sensor``:
    its rotation matrices, (F, 3, 3)); a fresh (3, F) array."""
    weighted = _cross(upper_bone, lower_bone)
    sin = np.sqrt(_dot(weighted, weighted))
    theta = np.arctan2(sin, _dot(upper_bone, lower_bone))
    sin[sin <= _EPS] = 1.0
    weighted *= theta / sin  # the unit instantaneous axis times θ
    steady = fallback
    if sensor is not None:
        matrices = sensor.reshape(-1, 9)
        # Σ_t R_tᵀ v_t: blocks[i, k, j] = Σ_t v_i[t] R_t[k, j], of which the k = i ones
        blocks = (weighted @ matrices).reshape(3, 3, 3)
        mean_local = np.einsum("iij->j", blocks)
        length = np.linalg.norm(mean_local)
        if length > _EPS:
            # R_t m for each t, as (3, F) rows: row i of kron(I, m) picks row i of R_t
            steady = np.kron(np.eye(3), mean_local / length) @ matrices.T
    out = steady * (np.pi - theta)
    out += weighted
    return out


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

    # Frames come from their axes, and are composed as quaternion arrays: Rotation.__mul__
    # on 6,283 rotations costs 3–5 ms in scipy 1.17, quaternions.multiply 0.1 ms.
    col = {name: np.ascontiguousarray(v.T) for name, v in pos.items()}
    w, lh, rh = col["waist"], col["l_hip"], col["r_hip"]
    ls, rs = col["l_shoulder"], col["r_shoulder"]
    axes: dict[str, Axes] = {
        "pelvis": _frame_from_yz(w - 0.5 * (lh + rh), _cross(rh - w, lh - w)),
        "chest": _frame_from_yz(0.5 * (ls + rs) - w, _cross(ls - w, rs - w)),
    }
    quats: dict[str, Float] = {seg: _quat(a) for seg, a in axes.items()}
    quats["spine"] = _align_y(quats["chest"], col["chest"] - w)
    quats["cervical"] = _align_y(quats["chest"], col["neck"] - col["chest"])

    pelvis_x, pelvis_y, pelvis_z = axes["pelvis"]
    pelvis_i0 = quat.from_axes(pelvis_x[:, i0], pelvis_y[:, i0], pelvis_z[:, i0])
    ends = ("head", "l_hand", "r_hand", "l_foot", "r_foot")
    if isinstance(calibration, str):
        if calibration == "pelvis":
            reference = dict.fromkeys(ends, pelvis_i0)
        elif calibration == "upright":
            y = np.array(up, dtype=float).reshape(3, 1)
            upright = _quat(_frame_from_yz(y, pelvis_z[:, [i0]]))[0]
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
            # q ⊗ c for one quaternion c is linear in q: rows e_j ⊗ c of a 4 × 4 matrix
            offset = quat.multiply(np.eye(4), quat.relative(q[i0], ref))
            quats[seg] = _canonical(q @ offset)

    for upper, lower, distal, prox, mid, end, sign in _LIMBS:
        upper_bone = _normalise(col[prox] - col[mid])
        lower_bone = _normalise(col[mid] - col[end])
        parent_x = axes["pelvis" if upper.endswith("thigh") else "chest"][0]
        sensor = sensor_rotations.get(upper)
        x = _flexion_axis(upper_bone, lower_bone,
                          None if sensor is None else sensor.as_matrix(), sign * parent_x)
        x *= sign
        quats[upper] = _quat_from_xy(x, upper_bone)
        if distal not in quats:
            quats[lower] = _quat_from_xy(x, lower_bone)
            quats[distal] = quats[lower]
        elif sign < 0:
            quats[lower] = _align_y(quats[distal], lower_bone)
        else:
            quats[lower] = _quat_from_xy(x, lower_bone)
    return quats
