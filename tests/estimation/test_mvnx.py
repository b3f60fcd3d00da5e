"""Xsens MVNX: streaming reader (Z up → Y up, free accelerations, foot contacts), writer."""

from __future__ import annotations

import contextlib
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from bonefit.estimation.errors import BonefitError, InputError
from bonefit.estimation.io.kinematics import (
    GRAVITY,
    read_kinematics,
    sniff_kinematics,
    write_translation,
)
from bonefit.estimation.io.mvnx import (
    MAX_FRAME_ELEMENTS,
    MAX_HEADER_ELEMENTS,
    MIN_BYTES_PER_TAG,
    y_up_to_z_up,
    z_up_to_y_up,
)
from bonefit.estimation.simulate.inertial import InertialTruth, simulate_walker
from bonefit.estimation.translation import estimate_translation

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


# --------------------------------------------------------------------------- issue 17 §4


def variant(path: Path, out: Path, *, quote: str = '"', mvnx3: bool = False,
            subjects: int = 1, gravity_left: bool = False) -> Path:
    """The fixture rewritten: single-quoted attributes, MVNX 3 accelerations (sensor frame,
    gravity in, with sensorOrientation), a second subject, or gravity left in."""
    rng = np.random.default_rng(5)
    lines = []
    for line in path.read_text().splitlines():
        tag = "<sensorFreeAcceleration>"
        if line.startswith(tag) and (mvnx3 or gravity_left):
            free = np.array(line[len(tag):-len(tag) - 1].split(), dtype=float).reshape(-1, 3)
            specific = free + np.array([0.0, 0.0, GRAVITY])  # Z up
            if gravity_left:
                line = tag + " ".join(f"{v:.6f}" for v in specific.ravel()) + tag.replace(
                    "<", "</")
            else:
                quats = Rotation.random(len(free), rng=rng)
                local = quats.inv().apply(specific)
                q = quats.as_quat(scalar_first=True)
                line = ("<sensorOrientation>" + " ".join(f"{v:.9f}" for v in q.ravel())
                        + "</sensorOrientation><sensorAcceleration>"
                        + " ".join(f"{v:.6f}" for v in local.ravel()) + "</sensorAcceleration>")
        lines.append(line)
    text = "\n".join(lines) + "\n"
    if subjects == 2:
        start, end = text.index("<subject "), text.index("</subject>") + len("</subject>")
        block = text[start:end].replace('label="walker"', 'label="second"')
        # the second subject walks 1 m to the side
        block = re.sub(r"<position>([^<]*)</position>", lambda m: "<position>" + " ".join(
            f"{float(v) + (1.0 if i % 3 == 1 else 0.0):.6f}"
            for i, v in enumerate(m.group(1).split())) + "</position>", block)
        text = text[:end] + "\n" + block + text[end:]
    if quote == "'":
        text = re.sub(r'(\w+)="([^"]*)"', r"\1='\2'", text)
    out.write_text(text)
    return out


def test_mvnx3_acceleration_with_gravity_and_orientation(mvnx_file: MvnxFixture,
                                                         tmp_path: Path) -> None:
    path, _, _ = mvnx_file
    old = variant(path, tmp_path / "v3.mvnx", mvnx3=True)
    assert "sensorFreeAcceleration" not in old.read_text()
    rec, ref = read_kinematics(old), read_kinematics(path)
    for foot in ("LeftFoot", "RightFoot"):
        np.testing.assert_allclose(rec.accelerations[foot], ref.accelerations[foot], atol=1e-4)
    assert any("MVNX 3" in n for n in rec.notes)


def test_gravity_left_in_free_acceleration_is_refused(mvnx_file: MvnxFixture,
                                                      tmp_path: Path) -> None:
    path, _, _ = mvnx_file
    bad = variant(path, tmp_path / "g.mvnx", gravity_left=True)
    with pytest.raises(InputError, match=r"averages 9\.\d+ m/s² vertically.*not removed") as err:
        read_kinematics(bad)
    assert err.value.sensor == "LeftFoot"


def test_two_subjects_first_by_default_or_chosen(mvnx_file: MvnxFixture,
                                                 tmp_path: Path) -> None:
    path, truth, _ = mvnx_file
    two = variant(path, tmp_path / "two.mvnx", subjects=2)
    first = read_kinematics(two)
    np.testing.assert_allclose(first.positions, truth.positions, atol=2e-6)
    assert any("2 subjects" in n and "subject=" in n for n in first.notes)
    for choice in ("2", "second"):
        other = read_kinematics(two, subject=choice)
        np.testing.assert_allclose(other.positions[..., 2], truth.positions[..., 2] - 1.0,
                                   atol=2e-6)  # MVNX +y is Y-up -z
    with pytest.raises(InputError, match=r"no subject 'third'.*'walker', 'second'") as err:
        read_kinematics(two, subject="third")
    assert err.value.field == "subject"
    assert sniff_kinematics(two)["frames"] == truth.root.shape[0]
    # the writer corrects the chosen subject and leaves the other as it was
    result = estimate_translation(other)
    out = tmp_path / "out.mvnx"
    write_translation(result, other, out, format="mvnx")
    np.testing.assert_allclose(read_kinematics(out, subject="2").positions, result.positions,
                               atol=2e-6)
    np.testing.assert_allclose(read_kinematics(out).positions, first.positions, atol=2e-6)


