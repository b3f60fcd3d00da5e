"""Numbers written in bulk: byte for byte as printf / numpy.savetxt, JSON with the values
of ``np.round(...).tolist()``."""

from __future__ import annotations

import io
import json
from typing import Any

import numpy as np
import pytest

from bonefit.estimation import numtext
from bonefit.estimation.numtext import JsonArray, JsonLater, fixed_text, json_blocks, plain


def printf_rows(table: np.ndarray, decimals: int, sep: str, nan: str | None = None) -> str:
    """The reference: one Python format per number."""
    def one(v: float) -> str:
        if nan is not None and not np.isfinite(v):
            return nan
        return f"{v:.{decimals}f}"
    return "".join(sep.join(one(v) for v in row) + "\n" for row in table.tolist())


@pytest.mark.parametrize("seed", range(6))
def test_rows_are_printf_byte_for_byte(seed: int, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(numtext, "_python_block", None)  # every digit from numpy here
    rng = np.random.default_rng(seed)
    for decimals in (0, 1, 3, 6, 8, 10):
        # up to 1e12 once scaled: far from 2**52, so ties are the only way to Python
        table = rng.normal(size=(40, 5)) * 10.0 ** rng.integers(-7, 11 - decimals)
        table[3, 2], table[5, 0] = -0.0, -1e-12  # negative zeros print "-0.000"
        table[6, 3] = 1234.0                     # a wide integer part
        for sep in (",", " ", ""):
            assert fixed_text(table, decimals, sep=sep) == printf_rows(table, decimals, sep)


def test_ties_and_huge_values_are_printf_too() -> None:
    rng = np.random.default_rng(7)
    table = np.round(rng.normal(size=(30, 4)) * 100, 2)  # exact binary ties at 1 decimal
    table[0] = [0.125, 2.5, -0.375, 2.0 ** 60]            # and beyond the integer path
    for decimals in (0, 1, 2, 6):
        assert fixed_text(table, decimals) == printf_rows(table, decimals, ",")


def test_savetxt_identity_and_small_blocks(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(numtext, "BLOCK_VALUES", 7)  # many blocks, rows split across none
    table = np.random.default_rng(1).normal(size=(25, 4)) * 50
    out = io.StringIO()
    np.savetxt(out, table, fmt="%.6f", delimiter=" ")
    assert fixed_text(table, 6, sep=" ") == out.getvalue()


@pytest.mark.parametrize("decimals", range(16))
def test_every_count_of_decimals_and_integer_digits(decimals: int) -> None:
    """The digits of the decimals go in 8-byte words where they fit within the number's
    field: every split of integer digits and decimals against printf."""
    rng = np.random.default_rng(decimals)
    for digits in range(1, 16 - decimals):
        table = rng.uniform(-1, 1, size=(7, 3)) * 10.0 ** digits
        table[0, 0] = -(10.0 ** (digits - 1))  # the widest integer part of the block
        for sep, ends in ((",", ("", "\n")), (", ", (", [", "]"))):
            text = fixed_text(table, decimals, sep=sep, row_start=ends[0], row_end=ends[1])
            rows = "".join(ends[0] + sep.join(f"{v:.{decimals}f}" for v in row) + ends[1]
                           for row in table.tolist())
            assert text == rows, (decimals, digits)


def test_integer_parts_at_every_power_of_ten(monkeypatch: pytest.MonkeyPatch) -> None:
    """Integer digits are divided out in the narrowest type that holds them (16, 32, 64
    bits): both sides of each power of ten, where a type or a leading zero changes."""
    monkeypatch.setattr(numtext, "_python_block", None)  # every digit from numpy here
    for digits in range(1, 16):
        for decimals in sorted({0, min(3, 15 - digits), 15 - digits}):
            table = np.array([[10.0 ** digits - 1, -(10.0 ** (digits - 1))],
                              [10.0 ** (digits - 1) - 1, 0.3], [-7.0, 0.0]])
            assert fixed_text(table, decimals, sep=" ") == printf_rows(table, decimals, " ")


def test_any_memory_layout() -> None:
    table = np.random.default_rng(2).normal(size=(9, 6)) * 1e3
    for view in (table.T, np.asfortranarray(table), table[::2, ::3]):
        assert fixed_text(view, 4) == printf_rows(view, 4, ",")


def test_non_finite_values_as_empty_cells_or_printf() -> None:
    table = np.array([[1.5, np.nan, -np.inf], [np.inf, 2.25, 0.0]])
    assert fixed_text(table, 2, nan="") == "1.50,,\n,2.25,0.00\n"
    assert fixed_text(table, 2) == printf_rows(table, 2, ",")


def test_row_start_and_end() -> None:
    table = np.array([[1.0, -2.5], [3.125, 4.0]])
    assert fixed_text(table, 3, sep=", ", row_start="[", row_end="];") == (
        "[1.000, -2.500];[3.125, 4.000];")


@pytest.mark.parametrize("separators", [None, (",", ":")])
def test_json_document_has_the_values_of_rounded_lists(separators: tuple[str, str] | None,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(numtext, "BLOCK_VALUES", 5)
    rng = np.random.default_rng(3)
    pos, q = rng.normal(size=(11, 3)) * 1e-3, rng.normal(size=(11, 4))
    doc = {"a": JsonArray(pos, 6), "n": {"q": JsonArray(q, 8)}, "t": JsonArray(pos[:, 0], 5),
           "s": "x\u0000y", "e": JsonArray(np.empty((0, 3)), 6)}
    text = "".join(json_blocks(doc, separators=separators))
    reference = {"a": np.round(pos, 6).tolist(), "n": {"q": np.round(q, 8).tolist()},
                 "t": np.round(pos[:, 0], 5).tolist(), "s": "x\u0000y", "e": []}
    assert json.loads(text) == reference == plain(doc)
    assert "e-" not in text  # no exponent notation for small values


@pytest.mark.parametrize("decimals", [0, 3, 6, 8])
def test_json_arrays_are_the_rounded_values_printf_byte_for_byte(
        decimals: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """The digits come from ``rint(v * 10**d)``, np.round's intermediate: the text of the
    rounded values, negative zeros and halfway cases included; a block with a value too
    large for that goes through np.round and printf."""
    monkeypatch.setattr(numtext, "BLOCK_VALUES", 6)  # blocks of two rows
    rng = np.random.default_rng(decimals)
    values = rng.normal(size=(9, 3)) * 10.0 ** rng.integers(-9, 5, size=(9, 3))
    values[0] = [-0.0, -1e-12, 0.5 * 10.0 ** -decimals]  # "-0...", "-0...", a halfway case
    values[1] = [2.5, -1.5 * 10.0 ** -decimals, 1e-300]
    values[4, 1] = 3e14  # past 2**49 once scaled (for decimals > 1): np.round, then printf
    rounded = np.round(values, decimals)
    expected = "[" + ", ".join("[" + ", ".join(f"{v:.{decimals}f}" for v in row) + "]"
                               for row in rounded.tolist()) + "]"
    slow: list[int] = []

    def counted(table: np.ndarray, places: int, **layout: Any) -> str:
        slow.append(len(table))
        return fixed_text(table, places, **layout)

    monkeypatch.setattr(numtext, "fixed_text", counted)
    assert "".join(JsonArray(values, decimals).blocks(", ")) == expected
    assert slow == ([2] if decimals > 0 else [])  # only the block of rows 4 and 5


@pytest.mark.parametrize("layout", [{}, {"indent": 2}, {"separators": (",", ":")}])
def test_a_later_value_is_computed_when_reached_and_laid_out_as_json_dumps(
        layout: dict[str, Any]) -> None:
    calls: list[str] = []

    def timings() -> dict[str, object]:
        calls.append("timings")
        return {"read_s": 0.5, "nested": [1, {"x": 2.0}]}

    doc = {"a": JsonArray(np.arange(4.0), 1), "b": {"c": [1, 2], "t": JsonLater(timings)}}
    blocks = json_blocks(doc, **layout)
    head = next(blocks)
    assert calls == []  # not computed before its turn
    text = head + "".join(blocks)
    assert calls == ["timings"]
    assert json.loads(text) == plain(doc)
    without_arrays = {"b": doc["b"]}
    assert "".join(json_blocks(without_arrays, **layout)) == json.dumps(plain(without_arrays),
                                                                        **layout)


# --------------------------------------------------------------------------- parsing


def loadtxt_rows(data: bytes) -> np.ndarray:
    """The reference: numpy.loadtxt of the same lines."""
    return np.loadtxt(io.StringIO(data.decode()), delimiter=",", dtype=float, ndmin=2,
                      comments=None, quotechar=None)


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and bool((a.view(np.int64) == b.view(np.int64)).all())


@pytest.mark.parametrize("seed", range(8))
def test_plain_decimals_parse_to_the_bits_of_loadtxt(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n_rows, n_cols = int(rng.integers(1, 60)), int(rng.integers(1, 12))
    values = rng.normal(size=(n_rows, n_cols)) * 10.0 ** rng.integers(-9, 9, (n_rows, n_cols))
    places = rng.integers(0, 16, (n_rows, n_cols))
    cells = [[f"{v:.{d}f}"[:16] for v, d in zip(row, ds, strict=True)]
             for row, ds in zip(values.tolist(), places.tolist(), strict=True)]
    cells[0][0] = "-0.000"  # -0.0
    if n_cols > 1:
        cells[-1][1] = ["+.5", "7.", "-.25", "0012.50", "+3"][seed % 5]
    data = "".join(",".join(row) + "\n" for row in cells).encode()
    got = numtext.decimal_rows(data, n_cols)
    assert got is not None
    assert same_bits(got, loadtxt_rows(data))


def test_fifteen_significant_digits_and_uniform_places_are_exact() -> None:
    rng = np.random.default_rng(11)
    mantissas = rng.integers(0, 10**15, size=(500, 3))
    for places in (0, 6, 14):  # 15 digits in at most 16 characters
        data = "".join(",".join(f"{m / 10**places:.{places}f}" if places else str(m)
                                for m in row) + "\n" for row in mantissas.tolist()).encode()
        got = numtext.decimal_rows(data, 3)
        assert got is not None
        assert same_bits(got, loadtxt_rows(data))


def test_empty_cells_are_nan() -> None:
    got = numtext.decimal_rows(b",1.5,\n-2,,0\n", 3)
    assert got is not None
    assert np.array_equal(got, [[np.nan, 1.5, np.nan], [-2.0, np.nan, 0.0]], equal_nan=True)


@pytest.mark.parametrize("data", [
    b"1e5,2\n", b"nan,2\n", b"1, 2\n", b"1,2\r\n", b"1,\"2\"\n", b"#1,2\n",  # loadtxt's own
    b"1,2\n\n3,4\n", b"1,2\n3\n", b"1,2,3\n", b"1,2",                      # layout
    b"1.2.3,4\n", b"--1,2\n", b"1-,2\n", b"+-1,2\n", b"-,2\n", b".,2\n",  # malformed
    b"12345678901234567,1\n", b"9007199254740993,1\n", b"1,2\n\xc3\xa9,3\n", b"",
])
def test_anything_else_is_left_to_loadtxt(data: bytes) -> None:
    assert numtext.decimal_rows(data, 2) is None


def test_a_blank_line_of_one_column_is_not_an_empty_cell() -> None:
    assert numtext.decimal_rows(b"1\n\n2\n", 1) is None  # loadtxt skips it: two rows
    got = numtext.decimal_rows(b"1\n-2.5\n", 1)
    assert got is not None
    assert same_bits(got, loadtxt_rows(b"1\n-2.5\n"))
