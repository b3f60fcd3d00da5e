"""Kinematics CSV and BVH + accelerations readers, writers and their error paths."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np
import pytest

from bonefit.estimation.bvh import BvhMotion, forward_kinematics, read_bvh, write_bvh
from bonefit.estimation.errors import InputError
from bonefit.estimation.io.kinematics import (
    GRAVITY,
    KinematicsRecording,
    read_kinematics,
    sniff_kinematics,
    translation_to_dict,
    write_kinematics_csv,
    write_translation,
)
from bonefit.estimation.io.result_json import result_from_dict, translation_from_dict
from bonefit.estimation.results import TranslationResult
from bonefit.estimation.simulate.inertial import simulate_walker
from bonefit.estimation.translation import estimate_translation
from tests.estimation.conftest import two_feet_motion


@pytest.fixture(scope="module")
def walker() -> KinematicsRecording:
    rec, _, _ = simulate_walker(fps=60)
    return rec


def write_csv_with_extras(rec: KinematicsRecording, path: Path) -> list[str]:
    """The walker as a kinematics CSV with extra columns in between (passthrough check)."""
    buf = io.StringIO()
    write_kinematics_csv(rec, buf)
    rows = list(csv.reader(io.StringIO(buf.getvalue())))
    header = rows[0]
    out_header = [*header[:2], "Hips.Rx", *header[2:], "LFP.ax", "Marker"]
    body = [[*r[:2], f"{i * 0.5:g}", *r[2:], "0.25", str(i)] for i, r in
            enumerate(rows[1:])]
    with open(path, "w", newline="") as handle:
        w = csv.writer(handle)
        w.writerow(out_header)
        w.writerows(body)
    return out_header


def test_csv_round_trip_keeps_every_column(walker: KinematicsRecording, tmp_path: Path) -> None:
    src = tmp_path / "walk.csv"
    header = write_csv_with_extras(walker, src)
    rec = read_kinematics(src)
    assert rec.source_format == "kinematics-csv"
    assert rec.joints == walker.joints
    assert rec.fps == pytest.approx(60.0)
    np.testing.assert_allclose(rec.positions, walker.positions, atol=1e-9)
    np.testing.assert_allclose(rec.accelerations["LeftFoot"], walker.accelerations["LeftFoot"],
                               rtol=1e-8, atol=1e-8)
    assert rec.toes == {"LeftFoot": "LeftToe", "RightFoot": "RightToe"}
    assert any("in g" in note for note in rec.notes)
    result = estimate_translation(rec)
    out = tmp_path / "out.csv"
    write_translation(result, rec, out, format="kinematics-csv")
    with open(out, newline="") as handle:
        rows = list(csv.reader(handle))
    assert rows[0] == header
    table = np.array(rows[1:], dtype=float)
    original = np.loadtxt(src, delimiter=",", skiprows=1)
    passthrough = [i for i, h in enumerate(header) if not h.endswith((".Dx", ".Dy", ".Dz"))]
    np.testing.assert_allclose(table[:, passthrough], original[:, passthrough], rtol=1e-9)
    again = read_kinematics(out)
    np.testing.assert_allclose(again.positions, result.positions, atol=1e-8)


def test_json_and_bvh_outputs(walker: KinematicsRecording, tmp_path: Path) -> None:
    result = estimate_translation(walker)
    path = tmp_path / "r.json"
    write_translation(result, walker, path, format="json")
    data = json.loads(path.read_text())
    assert data["frames"] == walker.n_frames
    assert len(data["root"]) == walker.n_frames
    assert len(data["contacts"]) == walker.n_frames
    assert set(data["quality"]) >= {"foot_skate_cm_s", "floor_penetration_cm", "closure_cm"}
    np.testing.assert_allclose(np.array(data["root"]), result.root, atol=1e-5)
    bvh_path = tmp_path / "r.bvh"
    write_translation(result, walker, bvh_path, format="bvh")
    motion = read_bvh(bvh_path)
    pos, _ = forward_kinematics(motion)
    for j, name in enumerate(walker.joints):
        np.testing.assert_allclose(pos[:, motion.index(name)] * 0.01, result.positions[:, j],
                                   atol=1e-7)
    with pytest.raises(InputError, match="unknown output format"):
        write_translation(result, walker, tmp_path / "x", format="fbx")


RECORDING_CONTEXT = {"root_joint", "time", "feet", "foot_heights", "input_length_unit_m",
                     "notes"}
"""Members of the translation JSON that describe the input, written only with the recording."""


def test_json_reads_back_into_the_result(walker: KinematicsRecording, tmp_path: Path) -> None:
    result = estimate_translation(walker)
    path = tmp_path / "r.json"
    write_translation(result, walker, path, format="json")
    written = json.loads(path.read_text())
    back = result_from_dict(written)
    assert isinstance(back, TranslationResult)
    assert (back.method, back.fps, back.n_frames) == (result.method, walker.fps, walker.n_frames)
    for name in ("root", "translation", "floor"):  # 5 decimals in metres
        np.testing.assert_allclose(getattr(back, name), getattr(result, name), atol=5e-6)
    np.testing.assert_array_equal(back.contacts, result.contacts)
    assert back.positions is None
    # writer -> reader -> writer gives the same document, but for the input's members
    assert translation_to_dict(back) == {k: v for k, v in written.items()
                                         if k not in RECORDING_CONTEXT} | {"root_joint": None}
    assert translation_from_dict(translation_to_dict(back)).quality == back.quality
    with pytest.raises(InputError, match="every joint's position") as info:
        write_translation(back, walker, tmp_path / "x.bvh", format="bvh")  # a point-joint BVH
    assert info.value.field == "positions"


def test_json_reader_names_the_bad_member(walker: KinematicsRecording) -> None:
    document = translation_to_dict(estimate_translation(walker, method="hachaj2018"))
    frames = document["frames"]
    assert translation_from_dict(document).n_frames == frames
    for change, field in (({"kind": "skeleton"}, "kind"), ({"root": document["root"][:-1]},
                          "root"), ({"contacts": document["contacts"][1:]}, "contacts"),
                          ({"translation": document["translation"][:-1]}, "translation"),
                          ({"frames": frames + 1}, "root"), ({"frames": "12"}, "frames"),
                          ({"up": "+Z"}, "up"), ({"fps": "60"}, "fps"),
                          ({"quality": []}, "quality"), ({"floor": [[0.0]] * frames}, "floor")):
        with pytest.raises(InputError) as info:
            translation_from_dict({**document, **change})
        assert info.value.field == field, change
    del document["floor"]
    with pytest.raises(InputError, match="lacks 'floor'"):
        translation_from_dict(document)


def test_accelerations_in_m_s2_are_reported(walker: KinematicsRecording, tmp_path: Path) -> None:
    path = tmp_path / "ms2.csv"
    write_kinematics_csv(walker, path)  # g
    header = path.read_text().splitlines()[0].split(",")
    table = np.loadtxt(path, delimiter=",", skiprows=1)
    acc_cols = [i for i, h in enumerate(header) if ".a" in h]
    table[:, acc_cols] *= GRAVITY  # now m/s²
    np.savetxt(path, table, delimiter=",", header=",".join(header), comments="", fmt="%.10g")
    with pytest.raises(InputError, match="m/s²"):
        read_kinematics(path)
    rec = read_kinematics(path, acceleration_units="m/s2")
    np.testing.assert_allclose(rec.accelerations["LeftFoot"], walker.accelerations["LeftFoot"],
                               rtol=1e-8, atol=1e-8)
    with pytest.raises(InputError, match="declared as g"):
        read_kinematics(path, acceleration_units="g")
    with pytest.raises(InputError, match="unknown acceleration units"):
        read_kinematics(path, acceleration_units="furlongs")


def test_second_differences_are_reported(walker: KinematicsRecording, tmp_path: Path) -> None:
    path = tmp_path / "d2.csv"
    write_kinematics_csv(walker, path)
    header = path.read_text().splitlines()[0].split(",")
    table = np.loadtxt(path, delimiter=",", skiprows=1)
    col = {h: i for i, h in enumerate(header)}
    for foot in ("LeftFoot", "RightFoot"):
        for axis in "xyz":
            p = table[:, col[f"{foot}.D{axis}"]]
            d2 = np.zeros_like(p)
            d2[1:-1] = p[2:] - 2 * p[1:-1] + p[:-2]
            table[:, col[f"{foot}.a{axis}"]] = d2
    np.savetxt(path, table, delimiter=",", header=",".join(header), comments="", fmt="%.12g")
    with pytest.raises(InputError, match="second differences"):
        read_kinematics(path)
    rec = read_kinematics(path, acceleration_units="second-differences")
    assert rec.acceleration_frame == "world"


def test_missing_foot_lists_the_joints(walker: KinematicsRecording, tmp_path: Path) -> None:
    path = tmp_path / "w.csv"
    write_kinematics_csv(walker, path)
    with pytest.raises(InputError, match="Hips, LeftFoot, LeftToe, RightFoot, RightToe"):
        read_kinematics(path, left_foot="LFoot")
    header = path.read_text().splitlines()[0].split(",")
    keep = [i for i, h in enumerate(header) if not h.startswith("RightFoot.a")]
    table = np.loadtxt(path, delimiter=",", skiprows=1)[:, keep]
    np.savetxt(path, table, delimiter=",", header=",".join(header[i] for i in keep),
               comments="", fmt="%.10g")
    with pytest.raises(InputError, match="sensors with accelerations: LeftFoot"):
        read_kinematics(path)


def test_malformed_csv_names_the_line(tmp_path: Path) -> None:
    path = tmp_path / "bad.csv"
    path.write_text("Time,A.Dx,A.Dy,A.Dz\n0,1,2,3\n0.01,1,x,3\n")
    with pytest.raises(InputError) as info:
        read_kinematics(path, format="kinematics-csv")
    assert info.value.line == 3
    assert info.value.field == "A.Dy"
    path.write_text("hello\n")
    with pytest.raises(InputError, match="cannot tell the format"):
        read_kinematics(path)


def test_sniff_streams_a_summary(walker: KinematicsRecording, tmp_path: Path) -> None:
    path = tmp_path / "w.csv"
    write_kinematics_csv(walker, path)
    info = sniff_kinematics(path)
    assert info["format"] == "kinematics-csv"
    assert info["frames"] == walker.n_frames
    assert info["joints"] == list(walker.joints)
    assert info["fps"] == pytest.approx(60.0)


def small_bvh() -> BvhMotion:
    n = 120
    t = np.arange(n) / 60.0
    values = np.zeros((n, 12))
    values[:, 0] = 50 * t  # root walks 50 cm/s along x
    values[:, 1] = 90
    values[:, 5] = 20 * np.sin(t)  # yaw
    values[:, 7] = 15 * np.sin(3 * t)  # left foot pitch
    values[:, 10] = -15 * np.sin(3 * t)
    return two_feet_motion(values, 60.0)


def test_bvh_with_accelerations(tmp_path: Path) -> None:
    motion = small_bvh()
    bvh_path = tmp_path / "m.bvh"
    write_bvh(motion, bvh_path)
    acc_path = tmp_path / "acc.csv"
    n = motion.n_frames
    rng = np.random.default_rng(0)
    a = rng.normal(0, 0.05, (n, 6)) + np.array([0, 1, 0, 0, 1, 0])
    header = "time,LeftFoot.ax [g],LeftFoot.ay [g],LeftFoot.az [g],RightFoot.ax [g]," \
             "RightFoot.ay [g],RightFoot.az [g]"
    np.savetxt(acc_path, np.column_stack([np.arange(n) / 60.0, a]), delimiter=",",
               header=header, comments="", fmt="%.8f")
    rec = read_kinematics(bvh_path, accelerations=acc_path)
    assert rec.source_format == "bvh"
    hips = rec.positions[:, rec.index("Hips")]
    np.testing.assert_allclose(hips, np.broadcast_to(hips[0], hips.shape))  # root frozen
    assert rec.toes == {"LeftFoot": "LeftFoot_end", "RightFoot": "RightFoot_end"}
    np.testing.assert_allclose(rec.accelerations["LeftFoot"], a[:, :3] * GRAVITY, atol=1e-6)
    result = estimate_translation(rec)
    out = tmp_path / "out.bvh"
    write_translation(result, rec, out, format="bvh")
    back = read_bvh(out)
    pos, _ = forward_kinematics(back)
    np.testing.assert_allclose(pos * 0.01, result.positions, atol=1e-7)
    with pytest.raises(InputError, match="needs an accelerations CSV"):
        read_kinematics(bvh_path)
    with pytest.raises(InputError, match="not found in the BVH"):
        read_kinematics(bvh_path, accelerations=acc_path, left_foot="Foot_L")
    with pytest.raises(InputError, match="cannot write a kinematics CSV"):
        write_translation(result, rec, tmp_path / "x.csv", format="kinematics-csv")
    info = sniff_kinematics(bvh_path)
    assert info["format"] == "bvh"
    assert info["frames"] == n
    assert "LeftFoot" in info["joints"]