def test_single_quoted_attributes_read_sniffed_and_written(mvnx_file: MvnxFixture,
                                                           tmp_path: Path) -> None:
    path, truth, _ = mvnx_file
    single = variant(path, tmp_path / "single.mvnx", quote="'")
    assert "type='normal'" in single.read_text()
    rec = read_kinematics(single)
    np.testing.assert_allclose(rec.positions, truth.positions, atol=2e-6)
    assert sniff_kinematics(single) == sniff_kinematics(path)
    result = estimate_translation(rec)
    out = tmp_path / "out.mvnx"
    write_translation(result, rec, out, format="mvnx")
    np.testing.assert_allclose(read_kinematics(out).positions, result.positions, atol=2e-6)


def test_writer_refuses_an_input_that_no_longer_matches(mvnx_file: MvnxFixture,
                                                        tmp_path: Path) -> None:
    path, _, _ = mvnx_file
    copy = tmp_path / "c.mvnx"
    copy.write_text(path.read_text())
    rec = read_kinematics(copy)
    result = estimate_translation(rec)
    copy.write_text(path.read_text().replace('type="normal"', 'type="other"'))
    with pytest.raises(InputError, match="0 normal frames where"):
        write_translation(result, rec, tmp_path / "o.mvnx", format="mvnx")


# --------------------------------------------------------------------------- bombs, fuzz


def test_element_bombs_are_refused_with_the_limit(mvnx_file: MvnxFixture,
                                                  tmp_path: Path) -> None:
    path, _, _ = mvnx_file
    text = path.read_text()
    cut = text.index("<segments>")
    dense = tmp_path / "dense.mvnx"  # 10 M elements in 40 MB in the issue; 2.5 M here
    dense.write_text(text[:cut] + "<a/>" * 2_500_000 + text[cut:])
    many = tmp_path / "many.mvnx"  # below the density check: the element limit refuses it
    point = "<point label='a point, 20 bytes a tag'>1</point>"
    many.write_text(text[:cut] + point * (MAX_HEADER_ELEMENTS + 1) + text[cut:])
    frame = tmp_path / "frame.mvnx"
    at = text.index("<position>", text.index('type="normal"'))
    frame.write_text(text[:at] + "<b/>" * (MAX_FRAME_ELEMENTS + 1) + text[at:])
    for bomb, limit in ((dense, f"one per {MIN_BYTES_PER_TAG} bytes"),
                        (many, f"more than {MAX_HEADER_ELEMENTS} elements outside")):
        for call in (read_kinematics, sniff_kinematics):
            with pytest.raises(InputError, match=limit):
                call(bomb)
    # the sniff does not parse frames (it counts their tags), the reader refuses the frame
    with pytest.raises(InputError, match=f"more than {MAX_FRAME_ELEMENTS} elements"):
        read_kinematics(frame)


def test_entity_declarations_are_refused(tmp_path: Path) -> None:
    laughs = ('<?xml version="1.0"?>\n<!DOCTYPE mvnx [<!ENTITY a "aaaaaaaaaa">'
              '<!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">'
              '<!ENTITY c "&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;">]>\n'
              f'<mvnx xmlns="{NS}"><subject label="&c;"/></mvnx>\n')
    external = ('<?xml version="1.0"?>\n<!DOCTYPE mvnx [<!ENTITY x SYSTEM "file:///etc/passwd">]>'
                f'\n<mvnx xmlns="{NS}"><subject label="&x;"/></mvnx>\n')
    hidden = external.replace("?>\n", "?>\n<!-- <mvnx -->\n", 1)
    for name, text in (("laughs.mvnx", laughs), ("external.mvnx", external),
                       ("hidden.mvnx", hidden)):
        (tmp_path / name).write_text(text)
        for call in (read_kinematics, sniff_kinematics):
            with pytest.raises(InputError, match="DOCTYPE or entity declarations"):
                call(tmp_path / name)


@settings(max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.integers(min_value=0, max_value=20_000),
       junk=st.sampled_from(["", "<", "&", "<frame type='normal'>", "</frames>", "1e999",
                             "<position>x</position>", "<subject frameRate='abc'>", "\x00",
                             "<frame time='zz' type='normal'><position>0</position></frame>"]),
       keep=st.booleans())
def test_fuzzed_mvnx_raises_only_bonefit_errors(mvnx_file: MvnxFixture, tmp_path: Path,
                                                cut: int, junk: str, keep: bool) -> None:
    path, _, _ = mvnx_file
    text = path.read_text()
    cut = min(cut, len(text))
    fuzzed = tmp_path / "fuzz.mvnx"
    fuzzed.write_text(text[:cut] + junk + (text[cut:] if keep else ""))
    for call in (read_kinematics, sniff_kinematics):
        with contextlib.suppress(BonefitError):
            call(fuzzed)


def test_frames_without_their_frames_wrapper(mvnx_file: MvnxFixture, tmp_path: Path) -> None:
    path, truth, _ = mvnx_file
    bare = tmp_path / "bare.mvnx"
    bare.write_text(re.sub(r"<frames[^>]*>\n|</frames>\n", "", path.read_text()))
    np.testing.assert_allclose(read_kinematics(bare).positions, truth.positions, atol=2e-6)
