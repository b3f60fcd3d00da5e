"""Skeleton result writers: JSON contract, CSV, BVH (own reader and an independent parser)."""

from __future__ import annotations

import io
import json
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import bvh as pybvh
import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from bonefit.estimation.bvh import BvhMotion, forward_kinematics, read_bvh
from bonefit.estimation.errors import InputError
from bonefit.estimation.io import skeleton as skeleton_io
from bonefit.estimation.io.outputs import SkeletonOutputs
from bonefit.estimation.io.skeleton import (
    BVH_NODES,
    read_skeleton_json,
    read_skeleton_npz,
    skeleton_to_bvh,
    skeleton_to_dict,
    skeleton_tree,
    write_skeleton_bvh,
    write_skeleton_csv,
    write_skeleton_files,
    write_skeleton_json,
    write_skeleton_npz,
)
from bonefit.estimation.model import JOINTS, SEGMENTS
from bonefit.estimation.results import JointOffset, SkeletonResult

# Joint position relative to its parent joint, in the parent node's segment frame (metres).
REST = {
    "waist": (0.0, 0.10, 0.0), "chest": (0.0, 0.20, 0.0), "neck": (0.0, 0.22, 0.0),
    "l_shoulder": (0.17, 0.18, -0.01), "r_shoulder": (-0.17, 0.18, -0.01),
    "l_elbow": (0.0, -0.29, 0.0), "r_elbow": (0.0, -0.29, 0.0),
    "l_wrist": (0.0, -0.26, 0.01), "r_wrist": (0.0, -0.26, 0.01),
    "l_hip": (0.09, -0.05, 0.0), "r_hip": (-0.09, -0.05, 0.0),
    "l_knee": (0.0, -0.42, 0.0), "r_knee": (0.0, -0.42, 0.0),
    "l_ankle": (0.0, -0.41, -0.01), "r_ankle": (0.0, -0.41, -0.01),
}
PARENT = dict(skeleton_tree())
DRIVER = {node: segment for node, _, segment in BVH_NODES}


def smooth_rotations(n_frames: int, rng: np.random.Generator, scale: float = 1.0,
                     upright: bool = False) -> Rotation:
    t = np.linspace(0, 2 * np.pi, n_frames)[:, None]
    amp = rng.uniform(0.2, 0.9, 3) * scale
    phase = rng.uniform(0, 2 * np.pi, 3)
    base = Rotation.identity() if upright else Rotation.random(rng=rng)
    return base * Rotation.from_rotvec(amp * np.sin(t * rng.uniform(0.5, 2.0, 3) + phase))


def rigid_result(n_frames: int = 30, seed: int = 0, jitter: float = 0.0,
                 yaw_turns: float = 0.0) -> SkeletonResult:
    """A result whose joints follow its orientations exactly (plus optional jitter, m)."""
    rng = np.random.default_rng(seed)
    segments = [*SEGMENTS, "spine", "cervical"]
    orient = {s: smooth_rotations(n_frames, rng, 0.3 if yaw_turns else 1.0, bool(yaw_turns))
              for s in segments}
    if yaw_turns:
        yaw = Rotation.from_euler("y", np.linspace(0, 2 * np.pi * yaw_turns, n_frames)[:, None])
        orient = {s: yaw * r for s, r in orient.items()}
    t = np.linspace(0, 1, n_frames)[:, None]
    joints: dict[str, NDArray[np.float64]] = {
        "root": np.array([0.2, 0.95, -0.1]) + t * np.array([0.5, 0.02, 1.0])}
    for node, parent, _ in BVH_NODES[1:]:
        assert parent is not None
        joints[node] = joints[parent] + orient[DRIVER[parent]].apply(REST[node])
    joints = {k: v + rng.normal(scale=jitter, size=v.shape) if jitter else v
              for k, v in joints.items()}
    return SkeletonResult(
        method="llsf", fps=30.0, joints={j: joints[j] for j in JOINTS},
        offsets={"l_knee": JointOffset("l_thigh", np.array([0.01, -0.2, 0.03])),
                 "waist": JointOffset("pelvis", np.array([0.0, 0.1, -0.05]))},
        bone_lengths={"l_thigh": 0.42, "l_forearm": np.float64(0.26), "l_hand": 0.09},
        orientations={s: r.as_quat(scalar_first=True) for s, r in orient.items()},
        quality={"l_knee": {"rms_residual_m": np.float32(0.002), "hinge": np.bool_(True),
                            "singular_value_ratio": np.float64(0.01), "estimator": "llsf",
                            "axis": np.array([1.0, 0.0, 0.0]), "count": np.int64(3)},
                 "root": {"rms_residual_m": float("nan")}},
        warnings=("l_knee is a hinge",),
        timings={"estimate_s": 0.5},
    )


