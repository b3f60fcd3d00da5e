"""Tracker ASCII exports (Polhemus, Ascension/NDI trakSTAR, ROS CSV): layout and reader.

A tracker export holds one record per station per frame. Which column is what (station,
frame counter, time, quality, position, Euler angles or quaternion and in which order) is
described by a :class:`TrackerLayout`, which :func:`detect_tracker_layout` infers from a
header row or from the data, and :func:`parse_tracker_layout` reads from a short spec such as
``"frame,station,x,y,z,az,el,roll"``. Every layout is described with an example in
``docs/skeleton-io.md``.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..model import SEGMENTS
from ..recording import SensorRecording
from . import limits
from .sensor_common import (
    UNITS,
    PathLike,
    check_recording,
    fps_from_time,
    metadata_comment,
    normalise_quaternions,
    open_text,
    parse_fps,
    time_from_fps,
    unit_scale,
)

MAX_STATIONS: Final[int] = 64
"""Distinct station numbers a tracker file may hold (real trackers have 4 to 16)."""

MAX_DROPPED_FRAMES: Final[int] = 100_000
"""Frames a frame counter or time stamps may skip in all: a counter that jumps further is
corrupt and would otherwise allocate a huge table of dropped frames."""

MAX_EXTRA_COLUMNS: Final[int] = 4
"""Columns besides position and rotation (station, counter, time, quality) that detection
from the data accepts; wider records (a kinematics CSV, say) need a header or a layout."""

DETECT_RECORDS: Final[int] = 400
"""Data records read from the top of the file to detect its layout."""

TIME_UNITS: Final[dict[str, float]] = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
"""Units of a time column and their size in seconds."""

ROLES: Final[tuple[str, ...]] = ("station", "frame", "time", "quality", "-", "x", "y", "z",
                                 "qw", "qx", "qy", "qz", "az", "el", "roll", "rx", "ry", "rz")
"""Column roles of a layout spec; ``-`` is a column that is ignored."""

_ANGLE_AXES: Final[dict[str, str]] = {"az": "Z", "el": "Y", "roll": "X",
                                      "rx": "X", "ry": "Y", "rz": "Z"}
_QUATERNION: Final[tuple[str, ...]] = ("qw", "qx", "qy", "qz")
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
_SPLIT = re.compile(r"[,;\s]+")
_FASTRAK = re.compile(r"0[1-9][ A-Za-z]")

# header names (lower case, ROS "field." prefixes and separators dropped) -> role
_HEADER_ROLES: Final[dict[str, str]] = {
    **dict.fromkeys(("station", "sensor", "id", "sensorid", "stationid", "st", "channel",
                     ), "station"),
    **dict.fromkeys(("frame", "frameno", "framenumber", "framecount", "count", "counter",
                     "sample", "index"), "frame"),
    **dict.fromkeys(("time", "t", "timestamp", "times", "timems", "timeus", "timens",
                     "%time", "stamp", "headerstamp"), "time"),
    # ROS header.seq counts messages, not frames: ignored
    **dict.fromkeys(("seq", "headerseq", "headerframeid", "frameid"), "-"),
    **dict.fromkeys(("quality", "q", "error", "err", "status", "distortion"), "quality"),
    **dict.fromkeys(("x", "posx", "positionx", "translationx"), "x"),
    **dict.fromkeys(("y", "posy", "positiony", "translationy"), "y"),
    **dict.fromkeys(("z", "posz", "positionz", "translationz"), "z"),
    **dict.fromkeys(("qw", "w", "orientationw", "rotationw", "q0"), "qw"),
    **dict.fromkeys(("qx", "orientationx", "rotationx", "q1"), "qx"),
    **dict.fromkeys(("qy", "orientationy", "rotationy", "q2"), "qy"),
    **dict.fromkeys(("qz", "orientationz", "rotationz", "q3"), "qz"),
    **dict.fromkeys(("az", "a", "azimuth", "yaw"), "az"),
    **dict.fromkeys(("el", "e", "elevation", "pitch"), "el"),
    **dict.fromkeys(("roll", "r", "ro"), "roll"),
}


@dataclass(frozen=True)
class TrackerLayout:
    """What each column of a tracker record holds.

    Attributes
    ----------
    columns : tuple of str
        Role of each column (see ``ROLES``): ``station``, ``frame`` (counter), ``time``,
        ``quality`` (read but ignored), ``-`` (ignored), ``x y z`` (position), ``qw qx qy qz``
        (quaternion, in any column order) or three Euler angles: ``az el roll`` (rotations
        about Z, Y, X) or ``rx ry rz``, composed intrinsically in their column order
        (``az,el,roll``: R = Rz·Ry·Rx).
    time_unit : {"s", "ms", "us", "ns"}
        Unit of the time column.
    degrees : bool
        Euler angles in degrees (else radians).
    fastrak : bool
        Polhemus FASTRAK records: ``0``, the station digit and an error-code character,
        then fixed-width numbers that may touch (``12.34-123.45``); ``station`` is the digit.
    skip_lines : int
        Lines at the top (banners, header row) that are not records.
    units : str
        Default units of the positions: ``in`` (Polhemus, trakSTAR factory setting), ``m``
        for ROS exports (REP 103); the reader's ``units`` and a ``# units:`` comment win.
    source : str
        ``"header"``, ``"data"`` or ``"explicit"``: where the layout came from.
    """

    columns: tuple[str, ...]
    time_unit: str = "s"
    degrees: bool = True
    fastrak: bool = False
    skip_lines: int = 0
    units: str = "in"
    source: str = field(default="explicit", compare=False)

    def __post_init__(self) -> None:
        _validate_columns(self.columns)
        if self.units not in UNITS:
            raise InputError(f"units {self.units!r} are not one of {', '.join(UNITS)}",
                             field="tracker_layout")
        if self.time_unit not in TIME_UNITS:
            raise InputError(f"time unit {self.time_unit!r} is not one of "
                             f"{', '.join(TIME_UNITS)}", field="tracker_layout")

    def column(self, role: str) -> int | None:
        """Index of the column with ``role``, or None."""
        return self.columns.index(role) if role in self.columns else None

    @property
    def rotation(self) -> str:
        """``"quaternion"`` or ``"euler"``."""
        return "quaternion" if "qw" in self.columns else "euler"

    @property
    def rotation_columns(self) -> tuple[int, ...]:
        """Columns of qw, qx, qy, qz, or of the three angles in composition order."""
        if self.rotation == "quaternion":
            return tuple(self.columns.index(r) for r in _QUATERNION)
        return tuple(i for i, r in enumerate(self.columns) if r in _ANGLE_AXES)

    @property
    def euler_order(self) -> str:
        """Intrinsic Euler sequence (``"ZYX"`` for azimuth, elevation, roll); "" for quaternions."""
        if self.rotation == "quaternion":
            return ""
        return "".join(_ANGLE_AXES[self.columns[i]] for i in self.rotation_columns)

    def spec(self) -> str:
        """The layout as a spec string that :func:`parse_tracker_layout` reads back."""
        options = []
        if "time" in self.columns:
            options.append(f"time={self.time_unit}")
        if not self.degrees:
            options.append("rad")
        if self.fastrak:
            options.append("fastrak")
        if self.skip_lines:
            options.append(f"skip={self.skip_lines}")
        if self.units != "in":
            options.append(f"units={self.units}")
        return ";".join([",".join(self.columns), *options])

    def describe(self) -> str:
        """One line saying what was detected, e.g. for ``bonefit skeleton``."""
        parts = [f"columns {','.join(self.columns)}"]
        if self.fastrak:
            parts.insert(0, "Polhemus FASTRAK records")
        if self.rotation == "quaternion":
            order = "".join(r[1] for r in self.columns if r in _QUATERNION)
            parts.append(f"quaternion {order}")
        else:
            parts.append(f"Euler {self.euler_order} in {'degrees' if self.degrees else 'radians'}")
        if "station" not in self.columns:
            parts.append("no station column: records cycle through the stations in order")
        if "time" in self.columns:
            parts.append(f"time in {self.time_unit}")
        if self.skip_lines:
            parts.append(f"{self.skip_lines} banner/header line(s) skipped")
        names = {"in": "inches", "m": "metres", "cm": "centimetres", "mm": "millimetres"}
        parts.append(f"positions in {names[self.units]} unless units are given")
        origin = {"header": "from the header row", "data": "from the data"}.get(
            self.source, "as given")
        return f"tracker layout {origin}: " + "; ".join(parts) + \
            f" (--tracker-layout '{self.spec()}')"


def _validate_columns(columns: Sequence[str]) -> None:
    for name in columns:
        if name not in ROLES:
            raise InputError(f"unknown column {name!r} in the tracker layout; columns are "
                             f"{', '.join(ROLES)}", field="tracker_layout")
    for name in ROLES:
        if name not in ("-", "quality") and list(columns).count(name) > 1:
            raise InputError(f"column {name!r} appears twice in the tracker layout",
                             field="tracker_layout")
    missing = [c for c in ("x", "y", "z") if c not in columns]
    if missing:
        raise InputError(f"the tracker layout lacks position column(s) {', '.join(missing)}",
                         field="tracker_layout")
    quats = [c for c in columns if c in _QUATERNION]
    angles = [c for c in columns if c in _ANGLE_AXES]
    axes = {_ANGLE_AXES[c] for c in angles}
    if quats and (len(quats) != 4 or angles):
        raise InputError("a tracker layout needs all of qw,qx,qy,qz and no angles, got "
                         f"{','.join(quats + angles)}", field="tracker_layout")
    if not quats and (len(angles) != 3 or len(axes) != 3):
        raise InputError("a tracker layout needs qw,qx,qy,qz or three angles about different "
                         f"axes (az,el,roll or rx,ry,rz), got {','.join(angles) or 'none'}",
                         field="tracker_layout")


def parse_tracker_layout(spec: str | TrackerLayout) -> TrackerLayout:
    """Read a layout spec: column roles, then ``;``-separated options.

    Parameters
    ----------
    spec : str or TrackerLayout
        ``"station,x,y,z,az,el,roll"``, ``"frame,station,x,y,z,qw,qx,qy,qz"``,
        ``"time,x,y,z,qx,qy,qz,qw;time=ns"`` ... Roles: see ``ROLES``. Options: ``time=s|ms|
        us|ns``, ``rad`` (angles in radians), ``fastrak`` (FASTRAK records), ``skip=N`` (lines
        at the top that are no records; banners and a header row are skipped anyway).

    Returns
    -------
    TrackerLayout

    Raises
    ------
    InputError
        Unknown role or option, roles given twice, no position or rotation (field
        ``tracker_layout``).
    """
    if isinstance(spec, TrackerLayout):
        return spec
    body, *options = [part.strip() for part in str(spec).split(";")]
    columns = tuple(c.strip().lower() for c in body.split(",") if c.strip())
    kwargs: dict[str, Any] = {}
    for option in filter(None, options):
        key, _, value = option.partition("=")
        key = key.strip().lower()
        if key == "time" and value.strip() in TIME_UNITS:
            kwargs["time_unit"] = value.strip()
        elif key in ("rad", "radians") and not value:
            kwargs["degrees"] = False
        elif key == "fastrak" and not value:
            kwargs["fastrak"] = True
        elif key == "skip" and value.strip().isdigit():
            kwargs["skip_lines"] = int(value)
        elif key == "units" and value.strip() in UNITS:
            kwargs["units"] = value.strip()
        else:
            raise InputError(f"unknown tracker layout option {option!r}; options are "
                             f"time=s|ms|us|ns, rad, fastrak, skip=N, units=in|cm|mm|m",
                             field="tracker_layout")
    if kwargs.get("fastrak") and columns[:1] != ("station",):
        raise InputError("a fastrak layout starts with the station column",
                         field="tracker_layout")
    return TrackerLayout(columns, **kwargs)


# --------------------------------------------------------------------------- stations


def parse_stations(spec: str | Mapping[Any, Any] | PathLike) -> dict[int, str]:
    """Station-number → segment mapping of a tracker recording.

    Parameters
    ----------
    spec : str, mapping or path
        ``"1=pelvis,2=chest,..."``, a mapping ``{1: "pelvis", ...}`` (keys may be strings of
        digits), or the path of a JSON file holding such a mapping.

    Returns
    -------
    dict of int to str

    Raises
    ------
    InputError
        On a malformed entry, an unknown segment or a segment given twice.
    """
    items = list(spec.items()) if isinstance(spec, Mapping) else _station_items(spec)
    mapping: dict[int, str] = {}
    for key, value in items:
        try:
            number = int(key)
        except (TypeError, ValueError):
            raise InputError(f"station {key!r} is not a number", field="stations") from None
        if value not in SEGMENTS:
            raise InputError(f"station {number} maps to unknown segment {value!r}; "
                             f"segments are {', '.join(SEGMENTS)}", field="stations")
        if value in mapping.values():
            raise InputError(f"segment {value!r} is given to two stations", field="stations")
        mapping[number] = str(value)
    if not mapping:
        raise InputError("stations mapping is empty", field="stations")
    return mapping


def _station_items(spec: str | PathLike) -> list[tuple[Any, Any]]:
    """The (station, segment) pairs of a stations JSON file or ``"1=pelvis,..."`` text."""
    text = os.fspath(spec).strip()
    path = Path(text)
    if text.endswith(".json") or ("=" not in text and path.is_file()):
        return _station_file_items(path, text)
    items = []
    for part in text.split(","):
        if not part.strip():
            continue
        key, sep, value = part.partition("=")
        if not sep:
            raise InputError(f"stations entry {part.strip()!r} is not NUMBER=SEGMENT",
                             field="stations")
        items.append((key.strip(), value.strip()))
    return items


def _station_file_items(path: Path, text: str) -> list[tuple[Any, Any]]:
    """The (station, segment) pairs of the stations JSON file ``path`` (given as ``text``)."""
    import json

    try:
        loaded = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"stations file {text} not found", field="stations") from None
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot read stations file {text}: {exc}",
                         field="stations") from None
    if not isinstance(loaded, dict):
        raise InputError("stations JSON must be an object {\"1\": \"pelvis\", ...}",
                         field="stations")
    return list(loaded.items())


def format_stations(mapping: Mapping[int, str]) -> str:
    """``"1=pelvis,2=chest"`` form of a station mapping."""
    return ",".join(f"{k}={v}" for k, v in sorted(mapping.items()))


class StationCycle:
    """Splits a stream of station numbers into frames.

    Trackers report their stations in a fixed order each frame (the order of the first
    cycle); a frame ends when a station does not come later in that order than the previous
    record, so a station missing from a frame leaves a gap instead of shifting the rest.
    At most ``MAX_STATIONS`` distinct stations are accepted.
    """

    def __init__(self) -> None:
        self.order: list[int] = []
        self.rank: dict[int, int] = {}
        self.last: int | None = None

    def starts_frame(self, number: int, line: int) -> bool:
        """Whether the record of station ``number`` (at ``line``) begins a new frame."""
        if number not in self.rank:
            if len(self.order) >= MAX_STATIONS:
                raise InputError(f"more than {MAX_STATIONS} stations (station {number} at line "
                                 f"{line}); trackers have up to {MAX_STATIONS}",
                                 field="stations", line=line)
            # first seen (first cycle, or a station missing from it): it follows the previous
            at = 0 if self.last is None else self.order.index(self.last) + 1
            self.order.insert(at, number)
            self.rank = {n: i for i, n in enumerate(self.order)}
            new = self.last is None
        else:
            new = self.last is None or self.rank[number] <= self.rank[self.last]
        self.last = number
        return new


# --------------------------------------------------------------------------- records


def _split_glued(token: str) -> list[str]:
    """``"12.34-123.45"`` → two numbers; a token that is not numbers stays whole."""
    parts = _NUMBER.findall(token)
    return parts if len(parts) > 1 and "".join(parts) == token else [token]


def _tokens(text: str, fastrak: bool) -> list[str]:
    """Fields of one record; FASTRAK's station digit and error code become two fields."""
    if fastrak and _FASTRAK.match(text):
        return [text[1], text[2].strip() or "0", *_NUMBER.findall(text[3:])]
    out: list[str] = []
    for token in _SPLIT.split(text.strip()):
        if token:
            out.extend(_split_glued(token))
    return out


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _is_record(tokens: Sequence[str]) -> bool:
    """A data record: six numbers or more, at most a quarter of the fields text."""
    numbers = sum(_is_number(t) for t in tokens)
    return numbers >= 6 and numbers >= 0.75 * len(tokens)


