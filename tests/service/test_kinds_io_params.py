"""The job kinds pass the tracker layout and the MVNX subject through to the readers."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from bonefit.estimation.errors import InputError
from bonefit.estimation.io.mvnx import y_up_to_z_up
from bonefit.estimation.simulate.inertial import simulate_walker
from bonefit.service.kinds import (
    Input,
    SkeletonParams,
    TranslationParams,
    run_skeleton,
    run_translation,
)

NS = "http://www.xsens.com/mvn/mvnx"
SEGMENTS = ("Pelvis", "LeftFoot", "RightFoot")


def no_progress(fraction: float, stage: str = "") -> None:
    """Progress callback that ignores reports."""


def test_skeleton_params_carry_the_tracker_layout(tmp_path: Path) -> None:
    path = tmp_path / "t.txt"
    path.write_text("1 1.0 2.0 3.0 0 0 0 0.5 2\n2 1.0 9.0 3.0 0 0 0 0.5 2\n")
    params = SkeletonParams(fps=60, stations={"1": "pelvis", "2": "chest"},
                            tracker_layout="station,x,y,z,az,el,roll")
    # the layout given is the one used: it has 7 columns where the file has 9
    with pytest.raises(InputError, match="has 9 fields; the layout 'station,x,y,z,az,el,roll'"):
        run_skeleton({"recording": Input(path, "tracker")}, params, no_progress, tmp_path)
    with pytest.raises(ValidationError):
        SkeletonParams(tracker_layout="x" * 201)


def mvnx_two_subjects(path: Path) -> None:
    _rec, truth, _ = simulate_walker(fps=60)
    free = {k: (truth.positions[2:, k] - 2 * truth.positions[1:-1, k]
                + truth.positions[:-2, k]) * 3600 for k in (1, 3)}
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', f'<mvnx version="4" xmlns="{NS}">']
    for label, shift in (("first", 0.0), ("second", 1.0)):
        lines += [f'<subject label="{label}" frameRate="60">', "<segments>"]
        lines += [f'<segment label="{s}" id="{i}"/>' for i, s in enumerate(SEGMENTS, 1)]
        lines += ["</segments>", "<sensors>"]
        lines += [f'<sensor label="{s}"/>' for s in SEGMENTS]
        lines += ["</sensors>", "<frames>"]
        for i in range(len(free[1])):
            pos = y_up_to_z_up(truth.positions[i + 1, [0, 1, 3]]) + np.array([0.0, shift, 0.0])
            acc = [0.0, 0.0, 0.0, *y_up_to_z_up(free[1][i]), *y_up_to_z_up(free[3][i])]
            lines += [f'<frame time="{round(i * 1000 / 60)}" type="normal">',
                      "<position>" + " ".join(f"{v:.6f}" for v in pos.ravel()) + "</position>",
                      "<sensorFreeAcceleration>" + " ".join(f"{v:.6f}" for v in acc)
                      + "</sensorFreeAcceleration>", "</frame>"]
        lines += ["</frames>", "</subject>"]
    lines.append("</mvnx>")
    path.write_text("\n".join(lines) + "\n")


def test_translation_params_carry_the_subject(tmp_path: Path) -> None:
    path = tmp_path / "duo.mvnx"
    mvnx_two_subjects(path)
    roots = {}
    for subject in ("first", "2"):
        out = tmp_path / subject
        out.mkdir()
        files = run_translation({"recording": Input(path, "mvnx")},
                                TranslationParams(subject=subject), no_progress, out)
        roots[subject] = json.loads(files["json"].read_text())["root"]
    # the second subject stands 1 m further along MVNX +y, which is Y-up -z
    assert roots["2"][0][2] == pytest.approx(roots["first"][0][2] - 1.0, abs=1e-3)
    with pytest.raises(InputError, match="no subject 'third'"):
        run_translation({"recording": Input(path, "mvnx")}, TranslationParams(subject="third"),
                        no_progress, tmp_path)


def test_a_skeleton_job_reports_the_runs_stages_in_order(tmp_path: Path) -> None:
    """The job's progress is the pipeline's, read to writes: non-decreasing, reading first,
    writing at 1 last, fractions inside the job from the read on."""
    from bonefit.estimation.io.sensors import example_path

    reports: list[tuple[float, str]] = []
    out = run_skeleton({"recording": Input(example_path(), "sensor-csv")}, SkeletonParams(),
                       lambda f, s: reports.append((f, s)), tmp_path)
    fractions = [f for f, _ in reports]
    assert fractions == sorted(fractions)
    assert (reports[0], reports[-1]) == ((0.0, "reading"), (1.0, "writing"))
    stages = [s for _, s in reports]
    assert stages.index("reading") < stages.index("gaps") < stages.index("writing")
    assert any(0.0 < f < 1.0 for f, s in reports if s == "reading")
    assert len({f for f, s in reports if s == "writing" and 0.0 < f < 1.0}) >= 3
    assert all(path.stat().st_size > 0 for path in out.values())


def test_a_job_writes_only_the_formats_asked_for(tmp_path: Path) -> None:
    """``formats`` chooses the files; those it writes are the default run's, byte for byte
    (the JSON apart from its timings)."""
    from bonefit.estimation.io.sensors import example_path

    source = {"recording": Input(example_path(), "sensor-csv")}
    every, some = tmp_path / "every", tmp_path / "some"
    every.mkdir()
    some.mkdir()
    all_files = run_skeleton(source, SkeletonParams(), no_progress, every)
    asked = run_skeleton(source, SkeletonParams(formats=["bvh", "json"]), no_progress, some)
    assert set(all_files) == {"json", "bvh", "csv", "npz"}
    assert set(asked) == {"json", "bvh"}
    assert sorted(p.name for p in some.iterdir()) == ["skeleton.bvh", "skeleton.json"]
    assert asked["bvh"].read_bytes() == all_files["bvh"].read_bytes()
    docs = [json.loads(files["json"].read_text()) for files in (all_files, asked)]
    for doc in docs:
        del doc["timings"]
    assert docs[0] == docs[1]


def test_a_translation_job_writes_only_the_formats_asked_for(tmp_path: Path) -> None:
    path = tmp_path / "duo.mvnx"
    mvnx_two_subjects(path)
    out = tmp_path / "out"
    out.mkdir()
    files = run_translation({"recording": Input(path, "mvnx")},
                            TranslationParams(formats=["npz", "json"]), no_progress, out)
    assert set(files) == {"json", "npz"}
    assert sorted(p.name for p in out.iterdir()) == ["translation.json", "translation.npz"]


@pytest.mark.parametrize("params", [SkeletonParams, TranslationParams])
def test_formats_must_name_the_json_and_known_formats(params: type[SkeletonParams]) -> None:
    assert params().formats == ("json", "bvh", "csv", "npz")
    assert params(formats=["json", "bvh", "json"]).formats == ("json", "bvh")
    for bad in (["bvh"], [], ["json", "xml"], "json", ["json"] * 5):
        with pytest.raises(ValidationError, match="formats"):
            params(formats=bad)
