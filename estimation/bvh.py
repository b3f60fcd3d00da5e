"""Reading, writing and forward kinematics of BVH motion files.

A BVH file is a joint hierarchy (offsets, channels) plus one row of channel values per frame.
Position channels replace a joint's OFFSET; rotation channels compose in the order listed
(``Zrotation Xrotation Yrotation`` is R = Rz·Rx·Ry, intrinsic). End sites become nodes named
``<parent>_end`` with no channels.
"""

from __future__ import annotations

import io
import os
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Final

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
    notes : tuple of str
        What the reader tolerated (a ``Frames:`` count that differs from the rows).
    """

    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: NDArray[np.float64]
    channels: tuple[tuple[str, ...], ...]
    frame_time: float
    values: NDArray[np.float64]
    notes: tuple[str, ...] = ()
    _starts: tuple[int, ...] = field(init=False, repr=False)
    _with_children: frozenset[int] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_with_children", frozenset(self.parents))
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
        """Index of node ``name``; raises InputError listing the joints present."""
        try:
            return self.names.index(name)
        except ValueError:
            raise InputError(f"joint {name!r} not in BVH; it has {', '.join(self.joints())}",
                             field=name) from None

    def is_end_site(self, node: int) -> bool:
        """Whether ``node`` is an End Site (``<parent>_end``: no channels, no children)."""
        parent = self.parents[node]
        return (parent >= 0 and not self.channels[node] and node not in self._with_children
                and self.names[node].startswith(f"{self.names[parent]}_end"))

    def joints(self) -> tuple[str, ...]:
        """Names of the real joints (end sites left out), in file order."""
        return tuple(n for j, n in enumerate(self.names) if not self.is_end_site(j))

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


MAX_NODES: Final[int] = 10_000
"""Most nodes (joints and end sites) a BVH may declare; real rigs have a few hundred."""
MAX_CHANNELS: Final[int] = 6
"""Most channels per joint: three positions and three rotations."""


class _Tokens:
    """Whitespace-separated tokens of the hierarchy, read one line at a time from an
    iterator, so that nothing beyond the point of failure is split or kept."""

    def __init__(self, lines: Iterator[str]) -> None:
        self.lines = lines
        self.buffer: list[str] = []  # tokens left on the current line
        self.line = 0               # 1-based number of the current line

    def _fill(self) -> bool:
        while not self.buffer:
            text = next(self.lines, None)
            if text is None:
                return False
            self.line += 1
            self.buffer = text.split()[::-1]
        return True

    def peek(self) -> str | None:
        """The next token, or None at the end of the file."""
        return self.buffer[-1] if self._fill() else None

    def take(self, expected: str | None = None, what: str = "") -> tuple[str, int]:
        """The next token and its line; InputError at the end or when it is not ``expected``
        (compared without case)."""
        if not self._fill():
            wanted = f"; expected {expected or what}" if expected or what else ""
            raise InputError(f"unexpected end of BVH file{wanted}", line=self.line)
        tok = self.buffer.pop()
        if expected is not None and tok.upper() != expected.upper():
            raise InputError(f"expected {expected!r}, found {tok!r}", line=self.line)
        return tok, self.line

    def rest_of_line(self) -> list[str]:
        """The tokens left on the current line (consumed)."""
        rest = self.buffer[::-1]
        self.buffer = []
        return rest

    def number(self, what: str) -> float:
        """The next token as a finite number."""
        tok, line = self.take(what=what)
        try:
            value = float(tok)
        except ValueError:
            raise InputError(f"expected a number ({what}), found {tok!r}", line=line) from None
        if not np.isfinite(value):
            raise InputError(f"{what} must be finite, found {tok!r}", line=line)
        return value


@dataclass
class _Hierarchy:
    names: list[str] = field(default_factory=list)
    parents: list[int] = field(default_factory=list)
    offsets: list[list[float]] = field(default_factory=list)
    channels: list[tuple[str, ...]] = field(default_factory=list)


def read_bvh(source: str | os.PathLike[str] | io.TextIOBase) -> BvhMotion:
    """Read a BVH file.

    Accepts what Blender's importer accepts: a UTF-8 byte-order mark, CRLF line ends, tabs,
    joint names with spaces (3ds Max Biped's ``Bip01 L Thigh``) and a ``Frames:`` count larger
    than the rows present (the rows are read; ``notes`` says so).

    Parameters
    ----------
    source : path or text stream

    Returns
    -------
    BvhMotion
        Offsets and position channels in the file's length unit.

    Raises
    ------
    InputError
        On a malformed hierarchy or motion section, naming the line; on more than
        :data:`MAX_NODES` nodes or :data:`MAX_CHANNELS` channels per joint.
    """
    if isinstance(source, io.TextIOBase):
        text = source.read()
    else:
        text = Path(source).read_text(encoding="utf-8", errors="replace")
    lines = iter(io.StringIO(text.removeprefix("\ufeff"), newline=None))
    tokens = _Tokens(lines)
    tokens.take("HIERARCHY")
    tokens.take("ROOT")
    tree = _Hierarchy()
    _read_nodes(tokens, tree)
    tokens.take("MOTION")
    n_frames, frame_time, body_start = _read_motion_header(tokens)
    values, notes = _read_motion_rows(lines, body_start, n_frames,
                                      sum(len(c) for c in tree.channels))
    return BvhMotion(tuple(tree.names), tuple(tree.parents), np.array(tree.offsets, dtype=float),
                     tuple(tree.channels), frame_time, values, notes=notes)


def _read_nodes(tokens: _Tokens, tree: _Hierarchy) -> None:
    """Read the ROOT node (its keyword already taken) and everything below it."""
    stack: list[int] = []
    keyword = "ROOT"
    while True:
        line = tokens.line
        if keyword == "END":
            tokens.take("Site")
            node_name = f"{tree.names[stack[-1]]}_end"
            while node_name in tree.names:  # a second end site of the same joint
                node_name += "_"
        else:
            node_name = _node_name(tokens, keyword, line)
        tokens.take("{")
        if len(tree.names) >= MAX_NODES:
            raise InputError(f"more than {MAX_NODES} joints in the hierarchy; "
                             "not a body's skeleton", line=line)
        tree.names.append(node_name)
        tree.parents.append(stack[-1] if stack else -1)
        stack.append(len(tree.names) - 1)
        tokens.take("OFFSET")
        tree.offsets.append([tokens.number("OFFSET x"), tokens.number("OFFSET y"),
                             tokens.number("OFFSET z")])
        chans: tuple[str, ...] = ()
        nxt = tokens.peek()
        if keyword != "END" and nxt is not None and nxt.upper() == "CHANNELS":
            chans = _read_channels(tokens)
        tree.channels.append(chans)
        keyword = _close_nodes(tokens, stack)
        if not stack:
            return


def _node_name(tokens: _Tokens, keyword: str, line: int) -> str:
    """A ROOT or JOINT name: the rest of its line (names may hold spaces), an opening brace
    on the same line excepted."""
    rest = tokens.rest_of_line()
    if rest and rest[-1] == "{":
        tokens.buffer = ["{"]
        rest = rest[:-1]
    elif rest and rest[-1].endswith("{"):
        tokens.buffer = ["{"]
        rest[-1] = rest[-1][:-1]
    if not rest:
        raise InputError(f"{keyword} without a name", line=line)
    return " ".join(rest)


def _read_channels(tokens: _Tokens) -> tuple[str, ...]:
    tokens.take("CHANNELS")
    count_tok, count_line = tokens.take(what="a channel count")
    if not count_tok.isdigit():
        raise InputError(f"expected a channel count, found {count_tok!r}", line=count_line)
    count = int(count_tok)
    if count > MAX_CHANNELS:
        raise InputError(f"CHANNELS {count_tok}: a joint has at most {MAX_CHANNELS} channels "
                         "(3 positions, 3 rotations)", line=count_line)
    chans = []
    for _ in range(count):
        ch, ch_line = tokens.take(what="a channel name")
        if ch not in _AXES and ch not in _ROT_AXES:
            raise InputError(f"unknown channel {ch!r}; expected Xposition, Yposition, "
                             "Zposition, Xrotation, Yrotation or Zrotation", line=ch_line)
        chans.append(ch)
    return tuple(chans)


def _close_nodes(tokens: _Tokens, stack: list[int]) -> str:
    """Consume closing braces up to the next JOINT / End Site; returns its keyword ("" when
    the root closed)."""
    while True:
        tok, line = tokens.take(what="JOINT, End Site or '}'")
        up = tok.upper()
        if up in ("JOINT", "END"):
            return up
        if tok == "}":
            stack.pop()
            if not stack:
                return ""
            continue
        raise InputError(f"unexpected {tok!r} in hierarchy; expected JOINT, End Site or '}}'",
                         line=line)


def _read_motion_header(tokens: _Tokens) -> tuple[int, float, int]:
    """``Frames: N`` and ``Frame Time: dt``; returns N, dt and the number of the header's
    last line."""
    tok, line = tokens.take(what="Frames:")
    if tok.upper() == "FRAMES:":
        count_tok, line = tokens.take(what="a frame count")
    elif tok.upper().startswith("FRAMES:"):
        count_tok = tok[len("FRAMES:"):]
    else:
        raise InputError(f"expected 'Frames:', found {tok!r}", line=line)
    if not count_tok.isdigit():
        raise InputError(f"bad frame count {count_tok!r}", line=line)
    tokens.take("Frame")
    tokens.take("Time:")
    frame_time = tokens.number("frame time")
    if not frame_time > 0:
        raise InputError(f"frame time must be positive, got {frame_time}", line=tokens.line)
    if tokens.rest_of_line():
        raise InputError("motion rows must start on the line after 'Frame Time:'",
                         line=tokens.line)
    return int(count_tok), frame_time, tokens.line


def _read_motion_rows(lines: Iterator[str], start: int, n_frames: int, n_channels: int
                      ) -> tuple[NDArray[np.float64], tuple[str, ...]]:
    """Channel values (F, C) of the remaining non-blank lines, the first being line
    ``start + 1``."""
    if n_channels == 0:
        raise InputError("the hierarchy declares no channels", line=start)
    numbered = [(n, ln) for n, ln in enumerate(lines, start + 1) if ln.strip()]
    notes: tuple[str, ...] = ()
    if len(numbered) < n_frames:
        notes = (f"header says {n_frames} frames, the file has {len(numbered)} rows: "
                 f"read {len(numbered)}",)
    elif len(numbered) > n_frames:
        notes = (f"header says {n_frames} frames, the file has {len(numbered)} rows: "
                 f"read the first {n_frames}",)
        numbered = numbered[:n_frames]
    if not numbered:
        raise InputError("no motion rows after 'Frame Time:'", line=start)
    values = _parse_rows([ln for _, ln in numbered], n_channels)
    if values is None:
        _raise_bad_row(numbered, n_channels)
    assert values is not None
    return values, notes


def _parse_rows(rows: list[str], n_channels: int) -> NDArray[np.float64] | None:
    """All rows as floats, or None when any row is malformed (wrong count, not a number,
    not finite)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            values = np.loadtxt(rows, dtype=float, ndmin=2)
    except (ValueError, UserWarning):
        return None
    if values.shape != (len(rows), n_channels) or not np.isfinite(values).all():
        return None
    return values


def _raise_bad_row(numbered: list[tuple[int, str]], n_channels: int) -> None:
    for line, row in numbered:
        parts = row.split()
        if len(parts) != n_channels:
            cut = " (a truncated row?)" if len(parts) < n_channels else ""
            raise InputError(f"motion row has {len(parts)} values, the hierarchy declares "
                             f"{n_channels} channels{cut}", line=line)
        for k, part in enumerate(parts, 1):
            try:
                value = float(part)
            except ValueError:
                raise InputError(f"not a number: {part[:40]!r} (value {k} of the row)",
                                 line=line, column=k) from None
            if not np.isfinite(value):
                raise InputError(f"value {k} of the row is {part!r}; channel values must be "
                                 "finite", line=line, column=k)
    raise InputError("malformed motion rows", line=numbered[0][0])


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
