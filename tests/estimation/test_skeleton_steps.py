"""The named steps of ``estimate_skeleton`` (options, sensors, motion, the per-joint plan, the
shared slip model's role) and the body model every topology table derives from."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bonefit.estimation.errors import EstimationError, InputError
from bonefit.estimation.io.skeleton import skeleton_from_dict, skeleton_to_dict
from bonefit.estimation.model import (
    BODY,
    BONES,
    BVH_TREE,
    JOINT_SEGMENTS,
    JOINTS,
    LIMBS,
    REDUCED_SEGMENTS,
    SEGMENTS,
)
from bonefit.estimation.recording import SensorRecording
from bonefit.estimation.results import JointQuality
from bonefit.estimation.simulate.sensors import SimulationTruth
from bonefit.estimation.skeleton import (
    AutoOptions,
    GdkeOptions,
    JointPlan,
    LlsfOptions,
    LocatedJoints,
    ReducedOptions,
    check_recording,
    estimate_skeleton,
    joint_motion,
    locate_joint,
    sensors_used,
    shared_role,
    skeleton_context,
    skeleton_options,
    torso_plan,
)
from bonefit.estimation.slip import EIV_SIGNAL_SHARE

Sim = tuple[SensorRecording, SimulationTruth]


def test_body_model_tables_agree() -> None:
    assert tuple(j.name for j in BODY) == JOINTS
    assert set(JOINT_SEGMENTS) == set(JOINTS) - {"root", "chest"}
    for name, (a, b) in JOINT_SEGMENTS.items():
        assert a in SEGMENTS
        assert b in SEGMENTS
        assert name in BONES[a] or name in BONES.get(b, ())
    # every bone joins a parent and its descendant in the tree
    parent = {node: up for node, up, _ in BVH_TREE}
    for seg, (top, bottom) in BONES.items():
        chain = [bottom]
        while parent[chain[-1]] is not None:
            chain.append(parent[chain[-1]])  # type: ignore[arg-type]
        assert top in chain, seg
    # parents come first in the BVH tree
    seen: set[str] = set()
    for node, up, _ in BVH_TREE:
        assert up is None or up in seen
        seen.add(node)
    assert seen == set(JOINTS)
    limb_segments = {seg for limb in LIMBS.values() for seg in limb.segments}
    assert limb_segments | {"pelvis", "chest", "head"} == set(SEGMENTS)
    assert LIMBS["l_arm"].length_keys == ("upperarm", "forearm")
    assert LIMBS["r_leg"].segments == ("r_thigh", "r_shank", "r_foot")


def test_options_are_checked_before_any_work(sim15: Sim) -> None:
    rec, _ = sim15
    opt = skeleton_options("reduced", {"torso": "gdke"})
    assert isinstance(opt, ReducedOptions)
    assert (opt.estimator, opt.loss, opt.plain, opt.smooth) == ("gdke", "linear", False, False)
    auto = AutoOptions(highpass_s=0.5)
    assert (auto.estimator, auto.loss, auto.smooth) == ("llsf", "huber", True)
    assert auto.highpass(rec.fps) == round(0.5 * rec.fps)
    assert (LlsfOptions().highpass(rec.fps), LlsfOptions().plain) == (0, True)
    assert GdkeOptions().estimator == "gdke"
    with pytest.raises(InputError) as err:
        skeleton_options("fastest", {})
    assert err.value.field == "method"
    with pytest.raises(InputError) as err:
        check_recording(rec, AutoOptions(i0=rec.n_frames))
    assert err.value.field == "i0"
    with pytest.raises(InputError) as err:  # at most half the frame rate: needs the recording
        check_recording(rec, AutoOptions(slip_hz=rec.fps))
    assert err.value.field == "slip_hz"


def test_sensors_used_by_each_method(sim15: Sim, sim11: Sim) -> None:
    rec15, _ = sim15
    assert list(sensors_used(rec15, "auto", []).positions) == list(SEGMENTS)
    assert list(sensors_used(rec15, "reduced", []).positions) == list(REDUCED_SEGMENTS)
    with pytest.raises(InputError) as err:
        sensors_used(sim11[0], "llsf", [])
    assert err.value.sensor in set(SEGMENTS) - set(REDUCED_SEGMENTS)


def test_joint_motion_flags_still_joints_and_refuses_a_still_recording(sim15: Sim) -> None:
    rec, _ = sim15
    sensors = sensors_used(rec, "auto", [])
    motion = joint_motion(sensors, "auto", 2.0)
    assert motion.pairs == list(JOINT_SEGMENTS)
    assert motion.static == []
    assert min(motion.rom.values()) > 2.0
    torso_only = joint_motion(sensors, "reduced", 2.0)
    assert set(torso_only.pairs) == {"waist", "neck", "l_shoulder", "r_shoulder", "l_hip",
                                     "r_hip"}
    with pytest.raises(EstimationError, match="too little motion"):
        joint_motion(sensors, "auto", 179.0)


def test_plan_and_shared_role_of_each_joint(sim15: Sim) -> None:
    rec, _ = sim15
    opt = AutoOptions()
    ctx = skeleton_context(sensors_used(rec, "auto", []), opt, rec.fps)
    assert ctx.shared is not None
    assert shared_role(ctx, "waist") == "torso"
    for name in ("l_knee", "l_ankle", "r_wrist"):
        share = ctx.shared.fit.signal_share[ctx.shared.index[name]]
        assert shared_role(ctx, name) == ("limb" if share >= EIV_SIGNAL_SHARE else None)
    assert shared_role(ctx, "l_hip") == "torso"
    plain = skeleton_context(sensors_used(rec, "llsf", []), LlsfOptions(),
                             rec.fps)
    assert plain.shared is None
    assert shared_role(plain, "waist") is None
    # the first torso joints have no prior; the neck's plan carries its prior and mid-plane
    located = LocatedJoints(warnings=[])
    first = torso_plan(ctx, located, "l_hip")
    assert (first.prior, first.symmetry, first.quiet) == (None, None, True)
    for name in ("l_hip", "r_hip", "l_shoulder", "r_shoulder", "waist"):
        located.record(name, located.locate(ctx, torso_plan(ctx, located, name)))
    neck = torso_plan(ctx, located, "neck")
    assert neck.prior is not None
    assert neck.symmetry is not None
    assert neck.anchor is not None  # the shoulders' posterior widens it


def test_locate_joint_matches_the_estimate(sim15: Sim) -> None:
    rec, truth = sim15
    ctx = skeleton_context(sensors_used(rec, "llsf", []), LlsfOptions(),
                           rec.fps)
    found = locate_joint(ctx, JointPlan("l_hip", "llsf"))
    assert found.posterior is None
    assert found.fit.quality["reliability"] == "data"
    np.testing.assert_array_equal(found.fit.positions,
                                  estimate_skeleton(rec, method="llsf").joints["l_hip"])
    error = np.linalg.norm(found.fit.positions - truth.joints["l_hip"], axis=1).mean()
    assert error < 0.02


def test_joint_quality_is_typed_and_keeps_the_json_keys(sim15: Sim) -> None:
    rec, _ = sim15
    result = estimate_skeleton(rec, method="llsf")
    knee = result.quality["l_knee"]
    assert isinstance(knee, JointQuality)
    assert knee.estimator == "llsf"
    assert knee.reliability == "data"
    assert knee.hinge is True
    assert knee.rms_residual_m == knee["rms_residual_m"] > 0
    assert "hinge_rule" in knee  # a hinge reports its rule, null when none applied
    figures = {"estimator": "llsf", "hinge": True, "hinge_rule": None, "axis": [1.0, 0, 0],
               "data_sd_m": 0.01}
    typed = JointQuality.of(figures)
    assert typed.data_sd_m == 0.01
    assert typed.details == {"hinge_rule": None, "axis": [1.0, 0, 0]}
    assert dict(typed) == figures
    assert len(typed) == len(figures)
    assert typed.get("prior_weight") is None
    with pytest.raises(KeyError):
        typed["prior_weight"]
    # through the JSON writer and reader: the same keys and values per joint
    back = skeleton_from_dict(json.loads(json.dumps(skeleton_to_dict(result))))
    for name, quality in result.quality.items():
        assert isinstance(back.quality[name], JointQuality)
        assert set(back.quality[name]) == set(quality), name
        assert back.quality[name].estimator == quality.estimator
