"""Segment orientations (bonefit.estimation.orientations) against bodies with known segment
frames."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from bonefit.estimation.errors import InputError
from bonefit.estimation.model import SEGMENTS
from bonefit.estimation.orientations import estimate_orientations, quat_from_xy
from bonefit.estimation.simulate.sensors import example_motion, simulate_sensors

# Upright rest pose, facing +z, left = +x, metres.
REST = {
    "waist": (0.0, 1.0, 0.0), "l_hip": (0.1, 0.9, 0.0), "r_hip": (-0.1, 0.9, 0.0),
    "chest": (0.0, 1.45, 0.0), "neck": (0.0, 1.55, 0.0),
    "l_shoulder": (0.18, 1.45, 0.0), "r_shoulder": (-0.18, 1.45, 0.0),
    "l_elbow": (0.18, 1.17, 0.0), "r_elbow": (-0.18, 1.17, 0.0),
    "l_wrist": (0.18, 0.92, 0.0), "r_wrist": (-0.18, 0.92, 0.0),
    "l_knee": (0.1, 0.5, 0.0), "r_knee": (-0.1, 0.5, 0.0),
    "l_ankle": (0.1, 0.1, 0.0), "r_ankle": (-0.1, 0.1, 0.0),
}
REST["root"] = tuple(np.mean([REST["waist"], REST["l_hip"], REST["r_hip"]], axis=0))


def rx(angle: NDArray[np.float64]) -> Rotation:
    return Rotation.from_euler("x", angle[:, None])


def ry(angle: NDArray[np.float64]) -> Rotation:
    return Rotation.from_euler("y", angle[:, None])


def posed_body(n: int = 200, seed: int = 0) -> tuple[dict[str, NDArray[np.float64]],
                                                       dict[str, Rotation],
                                                       dict[str, Rotation]]:
    """A body turning and translating as a whole (G), with a moving left hip (H), a flexing
    left knee (φ), a moving left shoulder (A), a flexing left elbow (ψ), a left wrist twisting
    about the forearm (τ), a foot rigid on its shank; right limbs straight. Frame 0 is the rest
    pose. Returns joints, true segment frames and sensor rotations."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, n)
    ramp = np.sin(np.pi * t / 2) ** 2  # 0 at frame 0
    g = Rotation.from_rotvec(np.outer(ramp, [0.3, 1.5, -0.2]))
    shift = np.column_stack([0.5 * t, 0.05 * np.sin(6 * t), t])
    h = Rotation.from_rotvec(np.outer(ramp, [-0.6, 0.2, 0.1]))
    phi = 1.4 * np.abs(np.sin(3 * np.pi * t))  # knee straight at times: eq. 6 blend
    a = Rotation.from_rotvec(np.outer(ramp, [0.4, -0.3, 0.5]))
    psi = 1.8 * np.abs(np.sin(2 * np.pi * t))
    tau = 1.2 * np.sin(2 * np.pi * t) * ramp
    truth = dict.fromkeys(("pelvis", "chest", "head", "spine", "cervical", "r_thigh",
                           "r_shank", "r_foot", "r_upperarm", "r_forearm", "r_hand"), g)
    truth["l_thigh"] = g * h
    truth["l_shank"] = truth["l_foot"] = g * h * rx(phi)
    truth["l_upperarm"] = g * a
    truth["l_forearm"] = g * a * rx(-psi)
    truth["l_hand"] = truth["l_forearm"] * ry(tau)

    rest = {k: np.asarray(v) for k, v in REST.items()}
    joints: dict[str, NDArray[np.float64]] = {}
    for name in ("root", "waist", "chest", "neck", "l_hip", "r_hip", "l_shoulder",
                 "r_shoulder", "r_elbow", "r_wrist", "r_knee", "r_ankle"):
        joints[name] = g.apply(rest[name]) + shift
    joints["l_knee"] = joints["l_hip"] + truth["l_thigh"].apply(rest["l_knee"] - rest["l_hip"])
    joints["l_ankle"] = joints["l_knee"] + truth["l_shank"].apply(
        rest["l_ankle"] - rest["l_knee"])
    joints["l_elbow"] = joints["l_shoulder"] + truth["l_upperarm"].apply(
        rest["l_elbow"] - rest["l_shoulder"])
    joints["l_wrist"] = joints["l_elbow"] + truth["l_forearm"].apply(
        rest["l_wrist"] - rest["l_elbow"])
    sensors = {s: truth[s] * Rotation.random(rng=rng) for s in SEGMENTS}
    return joints, truth, sensors


def angle_deg(q: NDArray[np.float64], truth: Rotation) -> NDArray[np.float64]:
    est = Rotation.from_quat(q, scalar_first=True)
    return np.asarray(np.degrees((truth.inv() * est).magnitude()))


