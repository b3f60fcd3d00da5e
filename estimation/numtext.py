"""Numbers as text in bulk: rows of fixed-decimal numbers and JSON arrays, formatted by
numpy a block of rows at a time instead of one Python call per number; and the reverse for
plain decimals (:func:`decimal_rows`, the sensor CSV reader's parse).

A number is written as ``f"{v:.{decimals}f}"`` would write it (C ``printf``, correctly
rounded), byte for byte: its digits come from the integer ``rint(v * 10**decimals)``, which is
the correct rounding except within a rounding error of a tie; a block holding such a value (or
one too large for 52 bits, or a NaN where a text for it is needed) is formatted by Python
instead. Text is produced in blocks of about :data:`BLOCK_VALUES` numbers, so a writer holds a
few megabytes of text at a time whatever the size of the table.

Examples
--------
>>> import numpy as np
>>> from bonefit.estimation.numtext import fixed_text
>>> fixed_text(np.array([[1.25, -0.5], [3.0, 1e-9]]), 3, sep=",")
'1.250,-0.500\\n3.000,0.000\\n'
"""

from __future__ import annotations

import io
import itertools
import json
import os
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np
from numpy.typing import NDArray

BLOCK_VALUES: Final[int] = 1 << 17
"""Numbers formatted per block (about 1.5 MB of text, ~10 MB of scratch arrays)."""

_MAX_DECIMALS: Final[int] = 15
_DIGIT0: Final[int] = ord("0")
_MARK: Final[str] = "\x00bonefit-array\x00"


