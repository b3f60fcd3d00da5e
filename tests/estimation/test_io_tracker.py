"""Tracker exports as the devices' software writes them: one motion, every layout.

Every variant is written from the same synthetic motion (quantised once to what the coarsest
layout carries: 0.01 inch, 0.01 degree) and must give the joints of the canonical sensor CSV
of that motion to 0.1 mm.
"""

from __future__ import annotations

import contextlib
import json
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from bonefit.cli import main
from bonefit.estimation.errors import BonefitError, InputError
from bonefit.estimation.io.sensors import (
    detect_format,
    read_recording,
    sniff_recording,
    write_sensor_csv,
)
from bonefit.estimation.io.tracker import (
    MAX_STATIONS,
    detect_tracker_layout,
    parse_tracker_layout,
    read_tracker_ascii,
)
from bonefit.estimation.recording import SensorRecording
from bonefit.estimation.simulate.sensors import example_motion, simulate_sensors
from bonefit.estimation.skeleton import estimate_skeleton

FPS = 60.0
N_FRAMES = 150
DROPPED = (40, 41, 97)  # whole frames missing from the variants with a counter or time


@dataclass(frozen=True)
class Motion:
    sensors: tuple[str, ...]
    inches: NDArray[np.float64]   # (F, S, 3), two decimals
    angles: NDArray[np.float64]   # (F, S, 3) azimuth, elevation, roll, degrees, two decimals
    quats: NDArray[np.float64]    # (F, S, 4) w, x, y, z of those angles

    @property
    def stations(self) -> str:
        return ",".join(f"{i + 1}={s}" for i, s in enumerate(self.sensors))

    def recording(self, dropped: tuple[int, ...] = ()) -> SensorRecording:
        pos = self.inches * 0.0254
        quats = self.quats.copy()
        pos[list(dropped)] = np.nan
        quats[list(dropped)] = np.nan
        return SensorRecording(self.sensors, pos, quats, FPS, np.arange(N_FRAMES) / FPS)


@pytest.fixture(scope="module")
def motion() -> Motion:
    rec, _ = simulate_sensors(example_motion(n_frames=N_FRAMES, fps=FPS), units_m=0.01,
                              drop_fraction=0.0, seed=3)
    inches = np.round(rec.positions / 0.0254, 2)
    rot = Rotation.from_quat(rec.quaternions.reshape(-1, 4), scalar_first=True)
    angles = np.round(rot.as_euler("ZYX", degrees=True), 2)
    quats = Rotation.from_euler("ZYX", angles, degrees=True).as_quat(scalar_first=True)
    shape = rec.positions.shape[:2]
    return Motion(rec.sensors, inches, angles.reshape(*shape, 3), quats.reshape(*shape, 4))


def joints_of(rec: SensorRecording) -> dict[str, NDArray[np.float64]]:
    return {k: np.asarray(v) for k, v in estimate_skeleton(rec).joints.items()}


@pytest.fixture(scope="module")
def canonical(motion: Motion, tmp_path_factory: pytest.TempPathFactory
              ) -> dict[bool, dict[str, NDArray[np.float64]]]:
    """Joints from the canonical sensor CSV, without and with the dropped frames."""
    out = {}
    for gappy in (False, True):
        path = tmp_path_factory.mktemp("canonical") / "take.csv"
        write_sensor_csv(motion.recording(DROPPED if gappy else ()), path, units="in",
                         decimals=9)
        out[gappy] = joints_of(read_recording(path))
    return out


def f2(v: float) -> str:
    return f"{v:.2f}"


def records(m: Motion, fmt: Callable[[int, int], str | None],
            dropped: tuple[int, ...] = ()) -> list[str]:
    """``fmt(frame, sensor)`` of every sample, station by station, frame by frame."""
    lines = []
    for f in range(N_FRAMES):
        if f in dropped:
            continue
        for s in range(len(m.sensors)):
            text = fmt(f, s)
            if text is not None:
                lines.append(text)
    return lines


def euler_fields(m: Motion, f: int, s: int, sep: str = " ") -> str:
    return sep.join(f2(v) for v in (*m.inches[f, s], *m.angles[f, s]))