def _data_lines(handle: Any, meta: dict[str, str]) -> Iterator[tuple[int, str]]:
    """(line number, text) of the lines that are neither blank nor ``#`` comments; a line
    over ``MAX_LINE_CHARS`` is refused before it is read whole."""
    for line, text in enumerate(limits.bounded_lines(handle), 1):
        stripped = text.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            found = metadata_comment(stripped)
            if found:
                meta[found[0]] = found[1]
            continue
        yield line, text.rstrip("\r\n").lstrip()


# --------------------------------------------------------------------------- detection


def _header_key(name: str) -> str:
    key = name.strip().lower()
    if key != "%time":
        key = key.removeprefix("field.").removeprefix("transforms0.").removeprefix("pose.")
        key = key.removeprefix("transform.")
        key = re.sub(r"[^a-z0-9%]", "", key)
    return key


def _time_unit_of(name: str) -> str | None:
    key = name.strip().lower()
    if key == "%time" or "stamp" in key or key.endswith("ns"):
        return "ns"
    for unit in ("ms", "us"):
        if key.endswith(unit):
            return unit
    if key.endswith("_s") or key.endswith("(s)"):
        return "s"
    return None


def _layout_from_header(names: Sequence[str]) -> tuple[tuple[str, ...], str | None] | None:
    """Roles from column names (unknown names ignored); None unless x, y, z and a rotation."""
    roles: list[str] = []
    unit: str | None = None
    for name in names:
        role = _HEADER_ROLES.get(_header_key(name), "-")
        if role in roles and role not in ("-", "quality"):
            if role == "time" and "stamp" in name.lower():  # ROS: header.stamp over %time
                roles[roles.index("time")] = "-"
            else:
                role = "-"
        if role == "time":
            unit = _time_unit_of(name)
        roles.append(role)
    try:
        _validate_columns(roles)
    except InputError:
        return None
    return tuple(roles), unit


