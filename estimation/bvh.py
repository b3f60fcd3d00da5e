"""Reading, writing and forward kinematics of BVH motion files.

A BVH file is a joint hierarchy (offsets, channels) plus one row of channel values per frame.
Position channels replace a joint's OFFSET; rotation channels compose in the order listed
(``Zrotation Xrotation Yrotation`` is R = Rz·Rx·Ry, intrinsic). End sites become nodes named
``<parent>_end`` with no channels.
"""

from __future__ import annotations

import io
import os
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from .errors import InputError

if TYPE_CHECKING:  # scipy is imported where it is used: the readers serve processes without it
    from scipy.spatial.transform import Rotation

_AXES = {"Xposition": 0, "Yposition": 1, "Zposition": 2}
_ROT_AXES = {"Xrotation": "X", "Yrotation": "Y", "Zrotation": "Z"}


@dataclass(frozen=True, eq=False)
class BvhMotion:
    """A BVH hierarchy and its motion.

    Attributes
    ----------
    names : tuple of str
        Node names in file order (J nodes, end sites included as ``<parent>_end``).
    parents : tuple of int
        Parent index of each node, -1 for the root.
    offsets : ndarray, shape (J, 3)
        OFFSET of each node in its parent's frame, file units.
    channels : tuple of tuple of str
        Channel names of each node (empty for end sites).
    frame_time : float
        Seconds per frame.
    values : ndarray, shape (F, C)
        Channel values per frame, in node then channel order; rotations in degrees.
    """

    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: NDArray[np.float64]
    channels: tuple[tuple[str, ...], ...]
    frame_time: float
    values: NDArray[np.float64]
    _starts: tuple[int, ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        starts, total = [], 0
        for ch in self.channels:
            starts.append(total)
            total += len(ch)
        object.__setattr__(self, "_starts", tuple(starts))
        if self.values.ndim != 2 or self.values.shape[1] != total:
            raise InputError(f"motion rows have {self.values.shape[-1]} values, "
                             f"the hierarchy declares {total} channels", field="MOTION")

    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return int(self.values.shape[0])

    @property
    def fps(self) -> float:
        """Frames per second (1 / frame_time)."""
        return 1.0 / self.frame_time

    def index(self, name: str) -> int:
        """Index of node ``name``; raises InputError listing the nodes present."""
        try:
            return self.names.index(name)
        except ValueError:
            raise InputError(f"joint {name!r} not in BVH; it has {', '.join(self.names)}",
                             field=name) from None

    def channel_values(self, node: int) -> NDArray[np.float64]:
        """Values (F, n_channels) of one node's channels."""
        start = self._starts[node]
        return self.values[:, start:start + len(self.channels[node])]

    def local_translations(self) -> NDArray[np.float64]:
        """Translation (F, J, 3) of each node in its parent frame (OFFSET or position channels)."""
        out = np.broadcast_to(self.offsets, (self.n_frames, *self.offsets.shape)).copy()
        for j, chans in enumerate(self.channels):
            vals = self.channel_values(j)
            for k, name in enumerate(chans):
                if name in _AXES:
                    out[:, j, _AXES[name]] = vals[:, k]
        return out

    def local_rotations(self) -> list[Rotation]:
        """Rotation of each node relative to its parent, one Rotation of length F per node."""
        from scipy.spatial.transform import Rotation

        rots = []
        for j, chans in enumerate(self.channels):
            order = "".join(_ROT_AXES[c] for c in chans if c in _ROT_AXES)
            if not order:
                rots.append(Rotation.identity(self.n_frames))
                continue
            vals = self.channel_values(j)
            angles = vals[:, [k for k, c in enumerate(chans) if c in _ROT_AXES]]
            rots.append(Rotation.from_euler(order, angles, degrees=True))
        return rots

    def with_values(self, values: NDArray[np.float64]) -> BvhMotion:
        """The same hierarchy with other channel values."""
        return replace(self, values=np.asarray(values, dtype=float))


def forward_kinematics(motion: BvhMotion) -> tuple[NDArray[np.float64], list[Rotation]]:
    """Global positions and orientations of every node.

    Parameters
    ----------
    motion : BvhMotion

    Returns
    -------
    positions : ndarray, shape (F, J, 3)
        Node origins in the world frame, file units.
    rotations : list of Rotation
        Node frame → world rotation, one Rotation of length F per node.
    """
    trans = motion.local_translations()
    local = motion.local_rotations()
    positions = np.empty_like(trans)
    rotations: list[Rotation] = []
    for j, parent in enumerate(motion.parents):
        if parent < 0:
            positions[:, j] = trans[:, j]
            rotations.append(local[j])
        else:
            positions[:, j] = positions[:, parent] + rotations[parent].apply(trans[:, j])
            rotations.append(rotations[parent] * local[j])
    return positions, rotations


_TOKEN = re.compile(r"\S+")


def read_bvh(source: str | os.PathLike[str] | io.TextIOBase) -> BvhMotion:
    """Read a BVH file.

    Parameters
    ----------
    source : path or text stream

    Returns
    -------
    BvhMotion

    Raises
    ------
    InputError
        On a malformed hierarchy or motion section, naming the line.
    """
    if isinstance(source, io.TextIOBase):
        text = source.read()
    else:
        text = Path(source).read_text(encoding="utf-8", errors="replace")
    lines = text.splitlines()
    tokens: list[tuple[str, int]] = [
        (m.group(0), n) for n, line in enumerate(lines, 1) for m in _TOKEN.finditer(line)
    ]
    pos = 0

    def take(expected: str | None = None) -> tuple[str, int]:
        nonlocal pos
        if pos >= len(tokens):
            raise InputError("unexpected end of BVH file", line=len(lines))
        tok, line = tokens[pos]
        pos += 1
        if expected is not None and tok.upper() != expected.upper():
            raise InputError(f"expected {expected!r}, found {tok!r}", line=line)
        return tok, line

    def number() -> float:
        tok, line = take()
        try:
            return float(tok)
        except ValueError:
            raise InputError(f"expected a number, found {tok!r}", line=line) from None

    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []

    take("HIERARCHY")
    stack: list[int] = []
    tok, line = take()
    if tok.upper() != "ROOT":
        raise InputError(f"expected ROOT, found {tok!r}", line=line)
    keyword = "ROOT"
    while True:
        if keyword in ("ROOT", "JOINT"):
            name, _ = take()
            node_name = name
        else:  # End Site
            take("Site")
            node_name = f"{names[stack[-1]]}_end"
        take("{")
        names.append(node_name)
        parents.append(stack[-1] if stack else -1)
        stack.append(len(names) - 1)
        take("OFFSET")
        offsets.append([number(), number(), number()])
        chans: tuple[str, ...] = ()
        if keyword != "End" and pos < len(tokens) and tokens[pos][0].upper() == "CHANNELS":
            take()
            count_tok, count_line = take()
            if not count_tok.isdigit():
                raise InputError(f"expected a channel count, found {count_tok!r}",
                                 line=count_line)
            items = [take() for _ in range(int(count_tok))]
            for ch, ch_line in items:
                if ch not in _AXES and ch not in _ROT_AXES:
                    raise InputError(f"unknown channel {ch!r}", line=ch_line)
            chans = tuple(ch for ch, _ in items)
        channels.append(chans)
        # children or closing braces
        while True:
            tok, line = take()
            up = tok.upper()
            if up in ("JOINT", "END"):
                keyword = "JOINT" if up == "JOINT" else "End"
                break
            if tok == "}":
                stack.pop()
                if not stack:
                    keyword = ""
                    break
                continue
            raise InputError(f"unexpected {tok!r} in hierarchy", line=line)
        if not stack:
            break

    take("MOTION")
    take("Frames:")
    count_tok, count_line = take()
    try:
        n_frames = int(count_tok)
    except ValueError:
        raise InputError(f"bad frame count {count_tok!r}", line=count_line) from None
    take("Frame")
    take("Time:")
    frame_time = number()
    if not frame_time > 0:
        raise InputError(f"frame time must be positive, got {frame_time}",
                         line=tokens[pos - 1][1])
    n_channels = sum(len(c) for c in channels)
    first_line = tokens[pos][1] if pos < len(tokens) else len(lines) + 1
    body = lines[first_line - 1:]
    rows = [ln for ln in body if ln.strip()]
    if len(rows) < n_frames:
        raise InputError(f"header says {n_frames} frames, file has {len(rows)}",
                         line=len(lines))
    try:
        values = np.loadtxt(io.StringIO("\n".join(rows[:n_frames])), dtype=float, ndmin=2)
    except ValueError as exc:
        bad = _first_bad_row(rows[:n_frames], n_channels)
        raise InputError(f"malformed motion row: {exc}",
                         line=first_line + bad if bad is not None else None) from None
    if values.shape != (n_frames, n_channels):
        bad = _first_bad_row(rows[:n_frames], n_channels)
        raise InputError(f"motion rows must have {n_channels} values",
                         line=first_line + bad if bad is not None else None)
    return BvhMotion(tuple(names), tuple(parents), np.array(offsets, dtype=float),
                     tuple(channels), float(frame_time), values)


def _first_bad_row(rows: list[str], n_channels: int) -> int | None:
    for i, row in enumerate(rows):
        parts = row.split()
        if len(parts) != n_channels:
            return i
        try:
            [float(p) for p in parts]
        except ValueError:
            return i
    return None


def write_bvh(motion: BvhMotion, target: str | os.PathLike[str] | io.TextIOBase,
              *, precision: int = 6) -> None:
    """Write ``motion`` as BVH text.

    Parameters
    ----------
    motion : BvhMotion
    target : path or text stream
    precision : int
        Decimal places of channel values and offsets.
    """
    out = io.StringIO()
    children: dict[int, list[int]] = {j: [] for j in range(len(motion.names))}
    for j, p in enumerate(motion.parents):
        if p >= 0:
            children[p].append(j)

    def fmt(v: float) -> str:
        return f"{v:.{precision}f}"

    def node(j: int, depth: int) -> None:
        pad = "  " * depth
        if motion.parents[j] < 0:
            out.write(f"{pad}ROOT {motion.names[j]}\n")
        elif not motion.channels[j] and not children[j]:
            out.write(f"{pad}End Site\n")
        else:
            out.write(f"{pad}JOINT {motion.names[j]}\n")
        out.write(f"{pad}{{\n{pad}  OFFSET {' '.join(fmt(v) for v in motion.offsets[j])}\n")
        if motion.channels[j] or children[j]:
            chans = motion.channels[j]
            out.write(f"{pad}  CHANNELS {len(chans)} {' '.join(chans)}\n".replace("  \n", "\n"))
        for c in children[j]:
            node(c, depth + 1)
        out.write(f"{pad}}}\n")

    out.write("HIERARCHY\n")
    node(motion.parents.index(-1), 0)
    out.write(f"MOTION\nFrames: {motion.n_frames}\nFrame Time: {motion.frame_time:.8f}\n")
    np.savetxt(out, motion.values, fmt=f"%.{precision}f", delimiter=" ")
    text = out.getvalue()
    if isinstance(target, io.TextIOBase):
        target.write(text)
    else:
        Path(target).write_text(text, encoding="utf-8")
