"""``bonefit skeleton``: options, outputs and bad inputs (exit code 2 with a one-line reason)."""

from __future__ import annotations

import dataclasses
import importlib
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from bonefit.cli import main
from bonefit.estimation import skeleton as skeleton_module
from bonefit.estimation.bvh import forward_kinematics, read_bvh
from bonefit.estimation.io.sensors import example_path, read_recording, write_sensor_csv
from bonefit.estimation.io.skeleton import BVH_NODES, read_skeleton_npz
from bonefit.estimation.model import JOINTS, SEGMENTS
from bonefit.estimation.pipeline import import_meanwhile
from bonefit.estimation.recording import SensorRecording
from bonefit.estimation.results import SkeletonResult


@pytest.fixture(scope="module")
def walk() -> SensorRecording:
    return read_recording(example_path())


def run(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = main(["skeleton", "--quiet", *args])
    out, err = capsys.readouterr()
    return code, out, err


def assert_bad_input(code: int, err: str, *needles: str) -> None:
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("bonefit: error: ")
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


def subset(rec: SensorRecording, sensors: list[str]) -> SensorRecording:
    idx = [rec.index(s) for s in sensors]
    return SensorRecording(tuple(sensors), rec.positions[:, idx], rec.quaternions[:, idx],
                           rec.fps, rec.time)


# --------------------------------------------------------------------------- options


def test_help_shows_examples(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["skeleton", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "examples:" in out
    assert "bonefit skeleton walk.csv -o walk.json --bvh walk.bvh" in out
    assert "--stations" in out


@pytest.mark.parametrize(("args", "needles"), [
    (["--units", "furlong"], ["--units", "furlong"]),
    (["--up", "+w"], ["--up", "+w"]),
    (["--method", "magic"], ["--method", "magic"]),
    (["--optimizer", "bfgs"], ["--optimizer", "bfgs"]),
    (["--format", "c3d"], ["--format", "c3d"]),
    (["--fps", "-3"], ["--fps", "positive"]),
    (["--fps", "fast"], ["--fps", "number"]),
    (["--fps", "5e-324"], ["--fps", "1 Hz", "5e-324"]),
    (["--fps", "inf"], ["--fps", "10000 Hz"]),
    (["--i0", "x"], ["--i0", "number"]),
    (["--i0", "5000"], ["--i0", "past the last frame"]),
    (["--stations", "1:pelvis"], ["1:pelvis", "NUMBER=SEGMENT"]),
    (["--torso", "reduced"], ["--torso", "reduced"]),
    (["--anthropometry", "dreyfuss"], ["--anthropometry", "dreyfuss"]),
    (["--w-s", "heavy"], ["--w-s", "number"]),
    (["--w-l", "-1"], ["w_l", "-1"]),
])
def test_bad_option_values(capsys: pytest.CaptureFixture[str], args: list[str],
                           needles: list[str]) -> None:
    code, _, err = run(capsys, str(example_path()), *args)
    assert_bad_input(code, err, *needles)


def test_bad_input_and_output_paths(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert_bad_input(*run(capsys, str(tmp_path / "absent.csv"))[::2], "absent.csv")
    assert_bad_input(*run(capsys)[::2], "no INPUT")
    assert_bad_input(*run(capsys, "--example", "x.csv")[::2], "not both")
    assert_bad_input(*run(capsys, "--example", "-o", str(tmp_path / "no" / "r.json"))[::2],
                     "does not exist")
    assert not (tmp_path / "no").exists()


# --------------------------------------------------------------------------- bad files


def test_unknown_column(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    text = example_path().read_text().replace("l_hand.qz", "l_hand.quux", 1)
    (tmp_path / "r.csv").write_text(text)
    assert_bad_input(*run(capsys, str(tmp_path / "r.csv"))[::2], "unknown column 'l_hand.quux'")


def test_malformed_number_names_its_line(capsys: pytest.CaptureFixture[str],
                                         tmp_path: Path) -> None:
    lines = example_path().read_text().splitlines()
    cells = lines[41].split(",")
    cells[30] = "0.1o5"
    lines[41] = ",".join(cells)
    (tmp_path / "r.csv").write_text("\n".join(lines))
    assert_bad_input(*run(capsys, str(tmp_path / "r.csv"))[::2], "'0.1o5'", "line 42",
                     "column 31")


def test_all_nan_sensor(capsys: pytest.CaptureFixture[str], tmp_path: Path,
                        walk: SensorRecording) -> None:
    pos = walk.positions.copy()
    pos[:, walk.index("r_shank")] = np.nan
    write_sensor_csv(dataclasses.replace(walk, positions=pos), tmp_path / "r.csv")
    assert_bad_input(*run(capsys, str(tmp_path / "r.csv"))[::2], "'r_shank'", "no valid sample")


def test_positions_in_millimetres_declared_metres(capsys: pytest.CaptureFixture[str],
                                                  tmp_path: Path, walk: SensorRecording
                                                  ) -> None:
    write_sensor_csv(walk, tmp_path / "mm.csv", units="mm")
    code, _, err = run(capsys, str(tmp_path / "mm.csv"), "--units", "m")
    assert_bad_input(code, err, "--units")


def test_tracker_without_stations(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    (tmp_path / "t.txt").write_text("1 1 2 3 0 0 0\n2 4 5 6 0 0 0\n")
    assert_bad_input(*run(capsys, str(tmp_path / "t.txt"), "--fps", "60")[::2], "stations")


def test_missing_sensor(capsys: pytest.CaptureFixture[str], tmp_path: Path,
                        walk: SensorRecording) -> None:
    write_sensor_csv(subset(walk, [s for s in walk.sensors if s != "l_hand"]),
                     tmp_path / "r.csv")
    assert_bad_input(*run(capsys, str(tmp_path / "r.csv"))[::2], "'l_hand'", "missing")


def test_too_little_motion(capsys: pytest.CaptureFixture[str], tmp_path: Path,
                           walk: SensorRecording) -> None:
    still = dataclasses.replace(walk, positions=np.repeat(walk.positions[:1], 100, axis=0),
                                quaternions=np.repeat(walk.quaternions[:1], 100, axis=0),
                                time=walk.time[:100])
    write_sensor_csv(still, tmp_path / "r.csv")
    code, _, err = run(capsys, str(tmp_path / "r.csv"))
    assert_bad_input(code, err)
    assert "motion" in err or "move" in err


@pytest.mark.parametrize("scale", [3.0, 0.0254])
def test_bone_lengths_outside_human_range(capsys: pytest.CaptureFixture[str], tmp_path: Path,
                                          walk: SensorRecording, scale: float) -> None:
    # 3×: a 5 m tall body; 0.0254: metres read as inches. Both pass the reader's coarse check.
    write_sensor_csv(dataclasses.replace(walk, positions=walk.positions * scale),
                     tmp_path / "r.csv")
    code, _, err = run(capsys, str(tmp_path / "r.csv"))
    assert_bad_input(code, err, "units")


# --------------------------------------------------------------------------- outputs


def fake_result(rec: SensorRecording) -> SkeletonResult:
    """A rigid stand-in: joints at fixed offsets from a moving root, segments unrotated."""
    n = rec.n_frames
    root = np.nanmean(rec.positions, axis=1)
    rest = {"root": np.zeros(3)}
    for k, (node, parent, _) in enumerate(BVH_NODES[1:], 1):
        assert parent is not None
        rest[node] = rest[parent] + np.array([0.01 * k, -0.1, 0.02])
    identity = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    return SkeletonResult(
        method="fake", fps=rec.fps, joints={j: root + rest[j] for j in JOINTS}, offsets={},
        bone_lengths={"l_thigh": 0.4},
        orientations=dict.fromkeys((*SEGMENTS, "spine", "cervical"), identity),
        quality={"l_knee": {"rms_residual_m": 0.0012, "data_sd_m": 0.0347, "hinge": True,
                            "estimator": "fake"}},
        warnings=("a warning",), timings={"estimate_s": 0.25})


def test_options_reach_the_estimator_and_outputs_are_written(
        capsys: pytest.CaptureFixture[str], tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[dict[str, Any]] = []

    def estimate(rec: SensorRecording, **kwargs: Any) -> SkeletonResult:
        calls.append(kwargs)
        return fake_result(rec)

    monkeypatch.setattr(skeleton_module, "estimate_skeleton", estimate)
    code, out, err = run(capsys, "--example", "--method", "reduced", "--optimizer",
                         "Nelder-Mead", "--up=-z", "--i0", "7", "-o", str(tmp_path / "r.json"),
                         "--bvh", str(tmp_path / "r.bvh"), "--csv", str(tmp_path / "r.csv"),
                         "--npz", str(tmp_path / "r.npz"))
    assert (code, out, err) == (0, "", "")
    assert calls == [{"method": "reduced", "optimizer": "nelder-mead", "torso": "llsf",
                      "up": (0.0, 0.0, -1.0), "i0": 7, "anthropometry": "aist", "w_s": 0.01,
                      "w_l": 0.01, "smooth": None, "progress": None}]
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["method"] == "fake"
    assert doc["frames"] == 300
    assert set(doc["timings"]) == {"read_s", "estimate_s", "write_s"}
    assert doc["timings"]["estimate_s"] == 0.25  # the estimator's own figure is kept
    assert all(v >= 0 for v in doc["timings"].values())
    positions, _ = forward_kinematics(read_bvh(tmp_path / "r.bvh"))
    np.testing.assert_allclose(positions[:, 0] / 100, doc["joints"]["root"], atol=1e-6)
    assert len((tmp_path / "r.csv").read_text().splitlines()) == 301
    binary = read_skeleton_npz(tmp_path / "r.npz")
    np.testing.assert_allclose(binary.joints["root"], doc["joints"]["root"], atol=5e-7)
    assert binary.timings["estimate_s"] == 0.25


def test_fit_options_reach_the_estimator(capsys: pytest.CaptureFixture[str], tmp_path: Path,
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[dict[str, Any]] = []

    def estimate(rec: SensorRecording, **kwargs: Any) -> SkeletonResult:
        calls.append(kwargs)
        return fake_result(rec)

    monkeypatch.setattr(skeleton_module, "estimate_skeleton", estimate)
    table = {"torso": 52.0, "thigh": 42.0, "shank": 41.0, "upperarm": 30.0, "forearm": 25.0}
    (tmp_path / "table.json").write_text(json.dumps(table))
    code, _, err = run(capsys, "--example", "--method", "reduced", "--torso", "GDKE",
                       "--anthropometry", str(tmp_path / "table.json"), "--w-s", "0.5",
                       "--w-l", "0", "--no-smooth")
    assert code == 0, err
    assert [{k: c[k] for k in ("torso", "anthropometry", "w_s", "w_l", "smooth")}
            for c in calls] == [{"torso": "gdke", "anthropometry": table, "w_s": 0.5,
                                 "w_l": 0.0, "smooth": False}]
    calls.clear()
    assert run(capsys, "--example", "--anthropometry", "Winter", "--smooth")[0] == 0
    assert (calls[0]["anthropometry"], calls[0]["smooth"]) == ("winter", True)


def test_unwritable_output_is_bad_input(capsys: pytest.CaptureFixture[str],
                                        tmp_path: Path) -> None:
    (tmp_path / "taken.json").mkdir()
    code, _, err = run(capsys, "--example", "--method", "llsf",
                       "-o", str(tmp_path / "taken.json"))
    assert_bad_input(code, err, "cannot write", "taken.json")


def test_summary_without_output(capsys: pytest.CaptureFixture[str],
                                monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(skeleton_module, "estimate_skeleton",
                        lambda rec, **kwargs: fake_result(rec))
    code, out, _ = run(capsys, "--example")
    assert code == 0
    assert "method fake, 300 frames at 60 Hz, 15 sensors" in out
    assert "l_thigh" in out
    assert "40.0" in out        # bone length in cm
    assert "l_knee" in out
    assert "1.2" in out         # rms residual in mm
    assert "data sd mm" in out
    assert "34.7" in out        # the data's uncertainty of the joint, mm
    assert "warning: a warning" in out


def test_progress_bar_goes_to_stderr(capsys: pytest.CaptureFixture[str],
                                     monkeypatch: pytest.MonkeyPatch) -> None:
    def estimate(rec: SensorRecording, *, progress: Any, **kwargs: Any) -> SkeletonResult:
        progress(0.0, "locating")
        progress(1.0, "done")
        return fake_result(rec)

    monkeypatch.setattr(skeleton_module, "estimate_skeleton", estimate)
    assert main(["skeleton", "--example"]) == 0
    out, err = capsys.readouterr()
    assert "locating" in err
    assert "locating" not in out


def joints_of(path: Path) -> dict[str, NDArray[np.float64]]:
    doc = json.loads(path.read_text())
    return {k: np.asarray(v) for k, v in doc["joints"].items()}


def test_bundled_example_end_to_end(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    code, _out, err = run(capsys, "--example", "-o", str(tmp_path / "w.json"),
                         "--bvh", str(tmp_path / "w.bvh"), "--csv", str(tmp_path / "w.csv"))
    assert code == 0, err
    doc = json.loads((tmp_path / "w.json").read_text())
    assert doc["kind"] == "skeleton"
    assert doc["frames"] == 300
    assert list(doc["joints"]) == list(JOINTS)
    assert all(np.isfinite(np.asarray(v)).all() for v in doc["joints"].values())
    assert {"read_s", "estimate_s", "write_s"} <= set(doc["timings"])
    # the example's true bone lengths (scripts/make_example.py)
    for seg, length in {"l_thigh": 0.42, "r_shank": 0.41, "l_upperarm": 0.29,
                        "r_forearm": 0.26}.items():
        assert doc["bone_lengths"][seg] == pytest.approx(length, abs=0.02), seg
    motion = read_bvh(tmp_path / "w.bvh")
    positions, _ = forward_kinematics(motion)
    for joint in JOINTS:
        err_m = np.linalg.norm(positions[:, motion.index(joint)] / 100
                               - np.asarray(doc["joints"][joint]), axis=-1)
        assert np.median(err_m) < 0.02, joint  # mean-offset skeleton vs per-frame joints
    table = np.loadtxt(tmp_path / "w.csv", delimiter=",", skiprows=1)
    assert table.shape == (300, 1 + 3 * len(JOINTS))
    np.testing.assert_allclose(table[:, 1:4], doc["joints"]["root"], atol=2e-6)


@pytest.mark.parametrize("chains", [False, True])
def test_the_bvh_puts_the_joints_where_the_json_has_them(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, chains: bool) -> None:
    # auto's joints lie on a rigid tree of bones: the default file is exact, and slip
    # chains find nothing to carry
    code, _out, err = run(capsys, "--example", "-o", str(tmp_path / "w.json"),
                          "--bvh", str(tmp_path / "w.bvh"),
                          "--bvh-slip-chains" if chains else "--no-bvh-slip-chains")
    assert code == 0, err
    doc = json.loads((tmp_path / "w.json").read_text())
    motion = read_bvh(tmp_path / "w.bvh")
    assert not any(name.endswith("_slip_base") for name in motion.names)
    positions, _ = forward_kinematics(motion)
    for joint in JOINTS:
        err_m = np.linalg.norm(positions[:, motion.index(joint)] / 100
                               - np.asarray(doc["joints"][joint]), axis=-1)
        assert err_m.max() < 1e-5, joint  # the file's rounding only, at every frame


def test_tracker_file_gives_the_same_skeleton_as_csv(capsys: pytest.CaptureFixture[str],
                                                     tmp_path: Path,
                                                     walk: SensorRecording) -> None:
    lines = []
    for f in range(walk.n_frames):
        for s in range(len(walk.sensors)):
            if walk.valid()[f, s]:
                p = walk.positions[f, s] / 0.0254
                q = walk.quaternions[f, s]
                lines.append(f"{s + 1:2d} " + " ".join(f"{v:.7f}" for v in (*p, *q)))
    (tmp_path / "take.txt").write_text("\n".join(lines) + "\n")
    stations = ",".join(f"{i + 1}={s}" for i, s in enumerate(walk.sensors))
    assert run(capsys, str(tmp_path / "take.txt"), "--stations", stations, "--fps", "60",
               "-o", str(tmp_path / "t.json"))[0] == 0
    assert run(capsys, "--example", "-o", str(tmp_path / "c.json"))[0] == 0
    tracker, csv = joints_of(tmp_path / "t.json"), joints_of(tmp_path / "c.json")
    for joint in JOINTS:
        np.testing.assert_allclose(tracker[joint], csv[joint], atol=1e-4)


def test_offsets_from_a_calibration_file(capsys: pytest.CaptureFixture[str],
                                         tmp_path: Path) -> None:
    calibration = tmp_path / "calibration.json"
    code, _out, err = run(capsys, "--example", "-o", str(calibration))
    assert code == 0, err
    doc = json.loads(calibration.read_text())
    code, _out, err = run(capsys, "--example", "--offsets", str(calibration), "-o",
                          str(tmp_path / "take.json"))
    assert code == 0, err
    take = json.loads((tmp_path / "take.json").read_text())
    assert take["method"] == "offsets"
    assert take["offsets"] == doc["offsets"]
    # the same recording: the calibrated joints are the fitted ones up to the fit's
    # per-frame scatter about its offsets (auto smooths and averages both sensors)
    for joint in JOINTS:
        gap = np.linalg.norm(np.asarray(take["joints"][joint])
                             - np.asarray(doc["joints"][joint]), axis=-1)
        assert np.median(gap) < 0.01, joint
    # an offsets-only document is a calibration too
    only = tmp_path / "only.json"
    only.write_text(json.dumps({"offsets": doc["offsets"]}))
    code, _out, err = run(capsys, "--example", "--offsets", str(only))
    assert code == 0, err


def test_bad_calibration_files(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    broken = tmp_path / "broken.json"
    broken.write_text('{"offsets": {"neck": ')
    assert_bad_input(*run(capsys, "--example", "--offsets", str(broken))[::2], "line 1")
    none = tmp_path / "none.json"
    none.write_text('{"kind": "skeleton"}')
    assert_bad_input(*run(capsys, "--example", "--offsets", str(none))[::2], "offsets")
    bad = tmp_path / "bad.json"
    bad.write_text('{"offsets": {"neck": {"sensor": "chest", "local": [0, 1]}}}')
    assert_bad_input(*run(capsys, "--example", "--offsets", str(bad))[::2], "offsets.neck")
    partial = tmp_path / "partial.json"
    partial.write_text('{"offsets": {"neck": {"sensor": "chest", "local": [0, 0.1, 0]}}}')
    assert_bad_input(*run(capsys, "--example", "--offsets", str(partial))[::2],
                     "no offset for joint")
    assert_bad_input(*run(capsys, "--example", "--offsets", str(tmp_path / "nope.json"))[::2],
                     "nope.json")


# --------------------------------------------------------------------------- start-up


def test_the_command_starts_without_scipy_and_loads_it_while_reading() -> None:
    """scipy and the estimators (about a second) are imported by a thread while the
    recording is parsed, not before the read starts."""
    script = (
        "import sys\n"
        "from bonefit.estimation.cli import skeleton\n"
        "assert 'scipy' not in sys.modules, 'scipy loaded before the run'\n"
        "from bonefit.estimation import pipeline\n"
        "from bonefit.estimation.io import sensors\n"
        "seen = []\n"
        "read = sensors.read_recording\n"
        "def reading(*args, **kwargs):\n"
        "    pipeline_thread = [t.name for t in __import__('threading').enumerate()]\n"
        "    seen.append('bonefit-import' in pipeline_thread)\n"
        "    return read(*args, **kwargs)\n"
        "sensors.read_recording = reading\n"
        "from bonefit.cli import main\n"
        f"code = main(['skeleton', '--quiet', {str(example_path())!r}])\n"
        "assert code == 0 and seen == [True], (code, seen)\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=300, check=False)
    assert done.returncode == 0, done.stderr


def test_a_failed_import_meanwhile_is_left_to_the_caller(recwarn: pytest.WarningsRecorder
                                                         ) -> None:
    thread = import_meanwhile(["bonefit.no_such_module", "json"])
    thread.join(timeout=60)
    assert not thread.is_alive()
    assert not recwarn.list  # no unhandled exception in the thread
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module("bonefit.no_such_module")
    sys.modules.pop("colorsys", None)  # a small module nothing here has imported
    import_meanwhile(["colorsys"]).join(timeout=60)
    assert "colorsys" in sys.modules
