"""Issue 17 §2–3: every BVH layout, unit and quirk of the generated corpus gives the canonical
route's root path, or is refused with a message that says how to fix it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from bonefit.cli import main
from bonefit.estimation.bvh import BvhMotion
from bonefit.estimation.errors import InputError
from bonefit.estimation.io.body import LENGTH_UNITS, classify, find_bvh_feet
from bonefit.estimation.io.kinematics import read_kinematics, sniff_kinematics, translation_to_dict
from bonefit.estimation.translation import estimate_translation
from tests.estimation.bvh_corpus import (
    CONVENTIONS,
    accelerations_csv,
    anonymous,
    body_motion,
    bvh_text,
)


def root_path(bvh: Path, acc: Path, **kwargs: object) -> NDArray[np.float64]:
    rec = read_kinematics(bvh, accelerations=acc, **kwargs)  # type: ignore[arg-type]
    return estimate_translation(rec).root


def write(path: Path, motion: BvhMotion, **quirks: object) -> Path:
    path.write_text(bvh_text(motion, **quirks), encoding="utf-8",  # type: ignore[arg-type]
                    newline="")
    return path


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("corpus")


@pytest.fixture(scope="module")
def acc(corpus: Path) -> Path:
    return accelerations_csv(corpus / "feet.csv", "LeftFoot", "RightFoot")


@pytest.fixture(scope="module")
def canonical(corpus: Path, acc: Path) -> dict[bool, NDArray[np.float64]]:
    """Root path of the canonical file (cm, CMU/Mixamo names), with and without toe joints."""
    return {toes: root_path(write(corpus / f"canonical-{toes}.bvh", body_motion(toes=toes)),
                            acc)
            for toes in (True, False)}


@pytest.mark.parametrize("convention", sorted(CONVENTIONS))
def test_suit_names_give_the_canonical_path(convention: str, corpus: Path, acc: Path,
                                            canonical: dict[bool, NDArray[np.float64]]
                                            ) -> None:
    names = CONVENTIONS[convention]
    bvh = write(corpus / f"{convention}.bvh",
                body_motion(names, hip_joints=convention.startswith("cmu")))
    feet_acc = accelerations_csv(corpus / f"{convention}.csv", names["l_foot"],
                                 names["r_foot"])
    rec = read_kinematics(bvh, accelerations=feet_acc)
    assert (rec.left_foot, rec.right_foot) == (names["l_foot"], names["r_foot"])
    assert rec.toes == {names["l_foot"]: names["l_toe"], names["r_foot"]: names["r_toe"]}
    assert any(n.startswith(f"feet: {names['l_foot']} (left)") for n in rec.notes)
    np.testing.assert_allclose(estimate_translation(rec).root, canonical[True], atol=1e-6)


def test_feet_without_toe_joints(corpus: Path, acc: Path,
                                 canonical: dict[bool, NDArray[np.float64]]) -> None:
    """Perception Neuron / Daz: the foot ends in an End Site, which becomes the toe."""
    names = CONVENTIONS["daz"]
    bvh = write(corpus / "daz-no-toes.bvh", body_motion(names, toes=False))
    rec = read_kinematics(bvh, accelerations=accelerations_csv(corpus / "daz.csv", "lFoot",
                                                               "rFoot"))
    assert rec.toes == {"lFoot": "lFoot_end", "rFoot": "rFoot_end"}
    np.testing.assert_allclose(estimate_translation(rec).root, canonical[False], atol=1e-6)


@pytest.mark.parametrize("toes", [True, False])
def test_feet_by_topology_when_names_say_nothing(toes: bool, corpus: Path,
                                                 canonical: dict[bool, NDArray[np.float64]]
                                                 ) -> None:
    names = anonymous()
    bvh = write(corpus / f"anonymous-{toes}.bvh", body_motion(names, toes=toes))
    feet_acc = accelerations_csv(corpus / "anonymous.csv", names["l_foot"], names["r_foot"])
    rec = read_kinematics(bvh, accelerations=feet_acc)
    assert (rec.left_foot, rec.right_foot) == (names["l_foot"], names["r_foot"])
    assert any("found by topology" in n for n in rec.notes)
    np.testing.assert_allclose(estimate_translation(rec).root, canonical[toes], atol=1e-6)


def test_accelerometers_named_by_the_suit_not_the_joint(corpus: Path, acc: Path,
                                                        canonical: dict[bool, NDArray[
                                                            np.float64]]) -> None:
    """Xsens BVH joints are LeftAnkle/RightAnkle, its foot sensors LeftFoot/RightFoot."""
    bvh = write(corpus / "xsens.bvh", body_motion(CONVENTIONS["xsens-mvn"]))
    rec = read_kinematics(bvh, accelerations=acc)
    assert rec.left_foot == "LeftAnkle"
    assert "accelerations of LeftAnkle from sensor LeftFoot" in rec.notes
    np.testing.assert_allclose(estimate_translation(rec).root, canonical[True], atol=1e-6)


def test_a_wrong_flag_names_the_feet_found(corpus: Path, acc: Path) -> None:
    """The old default (LeftFoot) on an Xsens BVH says which feet it has."""
    bvh = write(corpus / "xsens-flag.bvh", body_motion(CONVENTIONS["xsens-mvn"]))
    with pytest.raises(InputError, match="the feet found without flags are LeftAnkle and "
                                         "RightAnkle") as info:
        read_kinematics(bvh, accelerations=acc, left_foot="LeftFoot", right_foot="RightFoot")
    assert info.value.field == "left_foot"


def test_flags_override_the_feet_found(corpus: Path, acc: Path) -> None:
    bvh = write(corpus / "override.bvh", body_motion())
    rec = read_kinematics(bvh, accelerations=acc, left_foot="LeftToeBase",
                          right_foot="RightToeBase")
    assert (rec.left_foot, rec.right_foot) == ("LeftToeBase", "RightToeBase")
    assert any("as given" in n for n in rec.notes)


def test_missing_foot_lists_only_real_joints(corpus: Path, acc: Path) -> None:
    bvh = write(corpus / "missing.bvh", body_motion())
    with pytest.raises(InputError, match="'LFoot' not found in the BVH") as info:
        read_kinematics(bvh, accelerations=acc, left_foot="LFoot")
    assert "_end" not in info.value.detail
    assert "LeftToeBase" in info.value.detail
    rec = read_kinematics(bvh, accelerations=acc)
    with pytest.raises(InputError, match="joint 'LFoot' not found") as info:
        estimate_translation(rec, left_foot="LFoot")
    assert "_end" not in info.value.detail
    names = anonymous()
    flat = body_motion(names)
    # no names and no legs: every joint a child of the root
    parents = tuple(p if p < 0 or flat.is_end_site(j) else 0 for j, p in enumerate(flat.parents))
    flat = BvhMotion(flat.names, parents, flat.offsets, flat.channels, flat.frame_time,
                     flat.values)
    with pytest.raises(InputError, match=r"cannot find the feet.*pass left_foot") as info:
        read_kinematics(write(corpus / "flat.bvh", flat), accelerations=acc)
    assert "_end" not in info.value.detail


@pytest.mark.parametrize("unit", sorted(LENGTH_UNITS))
def test_length_units_are_inferred(unit: str, corpus: Path, acc: Path,
                                   canonical: dict[bool, NDArray[np.float64]]) -> None:
    bvh = write(corpus / f"unit-{unit}.bvh", body_motion(unit_m=LENGTH_UNITS[unit]))
    rec = read_kinematics(bvh, accelerations=acc)
    assert rec.length_scale == LENGTH_UNITS[unit]
    assert any(n.startswith(f"lengths in {unit} (inferred") for n in rec.notes)
    np.testing.assert_allclose(estimate_translation(rec).root, canonical[True], atol=1e-6)
    declared = root_path(bvh, acc, units=unit)
    np.testing.assert_allclose(declared, canonical[True], atol=1e-6)


def test_metres_per_unit_may_be_given(corpus: Path, acc: Path,
                                      canonical: dict[bool, NDArray[np.float64]]) -> None:
    bvh = write(corpus / "cmu-numeric.bvh", body_motion(unit_m=0.05644))
    rec = read_kinematics(bvh, accelerations=acc, units=0.05644)
    assert rec.length_scale == 0.05644
    rec = read_kinematics(bvh, accelerations=acc, units="0.05644")
    np.testing.assert_allclose(estimate_translation(rec).root, canonical[True], atol=1e-6)


@pytest.mark.parametrize(("file_unit", "declared"), [("cmu", "cm"), ("m", "cm"), ("cm", "m"),
                                                     ("cm", "in"), ("mm", "cm")])
def test_an_implausible_unit_is_refused_naming_the_likely_one(
        file_unit: str, declared: str, corpus: Path, acc: Path) -> None:
    bvh = write(corpus / f"wrong-{file_unit}.bvh", body_motion(unit_m=LENGTH_UNITS[file_unit]))
    with pytest.raises(InputError, match=f"pass units={file_unit}") as info:
        read_kinematics(bvh, accelerations=acc, units=declared)
    assert info.value.field == "units"
    assert f"with units {declared} the legs" in info.value.detail


def test_no_unit_fits_a_person(corpus: Path, acc: Path) -> None:
    bvh = write(corpus / "giant.bvh", body_motion(unit_m=1e-5))
    with pytest.raises(InputError, match=r"cannot infer the length unit.*pass units"):
        read_kinematics(bvh, accelerations=acc)
    with pytest.raises(InputError, match="unknown length unit 'furlong'"):
        read_kinematics(bvh, accelerations=acc, units="furlong")
    with pytest.raises(InputError, match="positive"):
        read_kinematics(bvh, accelerations=acc, units=-0.01)


QUIRKS: dict[str, dict[str, object]] = {
    "bom": {"bom": True},
    "crlf": {"newline": "\r\n"},
    "tabs": {"indent": "\t"},
    "brace-on-name-line": {"brace_on_name_line": True},
    "frames-larger-than-rows": {"frames": 10**9},
    "all-at-once": {"bom": True, "newline": "\r\n", "indent": "\t", "frames": 500},
}


@pytest.mark.parametrize("quirk", sorted(QUIRKS))
def test_quirks_read_like_blender(quirk: str, corpus: Path, acc: Path,
                                  canonical: dict[bool, NDArray[np.float64]]) -> None:
    names = CONVENTIONS["3ds-max-biped"]  # joint names with spaces
    bvh = write(corpus / f"quirk-{quirk}.bvh", body_motion(names), **QUIRKS[quirk])
    feet_acc = accelerations_csv(corpus / "biped.csv", names["l_foot"], names["r_foot"])
    rec = read_kinematics(bvh, accelerations=feet_acc)
    assert rec.left_foot == "Bip01 L Foot"
    if "frames" in QUIRKS[quirk]:
        assert any("header says" in n and "read 240" in n for n in rec.notes)
    np.testing.assert_allclose(estimate_translation(rec).root, canonical[True], atol=1e-6)


def test_truncated_last_row_names_its_line(corpus: Path, acc: Path) -> None:
    text = bvh_text(body_motion())
    lines = text.splitlines()
    lines[-1] = " ".join(lines[-1].split()[:7])
    bvh = corpus / "truncated.bvh"
    bvh.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match="truncated") as info:
        read_kinematics(bvh, accelerations=acc)
    assert info.value.line == len(lines)
    assert "column" not in info.value.detail  # numpy's "the number of columns changed"


def test_json_and_cli_report_the_feet_and_unit(corpus: Path, acc: Path, tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    bvh = write(corpus / "cli-xsens.bvh", body_motion(CONVENTIONS["xsens-mvn"],
                                                      unit_m=LENGTH_UNITS["cmu"]))
    rec = read_kinematics(bvh, accelerations=acc)
    result = estimate_translation(rec)
    data = translation_to_dict(result, rec)
    assert data["feet"] == {"left": "LeftAnkle", "right": "RightAnkle",
                            "toes": {"LeftAnkle": "LeftToe", "RightAnkle": "RightToe"}}
    for side, foot in (("left", "LeftAnkle"), ("right", "RightAnkle")):
        heights = np.asarray(data["foot_heights"][side])
        assert heights.shape == (rec.n_frames,)
        np.testing.assert_allclose(heights, result.positions[:, rec.index(foot), 1], atol=1e-5)
    assert np.ptp(data["foot_heights"]["left"]) > 0.02  # a walking foot lifts
    assert data["input_length_unit_m"] == LENGTH_UNITS["cmu"]
    assert main(["translate", str(bvh), "--accelerations", str(acc), "-o",
                 str(tmp_path / "o.bvh"), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "bonefit: feet: LeftAnkle (left), RightAnkle (right), found by name" in err
    assert "bonefit: lengths in cmu (inferred" in err
    assert main(["translate", str(bvh), "--accelerations", str(acc), "--units", "cm",
                 "-o", str(tmp_path / "x.bvh"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "pass units=cmu" in err[0]


@pytest.mark.parametrize(("name", "expected"), [
    ("LeftFoot", ("left", "foot")), ("RightAnkle", ("right", "foot")),
    ("mixamorig:LeftToeBase", ("left", "toe")), ("Foot_R", ("right", "foot")),
    ("lFoot", ("left", "foot")), ("rToe", ("right", "toe")), ("Bip01 L Toe0", ("left", "toe")),
    ("leftfoot", ("left", "foot")), ("LHipJoint", ("left", None)), ("lhand", (None, None)),
    ("Toes_L", ("left", "toe")), ("Hips", (None, None)), ("rfoot", ("right", "foot")),
    ("foot.L", ("left", "foot")), ("DEF-toe.R", ("right", "toe")), ("reye", (None, None)),
    ("Character1_LeftFoot", ("left", "foot")), ("ankle_l", ("left", "foot")),
])
def test_name_classification(name: str, expected: tuple[str | None, str | None]) -> None:
    assert classify(name) == expected


def test_feet_search_on_a_pathological_hierarchy_is_bounded() -> None:
    """10,000 nested joints all named LeftFoot: refused quickly, not O(J²) walks."""
    n = 10_000
    motion = BvhMotion(("Hips",) + ("LeftFoot",) * (n - 1), (-1, *range(n - 1)),
                       np.tile([0.0, -1.0, 0.0], (n, 1)), (("Xrotation",),) * n, 1 / 60,
                       np.zeros((2, n)))
    with pytest.raises(InputError, match="cannot find the feet"):
        find_bvh_feet(motion)


def test_sniff_reads_quirky_headers(corpus: Path) -> None:
    bvh = write(corpus / "sniff.bvh", body_motion(CONVENTIONS["3ds-max-biped"]), bom=True,
                newline="\r\n", frames=10**9)
    info = sniff_kinematics(bvh)
    assert info["format"] == "bvh"
    assert "Bip01 L Foot" in info["joints"]
    assert info["frames"] == 240  # the rows present, as read_bvh reads them
    bvh.write_text(bvh.read_text().replace("Frame Time:", "Frame Time: 0 #"))
    assert sniff_kinematics(bvh)["fps"] is None
    bvh.write_text(bvh.read_text().replace(f"Frames:  {10**9}", "Frames: lots"))
    with pytest.raises(InputError, match="bad Frames: line"):
        sniff_kinematics(bvh)
    bvh.write_text("HIERARCHY\nROOT r\n{\n" + "JOINT j\n{\n" * 20_000)
    with pytest.raises(InputError, match="more than 10000 joints"):
        sniff_kinematics(bvh)