def bvh_positions_m(path: Path) -> dict[str, NDArray[np.float64]]:
    motion = read_bvh(path)
    positions, _ = forward_kinematics(motion)
    return {name: positions[:, j] / 100.0 for j, name in enumerate(motion.names)}


# --------------------------------------------------------------------------- BVH


def test_bvh_reproduces_a_rigid_result_within_a_millimetre(tmp_path: Path) -> None:
    result = rigid_result()
    write_skeleton_bvh(result, tmp_path / "s.bvh")
    got = bvh_positions_m(tmp_path / "s.bvh")
    for joint in JOINTS:
        err = np.linalg.norm(got[joint] - result.joints[joint], axis=-1)
        assert err.max() < 1e-3, joint
        assert err.max() < 1e-5, joint  # only the 6-decimal rounding of the file


def read_bvh_text(result: SkeletonResult, **options: str | bool) -> BvhMotion:
    """``result`` written as BVH text with ``options`` and read back."""
    buf = io.StringIO()
    write_skeleton_bvh(result, buf, **options)
    return read_bvh(io.StringIO(buf.getvalue()))


def test_bvh_nodes_turn_with_their_segments_swung_onto_their_first_child(
        tmp_path: Path) -> None:
    result = rigid_result(jitter=0.005, seed=3)
    write_skeleton_bvh(result, tmp_path / "s.bvh", slip_chains=False)
    motion = read_bvh(tmp_path / "s.bvh")
    positions, rotations = forward_kinematics(motion)
    rot = {n: Rotation.from_quat(result.orientations[DRIVER[n]], scalar_first=True)
           for n in DRIVER}
    segment = read_bvh_text(result, rest="segment", slip_chains=False)
    seg_positions, segment_frames = forward_kinematics(segment)
    slipped = read_bvh_text(result)  # the default: slip chains where a joint strays
    exact, exact_rotations = forward_kinematics(slipped)
    first = {"root": "waist", "waist": "chest", "chest": "neck", "l_shoulder": "l_elbow",
             "r_shoulder": "r_elbow", "l_elbow": "l_wrist", "r_elbow": "r_wrist",
             "l_hip": "l_knee", "r_hip": "r_knee", "l_knee": "l_ankle", "r_knee": "r_ankle"}
    for node in DRIVER:
        j, s = motion.index(node), segment.index(node)
        # rest="segment": the segment's frame turned by the smallest swing (no twist about
        # the first child's OFFSET) that puts that child on the JSON's direction
        swing = (rot[node].inv() * segment_frames[s]).as_rotvec()
        if node in first:
            child = segment.index(first[node])
            axis = segment.offsets[child] / np.linalg.norm(segment.offsets[child])
            assert np.abs(swing @ axis).max() < 1e-7, node  # the file's 6 decimals
            want = result.joints[first[node]] - result.joints[node]
            got = seg_positions[:, child] / 100 - seg_positions[:, s] / 100
            cos = np.einsum("ij,ij->i", want, got) / (np.linalg.norm(want, axis=1)
                                                      * np.linalg.norm(got, axis=1))
            assert np.arccos(np.clip(cos, -1, 1)).max() < 1e-6, node
        else:  # no child joint: the segment as it is
            assert np.abs(swing).max() < 1e-7, node
        # the default rest turns every node by a constant rotation; slip chains leave the
        # nodes' rotations alone and put every joint exactly where the JSON has it
        rest = segment_frames[s].inv() * rotations[j]
        assert (rest[0].inv() * rest).magnitude().max() < 1e-5
        k = slipped.index(node)
        assert (exact_rotations[k].inv() * rotations[j]).magnitude().max() < 1e-5
        np.testing.assert_allclose(exact[:, k] / 100, result.joints[node], atol=1e-7)
    # jitter makes the bone lengths vary: the rigid skeleton is off the raw joints, but by
    # millimetres
    err = np.linalg.norm(positions[:, motion.index("l_ankle")] / 100
                         - result.joints["l_ankle"], axis=-1)
    assert 1e-3 < err.max() < 0.05


