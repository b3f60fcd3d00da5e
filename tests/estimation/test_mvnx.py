"""Xsens MVNX: streaming reader (Z up → Y up, free accelerations, foot contacts), writer."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from estimation.errors import InputError
from estimation.io.kinematics import read_kinematics, sniff_kinematics, write_translation
from estimation.io.mvnx import y_up_to_z_up, z_up_to_y_up
from estimation.simulate.inertial import InertialTruth, simulate_walker
from estimation.translation import estimate_translation

NS = "http://www.xsens.com/mvn/mvnx"
MvnxFixture = tuple[Path, InertialTruth, NDArray[np.str_]]
SEGMENTS = ("Pelvis", "LeftFoot", "LeftToe", "RightFoot", "RightToe")


def write_mvnx(path: Path, world: NDArray[np.float64], free: dict[str, NDArray[np.float64]],
               contacts: dict[str, NDArray[np.bool_]] | None, fps: float) -> None:
    """A minimal MVNX 4 file as MVN writes it (one element per line), from Y-up data."""
    zup = y_up_to_z_up(world)
    lines = ['<?xml version="1.0" encoding="UTF-8" standalone="no"?>',
             f'<mvnx version="4" xmlns="{NS}">',
             f'<subject label="walker" torsoColor="#ea6852" frameRate="{fps:g}" '
             f'segmentCount="{len(SEGMENTS)}" recDate="" originalFilename="">',
             "<segments>"]
    for k, name in enumerate(SEGMENTS, 1):
        lines += [f'<segment label="{name}" id="{k}">', "<points>",
                  '<point label="p"><pos_b>0 0 0</pos_b></point>', "</points>", "</segment>"]
    lines += ["</segments>", "<sensors>", '<sensor label="Pelvis"/>',
              '<sensor label="LeftFoot"/>', '<sensor label="RightFoot"/>', "</sensors>",
              "<footContactDefinition>",
              '<contactDefinition label="LeftFoot_Heel" index="0"/>',
              '<contactDefinition label="LeftFoot_Toe" index="1"/>',
              '<contactDefinition label="RightFoot_Heel" index="2"/>',
              '<contactDefinition label="RightFoot_Toe" index="3"/>',
              "</footContactDefinition>",
              f'<frames segmentCount="{len(SEGMENTS)}" sensorCount="3">',
              '<frame time="0" index="" tc="" ms="" type="identity">',
              "<orientation>" + " ".join(["1 0 0 0"] * len(SEGMENTS)) + "</orientation>",
              "<position>" + " ".join(["0 0 0"] * len(SEGMENTS)) + "</position>",
              "</frame>"]
    pelvis_acc = np.zeros((world.shape[0], 3))
    for i in range(world.shape[0]):
        acc = np.concatenate([pelvis_acc[i]] + [y_up_to_z_up(free[f][i])
                                                for f in ("LeftFoot", "RightFoot")])
        lines += [f'<frame time="{round(i * 1000 / fps)}" index="{i}" tc="" ms="" '
                  'type="normal">',
                  "<orientation>" + " ".join(["1 0 0 0"] * len(SEGMENTS)) + "</orientation>",
                  "<position>" + " ".join(f"{v:.6f}" for v in zup[i].ravel()) + "</position>",
                  "<sensorFreeAcceleration>" + " ".join(f"{v:.6f}" for v in acc)
                  + "</sensorFreeAcceleration>"]
        if contacts is not None:
            flags = [contacts["LeftFoot"][i]] * 2 + [contacts["RightFoot"][i]] * 2
            lines.append("<footContacts>" + " ".join(str(int(f)) for f in flags)
                         + "</footContacts>")
        lines.append("</frame>")
    lines += ["</frames>", "</subject>", "</mvnx>"]
    path.write_text("\n".join(lines) + "\n")


@pytest.fixture(scope="module")
def mvnx_file(tmp_path_factory: pytest.TempPathFactory) -> MvnxFixture:
    _rec, truth, contacts = simulate_walker(fps=60)
    # MVNX carries the suit's own translation and gravity-free world accelerations
    free = {}
    for k, foot in ((1, "LeftFoot"), (3, "RightFoot")):
        p = truth.positions[:, k]
        free[foot] = np.gradient(np.gradient(p, 1 / 60, axis=0), 1 / 60, axis=0)
    flags = {"LeftFoot": np.isin(contacts, ("left", "both")),
             "RightFoot": np.isin(contacts, ("right", "both"))}
    path = tmp_path_factory.mktemp("mvnx") / "walk.mvnx"
    write_mvnx(path, truth.positions, free, flags, 60.0)
    return path, truth, contacts


def test_axes_conversion_round_trips() -> None:
    v = np.random.default_rng(0).normal(size=(5, 3))
    np.testing.assert_allclose(y_up_to_z_up(z_up_to_y_up(v)), v)
    np.testing.assert_allclose(z_up_to_y_up(np.array([0.0, 0.0, 1.0])), [0.0, 1.0, 0.0])


def test_read_mvnx(mvnx_file: MvnxFixture) -> None:
    path, truth, contacts = mvnx_file
    rec = read_kinematics(path)
    assert rec.source_format == "mvnx"
    assert rec.joints == SEGMENTS
    assert rec.fps == 60.0
    assert rec.acceleration_frame == "world"
    np.testing.assert_allclose(rec.positions, truth.positions, atol=2e-6)
    assert rec.toes == {"LeftFoot": "LeftToe", "RightFoot": "RightToe"}
    assert rec.root == "Pelvis"
    np.testing.assert_array_equal(rec.contacts["LeftFoot"],
                                  np.isin(contacts, ("left", "both")))
    assert rec.time[1] == pytest.approx(1 / 60, abs=1e-3)


def test_translation_from_mvnx_contacts_and_writer(mvnx_file: MvnxFixture,
                                                   tmp_path: Path) -> None:
    path, truth, _ = mvnx_file
    rec = read_kinematics(path)
    result = estimate_translation(rec)
    assert result.quality["contacts_source"] == "file"
    true_root = truth.root
    err = np.linalg.norm(result.root[:, [0, 2]] - true_root[:, [0, 2]], axis=1).max()
    assert err < 0.05
    # without the file's contacts the free accelerations drive the contact model
    alone = estimate_translation(rec, use_file_contacts=False)
    err = np.linalg.norm(alone.root[:, [0, 2]] - true_root[:, [0, 2]], axis=1).mean()
    assert err < 0.05
    out = tmp_path / "out.mvnx"
    write_translation(result, rec, out, format="mvnx")
    ET.parse(out)  # still well-formed XML
    back = read_kinematics(out)
    np.testing.assert_allclose(back.positions, result.positions, atol=2e-6)


def test_sniff_and_errors(mvnx_file: MvnxFixture, tmp_path: Path) -> None:
    path, truth, _ = mvnx_file
    info = sniff_kinematics(path)
    assert info == {"format": "mvnx", "frames": truth.root.shape[0],
                    "joints": list(SEGMENTS), "fps": 60.0}
    with pytest.raises(InputError, match="Pelvis, LeftFoot, LeftToe"):
        read_kinematics(path, left_foot="LeftAnkle")
    broken = tmp_path / "broken.mvnx"
    broken.write_text(path.read_text()[:5000])
    with pytest.raises(InputError, match="malformed MVNX"):
        read_kinematics(broken)
