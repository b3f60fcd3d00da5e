"""Readers of sensor recordings: CSV, tracker ASCII, NPZ, detection, sniffing, errors."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from bonefit.estimation import threads
from bonefit.estimation.errors import InputError
from bonefit.estimation.io import sensor_csv
from bonefit.estimation.io.sensors import (
    RowCounter,
    detect_format,
    example_path,
    read_recording,
    read_sensor_csv,
    read_sensor_npz,
    sniff_recording,
    write_sensor_csv,
    write_sensor_npz,
)
from bonefit.estimation.io.tracker import parse_stations, read_tracker_ascii
from bonefit.estimation.model import JOINT_SEGMENTS, SEGMENTS
from bonefit.estimation.recording import SensorRecording

HEADER3 = ",".join(["time"] + [f"{s}.{c}" for s in ("pelvis", "chest", "head")
                               for c in ("x", "y", "z", "qw", "qx", "qy", "qz")])


def small_recording(n_frames: int = 12, seed: int = 0) -> SensorRecording:
    """Three sensors about a body's size apart, random orientations, one dropped sample."""
    rng = np.random.default_rng(seed)
    base = np.array([[0.0, 1.0, 0.0], [0.0, 1.4, 0.05], [0.0, 1.7, 0.0]])
    pos = base + rng.normal(scale=0.02, size=(n_frames, 3, 3))
    quats = Rotation.random(n_frames * 3, rng=rng).as_quat(scalar_first=True).reshape(
        n_frames, 3, 4)
    pos[4, 1] = np.nan
    quats[4, 1] = np.nan
    return SensorRecording(("pelvis", "chest", "head"), pos, quats, 50.0,
                           np.arange(n_frames) / 50.0)


def write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def row(t: float, *sensors: tuple[float, ...]) -> str:
    return ",".join([f"{t:g}"] + [f"{v:g}" for s in sensors for v in s])


PELVIS = (0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0)
CHEST = (0.0, 1.4, 0.0, 0.0, 1.0, 0.0, 0.0)
HEAD = (0.1, 1.7, 0.0, 0.0, 0.0, 0.0, 1.0)


def csv_text(rows: int = 3) -> str:
    return HEADER3 + "\n" + "\n".join(row(i / 10, PELVIS, CHEST, HEAD) for i in range(rows))


# --------------------------------------------------------------------------- CSV


def test_csv_round_trip_keeps_values_and_dropped_samples(tmp_path: Path) -> None:
    rec = small_recording()
    write_sensor_csv(rec, tmp_path / "r.csv")
    back = read_sensor_csv(tmp_path / "r.csv")
    assert back.sensors == rec.sensors
    assert back.fps == pytest.approx(50.0)
    np.testing.assert_allclose(back.time, rec.time, atol=1e-9)
    np.testing.assert_allclose(back.positions, rec.positions, atol=1e-6)
    np.testing.assert_allclose(back.quaternions, rec.quaternions, atol=2e-6)
    assert np.isnan(back.positions[4, 1]).all()
    assert np.isnan(back.quaternions[4, 1]).all()
    assert back.valid().sum() == rec.valid().sum() == 12 * 3 - 1


@pytest.mark.parametrize(("units", "scale"), [("mm", 0.001), ("cm", 0.01), ("in", 0.0254)])
def test_csv_units_convert_to_metres(tmp_path: Path, units: str, scale: float) -> None:
    rec = small_recording()
    write_sensor_csv(rec, tmp_path / "r.csv", units=units)
    text = (tmp_path / "r.csv").read_text()
    assert text.startswith(f"# units: {units}\n")
    # the comment sets the default ...
    back = read_sensor_csv(tmp_path / "r.csv")
    np.testing.assert_allclose(back.positions, rec.positions, atol=1e-6)
    # ... and without it the number is read in metres unless units= says otherwise
    bare = write(tmp_path / "bare.csv", text.split("\n", 1)[1])
    first = float(text.splitlines()[2].split(",")[1])
    assert read_sensor_csv(bare, units=units).positions[0, 0, 0] == pytest.approx(first * scale)


