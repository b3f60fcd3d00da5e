"""Segment orientations from joint centres and sensor orientations (Miura et al. 2015, §2.2).

Segment frames: x left, y up, z forward in an upright posture; limb segments have y along the
bone, pointing from the distal to the proximal joint. Every function is vectorised over frames.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from . import quaternions as quat
from .errors import EstimationError, InputError
from .model import JOINTS, LIMBS, SEGMENTS
from .progress import Progress, no_progress, scaled
from .threads import Report, run_each

__all__ = ["estimate_orientations"]

Float = NDArray[np.float64]

# (upper segment, lower segment, distal segment, proximal, middle, distal joint, sign of x)
_LIMBS = tuple((*limb.segments, *limb.joints, -1.0 if limb.is_arm else 1.0)
               for limb in sorted(LIMBS.values(), key=lambda limb: limb.is_arm))
_ENDS = ("head", "l_hand", "r_hand", "l_foot", "r_foot")
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


def _canonical(rows: Float, out: Float) -> Float:
    """Quaternions given as (4, F) rows, written into ``out`` (F, 4) with ``w ≥ 0`` as
    ``quaternions.from_matrix`` returns rotations."""
    np.multiply(rows, np.where(rows[0] < 0, -1.0, 1.0), out=out.T)
    return out


Axes = tuple[Float, Float, Float]
"""A frame's x, y, z axes in the world, each (3, F): the columns of its rotation matrices."""


def _frame_from_yz(y: Float, z: Float) -> Axes:
    """Normalised y, z made orthogonal to it and normalised, and x = y × z. ``y`` and ``z``
    are fresh arrays, changed in place."""
    y = _normalise(y)
    z -= _dot(z, y) * y
    z = _normalise(z)
    return _cross(y, z), y, z


_TURN_Z = np.array([[-1.0], [-1.0], [1.0], [1.0]])
"""``p ⊗ q' = (−q'_z, −q'_y, q'_x, q'_w)`` with ``p = (0, 0, 0, 1)`` (R_z(π)): these signs
times the components of q' in reverse order."""


class _Down(NamedTuple):
    """The frames whose bone points down (``y₁ < 0``), for ``quat_from_xy``: as indices when
    fewer than a quarter (changed one by one), else as a mask and a sign per frame (a forearm
    or shank points down in most frames, where gathering and scattering the indices took as
    long as the rest of the function; the products with ±1 negate exactly, so both ways give
    the same bits)."""

    mask: NDArray[np.bool_]
    frames: NDArray[np.intp] | None  # their indices; None: many, use the mask
    sign: Float | None

    @classmethod
    def of(cls, y1: Float) -> _Down:
        mask = y1 < 0
        count = int(np.count_nonzero(mask))
        if 4 * count < mask.size:
            return cls(mask, np.flatnonzero(mask), None)
        return cls(mask, None, np.where(mask, -1.0, 1.0))

    def negated(self, rows: tuple[Float, ...]) -> tuple[Float, ...]:
        """``rows`` (fresh arrays when changed) negated in the frames down."""
        if self.sign is not None:
            return tuple(row * self.sign for row in rows)
        if self.frames is None or not self.frames.size:
            return rows
        out = tuple(row.copy() for row in rows)
        for row in out:
            row[self.frames] *= -1.0
        return out

    def turned(self, q: Float) -> Float:
        """Quaternion rows ``q`` (4, F) composed with ``p`` in the frames down."""
        if self.sign is not None:
            return np.asarray(np.where(self.mask, q[::-1] * _TURN_Z, q))
        if self.frames is not None and self.frames.size:
            q[:, self.frames] = q[::-1, self.frames] * _TURN_Z
        return q