def _column_stats(values: NDArray[np.float64]) -> dict[str, Any]:
    finite = values[np.isfinite(values)]
    if finite.size < values.size or finite.size == 0:
        return {"numeric": False}
    steps = np.diff(finite)
    positive = steps[steps > 0]
    return {"numeric": True,
            "integer": bool(np.all(finite == np.round(finite))),
            "monotone": bool(np.all(steps >= 0)) and positive.size > 0,
            "distinct": int(np.unique(finite).size),
            "repeats": bool(np.any(steps == 0)),
            "min_step": float(positive.min()) if positive.size else 0.0,
            "min": float(finite.min()), "max": float(finite.max())}


def _extra_role(stats: dict[str, Any], have: set[str]) -> str | None:
    """Role of a column that is not data: station, frame counter or time; None if data."""
    if not stats["numeric"]:
        return "-"
    if stats["monotone"]:
        # 1, 2, 3 ... without repeats is a station per record as much as a counter of
        # one-station frames: a counter then, only past the number of stations there can be
        counter = stats["repeats"] or stats["distinct"] > MAX_STATIONS
        if stats["integer"] and stats["min_step"] == 1:
            if counter and "frame" not in have:
                return "frame"
            if not counter and "station" not in have and stats["min"] >= 0:
                return "station"
        return "time" if "time" not in have else None
    if stats["integer"] and stats["min"] >= 0 and "station" not in have:
        return "station"  # even past MAX_STATIONS distinct values: the reader names the limit
    return None


