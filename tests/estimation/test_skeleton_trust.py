"""Issue 20 §2–4 on small simulated recordings with exact truth: the default does no harm
where the data locate a joint, the simulator's knees and elbows sit off their neighbours'
line, and "data" labels only what the data locate."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bonefit.estimation.joints import JointFit
from bonefit.estimation.model import JOINTS
from bonefit.estimation.simulate.sensors import HingeRig, example_motion, simulate_sensors
from bonefit.estimation.skeleton import (
    SHARED_SD_FACTOR,
    PairPoses,
    SharedPriors,
    estimate_skeleton,
    shared_fit,
)
from bonefit.estimation.slip import SlipFit

HINGES = ("l_knee", "r_knee", "l_elbow", "r_elbow")


def error_mm(joints: Mapping[str, np.ndarray], truth: Mapping[str, np.ndarray],
             joint: str) -> float:
    return float(np.linalg.norm(joints[joint] - truth[joint], axis=1).mean() * 1000.0)


@pytest.mark.parametrize("seed", [1, 2])
def test_auto_does_no_harm_where_the_data_locate_the_joint(seed: int) -> None:
    # little noise, no slip, 30 fps: the shared slip model (its low-passed regressors) and
    # the wrists' hinge rules used to cost up to 0.74 mm against plain llsf on joints the
    # data locate to 1-2 mm
    rec, truth = simulate_sensors(example_motion(180, fps=30.0, seed=seed), units_m=0.01,
                                  seed=seed, position_noise_m=0.001,
                                  orientation_noise_deg=0.3, slip_m=0.0)
    auto = estimate_skeleton(rec)
    llsf = estimate_skeleton(rec, method="llsf")
    good = [j for j in JOINTS if auto.quality[j].get("data_sd_m", math.inf) <= 0.002]
    assert len(good) >= 6
    for joint in good:
        assert error_mm(auto.joints, truth.joints, joint) <= \
            error_mm(llsf.joints, truth.joints, joint) + 0.5, joint


def test_the_shared_model_does_not_override_what_the_joint_own_data_locate() -> None:
    # a torso joint whose shared-model centre sits 5.4 posterior sds off the truth (the
    # benchmark's salsa shoulders and hips: the model's sd is optimistic) while its own
    # plain fit locates it to about 1 mm: the two readings are combined by their precisions
    # (the model's taken SHARED_SD_FACTOR² smaller; its residual is zero here, so nothing
    # more), centres and paths alike, so the good data are not overridden; where the own
    # data are poor (20 mm) the model's centre and path stay
    n = 50
    eye = Rotation.from_quat(np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)))
    zeros, ok = np.zeros((n, 3)), np.ones(n, dtype=np.bool_)
    truth = np.array([0.02, -0.1, 0.05])
    model = truth + np.array([0.004, -0.003, 0.002])
    shared = SlipFit(slip={}, centres=np.tile(model, (1, 2, 1)),
                     covariances=(1e-3) ** 2 * np.eye(6)[None], corrected=(False,),
                     signal_share=(1.0,))
    fit = JointFit(local_a=model, local_b=model, positions=zeros, residuals=np.zeros(n),
                   quality={})
    poses = PairPoses(zeros, eye, zeros, eye, ok, ok)
    alone, _ = shared_fit(fit, shared, 0, poses, SharedPriors())
    assert np.linalg.norm(alone.local_a - truth) > 0.005
    own = np.tile(truth + np.array([0.0003, 0.0, -0.0002]), 2)
    own_fit = replace(fit, positions=np.tile(own[:3], (n, 1)))  # its path on raw positions
    for own_sd, bound in ((0.0012, 0.0016), (0.02, None)):
        found, cov_a = shared_fit(own_fit, shared, 0, poses,
                                  SharedPriors(own=(own, np.eye(6) / own_sd**2)))
        w_model = 1.0 / (SHARED_SD_FACTOR * 1e-3) ** 2
        w_own = 1.0 / own_sd**2
        expected = (w_model * model + w_own * own[:3]) / (w_model + w_own)
        np.testing.assert_allclose(found.local_a, expected, atol=1e-9)
        np.testing.assert_allclose(found.local_b, expected, atol=1e-9)
        np.testing.assert_allclose(cov_a, np.eye(3) / (w_model + w_own), rtol=1e-6)
        share = w_own / (w_model + w_own)  # the own reading's share of the precision
        np.testing.assert_allclose(found.positions,
                                   np.tile((1 - share) * expected + share * own[:3], (n, 1)),
                                   atol=1e-9)
        if bound is not None:  # the good own data decide
            assert np.linalg.norm(found.local_a - truth) < bound
        else:  # poor own data barely move the model's centre
            assert np.linalg.norm(found.local_a - model) < 0.0002


def test_the_rig_moves_the_middle_joints_off_the_line() -> None:
    motion = example_motion(120, fps=60.0, seed=4)
    rig = HingeRig(offset_range_m=(0.01, 0.01), seed=4)
    _, plain = simulate_sensors(motion, units_m=0.01, seed=4)
    _, real = simulate_sensors(motion, units_m=0.01, seed=4, rig=rig)
    for joint in HINGES:
        moved = np.linalg.norm(real.joints[joint] - plain.joints[joint], axis=1)
        assert np.allclose(moved, 0.01, atol=1e-9), joint
    # the distal joints stay where they were at the clip's mean pose (within the flexion
    # range's lever: a few mm)
    for joint in ("l_ankle", "r_ankle", "l_wrist", "r_wrist"):
        moved = np.linalg.norm(real.joints[joint] - plain.joints[joint], axis=1)
        assert float(moved.min()) < 0.004, joint
    # the hips and shoulders are not touched
    for joint in ("l_hip", "r_hip", "l_shoulder", "r_shoulder"):
        assert np.allclose(real.joints[joint], plain.joints[joint]), joint


@pytest.mark.parametrize("seed", [1, 2])
def test_data_label_agrees_with_its_uncertainty(seed: int) -> None:
    # the protocol's noise on a clip whose legs barely move: a joint labelled "data" is
    # within 3 data_sd_m + 5 mm of the truth, and the barely moving legs are not "data"
    motion = example_motion(240, fps=60.0, seed=seed)
    cols = [i for i, name in enumerate(motion.names) for _ in motion.channels[i]]
    values = motion.values.copy()
    for k, name in enumerate(motion.names):
        if name in ("LeftKnee", "RightKnee", "LeftAnkle", "RightAnkle"):
            mine = [c for c, owner in enumerate(cols) if owner == k]
            values[:, mine] = values[0, mine] + 0.08 * (values[:, mine] - values[0, mine])
    rec, truth = simulate_sensors(motion.with_values(values), units_m=0.01, seed=seed)
    result = estimate_skeleton(rec)
    labelled = [j for j in JOINTS if result.quality[j].get("reliability") == "data"
                and "data_sd_m" in result.quality[j]]
    assert len(labelled) >= 6
    for joint in labelled:
        bound = 3000.0 * result.quality[joint]["data_sd_m"] + 5.0
        assert error_mm(result.joints, truth.joints, joint) < bound, joint
    for joint in ("l_ankle", "r_ankle"):
        assert result.quality[joint]["reliability"] != "data", joint


def test_hinges_off_the_line_follow_the_data_where_they_locate_them() -> None:
    # knees and elbows 12 mm off their neighbours' line (random direction across the bone)
    # with 0.1 rad/rad of twist coupled to flexion, 20 s, little noise and no slip: the
    # straight-limb rule alone misses each by the offset's component along the flexion
    # axis; weighed against what the data say there (net of orientation noise) it no
    # longer overrides them. Median over 3 recordings x 4 hinges: 8.1 mm before, 4.7 now
    errors = []
    for seed in (10, 11, 12):
        rig = HingeRig(offset_range_m=(0.012, 0.012), coupling_range=(0.1, 0.1), seed=seed)
        rec, truth = simulate_sensors(example_motion(1200, fps=60.0, seed=0), units_m=0.01,
                                      seed=seed, position_noise_m=0.001,
                                      orientation_noise_deg=0.3, slip_m=0.0, rig=rig)
        result = estimate_skeleton(rec)
        assert all(result.quality[j].get("hinge_rule") == "straight-limb" for j in HINGES)
        errors += [error_mm(result.joints, truth.joints, j) for j in HINGES]
    assert float(np.median(errors)) < 6.0, errors