def quat_from_xy(x: Float, y: Float, out: Float) -> Float:
    """The frame with y (a unit vector: the bone) kept exactly, x made orthogonal to it and
    z = x × y, as quaternions written into ``out`` (F, 4), ``w ≥ 0``.

    Composed as ``s ⊗ t`` without forming the frame's matrix: ``s = (1 + y₁, y₂, 0, −y₀)``
    (unnormalised) the minimal rotation taking e_y onto y, ``t`` the turn about e_y taking
    e_x onto ``(a, 0, c)``, the projection of ``sᵀ x`` on the xz plane."""
    # for y₁ < 0 (1 + y₁ would cancel) the frame turned by P = R_z(π), which negates the
    # first two components of y and x, is composed instead, and q = p ⊗ q' with p = (0, 0, 0, 1)
    down = _Down.of(y[1])
    y0, y1, x0, x1 = down.negated((y[0], y[1], x[0], x[1]))
    y2, x2 = y[2], x[2]
    one_y = 1.0 + y1
    # sᵀ x = (x₀ − y₀ h, ·, x₂ − y₂ h) with h = x₁ + (y₀ x₀ + y₂ x₂) / (1 + y₁)
    # (each step into a fresh array or in place: fewer temporaries, the same roundings)
    h = y0 * x0
    scratch = np.multiply(y2, x2)
    h += scratch
    h /= one_y
    h += x1
    a = np.multiply(y0, h)
    np.subtract(x0, a, out=a)
    c = np.multiply(y2, h, out=scratch)
    np.subtract(x2, c, out=c)
    r = a * a
    r += np.multiply(c, c, out=h)
    np.sqrt(r, out=r)
    zero = r <= _EPS
    if zero.any():  # x along the bone: any x ⟂ y will do
        a[zero], c[zero], r[zero] = 1.0, 0.0, 1.0
    # t ∝ (r + a, 0, −c, 0), or for a < 0 (where r + a cancels) the same rotation as
    # (−c, 0, r − a, 0); either way |t|² = 2 r (r + |a|)
    turn = np.abs(a)
    turn += r
    ahead = a >= 0
    c *= -1.0  # after the difference (an exact zero of it becomes −0, as q's signs need)
    tw = np.where(ahead, turn, c)
    ty = np.where(ahead, c, turn)
    q = np.empty((4, len(one_y)))
    np.multiply(one_y, tw, out=q[0])
    np.multiply(y2, tw, out=q[1])
    q[1] += np.multiply(y0, ty, out=h)
    np.multiply(one_y, ty, out=q[2])
    np.multiply(y2, ty, out=q[3])
    q[3] -= np.multiply(y0, tw, out=h)
    q = down.turned(q)
    scale = one_y * r
    scale *= turn
    np.sqrt(scale, out=scale)
    scale *= 2.0
    np.copysign(scale, q[0], out=scale)
    np.divide(q, scale, out=out.T)
    return out


def _in_frame(axes: Axes, v: Float) -> Float:
    """``Rᵀ v``: the coordinates of vectors ``v`` (3, F) in the frames with these axes."""
    out = np.empty_like(v)
    for row, axis in zip(out, axes, strict=True):
        np.einsum("i...,i...->...", axis, v, out=row)
    return out


def _align_y(frames_q: Float, local: Float, out: Float) -> Float:
    """Eq. 10: ``R · R(θ, n)``, the minimal rotation about an axis fixed in the frame that
    turns its y axis onto the target direction, written into ``out`` (F, 4).

    ``frames_q`` (F, 4) are the rotations ``R``, ``local`` the target in their frames,
    ``R⁻¹ target`` (3, F), a fresh array. The minimal rotation taking e_y to the unit vector
    ``l`` along it is the half-way quaternion ``(1 + e_y·l, e_y × l)``
    ``= (1 + l_y, l_z, 0, −l_x)`` normalised."""
    lx, ly, lz = _normalise(local)
    hw, hx, hz = 1.0 + ly, lz, -lx
    norm = np.sqrt(hw * hw + hx * hx + hz * hz)
    # at θ = π the axis is undefined: any axis ⟂ y will do (z)
    flip = np.flatnonzero(norm <= _EPS)
    if flip.size:
        hw[flip], hx[flip], hz[flip], norm[flip] = 0.0, 0.0, 1.0, 1.0
    # R ⊗ h (h's y component being zero), divided by |h| with the sign that makes w ≥ 0
    qw, qx, qy, qz = frames_q.T
    rows = np.empty((4, len(hw)))
    term = np.empty(len(hw))  # each row summed left to right in place, one scratch row
    w, x, y, z = rows
    np.multiply(qw, hw, out=w)
    w -= np.multiply(qx, hx, out=term)
    w -= np.multiply(qz, hz, out=term)
    np.multiply(qw, hx, out=x)
    x += np.multiply(qx, hw, out=term)
    x += np.multiply(qy, hz, out=term)
    np.multiply(qy, hw, out=y)
    y -= np.multiply(qx, hz, out=term)
    y += np.multiply(qz, hx, out=term)
    np.multiply(qw, hz, out=z)
    z -= np.multiply(qy, hx, out=term)
    z += np.multiply(qz, hw, out=term)
    np.divide(rows, np.copysign(norm, rows[0], out=norm), out=out.T)
    return out


