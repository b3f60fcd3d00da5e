"""Hostile and broken inputs are refused early, in bounded memory, with a named limit or the
line and column at fault (issue 16 §1)."""

from __future__ import annotations

import io
import tracemalloc
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bonefit.estimation.errors import InputError, LimitError
from bonefit.estimation.io import limits, sensor_csv
from bonefit.estimation.io.kinematics import (
    read_acceleration_csv,
    read_kinematics_csv,
    sniff_kinematics,
)
from bonefit.estimation.io.sensors import (
    example_path,
    read_recording,
    read_sensor_csv,
    read_sensor_npz,
    sniff_recording,
)
from tests.estimation.test_io_fuzz import acceleration_csv, kinematics_csv

MB = 1024 * 1024


def npy_header(dtype: str, shape: tuple[int, ...]) -> bytes:
    out = io.BytesIO()
    np.lib.format.write_array_header_1_0(out, {"descr": dtype, "fortran_order": False,
                                               "shape": shape})
    return out.getvalue()


def add_member(archive: zipfile.ZipFile, key: str, header: bytes, zeros: int) -> None:
    with archive.open(f"{key}.npy", "w", force_zip64=True) as member:
        member.write(header)
        block = bytes(MB)
        while zeros > 0:
            member.write(block[:min(zeros, MB)])
            zeros -= MB


def small_npz(archive: zipfile.ZipFile) -> None:
    add_member(archive, "positions", npy_header("<f8", (10, 1, 3)), 240)
    add_member(archive, "quaternions", npy_header("<f8", (10, 1, 4)), 320)
    add_member(archive, "fps", npy_header("<f8", ()), 8)


