"""Every BVH bonefit writes, read by independent readers, says what the JSON says.

Readers: bvhio (PyPI) and three.js's BVHLoader under Node (``bvh_readers``). Files: the
skeleton BVH, the translated BVH of a BVH input (Bandai-style position channels on every
joint) and the point-joint BVH of CSV and MVNX inputs. Plus the sub-frame check: channels
interpolated linearly at half frames (as Blender's importer keys them) stay within 10 mm of
the midpoint of the JSON's neighbouring frames.
"""

from __future__ import annotations

import io
import itertools
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from bonefit.estimation import bvh as bvh_module
from bonefit.estimation.bvh import (
    EULER_ORDERS,
    JUMP_DEG,
    BvhMotion,
    compose_quaternions,
    continuous_euler,
    euler_angle_rows,
    euler_channels,
    euler_degrees,
    fold_position_channels,
    forward_kinematics,
    half_frame_error,
    jump_steps,
    point_joint_bvh,
    read_bvh,
    rest_euler_channels,
    slip_chain,
    write_bvh,
)
from bonefit.estimation.errors import InputError
from bonefit.estimation.io.body import find_bvh_feet
from bonefit.estimation.io.kinematics import (
    read_kinematics,
    write_kinematics_csv,
    write_translation,
)
from bonefit.estimation.io.skeleton import BVH_NODES, skeleton_to_bvh, write_skeleton_bvh
from bonefit.estimation.model import JOINTS, SEGMENTS
from bonefit.estimation.recording import SensorRecording
from bonefit.estimation.results import SkeletonResult
from bonefit.estimation.simulate.inertial import simulate_walker
from bonefit.estimation.simulate.sensors import SimulationTruth, example_motion, simulate_sensors
from bonefit.estimation.skeleton import estimate_skeleton
from bonefit.estimation.translation import estimate_translation
from tests.estimation.bvh_readers import bvhio_positions, install_three, threejs_positions
from tests.estimation.test_io_skeleton import REST, rigid_result
from tests.estimation.test_mvnx import write_mvnx

READERS = ("bvhio", "three.js")
DRIVER = {node: segment for node, _, segment in BVH_NODES}


@pytest.fixture(scope="module")
def three_script() -> Path:
    return install_three()


def read_with(reader: str, path: Path, three_script: Path | None
              ) -> dict[str, NDArray[np.float64]]:
    if reader == "bvhio":
        return bvhio_positions(path)
    assert three_script is not None
    return threejs_positions(three_script, path)