def _flexion_axis(upper_bone: Float, lower_bone: Float, sensor: Float | None,
                  fallback: Float, sign: float) -> Float:
    """Eq. 6: the instantaneous flexion axis I_m × I_{m+1} blended, by the flexion angle θ,
    with its θ-weighted mean direction fixed in the upper segment's sensor frame (``sensor``:
    its rotation matrices, (F, 3, 3)), or without a sensor with the parent's x axis
    (``fallback``, of any length), times ``sign``; a fresh (3, F) array."""
    weighted = _cross(upper_bone, lower_bone)
    sin = np.sqrt(_dot(weighted, weighted))
    theta = np.arctan2(sin, _dot(upper_bone, lower_bone))
    sin[sin <= _EPS] = 1.0
    weighted *= theta / sin  # the unit instantaneous axis times θ
    steady = None
    if sensor is not None:
        matrices = sensor.reshape(-1, 9)
        # Σ_t R_tᵀ v_t: blocks[i, k, j] = Σ_t v_i[t] R_t[k, j], of which the k = i ones
        blocks = (weighted @ matrices).reshape(3, 3, 3)
        mean_local = np.einsum("iij->j", blocks)
        length = math.hypot(*mean_local)
        if length > _EPS:
            # R_t m for each t, as (3, F) rows: row i of kron(I, m) picks row i of R_t (built
            # here directly: np.kron takes 15 µs)
            picker = np.zeros((3, 3, 3))
            picker[range(3), range(3)] = mean_local / length
            steady = picker.reshape(3, 9) @ matrices.T
    if steady is None:
        steady = _normalise(fallback * sign)
    out = steady * (np.pi - theta)
    out += weighted
    out *= sign
    return out


def _rows(pos: Mapping[str, Float], a: str, b: str) -> Float:
    """Joint ``a`` minus joint ``b``, (3, F)."""
    return np.ascontiguousarray((pos[a] - pos[b]).T)


