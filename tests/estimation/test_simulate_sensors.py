"""Simulated sensor recordings: exact truth, noise levels, sensor sets, BVH name maps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bonefit.estimation.bvh import BvhMotion, read_bvh
from bonefit.estimation.errors import InputError
from bonefit.estimation.model import JOINT_SEGMENTS, JOINTS, REDUCED_SEGMENTS, SEGMENTS
from bonefit.estimation.recording import SensorRecording
from bonefit.estimation.simulate.sensors import (
    SimulationTruth,
    detect_skeleton,
    example_motion,
    simulate_sensors,
)

Sim = tuple[SensorRecording, SimulationTruth]
DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "motions"


def local_paths(rec: SensorRecording, truth: SimulationTruth, joint: str,
                sensor: str) -> np.ndarray:
    k = rec.index(sensor)
    rot = Rotation.from_quat(rec.quaternions[:, k], scalar_first=True)
    return np.asarray(rot.inv().apply(truth.joints[joint] - rec.positions[:, k]))


def test_clean_joints_are_fixed_in_both_sensor_frames(clean15: Sim) -> None:
    rec, truth = clean15
    assert rec.sensors == SEGMENTS
    assert set(truth.joints) == set(JOINTS)
    for joint, (a, b) in JOINT_SEGMENTS.items():
        for sensor in (a, b):
            assert np.ptp(local_paths(rec, truth, joint, sensor), axis=0).max() < 1e-9


def test_sensors_sit_off_the_bone(clean15: Sim) -> None:
    rec, truth = clean15
    for seg in ("l_thigh", "r_upperarm", "l_shank"):
        start, end = {"l_thigh": ("l_hip", "l_knee"), "r_upperarm": ("r_shoulder", "r_elbow"),
                      "l_shank": ("l_knee", "l_ankle")}[seg]
        a, b = truth.joints[start][0], truth.joints[end][0]
        p = rec.positions[0, rec.index(seg)]
        u = (b - a) / np.linalg.norm(b - a)
        off = np.linalg.norm((p - a) - ((p - a) @ u) * u)
        assert 0.03 - 1e-9 <= off <= 0.07 + 1e-9


def test_noise_slip_and_drops(clean15: Sim, sim15: Sim) -> None:
    clean, _ = clean15
    noisy, _ = sim15
    dropped = ~noisy.valid()
    assert 0.005 < dropped.mean() < 0.02
    assert not (~clean.valid()).any()
    ok = ~dropped
    diff = noisy.positions[ok] - clean.positions[ok]
    # white 2 mm per axis plus slow slip of 5 mm RMS
    assert 0.004 < np.sqrt(np.mean(np.sum(diff**2, axis=-1))) < 0.009
    white = np.diff(noisy.positions - clean.positions, axis=0)
    white = white[np.isfinite(white).all(axis=-1)]
    assert abs(white.std() / np.sqrt(2) - 0.002) < 0.0003
    r_noisy = Rotation.from_quat(noisy.quaternions[ok], scalar_first=True)
    r_clean = Rotation.from_quat(clean.quaternions[ok], scalar_first=True)
    angle = np.degrees((r_clean.inv() * r_noisy).magnitude())
    assert 0.5 < np.sqrt(np.mean(angle**2)) < 1.2  # 0.5° per axis: RMS 0.87°


def test_reduced_suit_shares_sensors(sim15: Sim, sim11: Sim) -> None:
    _, t15 = sim15
    reduced, t11 = sim11
    assert reduced.sensors == REDUCED_SEGMENTS
    for seg in REDUCED_SEGMENTS:
        assert np.allclose(t15.sensor_local[seg], t11.sensor_local[seg])
    for j in JOINTS:
        assert np.allclose(t15.joints[j], t11.joints[j])


def test_truth_root_and_chest(clean15: Sim) -> None:
    _, truth = clean15
    j = truth.joints
    assert np.allclose(j["root"], (j["waist"] + j["l_hip"] + j["r_hip"]) / 3)
    d = np.linalg.norm(j["chest"] - j["waist"], axis=1)
    assert np.ptp(d) < 1e-9  # at the constant distance α from W


def test_fps_override_and_segments_argument(example_clip: BvhMotion) -> None:
    rec, _ = simulate_sensors(example_clip, units_m=0.01, fps=30.0,
                              segments=("pelvis", "l_thigh"))
    assert rec.fps == 30.0
    assert rec.sensors == ("pelvis", "l_thigh")
    assert np.isclose(rec.time[1], 1 / 30)
    with pytest.raises(InputError, match="n_sensors"):
        simulate_sensors(example_clip, units_m=0.01, n_sensors=12)
    with pytest.raises(InputError, match="knee"):
        simulate_sensors(example_clip, units_m=0.01, segments=("knee",))


def test_unknown_skeleton() -> None:
    motion = example_motion(20)
    renamed = BvhMotion(tuple(f"x{n}" for n in motion.names), motion.parents, motion.offsets,
                        motion.channels, motion.frame_time, motion.values)
    with pytest.raises(InputError, match="unknown BVH skeleton"):
        detect_skeleton(renamed)


@pytest.mark.skipif(not DATA.is_dir(), reason="shared motion data not present")
@pytest.mark.parametrize(("clip", "units", "name"), [
    ("cmu_bvh11/131_03.bvh", 0.05644, "cmu_bvh11"),
    ("cmu_fairmotion/01_01.bvh", 0.05644, "cmu_fairmotion"),
    ("cmu_acrnn/salsa/01.bvh", 0.01, "cmu_acrnn"),
    ("bandai_namco/dataset-1_walk_normal_001.bvh", 0.01, "bandai_namco"),
])
def test_real_clips_give_exact_rigid_truth(clip: str, units: float, name: str) -> None:
    motion = read_bvh(DATA / clip)
    assert detect_skeleton(motion) == name
    rec, truth = simulate_sensors(motion, units_m=units, position_noise_m=0.0,
                                  orientation_noise_deg=0.0, slip_m=0.0, drop_fraction=0.0)
    for joint, (a, b) in JOINT_SEGMENTS.items():
        for sensor in (a, b):
            assert np.ptp(local_paths(rec, truth, joint, sensor), axis=0).max() < 1e-9
    for seg in ("l_thigh", "l_shank", "l_upperarm", "l_forearm"):
        assert 0.15 < truth.bone_lengths[seg] < 0.55, seg
