"""Foot geometry of the contact model: axes, lever arm of the foot sensor, rolling stance
point, legs and heading."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bonefit.estimation.kinematics import GRAVITY
from bonefit.estimation.stance import (
    SOLE_BELOW,
    TOE_AHEAD,
    UP,
    ball_on_foot,
    body_heading,
    estimate_sensor_offset,
    foot_axes,
    foot_point,
    heading_by_knees,
    leg_joints,
    leg_length,
    rise_tilt,
    roll_advance,
    sensor_track,
)

FPS = 200.0


def rolling_foot(n: int = 800) -> tuple[np.ndarray, np.ndarray]:
    """Ankle and toe (F, 3) of a foot that pitches (heel-off and back, up to 35°) and turns
    about the vertical, the ankle also translating: a rigid foot 14 cm long."""
    t = np.arange(n) / FPS
    pitch = np.radians(35) * np.sin(2.1 * t) ** 2
    yaw = 0.8 * np.sin(0.9 * t)
    rot = Rotation.from_euler("YX", np.column_stack([yaw, -pitch]))
    ankle = np.column_stack([0.3 * np.sin(1.3 * t), 0.08 + 0.02 * np.sin(3.0 * t), 0.2 * t])
    toe = ankle + rot.apply(np.array([0.0, -0.06, 0.13]))
    return ankle, toe


def second_derivative(x: np.ndarray) -> np.ndarray:
    return np.gradient(np.gradient(x, 1.0 / FPS, axis=0), 1.0 / FPS, axis=0)


def test_foot_axes_are_orthonormal_and_point_along_the_foot() -> None:
    ankle, toe = rolling_foot()
    axes = foot_axes(ankle, toe)
    gram = np.einsum("fij,fkj->fik", axes, axes)
    np.testing.assert_allclose(gram, np.broadcast_to(np.eye(3), gram.shape), atol=1e-12)
    forward = (toe - ankle) / np.linalg.norm(toe - ankle, axis=1, keepdims=True)
    np.testing.assert_allclose(axes[:, 0], forward, atol=1e-12)
    assert (axes[:, 1] @ UP > 0).all()


@pytest.mark.parametrize("offset", [(0.05, 0.04, 0.01), (0.02, 0.06, -0.015), (0.0, 0.0, 0.0)])
def test_lever_arm_estimate_recovers_a_known_offset(offset: tuple[float, float, float]) -> None:
    ankle, toe = rolling_foot()
    axes = foot_axes(ankle, toe)
    truth = np.array(offset)
    sensor = sensor_track(ankle, axes, truth)
    up = np.array([0.0, GRAVITY, 0.0])
    # what a strapped accelerometer reads: specific force in a rotated sensor frame + noise
    mount = Rotation.from_rotvec([0.4, -1.1, 2.0])
    rng = np.random.default_rng(3)
    measured = mount.apply(second_derivative(sensor) + up)
    measured += rng.normal(0.0, 0.01 * GRAVITY, measured.shape)
    base = second_derivative(ankle) + up
    use = np.ones(ankle.shape[0], dtype=bool)
    use[:5] = use[-5:] = False  # np.gradient's one-sided ends
    found = estimate_sensor_offset(base, second_derivative(axes), measured, use)
    # forward and up are seen through the pitch (up only through ω², so the ridge prior
    # shortens it by a few mm); a lateral offset lies on the pitch axis and barely changes
    # the magnitude under yaw, so the prior keeps it small and never invents it
    np.testing.assert_allclose(found[:2], truth[:2], atol=0.008)
    assert abs(found[2]) <= abs(truth[2]) + 0.001


def test_lever_arm_estimate_needs_frames() -> None:
    ankle, toe = rolling_foot(50)
    axes = foot_axes(ankle, toe)
    use = np.zeros(50, dtype=bool)
    use[:5] = True
    found = estimate_sensor_offset(ankle, second_derivative(axes), ankle, use)
    np.testing.assert_array_equal(found, np.zeros(3))


def test_rolling_stance_point_stays_on_the_ball_while_the_heel_lifts() -> None:
    leg = 0.9
    length, drop = 0.13 * leg, 0.055 * leg
    theta = np.radians(np.linspace(0.0, 40.0, 50))
    ball = np.array([0.4, 0.0, 1.0])
    forward = np.array([0.6, 0.0, 0.8])
    # heel lifted by θ about the ball: the ankle rises on a circle around it
    ankle = (ball - forward * (length * np.cos(theta) - drop * np.sin(theta))[:, None]
             + UP * (length * np.sin(theta) + drop * np.cos(theta))[:, None])
    other = np.tile([0.0, drop, 0.5], (50, 1))  # the other foot flat on the same floor
    tilt = rise_tilt(ankle, other, leg)
    np.testing.assert_allclose(tilt, theta, atol=1e-12)
    # moved back by its advance, the ankle stays where the flat foot's ankle was (across)
    point = (ankle - forward * roll_advance(tilt, leg)[:, None])[:, [0, 2]]
    np.testing.assert_allclose(point, np.broadcast_to(ankle[0, [0, 2]], point.shape),
                               atol=1e-12)


def test_roll_stops_where_the_ankle_is_above_the_ball() -> None:
    leg = 1.0
    ankle = np.array([[0.0, 0.055 + 0.5, 0.0]])  # far higher than a heel can roll
    tilt = rise_tilt(ankle, np.array([[0.0, 0.055, 0.0]]), leg)
    np.testing.assert_allclose(roll_advance(tilt, leg), [0.13], atol=1e-12)


def test_legs_and_heading_of_a_planar_walker_with_mirrored_sides() -> None:
    # legs bending in one plane keep each knee at a fixed distance from both hips: the
    # nearer is its own; a file with left and right swapped still faces the knees' way
    t = np.linspace(0.0, 2.0, 200)
    hips, knees, ankles, joints = [], [], [], []
    for side, phase in ((-0.1, 0.0), (0.1, np.pi)):
        flex = 0.3 + 0.25 * np.sin(2 * np.pi * t + phase)
        hip = np.column_stack([0 * t, 0.9 + 0 * t, side + 0 * t])
        knee = hip + np.column_stack([0.42 * np.sin(flex), -0.42 * np.cos(flex), 0 * t])
        ankle = knee + np.column_stack([-0.42 * np.sin(flex), -0.42 * np.cos(flex), 0 * t])
        hips.append(hip), knees.append(knee), ankles.append(ankle)
        joints += [hip, knee, ankle]
    positions = np.stack([np.column_stack([0 * t, 1.0 + 0 * t, 0 * t]), *joints], axis=1)
    assert leg_joints(positions, 3, 0.8) == (2, 1)
    assert leg_joints(positions, 6, 0.8) == (5, 4)
    swapped = body_heading(hips[1], hips[0])  # the +Z hip taken as the left one
    np.testing.assert_allclose(swapped[0], [-1.0, 0.0, 0.0], atol=1e-12)
    fixed = heading_by_knees(swapped, hips, knees, ankles)
    np.testing.assert_allclose(fixed, np.tile([1.0, 0.0, 0.0], (t.size, 1)), atol=1e-12)


def test_body_heading_is_horizontal_and_faces_forward() -> None:
    left = np.array([[0.1, 0.9, 0.0], [0.0, 0.95, -0.1]])
    right = np.array([[-0.1, 0.9, 0.0], [0.0, 0.9, 0.1]])
    np.testing.assert_allclose(body_heading(left, right), [[0, 0, 1], [1, 0, 0]], atol=1e-12)


def heel_lift_with_end_site(end_pitch_deg: float, *, ahead: float = 0.13,
                            below: float = 0.055, lift_deg: float = 40.0
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Ankle, an End Site rigid with the foot 16 cm away pitched ``end_pitch_deg`` when the
    foot is flat, the still pivot (``ahead`` and ``below`` leg lengths of 0.9 m ahead of and
    below the flat foot's ankle; by default the ball) and the flat frames: flat for 20
    frames, then the foot turns about the pivot, the heel up by ``lift_deg`` (negative: the
    toes up)."""
    leg = 0.9
    length, drop = ahead * leg, below * leg
    theta = np.concatenate([np.zeros(20), np.radians(np.linspace(0.0, lift_deg, 50))])
    ball = np.array([0.4, 0.0, 1.0])
    forward = np.array([0.6, 0.0, 0.8])
    lateral = np.cross(forward, UP)
    turn = Rotation.from_rotvec(-theta[:, None] * lateral)  # heel up, toes down
    ankle = ball + turn.apply(-length * forward + drop * UP)
    pitch = np.radians(end_pitch_deg)
    end = ankle + turn.apply(0.16 * (np.cos(pitch) * forward + np.sin(pitch) * UP))
    return ankle, end, ball, theta == 0


