"""``bonefit.estimation.io.sniff.sniff_file``: every format bonefit reads, told apart in the
library."""

from __future__ import annotations

from pathlib import Path

import pytest

from bonefit.estimation.errors import InputError
from bonefit.estimation.io.sensors import example_path
from bonefit.estimation.io.sniff import sniff_file


def test_a_sensor_csv_is_found_without_a_name() -> None:
    found, summary = sniff_file(example_path())
    assert (found, summary["format"], summary["frames"]) == ("csv", "csv", 300)


def test_accelerations_are_summarised_when_declared(tmp_path: Path) -> None:
    path = tmp_path / "feet.csv"
    path.write_text("time,LeftFoot.ax,LeftFoot.ay,LeftFoot.az\n0,0,1,0\n0.01,0,1,0\n")
    found, summary = sniff_file(path, "accelerations-csv")
    assert found == "accelerations-csv"
    assert (summary["frames"], summary["sensors"]) == (2, ["LeftFoot"])


def test_accelerations_without_a_sensor_are_refused(tmp_path: Path) -> None:
    path = tmp_path / "feet.csv"
    path.write_text("time,LeftFoot.ax\n0,0\n")
    with pytest.raises(InputError, match=r"no <Sensor>\.ax"):
        sniff_file(path, "accelerations-csv")


def test_a_bvh_is_found_by_its_name(tmp_path: Path) -> None:
    path = tmp_path / "take.bvh"
    path.write_text("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 3 Xposition Yposition "
                    "Zposition\n End Site\n {\n  OFFSET 0 10 0\n }\n}\nMOTION\nFrames: 2\n"
                    "Frame Time: 0.01\n0 0 0\n1 0 0\n")
    found, summary = sniff_file(path, filename="take.bvh")
    assert found == "bvh"
    assert summary["frames"] == 2