def euler_matrix(channels: list[str], degrees: list[float]) -> NDArray[np.float64]:
    """Rotation of BVH rotation channels, composed in the listed order (own implementation)."""
    out = np.eye(3)
    for name, value in zip(channels, degrees, strict=True):
        a = np.radians(value)
        c, s = np.cos(a), np.sin(a)
        m = {"X": [[1, 0, 0], [0, c, -s], [0, s, c]],
             "Y": [[c, 0, s], [0, 1, 0], [-s, 0, c]],
             "Z": [[c, -s, 0], [s, c, 0], [0, 0, 1]]}[name[0]]
        out = out @ np.array(m)
    return out


def test_independent_bvh_parser_reads_the_same_joint_positions(tmp_path: Path) -> None:
    result = rigid_result(n_frames=12, seed=5)
    write_skeleton_bvh(result, tmp_path / "s.bvh")
    mocap = pybvh.Bvh((tmp_path / "s.bvh").read_text())
    names = mocap.get_joints_names()
    assert names == [node for node, _ in skeleton_tree()]
    assert mocap.nframes == 12
    assert mocap.frame_time == pytest.approx(1 / 30)
    for frame in range(mocap.nframes):
        world: dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}
        for name in names:
            chans = mocap.joint_channels(name)
            vals = mocap.frame_joint_channels(frame, name, chans)
            rot = [c for c in chans if c.endswith("rotation")]
            r_local = euler_matrix(rot, [v for c, v in zip(chans, vals, strict=True)
                                         if c.endswith("rotation")])
            parent_index = mocap.joint_parent_index(name)
            if parent_index < 0:
                pos = np.array([vals[chans.index(f"{a}position")] for a in "XYZ"])
                world[name] = (pos, r_local)
            else:
                p_pos, p_rot = world[names[parent_index]]
                world[name] = (p_pos + p_rot @ np.array(mocap.joint_offset(name)),
                               p_rot @ r_local)
        for name in JOINTS:
            err = np.linalg.norm(world[name][0] / 100 - result.joints[name][frame])
            assert err <= 1e-3, (frame, name)


def test_bvh_hierarchy_channels_units_and_end_sites() -> None:
    result = rigid_result(n_frames=5)
    motion = skeleton_to_bvh(result)
    assert motion.names[0] == "root"
    assert motion.channels[0][:3] == ("Xposition", "Yposition", "Zposition")
    assert sorted(motion.channels[0][3:]) == ["Xrotation", "Yrotation", "Zrotation"]
    np.testing.assert_array_equal(motion.offsets[0], 0.0)  # three.js adds OFFSET to channels
    for j, name in enumerate(motion.names[1:], 1):
        if name.endswith("_end"):
            assert motion.channels[j] == ()
        else:
            assert sorted(motion.channels[j]) == ["Xrotation", "Yrotation", "Zrotation"]
            assert motion.names[motion.parents[j]] == PARENT[name]
    ends = {n for n in motion.names if n.endswith("_end")}
    assert ends == {"neck_end", "l_wrist_end", "r_wrist_end", "l_ankle_end", "r_ankle_end"}
    # offsets in cm; the hand end site takes the hand's bone length, along -y
    np.testing.assert_allclose(motion.offsets[motion.index("l_elbow")], [0, -29, 0], atol=1e-9)
    np.testing.assert_allclose(motion.offsets[motion.index("l_wrist_end")], [0, -9, 0])
    np.testing.assert_allclose(motion.values[:, :3], result.joints["root"] * 100)
    in_m = skeleton_to_bvh(result, units="m")
    np.testing.assert_allclose(in_m.offsets * 100, motion.offsets, atol=1e-12)
    assert motion.frame_time == pytest.approx(1 / 30)