def test_upright_rest_pose_gives_identity_frames() -> None:
    n = 5
    joints = {k: np.tile(v, (n, 1)) for k, v in REST.items()}
    rng = np.random.default_rng(1)
    sensors = {s: Rotation.from_quat(np.tile(Rotation.random(rng=rng).as_quat(), (n, 1)))
               for s in SEGMENTS}
    out = estimate_orientations(joints, sensors)
    assert set(out) == {*SEGMENTS, "spine", "cervical"}
    for seg, q in out.items():
        assert q.shape == (n, 4), seg
        assert np.allclose(angle_deg(q, Rotation.identity(n)), 0.0, atol=1e-6), seg


def test_posed_body_recovers_known_frames() -> None:
    joints, truth, sensors = posed_body()
    out = estimate_orientations(joints, sensors, i0=0)
    for seg, rot in truth.items():
        assert angle_deg(out[seg], rot).max() < 1e-5, seg


def test_forearm_keeps_the_elbow_frame_when_the_wrist_twists() -> None:
    # a generated clip whose wrists twist about the forearm (the simulator's truth, as in
    # the motion-capture clips): the forearm turned to the hand frame took that twist and
    # every hand-sensor error, and was up to 166 degrees off (a flip of the minimal rotation)
    motion = example_motion(240, seed=3, scale=1.5)
    rec, truth = simulate_sensors(motion, units_m=0.01, orientation_noise_deg=0.0,
                                  position_noise_m=0.0, slip_m=0.0, drop_fraction=0.0)
    sensors = {s: Rotation.from_quat(rec.quaternions[:, k], scalar_first=True)
               for k, s in enumerate(rec.sensors)}
    out = estimate_orientations(truth.joints, sensors)
    for seg in ("l_forearm", "r_forearm", "l_shank", "r_shank"):
        # the model's frames differ from the clip's nodes' by a fixed rotation
        offset = truth.segment_rotations[seg].inv() * Rotation.from_quat(out[seg],
                                                                        scalar_first=True)
        assert np.degrees((offset[0].inv() * offset).magnitude()).max() < 1.0, seg


def test_knee_flexion_gives_flexion_axis_as_x() -> None:
    joints, _, sensors = posed_body(seed=3)
    out = estimate_orientations(joints, sensors)
    x_thigh = Rotation.from_quat(out["l_thigh"], scalar_first=True).apply([1.0, 0.0, 0.0])
    x_shank = Rotation.from_quat(out["l_shank"], scalar_first=True).apply([1.0, 0.0, 0.0])
    hip, knee, ankle = joints["l_hip"], joints["l_knee"], joints["l_ankle"]
    cross = np.cross(hip - knee, knee - ankle)
    bent = np.linalg.norm(cross, axis=1) > 1e-3
    cross = cross[bent] / np.linalg.norm(cross[bent], axis=1)[:, None]
    # the flexion axis is the thigh's (and shank's) x, pointing left
    assert np.allclose(np.einsum("ij,ij->i", x_thigh[bent], cross), 1.0, atol=1e-9)
    assert np.allclose(x_thigh, x_shank, atol=1e-9)
    # y along the bone, from the distal to the proximal joint
    y_shank = Rotation.from_quat(out["l_shank"], scalar_first=True).apply([0.0, 1.0, 0.0])
    bone = (knee - ankle) / np.linalg.norm(knee - ankle, axis=1)[:, None]
    assert np.allclose(y_shank, bone, atol=1e-9)


def test_spine_and_cervical_follow_their_segments_by_minimal_rotation() -> None:
    joints, _, sensors = posed_body(n=50, seed=2)
    rng = np.random.default_rng(4)
    joints["chest"] = joints["chest"] + rng.normal(scale=0.05, size=(50, 3))
    joints["neck"] = joints["neck"] + rng.normal(scale=0.03, size=(50, 3))
    out = estimate_orientations(joints, sensors)
    chest = Rotation.from_quat(out["chest"], scalar_first=True)
    for seg, a, b in (("spine", "waist", "chest"), ("cervical", "chest", "neck")):
        rot = Rotation.from_quat(out[seg], scalar_first=True)
        bone = joints[b] - joints[a]
        bone /= np.linalg.norm(bone, axis=1)[:, None]
        assert np.allclose(rot.apply([0.0, 1.0, 0.0]), bone, atol=1e-9), seg
        # eq. 10: the rotation from the chest frame has no component about y
        rel = (chest.inv() * rot).as_rotvec()
        assert np.allclose(rel[:, 1], 0.0, atol=1e-9), seg