def _trunk(pos: Mapping[str, Float], slots: Iterator[Float], i0: int,
           ) -> tuple[dict[str, Float], dict[str, Float], Float]:
    """The pelvis, chest, spine and cervical frames (eqs. 8–10) written into ``slots``; the
    pelvis and chest x axes, the pelvis' not normalised (the limbs' fallback flexion axes);
    the pelvis' forward direction at ``i0``, not normalised (3, 1)."""
    lh, rh = _rows(pos, "l_hip", "waist"), _rows(pos, "r_hip", "waist")
    ls, rs = _rows(pos, "l_shoulder", "waist"), _rows(pos, "r_shoulder", "waist")
    pelvis_y = lh + rh
    pelvis_y *= -0.5
    pelvis_y = _normalise(pelvis_y)
    chest_y = ls + rs
    chest_y *= 0.5
    chest_y = _normalise(chest_y)
    # x = y × z is orthogonal to y whatever z's y component, so z is used as it comes
    pelvis_x = _cross(pelvis_y, _cross(rh, lh))
    chest_x = _cross(chest_y, _cross(ls, rs))
    quats = {"pelvis": quat_from_xy(pelvis_x, pelvis_y, next(slots)),
             "chest": quat_from_xy(chest_x, chest_y, next(slots))}
    chest_x = _normalise(chest_x)
    chest = (chest_x, chest_y, _cross(chest_x, chest_y))
    for seg, top, bottom in (("spine", "chest", "waist"), ("cervical", "neck", "chest")):
        local = _in_frame(chest, _rows(pos, top, bottom))
        quats[seg] = _align_y(quats["chest"], local, next(slots))
    forward_i0 = _cross(pelvis_x[:, [i0]], pelvis_y[:, [i0]])
    return quats, {"pelvis": pelvis_x, "chest": chest_x}, forward_i0


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
                          progress: Progress | None = None) -> dict[str, Float]:
    """Orientation of every segment from the joint centres and the sensors.

    Parameters
    ----------
    joints : mapping of str to array_like, shape (F, 3)
        World positions (metres) of the 16 joints of ``bonefit.estimation.model.JOINTS``.
    sensor_rotations : mapping of str to Rotation
        Sensor → world rotation (length F) of the sensors present, by segment name. The hand,
        foot and head sensors give those segments' orientations (eq. 7); the thigh and upper-arm
        sensors anchor the flexion axis (eq. 6) of the thigh and shank, upper arm and forearm.
        Missing ones fall back to the parent segment.
    i0 : int, default 0
        Calibration frame of eq. 7.
    up : array_like, shape (3,), default (0, 1, 0)
        World up, used by ``calibration="upright"``.
    calibration : {"pelvis", "upright"} or mapping of str to Rotation
        Orientation of the hands, feet and head at frame ``i0`` (the paper's only manual
        input): ``"pelvis"`` (default) aligns them with the pelvis frame, ``"upright"`` with a
        frame whose y is ``up`` and whose z is the pelvis' forward direction made horizontal;
        a mapping gives a single rotation (segment → world) per segment.
    progress : callable, optional
        ``progress(fraction, "orientations")`` after the trunk, the end segments and while
        the limbs are composed.

    Returns
    -------
    dict of str to ndarray, shape (F, 4)
        Segment frame → world rotation, scalar-first unit quaternions, for the 15 segments of
        ``bonefit.estimation.model.SEGMENTS`` plus ``"spine"`` (waist–chest) and ``"cervical"``
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
    - forearm: like the shank, y along the bone and x the elbow's flexion axis (eq. 6). The
      paper's Fig. 4 turns the hand frame onto the forearm instead, which hands the
      forearm the wrist's twist (pronation) and every error of the hand sensor, and flips
      it where the bone passes the hand frame's −y: on the 38 simulated benchmark clips,
      whose forearms carry little of the wrist's twist, it was 0.8–50° off (median per
      clip; up to 180°) against 0.5–12° (up to 64°) now.
    """
    pos, n = _checked_joints(joints, sensor_rotations, i0)
    # Frames come from their axes, and are composed as quaternion arrays: Rotation.__mul__
    # on 6,283 rotations costs 3–5 ms in scipy 1.17, quaternions.multiply 0.1 ms.
    # Memory: the results are slices of one block, and the temporaries alive at any time take
    # less room than it: glibc returns a freed heap top to the system once it exceeds twice the
    # largest block freed so far, and faulting that memory in again cost 2–3 ms a call
    report = progress or no_progress
    slots = iter(np.empty((len(SEGMENTS) + 2, n, 4)))
    quats, parent_x, forward_i0 = _trunk(pos, slots, i0)
    report(0.2, "orientations")
    reference = _end_references(calibration, quats["pelvis"][i0], up, forward_i0)
    _end_segments(quats, sensor_rotations, reference, i0, slots)
    report(0.4, "orientations")
    _limb_segments(quats, pos, sensor_rotations, parent_x, slots,
                   progress=scaled(report, 0.4, 1.0))
    return quats


