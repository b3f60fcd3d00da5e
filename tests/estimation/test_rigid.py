"""The rigid step: joint paths held on a rigid tree of bones, moved the least where the data
locate them best (issue 17 §5)."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from bonefit.estimation import skeleton as skeleton_module
from bonefit.estimation.model import BONES, JOINTS, LIMBS
from bonefit.estimation.recording import SensorRecording
from bonefit.estimation.rigid import (
    PELVIS,
    clavicle_heights,
    clavicle_points,
    hold_distances,
    rigid_paths,
)
from bonefit.estimation.simulate.sensors import SimulationTruth, example_motion, simulate_sensors
from bonefit.estimation.skeleton import estimate_skeleton
from tests.estimation.test_io_skeleton import rigid_result

LIMB_BONES = {seg: BONES[seg] for limb in LIMBS.values() for seg in limb.segments[:2]}


def distances(points: NDArray[np.float64], pairs: list[tuple[int, int]]) -> NDArray[np.float64]:
    return np.stack([np.linalg.norm(points[:, j] - points[:, i], axis=-1) for i, j in pairs],
                    axis=1)


def test_held_distances_are_met_and_anchors_stay() -> None:
    rng = np.random.default_rng(1)
    # bones of 0.3, 0.28, 0.25 m pointing anywhere, the joints off by up to centimetres
    steps = rng.normal(size=(500, 3, 3))
    steps *= np.array([0.3, 0.28, 0.25])[:, None] / np.linalg.norm(steps, axis=-1,
                                                                    keepdims=True)
    chain = np.concatenate([np.zeros((500, 1, 3)), np.cumsum(steps, axis=1)], axis=1)
    chain[:, 1:] += rng.normal(scale=[[0.002], [0.02], [0.003]], size=(500, 3, 3))
    pairs = [(0, 1), (1, 2), (2, 3)]
    lengths = np.array([0.3, 0.28, 0.25])
    held = hold_distances(chain, np.array([0.0, 0.002, 0.05, 0.003]), pairs, lengths)
    np.testing.assert_allclose(distances(held, pairs), np.broadcast_to(lengths, (500, 3)),
                               atol=2e-6)
    np.testing.assert_array_equal(held[:, 0], chain[:, 0])
    # the poorly located joint takes most of the correction
    moved = np.linalg.norm(held - chain, axis=-1).mean(axis=0)
    assert moved[2] > 5 * max(moved[1], moved[3])


def test_a_triangle_keeps_its_shape() -> None:
    rng = np.random.default_rng(2)
    shape = np.array([[0.0, 0.1, 0.0], [0.09, -0.05, 0.0], [-0.09, -0.05, 0.01]])
    turns = Rotation.from_rotvec(rng.normal(size=(300, 3)))
    points = np.stack([turns.apply(p) for p in shape], axis=1)
    noisy = points + rng.normal(scale=0.003, size=points.shape)
    pairs = [(0, 1), (0, 2), (1, 2)]
    true = distances(points, pairs)[0]
    held = hold_distances(noisy, np.full(3, 0.003), pairs, true)
    np.testing.assert_allclose(distances(held, pairs), np.broadcast_to(true, (300, 3)),
                               atol=2e-6)
    # the least movement onto the true shape: closer to the truth than the noisy points
    assert (np.linalg.norm(held - points, axis=-1).mean()
            < np.linalg.norm(noisy - points, axis=-1).mean())


def noisy_take(seed: int) -> tuple[dict[str, NDArray[np.float64]],
                                   dict[str, NDArray[np.float64]], dict[str, float]]:
    """A rigid skeleton's true joints, the same with per-frame noise (2 mm on the joints the
    data locate well, 10 mm on knees and elbows, as hinges are) and those sds. ``root`` is
    the centroid of the noisy waist and hips, ``chest`` moves with the noisy waist (eq. 1
    keeps |chest - waist|)."""
    truth = rigid_result(n_frames=400, seed=seed).joints
    rng = np.random.default_rng(seed + 100)
    sd = {j: 0.010 if j.endswith(("knee", "elbow")) else 0.002 for j in JOINTS
          if j not in ("root", "chest")}
    noisy = {j: truth[j] + rng.normal(scale=s, size=truth[j].shape) for j, s in sd.items()}
    noisy["root"] = sum(noisy[j] for j in PELVIS) / 3.0
    noisy["chest"] = truth["chest"] + noisy["waist"] - truth["waist"]
    return dict(truth), noisy, sd


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_rigid_step_brings_a_noisy_rigid_take_closer_to_its_truth(seed: int) -> None:
    truth, noisy, sd = noisy_take(seed)
    held = rigid_paths(noisy, sd)

    def error(paths: dict[str, NDArray[np.float64]], joint: str) -> float:
        return float(np.linalg.norm(paths[joint] - truth[joint], axis=-1).mean())

    before = {j: error(noisy, j) for j in JOINTS}
    after = {j: error(held, j) for j in JOINTS}
    assert np.mean(list(after.values())) < 0.8 * np.mean(list(before.values()))
    for joint in ("l_knee", "r_knee", "l_elbow", "r_elbow"):
        assert after[joint] < 0.8 * before[joint], joint
    for joint in JOINTS:
        assert after[joint] < before[joint] + 0.0002, joint  # none worse by 0.2 mm
    # every bone of the tree keeps its length, the pelvis its shape
    for seg, (a, b) in LIMB_BONES.items():
        length = np.linalg.norm(held[b] - held[a], axis=-1)
        assert np.ptp(length) < 2e-6, seg
    np.testing.assert_allclose(held["root"], sum(held[j] for j in PELVIS) / 3.0, atol=1e-12)
    heights = clavicle_heights(held["chest"], held["neck"], held["l_shoulder"],
                               held["r_shoulder"])
    for point, side in zip(clavicle_points(held["chest"], held["neck"], heights), "lr",
                           strict=True):
        assert np.ptp(np.linalg.norm(held[f"{side}_shoulder"] - point, axis=-1)) < 2e-6


@pytest.mark.parametrize(("n_sensors", "seed"), [(15, 11), (11, 11), (15, 4)])
def test_the_rigid_step_does_not_worsen_an_estimate(
        n_sensors: int, seed: int, monkeypatch: pytest.MonkeyPatch) -> None:
    rec, truth = simulate_sensors(example_motion(300, fps=60.0, seed=seed % 7),
                                  units_m=0.01, n_sensors=n_sensors, seed=seed)
    rigid = estimate_skeleton(rec, method="auto")
    monkeypatch.setattr(skeleton_module, "rigid_paths", lambda joints, sd: dict(joints))
    loose = estimate_skeleton(rec, method="auto")

    def error(result_joints: dict[str, NDArray[np.float64]], joint: str) -> float:
        return float(np.linalg.norm(result_joints[joint] - truth.joints[joint],
                                    axis=-1).mean())

    before = np.mean([error(dict(loose.joints), j) for j in JOINTS])
    after = np.mean([error(dict(rigid.joints), j) for j in JOINTS])
    assert after <= before + 1e-4, (after, before)
    for seg, (a, b) in LIMB_BONES.items():
        length = np.linalg.norm(rigid.joints[b] - rigid.joints[a], axis=-1)
        assert np.ptp(length) < 2e-6, seg
        assert rigid.bone_lengths[seg] == pytest.approx(float(length.mean()), abs=1e-12)


def test_only_auto_is_held_rigid(sim15: tuple[SensorRecording, SimulationTruth]) -> None:
    # the papers' methods stay as published
    result = estimate_skeleton(sim15[0], method="llsf")
    length = np.linalg.norm(result.joints["l_elbow"] - result.joints["l_shoulder"], axis=-1)
    assert np.ptp(length) > 1e-4