@pytest.mark.parametrize("end_pitch_deg", [-45.0, -20.0, 0.0, 10.0])
def test_ball_on_an_end_site_stays_still_while_the_heel_lifts(end_pitch_deg: float) -> None:
    # wherever the End Site sits on the foot, the ball placed on it does not move while the
    # foot rolls over it (the ankle alone moves 8 cm here)
    ankle, end, ball, flat = heel_lift_with_end_site(end_pitch_deg)
    local, heel = ball_on_foot(ankle, end, flat, 0.9)
    path = sensor_track(ankle, foot_axes(ankle, end), local)
    np.testing.assert_allclose(path, np.broadcast_to(ball, path.shape), atol=1e-12)
    assert np.linalg.norm(ankle - ankle[0], axis=1).max() > 0.07
    np.testing.assert_allclose(heel, 0.0, atol=1e-15)  # the heel point is the ankle


@pytest.mark.parametrize("end_pitch_deg", [-45.0, 0.0, 10.0])
@pytest.mark.parametrize(("ahead", "lift_deg"), [(TOE_AHEAD, 40.0), (0.0, -20.0)],
                         ids=["heel-off", "heel-strike"])
def test_sole_points_stay_still_while_the_foot_rolls_over_them(
        end_pitch_deg: float, ahead: float, lift_deg: float) -> None:
    # a foot rolls over the floor: forward over the sole's ball as the heel lifts, back on
    # the heel as the toes come down; the sole's points (SOLE_BELOW under the flat foot's
    # ankle) stay still where the ankle moves 6-8 cm and the toe joint's ball 2-3 cm
    ankle, end, pivot, flat = heel_lift_with_end_site(end_pitch_deg, ahead=ahead,
                                                      below=SOLE_BELOW, lift_deg=lift_deg)
    axes = foot_axes(ankle, end)
    ball, heel = ball_on_foot(ankle, end, flat, 0.9, sole=True)
    path = sensor_track(ankle, axes, ball if ahead else heel)
    np.testing.assert_allclose(path, np.broadcast_to(pivot, path.shape), atol=1e-12)
    joint_ball, _ = ball_on_foot(ankle, end, flat, 0.9)
    for moving in (ankle, sensor_track(ankle, axes, joint_ball)):
        assert np.linalg.norm(moving - moving[0], axis=1).max() > 0.015


