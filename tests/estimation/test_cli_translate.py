"""``bonefit translate``: outputs in the input's format, progress, exit code 2 on bad input."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from bonefit.cli import main
from bonefit.estimation.io.kinematics import read_kinematics, write_kinematics_csv
from bonefit.estimation.simulate.inertial import simulate_walker


@pytest.fixture(scope="module")
def walk_csv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    rec, _, _ = simulate_walker(fps=60)
    path = tmp_path_factory.mktemp("cli") / "walk.csv"
    write_kinematics_csv(rec, path)
    return path


def test_translate_writes_csv_bvh_and_json(walk_csv: Path, tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out.csv"
    code = main(["translate", str(walk_csv), "-o", str(out), "--bvh", str(tmp_path / "o.bvh"),
                 "--json", str(tmp_path / "o.json")])
    assert code == 0
    err = capsys.readouterr().err
    assert "100% writing" in err  # the run's progress ends with its writes
    assert "closure" in err
    with open(walk_csv, newline="") as a, open(out, newline="") as b:
        assert next(csv.reader(a)) == next(csv.reader(b))
    corrected = read_kinematics(out)
    hips = corrected.positions[:, 0]
    assert np.linalg.norm(hips[-1, [0, 2]] - hips[0, [0, 2]]) > 1.5  # the walker moved 2.1 m
    data = json.loads((tmp_path / "o.json").read_text())
    assert data["kind"] == "translation"
    assert data["method"] == "contact"
    assert len(data["contacts"]) == corrected.n_frames
    assert (tmp_path / "o.bvh").read_text().startswith("HIERARCHY")
    # the timings contract of every JSON result (README): the CLI measured all three
    assert list(data["timings"])[:3] == ["read_s", "estimate_s", "write_s"]
    assert all(data["timings"][k] > 0 for k in ("read_s", "estimate_s", "write_s"))


def test_translate_faithful_method(walk_csv: Path, tmp_path: Path) -> None:
    out = tmp_path / "paper.csv"
    assert main(["translate", str(walk_csv), "--method", "hachaj2018", "-o", str(out),
                 "--quiet"]) == 0
    assert out.is_file()


def test_missing_foot_exits_2_listing_joints(walk_csv: Path, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["translate", str(walk_csv), "--left-foot", "LFoot", "-o",
                 str(tmp_path / "x.csv")])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert err[0].startswith("bonefit: error:")
    assert "Hips, LeftFoot, LeftToe, RightFoot, RightToe" in err[0]


def test_missing_input_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["translate", str(tmp_path / "nope.csv"), "-o", str(tmp_path / "x")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_help_has_examples(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["translate", "--help"])
    text = capsys.readouterr().out
    assert "examples:" in text
    assert "--accelerations" in text
    assert "hachaj2018" in text
