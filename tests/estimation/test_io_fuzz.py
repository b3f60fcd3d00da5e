"""Fuzzing the readers: whatever the bytes, only a BonefitError escapes.

Each reader gets mutations of a valid file (bytes replaced, inserted, cut; lines doubled) and
random bytes. The example counts are small and there is no deadline, so the file runs in
seconds on a loaded machine; ``derandomize`` keeps CI reproducible.
"""

from __future__ import annotations

import contextlib
import io
import tempfile
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bonefit.estimation.errors import BonefitError
from bonefit.estimation.io.kinematics import (
    read_acceleration_csv,
    read_kinematics_csv,
    sniff_kinematics,
)
from bonefit.estimation.io.sensors import (
    example_path,
    read_sensor_csv,
    read_sensor_npz,
    sniff_recording,
    write_sensor_npz,
)
from bonefit.estimation.io.skeleton import read_skeleton_json, read_skeleton_offsets

FUZZ = settings(max_examples=40, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def sensor_csv() -> bytes:
    lines = example_path().read_bytes().splitlines(keepends=True)
    return b"".join(lines[:40])


def sensor_npz() -> bytes:
    from bonefit.estimation.io.sensors import read_sensor_csv as read

    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "walk.csv"
        src.write_bytes(sensor_csv())
        out = Path(tmp) / "walk.npz"
        write_sensor_npz(read(src), out)
        return out.read_bytes()


def sensor_npz_stored() -> bytes:
    """The same arrays in an uncompressed archive: mutations then reach the NPY headers."""
    with zipfile.ZipFile(io.BytesIO(sensor_npz())) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_STORED) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    return out.getvalue()


def kinematics_csv() -> bytes:
    names = ["Time"] + [f"{j}.D{a}" for j in ("Hips", "LeftFoot", "RightFoot") for a in "xyz"]
    names += [f"{f}.a{a}" for f in ("LeftFoot", "RightFoot") for a in "xyz"]
    rows = [",".join(names)]
    for i in range(30):
        pos = [f"{v:.3f}" for v in (0, 90, i, -10, 8, i, 10, 8 + (i % 3), i)]
        acc = [f"{v:.3f}" for v in (0.01 * i, 1.0, 0.0, 0.0, 0.98, 0.02)]
        rows.append(",".join([f"{i / 60:.5f}", *pos, *acc]))
    return ("\n".join(rows) + "\n").encode()


def acceleration_csv() -> bytes:
    rows = ["time,LeftFoot.ax [g],LeftFoot.ay [g],LeftFoot.az [g],RightFoot.ax [g],"
            "RightFoot.ay [g],RightFoot.az [g]"]
    rows += [f"{i / 60:.5f},0.0{i % 7},1.0,0.0,0.0,0.99,0.01" for i in range(30)]
    return ("\n".join(rows) + "\n").encode()


def skeleton_json() -> bytes:
    doc = ('{"kind": "skeleton", "method": "full", "fps": 60.0, "units": "m", '
           '"joints": {"hip": [[0, 1, 0], [0, 1.01, 0]]}, '
           '"orientations": {"pelvis": [[1, 0, 0, 0], [1, 0, 0, 0]]}, '
           '"offsets": {"hip": {"sensor": "pelvis", "local": [0.1, 0, 0]}}, '
           '"bone_lengths": {"femur_l": 0.4}, "quality": {"hip": {"reliability": 1}}, '
           '"warnings": ["w"], "timings": {"total": 1.5}}')
    return doc.encode()


@st.composite
def mutated(draw: st.DrawFn, seed: bytes) -> bytes:
    """``seed`` with a few bytes replaced, inserted or cut, a line repeated, or random
    bytes outright."""
    if draw(st.integers(0, 9)) == 0:
        return draw(st.binary(max_size=2048))
    data = bytearray(seed)
    for _ in range(draw(st.integers(1, 6))):
        op = draw(st.sampled_from(["replace", "insert", "cut", "token", "line"]))
        at = draw(st.integers(0, max(len(data) - 1, 0)))
        if op == "replace" and data:
            data[at] = draw(st.integers(0, 255))
        elif op == "insert":
            data[at:at] = draw(st.binary(min_size=1, max_size=8))
        elif op == "cut":
            del data[at:at + draw(st.integers(1, 64))]
        elif op == "token":
            data[at:at] = draw(st.sampled_from(
                [b"1e308", b"-1e309", b"inf", b"nan", b"NA", b",", b"\n", b"\r", b'"', b"#",
                 b"\x00", b"\xff", b"99999999999999999999", b"-0", b"{", b"[]", b"null"]))
        else:
            start = data.rfind(b"\n", 0, at) + 1
            end = data.find(b"\n", at)
            line = bytes(data[start:end + 1 if end >= 0 else len(data)])
            data[start:start] = line * draw(st.integers(1, 3))
    return bytes(data)