def quat_fields(m: Motion, f: int, s: int, order: str = "wxyz", sep: str = " ", *,
                metres: bool = False) -> str:
    q = dict(zip("wxyz", m.quats[f, s], strict=True))
    pos = [f"{v * 0.0254:.9f}" if metres else f2(v) for v in m.inches[f, s]]
    return sep.join([*pos, *(f"{q[c]:.9f}" for c in order)])


def plain(m: Motion) -> str:
    return "\n".join(records(m, lambda f, s: f"{s + 1:2d} {euler_fields(m, f, s)}")) + "\n"


def header_row(m: Motion) -> str:
    return "Station X Y Z Azimuth Elevation Roll\n" + plain(m)


def banner(m: Motion) -> str:
    return ("Polhemus LIBERTY  Ver 2.1\nRecorded 2026-11-26 10:00:00 by PiMgr\n\n" + plain(m))


def quaternion(m: Motion) -> str:
    return "\n".join(records(m, lambda f, s: f"{s + 1} {quat_fields(m, f, s)}")) + "\n"


def glued(m: Motion) -> str:
    """Fixed-width 7-character fields: a negative three-digit angle touches its neighbour."""
    def fmt(f: int, s: int) -> str:
        return f"{s + 1:2d}" + "".join(f"{v:7.2f}" for v in (*m.inches[f, s], *m.angles[f, s]))
    return "\n".join(records(m, fmt)) + "\n"


def extra_station(m: Motion) -> str:
    lines = []
    for f in range(N_FRAMES):
        lines += [f"{s + 1:2d} {euler_fields(m, f, s)}" for s in range(len(m.sensors))]
        lines.append(f"16 {f2(f * 0.1)} 1.00 2.00 {f2(f % 90)} 0.00 0.00")
    return "\n".join(lines) + "\n"


def frame_counter(m: Motion) -> str:
    return "\n".join(records(m, lambda f, s: f"{1000 + f} {s + 1} {euler_fields(m, f, s)}",
                             DROPPED)) + "\n"


def timestamp_ms(m: Motion) -> str:
    return "\n".join(records(m, lambda f, s: f"{round(f * 1000 / FPS) + 5000} {s + 1} "
                                             f"{euler_fields(m, f, s)}", DROPPED)) + "\n"


def trakstar(m: Motion) -> str:
    """ATC3DG sample style: station x y z a e r time quality."""
    return "\n".join(records(m, lambda f, s: f"{s + 1} {euler_fields(m, f, s)} "
                                             f"{12.5 + f / FPS:.4f} {(f * 7 + s) % 5}",
                             DROPPED)) + "\n"


def ros_csv(m: Motion) -> str:
    """``rostopic echo -p`` of PoseStamped, every sensor on one topic, no ids, w last, m."""
    head = ("%time,field.header.seq,field.header.stamp,field.header.frame_id,"
            "field.pose.position.x,field.pose.position.y,field.pose.position.z,"
            "field.pose.orientation.x,field.pose.orientation.y,field.pose.orientation.z,"
            "field.pose.orientation.w")
    t0 = 1_764_151_200_000_000_000

    def fmt(f: int, s: int) -> str:
        stamp = t0 + round(f * 1e9 / FPS)
        return (f"{stamp + 1000 * s + 250_000},{f * len(m.sensors) + s},{stamp},tracker,"
                + quat_fields(m, f, s, "xyzw", ",", metres=True))
    return head + "\n" + "\n".join(records(m, fmt, DROPPED)) + "\n"


VARIANTS: dict[str, tuple[Callable[[Motion], str], dict[str, object], bool]] = {
    # name: (writer, reader arguments besides stations, has dropped frames)
    "plain": (plain, {"fps": FPS}, False),
    "header-row": (header_row, {"fps": FPS}, False),
    "banner": (banner, {"fps": FPS}, False),
    "quaternion": (quaternion, {"fps": FPS}, False),
    "fixed-width-glued": (glued, {"fps": FPS}, False),
    "extra-station": (extra_station, {"fps": FPS}, False),
    "frame-counter": (frame_counter, {"fps": FPS}, True),
    "timestamp-ms": (timestamp_ms, {}, True),
    "trakstar-time-quality": (trakstar, {}, True),
    "ros-csv": (ros_csv, {}, True),
}