def test_csv_columns_in_any_order_subset_and_case(tmp_path: Path) -> None:
    header = "HEAD.qz,head.qy,head.qx,head.qw,head.z,head.y,head.x,Time"
    path = write(tmp_path / "h.csv", f"{header}\n0,0,0,1,0.1,1.7,0.2,0\n1,0,0,0,0.1,1.7,0.2,0.5\n")
    rec = read_sensor_csv(path)
    assert rec.sensors == ("head",)
    np.testing.assert_allclose(rec.positions[:, 0], [[0.2, 1.7, 0.1]] * 2)
    np.testing.assert_allclose(rec.quaternions[:, 0], [[1, 0, 0, 0], [0, 0, 0, 1]])
    assert rec.fps == pytest.approx(2.0)


def test_empty_or_nan_cell_drops_the_whole_sample(tmp_path: Path) -> None:
    lines = csv_text(4).splitlines()
    cells = lines[2].split(",")
    cells[2] = ""        # pelvis.y empty on frame 1
    lines[2] = ",".join(cells)
    cells = lines[3].split(",")
    cells[12] = "NaN"    # chest.qx on frame 2
    lines[3] = ",".join(cells)
    rec = read_sensor_csv(write(tmp_path / "d.csv", "\n".join(lines)))
    valid = rec.valid()
    assert not valid[1, 0]
    assert not valid[2, 1]
    assert valid.sum() == 4 * 3 - 2
    assert np.isnan(rec.positions[1, 0]).all()
    assert np.isnan(rec.quaternions[2, 1]).all()


def test_fps_without_time_column(tmp_path: Path) -> None:
    header = ",".join(f"pelvis.{c}" for c in ("x", "y", "z", "qw", "qx", "qy", "qz"))
    path = write(tmp_path / "p.csv", header + "\n0,1,0,1,0,0,0\n0,1,0.1,1,0,0,0\n")
    with pytest.raises(InputError, match="fps") as err:
        read_sensor_csv(path)
    assert err.value.field == "fps"
    rec = read_sensor_csv(path, fps=120)
    assert rec.fps == 120
    np.testing.assert_allclose(rec.time, [0.0, 1 / 120])
    meta = write(tmp_path / "m.csv", "# fps: 30\n" + header + "\n0,1,0,1,0,0,0\n")
    assert read_sensor_csv(meta).fps == 30


def test_unknown_column_is_named(tmp_path: Path) -> None:
    path = write(tmp_path / "u.csv", HEADER3.replace("chest.qy", "chest.qv") + "\n")
    with pytest.raises(InputError, match=r"unknown column 'chest\.qv'") as err:
        read_sensor_csv(path)
    assert err.value.column == HEADER3.split(",").index("chest.qy") + 1
    assert err.value.line == 1
    path = write(tmp_path / "s.csv", HEADER3.replace("head.", "nose.") + "\n")
    with pytest.raises(InputError, match="unknown segment 'nose'"):
        read_sensor_csv(path)


def test_malformed_number_names_line_and_column(tmp_path: Path) -> None:
    lines = csv_text(5).splitlines()
    cells = lines[3].split(",")
    cells[9] = "1.4.2"
    lines[3] = ",".join(cells)
    path = write(tmp_path / "bad.csv", "# units: m\n\n" + "\n".join(lines))
    with pytest.raises(InputError, match=r"'1\.4\.2' at line 6, column 10 \(chest\.y\)") as err:
        read_sensor_csv(path)
    assert (err.value.line, err.value.column, err.value.field) == (6, 10, "chest.y")