def test_bvh_euler_angles_are_continuous_through_half_turns(tmp_path: Path) -> None:
    result = rigid_result(n_frames=60, yaw_turns=1.5)
    motion = skeleton_to_bvh(result)
    jumps = np.abs(np.diff(motion.values[:, 3:], axis=0))
    assert jumps.max() < 90  # no ±180/360 wraps between frames
    write_skeleton_bvh(result, tmp_path / "t.bvh")
    got = bvh_positions_m(tmp_path / "t.bvh")
    assert np.abs(got["r_ankle"] - result.joints["r_ankle"]).max() < 1e-5


def test_bvh_needs_every_driving_orientation() -> None:
    result = rigid_result(n_frames=4)
    orientations = dict(result.orientations)
    del orientations["spine"]
    broken = SkeletonResult(result.method, result.fps, result.joints, result.offsets,
                            result.bone_lengths, orientations, result.quality)
    with pytest.raises(InputError, match="'spine'") as err:
        skeleton_to_bvh(broken)
    assert err.value.field == "orientations.spine"


# --------------------------------------------------------------------------- JSON


def no_nan(value: str) -> Any:
    raise AssertionError(f"non-standard JSON constant {value}")


def test_json_contract_keys_types_and_no_nan(tmp_path: Path) -> None:
    result = rigid_result(n_frames=7)
    write_skeleton_json(result, tmp_path / "s.json")
    doc = json.loads((tmp_path / "s.json").read_text(), parse_constant=no_nan)
    assert list(doc) == ["kind", "method", "fps", "frames", "units", "joints", "offsets",
                         "bone_lengths", "orientations", "quality", "warnings", "timings"]
    assert (doc["kind"], doc["method"], doc["fps"], doc["frames"], doc["units"]) == (
        "skeleton", "llsf", 30.0, 7, "m")
    assert list(doc["joints"]) == list(JOINTS)
    assert np.array(doc["joints"]["l_knee"]).shape == (7, 3)
    np.testing.assert_allclose(doc["joints"]["l_knee"], result.joints["l_knee"], atol=5e-7)
    assert doc["offsets"]["l_knee"] == {"sensor": "l_thigh", "local": [0.01, -0.2, 0.03]}
    assert list(doc["offsets"]) == ["waist", "l_knee"]  # JOINTS order
    assert doc["bone_lengths"] == {"l_thigh": 0.42, "l_forearm": 0.26, "l_hand": 0.09}
    assert np.array(doc["orientations"]["spine"]).shape == (7, 4)
    quality = doc["quality"]["l_knee"]
    assert quality["hinge"] is True
    assert quality["count"] == 3
    assert quality["axis"] == [1.0, 0.0, 0.0]
    assert quality["rms_residual_m"] == pytest.approx(0.002)
    assert doc["quality"]["root"]["rms_residual_m"] is None
    assert doc["warnings"] == ["l_knee is a hinge"]
    # the README's contract: every stage named; one not run here (no file read) is 0.0
    assert list(doc["timings"]) == ["read_s", "estimate_s", "write_s"]
    assert (doc["timings"]["read_s"], doc["timings"]["estimate_s"]) == (0.0, 0.5)
    assert doc["timings"]["write_s"] >= 0


