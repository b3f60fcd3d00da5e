"""Foot geometry of the contact model: a stance point that rolls over the ball of the foot
where the file has no toe joint, the foot's axes and the lever arm of a foot accelerometer
strapped away from the ankle.

Suits strap the foot sensor on the instep, a few centimetres ahead of and above the ankle, so
it reads the ankle's acceleration plus the foot's rotational terms α×r + ω×(ω×r) (r the
sensor's offset, ω and α the foot's angular velocity and acceleration). The foot's axes come
from its ankle and toe points, so the sensor's path is ``ankle + axesᵀ r`` and its
acceleration the second derivative of that path: linear in r, which is fitted to the
measured magnitudes where the foot is planted (the mounting rotation is unknown, the
magnitude does not depend on it).

Where the file has no toe joint, the contacts are decoded with the ball at the toe joint's
place and the path holds still the points of the sole the foot rolls over, under the heel
and the ball (:func:`ball_on_foot`).

References: the rigid-body acceleration of a point, a = a_o + α×r + ω×(ω×r) (e.g. Goldstein,
Classical Mechanics, ch. 4.10); the rolling stance point follows the foot's rocker, heel then
forefoot (Perry & Burnfield, Gait Analysis, 2nd ed., ch. 3).
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np
from numpy.typing import NDArray

UP: Final[NDArray[np.float64]] = np.array([0.0, 1.0, 0.0])
"""World up (+Y)."""

TOE_AHEAD: Final[float] = 0.13
"""Ankle → ball of the foot, horizontally, as a fraction of the leg (hips → ankle) length:
0.12 m for a 0.9 m leg, as the toe joints of the CMU and Bandai Namco rigs."""

TOE_BELOW: Final[float] = 0.055
"""Ankle height above the ball of the flat foot, as a fraction of the leg length."""

SOLE_BELOW: Final[float] = 0.08
"""Ankle height above the floor, as a fraction of the leg length: the heel and the ball
touch the floor this far below the ankle of the flat foot (ankle height 0.039 H, hip
height 0.530 H: Winter, Biomechanics and Motor Control of Human Movement, 4th ed.,
ch. 4). A foot rolls over these points (heel strike, heel-off), not over the ankle or the
toe joint, which move a few centimetres forward as it rolls."""


INSTEP_SENSOR: Final[tuple[float, float, float]] = (0.03, 0.02, 0.0)
"""Where the rolling-foot model takes the foot accelerometer, metres along the foot's axes
(forward, up, lateral) from the ankle: on the instep, where suits strap it, a few
centimetres ahead of and above the ankle. As the heel lifts about the ball, the reading of
a sensor there differs from the ankle's by the foot's rotational terms; taking it at the
ankle made the readings of a sensor near the ball look like a foot that does not roll
(docs/translation.md)."""


SHANK_RIGIDITY: Final[float] = 0.002
"""A joint whose distance to the ankle varies by less than this fraction (std / mean) rides
on the shank; the hip's distance varies with the knee's flexion (a 20° bend of a straight
leg shortens it by 1.5 %; BVH and suit skeletons keep their bones rigid to rounding)."""


FOOT_REACH: Final[tuple[float, float]] = (0.04, 0.35)
"""Distances from the ankle, as fractions of the leg length, of a point on the foot (the
shank's knee is about 0.5 leg lengths away, the tip of the foot 0.2–0.3)."""


def foot_axes(ankle: NDArray[np.float64], toe: NDArray[np.float64]) -> NDArray[np.float64]:
    """Axes of the foot per frame: forward (ankle → toe), up, lateral.

    Parameters
    ----------
    ankle, toe : ndarray, shape (F, 3)
        World positions, +Y up.

    Returns
    -------
    ndarray, shape (F, 3, 3)
        Rows forward, up (perpendicular to forward, towards +Y), lateral (forward × up):
        an orthonormal frame that turns with the foot's pitch and heading (its roll about the
        forward axis is not seen by two points and taken as zero).
    """
    forward = _unit(toe - ankle)
    lateral = _unit(np.cross(forward, UP))
    up = np.cross(lateral, forward)
    return np.stack([forward, up, lateral], axis=1)


def sensor_track(ankle: NDArray[np.float64], axes: NDArray[np.float64],
                 offset: NDArray[np.float64]) -> NDArray[np.float64]:
    """Path (F, 3) of a point fixed to the foot at ``offset`` (3,) in :func:`foot_axes`
    ``axes`` (F, 3, 3) from ``ankle`` (F, 3), metres."""
    out: NDArray[np.float64] = ankle + np.einsum("fij,i->fj", axes, offset)
    return out


def estimate_sensor_offset(base: NDArray[np.float64], axes_acc: NDArray[np.float64],
                           measured: NDArray[np.float64], use: NDArray[np.bool_], *,
                           sigma: float = 1.5, prior_m: float = 0.1,
                           iterations: int = 8) -> NDArray[np.float64]:
    """Offset of a foot accelerometer from the ankle, from its readings while planted.

    Parameters
    ----------
    base : ndarray, shape (F, 3)
        Predicted specific force of the ankle, world frame, m/s²: its acceleration in an
        inertial frame plus gravity (+9.81 along +Y), e.g. the kinematic ankle acceleration
        minus the planted point's while the foot is planted.
    axes_acc : ndarray, shape (F, 3, 3)
        Second time derivative of :func:`foot_axes` (rows), 1/s².
    measured : ndarray, shape (F, 3)
        Accelerometer readings, sensor frame, m/s² (only their magnitude is used: the
        mounting rotation is unknown).
    use : ndarray of bool, shape (F,)
        Frames to fit (planted, not saturated).
    sigma : float
        Scale of the residuals, m/s² (residuals beyond 3σ are down-weighted).
    prior_m : float
        Scale of the ridge prior pulling the offset towards the ankle, metres.
    iterations : int
        Gauss–Newton steps.

    Returns
    -------
    ndarray, shape (3,)
        Offset along forward, up, lateral of :func:`foot_axes`, metres; zero when fewer than
        10 frames are usable.

    Notes
    -----
    Minimises Σ w (|a_meas| − |base + Σ_i r_i ä_i|)² + (σ/prior)² |r|², ä_i the second
    derivatives of the foot's axes (the path of the point ankle + Σ r_i e_i differentiated
    twice carries α×r + ω×(ω×r)); Gauss–Newton with Cauchy weights w (Nocedal & Wright,
    Numerical Optimization, ch. 10).
    """
    if int(use.sum()) < 10:
        return np.zeros(3)
    size = np.linalg.norm(measured[use], axis=1)
    b, q = base[use], axes_acc[use]
    offset = np.zeros(3)
    ridge = (sigma / prior_m) ** 2 * np.eye(3)
    for _ in range(iterations):
        v = b + np.einsum("fij,i->fj", q, offset)
        norm = np.maximum(np.linalg.norm(v, axis=1), 1e-9)
        jac = np.einsum("fj,fij->fi", v / norm[:, None], q)
        r = size - norm
        w = 1.0 / (1.0 + (r / (3.0 * sigma)) ** 2)
        step = np.linalg.solve((jac * w[:, None]).T @ jac + ridge,
                               (jac * w[:, None]).T @ r - ridge @ offset)
        offset = offset + step
        if float(np.linalg.norm(step)) < 1e-5:
            break
    return offset


def foot_point(positions: NDArray[np.float64], ankle: int, leg_m: float) -> int | None:
    """A joint rigid with the foot (an End Site or toe joint under the ankle), found by its
    distance to ``ankle``: between :data:`FOOT_REACH` of the leg length ``leg_m`` and
    constant to :data:`SHANK_RIGIDITY`. The farthest such joint (the longest lever on the
    foot's pitch); None when there is none.

    ``positions`` (F, J, 3) in metres. A point on the foot moves with the foot's rotation,
    so with the ankle it gives the foot's pitch and heading even where the file has no toe
    joint and the reader does not know where on the foot its End Site sits.
    """
    d = np.linalg.norm(positions - positions[:, ankle:ankle + 1], axis=2)
    mean, spread = d.mean(axis=0), d.std(axis=0)
    low, high = FOOT_REACH
    ok = (mean > low * leg_m) & (mean < high * leg_m) & (spread < SHANK_RIGIDITY * mean)
    ok[ankle] = False
    return int(np.argmax(np.where(ok, mean, -np.inf))) if ok.any() else None


def leg_length(positions: NDArray[np.float64], ankle: int, root: int) -> float:
    """Hips → ankle length, metres: the median distance of ``ankle`` from ``root`` in
    ``positions`` (F, J, 3, metres), or from the leg's own hip (:func:`leg_joints`) where the
    root is nearer to the ankle than the knee is, so cannot be the pelvis (files whose root
    is a dummy at the floor, e.g. Bandai Namco's moving ``joint_Root``); the knee is the
    farthest joint whose distance to the ankle is constant to :data:`SHANK_RIGIDITY` (a
    crouching karateka's pelvis stays 1.4 shank lengths from the ankle), measured on at
    most about 1000 frames evenly spread (the test has a wide margin; long takes stay
    cheap)."""
    to_root = float(np.median(np.linalg.norm(positions[:, root] - positions[:, ankle],
                                             axis=1)))
    sample = positions[::max(1, positions.shape[0] // 1000)]
    d = np.linalg.norm(sample - sample[:, ankle:ankle + 1], axis=2)
    rigid = d.std(axis=0) < SHANK_RIGIDITY * np.maximum(d.mean(axis=0), 1e-9)
    rigid[ankle] = False
    shank = float(d.mean(axis=0)[rigid].max()) if rigid.any() else 0.0
    if shank <= 0 or to_root >= shank:
        return to_root
    found = leg_joints(positions, ankle, 2.0 * shank)
    if found is None:
        return to_root
    return float(np.median(np.linalg.norm(positions[:, found[1]] - positions[:, ankle],
                                          axis=1)))


def ball_on_foot(ankle: NDArray[np.float64], point: NDArray[np.float64],
                 flat: NDArray[np.bool_], leg_m: float, *, sole: bool = False
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Ball of the foot and heel point (3,) each in :func:`foot_axes` of ``ankle`` and a
    ``point`` rigid with the foot (F, 3 each, metres, +Y up), when the foot stands flat: the
    ball :data:`TOE_AHEAD` leg lengths ahead of and :data:`TOE_BELOW` below the ankle (the
    toe joint's place), the heel the ankle itself; with ``sole`` both on the sole, at
    :data:`SOLE_BELOW` below the ankle (the points that touch the floor, still while the
    foot rolls over them).

    The foot stands flat at the median pitch β of ankle → ``point`` over the frames of
    ``flat`` (F,) (all frames when fewer than 10): a point (L, −d) along the flat foot's
    heading and up is (L cos β − d sin β, −L sin β − d cos β, 0) along the axes.
    """
    ahead = _unit(point - ankle)
    pitch = np.arcsin(np.clip(ahead[:, 1], -1.0, 1.0))
    beta = float(np.median(pitch[flat] if int(flat.sum()) >= 10 else pitch))
    drop = (SOLE_BELOW if sole else TOE_BELOW) * leg_m
    heel_drop = SOLE_BELOW * leg_m if sole else 0.0
    return (_on_flat_foot(beta, TOE_AHEAD * leg_m, drop), _on_flat_foot(beta, 0.0, heel_drop))


def _on_flat_foot(beta: float, length: float, drop: float) -> NDArray[np.float64]:
    return np.array([length * math.cos(beta) - drop * math.sin(beta),
                     -length * math.sin(beta) - drop * math.cos(beta), 0.0])


def body_heading(left_hip: NDArray[np.float64], right_hip: NDArray[np.float64]
                 ) -> NDArray[np.float64]:
    """Horizontal unit direction (F, 3) the body faces: perpendicular to the hip line
    (left hip − right hip) × up, +Y up, metres in."""
    lateral = left_hip - right_hip
    lateral[:, 1] = 0.0
    return _unit(np.cross(lateral, UP))


def leg_joints(positions: NDArray[np.float64], ankle: int, leg_m: float
               ) -> tuple[int, int] | None:
    """(knee, hip) of the leg ending at ``ankle``, found by rigidity: the knee is the joint
    0.25–0.75 leg lengths from the ankle whose distance to it varies least, the hip the
    joint at such a distance from the knee that varies least while its distance to the
    ankle varies (not on the shank). None when none qualifies.

    ``positions`` (F, J, 3) in metres; ``leg_m`` the leg length.
    """
    knee = _most_rigid(positions, ankle, leg_m, exclude=np.zeros(positions.shape[1], bool))
    if knee is None:
        return None
    to_ankle = np.linalg.norm(positions - positions[:, ankle:ankle + 1], axis=2)
    on_shank = to_ankle.std(axis=0) < SHANK_RIGIDITY * np.maximum(to_ankle.mean(axis=0),
                                                                  1e-9)
    hip = _most_rigid(positions, knee, leg_m, exclude=on_shank)
    return None if hip is None else (knee, hip)


def _most_rigid(positions: NDArray[np.float64], joint: int, leg_m: float,
                exclude: NDArray[np.bool_]) -> int | None:
    d = np.linalg.norm(positions - positions[:, joint:joint + 1], axis=2)
    mean, spread = d.mean(axis=0), d.std(axis=0)
    ok = (mean > 0.25 * leg_m) & (mean < 0.75 * leg_m) & ~exclude
    ok[joint] = False
    if not ok.any():
        return None
    score = np.where(ok, spread / np.maximum(mean, 1e-9), np.inf)
    # equally rigid joints (a leg that bends in one plane keeps its knee at a fixed distance
    # from the other hip too): the nearest is the bone's own end
    tied = score <= float(score.min()) + 1e-6
    best = int(np.argmin(np.where(tied, mean, np.inf)))
    return best if score[best] < 0.05 else None


def _unit(v: NDArray[np.float64]) -> NDArray[np.float64]:
    out: NDArray[np.float64] = v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True),
                                              1e-12)
    return out


def roll_advance(tilt: NDArray[np.float64], leg_m: float) -> NDArray[np.float64]:
    """How far (F,) the ankle moves forward, metres, as the heel lifts by ``tilt`` about the
    ball of the foot (:data:`TOE_AHEAD` and :data:`TOE_BELOW` of the leg ahead and below):
    L (1 − cos θ) + d sin θ, θ clipped to where the ankle is straight above the ball."""
    length, drop = TOE_AHEAD * leg_m, TOE_BELOW * leg_m
    theta = np.clip(tilt, 0.0, math.atan2(length, drop))
    out: NDArray[np.float64] = length * (1.0 - np.cos(theta)) + drop * np.sin(theta)
    return out


def rise_tilt(ankle: NDArray[np.float64], other_ankle: NDArray[np.float64], leg_m: float
              ) -> NDArray[np.float64]:
    """Heel lift θ (F,) about the ball of the foot, radians, that raises the ankle by its
    height h above the other ankle (F, 3 each, metres, +Y up).

    The ball is L = :data:`TOE_AHEAD` and d = :data:`TOE_BELOW` leg lengths ahead of and
    below the flat foot's ankle, so L sin θ + d cos θ = d + h (the forefoot rocker, Perry &
    Burnfield ch. 3), at most where the ankle is straight above the ball. A foot planted on
    a step above the other reads as lifted too (docs/translation.md, Limitations)."""
    length, drop = TOE_AHEAD * leg_m, TOE_BELOW * leg_m
    reach, tilt = math.hypot(length, drop), math.atan2(drop, length)
    rise = np.clip(ankle[:, 1] - other_ankle[:, 1], 0.0, reach - drop)
    out: NDArray[np.float64] = np.arcsin(np.minimum((drop + rise) / reach, 1.0)) - tilt
    return out


def heading_by_knees(heading: NDArray[np.float64], hips: list[NDArray[np.float64]],
                     knees: list[NDArray[np.float64]], ankles: list[NDArray[np.float64]]
                     ) -> NDArray[np.float64]:
    """``heading`` (F, 3), reversed when the knees bend backwards along it: knees flex
    forward, so a hip line whose left and right are swapped (a mirrored file, or hips found
    on the wrong sides) still gives the way the feet point. Each leg's hip, knee and ankle
    paths (F, 3), metres."""
    ahead = 0.0
    for hip, knee, ankle in zip(hips, knees, ankles, strict=True):
        axis = _unit(ankle - hip)
        bend = knee - hip
        bend = bend - axis * np.sum(bend * axis, axis=1, keepdims=True)
        ahead += float(np.median(np.sum(bend * heading, axis=1)))
    return -heading if ahead < 0 else heading