@pytest.mark.parametrize("name", list(VARIANTS))
def test_every_layout_gives_the_joints_of_the_canonical_csv(
        name: str, motion: Motion, canonical: dict[bool, dict[str, NDArray[np.float64]]],
        tmp_path: Path) -> None:
    writer, kwargs, gappy = VARIANTS[name]
    path = tmp_path / ("take.csv" if name == "ros-csv" else "take.txt")
    path.write_text(writer(motion), encoding="utf-8")
    assert detect_format(path) == "tracker"
    rec = read_recording(path, stations=motion.stations, **kwargs)  # type: ignore[arg-type]
    assert rec.fps == FPS
    assert rec.n_frames == N_FRAMES
    assert rec.valid()[list(DROPPED)].any() != gappy
    joints = joints_of(rec)
    for joint, expected in canonical[gappy].items():
        np.testing.assert_allclose(joints[joint], expected, atol=1e-4, err_msg=joint)
    if gappy:
        assert any("3 dropped frame(s)" in w for w in rec.warnings)


def test_detected_layouts_are_described(motion: Motion, tmp_path: Path) -> None:
    expected = {
        "plain": "station,x,y,z,az,el,roll",
        "header-row": "station,x,y,z,az,el,roll;skip=1",
        "banner": "station,x,y,z,az,el,roll;skip=2",
        "quaternion": "station,x,y,z,qw,qx,qy,qz",
        "frame-counter": "frame,station,x,y,z,az,el,roll",
        "timestamp-ms": "time,station,x,y,z,az,el,roll;time=ms",
        "trakstar-time-quality": "station,x,y,z,az,el,roll,time,quality;time=s",
        "ros-csv": "-,-,time,-,x,y,z,qx,qy,qz,qw;time=ns;skip=1;units=m",
    }
    for name, spec in expected.items():
        path = tmp_path / f"{name}.txt"
        path.write_text(VARIANTS[name][0](motion), encoding="utf-8")
        layout = detect_tracker_layout(path)
        assert layout.spec() == spec, name
        assert parse_tracker_layout(spec) == layout
        assert spec in layout.describe()
    assert "quaternion xyzw" in detect_tracker_layout(tmp_path / "ros-csv.txt").describe()


def test_unmapped_station_is_a_warning(motion: Motion, tmp_path: Path) -> None:
    path = tmp_path / "extra.txt"
    path.write_text(extra_station(motion), encoding="utf-8")
    rec = read_tracker_ascii(path, stations=motion.stations, fps=FPS)
    assert rec.sensors == motion.sensors
    assert [w for w in rec.warnings if "station 16" in w and "ignored" in w]
    assert sniff_recording(path)["sensors"] == [str(n) for n in range(1, 17)]


def fastrak_line(station: int, error: str, values: NDArray[np.float64]) -> str:
    return f"0{station}{error}" + "".join(f"{v:7.2f}" for v in values)


def test_fastrak_records_with_glued_angles_and_error_codes(motion: Motion,
                                                           tmp_path: Path) -> None:
    # FASTRAK has four receivers: the first four sensors of the motion, Euler output
    lines = []
    for f in range(N_FRAMES):
        for s in range(4):
            error = "E" if (f, s) in ((3, 1), (90, 2)) else " "
            lines.append(fastrak_line(s + 1, error,
                                      np.concatenate([motion.inches[f, s], motion.angles[f, s]])))
    text = "\r\n".join(lines) + "\r\n"
    assert re.search(r"\d-\d{3}\.", text)  # glued: "12.34-123.45"
    path = tmp_path / "fastrak.txt"
    path.write_text(text, encoding="utf-8")
    layout = detect_tracker_layout(path)
    assert layout.fastrak
    assert layout.spec() == "station,quality,x,y,z,az,el,roll;fastrak"
    stations = ",".join(f"{i + 1}={s}" for i, s in enumerate(motion.sensors[:4]))
    rec = read_recording(path, stations=stations, fps=FPS)  # inches by default
    expected = motion.recording()
    np.testing.assert_allclose(rec.positions, expected.positions[:, :4], atol=1e-12)
    same = np.abs(np.sum(rec.quaternions * expected.quaternions[:, :4], axis=-1))
    np.testing.assert_allclose(same, 1.0, atol=1e-9)
    assert any("2 FASTRAK record(s) carry an error code" in w for w in rec.warnings)
    assert sniff_recording(path)["frames"] == N_FRAMES