def _unit_norm(table: NDArray[np.float64], start: int) -> bool:
    if start + 4 > table.shape[1]:
        return False
    norm = np.linalg.norm(table[:, start:start + 4], axis=1)
    return bool(np.all(np.abs(norm - 1.0) <= 0.05))


def _layout_from_data(table: NDArray[np.float64]) -> tuple[str, ...]:
    """Roles of a header-less table (records × columns, NaN where a field is text)."""
    n = table.shape[1]
    if not 6 <= n <= 7 + MAX_EXTRA_COLUMNS:
        raise InputError(f"records of {n} fields are no tracker layout bonefit can tell "
                         f"(6 or 7 values and up to {MAX_EXTRA_COLUMNS} more columns); give "
                         "tracker_layout (--tracker-layout)", field="tracker_layout")
    stats = [_column_stats(table[:, c]) for c in range(n)]
    roles: list[str] = []
    have: set[str] = set()
    col = 0
    while col < n and n - col > 6:
        role = _extra_role(stats[col], have)
        if role is None:
            break
        roles.append(role)
        have.add(role)
        col += 1
    if n - col >= 7 and _unit_norm(table, col + 3):
        w_last = stats[col + 3]["min"] < 0 <= stats[col + 6]["min"]
        rot = ["qx", "qy", "qz", "qw"] if w_last else list(_QUATERNION)
        roles += ["x", "y", "z", *rot]
        col += 7
    elif n - col >= 6 and all(stats[c]["numeric"] and stats[c]["min"] >= -360
                              and stats[c]["max"] <= 360 for c in range(col + 3, col + 6)):
        roles += ["x", "y", "z", "az", "el", "roll"]
        col += 6
    else:
        raise InputError("cannot tell which columns hold the position and the rotation; give "
                         "tracker_layout (--tracker-layout), e.g. 'station,x,y,z,az,el,roll'",
                         field="tracker_layout")
    if n - 6 - (roles.count("qw") > 0) > MAX_EXTRA_COLUMNS:
        raise InputError(f"{n} fields per record: more columns besides the position and "
                         f"rotation than a tracker writes ({MAX_EXTRA_COLUMNS}); give "
                         "tracker_layout (--tracker-layout)", field="tracker_layout")
    for c in range(col, n):
        role = _extra_role(stats[c], have)
        role = role if role in ("time", "-") else "quality"
        roles.append(role)
        have.add(role)
    return tuple(roles)