def only_bonefit_errors(read: Callable[[Path], Any], data: bytes, suffix: str) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"fuzz{suffix}"
        path.write_bytes(data)
        with contextlib.suppress(BonefitError):
            read(path)


READERS: dict[str, tuple[Callable[[Path], Any], Callable[[], bytes], str]] = {
    "sensor-csv": (read_sensor_csv, sensor_csv, ".csv"),
    "sensor-csv-sniff": (lambda p: sniff_recording(p, "csv"), sensor_csv, ".csv"),
    "npz": (read_sensor_npz, sensor_npz, ".npz"),
    "npz-stored": (read_sensor_npz, sensor_npz_stored, ".npz"),
    "npz-sniff": (lambda p: sniff_recording(p, "npz"), sensor_npz_stored, ".npz"),
    "kinematics-csv": (read_kinematics_csv, kinematics_csv, ".csv"),
    "kinematics-csv-sniff": (lambda p: sniff_kinematics(p, "kinematics-csv"), kinematics_csv,
                             ".csv"),
    "accelerations-csv": (read_acceleration_csv, acceleration_csv, ".csv"),
    "bvh-sniff": (lambda p: sniff_kinematics(p, "bvh"), kinematics_csv, ".bvh"),
    "skeleton-json": (read_skeleton_json, skeleton_json, ".json"),
    "skeleton-offsets": (read_skeleton_offsets, skeleton_json, ".json"),
}


@pytest.mark.parametrize("name", list(READERS))
def test_only_bonefit_errors_escape(name: str) -> None:
    read, seed, suffix = READERS[name]
    valid = seed()
    read_valid = name not in ("bvh-sniff",)  # the BVH seed is not a BVH: all must be refused
    if read_valid:
        with tempfile.TemporaryDirectory() as tmp:  # the seed itself reads
            path = Path(tmp) / f"seed{suffix}"
            path.write_bytes(valid)
            read(path)

    @FUZZ
    @given(data=mutated(valid))
    def fuzz(data: bytes) -> None:
        only_bonefit_errors(read, data, suffix)

    fuzz()


def test_the_seeds_are_what_they_claim() -> None:
    """Guard against a seed that every reader refuses (the fuzzing would then test little)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "k.csv"
        path.write_bytes(kinematics_csv())
        assert read_kinematics_csv(path).n_frames == 30
        path.write_bytes(acceleration_csv())
        time, feet, unit = read_acceleration_csv(path)
        assert time.shape == (30,)
        assert set(feet) == {"LeftFoot", "RightFoot"}
        assert unit == "g"
        path = Path(tmp) / "w.npz"
        path.write_bytes(sensor_npz_stored())
        assert np.isfinite(read_sensor_npz(path).fps)


@pytest.mark.parametrize("change", [
    {"joints": []}, {"fps": "60"}, {"fps": None}, {"quality": {"hip": 1}},
    {"warnings": 3}, {"timings": {"total": [1]}}, {"bone_lengths": {"femur_l": "long"}}])
def test_skeleton_json_fields_of_the_wrong_type_are_named(change: dict[str, Any]) -> None:
    import json

    doc = {**json.loads(skeleton_json()), **change}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "s.json"
        path.write_text(json.dumps(doc))
        with pytest.raises(BonefitError) as caught:
            read_skeleton_json(path)
    key = next(iter(change))
    assert caught.value.field is not None
    assert caught.value.field.startswith(key)


def test_skeleton_json_that_is_not_utf8() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "s.json"
        path.write_bytes(b'{"kind": "skeleton\xff"}')
        with pytest.raises(BonefitError, match="not a UTF-8 JSON document"):
            read_skeleton_json(path)