def test_explicit_layout_overrides_detection(motion: Motion, tmp_path: Path) -> None:
    path = tmp_path / "q.txt"
    # w last without any hint in the data: detection assumes w first, the spec says otherwise
    path.write_text("\n".join(records(motion, lambda f, s: f"{s + 1} "
                                      + quat_fields(motion, f, s, "xyzw"))) + "\n")
    rec = read_recording(path, stations=motion.stations, fps=FPS,
                         tracker_layout="station,x,y,z,qx,qy,qz,qw")
    np.testing.assert_allclose(np.abs(np.sum(rec.quaternions * motion.quats, axis=-1)), 1.0,
                               atol=1e-8)
    for bad, message in [("station,x,y,z,az,el", "three angles"),
                         ("station,x,y,x,az,el,roll", "appears twice"),
                         ("station,x,y,z,az,el,roll,speed", "unknown column 'speed'"),
                         ("station,x,y,z,az,el,roll;time=weeks", "unknown tracker layout option")]:
        with pytest.raises(InputError, match=message) as err:
            parse_tracker_layout(bad)
        assert err.value.field == "tracker_layout"
    with pytest.raises(InputError, match="line 1 has 8 fields; the layout") as err:
        read_recording(path, stations=motion.stations, fps=FPS,
                       tracker_layout="station,x,y,z,az,el,roll")
    assert err.value.line == 1


def test_counter_going_back_or_jumping_is_refused(tmp_path: Path) -> None:
    rows = ["1 1 1.0 2.0 3.0 0 0 0", "1 2 1.0 9.0 3.0 0 0 0", "2 1 1.0 2.0 3.0 0 0 0",
            "2 2 1.0 9.0 3.0 0 0 0"]
    spec = "frame,station,x,y,z,az,el,roll"
    back = tmp_path / "back.txt"
    back.write_text("\n".join([*rows, "1 1 1.0 2.0 3.0 0 0 0"]) + "\n")
    with pytest.raises(InputError, match="frame counter goes back from 2 to 1 at line 5"):
        read_tracker_ascii(back, stations="1=pelvis,2=chest", fps=60, layout=spec)
    jump = tmp_path / "jump.txt"
    jump.write_text("\n".join([*rows, "9000000000 1 1.0 2.0 3.0 0 0 0"]) + "\n")
    with pytest.raises(InputError, match=r"skips .* frames \(limit"):
        read_tracker_ascii(jump, stations="1=pelvis,2=chest", fps=60, layout=spec)


# --------------------------------------------------------------------------- bombs, fuzz


def test_eighty_thousand_stations_are_refused_at_the_limit(tmp_path: Path) -> None:
    path = tmp_path / "bomb.txt"
    path.write_text("".join(f"{n * 7919 % 80_000} 1.0 2.0 3.0 0 0 0\n" for n in range(80_000)))
    assert path.stat().st_size > 1_000_000
    for call in (lambda: read_tracker_ascii(path, stations="0=pelvis", fps=60),
                 lambda: sniff_recording(path), lambda: read_recording(path)):
        with pytest.raises(InputError, match=f"more than {MAX_STATIONS} stations") as err:
            call()
        assert err.value.line == MAX_STATIONS + 1  # refused on reaching the limit


@settings(max_examples=150, deadline=None)
@given(lines=st.lists(st.one_of(
    st.sampled_from(["1 1.0 2.0 3.0 10 20 30", "2 1.5 2.0 3.0 -170.00 0 5",
                     "01E  1.00  2.00  3.00-123.45  0.00  0.00", "%time,field.x",
                     "Station X Y Z A E R", "3 1 2 3 1 0 0 0", "# fps: 0", "# stations: 1=x",
                     "1,2,3,4,5,6,7,8,9", "nan nan nan nan nan nan nan", "1e308 1 1 1 1 1 1"]),
    st.text(alphabet="0123456789 .-+eE,;\t%abxyz#=:", max_size=60)), max_size=25),
    layout=st.sampled_from([None, "station,x,y,z,az,el,roll", "time,x,y,z,qx,qy,qz,qw"]))