def _time_unit_from_step(step: float) -> str:
    """Unit of a time column from its median step (frames at 1 Hz to 100 kHz)."""
    if step < 1.0:
        return "s"
    if step < 1e3:
        return "ms"
    return "us" if step < 1e6 else "ns"


def detect_layout_of_lines(lines: Sequence[str]) -> TrackerLayout:
    """:func:`detect_tracker_layout` of the file's first data lines (comments removed)."""
    first_fastrak = next((i for i, text in enumerate(lines) if _FASTRAK.match(text)), None)
    fastrak = first_fastrak is not None and all(_FASTRAK.match(t) for t in lines[first_fastrak:])
    tokens = [_tokens(text, fastrak) for text in lines]
    first = next((i for i, t in enumerate(tokens) if _is_record(t)), None)
    if first is None:
        raise InputError("no tracker records (lines of six numbers or more) found",
                         field="frames")
    records = [t for t in tokens[first:] if _is_record(t)]
    width = len(records[0])
    records = [t for t in records if len(t) == width]
    if fastrak:
        numbers = width - 2
        if numbers not in (6, 7):
            raise InputError(f"FASTRAK records with {numbers} numbers: give tracker_layout "
                             "(position and Euler angles or quaternion are 6 or 7)",
                             field="tracker_layout")
        rot = ("qw", "qx", "qy", "qz") if numbers == 7 else ("az", "el", "roll")
        return TrackerLayout(("station", "quality", "x", "y", "z", *rot), fastrak=True,
                             skip_lines=first, source="data")
    if first > 0 and len(tokens[first - 1]) == width:
        found = _layout_from_header(tokens[first - 1])
        if found is not None:
            columns, unit = found
            if "time" in columns and unit is None:
                unit = _time_unit_from_step(_time_step(records, columns.index("time")))
            ros = any(t.startswith(("%time", "field.")) for t in tokens[first - 1])
            return TrackerLayout(columns, time_unit=unit or "s", skip_lines=first,
                                 units="m" if ros else "in", source="header")
    table = np.array([[float(t) if _is_number(t) else math.nan for t in rec] for rec in records])
    columns = _layout_from_data(table)
    unit = "s"
    if "time" in columns:
        unit = _time_unit_from_step(_time_step(records, columns.index("time")))
    return TrackerLayout(columns, time_unit=unit, skip_lines=first, source="data")


def _time_step(records: Sequence[Sequence[str]], col: int) -> float:
    values = np.array([float(r[col]) if _is_number(r[col]) else math.nan for r in records])
    steps = np.diff(values[np.isfinite(values)])
    steps = steps[steps > 0]
    return float(np.median(steps)) if steps.size else 0.0


def detect_tracker_layout(path: PathLike) -> TrackerLayout:
    """Layout of a tracker export, from its header row or its first records.

    A header row (the line before the first record, with as many fields) names the columns
    (``station``, ``frame``, ``time``/``%time``/``stamp``, ``quality``, ``x``, ``qw``,
    ``field.pose.orientation.x``, ``azimuth`` ...). Without one, leading columns that are a
    station number (small integers), a frame counter (integers rising by 1) or a time
    (rising) are told from the data, then 7 columns whose last four have unit norm are a
    position and a quaternion (w first unless only the first of them goes negative), else
    6 are a position and azimuth, elevation, roll; the columns after are time or quality.
    Lines that start ``0``, a station digit and a blank or letter are FASTRAK records.

    Parameters
    ----------
    path : path

    Returns
    -------
    TrackerLayout
        ``describe()`` says what was found; ``spec()`` is the explicit form to correct it.

    Raises
    ------
    InputError
        No records, or columns that cannot be told apart (give a layout then).
    """
    meta: dict[str, str] = {}
    with open_text(path) as handle:
        head: list[str] = []
        for _, text in _data_lines(handle, meta):
            head.append(text)
            if len(head) >= DETECT_RECORDS:
                break
    return detect_layout_of_lines(head)


def looks_like_tracker(text: str) -> bool:
    """Whether the start of a file (decoded text) reads as a tracker export: its layout is
    detected, and a header row right above the records, if any, names tracker columns (a
    CSV of other columns, such as a bonefit sensor CSV or foot accelerations, is not one)."""
    lines = [t.strip() for t in text.splitlines()[:-1] if t.strip()
             and not t.strip().startswith("#")][:DETECT_RECORDS]
    try:
        layout = detect_layout_of_lines(lines)
    except InputError:
        return False
    if layout.source == "header" or layout.fastrak or layout.skip_lines == 0:
        return True
    above = _tokens(lines[layout.skip_lines - 1], False)
    return len(above) != len(_tokens(lines[layout.skip_lines], False))


# --------------------------------------------------------------------------- reading


@dataclass
class _Records:
    """Records of a tracker file grouped into frames (mutable while reading)."""

    frames: list[dict[int, list[float]]] = field(default_factory=list)
    lines: list[int] = field(default_factory=list)
    counters: list[int] = field(default_factory=list)
    times: list[float] = field(default_factory=list)
    errors: int = 0


def _short(text: str, limit: int = 40) -> str:
    """``repr`` of a file snippet, cut so that binary junk cannot flood an error line."""
    return repr(text if len(text) <= limit else text[:limit] + "…")


def _number(token: str, line: int, column: int) -> float:
    try:
        return float(token)
    except ValueError:
        raise InputError(f"malformed number {_short(token)} at line {line}, column {column}",
                         line=line, column=column) from None