@pytest.fixture(scope="module")
def sensors_bomb(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The issue's file: about 200 KB whose sensors.npy declares (and inflates to) 50 M
    entries, 200 MB."""
    path = tmp_path_factory.mktemp("bombs") / "sensors-bomb.npz"
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
        small_npz(zf)
        add_member(zf, "sensors", npy_header("<U1", (50_000_000,)), 200_000_000)
    assert path.stat().st_size < 2 * MB
    return path


def positions_bomb(path: Path) -> Path:
    """positions.npy declaring 50 M frames × 15 sensors × 3 (18 GB) in a few bytes."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        add_member(zf, "positions", npy_header("<f8", (50_000_000, 15, 3)), MB)
        add_member(zf, "quaternions", npy_header("<f8", (10, 1, 4)), 320)
        add_member(zf, "sensors", npy_header("<U6", (1,)), 24)
        add_member(zf, "fps", npy_header("<f8", ()), 8)
    return path


def peak_bytes(call: Callable[[], Any]) -> tuple[int, BaseException | None]:
    """Peak Python allocation while ``call`` runs, and what it raised."""
    tracemalloc.start()
    try:
        call()
        caught = None
    except Exception as exc:
        caught = exc
    finally:
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    return peak, caught


@pytest.mark.parametrize("read", [read_sensor_npz, lambda p: sniff_recording(p, "npz"),
                                  lambda p: read_recording(p)], ids=["read", "sniff", "auto"])
def test_npz_sensors_bomb_is_refused_unread(sensors_bomb: Path,
                                             read: Callable[[Path], Any]) -> None:
    peak, caught = peak_bytes(lambda: read(sensors_bomb))
    assert isinstance(caught, LimitError), caught
    assert caught.limit == "MAX_NPZ_SMALL_BYTES"
    assert caught.field == "sensors"
    assert "200000128 bytes" in caught.detail
    assert peak < 2 * MB  # the 200 MB member is never inflated


@pytest.mark.parametrize("read", [read_sensor_npz, lambda p: sniff_recording(p, "npz")],
                         ids=["read", "sniff"])
def test_npz_positions_bomb_is_refused_from_its_header(tmp_path: Path,
                                                        read: Callable[[Path], Any]) -> None:
    path = positions_bomb(tmp_path / "positions-bomb.npz")
    peak, caught = peak_bytes(lambda: read(path))
    assert isinstance(caught, LimitError), caught
    assert caught.limit == "MAX_VALUES"
    assert caught.field == "positions"
    assert peak < 2 * MB


def test_npz_member_that_holds_more_than_its_header_declares(tmp_path: Path) -> None:
    path = tmp_path / "liar.npz"
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        add_member(zf, "positions", npy_header("<f8", (10, 1, 3)), 64 * MB)
    with pytest.raises(InputError, match=r"declares shape .* but its member holds") as caught:
        sniff_recording(path, "npz")
    assert caught.value.field == "positions"


def test_npz_frames_beyond_the_limit(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "long.npz"
    np.savez(path, positions=np.zeros((11, 1, 3)), quaternions=np.ones((11, 1, 4)) / 2,
             sensors=np.array(["pelvis"]), fps=np.float64(60))
    monkeypatch.setattr(limits, "MAX_FRAMES", 10)
    for read in (read_sensor_npz, lambda p: sniff_recording(p, "npz")):
        with pytest.raises(LimitError, match="11 frames; the limit is 10") as caught:
            read(path)
        assert caught.value.limit == "MAX_FRAMES"


def test_npz_with_too_many_members(tmp_path: Path) -> None:
    path = tmp_path / "many.npz"
    with zipfile.ZipFile(path, "w") as zf:
        for i in range(limits.MAX_NPZ_MEMBERS + 1):
            zf.writestr(f"a{i}.npy", b"")
    with pytest.raises(LimitError) as caught:
        sniff_recording(path, "npz")
    assert caught.value.limit == "MAX_NPZ_MEMBERS"


def test_npz_object_arrays_are_refused_before_unpickling(tmp_path: Path) -> None:
    path = tmp_path / "pickle.npz"
    np.savez(path, positions=np.zeros((3, 1, 3)), quaternions=np.ones((3, 1, 4)) / 2,
             sensors=np.array([object()], dtype=object), fps=np.float64(60))
    with pytest.raises(InputError, match="holds Python objects") as caught:
        read_sensor_npz(path)
    assert caught.value.field == "sensors"


def test_npz_infinite_position_is_named(tmp_path: Path) -> None:
    positions = np.zeros((5, 2, 3))
    positions[:, 1, 0] = 0.5
    positions[3, 1, 2] = np.inf
    quats = np.zeros((5, 2, 4))
    quats[..., 0] = 1
    path = tmp_path / "inf.npz"
    np.savez(path, positions=positions, quaternions=quats,
             sensors=np.array(["pelvis", "chest"]), fps=np.float64(60))
    with pytest.raises(InputError, match="infinite value") as caught:
        read_sensor_npz(path)
    assert (caught.value.field, caught.value.sensor) == ("positions", "chest")


# --------------------------------------------------------------------------- long lines


@pytest.fixture(scope="module")
def one_line(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """A 50 MB file that is one header line of 12.5 M columns."""
    path = tmp_path_factory.mktemp("line") / "line.csv"
    with path.open("wb") as fh:
        fh.write(b"time")
        for _ in range(50):
            fh.write(b",a.x" * (MB // 4))
    yield path
    path.unlink()


@pytest.mark.parametrize("read", [
    read_sensor_csv, lambda p: sniff_recording(p, "csv"), read_kinematics_csv,
    read_acceleration_csv, lambda p: sniff_kinematics(p, "kinematics-csv"),
    lambda p: sniff_kinematics(p, "bvh")],
    ids=["sensor-csv", "sensor-sniff", "kinematics-csv", "accelerations-csv",
         "kinematics-sniff", "bvh-sniff"])
def test_a_50_mb_line_is_refused_after_reading_one_mb(one_line: Path,
                                                      read: Callable[[Path], Any]) -> None:
    peak, caught = peak_bytes(lambda: read(one_line))
    assert isinstance(caught, LimitError), caught
    assert (caught.limit, caught.line) == ("MAX_LINE_CHARS", 1)
    assert peak < 12 * MB  # one line of at most 1 Mi characters, not 50 MB split in cells


def test_a_long_data_line_is_refused_with_its_line(tmp_path: Path) -> None:
    lines = example_path().read_text().splitlines()[:20]
    lines[9] = lines[9] + "," * (limits.MAX_LINE_CHARS + 10)
    path = tmp_path / "long.csv"
    path.write_text("\n".join(lines) + "\n")
    header_line = next(i for i, t in enumerate(lines, 1) if not t.startswith("#"))
    for read in (read_sensor_csv, lambda p: sniff_recording(p, "csv")):
        with pytest.raises(LimitError) as caught:
            read(path)
        assert caught.value.line == 10
        assert caught.value.limit == "MAX_LINE_CHARS"
    assert header_line < 10


def test_too_many_columns(tmp_path: Path) -> None:
    path = tmp_path / "wide.csv"
    path.write_text("Time," + ",".join(f"c{i}" for i in range(limits.MAX_COLUMNS)) + "\n")
    with pytest.raises(LimitError) as caught:
        read_kinematics_csv(path)
    assert caught.value.limit == "MAX_COLUMNS"


def test_sensor_csv_frames_beyond_the_limit(tmp_path: Path,
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    lines = example_path().read_text().splitlines()[:40]
    path = tmp_path / "walk.csv"
    path.write_text("\n".join(lines) + "\n")
    rows = sum(1 for t in lines if t and not t.startswith("#")) - 1
    monkeypatch.setattr(limits, "MAX_FRAMES", rows - 1)
    for read in (read_sensor_csv, lambda p: sniff_recording(p, "csv")):
        with pytest.raises(LimitError) as caught:
            read(path)
        assert caught.value.limit == "MAX_FRAMES"


# --------------------------------------------------------------------------- values


def sensor_csv_with(tmp_path: Path, cell: str) -> tuple[Path, int, int, str]:
    """The example's first rows with ``cell`` in row 5, column 3; path, line, column, name."""
    lines = example_path().read_text().splitlines()[:30]
    header_at = next(i for i, t in enumerate(lines) if not t.startswith("#"))
    row = header_at + 5
    cells = lines[row].split(",")
    cells[2] = cell
    lines[row] = ",".join(cells)
    path = tmp_path / "cell.csv"
    path.write_text("\n".join(lines) + "\n")
    return path, row + 1, 3, lines[header_at].split(",")[2]


@pytest.mark.parametrize("cell", ["1e308", "-1e308", "inf", "-inf", "Infinity", "2e10"])
def test_sensor_csv_refuses_infinite_and_absurd_cells_with_line_and_column(
        tmp_path: Path, cell: str) -> None:
    path, line, column, name = sensor_csv_with(tmp_path, cell)
    with pytest.raises(InputError, match=f"at line {line}, column {column}") as caught:
        read_sensor_csv(path)
    assert (caught.value.line, caught.value.column, caught.value.field) == (line, column, name)


def test_sensor_csv_nan_cell_is_still_a_dropped_sample(tmp_path: Path) -> None:
    path, line, _, name = sensor_csv_with(tmp_path, "nan")
    rec = read_sensor_csv(path)
    header_at = next(i for i, t in enumerate(path.read_text().splitlines(), 1)
                     if not t.startswith("#"))
    sensor = rec.sensors.index(name.split(".")[0])
    assert np.isnan(rec.positions[line - header_at - 1, sensor]).all()


@pytest.mark.parametrize("cell", ["1e308", "inf", "nan", "NA"])
def test_kinematics_and_acceleration_csv_refuse_bad_cells_with_line_and_column(
        tmp_path: Path, cell: str) -> None:
    for make, read in ((kinematics_csv, read_kinematics_csv),
                       (acceleration_csv, read_acceleration_csv)):
        lines = make().decode().splitlines()
        cells = lines[7].split(",")
        cells[2] = cell
        lines[7] = ",".join(cells)
        path = tmp_path / "k.csv"
        path.write_text("\n".join(lines) + "\n")
        with pytest.raises(InputError) as caught:
            read(path)
        assert (caught.value.line, caught.value.column) == (8, 3), caught.value.detail


# --------------------------------------------------------------------------- formats


def test_random_bytes_and_a_sensor_csv_are_not_a_bvh(tmp_path: Path) -> None:
    random = tmp_path / "random.bvh"
    random.write_bytes(np.random.default_rng(3).bytes(64 * 1024))
    with pytest.raises(InputError, match="not a BVH file: line 1 should be HIERARCHY"):
        sniff_kinematics(random, "bvh")
    with pytest.raises(InputError, match="not a BVH file"):
        sniff_kinematics(example_path(), "bvh")
    truncated = tmp_path / "head.bvh"
    truncated.write_text("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n}\n")
    with pytest.raises(InputError, match="no Frames: line in the MOTION section"):
        sniff_kinematics(truncated, "bvh")


def test_a_sensor_csv_is_not_a_kinematics_csv(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not a kinematics CSV"):
        sniff_kinematics(example_path(), "kinematics-csv")


def test_bounded_lines_keeps_line_ends_and_refuses_only_past_the_limit() -> None:
    text = "ab\r\ncd\n" + "x" * 8 + "\n" + "y" * 9
    assert list(limits.bounded_lines(io.StringIO(text, newline=""), limit=9))[:3] == [
        "ab\r\n", "cd\n", "x" * 8 + "\n"]
    with pytest.raises(LimitError) as caught:
        list(limits.bounded_lines(io.StringIO("a\n" + "y" * 10), limit=9))
    assert caught.value.line == 2


def test_tracker_sniff_reads_bounded_lines(tmp_path: Path) -> None:
    path = tmp_path / "polhemus.txt"
    path.write_text("1 0 0 0 0 0 0\n" + "2" + " 0" * limits.MAX_LINE_CHARS + "\n")
    with pytest.raises(LimitError) as caught:
        sniff_recording(path, "tracker")
    assert (caught.value.limit, caught.value.line) == ("MAX_LINE_CHARS", 2)


def test_npz_with_too_many_sensors_names_max_sensors(tmp_path: Path) -> None:
    """MAX_SENSORS and MAX_NAME_CHARS are both 256: the error names the one exceeded."""
    path = tmp_path / "many.npz"
    n = limits.MAX_SENSORS + 1
    np.savez(path, positions=np.zeros((2, n, 3)), quaternions=np.ones((2, n, 4)) / 2,
             sensors=np.array(["pelvis"] * n), fps=np.float64(60))
    for read in (read_sensor_npz, lambda p: sniff_recording(p, "npz")):
        with pytest.raises(LimitError) as caught:
            read(path)
        assert caught.value.limit == "MAX_SENSORS"


def test_absurd_frame_rates_name_max_fps(tmp_path: Path) -> None:
    lines = example_path().read_text().splitlines()[:30]
    header_at = next(i for i, t in enumerate(lines) if not t.startswith("#"))
    path = tmp_path / "fast.csv"
    path.write_text("# fps: 1e308\n" + "\n".join(lines) + "\n")
    with pytest.raises(LimitError) as caught:
        read_sensor_csv(path)
    assert (caught.value.limit, caught.value.field) == ("MAX_FPS", "fps")
    stamps = lines[:header_at + 1] + [
        ",".join([f"{i * 1e-9:.12f}", *t.split(",")[1:]])
        for i, t in enumerate(lines[header_at + 1:])]
    path.write_text("\n".join(stamps) + "\n")
    with pytest.raises(LimitError) as caught:
        read_sensor_csv(path)
    assert (caught.value.limit, caught.value.field) == ("MAX_FPS", "time")
    bvh = tmp_path / "fast.bvh"
    bvh.write_text("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 3 Xposition Yposition "
                   "Zposition\n}\nMOTION\nFrames: 1\nFrame Time: 1e-300\n0 0 0\n")
    with pytest.raises(LimitError) as caught:
        sniff_kinematics(bvh, "bvh")
    assert (caught.value.limit, caught.value.line) == ("MAX_FPS", 9)


def test_sensor_csv_cells_beyond_max_values(tmp_path: Path,
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    lines = example_path().read_text().splitlines()[:40]
    path = tmp_path / "walk.csv"
    path.write_text("\n".join(lines) + "\n")
    header = next(t for t in lines if not t.startswith("#"))
    monkeypatch.setattr(limits, "MAX_VALUES", 10 * len(header.split(",")))
    for read in (read_sensor_csv, lambda p: sniff_recording(p, "csv")):
        with pytest.raises(LimitError) as caught:
            read(path)
        assert caught.value.limit == "MAX_VALUES"


def test_kinematics_and_acceleration_tables_beyond_max_values(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "k.csv"
    for make, read in ((kinematics_csv, read_kinematics_csv),
                       (kinematics_csv, lambda p: sniff_kinematics(p, "kinematics-csv")),
                       (acceleration_csv, read_acceleration_csv)):
        data = make()
        path.write_bytes(data)
        columns = data.split(b"\n", 1)[0].count(b",") + 1
        monkeypatch.setattr(limits, "MAX_VALUES", 10 * columns)
        with pytest.raises(LimitError) as caught:
            read(path)
        assert caught.value.limit == "MAX_VALUES"
        monkeypatch.undo()


def test_npz_path_that_is_a_directory_or_missing(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="cannot read"):
        read_sensor_npz(tmp_path)
    with pytest.raises(FileNotFoundError):
        read_sensor_npz(tmp_path / "absent.npz")


def test_max_values_admits_a_million_frames_of_a_full_suit() -> None:
    """A million frames of a 15- or 23-sensor suit (time and 7 values per sensor) are read
    (issue 19: time linear up to 1 M frames end to end); twice as many frames of 15 sensors
    are not, with a message giving the count and the limit."""
    for sensors in (15, 23):
        limits.check_rows(1_000_000, 1 + 7 * sensors)
    with pytest.raises(LimitError) as caught:
        limits.check_rows(2_000_000, 1 + 7 * 15, line=9)
    assert caught.value.limit == "MAX_VALUES"
    assert caught.value.detail == ("the file has 212000000 values (rows × columns); the limit "
                                   "is 200000000 (MAX_VALUES)")
    assert caught.value.line == 9


def test_a_csv_beyond_max_values_is_refused_at_the_block_crossing_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A sensor CSV past ``MAX_VALUES`` is refused, naming the first row beyond it, once the
    block of lines that crosses the limit is parsed: what it keeps is bounded by the limit and
    a block, not by the file."""
    lines = example_path().read_text().splitlines()
    header_line = next(k for k, t in enumerate(lines, 1) if not t.startswith("#"))
    columns = len(lines[header_line - 1].split(","))
    rows = [t.split(",", 1)[1] for t in lines[header_line:]] * 10  # 3,000 rows, 3 MB
    path = tmp_path / "walk.csv"
    path.write_text("\n".join([*lines[:header_line],
                               *(f"{k / 60:.6f},{r}" for k, r in enumerate(rows))]) + "\n")
    monkeypatch.setattr(sensor_csv, "CHUNK_CHARS", 16 * 1024)  # 16 rows a block
    whole, caught = peak_bytes(lambda: read_sensor_csv(path))
    assert caught is None
    monkeypatch.setattr(limits, "MAX_VALUES", 20 * columns)
    peak, caught = peak_bytes(lambda: read_sensor_csv(path))
    assert isinstance(caught, LimitError), caught
    assert caught.limit == "MAX_VALUES"
    assert caught.line == header_line + 21
    assert "the limit is" in caught.detail
    assert peak < whole / 4, (peak, whole)