def test_fuzzed_tracker_files_raise_only_bonefit_errors(lines: list[str], layout: str | None,
                                                        tmp_path_factory: pytest.TempPathFactory
                                                        ) -> None:
    path = tmp_path_factory.mktemp("fuzz") / "f.txt"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    for call in (lambda: read_tracker_ascii(path, stations="1=pelvis,2=chest,3=head", fps=60,
                                            layout=layout),
                 lambda: sniff_recording(path, "tracker"),
                 lambda: detect_format(path)):
        with contextlib.suppress(BonefitError):
            call()


def test_counter_with_a_dropped_frame_is_a_counter_not_a_time(tmp_path: Path) -> None:
    path = tmp_path / "c.txt"
    path.write_text("1000 1 10.00 20.00 -30.00 90.00 0.00 0.00\n"
                    "1000 2 12.00 30.00 -31.00 30.00 20.00 -40.00\n"
                    "1002 1 10.50 20.00 -30.00 45.00 10.00 5.00\n"
                    "1002 2 12.50 30.00 -31.00 30.00 20.00 -40.00\n"
                    "1003 1 11.00 20.00 -30.00 40.00 10.00 5.00\n"
                    "1003 2 13.00 30.00 -31.00 31.00 21.00 -41.00\n")
    assert detect_tracker_layout(path).spec() == "frame,station,x,y,z,az,el,roll"
    rec = read_tracker_ascii(path, stations="1=pelvis,2=chest", fps=240)
    assert rec.valid().tolist() == [[True, True], [False, False], [True, True], [True, True]]


def test_cli_prints_the_detected_layout_and_takes_an_explicit_one(
        motion: Motion, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    path = tmp_path / "take.txt"
    path.write_text(trakstar(motion), encoding="utf-8")
    assert main(["skeleton", "--quiet", str(path), "--format", "tracker", "--stations",
                 motion.stations, "-o", str(tmp_path / "a.json")]) == 0
    err = capsys.readouterr().err
    spec = "station,x,y,z,az,el,roll,time,quality;time=s"
    assert f"detected: tracker layout from the data: columns {spec.split(';')[0]}" in err
    assert f"--tracker-layout '{spec}'" in err
    document = json.loads((tmp_path / "a.json").read_text())
    assert any("3 dropped frame(s)" in w for w in document["warnings"])
    # an explicit layout is used as given, and nothing is printed about detection
    assert main(["skeleton", "--quiet", str(path), "--stations", motion.stations,
                 "--tracker-layout", spec, "-o", str(tmp_path / "b.json")]) == 0
    assert "detected" not in capsys.readouterr().err
    assert main(["skeleton", "--quiet", str(path), "--stations", motion.stations,
                 "--tracker-layout", "station,x,y,z,az,el,roll", "-o",
                 str(tmp_path / "c.json")]) == 2
    err = capsys.readouterr().err
    assert "line 1 has 9 fields; the layout 'station,x,y,z,az,el,roll' has 7" in err


def test_wide_tables_are_not_taken_for_tracker_records(tmp_path: Path) -> None:
    # a kinematics CSV whose joint names are no segment names: 1 + 3·J columns of numbers
    path = tmp_path / "kin.csv"
    rng = np.random.default_rng(0)
    header = "Time," + ",".join(f"J{j}.D{c}" for c in "xyz" for j in range(8))
    rows = [f"{i / 60:.4f}," + ",".join(f"{v:.3f}" for v in rng.normal(0, 30, 24))
            for i in range(50)]
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    with pytest.raises(InputError, match="no tracker layout") as err:
        detect_tracker_layout(path)
    assert err.value.field == "tracker_layout"
    assert detect_format(path) == "csv"


def test_csv_headers_of_other_columns_are_not_tracker_headers(tmp_path: Path) -> None:
    # foot accelerations: time and six numbers per row would read as a tracker record
    path = tmp_path / "feet.csv"
    rows = [f"{i / 60:.4f},{0.1 * i % 1:.3f},1.0,0.02,0.5,0.9,-0.1" for i in range(30)]
    path.write_text("time,LeftFoot.ax,LeftFoot.ay,LeftFoot.az,RightFoot.ax,RightFoot.ay,"
                    "RightFoot.az\n" + "\n".join(rows) + "\n")
    assert detect_format(path) == "csv"
    # without the header the rows are records, with a banner above them too
    path.write_text("\n".join(rows) + "\n")
    assert detect_format(path) == "tracker"