def _integer(token: str, line: int, column: int, what: str) -> int:
    value = _number(token, line, column)
    if not (math.isfinite(value) and value == round(value) and abs(value) < 2.0 ** 53):
        raise InputError(f"malformed {what} {_short(token)} at line {line}, column {column}: "
                         "expected a whole number", line=line, column=column, field=what)
    return int(value)


def _time_value(token: str, line: int, column: int) -> float | int:
    if token.isdigit() and len(token) <= 19:  # nanoseconds: exact as integers, not as floats
        return int(token)
    value = _number(token, line, column)
    if not math.isfinite(value):
        raise InputError(f"malformed time {_short(token)} at line {line}, column {column}",
                         line=line, column=column, field="time")
    return value


def _read_records(handle: Any, layout: TrackerLayout, meta: dict[str, str],
                  cycle_stations: Sequence[int] | None) -> _Records:
    """Parse every record and group them into frames (by counter, or by station cycle)."""
    out = _Records()
    width = len(layout.columns)
    station_col, frame_col, time_col = (layout.column(r) for r in ("station", "frame", "time"))
    value_cols = [layout.columns.index(c) for c in ("x", "y", "z")] + list(
        layout.rotation_columns)
    cycle = StationCycle()
    current: dict[int, list[float]] | None = None
    current_key: int | None = None
    started = False
    t0: float | int | None = None
    k = 0
    for n, (line, text) in enumerate(_data_lines(handle, meta)):
        if n < layout.skip_lines:
            continue
        tokens = _tokens(text, layout.fastrak)
        if not started and not _is_record(tokens):
            continue  # banner or header row above the first record
        started = True
        if len(tokens) != width:
            raise InputError(f"line {line} has {len(tokens)} fields; the layout "
                             f"'{layout.spec()}' has {width}", line=line)
        if station_col is not None:
            number = _integer(tokens[station_col], line, station_col + 1, "station")
        else:
            assert cycle_stations is not None
            number = cycle_stations[k % len(cycle_stations)]
            k += 1
        if layout.fastrak and tokens[1] != "0":
            out.errors += 1
        values = [_number(tokens[c], line, c + 1) for c in value_cols]
        if frame_col is not None:
            key = _integer(tokens[frame_col], line, frame_col + 1, "frame")
            new = key != current_key
            cycle.starts_frame(number, line)
        else:
            key = len(out.frames)
            new = cycle.starts_frame(number, line)
        if new or current is None:
            _check_counter(current_key, key, line, frame_col)
            current = {}
            current_key = key
            out.frames.append(current)
            out.lines.append(line)
            out.counters.append(key)
            if time_col is not None:
                stamp = _time_value(tokens[time_col], line, time_col + 1)
                t0 = stamp if t0 is None else t0
                out.times.append(float(stamp - t0) * TIME_UNITS[layout.time_unit])
        current[number] = values
    return out


def _check_counter(last: int | None, key: int, line: int, frame_col: int | None) -> None:
    """Refuse a frame counter (in column ``frame_col``) that goes back from ``last``."""
    if frame_col is not None and last is not None and key < last:
        raise InputError(f"frame counter goes back from {last} to {key} at "
                         f"line {line}", line=line, column=frame_col + 1, field="frame")


def _frame_index(records: _Records, fps: float | None, has_time: bool,
                 has_counter: bool) -> tuple[NDArray[np.int64], float | None]:
    """Frame number of each group of records (dropped frames skipped) and the frame rate:
    ``fps`` if given, else measured from the time stamps (None without them)."""
    index = np.asarray(records.counters, dtype=np.int64)
    index -= index[0]
    times = np.asarray(records.times, dtype=float)
    rate = fps
    if has_time and times.size >= 2:
        steps = np.diff(times)
        if (steps <= 0).any():
            i = int(np.argmax(steps <= 0)) + 1
            raise InputError(f"time does not increase at line {records.lines[i]}",
                             line=records.lines[i], field="time")
        if not has_counter:  # place the frames by their time stamps
            index = _frames_of_steps(steps, 1.0 / rate if rate is not None else None)
            short = np.flatnonzero(np.diff(index) == 0)
            if short.size:
                line = records.lines[int(short[0]) + 1]
                raise InputError(f"time stamps at line {line} fall on the frame before: "
                                 "irregular time; give fps or a frame counter",
                                 line=line, field="time")
        if rate is None:
            rate = _snap(float(index[-1]) / float(times[-1]), index, times) \
                if index[-1] > 0 else fps_from_time(times)
    _check_dropped(int(index[-1]) + 1 - index.size)
    return index, rate


def _frames_of_steps(steps: NDArray[np.float64], step: float | None) -> NDArray[np.int64]:
    """Frame numbers from the time steps between frames: whole multiples of the frame step,
    which (unless given) is refined from the median to the mean over the frames it spans so
    that stamps rounded to the millisecond do not drift."""
    if step is None:
        step = float(np.median(steps))
        for _ in range(2):
            count = np.maximum(np.rint(steps / step), 1.0)
            step = float(steps.sum() / count.sum())
    index = np.concatenate([[0.0], np.cumsum(np.rint(steps / step))])
    _check_dropped(float(index[-1]) + 1 - index.size)
    return index.astype(np.int64)


def _check_dropped(dropped: float) -> None:
    if not dropped <= MAX_DROPPED_FRAMES:  # NaN too
        raise InputError(f"the frame counter or time skips {dropped:.0f} frames (limit "
                         f"{MAX_DROPPED_FRAMES}): corrupt counter or wrong time unit",
                         field="frame")