@pytest.mark.parametrize("chunk", [64, 97, 1 << 22])
def test_blocks_of_any_size_read_the_same_rows_and_name_the_same_lines(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, chunk: int) -> None:
    """The fast parse goes a block of lines at a time: rows, dropped samples, comments,
    blank lines, CRLF and a last line without its end give what one pass gives, and a fault
    in a later block is named at its line."""
    monkeypatch.setattr(sensor_csv, "CHUNK_CHARS", chunk)
    rec = small_recording(n_frames=40, seed=3)
    write_sensor_csv(rec, tmp_path / "r.csv")
    lines = (tmp_path / "r.csv").read_text().splitlines()
    lines.insert(20, "# a comment between the rows")
    lines.insert(30, "")
    text = "\r\n".join(lines)  # CRLF, and no line end after the last row
    back = read_sensor_csv(write(tmp_path / "mixed.csv", text))
    np.testing.assert_allclose(back.positions, rec.positions, atol=1e-6)
    np.testing.assert_allclose(back.time, rec.time, atol=1e-9)
    assert back.valid().sum() == rec.valid().sum()
    cells = lines[37].split(",")
    cells[5] = "x"
    lines[37] = ",".join(cells)
    with pytest.raises(InputError, match=r"'x' at line 38, column 6") as err:
        read_sensor_csv(write(tmp_path / "bad.csv", "\n".join(lines) + "\n"))
    assert err.value.line == 38


