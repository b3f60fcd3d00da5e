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
