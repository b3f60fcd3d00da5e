"""Limits every reader enforces before it decompresses, allocates or keeps anything.

A file may declare anything (an NPZ member of 50 M entries in 200 KB, a header line of 12 M
columns); the readers and the service's sniff check what is declared against these limits
first and refuse beyond them with a :class:`~bonefit.estimation.errors.LimitError` that names the
limit. The limits are far above any real studio capture (documented in
``docs/skeleton-io.md``, "Limits"), so they only ever stop broken or hostile files.

Examples
--------
>>> from bonefit.estimation.io import limits
>>> limits.check_count("frames", 120, "MAX_FRAMES")
>>> limits.check_count("columns", 5000, "MAX_COLUMNS", line=1)
Traceback (most recent call last):
...
bonefit.estimation.errors.LimitError: the file has 5000 columns; the limit is 4096 (MAX_COLUMNS)
"""

from __future__ import annotations

import io
import math
import os
import struct
import tokenize
import zipfile
import zlib
from collections.abc import Iterator
from typing import IO, Any, Final

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError, LimitError
from ..params import MAX_FPS  # the estimators' bound, checked here while reading too

MAX_FRAMES: Final[int] = 5_000_000
"""Frames (data rows) of one recording: 5.8 h at 240 Hz, 1.4 h at 1 kHz."""

MAX_VALUES: Final[int] = 200_000_000
"""Numbers in one array or table (1.6 GB as float64): a million frames of a 23-sensor suit
(1 + 23 × 7 columns, 162 M) or 1.9 M frames (2.2 h at 240 Hz) of a 15-sensor one. The CLI's
skeleton of a million frames × 15 sensors peaked at 5.0 GB (47 bytes per value), so a table at
the limit needs about 9.5 GB; the service bounds a job's memory on its own
(``job_memory_mb``)."""

MAX_SENSORS: Final[int] = 256
"""Sensors or tracker stations of one recording (a full suit has 15 to 23)."""

MAX_JOINTS: Final[int] = 1024
"""Joints of a skeleton (BVH, kinematics CSV, MVNX; real ones have 20 to 150)."""

MAX_COLUMNS: Final[int] = 4096
"""Columns of a CSV (a Shadow kinematics export has 208)."""

MAX_LINE_CHARS: Final[int] = 1024 * 1024
"""Characters of one line of a text file (4096 columns of 24-digit numbers fit in 100 KB)."""

MAX_NAME_CHARS: Final[int] = 256
"""Characters of one sensor, joint or column name, or of a units string."""

MAX_ABS_VALUE: Final[float] = 1e10
"""Largest magnitude of any number in a recording (positions, quaternions, times,
accelerations, in whatever units): no capture comes near (time stamps in epoch seconds are
2e9); beyond it squares and sums lose all precision or overflow."""

MAX_NPZ_MEMBERS: Final[int] = 64
"""Arrays of one NPZ archive (a recording has 4 to 6)."""

MAX_ZIP_DIRECTORY_BYTES: Final[int] = 64 * 1024
"""Size of an NPZ archive's ZIP directory (46 bytes and a name per array: a few hundred
bytes for a recording)."""

MAX_NPZ_SMALL_BYTES: Final[int] = 64 * 1024
"""Uncompressed size of an NPZ member that holds names or a scalar (``sensors``, ``fps``,
``units``)."""

MAX_NPY_BYTES: Final[int] = 8 * MAX_VALUES
"""Uncompressed size of one NPZ member (``MAX_VALUES`` float64s); checked before
decompressing, so a deflate bomb (1000:1) is refused unread."""

NPY_HEADER_BYTES: Final[int] = 64 * 1024
"""Longest NPY header read (numpy writes 64 to 128 bytes; numpy itself refuses beyond 10 KB
unless told otherwise)."""

# what zipfile, zlib and numpy raise on a corrupt member (encrypted: RuntimeError; an
# unknown compression method: NotImplementedError; a bad header literal: SyntaxError or
# tokenize.TokenError)
_UNREADABLE: Final = (ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error,
                      NotImplementedError, SyntaxError, RuntimeError, struct.error,
                      tokenize.TokenError)

