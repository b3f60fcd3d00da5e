"""``read_bvh``: what Blender reads is read, malformed files are refused naming the line, and
hostile files (BVH bombs) cost bounded time and memory. Fuzzed: only BonefitError escapes."""

from __future__ import annotations

import contextlib
import io

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bonefit.estimation import bvh
from bonefit.estimation.bvh import MAX_NODES, BvhMotion, read_bvh, write_bvh
from bonefit.estimation.errors import BonefitError, InputError
from bonefit.estimation.io.body import find_bvh_feet
from bonefit.estimation.numtext import BLOCK_VALUES
from tests.estimation.bvh_corpus import CONVENTIONS, body_motion, bvh_text

SMALL = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Bip01 L Thigh
  {
    OFFSET 10 -5 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 -80 0
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.0333333
0 90 0 0 0 0 0 0 0
1 90 0 0 0 0 0 10 0
2 90 0 0 0 0 0 20 0
"""


def read(text: str) -> object:
    return read_bvh(io.StringIO(text))


def test_bom_crlf_and_names_with_spaces() -> None:
    motion = read_bvh(io.StringIO("\ufeff" + SMALL.replace("\n", "\r\n")))
    assert motion.names == ("Hips", "Bip01 L Thigh", "Bip01 L Thigh_end")
    assert motion.joints() == ("Hips", "Bip01 L Thigh")
    assert motion.values.shape == (3, 9)
    assert motion.notes == ()


def test_bom_in_a_file(tmp_path: object) -> None:
    from pathlib import Path

    path = Path(str(tmp_path)) / "bom.bvh"
    path.write_bytes(b"\xef\xbb\xbf" + SMALL.encode())
    assert read_bvh(path).n_frames == 3


def test_frames_larger_than_the_rows_reads_the_rows() -> None:
    motion = read_bvh(io.StringIO(SMALL.replace("Frames: 3", "Frames: 1000000000")))
    assert motion.n_frames == 3
    assert motion.notes == ("header says 1000000000 frames, the file has 3 rows: read 3",)


def test_more_rows_than_frames_reads_the_frames() -> None:
    motion = read_bvh(io.StringIO(SMALL.replace("Frames: 3", "Frames: 2")))
    assert motion.n_frames == 2
    assert "read the first 2" in motion.notes[0]


@pytest.mark.parametrize(("text", "line", "message"), [
    (SMALL.rstrip("\n")[:-4], 21, "has 7 values, the hierarchy declares 9 channels (a truncated"),
    (SMALL.replace("2 90 0 0 0 0 0 20 0", "2 90 0 0 x 0 0 20 0"), 21, "not a number: 'x'"),
    (SMALL.replace("2 90 0 0 0 0 0 20 0", "2 90 nan 0 0 0 0 20 0"), 21, "must be finite"),
    (SMALL.replace("OFFSET 10 -5 0", "OFFSET 10 -5 inf"), 8, "OFFSET z must be finite"),
    (SMALL.replace("Frame Time: 0.0333333", "Frame Time: 0"), 18, "frame time must be positive"),
    (SMALL.replace("Frames: 3", "Frames: many"), 17, "bad frame count 'many'"),
    (SMALL.replace("3 Zrotation Xrotation Yrotation", "3 Zrotation Xrotation Wiggle"), 9,
     "unknown channel 'Wiggle'"),
    (SMALL.replace("JOINT Bip01 L Thigh", "JOINT"), 6, "JOINT without a name"),
    (SMALL.replace("CHANNELS 3", "CHANNELS 10000000"), 9, "at most 6 channels"),
    (SMALL.split("MOTION")[0], 15, "unexpected end of BVH file"),
    ("HIERARCHY\nROOT\n", 2, "ROOT without a name"),
    ("hello\n", 1, "expected 'HIERARCHY'"),
])
def test_malformed_files_name_the_line(text: str, line: int, message: str) -> None:
    with pytest.raises(InputError) as info:
        read(text)
    assert message in info.value.detail
    assert info.value.line == line
    assert "loadtxt" not in info.value.detail
    assert "could not convert" not in info.value.detail


def test_a_million_joints_is_refused_after_the_limit() -> None:
    bomb = ("HIERARCHY\nROOT r\n{\nOFFSET 0 0 0\n"
            + "JOINT j\n{\nOFFSET 0 0 0\nCHANNELS 3 Xrotation Yrotation Zrotation\n" * 10**6)
    with pytest.raises(InputError, match=f"more than {MAX_NODES} joints") as info:
        read(bomb)
    assert info.value.line == 4 + 4 * (MAX_NODES - 1) + 1  # the JOINT one too many


def test_ten_million_channels_are_refused() -> None:
    bomb = SMALL.replace("CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation",
                         "CHANNELS 10000000 " + "Xrotation " * 20)
    with pytest.raises(InputError, match="CHANNELS 10000000: a joint has at most 6"):
        read(bomb)


def test_real_names_of_the_corpus_round_trip() -> None:
    names = CONVENTIONS["3ds-max-biped"]
    motion = body_motion(names)
    back = read_bvh(io.StringIO(bvh_text(motion, indent="\t", brace_on_name_line=True)))
    assert back.names == motion.names
    np.testing.assert_allclose(back.values, motion.values, rtol=1e-8)
    np.testing.assert_allclose(back.offsets, motion.offsets, rtol=1e-8, atol=1e-12)


FUZZ = settings(max_examples=250, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow])
BASE = bvh_text(body_motion(n_frames=4))


@st.composite
def mutated(draw: st.DrawFn) -> str:
    """The corpus body with characters, tokens or lines deleted, inserted or replaced."""
    text = BASE
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["cut", "insert", "replace", "token", "line"]))
        at = draw(st.integers(0, len(text)))
        if kind == "cut":
            text = text[:at] + text[at + draw(st.integers(1, 200)):]
        elif kind == "insert":
            text = text[:at] + draw(st.text(max_size=20)) + text[at:]
        elif kind == "replace":
            text = text[:at] + draw(st.characters()) + text[at + 1:]
        elif kind == "token":
            tok = draw(st.sampled_from(["{", "}", "JOINT", "End Site", "ROOT x", "CHANNELS",
                                        "OFFSET", "MOTION", "Frames:", "1e308", "-0", "nan",
                                        "99999999999999999999", "\ufeff", "\r", "\t"]))
            text = text[:at] + f" {tok} " + text[at:]
        else:
            lines = text.splitlines()
            k = draw(st.integers(0, len(lines) - 1))
            lines = lines[:k] + lines[k + 1:] if draw(st.booleans()) else \
                lines[:k] + [lines[k]] * 2 + lines[k + 1:]
            text = "\n".join(lines)
    return text


@FUZZ
@given(mutated())
def test_fuzzed_files_raise_only_bonefit_errors(text: str) -> None:
    try:
        motion = read_bvh(io.StringIO(text))
    except BonefitError:
        return
    with contextlib.suppress(BonefitError):
        find_bvh_feet(motion)


@FUZZ
@given(st.text(max_size=300))
def test_arbitrary_text_raises_only_bonefit_errors(text: str) -> None:
    with contextlib.suppress(BonefitError):
        read_bvh(io.StringIO("HIERARCHY\n" + text))


@pytest.mark.parametrize("threaded", [False, True])
def test_long_motion_rows_formatted_on_threads_are_the_text_of_one_thread(
        threaded: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """A long take's MOTION rows formatted block by block on two threads (from
    ``threads.MIN_FRAMES`` frames): the same file, rows in order, as in one thread, and
    read back to the values written."""
    n_frames = 3 * BLOCK_VALUES // 6 + 7  # four blocks of six channels, the last short
    rng = np.random.default_rng(19)
    values = rng.uniform(-400.0, 400.0, size=(n_frames, 6))
    motion = BvhMotion(("root", "root_end"), (-1, 0), np.array([[0.0, 0, 0], [0, 10, 0]]),
                       (("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation",
                         "Yrotation"), ()), 1 / 240, values)
    monkeypatch.setattr(bvh, "MIN_FRAMES", n_frames + 1)  # one thread
    one = io.StringIO()
    write_bvh(motion, one, precision=6)
    if threaded:
        monkeypatch.setattr(bvh, "MIN_FRAMES", n_frames)
        monkeypatch.setattr(bvh, "workers", lambda: 2)
    out = io.StringIO()
    write_bvh(motion, out, precision=6)
    assert out.getvalue() == one.getvalue()
    back = read_bvh(io.StringIO(out.getvalue()))
    assert np.abs(back.values - values).max() <= 5e-7