def test_json_round_trip(tmp_path: Path) -> None:
    result = rigid_result(n_frames=9, seed=2)
    write_skeleton_json(result, tmp_path / "s.json", indent=1)
    back = read_skeleton_json(tmp_path / "s.json")
    assert (back.method, back.fps, back.n_frames) == ("llsf", 30.0, 9)
    for j in JOINTS:
        np.testing.assert_allclose(back.joints[j], result.joints[j], atol=1e-6)
    for s, q in result.orientations.items():
        np.testing.assert_allclose(back.orientations[s], q, atol=1e-8)
    assert back.offsets["l_knee"].sensor == "l_thigh"
    np.testing.assert_allclose(back.offsets["l_knee"].local, [0.01, -0.2, 0.03])
    assert back.bone_lengths["l_thigh"] == 0.42
    assert back.quality["l_knee"]["hinge"] is True
    assert back.warnings == result.warnings
    written = json.loads((tmp_path / "s.json").read_text())
    assert skeleton_to_dict(back) == written  # write_s: measured by write_skeleton_json
    assert {k: v for k, v in written.items() if k != "timings"} == {
        k: v for k, v in skeleton_to_dict(result).items() if k != "timings"}


def test_json_refuses_nan_joints_and_foreign_documents(tmp_path: Path) -> None:
    result = rigid_result(n_frames=4)
    joints = dict(result.joints)
    joints["l_knee"] = joints["l_knee"].copy()
    joints["l_knee"][2, 1] = np.nan
    broken = SkeletonResult(result.method, result.fps, joints, result.offsets,
                            result.bone_lengths, result.orientations, result.quality)
    with pytest.raises(InputError, match=r"joints\.l_knee has NaN"):
        skeleton_to_dict(broken)
    (tmp_path / "x.json").write_text('{"kind": "translation", "method": "x"}')
    with pytest.raises(InputError, match="not a bonefit skeleton"):
        read_skeleton_json(tmp_path / "x.json")
    (tmp_path / "bad.json").write_text('{"kind": "skeleton",\n "fps": 3,,}')
    with pytest.raises(InputError, match="line 2") as err:
        read_skeleton_json(tmp_path / "bad.json")
    assert err.value.line == 2


# --------------------------------------------------------------------------- NPZ


def test_npz_round_trip_at_full_precision_with_the_json_names(tmp_path: Path) -> None:
    result = rigid_result(n_frames=9, seed=4)
    write_skeleton_npz(result, tmp_path / "s.bin")  # written as named, no ".npz" added
    back = read_skeleton_npz(tmp_path / "s.bin")
    assert (back.method, back.fps, back.n_frames) == ("llsf", 30.0, 9)
    for j in JOINTS:
        np.testing.assert_array_equal(back.joints[j], result.joints[j])
    for seg, q in result.orientations.items():
        np.testing.assert_array_equal(back.orientations[seg], q)
    assert back.offsets["l_knee"].sensor == "l_thigh"
    assert back.quality["l_knee"]["hinge"] is True
    assert back.warnings == result.warnings
    # plain numpy and json read it: the JSON document, each array named by its path
    write_skeleton_json(result, tmp_path / "s.json")
    written = json.loads((tmp_path / "s.json").read_text())
    with np.load(tmp_path / "s.bin") as npz:
        document = json.loads(str(npz["document"]))
        assert document["joints"]["l_knee"] == "joints/l_knee"
        np.testing.assert_array_equal(npz["joints/l_knee"], result.joints["l_knee"])
        np.testing.assert_array_equal(npz["orientations/spine"], result.orientations["spine"])
    for key in ("kind", "method", "fps", "frames", "units", "offsets", "bone_lengths",
                "quality", "warnings"):
        assert document[key] == written[key], key
    assert list(document) == list(written)


def test_npz_refuses_nan_and_foreign_archives(tmp_path: Path) -> None:
    result = rigid_result(n_frames=4)
    joints = {**result.joints, "l_knee": np.full((4, 3), np.nan)}
    with pytest.raises(InputError, match=r"joints\.l_knee has NaN"):
        write_skeleton_npz(replace(result, joints=joints), tmp_path / "nan.npz")
    np.savez(tmp_path / "other.npz", positions=np.zeros((3, 2, 3)))
    with pytest.raises(InputError, match="lacks the array 'document'"):
        read_skeleton_npz(tmp_path / "other.npz")
    (tmp_path / "text.npz").write_text("not a zip")
    with pytest.raises(InputError, match="not an NPZ archive"):
        read_skeleton_npz(tmp_path / "text.npz")


# --------------------------------------------------------------------------- CSV