@pytest.fixture(params=READERS)
def reader(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.fixture
def script_for(reader: str, request: pytest.FixtureRequest) -> Path | None:
    """three.js's script, installed only when the three.js reader is asked for."""
    return request.getfixturevalue("three_script") if reader == "three.js" else None


def flexing_result(n_frames: int = 40, fps: float = 30.0) -> SkeletonResult:
    """A rigid result whose knees and elbows flex 0–135° about x with a little twist, the
    pelvis turning a full circle (the motion that put flexion on Z-X-Y's middle axis)."""
    t = np.linspace(0.0, 1.0, n_frames)[:, None]
    yaw = Rotation.from_euler("y", 2 * np.pi * t)
    flex = np.radians(135.0) * np.sin(np.pi * t[:, 0]) ** 2
    wobble = Rotation.from_rotvec(np.column_stack([np.zeros(n_frames),
                                                   0.15 * np.sin(7 * t[:, 0]),
                                                   0.1 * np.cos(5 * t[:, 0])]))
    hinge = {"l_shank": 1.0, "r_shank": 0.8, "l_forearm": -1.0, "r_forearm": -0.9}
    parent_seg = {"l_shank": "l_thigh", "r_shank": "r_thigh", "l_forearm": "l_upperarm",
                  "r_forearm": "r_upperarm"}
    orient: dict[str, Rotation] = {}
    for seg in [*SEGMENTS, "spine", "cervical"]:
        orient[seg] = yaw * Rotation.from_rotvec(0.2 * np.sin(3 * t + len(seg)) * [1, 0, 1])
    for seg, sign in hinge.items():
        orient[seg] = orient[parent_seg[seg]] * Rotation.from_rotvec(
            np.outer(sign * flex, [1.0, 0.0, 0.0])) * wobble
    joints = {"root": np.array([0.1, 0.95, 0.0]) + t * np.array([0.4, 0.0, 0.8])}
    for node, parent, _ in BVH_NODES[1:]:
        assert parent is not None
        joints[node] = joints[parent] + orient[DRIVER[parent]].apply(REST[node])
    base = rigid_result(n_frames=2)
    return SkeletonResult(
        method="llsf", fps=fps, joints={j: joints[j] for j in JOINTS}, offsets=base.offsets,
        bone_lengths={}, orientations={s: r.as_quat(scalar_first=True)
                                       for s, r in orient.items()},
        quality={})


def joints_m(got: dict[str, NDArray[np.float64]], names: tuple[str, ...], per_m: float
             ) -> NDArray[np.float64]:
    return np.stack([got[n] for n in names], axis=1) / per_m


# --------------------------------------------------------------------------- skeleton BVH


@pytest.mark.parametrize("make", [lambda: rigid_result(n_frames=20, seed=7),
                                  lambda: rigid_result(n_frames=40, yaw_turns=1.5),
                                  flexing_result], ids=["random", "turning", "flexing"])
def test_skeleton_bvh_read_by_independent_readers_matches_the_json(
        make: object, reader: str, script_for: Path | None, tmp_path: Path) -> None:
    assert callable(make)
    result: SkeletonResult = make()
    path = tmp_path / "s.bvh"
    write_skeleton_bvh(result, path)
    got = joints_m(read_with(reader, path, script_for), JOINTS, 100.0)
    want = np.stack([result.joints[j] for j in JOINTS], axis=1)
    assert np.linalg.norm(got - want, axis=-1).max() < 1e-3


@pytest.fixture(scope="module")
def estimated(sim15: tuple[SensorRecording, SimulationTruth]) -> SkeletonResult:
    """The default estimate of the example clip, with the protocol's noise and slip: its
    joints lie on a rigid tree of bones (``rigid.rigid_paths``)."""
    return estimate_skeleton(sim15[0], method="auto")


@pytest.fixture(scope="module")
def estimated_llsf(sim15: tuple[SensorRecording, SimulationTruth]) -> SkeletonResult:
    """A plain ``llsf`` estimate of the example clip: its joints are not rigid with its
    orientations (bone lengths vary by millimetres from frame to frame)."""
    return estimate_skeleton(sim15[0], method="llsf")


@pytest.mark.parametrize("source", ["jittered", "llsf"])
def test_a_non_rigid_result_read_by_independent_readers_matches_the_json_exactly(
        source: str, reader: str, script_for: Path | None, tmp_path: Path,
        request: pytest.FixtureRequest) -> None:
    result: SkeletonResult = (rigid_result(n_frames=40, seed=5, jitter=0.004)
                              if source == "jittered"
                              else request.getfixturevalue("estimated_llsf"))
    want = np.stack([result.joints[j] for j in JOINTS], axis=1)
    bones = np.stack([np.linalg.norm(result.joints[n] - result.joints[p], axis=-1)
                      for n, p, _ in BVH_NODES if p is not None], axis=1)
    assert np.ptp(bones, axis=0).max() > 2e-3  # lengths vary: no rigid skeleton fits
    path = tmp_path / "s.bvh"
    write_skeleton_bvh(result, path)  # the default: slip chains where a joint strays
    got = joints_m(read_with(reader, path, script_for), JOINTS, 100.0)
    assert np.linalg.norm(got - want, axis=-1).max() < 1e-5  # the file's rounding only


@pytest.fixture(scope="module")
def estimated_others(sim11: tuple[SensorRecording, SimulationTruth]
                     ) -> dict[str, SkeletonResult]:
    """More estimates with the protocol's noise and slip: the 11-sensor suit, and another
    motion and sensor placement with 15."""
    other, _ = simulate_sensors(example_motion(300, fps=60.0, seed=5), units_m=0.01,
                                n_sensors=15, seed=4)
    return {"11 sensors": estimate_skeleton(sim11[0], method="auto"),
            "other clip": estimate_skeleton(other, method="auto")}


@pytest.mark.parametrize("source", ["estimated", "11 sensors", "other clip"])
def test_the_default_bvh_of_an_estimate_read_by_independent_readers_matches_the_json(
        source: str, reader: str, script_for: Path | None, tmp_path: Path,
        request: pytest.FixtureRequest) -> None:
    # no slip chains: the estimate's joints lie on a rigid tree of bones (rigid.rigid_paths)
    result: SkeletonResult = (request.getfixturevalue("estimated") if source == "estimated"
                              else request.getfixturevalue("estimated_others")[source])
    want = np.stack([result.joints[j] for j in JOINTS], axis=1)
    path = tmp_path / "s.bvh"
    write_skeleton_bvh(result, path)
    got = joints_m(read_with(reader, path, script_for), JOINTS, 100.0)
    assert np.linalg.norm(got - want, axis=-1).max() < 1e-3
    motion = read_bvh(path)
    assert len(motion.names) == len(JOINTS) + 2 + 5  # the clavicles and the end sites


def test_slip_chains_use_rotation_channels_only_and_turn_back_exactly_between_frames(
        ) -> None:
    result = rigid_result(n_frames=40, seed=5, jitter=0.004)
    slipped = skeleton_to_bvh(result)
    rigid = skeleton_to_bvh(result, slip_chains=False)
    assert set(rigid.names) <= set(slipped.names)
    assert slipped.joints() == rigid.joints()  # slip nodes are no joints: not in error lists
    # nor taken for feet by translate's name search (l_ankle_slip_base is named like one)
    feet = find_bvh_feet(slipped)
    assert (feet.left, feet.right) == ("l_ankle", "r_ankle")
    assert len(slipped.names) == len(rigid.names) + 3 * (len(JOINTS) - 1)
    for j, chans in enumerate(slipped.channels):  # what pybvh and bvhtoolbox read alike
        if slipped.parents[j] >= 0 and chans:
            assert len(chans) == 3
            assert all(c.endswith("rotation") for c in chans)
    _, turned = forward_kinematics(slipped.with_values(
        (slipped.values[:-1] + slipped.values[1:]) / 2))
    _, unslipped = forward_kinematics(rigid.with_values(
        (rigid.values[:-1] + rigid.values[1:]) / 2))
    for node in DRIVER:
        gap = (turned[slipped.index(node)].inv() * unslipped[rigid.index(node)]).magnitude()
        assert gap.max() < 1e-9, node


def test_a_slip_chain_reaches_every_residual_and_refuses_none() -> None:
    rng = np.random.default_rng(3)
    residual = rng.normal(scale=0.01, size=(200, 3))
    residual[50] *= 6.0  # one far frame: the links stay within their reach
    chain = slip_chain(residual, np.array([0.05, -0.4, 0.02]))
    base, bend, tip = (Rotation.from_euler(o, chain.values[:, k], degrees=True)
                       for k, o in enumerate(chain.orders))
    reached = (-chain.reach + base.apply(chain.links[0]) + (base * bend).apply(chain.links[1]))
    np.testing.assert_allclose(reached, residual, atol=1e-12)
    assert (base * bend * tip).magnitude().max() < 1e-12
    assert np.abs(np.diff(chain.values, axis=0)).max() < 180.0  # continuous channels
    with pytest.raises(InputError, match="not zero everywhere"):
        slip_chain(np.zeros((5, 3)), np.array([0.0, 1.0, 0.0]))


def half_frame_errors_mm(result: SkeletonResult, order: str | None = None,
                         rest: str = "auto") -> NDArray[np.float64]:
    """Distance (mm, per step and joint) between the BVH posed at half frames, channels
    interpolated linearly as Blender keys them, and the midpoint of the JSON's neighbouring
    frames."""
    motion = skeleton_to_bvh(result, euler_order=order, rest=rest)
    half = motion.with_values((motion.values[:-1] + motion.values[1:]) / 2)
    positions, _ = forward_kinematics(half)
    got = positions[:, [motion.index(j) for j in JOINTS]] / 100.0
    want = np.stack([result.joints[j] for j in JOINTS], axis=1)
    return np.asarray(np.linalg.norm(got - (want[:-1] + want[1:]) / 2, axis=-1) * 1000)


def json_jumps(result: SkeletonResult) -> NDArray[np.bool_]:
    """Steps where a segment of the JSON turns by more than ``JUMP_DEG``."""
    return jump_steps([Rotation.from_quat(q, scalar_first=True)
                       for q in result.orientations.values()])


def half_frame_error_mm(result: SkeletonResult, order: str | None = None,
                        rest: str = "auto") -> float:
    """Largest half-frame error (mm) over the steps that are not jumps in the JSON."""
    errors = half_frame_errors_mm(result, order, rest)
    return float(errors[~json_jumps(result)].max())


@pytest.mark.parametrize("make", [lambda: rigid_result(n_frames=60, seed=2),
                                  lambda: rigid_result(n_frames=60, yaw_turns=1.5),
                                  flexing_result], ids=["random", "turning", "flexing"])
def test_half_frames_interpolated_like_blender_stay_within_10_mm(make: object) -> None:
    assert callable(make)
    result = make()
    assert not json_jumps(result).any()
    assert half_frame_error_mm(result) < 10.0


def test_knee_and_elbow_flexion_is_kept_off_the_middle_axis() -> None:
    result = flexing_result()
    # the clip is one where a single Z-X-Y order fails (flexion on the middle axis)
    assert half_frame_error_mm(result, "ZXY", rest="segment") > 10.0
    motion = skeleton_to_bvh(result, rest="segment")
    local = motion.local_rotations()
    for node in ("l_knee", "r_knee", "l_elbow", "r_elbow"):
        j = motion.index(node)
        assert motion.channels[j][1] != "Xrotation", node
        # no channel moves much more than the joint turns between two frames
        step = np.abs(np.diff(motion.channel_values(j), axis=0)).max(axis=1)
        turn = np.degrees((local[j][:-1].inv() * local[j][1:]).magnitude())
        assert np.all(step <= 2.0 * turn + 0.5), node


@pytest.mark.parametrize("n_frames", [30, 40, 60])
def test_a_rest_rotation_takes_one_euler_order_off_gimbal_lock(n_frames: int) -> None:
    # knees and elbows flexing 0-135 deg about x: on Z-X-Y's middle axis, through its
    # gimbal lock at 90 deg; centred on the mean flexion the channels stay within 70 deg
    result = flexing_result(n_frames)
    assert half_frame_error_mm(result, "ZXY", rest="segment") > 10.0
    assert half_frame_error_mm(result, "ZXY") <= 10.0
    motion = skeleton_to_bvh(result, euler_order="ZXY")
    positions, _ = forward_kinematics(motion)
    got = positions[:, [motion.index(j) for j in JOINTS]] / 100.0
    want = np.stack([result.joints[j] for j in JOINTS], axis=1)
    assert np.abs(got - want).max() < 1e-9  # the keyframes are untouched
    # the rest pose changed: the shank (the ankle's OFFSET in the knee's frame) is bent
    shank = motion.offsets[motion.index("l_ankle")]
    assert abs(shank[1]) < 0.99 * np.linalg.norm(shank)


AXIS = {"X": 0, "Y": 1, "Z": 2}


def through_gimbal_locks(mean: Rotation, miss: NDArray[np.float64], leg: int = 12
                         ) -> Rotation:
    """Swings from ``mean`` through (within ``miss[k]``, rotation vectors) the gimbal lock
    of order k nearest to it, 1.4 times as far, and back, for each of the six orders."""
    ease = (1 - np.cos(np.pi * np.arange(leg) / leg)) / 2
    keys = [mean]
    for k, order in enumerate(EULER_ORDERS):
        last, first = mean.apply(np.eye(3)[AXIS[order[2]]]), np.eye(3)[AXIS[order[0]]]
        first = first if last @ first >= 0 else -first  # lock: the last axis on the first
        arc = np.cross(last, first)
        arc *= 1.4 * np.arccos(np.clip(last @ first, -1, 1)) / np.linalg.norm(arc)
        keys += [Rotation.from_rotvec(miss[k]) * Rotation.from_rotvec(arc) * mean, mean]
    legs = [a * Rotation.from_rotvec(np.outer(ease, (a.inv() * b).as_rotvec()))
            for a, b in itertools.pairwise(keys)]
    return Rotation.concatenate(legs)


def gimbal_lock_result(seed: int, fps: float = 30.0) -> SkeletonResult:
    """A rigid result whose left upper arm, about a mean pose as far from every order's
    well-conditioned region as any (a half turn about the diagonal: each order's middle
    angle is 42 deg there), passes by the gimbal lock of every Euler order."""
    rng = np.random.default_rng(seed)
    mean = (Rotation.from_rotvec(rng.normal(scale=0.1, size=3))
            * Rotation.from_rotvec(np.pi * np.ones(3) / np.sqrt(3)))
    miss = rng.normal(size=(6, 3))  # 3 deg off each lock, in a random direction
    arm = through_gimbal_locks(mean, np.radians(3.0) * miss / np.linalg.norm(miss, axis=1,
                                                                             keepdims=True))
    t = np.arange(len(arm))[:, None] / fps
    orient = {seg: Rotation.from_rotvec(0.1 * np.sin(3 * t + len(seg)) * [1, 0, 1])
              for seg in [*SEGMENTS, "spine", "cervical"]}
    orient["l_upperarm"] = orient["chest"] * arm
    orient["l_forearm"] = orient["l_hand"] = orient["l_upperarm"] * Rotation.from_rotvec(
        np.outer(0.3 * np.sin(2 * t[:, 0]), [1.0, 0.0, 0.0]))
    return result_of(orient, fps)


def result_of(orient: dict[str, Rotation], fps: float) -> SkeletonResult:
    """A rigid result with these segment orientations (rest vectors of ``REST``)."""
    n_frames = len(orient["pelvis"])
    joints = {"root": np.array([0.1, 0.95, 0.0])
              + np.linspace(0, 1, n_frames)[:, None] * np.array([0.4, 0.0, 0.8])}
    for node, parent, _ in BVH_NODES[1:]:
        assert parent is not None
        joints[node] = joints[parent] + orient[DRIVER[parent]].apply(REST[node])
    return SkeletonResult(
        method="llsf", fps=fps, joints={j: joints[j] for j in JOINTS},
        offsets=rigid_result(n_frames=2).offsets, bone_lengths={},
        orientations={s: r.as_quat(scalar_first=True) for s, r in orient.items()},
        quality={})


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_rest_rotations_play_back_every_order_past_its_gimbal_lock(seed: int) -> None:
    result = gimbal_lock_result(seed)
    centred = {o: half_frame_error_mm(result, o) for o in EULER_ORDERS}
    assert max(centred.values()) <= 10.0, centred
    assert half_frame_error_mm(result) <= 10.0
    # in the segment frames at least one order goes astray near its lock
    assert max(half_frame_error_mm(result, o, rest="segment") for o in EULER_ORDERS) > 10.0


def test_a_t_pose_frame_before_the_take_is_a_reported_jump() -> None:
    take = flexing_result(40)
    orient = {s: Rotation.from_quat(q, scalar_first=True) for s, q in take.orientations.items()}
    # frame 0: every segment in its rest frame (a T-pose-like calibration frame), then the take
    # from a pelvis turned half way round
    turned = {s: Rotation.concatenate([Rotation.identity(1),
                                       Rotation.from_euler("y", [150.0], degrees=True) * r])
              for s, r in orient.items()}
    result = result_of(turned, take.fps)
    jumps = json_jumps(result)
    assert jumps.tolist() == [True] + [False] * 39
    errors = half_frame_errors_mm(result)
    assert errors[0].max() > 100.0  # no interpolation of rotations follows a 150 deg jump
    assert errors[1:].max() <= 10.0
    # the jump does not steer the writer: the take plays back as well as without that frame
    alone = result_of({s: r[1:] for s, r in turned.items()}, take.fps)
    assert errors[1:].max() <= half_frame_errors_mm(alone).max() + 1.0
    assert JUMP_DEG == 60.0


def sequential_continuous_euler(angles: NDArray[np.float64]) -> NDArray[np.float64]:
    """Frame by frame: of the triple and its twin, wrapped, the one nearest the previous."""
    twin = angles + np.array([180.0, 0.0, 180.0])
    twin[..., 1] = 180.0 - angles[..., 1]
    out = angles.copy()
    for i in range(1, len(angles)):
        a = angles[i] - 360.0 * np.round((angles[i] - out[i - 1]) / 360.0)
        b = twin[i] - 360.0 * np.round((twin[i] - out[i - 1]) / 360.0)
        nearer = np.abs(b - out[i - 1]).sum(axis=-1) < np.abs(a - out[i - 1]).sum(axis=-1)
        out[i] = np.where(nearer[..., None], b, a)
    return out


@pytest.mark.parametrize("order", ["ZXY", "YZX"])
def test_vectorised_continuous_euler_matches_frame_by_frame(order: str) -> None:
    rng = np.random.default_rng(5)
    # random walks through the whole sphere, gimbal lock included
    walk = np.cumsum(rng.normal(scale=0.25, size=(400, 5, 3)), axis=0)
    angles = Rotation.from_rotvec(walk.reshape(-1, 3)).as_euler(order, degrees=True)
    angles = angles.reshape(400, 5, 3)
    out = continuous_euler(angles)
    np.testing.assert_allclose(out, sequential_continuous_euler(angles), atol=1e-9)
    assert np.abs(np.diff(out, axis=0)).max() <= 180.0
    back = Rotation.from_euler(order, out.reshape(-1, 3), degrees=True)
    np.testing.assert_allclose(
        (back.inv() * Rotation.from_rotvec(walk.reshape(-1, 3))).magnitude(), 0.0, atol=1e-9)


def test_continuous_euler_of_slow_motion_with_jumps_matches_frame_by_frame() -> None:
    # small steps (the twin is never nearer: the fast path) near gimbal lock, and a few
    # jumps of up to 180 degrees (measured four ways)
    rng = np.random.default_rng(11)
    steps = rng.normal(scale=0.01, size=(3000, 3))
    steps[rng.choice(3000, 12, replace=False)] = rng.normal(scale=1.5, size=(12, 3))
    walk = np.cumsum(steps, axis=0)
    walk[:, 0] += 1.55  # about x: Z-X-Y's middle angle near 90 degrees
    angles = Rotation.from_rotvec(walk).as_euler("ZXY", degrees=True)
    assert np.abs(angles[:, 1]).max() > 85.0
    np.testing.assert_allclose(continuous_euler(angles), sequential_continuous_euler(angles),
                               atol=1e-9)


def test_continuous_euler_of_small_steps_is_the_twin_scans_bit_for_bit(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # steps under 30 degrees a channel (the short path, no twin scan) near gimbal lock and
    # through the outer angles' wraps: the same bits as the scan of every step
    rng = np.random.default_rng(12)
    walk = np.cumsum(rng.normal(scale=0.005, size=(5000, 3)), axis=0)
    walk[:, 0] += 1.3  # middle angle up to 85 degrees
    angles = Rotation.from_rotvec(walk).as_euler("ZXY", degrees=True)
    step = np.diff(angles, axis=0)
    assert np.abs(step).max() > 300.0  # wraps of the outer angles
    assert np.abs(angles[:, 1]).max() > 80.0  # near gimbal lock
    assert np.abs(step - 360.0 * np.round(step / 360.0)).max() < 30.0  # else no short path
    short = continuous_euler(angles)
    monkeypatch.setattr(bvh_module, "SMALL_STEP_DEG", 0.0)  # every step scanned
    scanned = continuous_euler(angles)
    assert short.tobytes() == scanned.tobytes()
    np.testing.assert_allclose(short, sequential_continuous_euler(angles), atol=1e-9)


@pytest.mark.parametrize("order", ["ZXY", "ZYX", "YXZ", "YZX", "XYZ", "XZY"])
def test_euler_angle_rows_are_scipys_angles_up_to_whole_turns(order: str) -> None:
    rng = np.random.default_rng(3)
    middle = np.concatenate([rng.uniform(-90.0, 90.0, 300),  # anywhere, at and next to lock
                             [90.0, -90.0] * 50, 90.0 - 10.0 ** rng.uniform(-9, -1, 100)])
    outer = rng.uniform(-180.0, 180.0, (len(middle), 2))
    rotations = Rotation.from_euler(order, np.column_stack([outer[:, 0], middle, outer[:, 1]]),
                                    degrees=True)
    expected = euler_degrees(rotations, order)
    rows = euler_angle_rows(order, np.ascontiguousarray(rotations.as_quat().T))
    assert rows.shape == (3, len(middle))
    off = rows.T - expected
    np.testing.assert_allclose(off - 360.0 * np.round(off / 360.0), 0.0, atol=1e-5)
    assert np.abs(rows).max() <= 360.0
    # away from lock the arcsine loses nothing that matters
    regular = np.abs(np.abs(expected[:, 1]) - 90.0) > 1.0
    np.testing.assert_allclose(rows.T[regular] - expected[regular]
                               - 360.0 * np.round((rows.T[regular] - expected[regular]) / 360.0),
                               0.0, atol=1e-9)


def test_a_long_takes_channels_are_each_nodes_continuous_euler_angles() -> None:
    # from threads.MIN_FRAMES frames a second thread writes the channels of chosen nodes
    rng = np.random.default_rng(8)
    walks = [Rotation.from_rotvec(np.cumsum(rng.normal(scale=0.02, size=(24_000, 3)), axis=0))
             for _ in range(3)]
    channels, values = euler_channels(walks)
    assert values.shape == (24_000, 3, 3)
    for n, walk in enumerate(walks):
        order = "".join(c[0] for c in channels[n])
        np.testing.assert_allclose(values[:, n], continuous_euler(euler_degrees(walk, order)),
                                   rtol=0, atol=1e-9)


def test_compose_quaternions_is_scipys_product_bit_for_bit() -> None:
    p, q = Rotation.random(500, rng=1), Rotation.random(500, rng=2)
    assert np.array_equal(compose_quaternions(p.inv().as_quat(), q.as_quat()),
                          (p.inv() * q).as_quat())
    assert np.array_equal(compose_quaternions(p.as_quat()[:1], q.as_quat()),
                          (p[:1] * q).as_quat())


def test_the_segment_rest_pose_keeps_segment_frames_and_a_bad_rest_is_refused() -> None:
    result = flexing_result(30)
    auto, segment = skeleton_to_bvh(result), skeleton_to_bvh(result, rest="segment")
    ankle = segment.index("l_ankle")
    np.testing.assert_allclose(segment.offsets[ankle], np.asarray(REST["l_ankle"]) * 100.0,
                               atol=1e-9)
    assert not np.allclose(auto.offsets[ankle], segment.offsets[ankle], atol=1.0)
    with pytest.raises(InputError, match="rest must be one of") as err:
        skeleton_to_bvh(result, rest="tpose")
    assert err.value.field == "rest"


def test_a_swinging_shoulder_gets_the_order_players_interpolate_best() -> None:
    # a shoulder swinging 2x the example's range at 30 fps: the channel-swing term outweighed
    # the half-frame error 50:1 and picked X-Z-Y, 1.4 deg off at half frames where Z-X-Y
    # stays within 0.4 deg
    motion = example_motion(120, fps=30.0, seed=1, scale=2.0)
    rotation = motion.local_rotations()[motion.index("LeftShoulder")]
    channels, values = euler_channels([rotation])
    chosen = "".join(c[0] for c in channels[0])
    errors = {}
    for order in EULER_ORDERS:
        angles = continuous_euler(rotation.as_euler(order, degrees=True)[:, None, None])
        errors[order] = float(np.sum(half_frame_error(rotation, angles[:, 0, 0], order) ** 2))
    best = min(errors.values())
    assert errors[chosen] <= 1.5 * best, (chosen, errors)
    assert half_frame_error(rotation, values[:, 0], chosen).max() < 1.0


# --------------------------------------------------------------------------- translation BVHs


def test_point_joint_bvh_of_a_csv_input_read_by_independent_readers(
        reader: str, script_for: Path | None, tmp_path: Path) -> None:
    rec, _, _ = simulate_walker(fps=60)
    csv = tmp_path / "walk.csv"
    write_kinematics_csv(rec, csv)
    rec = read_kinematics(csv)
    result = estimate_translation(rec)
    path = tmp_path / "walk.bvh"
    write_translation(result, rec, path, format="bvh")
    got = joints_m(read_with(reader, path, script_for), rec.joints, 100.0)
    assert np.linalg.norm(got - result.positions, axis=-1).max() < 1e-3
    # readers that refuse position channels below the root (pybvh) can read it too
    motion = read_bvh(path)
    assert all(not c.endswith("position") for chans in motion.channels[1:] for c in chans)
    np.testing.assert_array_equal(motion.offsets[0], 0.0)


def test_point_joint_bvh_of_an_mvnx_input_read_by_independent_readers(
        reader: str, script_for: Path | None, tmp_path: Path) -> None:
    _, truth, _ = simulate_walker(fps=60)
    free = {foot: np.zeros_like(truth.positions[:, 0]) for foot in ("LeftFoot", "RightFoot")}
    write_mvnx(tmp_path / "w.mvnx", truth.positions, free, None, 60.0)
    rec = read_kinematics(tmp_path / "w.mvnx")
    result = estimate_translation(rec)
    path = tmp_path / "w.bvh"
    write_translation(result, rec, path, format="bvh")
    got = joints_m(read_with(reader, path, script_for), rec.joints, 100.0)
    assert np.linalg.norm(got - result.positions, axis=-1).max() < 1e-3


def test_point_joint_bvh_of_a_whole_body(reader: str, script_for: Path | None,
                                         tmp_path: Path) -> None:
    clip = example_motion(90, seed=4)
    positions, _ = forward_kinematics(clip)
    names = tuple(n for n in clip.names if not n.endswith("_end"))
    pos = positions[:, [clip.index(n) for n in names]]
    motion = point_joint_bvh(names, pos, 0, clip.frame_time)
    write_bvh(motion, tmp_path / "p.bvh")
    got = joints_m(read_with(reader, tmp_path / "p.bvh", script_for), names, 1.0)
    assert np.abs(got - pos).max() < 1e-3  # cm
    # joints of one rigid segment hang from its first joint, not from each other
    back = read_bvh(tmp_path / "p.bvh")
    assert len(back.names) <= 2 * len(names) + 2


def bandai_style_motion(n_frames: int = 120, fps: float = 60.0) -> BvhMotion:
    """A static dummy root over moving hips; every joint with position channels equal to
    its OFFSET (as the Bandai-Namco files have them), feet turning."""
    t = np.arange(n_frames) / fps
    six = ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
    names = ("joint_Root", "Hips", "LeftFoot", "LeftFoot_end", "RightFoot", "RightFoot_end")
    parents = (-1, 0, 1, 2, 1, 4)
    offsets = np.array([[0, 0, 0], [-11, 91, 32], [10, -80, 0], [0, -7, 15],
                        [-10, -80, 0], [0, -7, 15]], dtype=float)
    channels = (six, six, six, (), six, ())
    values = np.zeros((n_frames, 24))
    values[:, 6:9] = np.column_stack([50 * t, 90 + 2 * np.sin(4 * t), 10 * t])
    values[:, 11] = 30 * np.sin(t)
    values[:, 12:15] = offsets[2]
    values[:, 16] = 20 * np.sin(3 * t)
    values[:, 18:21] = offsets[4]
    values[:, 22] = -20 * np.sin(3 * t)
    return BvhMotion(names, parents, offsets, channels, 1.0 / fps, values)


def test_translated_bvh_of_a_bvh_input_read_by_independent_readers(
        reader: str, script_for: Path | None, tmp_path: Path) -> None:
    write_bvh(bandai_style_motion(), tmp_path / "in.bvh")
    n = bandai_style_motion().n_frames
    acc = np.tile([0.0, 1.0, 0.0, 0.0, 1.0, 0.0], (n, 1))
    np.savetxt(tmp_path / "acc.csv", np.column_stack([np.arange(n) / 60.0, acc]),
               delimiter=",", comments="", fmt="%.6f",
               header="time,LeftFoot.ax,LeftFoot.ay,LeftFoot.az,RightFoot.ax,RightFoot.ay,"
                      "RightFoot.az")
    rec = read_kinematics(tmp_path / "in.bvh", accelerations=tmp_path / "acc.csv",
                          acceleration_units="g")
    result = estimate_translation(rec)
    path = tmp_path / "out.bvh"
    write_translation(result, rec, path, format="bvh")
    # the static dummy root stays where the file has it; the hips carry the path
    named = tuple(j for j in rec.joints if not j.endswith("_end") and j != "joint_Root")
    got = joints_m(read_with(reader, path, script_for), named, 100.0)
    want = result.positions[:, [rec.index(j) for j in named]]
    assert np.linalg.norm(got - want, axis=-1).max() < 1e-3


def test_folding_position_channels_keeps_positions_and_drops_constant_channels() -> None:
    motion = bandai_style_motion(30)
    folded = fold_position_channels(motion)
    before, _ = forward_kinematics(motion)
    after, _ = forward_kinematics(folded)
    np.testing.assert_allclose(after, before, atol=1e-9)
    assert folded.channels[1] == motion.channels[1]  # the hips move: kept, OFFSET zero
    np.testing.assert_array_equal(folded.offsets[1], 0.0)
    assert folded.channels[2] == ("Zrotation", "Xrotation", "Yrotation")
    np.testing.assert_allclose(folded.offsets[2], motion.offsets[2])


def test_a_single_euler_order_can_be_asked_for_and_a_bad_one_is_refused() -> None:
    result = rigid_result(n_frames=10, seed=1)
    motion = skeleton_to_bvh(result, euler_order="XZY")
    assert {c[3:] if j == 0 else c for j, c in enumerate(motion.channels) if c} == {
        ("Xrotation", "Zrotation", "Yrotation")}
    with pytest.raises(InputError, match="Euler order must be one of") as err:
        skeleton_to_bvh(result, euler_order="XYX")
    assert err.value.field == "euler_order"


def test_half_frames_of_an_estimated_skeleton_stay_within_10_mm(
        sim15: tuple[SensorRecording, SimulationTruth]) -> None:
    rec, _ = sim15
    result = estimate_skeleton(rec, method="auto")
    assert half_frame_error_mm(result) < 10.0


def test_a_long_takes_bvh_built_on_threads_is_the_text_of_one_thread(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # from threads.MIN_FRAMES frames the node frames, links and Euler choices run per node
    # on the worker threads, children waiting for their parents' rest rotations
    from bonefit.estimation import threads

    def bvh_text(motion: BvhMotion) -> str:
        out = io.StringIO()
        write_bvh(motion, out, precision=6)
        return out.getvalue()

    result = flexing_result(600, fps=240.0)
    for module in (bvh_module, threads):
        monkeypatch.setattr(module, "MIN_FRAMES", 10**9)
    one = bvh_text(skeleton_to_bvh(result))
    for module in (bvh_module, threads):
        monkeypatch.setattr(module, "MIN_FRAMES", 1)
        monkeypatch.setattr(module, "workers", lambda: 2)
    assert bvh_text(skeleton_to_bvh(result)) == one


def test_rest_euler_channels_refuses_a_parent_after_its_node() -> None:
    turns = [Rotation.random(5, rng=k) for k in range(2)]
    with pytest.raises(InputError, match="parent must come before") as err:
        rest_euler_channels((1, -1), turns)
    assert err.value.field == "parents"