def _snap(rate: float, index: NDArray[np.int64], times: NDArray[np.float64]) -> float:
    """The rate measured over the whole take, snapped to the whole number it was set to when
    the stamps' rounding (their residual from a regular grid) cannot tell them apart."""
    residual = float(np.max(np.abs(times - index / rate)))
    tolerance = max(1e-4, 2.0 * residual / float(times[-1])) * rate
    return float(round(rate)) if abs(rate - round(rate)) <= tolerance else rate


def _is_sequential(index: NDArray[np.int64]) -> bool:
    return bool(np.array_equal(index, np.arange(index.size)))


def _quaternions(table: NDArray[np.float64], layout: TrackerLayout, sensors: tuple[str, ...],
                 lines: NDArray[np.int64]) -> NDArray[np.float64]:
    """(F, S, 4) scalar-first quaternions from the rotation part of ``table``."""
    rot = table[..., 3:]
    if layout.rotation == "quaternion":
        return normalise_quaternions(rot, sensors, lines)
    angles = rot.reshape(-1, 3)
    ok = np.isfinite(angles).all(axis=-1)
    xyzw = np.full((angles.shape[0], 4), np.nan)
    if ok.any():
        from scipy.spatial.transform import Rotation  # only here: sniffing needs no scipy

        xyzw[ok] = Rotation.from_euler(layout.euler_order, angles[ok],
                                       degrees=layout.degrees).as_quat()
    return xyzw[:, [3, 0, 1, 2]].reshape(*rot.shape[:2], 4)


def _resolve_stations(stations: Mapping[Any, Any] | str | None,
                      meta: dict[str, str]) -> dict[int, str]:
    if stations is None:
        if "stations" not in meta:
            raise InputError("tracker files need a stations mapping (station number → "
                             "segment), e.g. stations='1=pelvis,2=chest'", field="stations")
        stations = meta["stations"]
    return parse_stations(stations)


def _check_stations(records: _Records, mapping: Mapping[int, str]) -> tuple[list[int], list[str]]:
    """Mapped stations in number order, and warnings about unmapped ones (then ignored)."""
    numbers = sorted({n for frame in records.frames for n in frame})
    warnings = []
    for number in numbers:
        if number not in mapping:
            line = next(records.lines[i] for i, f in enumerate(records.frames) if number in f)
            warnings.append(f"station {number} (first frame at line {line}) is not in the "
                            f"stations mapping {format_stations(mapping)}: ignored")
    order = sorted(mapping)
    for number in order:
        if number not in numbers:
            raise InputError(f"station {number} ({mapping[number]}) has no records",
                             sensor=mapping[number])
    return order, warnings


def read_tracker_ascii(path: PathLike, *, stations: Mapping[Any, Any] | str | None = None,
                       units: str | None = None, fps: float | None = None,
                       layout: TrackerLayout | str | None = None) -> SensorRecording:
    """Read a tracker export: Polhemus LIBERTY/PATRIOT/FASTRAK, trakSTAR, ROS CSV ...

    Parameters
    ----------
    path : path
        One record per station per frame, fields separated by blanks, commas or semicolons
        (see :class:`TrackerLayout` and ``docs/skeleton-io.md`` for the layouts). Euler angles
        are in degrees, sensor → source rotation R = Rz(azimuth)·Ry(elevation)·Rx(roll).
        Without a frame counter a frame ends when a station repeats (a station missing from a
        frame is a dropped sample); a frame counter or time stamps place the frames, so that
        skipped frames become NaN rows. Lines starting with ``#`` are comments; ``# units:
        cm``, ``# fps: 240`` and ``# stations: 1=pelvis,...`` set defaults for the parameters.
    stations : mapping or str
        Station number → segment name (``{1: "pelvis", ...}`` or ``"1=pelvis,2=chest"``).
        Required (here or in the file). Stations it does not name are ignored with a warning
        (``SensorRecording.warnings``). Without a station column the records of a frame are
        the mapping's stations in number order.
    units : {"in", "cm", "mm", "m"}, optional
        Units of the positions; default the layout's: inches (the trackers' factory setting),
        metres for ROS exports.
    fps : float, optional
        Frame rate, Hz. Measured from the time column when there is one; required otherwise
        (LIBERTY 240, PATRIOT 60, trakSTAR 80 Hz by default).
    layout : TrackerLayout or str, optional
        Column layout (:func:`parse_tracker_layout` spec); detected by
        :func:`detect_tracker_layout` when omitted.

    Returns
    -------
    SensorRecording
        Sensors in station-number order, metres, scalar-first quaternions; ``warnings`` name
        ignored stations and FASTRAK records with an error code.

    Raises
    ------
    InputError
        Undetectable layout, missing or malformed stations mapping, more than
        ``MAX_STATIONS`` stations, malformed number (line and column), records of another
        width than the layout, counter going back or skipping more than
        ``MAX_DROPPED_FRAMES``, missing fps, non-unit quaternion, all-NaN sensor, implausible
        units.
    """
    plan = parse_tracker_layout(layout) if layout is not None else detect_tracker_layout(path)
    records, mapping, meta = _read_stations_and_records(path, plan, stations)
    order, warnings = _check_stations(records, mapping)
    if records.errors:
        warnings.append(f"{records.errors} FASTRAK record(s) carry an error code; their "
                        "values are used as given")
    index, rate = _tracker_frames(records, plan, fps, meta)
    sensors = tuple(mapping[n] for n in order)
    table = _tracker_table(records, index, order, 3 + len(plan.rotation_columns))
    n_frames = table.shape[0]
    if n_frames > index.size:
        warnings.append(f"{n_frames - index.size} dropped frame(s) (frame counter or time "
                        "stamps skip them) left as gaps")
    units = units if units is not None else meta.get("units", plan.units)
    lines = np.zeros(n_frames, dtype=np.int64)
    lines[index] = records.lines
    quats = _quaternions(table, plan, sensors, lines)
    rec = SensorRecording(sensors, table[..., :3] * unit_scale(units), quats, rate,
                          time_from_fps(n_frames, rate), warnings=tuple(warnings))
    return check_recording(rec, units)