def test_foot_point_is_the_joint_rigid_with_the_foot() -> None:
    ankle, end, _ball, _flat = heel_lift_with_end_site(-30.0)
    n = ankle.shape[0]
    knee = ankle + np.array([0.0, 0.42, 0.0])  # rigid but a shank away
    bending = end + np.column_stack([np.zeros(n), 0.02 * np.sin(np.arange(n) / 5.0),
                                     np.zeros(n)])  # a toe tip that bends
    hips = knee + np.array([0.0, 0.44, 0.0])
    positions = np.stack([hips, knee, ankle, bending, end], axis=1)
    assert foot_point(positions, 2, 0.9) == 4
    assert foot_point(positions[:, :4], 2, 0.9) is None


def test_leg_length_from_the_hip_when_the_root_is_a_dummy_at_the_floor() -> None:
    # two legs of 0.42 m bones bending in one plane under a pelvis at 1 m; the file's root is
    # the pelvis, or a dummy moving along the floor (Bandai's joint_Root), nearer to the
    # ankles than the knees are: the leg is then measured from the leg's own hip
    t = np.linspace(0.0, 2.0, 200)
    joints = []
    for side, phase in ((-0.1, 0.0), (0.1, np.pi)):
        flex = 0.3 + 0.25 * np.sin(2 * np.pi * t + phase)
        hip = np.column_stack([0 * t, 0.9 + 0 * t, side + 0 * t])
        knee = hip + np.column_stack([0.42 * np.sin(flex), -0.42 * np.cos(flex), 0 * t])
        ankle = knee + np.column_stack([-0.42 * np.sin(flex), -0.42 * np.cos(flex), 0 * t])
        joints += [hip, knee, ankle]
    pelvis = np.column_stack([0 * t, 1.0 + 0 * t, 0 * t])
    dummy = np.column_stack([0.05 * np.sin(t), 0 * t, 0 * t])
    positions = np.stack([dummy, pelvis, *joints], axis=1)
    to_hip = np.median(np.linalg.norm(positions[:, 2] - positions[:, 4], axis=1))
    to_pelvis = np.median(np.linalg.norm(positions[:, 1] - positions[:, 4], axis=1))
    assert leg_length(positions, 4, 1) == pytest.approx(to_pelvis, abs=1e-12)
    assert leg_length(positions, 4, 0) == pytest.approx(to_hip, abs=1e-12)
    assert 0.75 < to_hip < 0.84