_EOCD: Final = struct.Struct("<4s4H2LH")
_ZIP64_LOCATOR: Final = struct.Struct("<4sLQL")
_ZIP64_EOCD: Final = struct.Struct("<4sQ2H2L4Q")


def check_count(what: str, count: int, name: str, *, field: str | None = None,
                line: int | None = None) -> None:
    """Refuse ``count`` items of ``what`` beyond the limit called ``name``.

    Parameters
    ----------
    what : str
        Plural noun for the message (``"frames"``, ``"columns"``).
    count : int
    name : str
        Name of one of this module's limits (``"MAX_FRAMES"``); its value is read when
        called, and the error's ``limit`` is this name.
    field : str, optional
        Field of the file at fault (default ``what``).
    line : int, optional
        Line of the file at fault.

    Raises
    ------
    LimitError
    """
    limit = int(globals()[name])
    if count > limit:
        raise LimitError(f"the file has {count} {what}; the limit is {limit} ({name})",
                         limit=name, field=field or what, line=line)


def max_rows(columns: int) -> int:
    """Most data rows a table of ``columns`` columns may have (``MAX_FRAMES`` rows and
    ``MAX_VALUES`` cells)."""
    return min(MAX_FRAMES, MAX_VALUES // max(columns, 1))


def check_rows(rows: int, columns: int, *, line: int | None = None) -> None:
    """LimitError past ``MAX_FRAMES`` rows or ``MAX_VALUES`` cells."""
    check_count("frames", rows, "MAX_FRAMES", line=line)
    check_count("values (rows × columns)", rows * columns, "MAX_VALUES", line=line,
                field="frames")


def check_value(value: float, *, line: int | None = None, column: int | None = None,
                field: str | None = None, sensor: str | None = None,
                nan_ok: bool = True) -> None:
    """Refuse an infinite number, a NaN unless ``nan_ok``, or one beyond ``MAX_ABS_VALUE``.

    Raises
    ------
    InputError
        Naming ``line``, ``column``, ``field`` and ``sensor``.
    """
    if math.isnan(value):
        if nan_ok:
            return
        what = "a missing value (NaN)"
    elif math.isinf(value):
        what = f"an infinite value ({value})"
    elif abs(value) > MAX_ABS_VALUE:
        what = f"an absurd magnitude ({value:.3g}; the limit is {MAX_ABS_VALUE:.0e}, MAX_ABS_VALUE)"
    else:
        return
    where = ", ".join(p for p in (f"line {line}" if line is not None else "",
                                  f"column {column}" if column is not None else "",
                                  f"sensor {sensor!r}" if sensor else "") if p)
    if field:
        where = f"{where} ({field})" if where else field
    raise InputError(f"{what} at {where}", line=line, column=column, field=field,
                     sensor=sensor)


def first_bad_value(table: NDArray[np.float64], *, nan_ok: bool = True) -> tuple[int, ...] | None:
    """Index of the first value of ``table`` that :func:`check_value` refuses, or None.

    Parameters
    ----------
    table : ndarray of float
        Any shape; searched in C order.
    nan_ok : bool
        Whether NaN is allowed (a dropped sample).
    """
    with np.errstate(invalid="ignore"):
        bad = np.abs(table) > MAX_ABS_VALUE  # infinities too; NaN compares False
    if not nan_ok:
        bad |= np.isnan(table)
    if not bad.any():
        return None
    return tuple(int(i) for i in np.unravel_index(int(np.argmax(bad)), table.shape))


def check_fps(fps: float, *, field: str = "fps", line: int | None = None) -> float:
    """``fps`` if it is at most ``MAX_FPS``; LimitError naming ``field`` otherwise."""
    if fps > MAX_FPS:
        raise LimitError(f"{field} gives {fps:.6g} frames per second; the limit is "
                         f"{MAX_FPS:.0f} (MAX_FPS)", limit="MAX_FPS", field=field, line=line)
    return fps


def bounded_lines(handle: IO[str], *, start: int = 1,
                  limit: int = MAX_LINE_CHARS) -> Iterator[str]:
    """The lines of a text stream (line ends kept), refusing one longer than ``limit``
    characters before reading more of it.

    Raises
    ------
    LimitError
        Naming the line (counted from ``start``) and ``MAX_LINE_CHARS``.
    """
    line = start
    while text := handle.readline(limit + 1):
        if len(text) > limit and not text.endswith(("\n", "\r")):
            raise LimitError(f"line {line} is longer than {limit} characters "
                             f"(MAX_LINE_CHARS)", limit="MAX_LINE_CHARS", line=line)
        yield text
        line += 1


# --------------------------------------------------------------------------- NPZ


def zip_entry_count(handle: IO[bytes]) -> tuple[int, int]:
    """Entries and central-directory bytes a ZIP archive declares, from its end records
    alone (before ``zipfile`` reads the directory into memory).

    Raises
    ------
    InputError
        When there is no end-of-central-directory record: not a ZIP archive.
    """
    handle.seek(0, io.SEEK_END)
    size = handle.tell()
    tail_start = max(0, size - (_EOCD.size + 65535))
    handle.seek(tail_start)
    tail = handle.read()
    at = tail.rfind(b"PK\x05\x06")
    if at < 0 or len(tail) - at < _EOCD.size:
        raise InputError("not an NPZ archive: no ZIP end-of-central-directory record",
                         field="input")
    fields = _EOCD.unpack_from(tail, at)
    count, cd_bytes = fields[4], fields[5]
    if count == 0xFFFF or cd_bytes == 0xFFFFFFFF:  # ZIP64: the real numbers are elsewhere
        locator_at = tail_start + at - _ZIP64_LOCATOR.size
        if locator_at < 0:
            raise InputError("not an NPZ archive: truncated ZIP64 records", field="input")
        handle.seek(locator_at)
        sig, _, record_at, _ = _ZIP64_LOCATOR.unpack(handle.read(_ZIP64_LOCATOR.size))
        if sig != b"PK\x06\x07" or record_at > size - _ZIP64_EOCD.size:
            raise InputError("not an NPZ archive: bad ZIP64 locator", field="input")
        handle.seek(record_at)
        record = _ZIP64_EOCD.unpack(handle.read(_ZIP64_EOCD.size))
        if record[0] != b"PK\x06\x06":
            raise InputError("not an NPZ archive: bad ZIP64 end record", field="input")
        count, cd_bytes = record[6], record[7]
    handle.seek(0)
    return int(count), int(cd_bytes)


def open_npz(path: str | os.PathLike[str]) -> zipfile.ZipFile:
    """The archive at ``path``, opened only if its directory fits ``MAX_NPZ_MEMBERS``.

    Raises
    ------
    InputError
        Not a ZIP archive, a directory, no permission; LimitError beyond
        ``MAX_NPZ_MEMBERS`` entries.
    FileNotFoundError
        If ``path`` does not exist.
    """
    try:
        with open(path, "rb") as handle:
            count, cd_bytes = zip_entry_count(handle)
    except (IsADirectoryError, PermissionError) as exc:
        raise InputError(f"cannot read {os.fspath(path)}: {exc.strerror}",
                         field="input") from None
    check_count("arrays", count, "MAX_NPZ_MEMBERS", field="input")
    check_count("bytes of ZIP directory", cd_bytes, "MAX_ZIP_DIRECTORY_BYTES", field="input")
    try:
        return zipfile.ZipFile(path)
    except (*_UNREADABLE, zipfile.LargeZipFile) as exc:
        raise InputError(f"not an NPZ archive: {exc}", field="input") from None


def npy_header(archive: zipfile.ZipFile, key: str) -> tuple[tuple[int, ...], np.dtype[
        np.generic], zipfile.ZipInfo]:
    """Shape and dtype the member ``<key>.npy`` declares, read from its first bytes.

    Raises
    ------
    InputError
        Missing member, not an NPY array, Fortran order, object dtype (named by ``key``).
    """
    name = f"{key}.npy"
    try:
        info = archive.getinfo(name)
    except KeyError:
        present = ", ".join(n.removesuffix(".npy") for n in archive.namelist()[:MAX_NPZ_MEMBERS])
        raise InputError(f"NPZ archive lacks the array {key!r} (has {present or 'none'})",
                         field=key) from None
    try:
        with archive.open(info) as member:
            version = np.lib.format.read_magic(member)
            if version == (1, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(
                    member, max_header_size=NPY_HEADER_BYTES)
            elif version in ((2, 0), (3, 0)):
                shape, fortran, dtype = np.lib.format.read_array_header_2_0(
                    member, max_header_size=NPY_HEADER_BYTES)
            else:
                raise ValueError(f"unknown NPY version {version}")
    except _UNREADABLE as exc:
        raise InputError(f"array {key!r} is not a readable NPY array: {exc}",
                         field=key) from None
    if dtype.hasobject:
        raise InputError(f"array {key!r} holds Python objects (dtype {dtype}); only numbers "
                         "and strings are read", field=key)
    if fortran and len(shape) > 1:
        raise InputError(f"array {key!r} is stored in Fortran order; save it in C order",
                         field=key)
    return tuple(int(n) for n in shape), dtype, info


def check_npy(archive: zipfile.ZipFile, key: str, *, kinds: str = "biuf", small: bool = False
              ) -> tuple[tuple[int, ...], np.dtype[np.generic]]:
    """Shape and dtype of ``<key>.npy`` once its declared size is within limits.

    Parameters
    ----------
    archive : ZipFile
    key : str
        Array name (member ``<key>.npy``).
    kinds : str
        Accepted dtype kinds (``"biuf"`` numbers, ``"US"`` strings).
    small : bool
        Whether the member holds names or a scalar (``MAX_NPZ_SMALL_BYTES``) rather than
        data (``MAX_VALUES`` values, ``MAX_NPY_BYTES``).

    The member's uncompressed size (from the ZIP directory, which ``zipfile`` enforces while
    decompressing) must match what the header declares, so that loading it allocates no more
    than was checked here.

    Raises
    ------
    InputError, LimitError
    """
    shape, dtype, info = npy_header(archive, key)
    if dtype.kind not in kinds or dtype.subdtype is not None:
        wanted = {"b": "booleans", "i": "integers", "u": "integers", "f": "floats",
                  "U": "strings", "S": "strings"}
        names = sorted({wanted[k] for k in kinds})
        raise InputError(f"array {key!r} has dtype {dtype}; expected {' or '.join(names)}",
                         field=key)
    count = math.prod(shape)
    check_count(f"values in array {key!r}", count, "MAX_VALUES", field=key)
    payload = count * dtype.itemsize
    name = "MAX_NPZ_SMALL_BYTES" if small else "MAX_NPY_BYTES"
    max_bytes = int(globals()[name])
    if info.file_size > max_bytes:
        raise LimitError(f"array {key!r} is {info.file_size} bytes; the limit is {max_bytes} "
                         f"({name})", limit=name, field=key)
    if not payload <= info.file_size <= payload + NPY_HEADER_BYTES + 16:
        raise InputError(f"array {key!r} declares shape {shape} of {dtype} ({payload} bytes) "
                         f"but its member holds {info.file_size} bytes", field=key)
    return shape, dtype


def load_npy(archive: zipfile.ZipFile, key: str, *, kinds: str = "biuf",
             small: bool = False) -> NDArray[Any]:
    """``<key>.npy`` checked with :func:`check_npy`, then loaded (``allow_pickle=False``)."""
    check_npy(archive, key, kinds=kinds, small=small)
    try:
        with archive.open(f"{key}.npy") as member:
            return np.asarray(np.lib.format.read_array(member, allow_pickle=False,
                                                       max_header_size=NPY_HEADER_BYTES))
    except _UNREADABLE as exc:
        raise InputError(f"array {key!r} cannot be read: {exc}", field=key) from None