def _checked_joints(joints: Mapping[str, ArrayLike], sensor_rotations: Mapping[str, Rotation],
                    i0: int) -> tuple[dict[str, Float], int]:
    """Every joint of ``JOINTS`` as an (F, 3) array and F, the rotations' lengths and ``i0``
    checked."""
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
    return pos, n


def _end_references(calibration: str | Mapping[str, Rotation], pelvis_i0: Float,
                    up: ArrayLike, forward_i0: Float) -> dict[str, Float]:
    """Orientation (4,) of each end segment (hands, feet, head) at the calibration frame."""
    if not isinstance(calibration, str):
        return {s: calibration[s].as_quat(scalar_first=True) if s in calibration
                else pelvis_i0 for s in _ENDS}
    if calibration == "pelvis":
        return dict.fromkeys(_ENDS, pelvis_i0)
    if calibration == "upright":
        y = np.array(up, dtype=float).reshape(3, 1)
        upright = quat.from_axis_rows(*_frame_from_yz(y, forward_i0))[0]
        return dict.fromkeys(_ENDS, upright)
    raise InputError(f"unknown calibration {calibration!r}; use 'pelvis', 'upright' "
                     "or a mapping of rotations", field="calibration")


def _end_segments(quats: dict[str, Float], sensor_rotations: Mapping[str, Rotation],
                  reference: Mapping[str, Float], i0: int, slots: Iterator[Float]) -> None:
    """Eq. 7 into ``quats``: each end segment with a sensor turns with it from its
    ``reference`` orientation at ``i0``."""
    ends = [s for s in _ENDS if s in sensor_rotations]
    if not ends:
        return
    # scipy's own, scalar-last quaternions (a third of the cost of scalar-first ones)
    last = [sensor_rotations[s].as_quat() for s in ends]
    offset = quat.relative(np.array([q[i0, [3, 0, 1, 2]] for q in last]),
                           np.array([np.reshape(reference[s], 4) for s in ends]))
    # q ⊗ c for one quaternion c is linear in q: rows e_j ⊗ c of a 4 × 4 matrix, here
    # ordered as scipy's components
    matrices = quat.multiply(np.eye(4)[[1, 2, 3, 0]], offset[:, None])
    for seg, q, m in zip(ends, last, matrices, strict=True):
        quats[seg] = _canonical(m.T @ q.T, next(slots))


def _limb_segments(quats: dict[str, Float], pos: Mapping[str, Float],
                   sensor_rotations: Mapping[str, Rotation], parent_x: Mapping[str, Float],
                   slots: Iterator[Float], *, progress: Progress) -> None:
    """Thighs, shanks, upper arms and forearms (eq. 6) into ``quats``, and the feet and
    hands that have no sensor (their lower segment's frame). The four limbs two at a time
    (``threads.run_each``), each into its own two slots, taken in limb order."""
    def limb(spec: tuple[str, str, str, str, str, str, float],
             into: tuple[Float, Float]) -> Callable[[Report], tuple[Float, Float]]:
        upper, _lower, _distal, prox, mid, end, sign = spec

        def task(_report: Report) -> tuple[Float, Float]:
            upper_bone = _normalise(_rows(pos, prox, mid))
            lower_bone = _normalise(_rows(pos, mid, end))
            sensor = sensor_rotations.get(upper)
            x = _flexion_axis(upper_bone, lower_bone,
                              None if sensor is None else sensor.as_matrix(),
                              parent_x["pelvis" if upper.endswith("thigh") else "chest"], sign)
            return quat_from_xy(x, upper_bone, into[0]), quat_from_xy(x, lower_bone, into[1])
        return task

    tasks = [limb(spec, (next(slots), next(slots))) for spec in _LIMBS]
    frames = next(iter(pos.values())).shape[0]
    done = run_each(tasks, progress, "orientations", frames=frames)
    for (upper, lower, distal, *_), (q_upper, q_lower) in zip(_LIMBS, done, strict=True):
        quats[upper] = q_upper
        quats[lower] = q_lower
        if distal not in quats:
            quats[distal] = quats[lower]