def test_calibration_frame_and_mapping() -> None:
    joints, truth, sensors = posed_body(n=60)
    i0 = 40
    out = estimate_orientations(joints, sensors, i0=i0)
    # at i0 the hands, feet and head are aligned with the pelvis by default
    for seg in ("l_hand", "r_hand", "l_foot", "r_foot", "head"):
        assert angle_deg(out[seg][i0:i0 + 1], truth["pelvis"][i0:i0 + 1])[0] < 1e-6, seg
    # a given calibration orientation is reproduced at i0 and followed by the sensor
    given = Rotation.from_euler("x", 30, degrees=True)
    out2 = estimate_orientations(joints, sensors, i0=i0, calibration={"l_foot": given})
    assert angle_deg(out2["l_foot"][i0:i0 + 1], given)[0] < 1e-6
    foot = Rotation.from_quat(out2["l_foot"], scalar_first=True)
    rel = sensors["l_foot"].inv() * foot  # constant offset (eq. 7)
    assert np.allclose(rel.as_matrix(), rel[0].as_matrix(), atol=1e-9)
    upright = estimate_orientations(joints, sensors, i0=i0, calibration="upright",
                                    up=(0.0, 1.0, 0.0))
    head_y = Rotation.from_quat(upright["head"][i0], scalar_first=True).apply([0.0, 1.0, 0.0])
    assert np.allclose(head_y, [0.0, 1.0, 0.0], atol=1e-9)
    # i0 may count from the end, as numpy indices do
    for calibration in ("pelvis", "upright"):
        for frame in (i0, 59):
            back = estimate_orientations(joints, sensors, i0=frame - 60, calibration=calibration)
            ahead = estimate_orientations(joints, sensors, i0=frame, calibration=calibration)
            for seg, q in ahead.items():
                np.testing.assert_allclose(back[seg], q, atol=1e-12, err_msg=seg)


def test_missing_sensors_fall_back_to_parent_segments() -> None:
    joints, truth, sensors = posed_body(n=40)
    reduced = {s: r for s, r in sensors.items() if s not in ("l_hand", "l_foot")}
    out = estimate_orientations(joints, reduced)
    assert np.allclose(out["l_foot"], out["l_shank"])
    assert angle_deg(out["l_shank"], truth["l_shank"]).max() < 1e-5
    # without the hand the forearm keeps the flexion frame: y still along the bone
    y = Rotation.from_quat(out["l_forearm"], scalar_first=True).apply([0.0, 1.0, 0.0])
    bone = joints["l_elbow"] - joints["l_wrist"]
    assert np.allclose(y, bone / np.linalg.norm(bone, axis=1)[:, None], atol=1e-9)


def test_outputs_are_unit_quaternions_on_noisy_joints() -> None:
    joints, _, sensors = posed_body(n=80, seed=5)
    rng = np.random.default_rng(0)
    noisy = {k: v + rng.normal(scale=0.01, size=v.shape) for k, v in joints.items()}
    out = estimate_orientations(noisy, sensors)
    for seg, q in out.items():
        assert np.all(np.isfinite(q)), seg
        assert np.allclose(np.linalg.norm(q, axis=1), 1.0), seg


def test_bad_inputs() -> None:
    joints, _, sensors = posed_body(n=10)
    with pytest.raises(InputError, match="i0"):
        estimate_orientations(joints, sensors, i0=10)
    missing = {k: v for k, v in joints.items() if k != "l_knee"}
    with pytest.raises(InputError, match="l_knee"):
        estimate_orientations(missing, sensors)
    with pytest.raises(InputError, match="calibration"):
        estimate_orientations(joints, sensors, calibration="sideways")


@pytest.mark.parametrize("up_share", [0.0, 0.97])
def test_limb_frame_quaternions_match_scipy_for_every_direction(up_share: float) -> None:
    """Bones pointing down in about half the frames, or in a few (quat_from_xy turns the
    frames down by a sign per frame when they are many, by their indices when few)."""
    rng = np.random.default_rng(7)
    y = rng.normal(size=(3, 400))
    up = rng.random(400) < up_share
    y[1, up] = np.abs(y[1, up])
    # bones straight up and down, and twists of a half turn (x opposite the swung e_x)
    y[:, :4] = [[0.0, 0.0, 0.0, 0.0], [1.0, -1.0, 1.0, -1.0], [0.0, 0.0, 0.0, 0.0]]
    y /= np.linalg.norm(y, axis=0)
    x = rng.normal(size=(3, 400))
    x[:, :4] = [[1.0, 1.0, -1.0, -1.0], [0.3, 0.0, 0.0, 0.2], [0.0, 0.0, 0.0, 0.0]]
    q = quat_from_xy(x, y, np.empty((400, 4)))
    assert np.all(q[:, 0] >= 0)
    xu = x - np.einsum("ij,ij->j", x, y) * y
    xu /= np.linalg.norm(xu, axis=0)
    frames = np.stack([xu.T, y.T, np.cross(xu.T, y.T)], axis=-1)
    truth = Rotation.from_matrix(frames).as_quat(scalar_first=True)
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", q, truth)), 1.0, atol=1e-14)
    # x along the bone leaves the twist arbitrary but the frame valid
    along = quat_from_xy(y[:, :5].copy(), y[:, :5], np.empty((5, 4)))
    np.testing.assert_allclose(np.linalg.norm(along, axis=1), 1.0, atol=1e-14)
    y_axis = Rotation.from_quat(along, scalar_first=True).apply([0.0, 1.0, 0.0])
    np.testing.assert_allclose(y_axis, y[:, :5].T, atol=1e-14)