def test_blocks_parsed_on_threads_read_as_in_one_thread_and_raise_the_first_fault(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Blocks parsed two at a time give the recording of one thread bit for bit; with a
    fault in a block and another in a later one, the earlier is raised, whichever block
    was parsed first."""
    monkeypatch.setattr(sensor_csv, "CHUNK_CHARS", 512)
    rec = small_recording(n_frames=200, seed=7)
    path = tmp_path / "r.csv"
    write_sensor_csv(rec, path, decimals=9)
    lines = path.read_text().splitlines()
    read = {}
    for n in (1, 2):
        monkeypatch.setattr(threads, "workers", lambda n=n: n)
        read[n] = read_sensor_csv(path)
    for name in ("positions", "quaternions", "time"):
        a, b = getattr(read[1], name), getattr(read[2], name)
        assert a.shape == b.shape
        assert (a.view(np.int64) == b.view(np.int64)).all()
    for at in (40, 44):
        cells = lines[at].split(",")
        cells[3] = "1.2.3"
        lines[at] = ",".join(cells)
    bad = write(tmp_path / "bad.csv", "\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"'1\.2\.3' at line 41, column 4") as err:
        read_sensor_csv(bad)
    assert err.value.line == 41


@pytest.mark.parametrize("layout", ["plain", "crlf-bom", "exponents"])
def test_decimal_parse_reads_what_loadtxt_reads(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                layout: str) -> None:
    """Blocks of plain decimals (dropped samples as empty cells) are parsed by numpy array
    operations; the recording is bit for bit the one of the loadtxt path, in every block,
    whatever the line ends, a byte-order mark, or numbers loadtxt alone takes."""
    monkeypatch.setattr(sensor_csv, "CHUNK_CHARS", 4096)
    rec = small_recording(n_frames=300, seed=5)
    write_sensor_csv(rec, tmp_path / "r.csv", decimals=9)
    text = (tmp_path / "r.csv").read_text()
    if layout == "crlf-bom":
        text = "\ufeff" + text.replace("\n", "\r\n")
    elif layout == "exponents":
        text = text.replace("0.000", "0.000e0", 40)
    path = write(tmp_path / "t.csv", text)
    calls: list[bool] = []
    decimal_rows = sensor_csv.decimal_rows

    def counted(data: bytes, n_cols: int) -> np.ndarray | None:
        got = decimal_rows(data, n_cols)
        calls.append(got is not None)
        return got

    monkeypatch.setattr(sensor_csv, "decimal_rows", counted)
    fast = read_sensor_csv(path)
    assert any(calls)
    assert all(calls) == (layout != "exponents")
    monkeypatch.setattr(sensor_csv, "decimal_rows", lambda data, n_cols: None)
    slow = read_sensor_csv(path)
    for a, b in ((fast.positions, slow.positions), (fast.quaternions, slow.quaternions),
                 (fast.time, slow.time)):
        assert a.shape == b.shape
        assert (a.view(np.int64) == b.view(np.int64)).all()
    assert fast.fps == slow.fps
    assert not fast.valid()[4, 1]


def test_short_row_names_its_line(tmp_path: Path) -> None:
    text = csv_text(3) + "\n0.3,0,1\n"
    with pytest.raises(InputError, match="line 5 has 3 cells") as err:
        read_sensor_csv(write(tmp_path / "short.csv", text))
    assert err.value.line == 5


def test_missing_quaternion_component_is_an_error(tmp_path: Path) -> None:
    header = HEADER3.replace(",head.qx", "")
    with pytest.raises(InputError, match=r"'head' lacks column\(s\) head\.qx") as err:
        read_sensor_csv(write(tmp_path / "q.csv", header + "\n"))
    assert err.value.sensor == "head"


def test_duplicate_column_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="appears twice"):
        read_sensor_csv(write(tmp_path / "dup.csv", HEADER3 + ",pelvis.x\n"))


def test_quaternions_nearly_unit_are_normalised_far_ones_rejected(tmp_path: Path) -> None:
    near = (0.0, 1.0, 0.0, 1.02, 0.0, 0.0, 0.0)
    text = HEADER3 + "\n" + row(0, near, CHEST, HEAD) + "\n" + row(0.1, PELVIS, CHEST, HEAD)
    rec = read_sensor_csv(write(tmp_path / "n.csv", text))
    np.testing.assert_allclose(rec.quaternions[0, 0], [1, 0, 0, 0])
    far = (0.0, 1.0, 0.0, 10.0, 20.0, 30.0, 0.0)  # angles in quaternion columns
    text = HEADER3 + "\n" + row(0, PELVIS, CHEST, HEAD) + "\n" + row(0.1, PELVIS, CHEST, far)
    with pytest.raises(InputError, match="'head' at line 3 has norm") as err:
        read_sensor_csv(write(tmp_path / "f.csv", text))
    assert (err.value.sensor, err.value.line) == ("head", 3)


def test_all_nan_sensor_is_named(tmp_path: Path) -> None:
    lines = csv_text(3).splitlines()
    for i in range(1, 4):
        cells = lines[i].split(",")
        cells[15:22] = [""] * 7
        lines[i] = ",".join(cells)
    with pytest.raises(InputError, match="sensor 'head' has no valid sample") as err:
        read_sensor_csv(write(tmp_path / "nan.csv", "\n".join(lines)))
    assert err.value.sensor == "head"


def test_time_must_increase(tmp_path: Path) -> None:
    text = HEADER3 + "\n" + "\n".join(row(t, PELVIS, CHEST, HEAD) for t in (0, 0.1, 0.1))
    with pytest.raises(InputError, match="time does not increase at line 4") as err:
        read_sensor_csv(write(tmp_path / "t.csv", text))
    assert err.value.line == 4


def test_header_only_and_empty_files(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no frames"):
        read_sensor_csv(write(tmp_path / "h.csv", HEADER3 + "\n"))
    with pytest.raises(InputError, match="empty"):
        read_sensor_csv(write(tmp_path / "e.csv", "# units: m\n"))


def test_positions_far_too_large_for_declared_units(tmp_path: Path) -> None:
    rec = small_recording()
    write_sensor_csv(rec, tmp_path / "mm.csv", units="mm")
    bare = write(tmp_path / "bare.csv", (tmp_path / "mm.csv").read_text().split("\n", 1)[1])
    with pytest.raises(InputError, match="--units") as err:
        read_sensor_csv(bare)  # millimetres read as metres: a 700 m tall body
    assert err.value.field == "units"
    assert read_sensor_csv(bare, units="mm").n_frames == rec.n_frames
    with pytest.raises(InputError, match="apart if positions are in m"):
        read_sensor_csv(tmp_path / "mm.csv", units="m")  # the argument beats the comment


def test_positions_far_too_small_for_declared_units(tmp_path: Path) -> None:
    rec = small_recording()
    write_sensor_csv(rec, tmp_path / "m.csv", units="m")
    with pytest.raises(InputError, match="mm apart") as err:
        read_sensor_csv(tmp_path / "m.csv", units="mm")
    assert err.value.field == "units"


# --------------------------------------------------------------------------- tracker


def rz(a: float) -> NDArray[np.float64]:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def ry(a: float) -> NDArray[np.float64]:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rx(a: float) -> NDArray[np.float64]:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


TRACKER = """\
# Polhemus LIBERTY export
  1   10.00   20.00  -30.00   90.000    0.000    0.000
  2   12.00   30.00  -31.00   30.000   20.000  -40.000
  1   10.50   20.00  -30.00   45.000   10.000    5.000
  2   12.50   30.00  -31.00   30.000   20.000  -40.000
  2   13.00   30.00  -31.00   31.000   21.000  -41.000
  1   11.00   20.00  -30.00    0.000    0.000    0.000
  2   13.50   30.00  -31.00   32.000   22.000  -42.000
"""


def test_tracker_euler_angles_inches_and_frame_grouping(tmp_path: Path) -> None:
    path = write(tmp_path / "lib.txt", TRACKER)
    rec = read_tracker_ascii(path, stations={1: "pelvis", 2: "chest"}, fps=240)
    assert rec.sensors == ("pelvis", "chest")
    # frames: (1,2) (1,2) (2) (1,2): station 1 is missing from the third frame
    assert rec.n_frames == 4
    assert rec.valid().tolist() == [[True, True], [True, True], [False, True], [True, True]]
    np.testing.assert_allclose(rec.positions[0, 0], np.array([10, 20, -30]) * 0.0254)
    np.testing.assert_allclose(rec.positions[2, 1], np.array([13, 30, -31]) * 0.0254)
    np.testing.assert_allclose(rec.time, np.arange(4) / 240)
    az, el, roll = np.radians([30.0, 20.0, -40.0])
    expected = rz(az) @ ry(el) @ rx(roll)
    got = Rotation.from_quat(rec.quaternions[0, 1], scalar_first=True).as_matrix()
    np.testing.assert_allclose(got, expected, atol=1e-12)
    # azimuth 90: sensor x axis points along source y
    x_axis = Rotation.from_quat(rec.quaternions[0, 0], scalar_first=True).apply([1, 0, 0])
    np.testing.assert_allclose(x_axis, [0, 1, 0], atol=1e-12)


def test_tracker_quaternion_records_and_metadata_comments(tmp_path: Path) -> None:
    text = ("# units: cm\n# fps: 60\n# stations: 3=l_hand, 5=r_hand\n"
            "3 1 2 3 1 0 0 0\n5 4 5 6 0 1 0 0\n"
            "3 1 2 3.5 0.7071068 0 0.7071068 0\n5 4 5 6 0 1 0 0\n")
    rec = read_recording(write(tmp_path / "q.dat", text))
    assert rec.sensors == ("l_hand", "r_hand")
    assert rec.fps == 60
    np.testing.assert_allclose(rec.positions[1, 0], [0.01, 0.02, 0.035])
    np.testing.assert_allclose(rec.quaternions[1, 0], [2 ** -0.5, 0, 2 ** -0.5, 0], atol=1e-7)


def test_tracker_needs_stations_and_fps(tmp_path: Path) -> None:
    path = write(tmp_path / "lib.txt", TRACKER)
    with pytest.raises(InputError, match="stations mapping") as err:
        read_tracker_ascii(path, fps=240)
    assert err.value.field == "stations"
    # an unmapped station is ignored with a warning naming it (it used to be an error)
    rec = read_tracker_ascii(path, stations="1=pelvis", fps=240)
    assert rec.sensors == ("pelvis",)
    assert any(re.search(r"station 2 .* not in the stations mapping .*ignored", w)
               for w in rec.warnings)
    with pytest.raises(InputError, match="unknown segment 'torso'"):
        read_tracker_ascii(path, stations="1=pelvis,2=torso", fps=240)
    with pytest.raises(InputError, match="station 4 \\(head\\) has no records") as err:
        read_tracker_ascii(path, stations="1=pelvis,2=chest,4=head", fps=240)
    assert err.value.sensor == "head"
    with pytest.raises(InputError, match="give fps") as err:
        read_tracker_ascii(path, stations="1=pelvis,2=chest")
    assert err.value.field == "fps"


def test_tracker_malformed_records_name_the_line(tmp_path: Path) -> None:
    bad = TRACKER.replace("12.50", "12.5x")
    with pytest.raises(InputError, match="line 5, column 2") as err:
        read_tracker_ascii(write(tmp_path / "b.txt", bad), stations="1=pelvis,2=chest", fps=1)
    assert (err.value.line, err.value.column) == (5, 2)
    short = TRACKER + "  1  1.0 2.0 3.0\n"
    with pytest.raises(InputError, match="line 9 has 4 fields") as err:
        read_tracker_ascii(write(tmp_path / "s.txt", short), stations="1=pelvis,2=chest", fps=1)
    assert err.value.line == 9


# --------------------------------------------------------------------------- NPZ


def test_npz_round_trip_and_overrides(tmp_path: Path) -> None:
    rec = small_recording()
    write_sensor_npz(rec, tmp_path / "r.npz")
    back = read_sensor_npz(tmp_path / "r.npz")
    assert back.sensors == rec.sensors
    assert back.fps == 50.0
    np.testing.assert_allclose(back.positions, rec.positions, atol=1e-12)
    np.testing.assert_allclose(back.quaternions, rec.quaternions, atol=1e-12)
    np.savez(tmp_path / "cm.npz", positions=rec.positions * 100, quaternions=rec.quaternions,
             sensors=np.array(rec.sensors), fps=25)
    back = read_recording(tmp_path / "cm.npz", units="cm", fps=100)
    np.testing.assert_allclose(back.positions, rec.positions, atol=1e-12)
    assert back.fps == 100


def test_npz_missing_array_and_pickles_are_refused(tmp_path: Path) -> None:
    rec = small_recording()
    np.savez(tmp_path / "m.npz", positions=rec.positions, sensors=np.array(rec.sensors), fps=50)
    with pytest.raises(InputError, match="lacks the array 'quaternions'") as err:
        read_sensor_npz(tmp_path / "m.npz")
    assert err.value.field == "quaternions"
    names = np.array(list(rec.sensors), dtype=object)
    np.savez(tmp_path / "o.npz", positions=rec.positions, quaternions=rec.quaternions,
             sensors=names, fps=50)
    with pytest.raises(InputError, match="sensors"):
        read_sensor_npz(tmp_path / "o.npz")
    np.savez(tmp_path / "u.npz", positions=rec.positions, quaternions=rec.quaternions,
             sensors=np.array(["pelvis", "chest", "torso"]), fps=50)
    with pytest.raises(InputError, match="unknown sensor 'torso'"):
        read_sensor_npz(tmp_path / "u.npz")


# --------------------------------------------------------------------------- dispatch


def test_format_detection_by_content_then_extension(tmp_path: Path) -> None:
    rec = small_recording()
    write_sensor_csv(rec, tmp_path / "csv.txt")       # CSV content, tracker-like extension
    write(tmp_path / "lib.csv", TRACKER)                # tracker content, CSV extension
    write_sensor_npz(rec, tmp_path / "rec.bin.npz")
    (tmp_path / "npz.data").write_bytes((tmp_path / "rec.bin.npz").read_bytes())
    assert detect_format(tmp_path / "csv.txt") == "csv"
    assert detect_format(tmp_path / "lib.csv") == "tracker"
    assert detect_format(tmp_path / "npz.data") == "npz"
    assert read_recording(tmp_path / "csv.txt").sensors == rec.sensors
    assert read_recording(tmp_path / "npz.data").sensors == rec.sensors
    assert read_recording(tmp_path / "lib.csv", stations="1=pelvis,2=chest",
                          fps=240).n_frames == 4
    write(tmp_path / "what.xyz", "hello world\n")
    with pytest.raises(InputError, match="cannot tell the format"):
        read_recording(tmp_path / "what.xyz")
    with pytest.raises(InputError, match="unknown format 'c3d'"):
        read_recording(tmp_path / "csv.txt", format="c3d")
    with pytest.raises(InputError, match="unknown units 'furlong'"):
        read_recording(tmp_path / "csv.txt", units="furlong")
    with pytest.raises(FileNotFoundError):
        read_recording(tmp_path / "absent.csv")


def test_sniff_summarises_without_parsing_rows(tmp_path: Path) -> None:
    rec = small_recording(n_frames=40)
    write_sensor_csv(rec, tmp_path / "r.csv")
    text = (tmp_path / "r.csv").read_text() + "1.0,garbage\n"  # a full read would fail
    write(tmp_path / "r.csv", text)
    with pytest.raises(InputError):
        read_recording(tmp_path / "r.csv")
    info = sniff_recording(tmp_path / "r.csv")
    assert info == {"format": "csv", "frames": 41, "sensors": list(rec.sensors),
                    "fps": pytest.approx(50.0), "units": "m"}
    write_sensor_npz(rec, tmp_path / "r.npz")
    assert sniff_recording(tmp_path / "r.npz") == {
        "format": "npz", "frames": 40, "sensors": list(rec.sensors), "fps": 50.0, "units": "m"}
    info = sniff_recording(write(tmp_path / "lib.txt", TRACKER))
    assert info == {"format": "tracker", "frames": 4, "sensors": ["1", "2"], "fps": None,
                    "units": "in", "layout": "station,x,y,z,az,el,roll"}
    named = write(tmp_path / "n.txt", "# stations: 1=pelvis,2=chest\n# fps: 240\n" + TRACKER)
    assert sniff_recording(named)["sensors"] == ["pelvis", "chest"]
    assert sniff_recording(named)["fps"] == 240


def test_parse_stations_forms(tmp_path: Path) -> None:
    expected = {1: "pelvis", 2: "chest", 10: "r_foot"}
    assert parse_stations("1=pelvis, 2=chest,10=r_foot") == expected
    assert parse_stations({"1": "pelvis", 2: "chest", "10": "r_foot"}) == expected
    path = write(tmp_path / "st.json", json.dumps({"1": "pelvis", "2": "chest", "10": "r_foot"}))
    assert parse_stations(str(path)) == expected
    for bad, message in [("1:pelvis", "not NUMBER=SEGMENT"), ("a=pelvis", "not a number"),
                         ("1=pelvis,2=pelvis", "two stations"), ("", "empty")]:
        with pytest.raises(InputError, match=message):
            parse_stations(bad)


# --------------------------------------------------------------------------- example


def test_bundled_example_is_small_complete_and_moves_every_joint() -> None:
    path = example_path()
    assert path.stat().st_size < 1_000_000
    rec = read_recording(path)
    assert rec.sensors == SEGMENTS
    assert 200 <= rec.n_frames <= 1000
    assert rec.fps == 60.0
    assert 0 < (~rec.valid()).sum() < 0.01 * rec.valid().size  # a few dropped samples
    for joint, (a, b) in JOINT_SEGMENTS.items():
        qa = rec.quaternions[:, rec.index(a)]
        qb = rec.quaternions[:, rec.index(b)]
        ok = np.isfinite(qa).all(axis=1) & np.isfinite(qb).all(axis=1)
        rel = (Rotation.from_quat(qa[ok], scalar_first=True).inv()
               * Rotation.from_quat(qb[ok], scalar_first=True))
        spread = (rel[0].inv() * rel).magnitude()
        assert np.degrees(spread.max()) > 25, joint
    with pytest.raises(InputError, match="no bundled example"):
        example_path("nope.csv")


def test_tracker_frames_follow_the_first_cycle_order(tmp_path: Path) -> None:
    rec_line = "{0} {0} 2 3 0 0 0\n"
    # order 3,1,4 in the first cycle; then 3,1,2,4 (2 first seen), then 1,4 (3 missing)
    text = "".join(rec_line.format(n) for n in (3, 1, 4, 3, 1, 2, 4, 1, 4, 3, 1, 2, 4))
    rec = read_tracker_ascii(write(tmp_path / "o.txt", text), units="m", fps=10,
                             stations="1=pelvis,2=chest,3=head,4=l_hand")
    assert rec.sensors == ("pelvis", "chest", "head", "l_hand")
    assert rec.valid().tolist() == [[True, False, True, True], [True, True, True, True],
                                    [True, False, False, True], [True, True, True, True]]


def test_binary_junk_gives_a_short_named_error(tmp_path: Path) -> None:
    (tmp_path / "junk.csv").write_bytes(b"\x7fELF\x02\x01" + bytes(range(256)) * 4)
    with pytest.raises(InputError, match="unknown column") as err:
        read_recording(tmp_path / "junk.csv")
    assert len(err.value.detail) < 200
    (tmp_path / "nul.csv").write_bytes(HEADER3.encode() + b"\n0,\x00,1\n")
    with pytest.raises(InputError):
        read_recording(tmp_path / "nul.csv")
    with pytest.raises(InputError, match="directory"):
        read_recording(tmp_path)


@settings(max_examples=300, deadline=None)
@given(lines=st.lists(st.sampled_from(["0,1,2", "", "  ", "# note", " 3,4", "\t#x", "é,1",
                                       " é", "x"]), max_size=40),
       ends=st.lists(st.sampled_from(["\n", "\r\n", "\r"]), min_size=1, max_size=3),
       cuts=st.lists(st.integers(min_value=0, max_value=400), max_size=6))
def test_row_counter_matches_the_text_reader_whatever_the_blocks(
        lines: list[str], ends: list[str], cuts: list[int]) -> None:
    text = "".join(line + ends[i % len(ends)] for i, line in enumerate(lines))
    if lines and cuts and cuts[0] % 2:
        text = text.rstrip("\r\n")  # a last line without its line end counts too
    data = text.encode()
    expected = sum(1 for line in re.split(r"\r\n|\r|\n", text)
                   if line.strip() and not line.strip().startswith("#"))
    counter = RowCounter()
    start = 0
    for cut in sorted(min(c, len(data)) for c in cuts):
        counter.feed(data[start:cut])
        start = max(start, cut)
    buf = bytearray(data[start:]) + b"junk past the length"
    counter.feed(buf, len(data) - start)
    assert counter.rows == expected


def test_sniff_takes_the_rows_counted_while_receiving(tmp_path: Path) -> None:
    rec = small_recording(n_frames=120)
    path = tmp_path / "r.csv"
    write_sensor_csv(rec, path)
    with path.open("a") as fh:
        fh.write("# trailing comment\n\n")
    counter = RowCounter()
    data = path.read_bytes()
    for start in range(0, len(data), 1000):
        counter.feed(data[start:start + 1000])
    assert sniff_recording(path, counted_rows=counter.rows)["frames"] == 120
    # the count is used as given: a wrong one shows that the file was not read again
    assert sniff_recording(path, counted_rows=counter.rows + 5)["frames"] == 125
