"""Xsens MVNX (MVN Analyze/Studio XML export) for root-translation estimation.

The file is pull-parsed as a stream, every element dropped once handled, so memory does not
grow with the file beyond the arrays read; a DOCTYPE (entity expansion), more elements than
``MAX_HEADER_ELEMENTS`` outside the frames or ``MAX_FRAME_ELEMENTS`` in one frame, and files
denser in tags than one per ``MIN_BYTES_PER_TAG`` bytes are refused. Read per ``normal`` frame
of one subject (the first unless ``subject`` says): segment ``position`` (m),
``sensorFreeAcceleration`` (m/s², world frame, gravity removed) or, in MVNX 3,
``sensorAcceleration`` (sensor frame, gravity included) with ``sensorOrientation``, and, when
present, ``footContacts`` (heel/toe flags of each foot). MVNX is Z up; everything is
converted to the Y-up frame of :class:`~bonefit.estimation.io.kinematics.KinematicsRecording`
(x, y, z) → (x, z, −y).
"""

from __future__ import annotations

import math
import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final, cast

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..quaternions import rotate
from .body import find_toe
from .kinematics import GRAVITY, KinematicsRecording

if TYPE_CHECKING:
    from ..translation import TranslationResult

PathLike = str | os.PathLike[str]

MAX_HEADER_ELEMENTS: Final[int] = 100_000
"""Elements an MVNX may hold outside its frames (segments, points, sensors, joints ...)."""

MAX_FRAME_ELEMENTS: Final[int] = 1_000
"""Elements one frame may hold (MVN writes about 20)."""

MIN_BYTES_PER_TAG: Final[int] = 16
"""Files above ``DENSITY_MIN_BYTES`` with more than one tag per this many bytes are refused
unparsed (an MVN frame spends hundreds of bytes of numbers per tag)."""

DENSITY_MIN_BYTES: Final[int] = 1 << 20
"""Size from which the tag density is checked."""

PROLOG_BYTES: Final[int] = 1 << 20
"""Bytes in which the ``<mvnx>`` root element must start."""