def test_csv_one_row_per_frame_in_metres(tmp_path: Path) -> None:
    result = rigid_result(n_frames=6)
    write_skeleton_csv(result, tmp_path / "j.csv")
    lines = (tmp_path / "j.csv").read_text().splitlines()
    header = lines[0].split(",")
    assert header[:4] == ["time", "root.x", "root.y", "root.z"]
    assert header[1::3] == [f"{j}.x" for j in JOINTS]
    assert len(lines) == 7
    table = np.loadtxt(tmp_path / "j.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(table[:, 0], np.arange(6) / 30.0, atol=1e-6)
    k = header.index("l_wrist.x")
    np.testing.assert_allclose(table[:, k:k + 3], result.joints["l_wrist"], atol=1e-6)


def test_write_skeleton_files_times_every_write_in_the_json(tmp_path: Path) -> None:
    result = replace(rigid_result(n_frames=9, seed=2),
                     timings={"read_s": 0.125, "estimate_s": 0.5, "torso_s": 0.25})
    out = write_skeleton_files(result, SkeletonOutputs(
        json=tmp_path / "s.json", bvh=tmp_path / "s.bvh", csv=tmp_path / "s.csv"))
    doc = json.loads((tmp_path / "s.json").read_text())
    assert list(doc["timings"]) == ["read_s", "estimate_s", "write_s", "torso_s"]
    assert (doc["timings"]["read_s"], doc["timings"]["estimate_s"]) == (0.125, 0.5)
    assert 0 < doc["timings"]["write_s"] <= out.timings["write_s"]  # BVH and CSV before it
    assert (tmp_path / "s.bvh").read_text().startswith("HIERARCHY")
    assert (tmp_path / "s.csv").is_file()


def test_the_calling_thread_takes_the_files_the_other_has_not_started(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """While a long BVH is written beside the JSON, the CSV is written by the other thread
    (the calling one, once its JSON arrays are out; before, the second thread wrote all
    three in turn)."""
    writers: dict[str, str] = {}
    bvh_writer, csv_writer = skeleton_io.write_skeleton_bvh, skeleton_io.write_skeleton_csv

    def slow_bvh(result: SkeletonResult, path: Path, **options: bool) -> None:
        writers["bvh"] = threading.current_thread().name
        time.sleep(1.0)
        bvh_writer(result, path, **options)

    def csv(result: SkeletonResult, path: Path) -> None:
        writers["csv"] = threading.current_thread().name
        csv_writer(result, path)

    monkeypatch.setattr(skeleton_io, "write_skeleton_bvh", slow_bvh)
    monkeypatch.setattr(skeleton_io, "write_skeleton_csv", csv)
    result = rigid_result(n_frames=9, seed=2)
    write_skeleton_files(result, SkeletonOutputs(json=tmp_path / "s.json", bvh=tmp_path / "s.bvh",
                                                 csv=tmp_path / "s.csv", npz=tmp_path / "s.npz"))
    assert writers["bvh"] != writers["csv"]
    assert {writers["bvh"], writers["csv"]} & {threading.current_thread().name}
    assert json.loads((tmp_path / "s.json").read_text())["frames"] == 9
    assert read_skeleton_npz(tmp_path / "s.npz").n_frames == 9
    assert (tmp_path / "s.bvh").read_text().startswith("HIERARCHY")
    with pytest.raises(FileNotFoundError, match=r"missing/s\.csv"):
        write_skeleton_files(result, SkeletonOutputs(json=tmp_path / "t.json",
                                                     bvh=tmp_path / "t.bvh",
                                                     csv=tmp_path / "missing" / "s.csv"))
    assert not (tmp_path / "t.json").exists()


def test_a_failed_write_beside_the_json_is_raised_and_the_json_removed(tmp_path: Path) -> None:
    result = rigid_result(n_frames=9, seed=2)
    with pytest.raises(FileNotFoundError, match=r"missing/s\.bvh"):
        write_skeleton_files(result, SkeletonOutputs(json=tmp_path / "s.json",
                                                     bvh=tmp_path / "missing" / "s.bvh"))
    assert not (tmp_path / "s.json").exists()