def fixed_blocks(table: NDArray[np.float64], decimals: int, *, sep: str = ",",
                 row_start: str = "", row_end: str = "\n",
                 nan: str | None = None) -> Iterator[str]:
    """The text of the rows of ``table``, block by block.

    Parameters
    ----------
    table : ndarray, shape (R, C)
        Numbers to write.
    decimals : int
        Decimal places of every number (0 to 15).
    sep : str
        Between the numbers of a row.
    row_start, row_end : str
        Before and after each row.
    nan : str, optional
        Text of a non-finite value (e.g. ``""``: an empty cell); by default ``printf``'s
        (``nan``, ``inf``).

    Yields
    ------
    str
        Consecutive pieces of the text; their concatenation is every row in order.
    """
    table = np.asarray(table, dtype=float)
    if table.ndim != 2:
        raise ValueError(f"table must be 2-D, got shape {table.shape}")
    if not 0 <= decimals <= _MAX_DECIMALS:
        raise ValueError(f"decimals must be 0 to {_MAX_DECIMALS}, got {decimals}")
    layout = _Layout(decimals, sep, row_start, row_end, nan)
    step = max(1, BLOCK_VALUES // max(table.shape[1], 1))
    for start in range(0, table.shape[0], step):
        block = table[start:start + step]
        scaled = _scaled(block, layout)
        yield (_python_block(block, layout) if scaled is None
               else _numpy_block(block, scaled, layout))


def fixed_text(table: NDArray[np.float64], decimals: int, **layout: Any) -> str:
    """The whole text of :func:`fixed_blocks` (same parameters) as one string."""
    return "".join(fixed_blocks(table, decimals, **layout))


@dataclass(frozen=True)
class _Layout:
    decimals: int
    sep: str
    row_start: str
    row_end: str
    nan: str | None

    def number(self, value: float) -> str:
        """One number as Python writes it (the reference the numpy path reproduces)."""
        if not np.isfinite(value) and self.nan is not None:
            return self.nan
        return f"{value:.{self.decimals}f}"


def _python_block(block: NDArray[np.float64], layout: _Layout) -> str:
    return "".join(layout.row_start + layout.sep.join(layout.number(v) for v in row.tolist())
                   + layout.row_end for row in block)


def _scaled(block: NDArray[np.float64], layout: _Layout) -> NDArray[np.float64] | None:
    """``block * 10**decimals`` (non-finite values as 0) when its ``rint`` is the correct
    rounding of every value: none within a rounding error of a tie nor beyond 2**52, and
    non-finite values have a text the numpy path writes (empty); else None."""
    with np.errstate(invalid="ignore", over="ignore"):
        scaled = block * 10.0 ** layout.decimals
        finite = np.isfinite(scaled)
        if not finite.all():
            if layout.nan != "":
                return None
            scaled[~finite] = 0.0
        size = np.abs(scaled)
        tie_distance = np.abs(np.abs(scaled - np.trunc(scaled)) - 0.5)
    if size.max(initial=0.0) < 2.0 ** 52 and (tie_distance > size * 2.0 ** -51).all():
        return scaled
    return None


def _ascii8_words(values: NDArray[np.uint64]) -> NDArray[np.uint64]:
    """Little-endian 64-bit words whose bytes are the eight zero-padded ASCII digits of
    integers below 10**8 (...), the most significant first; computed within the words (SWAR:
    two halves of four digits, four pairs, eight digits)."""
    high = values // np.uint64(10_000)
    words = high | ((values - high * np.uint64(10_000)) << np.uint64(32))
    # x // 100 of x < 10**4 is (x * 10486) >> 20, and x // 10 of x < 100 is (x * 205) >> 11
    high = ((words * np.uint64(10486)) >> np.uint64(20)) & np.uint64(0x0000007F0000007F)
    words = high | ((words - high * np.uint64(100)) << np.uint64(16))
    high = ((words * np.uint64(205)) >> np.uint64(11)) & np.uint64(0x000F000F000F000F)
    words = high | ((words - high * np.uint64(10)) << np.uint64(8))
    words |= np.uint64(0x3030303030303030)  # "0" in each byte
    return np.ascontiguousarray(words, dtype="<u8")


_DIGIT_TYPES: Final[tuple[tuple[int, type[np.unsignedinteger[Any]]], ...]] = (
    (4, np.uint16), (9, np.uint32), (16, np.uint64))
"""The narrowest unsigned type of integers of up to so many digits: :func:`_put_digits`
divides in it (the narrower, the faster)."""


def _put_digits(values: NDArray[np.uint64], out: NDArray[np.uint8]) -> None:
    """Zero-padded ASCII digits of non-negative integers (R, C) below 10**W into ``out``
    (R, C, W), W at most 16: one division by ten per digit, each digit stored straight into
    its strided column (no (R, C, 8) temporary to copy from)."""
    width = out.shape[-1]
    kind = next(kind for digits, kind in _DIGIT_TYPES if width <= digits)
    rest = values.astype(kind)
    ten, zero = kind(10), kind(_DIGIT0)
    for k in range(width - 1, 0, -1):
        higher = rest // ten
        np.add(rest - higher * ten, zero, out=out[..., k], casting="unsafe")
        rest = higher
    np.add(rest, zero, out=out[..., 0], casting="unsafe")


@dataclass(frozen=True, eq=False)
class _Fields:
    """Rows of fixed-width fields, one per number: ``sign, width digits, point, decimals,
    sep``, between ``row_start`` and ``row_end``; ``line`` (R, L) holds the characters and
    ``mask`` (R, L) which of them the text keeps."""

    line: NDArray[np.uint8]
    mask: NDArray[np.bool_]
    start: int
    field: int
    width: int
    decimals: int

    def chars(self) -> NDArray[np.uint8]:
        """The fields of ``line`` (R, C, field), a view."""
        return self._of(self.line)

    def keep(self) -> NDArray[np.bool_]:
        """The fields of ``mask`` (R, C, field), a view."""
        return self._of(self.mask)

    def _of(self, rows: NDArray[Any]) -> NDArray[Any]:
        n_cols = (rows.shape[1] - self.start) // self.field
        return rows[:, self.start:self.start + n_cols * self.field].reshape(
            rows.shape[0], n_cols, self.field)

    def words(self, at: int) -> NDArray[np.uint64]:
        """The 8 bytes from ``at`` in every field as one little-endian word (R, C): a view
        for unaligned stores (``at + 8`` at most the field's width)."""
        n_cols = (self.line.shape[1] - self.start) // self.field
        return np.ndarray((self.line.shape[0], n_cols), dtype="<u8", buffer=self.line,
                          offset=self.start + at, strides=(self.line.strides[0], self.field))


def _fields(n_rows: int, n_cols: int, width: int, layout: _Layout) -> _Fields:
    """Rows of fields with their constant characters (``-``, the point, the separators,
    the row's start and end), from one template row."""
    d, sep = layout.decimals, layout.sep
    one = "-" + "0" * width + ("." + "0" * d if d else "")
    text = layout.row_start + (one + sep) * n_cols + layout.row_end
    row = np.frombuffer(text.encode(), dtype=np.uint8)
    kept = np.ones(row.size, dtype=bool)
    end = len(layout.row_start) + n_cols * (len(one) + len(sep))
    if n_cols:
        kept[end - len(sep):end] = False  # no separator after the last number
    line = np.empty((n_rows, row.size), dtype=np.uint8)
    line[...] = row
    mask = np.empty(line.shape, dtype=bool)
    mask[...] = kept
    return _Fields(line, mask, len(layout.row_start), len(one) + len(sep), width, d)


def _put_number_digits(fields: _Fields, whole: NDArray[np.uint64],
                       frac: NDArray[np.uint64]) -> None:
    """The digits of the integer and decimal parts into ``fields``; leading zeros of the
    integer part masked."""
    chars, width, d = fields.chars(), fields.width, fields.decimals
    at = 2 + width + d - 8  # the eight digits of the decimals (d ≤ 8) ending at theirs
    if 0 < d <= 8 and at >= 0:
        fields.words(at)[...] = _ascii8_words(frac)  # over the point and integer digits
        chars[..., 1 + width] = ord(".")
        if at == 0:
            chars[..., 0] = ord("-")
    elif d:
        _put_digits(frac, chars[..., 2 + width:2 + width + d])
    if width == 1:
        chars[..., 1] = whole.astype(np.uint8) + np.uint8(ord("0"))
        return
    _put_digits(whole, chars[..., 1:1 + width])
    keep = fields.keep()
    for k in range(width - 1):  # a leading digit is kept if the number reaches its place
        np.greater_equal(whole, np.uint64(10 ** (width - 1 - k)), out=keep[..., 1 + k])


def _numpy_block(block: NDArray[np.float64], scaled: NDArray[np.float64],
                 layout: _Layout) -> str:
    """Rows of ``block`` with every digit computed by numpy: each number in a fixed-width
    field of the row, a mask keeping the characters it uses."""
    number = np.abs(np.rint(scaled)).astype(np.uint64)
    whole = number // np.uint64(10**layout.decimals)
    frac = number - whole * np.uint64(10**layout.decimals)
    width = len(str(int(whole.max(initial=0))))
    fields = _fields(block.shape[0], block.shape[1], width, layout)
    _put_number_digits(fields, whole, frac)
    keep = fields.keep()
    keep[..., 0] = np.signbit(block)
    if layout.nan == "":
        keep[~np.isfinite(block), :fields.field - len(layout.sep)] = False
    return fields.line[fields.mask].tobytes().decode("utf-8")


# --------------------------------------------------------------------------- JSON


@dataclass(frozen=True, eq=False)
class JsonArray:
    """A numeric array in a JSON document: written with the values
    ``np.round(values, decimals).tolist()`` has, each with ``decimals`` decimals (``0.000061``
    where ``json.dumps`` writes ``6.1e-05``, ``1.500000`` for ``1.5``), in bulk.

    Attributes
    ----------
    values : ndarray, shape (F,) or (F, C)
        Finite numbers.
    decimals : int
        Decimal places they are rounded to.
    """

    values: NDArray[np.float64]
    decimals: int

    def tolist(self) -> list[Any]:
        """The plain Python lists ``json`` would get."""
        out: list[Any] = np.round(np.asarray(self.values, dtype=float), self.decimals).tolist()
        return out

    def blocks(self, sep: str, done: Callable[[int], None] | None = None) -> Iterator[str]:
        """The JSON text of the array, block by block, items separated by ``sep``;
        ``done(n)`` is told the count of numbers of each block once it is yielded."""
        values = np.asarray(self.values, dtype=float)
        flat = values.ndim == 1
        table = values.reshape(-1, 1) if flat else values
        first = True
        yield "["
        layout = _Layout(self.decimals, sep, sep if flat else sep + "[", "" if flat else "]",
                         None)
        step = max(1, BLOCK_VALUES // max(table.shape[1], 1))
        for start in range(0, table.shape[0], step):
            text = _rounded_text(table[start:start + step], layout)
            yield text[len(sep):] if first else text
            first = False
            if done is not None:
                done(table[start:start + step].size)
        yield "]"


_EXACT_DIGITS: Final[float] = 2.0 ** 49
"""Scaled values below which :func:`_rounded_text` writes the digits of ``rint(v * 10**d)``
itself: ``np.round``'s value ``n / 10**d`` times ``10**d`` is then within a quarter of the
integer ``n``, so printf writes ``n``'s digits."""


def _rounded_text(block: NDArray[np.float64], layout: _Layout) -> str:
    """The text of ``np.round(block, decimals)`` with ``decimals`` decimals (``fixed_text``
    of it), the digits from ``rint(block * 10**decimals)``, ``np.round``'s own intermediate,
    without dividing back and scaling again: the same text, a third fewer passes. Blocks
    with a value beyond :data:`_EXACT_DIGITS` once scaled, or not finite, are rounded and
    written by ``fixed_text``."""
    scaled = np.rint(block * 10.0 ** layout.decimals)
    if scaled.size and scaled.min() > -_EXACT_DIGITS and scaled.max() < _EXACT_DIGITS:
        # the sign of n / 10**d is n's, -0.0 included
        return _numpy_block(scaled, scaled, layout)
    return fixed_text(np.round(block, layout.decimals), layout.decimals, sep=layout.sep,
                      row_start=layout.row_start, row_end=layout.row_end)


@dataclass(frozen=True, eq=False)
class JsonLater:
    """A value of a JSON document known only when the writer reaches it: ``value()`` is
    called then and its JSON written in its place (the timings at the end of a result whose
    other files are written meanwhile).

    Attributes
    ----------
    value : callable
        Returns plain JSON data (no :class:`JsonArray`); what it raises, the writer raises.
    """

    value: Callable[[], Any]


def plain(document: Any) -> Any:
    """``document`` with every :class:`JsonArray` replaced by its lists and every
    :class:`JsonLater` by its value."""
    if isinstance(document, JsonArray):
        return document.tolist()
    if isinstance(document, JsonLater):
        return plain(document.value())
    if isinstance(document, Mapping):
        return {k: plain(v) for k, v in document.items()}
    if isinstance(document, list | tuple):
        return [plain(v) for v in document]
    return document


def array_values(document: Any) -> int:
    """The count of numbers in the :class:`JsonArray` values of ``document`` (what
    :func:`json_blocks` tells its ``done``)."""
    if isinstance(document, JsonArray):
        return int(np.size(document.values))
    if isinstance(document, Mapping):
        return sum(array_values(v) for v in document.values())
    if isinstance(document, list | tuple):
        return sum(array_values(v) for v in document)
    return 0


def json_blocks(document: Any, *, indent: int | None = None,
                separators: tuple[str, str] | None = None,
                done: Callable[[int], None] | None = None) -> Iterator[str]:
    """The text of ``json.dumps(plain(document), indent=..., separators=...)`` up to the
    layout inside the arrays, piece by piece: the document around its :class:`JsonArray`
    values is dumped by ``json`` (``allow_nan=False``), each array in bulk, each
    :class:`JsonLater` when its turn comes. ``done(n)``, optional, is told the count of
    numbers of each array block written (they add up to :func:`array_values`)."""
    arrays: list[JsonArray | JsonLater] = []

    def mark(value: Any) -> Any:
        if isinstance(value, JsonArray | JsonLater):
            arrays.append(value)
            return f"{_MARK}{len(arrays) - 1}{_MARK}"
        if isinstance(value, Mapping):
            return {k: mark(v) for k, v in value.items()}
        if isinstance(value, list | tuple):
            return [mark(v) for v in value]
        return value

    item_sep = separators[0] if separators is not None else ", "
    text = json.dumps(mark(document), indent=indent, separators=separators, allow_nan=False)
    marker = json.dumps(_MARK)[1:-1]  # as json escapes it
    parts = text.split(f'"{marker}')
    yield parts[0]
    for before, part in itertools.pairwise(parts):
        number, _, rest = part.partition(f'{marker}"')
        item = arrays[int(number)]
        if isinstance(item, JsonArray):
            yield from item.blocks(item_sep, done)
        else:  # at the depth of its line, as json.dumps would have indented it
            depth = before[before.rfind("\n") + 1:]
            depth = depth[:len(depth) - len(depth.lstrip(" "))]
            yield json.dumps(item.value(), indent=indent, separators=separators,
                             allow_nan=False).replace("\n", "\n" + depth)
        yield rest


def write_text_blocks(blocks: Iterable[str], target: str | os.PathLike[str] | io.TextIOBase,
                      *, end: str = "") -> None:
    """Write consecutive pieces of text to a path (UTF-8) or a text stream."""
    if isinstance(target, io.TextIOBase):
        for text in blocks:
            target.write(text)
        target.write(end)
        return
    with Path(target).open("w", encoding="utf-8", newline="") as handle:
        for text in blocks:
            handle.write(text)
        handle.write(end)


# --------------------------------------------------------------------------- parsing

_MAX_CELL: Final[int] = 16
"""Characters of the longest cell :func:`decimal_rows` parses (two 8-byte words)."""

_KEEP_LAST: Final = np.array([0] + [((1 << 64) - 1) << 8 * (8 - k) & ((1 << 64) - 1)
                                    for k in range(1, 9)], dtype=np.uint64)
"""Masks keeping the last k bytes (0 to 8) of a little-endian 8-byte word."""

_KEEP_LOW: Final = _KEEP_LAST[np.minimum(np.arange(_MAX_CELL + 1), 8)]
_KEEP_HIGH: Final = _KEEP_LAST[np.maximum(np.arange(_MAX_CELL + 1) - 8, 0)]
_POW10: Final = 10 ** np.arange(_MAX_CELL + 1, dtype=np.uint64)
_POW10_FLOAT: Final = np.array([float(10**k) for k in range(_MAX_CELL + 1)])
"""Powers of ten up to 1e16, exact in float64 (up to 1e22 they are)."""
_EXACT: Final[int] = 2**53


@dataclass(frozen=True, eq=False)
class _Cells:
    """Where the cells of a block of text are: the separator ending each (C,), its
    start (C,), its length (C,), its first character (C,), and the positions of the
    decimal points (P,)."""

    ends: NDArray[np.intp]
    starts: NDArray[np.intp]
    lengths: NDArray[np.intp]
    first: NDArray[np.uint8]
    points: NDArray[np.intp]


def decimal_rows(data: bytes, n_cols: int) -> NDArray[np.float64] | None:
    """The numbers of lines of ``n_cols`` comma-separated plain decimals, parsed by numpy
    outside the interpreter lock, bit for bit as ``numpy.loadtxt`` (``strtod``) parses them.

    Parameters
    ----------
    data : bytes
        Lines, each ending in ``\\n``, of ``n_cols`` cells each. A cell is empty or an
        optional sign, digits and at most one decimal point (at least one digit), at most
        16 characters.
    n_cols : int
        Cells per line.

    Returns
    -------
    ndarray, shape (R, n_cols), or None
        The numbers, an empty cell NaN; None when ``data`` is anything else (an exponent,
        ``nan``, a space, a quote, a comment, a blank line, a line of another length, more
        than 15 significant digits): the caller then parses it by ``numpy.loadtxt``.

    Notes
    -----
    A cell's digits make an integer mantissa ``m`` < 2**53 (exact in a float64) and its
    decimal places ``d`` ≤ 15, so ``m / 10**d`` is one correctly rounded division of exact
    values: the float ``strtod`` reads from the text. The digits are combined eight at a
    time, within 64-bit words (SWAR), from the bytes that end each cell.
    """
    text = np.frombuffer(data, dtype=np.uint8)
    if not text.size or text[-1] != ord("\n"):
        return None
    digit = text - np.uint8(ord("0"))
    is_digit = digit < 10
    cells = _cells(text, n_cols, int(np.count_nonzero(is_digit)))
    if cells is None:
        return None
    places = _decimal_places(cells)
    if places is None:
        return None
    np.multiply(digit, is_digit, out=digit)  # a point or sign is a 0 digit
    mantissa = _mantissas(digit, cells, places)
    if mantissa is None:
        return None
    values = mantissa.astype(np.float64)
    values /= _POW10_FLOAT[places] if isinstance(places, int) else _POW10_FLOAT[
        np.maximum(places, 0)]
    np.negative(values, out=values, where=cells.first == ord("-"))
    values[cells.lengths == 0] = np.nan
    return values.reshape(-1, n_cols)


def _cells(text: NDArray[np.uint8], n_cols: int, digits: int) -> _Cells | None:
    """The cells of ``text`` (which has ``digits`` digits) when it holds only digits,
    ``+,-.`` and newlines, every line has ``n_cols`` cells, at most :data:`_MAX_CELL`
    characters long, with a sign only first, and no line is blank; else None."""
    newline = text == ord("\n")
    ends = np.flatnonzero(newline | (text == ord(",")))
    points = np.flatnonzero(text == ord("."))
    marks = int(np.count_nonzero((text - np.uint8(ord("+"))) < 4))  # + , - .
    rows = int(np.count_nonzero(newline))
    if digits + marks + rows != text.size or ends.size != rows * n_cols \
            or not newline[ends[n_cols - 1::n_cols]].all():
        return None
    starts = np.empty_like(ends)
    starts[0] = 0
    np.add(ends[:-1], 1, out=starts[1:])
    lengths = ends - starts
    if lengths.max() > _MAX_CELL or (n_cols == 1 and not lengths.all()):
        return None  # a long cell, or a blank line (no cell, for loadtxt)
    first = text[starts]  # an empty cell's is its separator
    signs = marks - (ends.size - rows) - points.size
    if signs != np.count_nonzero((first == ord("-")) | (first == ord("+"))):
        return None
    return _Cells(ends, starts, lengths, first, points)


def _decimal_places(cells: _Cells) -> NDArray[np.intp] | int | None:
    """Digits after the point of each cell (C,), or one count for all; a cell without a
    point has -1 (for :func:`_mantissas`). None for a cell with two points or no digit."""
    points = cells.points
    if points.size == cells.ends.size and ((points >= cells.starts)
                                           & (points < cells.ends)).all():
        places = cells.ends - points - 1  # one point per cell: the common layout
        digits = cells.lengths - 1
    else:
        cell = np.searchsorted(cells.ends, points)
        if (np.diff(cell) == 0).any():
            return None
        places = np.full(cells.ends.size, -1, dtype=np.intp)
        places[cell] = cells.ends[cell] - points - 1
        digits = cells.lengths - (places >= 0)
    digits -= (cells.first == ord("-")) | (cells.first == ord("+"))
    if ((digits <= 0) & (cells.lengths > 0)).any():
        return None
    low, high = int(places.min()), int(places.max())
    return low if low == high and low >= 0 else places


def _eight_digits(words: NDArray[np.uint64]) -> NDArray[np.uint64]:
    """The integers written by eight digit values (0 to 9), the first byte the most
    significant, of little-endian 64-bit words."""
    pairs = np.uint64(0x00FF00FF00FF00FF)
    quads = np.uint64(0x0000FFFF0000FFFF)
    words = (words & pairs) * np.uint64(10) + ((words >> np.uint64(8)) & pairs)
    words = (words & quads) * np.uint64(100) + ((words >> np.uint64(16)) & quads)
    return (words & np.uint64(0xFFFFFFFF)) * np.uint64(10_000) + (words >> np.uint64(32))


def _mantissas(digits: NDArray[np.uint8], cells: _Cells,
               places: NDArray[np.intp] | int) -> NDArray[np.uint64] | None:
    """Each cell's digits (``digits``: the value of each character, 0 but for digits) as
    one integer (C,), the point left out; None if one reaches 2**53."""
    values = np.zeros(digits.size + _MAX_CELL, dtype=np.uint8)  # leading zeros for cell 0
    values[_MAX_CELL:] = digits
    # the 8 bytes starting at each byte, as one little-endian word (unaligned reads)
    words = np.ndarray((values.size - 7,), dtype="<u8", buffer=values, strides=(1,))
    low = _eight_digits(words[cells.ends + 8] & _KEEP_LOW[cells.lengths])
    high = _eight_digits(words[cells.ends] & _KEEP_HIGH[cells.lengths])
    number = high * np.uint64(10**8) + low
    # the point, a 0 digit `places` from the right: drop it
    scale = np.uint64(10**places) if isinstance(places, int) else _POW10[np.maximum(places, 0)]
    mantissa = number // (scale * np.uint64(10)) * scale + number % scale
    if not isinstance(places, int):
        mantissa = np.where(places >= 0, mantissa, number)
    if mantissa.max(initial=0) >= _EXACT:
        return None
    return mantissa
