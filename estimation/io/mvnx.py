"""Xsens MVNX (MVN Analyze/Studio XML export) for root-translation estimation.

The file is parsed as a stream (``xml.etree.ElementTree.iterparse``, each frame cleared once
read), so recordings of any length fit in memory as arrays. Read per ``normal`` frame:
segment ``position`` (m), ``sensorFreeAcceleration`` (m/s², world frame, gravity removed)
and, when present, ``footContacts`` (heel/toe flags of each foot). MVNX is Z up; everything is
converted to the Y-up frame of :class:`~estimation.io.kinematics.KinematicsRecording`
(x, y, z) → (x, z, −y).
"""

from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from .kinematics import KinematicsRecording, _auto_toe

if TYPE_CHECKING:
    from ..translation import TranslationResult

PathLike = str | os.PathLike[str]


def z_up_to_y_up(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """(x, y, z) Z-up → (x, z, −y) Y-up, on the last axis."""
    return np.stack([v[..., 0], v[..., 2], -v[..., 1]], axis=-1)


def y_up_to_z_up(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """Inverse of :func:`z_up_to_y_up`."""
    return np.stack([v[..., 0], -v[..., 2], v[..., 1]], axis=-1)


def _tag(elem: ET.Element) -> str:
    return elem.tag.rsplit("}", 1)[-1]


def _floats(text: str | None, expected: int, what: str, frame: int) -> NDArray[np.float64]:
    values = np.array((text or "").split(), dtype=float)
    if values.size != expected:
        raise InputError(f"frame {frame}: {what} has {values.size} values, expected {expected}",
                         field=what)
    return values


def read_mvnx(path: PathLike, *, left_foot: str = "LeftFoot",
              right_foot: str = "RightFoot") -> KinematicsRecording:
    """Read an MVNX file.

    Parameters
    ----------
    path : path
    left_foot, right_foot : str
        Segment names of the feet; their sensors must carry ``sensorFreeAcceleration``.

    Returns
    -------
    KinematicsRecording
        ``acceleration_frame="world"``; ``contacts`` from ``footContacts`` when present.

    Raises
    ------
    InputError
        Not MVNX, missing feet (listing the segments present), inconsistent frames.
    """
    segments: list[str] = []
    sensors: list[str] = []
    contact_labels: list[str] = []
    fps: float | None = None
    positions: list[NDArray[np.float64]] = []
    accelerations: list[NDArray[np.float64]] = []
    contacts: list[NDArray[np.float64]] = []
    times: list[float] = []
    frames_parent: ET.Element | None = None
    in_segments = in_sensors = False
    try:
        for event, elem in ET.iterparse(str(path), events=("start", "end")):
            tag = _tag(elem)
            if event == "start":
                if tag == "subject" and elem.get("frameRate"):
                    fps = float(elem.get("frameRate", "0"))
                elif tag == "segments":
                    in_segments = True
                elif tag == "sensors":
                    in_sensors = True
                elif tag == "frames":
                    frames_parent = elem
                continue
            if tag == "segments":
                in_segments = False
            elif tag == "sensors":
                in_sensors = False
            elif tag == "segment" and in_segments:
                segments.append(elem.get("label", f"segment{len(segments) + 1}"))
                elem.clear()
            elif tag == "sensor" and in_sensors:
                sensors.append(elem.get("label", ""))
            elif tag == "contactDefinition":
                contact_labels.append(elem.get("label", ""))
            elif tag == "frame":
                if elem.get("type", "normal") == "normal":
                    k = len(positions)
                    children = {_tag(c): c.text for c in elem}
                    if "position" not in children:
                        raise InputError(f"frame {k} has no position", field="position")
                    positions.append(_floats(children["position"], 3 * len(segments),
                                             "position", k))
                    if "sensorFreeAcceleration" in children:
                        accelerations.append(_floats(children["sensorFreeAcceleration"],
                                                     3 * len(sensors),
                                                     "sensorFreeAcceleration", k))
                    if "footContacts" in children and contact_labels:
                        contacts.append(_floats(children["footContacts"], len(contact_labels),
                                                "footContacts", k))
                    ms = elem.get("time")
                    times.append(float(ms) / 1000.0 if ms not in (None, "") else np.nan)
                elem.clear()
                if frames_parent is not None:
                    frames_parent.clear()
    except ET.ParseError as exc:
        line = exc.position[0] if hasattr(exc, "position") else None
        raise InputError(f"malformed MVNX: {exc}", line=line) from None
    if not segments:
        raise InputError("no <segments> in MVNX", field="segments")
    if not positions:
        raise InputError("MVNX has no normal frames", field="frames")
    joints = tuple(segments)
    for foot in (left_foot, right_foot):
        if foot not in joints:
            raise InputError(f"foot segment {foot!r} not found in the MVNX; segments: "
                             f"{', '.join(joints)}", field=foot)
        if foot not in sensors:
            raise InputError(f"no sensor on {foot!r}; sensors: {', '.join(sensors)}",
                             sensor=foot)
    n = len(positions)
    if len(accelerations) != n:
        raise InputError("MVNX frames lack sensorFreeAcceleration", field="sensorFreeAcceleration")
    pos = z_up_to_y_up(np.array(positions).reshape(n, len(segments), 3))
    acc = z_up_to_y_up(np.array(accelerations).reshape(n, len(sensors), 3))
    time = np.array(times)
    if fps is None or not fps > 0:
        if np.isnan(time).any() or n < 2:
            raise InputError("MVNX has neither frameRate nor frame times", field="frameRate")
        fps = 1.0 / float(np.median(np.diff(time)))
    if np.isnan(time).any():
        time = np.arange(n) / fps
    feet = (left_foot, right_foot)
    notes = ["MVNX Z up converted to Y up", "accelerations: sensorFreeAcceleration (m/s², "
             "gravity removed)"]
    flags: dict[str, NDArray[np.bool_]] = {}
    if contacts and len(contacts) == n:
        c = np.array(contacts) > 0.5
        for foot in feet:
            cols = [i for i, lab in enumerate(contact_labels) if lab.startswith(f"{foot}_")]
            if cols:
                flags[foot] = np.asarray(c[:, cols].any(axis=1))
        if flags:
            notes.append("foot contacts from footContacts")
    toes = {}
    for foot in feet:
        toe = _auto_toe(foot, joints, pos)
        if toe is not None:
            toes[foot] = toe
    root = next((s for s in joints if s.lower() == "pelvis"), joints[0])
    return KinematicsRecording(
        joints=joints, positions=pos, fps=float(fps), time=time - time[0],
        accelerations={f: acc[:, sensors.index(f)] for f in feet}, acceleration_frame="world",
        left_foot=left_foot, right_foot=right_foot, toes=toes, contacts=flags,
        source_format="mvnx", length_scale=1.0, root=root, source_path=str(path),
        notes=tuple(notes))


def sniff_mvnx(path: PathLike) -> dict[str, Any]:
    """Format, frames, segment names and fps of an MVNX file, by a streaming scan."""
    segments: list[str] = []
    fps: float | None = None
    for event, elem in ET.iterparse(str(path), events=("start", "end")):
        tag = _tag(elem)
        if event == "start":
            if tag == "subject" and elem.get("frameRate"):
                fps = float(elem.get("frameRate", "0"))
            if tag == "frames":
                break
        elif tag == "segment":
            segments.append(elem.get("label", ""))
            elem.clear()
    frames = 0
    pattern = re.compile(rb'<frame\b[^>]*type="normal"')
    tail = b""
    with open(path, "rb") as handle:
        while chunk := handle.read(1 << 20):
            data = tail + chunk
            frames += len(pattern.findall(data))
            cut = data.rfind(b"<")
            tail = data[cut:] if cut >= 0 else b""
            if tail and pattern.match(tail):
                frames -= 1
    return {"format": "mvnx", "frames": frames, "joints": segments, "fps": fps}


_FRAME = re.compile(r'<frame\b[^>]*>|<position>[^<]*</position>')


def write_mvnx(result: TranslationResult, recording: KinematicsRecording,
               path: PathLike) -> None:
    """Copy the input MVNX with the corrected segment positions of every normal frame."""
    if recording.source_path is None or recording.source_format != "mvnx":
        raise InputError("MVNX output needs an MVNX input", field="format")
    corrected = y_up_to_z_up(result.positions)
    index = -1
    in_normal = False

    def replace(match: re.Match[str]) -> str:
        nonlocal index, in_normal
        text = match.group(0)
        if text.startswith("<frame"):
            in_normal = 'type="normal"' in text
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