def z_up_to_y_up(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """(x, y, z) Z-up → (x, z, −y) Y-up, on the last axis."""
    return np.stack([v[..., 0], v[..., 2], -v[..., 1]], axis=-1)


def y_up_to_z_up(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """Inverse of :func:`z_up_to_y_up`."""
    return np.stack([v[..., 0], -v[..., 2], v[..., 1]], axis=-1)


def _tag(elem: ET.Element) -> str:
    return elem.tag.rsplit("}", 1)[-1]


def _numbers(text: str, what: str, frame: int) -> NDArray[np.float64]:
    try:
        return np.array(text.split(), dtype=float)
    except ValueError:
        raise InputError(f"frame {frame}: {what} holds a value that is not a number",
                         field=what) from None


def _floats(values: NDArray[np.float64], expected: int, what: str,
            frame: int) -> NDArray[np.float64]:
    if values.size != expected:
        raise InputError(f"frame {frame}: {what} has {values.size} values, expected {expected}",
                         field=what)
    return values


# --------------------------------------------------------------------------- streaming


def _check_prolog(path: PathLike) -> int:
    """Refuse a DOCTYPE (entity tricks) and files too dense in elements; returns the size.

    The declarations must precede the root element, which must start in the first
    ``PROLOG_BYTES``, so those are all that needs looking at; the density check counts ``<``
    in binary blocks, which costs milliseconds where parsing millions of empty elements would
    cost a minute.
    """
    size = os.path.getsize(path)
    tags = 0
    with open(path, "rb") as handle:
        head = handle.read(PROLOG_BYTES)
        root = head.find(b"<mvnx")
        # the whole head, not only what precedes "<mvnx": that may sit in a comment
        if b"<!DOCTYPE" in head.upper() or b"<!ENTITY" in head.upper():
            raise InputError("MVNX with a DOCTYPE or entity declarations is refused (MVN "
                             "never writes them; entities can expand without bound)",
                             field="input")
        if root < 0 and size > PROLOG_BYTES:
            raise InputError(f"no <mvnx> root element in the first {PROLOG_BYTES} bytes",
                             field="format")
        tags = head.count(b"<")
        while block := handle.read(1 << 20):
            tags += block.count(b"<")
    if size > DENSITY_MIN_BYTES and tags * MIN_BYTES_PER_TAG > size:
        raise InputError(f"MVNX has {tags} tags in {size} bytes, more than one per "
                         f"{MIN_BYTES_PER_TAG} bytes (limit): not an MVN export",
                         field="input")
    return size


def _stream(path: PathLike) -> Iterator[tuple[str, ET.Element, ET.Element | None]]:
    """(event, element, parent) of a pull parse; every element is detached from its parent
    once its end has been handled, so memory does not grow with the file."""
    parser: ET.XMLPullParser[ET.Element] = ET.XMLPullParser(events=("start", "end"))
    stack: list[ET.Element] = []
    try:
        with open(path, "rb") as handle:
            while chunk := handle.read(1 << 16):
                parser.feed(chunk)
                # only start and end events are asked for: (event, element) pairs
                events = cast("Iterator[tuple[str, ET.Element]]", parser.read_events())
                for event, elem in events:
                    if event == "start":
                        yield "start", elem, stack[-1] if stack else None
                        stack.append(elem)
                        continue
                    stack.pop()
                    parent = stack[-1] if stack else None
                    yield "end", elem, parent
                    if parent is not None:
                        parent.remove(elem)
            parser.close()
    except ET.ParseError as exc:
        line = exc.position[0] if hasattr(exc, "position") else None
        raise InputError(f"malformed MVNX: {exc}", line=line) from None
    except LookupError as exc:  # an XML declaration naming an unknown encoding
        raise InputError(f"malformed MVNX: {exc}", field="encoding") from None


@dataclass
class _Subject:
    """What the reader keeps of one ``<subject>`` (mutable while streaming)."""

    label: str
    number: int
    fps: float | None = None
    segments: list[str] = field(default_factory=list)
    sensors: list[str] = field(default_factory=list)
    contact_labels: list[str] = field(default_factory=list)
    frames: list[dict[str, NDArray[np.float64]]] = field(default_factory=list)
    times: list[float] = field(default_factory=list)


_FRAME_FIELDS = frozenset({"position", "sensorFreeAcceleration", "sensorAcceleration",
                           "sensorOrientation", "footContacts"})


class _Scanner:
    """Streams an MVNX and keeps the definitions and frames of the chosen subject."""

    def __init__(self, chosen: str | None, stop_at_frames: bool = False) -> None:
        self.chosen = chosen
        self.stop_at_frames = stop_at_frames
        self.labels: list[str] = []
        self.subject: _Subject | None = None
        self.current: _Subject | None = None
        self.section = ""
        self.in_frame: ET.Element | None = None  # the <frame> being read
        self.frame: dict[str, str] | None = None  # texts of the normal frame being read
        self.frame_elements = 0
        self.header_elements = 0

    def _wanted(self, label: str, number: int) -> bool:
        if self.chosen is None:
            return number == 1
        return self.chosen == label or self.chosen == str(number)

    def start(self, elem: ET.Element) -> bool:
        """Handle a start tag; False to stop reading."""
        tag = _tag(elem)
        if self.in_frame is not None:
            self.frame_elements += 1
            if self.frame_elements > MAX_FRAME_ELEMENTS:
                raise InputError(f"an MVNX frame holds more than {MAX_FRAME_ELEMENTS} "
                                 "elements (limit)", field="frames")
            return True
        if tag == "frame":
            self.in_frame = elem
            self.frame_elements = 0
            if self.current is not None and elem.get("type", "normal") == "normal":
                self.frame = {}
                ms = elem.get("time")
                self.current.times.append(_ms(ms) if ms not in (None, "") else math.nan)
            return True
        self.header_elements += 1
        if self.header_elements > MAX_HEADER_ELEMENTS:
            raise InputError(f"MVNX has more than {MAX_HEADER_ELEMENTS} elements outside its "
                             "frames (limit)", field="input")
        if tag == "subject":
            label = elem.get("label", "")
            self.labels.append(label)
            self.current = None
            number = len(self.labels)
            if self.subject is None and self._wanted(label, number):
                self.current = self.subject = _Subject(label or f"subject {number}", number - 1)
                rate = elem.get("frameRate")
                self.current.fps = _rate(rate) if rate else None
        elif tag in ("segments", "sensors", "frames"):
            self.section = tag
            if tag == "frames" and self.stop_at_frames and self.current is not None:
                return False
        return True

    @staticmethod
    def _numbers(texts: dict[str, str], k: int) -> dict[str, NDArray[np.float64]]:
        """A frame's fields as numbers, once read (MVNX 3 fields only when needed)."""
        if "sensorFreeAcceleration" in texts:
            texts.pop("sensorAcceleration", None)
            texts.pop("sensorOrientation", None)
        return {what: _numbers(text, what, k) for what, text in texts.items()}

    def end(self, elem: ET.Element, parent: ET.Element | None) -> None:
        if self.in_frame is not None:
            self._end_in_frame(elem, parent)
        elif self.current is not None:
            self._end_in_subject(elem, self.current)

    def _end_in_frame(self, elem: ET.Element, parent: ET.Element | None) -> None:
        """A frame ends (its fields read as numbers), or one of its fields does."""
        tag = _tag(elem)
        subject = self.current
        if elem is self.in_frame:
            if self.frame is not None and subject is not None:
                subject.frames.append(self._numbers(self.frame, len(subject.frames)))
            self.in_frame = None
            self.frame = None
        elif self.frame is not None and parent is not None and _tag(parent) == "frame" \
                and tag in _FRAME_FIELDS:
            self.frame[tag] = elem.text or ""

    def _end_in_subject(self, elem: ET.Element, subject: _Subject) -> None:
        """An element of the chosen subject's header ends."""
        tag = _tag(elem)
        if tag == "segment" and self.section == "segments":
            subject.segments.append(elem.get("label", f"segment{len(subject.segments) + 1}"))
        elif tag == "sensor" and self.section == "sensors":
            subject.sensors.append(elem.get("label", ""))
        elif tag == "contactDefinition":
            subject.contact_labels.append(elem.get("label", ""))
        elif tag in ("segments", "sensors", "frames"):
            self.section = ""
        elif tag == "subject":
            self.current = None


def _rate(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise InputError(f"frameRate {text[:40]!r} is not a number", field="frameRate") from None


def _ms(text: str | None) -> float:
    try:
        return float(text or "") / 1000.0
    except ValueError:
        raise InputError(f"frame time {(text or '')[:40]!r} is not a number",
                         field="time") from None


def _scan(path: PathLike, subject: str | None, stop_at_frames: bool = False) -> _Scanner:
    _check_prolog(path)
    scanner = _Scanner(subject, stop_at_frames)
    for event, elem, parent in _stream(path):
        if event == "start":
            if not scanner.start(elem):
                break
        else:
            scanner.end(elem, parent)
    return scanner


# --------------------------------------------------------------------------- reader


def _chosen_subject(scanner: _Scanner, subject: str | None,
                    notes: list[str]) -> _Subject:
    if scanner.subject is None:
        if subject is not None:
            raise InputError(f"no subject {subject!r} in the MVNX; subjects: "
                             f"{', '.join(repr(s) for s in scanner.labels) or 'none'}",
                             field="subject")
        raise InputError("no <subject> in MVNX", field="subject")
    if subject is None and len(scanner.labels) > 1:
        notes.append(f"warning: the MVNX holds {len(scanner.labels)} subjects "
                     f"({', '.join(repr(s) for s in scanner.labels)}); read the first, "
                     "choose another with subject= (label or number)")
    return scanner.subject


def _world_accelerations(chosen: _Subject, notes: list[str]) -> NDArray[np.float64]:
    """(F, sensors, 3) gravity-free accelerations in the MVNX world frame (Z up), m/s²."""
    n_sensors = len(chosen.sensors)
    frames = chosen.frames
    if all("sensorFreeAcceleration" in f for f in frames):
        notes.append("accelerations: sensorFreeAcceleration (m/s², gravity removed)")
        return np.array([_floats(f["sensorFreeAcceleration"], 3 * n_sensors,
                                 "sensorFreeAcceleration", k)
                         for k, f in enumerate(frames)]).reshape(len(frames), n_sensors, 3)
    if all("sensorAcceleration" in f and "sensorOrientation" in f for f in frames):
        acc = np.array([_floats(f["sensorAcceleration"], 3 * n_sensors, "sensorAcceleration", k)
                        for k, f in enumerate(frames)]).reshape(len(frames), n_sensors, 3)
        quat = np.array([_floats(f["sensorOrientation"], 4 * n_sensors, "sensorOrientation", k)
                         for k, f in enumerate(frames)]).reshape(len(frames), n_sensors, 4)
        norm = np.linalg.norm(quat, axis=-1, keepdims=True)
        if np.any(np.abs(norm - 1.0) > 0.05):
            raise InputError("sensorOrientation holds quaternions whose norm is not 1",
                             field="sensorOrientation")
        notes.append("accelerations: MVNX 3 sensorAcceleration rotated to the world by "
                     f"sensorOrientation, gravity ({GRAVITY} m/s²) removed")
        world = rotate(quat / norm, acc) - np.array([0.0, 0.0, GRAVITY])
        return np.asarray(world, dtype=float)
    raise InputError("MVNX frames lack sensorFreeAcceleration (MVNX 4) and "
                     "sensorAcceleration with sensorOrientation (MVNX 3)",
                     field="sensorFreeAcceleration")


def _check_gravity_removed(acc: NDArray[np.float64], sensors: list[str],
                           feet: tuple[str, str]) -> None:
    """A free acceleration averages about 0 over a take; gravity left in averages 1 g."""
    for foot in feet:
        vertical = float(np.mean(acc[:, sensors.index(foot), 2]))
        if abs(vertical) > GRAVITY / 2:
            raise InputError(
                f"the free acceleration of {foot!r} averages {vertical:.2f} m/s² vertically; "
                f"a gravity-free acceleration averages about 0: gravity ({GRAVITY} m/s²) was "
                "not removed. Export sensorFreeAcceleration from MVN, or remove gravity "
                "first", sensor=foot, field="sensorFreeAcceleration")


def _check_feet(feet: tuple[str, str], joints: tuple[str, ...], sensors: list[str]) -> None:
    """Both feet are segments and carry a sensor."""
    for foot in feet:
        if foot not in joints:
            raise InputError(f"foot segment {foot!r} not found in the MVNX; segments: "
                             f"{', '.join(joints)}", field=foot)
        if foot not in sensors:
            raise InputError(f"no sensor on {foot!r}; sensors: {', '.join(sensors)}",
                             sensor=foot)


def _positions(chosen: _Subject) -> NDArray[np.float64]:
    """(F, segments, 3) segment positions, converted to Y up."""
    n = len(chosen.frames)
    for k, frame in enumerate(chosen.frames):
        if "position" not in frame:
            raise InputError(f"frame {k} has no position", field="position")
    size = 3 * len(chosen.segments)
    values = [_floats(f["position"], size, "position", k) for k, f in enumerate(chosen.frames)]
    return z_up_to_y_up(np.array(values).reshape(n, -1, 3))


def _rate_and_time(chosen: _Subject) -> tuple[float, NDArray[np.float64]]:
    """The frame rate (``frameRate``, else from the frame times) and the frames' times (the
    file's, else from the rate), s."""
    n = len(chosen.frames)
    time = np.array(chosen.times)
    fps = chosen.fps
    if fps is None or not fps > 0:
        if np.isnan(time).any() or n < 2:
            raise InputError("MVNX has neither frameRate nor frame times", field="frameRate")
        fps = 1.0 / float(np.median(np.diff(time)))
    if np.isnan(time).any():
        time = np.arange(n) / fps
    return fps, time


def read_mvnx(path: PathLike, *, left_foot: str = "LeftFoot",
              right_foot: str = "RightFoot", subject: str | None = None) -> KinematicsRecording:
    """Read an MVNX file (MVNX 4, or MVNX 3 with sensorAcceleration and sensorOrientation).

    Parameters
    ----------
    path : path
    left_foot, right_foot : str
        Segment names of the feet; their sensors must carry ``sensorFreeAcceleration`` (or,
        MVNX 3, ``sensorAcceleration`` and ``sensorOrientation``: the acceleration is rotated
        to the world frame and gravity removed).
    subject : str, optional
        Label or 1-based number of the ``<subject>`` to read; default the first (with a
        warning in ``notes`` when the file holds several).

    Returns
    -------
    KinematicsRecording
        ``acceleration_frame="world"``; ``contacts`` from ``footContacts`` when present.

    Raises
    ------
    InputError
        Not MVNX, DOCTYPE/entities, more elements than the limits (``MAX_HEADER_ELEMENTS``,
        ``MAX_FRAME_ELEMENTS``, one tag per ``MIN_BYTES_PER_TAG`` bytes), unknown subject,
        missing feet (listing the segments present), inconsistent frames, gravity left in
        a free acceleration.
    """
    scanner = _scan(path, subject)
    notes = ["MVNX Z up converted to Y up"]
    chosen = _chosen_subject(scanner, subject, notes)
    segments, sensors = chosen.segments, chosen.sensors
    if not segments:
        raise InputError("no <segments> in MVNX", field="segments")
    if not chosen.frames:
        raise InputError("MVNX has no normal frames", field="frames")
    joints = tuple(segments)
    feet = (left_foot, right_foot)
    _check_feet(feet, joints, sensors)
    pos = _positions(chosen)
    world = _world_accelerations(chosen, notes)
    _check_gravity_removed(world, sensors, feet)
    acc = z_up_to_y_up(world)
    fps, time = _rate_and_time(chosen)
    flags = _contacts(chosen, feet, notes)
    toes = {}
    for foot in feet:
        toe = find_toe(foot, joints, pos)
        if toe is not None:
            toes[foot] = toe
    root = next((s for s in joints if s.lower() == "pelvis"), joints[0])
    return KinematicsRecording(
        joints=joints, positions=pos, fps=float(fps), time=time - time[0],
        accelerations={f: acc[:, sensors.index(f)] for f in feet}, acceleration_frame="world",
        left_foot=left_foot, right_foot=right_foot, toes=toes, contacts=flags,
        source_format="mvnx", length_scale=1.0, root=root, source_path=str(path),
        notes=tuple(notes), source_subject=chosen.number)


def _contacts(chosen: _Subject, feet: tuple[str, str],
              notes: list[str]) -> dict[str, NDArray[np.bool_]]:
    labels = chosen.contact_labels
    if not labels or not all("footContacts" in f for f in chosen.frames):
        return {}
    c = np.array([_floats(f["footContacts"], len(labels), "footContacts", k)
                  for k, f in enumerate(chosen.frames)]) > 0.5
    flags: dict[str, NDArray[np.bool_]] = {}
    for foot in feet:
        cols = [i for i, lab in enumerate(labels) if lab.startswith(f"{foot}_")]
        if cols:
            flags[foot] = np.asarray(c[:, cols].any(axis=1))
    if flags:
        notes.append("foot contacts from footContacts")
    return flags


# --------------------------------------------------------------------------- sniff, writer


_NORMAL = re.compile(rb"""<subject\b|<frame\b[^>]*\btype\s*=\s*["']normal["']""")


def sniff_mvnx(path: PathLike) -> dict[str, Any]:
    """Format, frames, segment names and fps of the first subject, by a streaming scan."""
    scanner = _scan(path, None, stop_at_frames=True)
    chosen = scanner.subject
    frames: dict[int, int] = {}
    subject = 0
    tail = b""
    with open(path, "rb") as handle:
        while chunk := handle.read(1 << 20):
            data = tail + chunk
            cut = data.rfind(b"<")
            # a tag cut by the block end is counted with the next block
            body, tail = (data[:cut], data[cut:]) if cut >= 0 else (data, b"")
            for match in _NORMAL.finditer(body):
                if match.group(0).startswith(b"<subject"):
                    subject += 1
                else:
                    frames[subject] = frames.get(subject, 0) + 1
        for match in _NORMAL.finditer(tail):
            if not match.group(0).startswith(b"<subject"):
                frames[subject] = frames.get(subject, 0) + 1
    return {"format": "mvnx", "frames": frames.get(1, 0),
            "joints": list(chosen.segments) if chosen else [],
            "fps": chosen.fps if chosen else None}


_FRAME = re.compile(r"""<subject\b[^>]*>|<frame\b[^>]*>|<position>[^<]*</position>""")
_NORMAL_TYPE = re.compile(r"""\btype\s*=\s*["']normal["']""")


def write_mvnx(result: TranslationResult, recording: KinematicsRecording,
               path: PathLike) -> None:
    """Copy the input MVNX with the corrected segment positions of every normal frame of the
    subject that was read.

    Raises
    ------
    InputError
        Input not MVNX, or its normal frames do not match the result's (the file changed).
    """
    if recording.source_path is None or recording.source_format != "mvnx":
        raise InputError("MVNX output needs an MVNX input", field="format")
    corrected = y_up_to_z_up(result.joint_positions("an MVNX"))
    index = -1
    subject = -1
    in_normal = False

    def replace(match: re.Match[str]) -> str:
        nonlocal index, in_normal, subject
        text = match.group(0)
        if text.startswith("<subject"):
            subject += 1
            return text
        if text.startswith("<frame"):
            in_normal = (subject == recording.source_subject
                         and _NORMAL_TYPE.search(text) is not None)
            if in_normal:
                index += 1
            return text
        if not in_normal or index >= corrected.shape[0]:
            return text
        values = " ".join(f"{v:.6f}" for v in corrected[index].ravel())
        return f"<position>{values}</position>"

    with open(recording.source_path, encoding="utf-8") as src, \
            open(Path(path), "w", encoding="utf-8") as dst:
        for line in src:
            dst.write(_FRAME.sub(replace, line))
    if index + 1 != corrected.shape[0]:
        raise InputError(f"MVNX output: the input has {index + 1} normal frames where "
                         f"{corrected.shape[0]} were read; it changed since", field="format")