def _read_stations_and_records(path: PathLike, plan: TrackerLayout,
                               stations: Mapping[Any, Any] | str | None
                               ) -> tuple[_Records, dict[int, str], dict[str, str]]:
    """The records of a tracker export, its stations mapping (``stations``, else the file's
    ``# stations:`` comment) and its comments' settings."""
    meta: dict[str, str] = {}
    with open_text(path) as handle:
        # the mapping may sit in a comment: read it before the records when there are no ids
        if "station" not in plan.columns and stations is None:
            for _ in _data_lines(handle, meta):
                break
            handle.seek(0)
        mapping = _resolve_stations(stations, meta) if (
            stations is not None or "station" not in plan.columns) else None
        records = _read_records(handle, plan, meta,
                                sorted(mapping) if mapping is not None else None)
    if not records.frames:
        raise InputError(f"{os.fspath(path)} holds no tracker records", field="frames")
    mapping = mapping if mapping is not None else _resolve_stations(stations, meta)
    return records, mapping, meta


def _tracker_frames(records: _Records, plan: TrackerLayout, fps: float | None,
                    meta: dict[str, str]) -> tuple[NDArray[np.int64], float]:
    """Frame number of each group of records and the frame rate (``fps``, the file's
    ``# fps:`` comment, or measured from the time stamps)."""
    if fps is None and "fps" in meta:
        fps = parse_fps(meta["fps"])
    index, rate = _frame_index(records, parse_fps(fps) if fps is not None else None,
                               "time" in plan.columns, "frame" in plan.columns)
    if rate is None:
        raise InputError("this tracker file carries no time: give fps (LIBERTY 240, "
                         "PATRIOT 60, trakSTAR 80 Hz by default)", field="fps")
    return index, rate


def _tracker_table(records: _Records, index: NDArray[np.int64], order: list[int],
                   width: int) -> NDArray[np.float64]:
    """(F, S, width) values of the stations in ``order`` per frame; NaN rows where a station
    has no record, a frame was dropped, or a value is not finite."""
    table = np.full((int(index[-1]) + 1, len(order), width), np.nan)
    for i, frame in zip(index.tolist(), records.frames, strict=True):
        for s, number in enumerate(order):
            if number in frame:
                table[i, s] = frame[number]
    table[~np.isfinite(table).all(axis=-1)] = np.nan
    return table


def _sniffed_sensors(order: list[int], has_station: bool, frames: int,
                     meta: dict[str, str]) -> tuple[list[str], int]:
    """The sensors a sniff reports (the stations' numbers, or their segments when the file
    has a valid ``# stations:`` comment) and its frame count (without a station column,
    records per frame are the mapping's stations)."""
    sensors = [str(n) for n in order] if has_station else []
    if "stations" in meta:
        try:
            mapping = parse_stations(meta["stations"])
        except InputError:
            pass
        else:
            sensors = ([mapping.get(n, str(n)) for n in order] if has_station
                       else [mapping[n] for n in sorted(mapping)])
            if not has_station and mapping:
                frames = math.ceil(frames / len(mapping))
    return sensors, frames


def sniff_tracker(path: PathLike) -> dict[str, Any]:
    """Summary of a tracker export: frames, stations, fps, units, detected layout.

    Reads the station (and frame counter) column of every record without converting the
    rest; more than ``MAX_STATIONS`` distinct stations are refused.

    Returns
    -------
    dict
        ``format`` ("tracker"), ``frames`` (int), ``sensors`` (station numbers as strings, or
        segment names when the file has a ``# stations:`` comment), ``fps`` (float or None),
        ``units`` (str), ``layout`` (the :meth:`TrackerLayout.spec`).
    """
    plan = detect_tracker_layout(path)
    meta: dict[str, str] = {}
    station_col, frame_col = plan.column("station"), plan.column("frame")
    cycle = StationCycle()
    frames = 0
    last_key: str | None = None
    started = False
    # the station and counter come before the numbers that may touch: split only up to them
    wanted = [c for c in (station_col, frame_col) if c is not None]
    quick = not plan.fastrak and max(wanted, default=0) < min(plan.rotation_columns)
    with open_text(path) as handle:
        for n, (line, text) in enumerate(_data_lines(handle, meta)):
            if n < plan.skip_lines:
                continue
            if started and quick:
                tokens = _SPLIT.split(text.strip(), maxsplit=max(wanted, default=0) + 1)
                if len(tokens) <= max(wanted, default=0):
                    continue
            else:
                tokens = _tokens(text, plan.fastrak)
                if not started and not _is_record(tokens):
                    continue
                started = True
                if len(tokens) != len(plan.columns):
                    continue
            number = 0
            if station_col is not None:
                number = _integer(tokens[station_col], line, station_col + 1, "station")
            new = cycle.starts_frame(number, line)
            if frame_col is not None:
                new = tokens[frame_col] != last_key
                last_key = tokens[frame_col]
            frames += new
    sensors, frames = _sniffed_sensors(sorted(cycle.order), station_col is not None, frames,
                                       meta)
    fps = parse_fps(meta["fps"]) if "fps" in meta else None
    return {"format": "tracker", "frames": frames, "sensors": sensors, "fps": fps,
            "units": meta.get("units", plan.units), "layout": plan.spec()}
