"""Reading, writing and forward kinematics of BVH motion files.

A BVH file is a joint hierarchy (offsets, channels) plus one row of channel values per frame.
Position channels replace a joint's OFFSET; rotation channels compose in the order listed
(``Zrotation Xrotation Yrotation`` is R = Rz·Rx·Ry, intrinsic). End sites become nodes named
``<parent>_end`` with no channels.
"""

from __future__ import annotations

import io
import itertools
import os
import warnings
from collections import deque
from collections.abc import Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Final

import numpy as np
from numpy.typing import NDArray

from . import _rows as rows
from .errors import InputError
from .numtext import BLOCK_VALUES, fixed_blocks, fixed_text, write_text_blocks
from .threads import MIN_FRAMES, workers

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
        """Names of the real joints (end sites and slip-chain nodes left out), in file
        order."""
        return tuple(n for j, n in enumerate(self.names)
                     if not self.is_end_site(j) and not is_slip_node(n))

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
    stream = io.StringIO(text.removeprefix("\ufeff"), newline=None)
    del text
    tokens = _Tokens(stream)
    tokens.take("HIERARCHY")
    tokens.take("ROOT")
    tree = _Hierarchy()
    _read_nodes(tokens, tree)
    tokens.take("MOTION")
    n_frames, frame_time, body_start = _read_motion_header(tokens)
    values, notes = _read_motion_rows(stream.read(), body_start, n_frames,
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


def _read_motion_rows(rest: str, start: int, n_frames: int, n_channels: int
                      ) -> tuple[NDArray[np.float64], tuple[str, ...]]:
    """Channel values (F, C) of the non-blank lines of ``rest``, the text after the motion
    header, whose first line is line ``start + 1``: parsed whole by ``numpy.loadtxt`` when
    there is no blank line or "#" among the rows, else line by line (naming a bad row's line)."""
    if n_channels == 0:
        raise InputError("the hierarchy declares no channels", line=start)
    rows = rest.rstrip()
    n_rows = rows.count("\n") + 1 if rows else 0
    if n_rows and "\n\n" not in rows and "#" not in rows:
        values = _parse_rows(io.StringIO(rows), min(n_rows, n_frames), n_channels)
        if values is not None:
            return values, _frame_count_notes(n_frames, n_rows)
    numbered = [(n, ln) for n, ln in enumerate(rest.splitlines(), start + 1) if ln.strip()]
    notes = _frame_count_notes(n_frames, len(numbered))
    numbered = numbered[:n_frames]
    if not numbered:
        raise InputError("no motion rows after 'Frame Time:'", line=start)
    found = _parse_rows([ln for _, ln in numbered], len(numbered), n_channels)
    if found is None:
        _raise_bad_row(numbered, n_channels)
    assert found is not None
    return found, notes


def _frame_count_notes(n_frames: int, n_rows: int) -> tuple[str, ...]:
    """What the reader says when the rows present differ from the header's count."""
    if n_rows < n_frames:
        return (f"header says {n_frames} frames, the file has {n_rows} rows: read {n_rows}",)
    if n_rows > n_frames:
        return (f"header says {n_frames} frames, the file has {n_rows} rows: "
                f"read the first {n_frames}",)
    return ()


def _parse_rows(rows: Iterable[str], n_rows: int, n_channels: int
                ) -> NDArray[np.float64] | None:
    """The first ``n_rows`` rows as floats, or None when any of them is malformed (wrong
    count, not a number, not finite)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            values = np.loadtxt(rows, dtype=float, ndmin=2, max_rows=n_rows)
    except (ValueError, UserWarning):
        return None
    if values.shape != (n_rows, n_channels) or not np.isfinite(values).all():
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
    rows = _motion_rows(motion.values.reshape(motion.n_frames, -1), precision)
    write_text_blocks(itertools.chain([out.getvalue()], rows), target)


def _motion_rows(table: NDArray[np.float64], precision: int) -> Iterator[str]:
    """The text of the MOTION rows ``table`` (F, C), block by block (``fixed_blocks``).

    From ``threads.MIN_FRAMES`` frames the blocks are formatted on ``threads.workers()``
    threads (numpy's formatting releases the interpreter lock) and yielded in order, at most
    two per thread held: a skeleton BVH's text ends its writing, when the JSON written
    alongside it (``io.skeleton.write_skeleton_files``) is done and a core is free."""
    if len(table) < MIN_FRAMES or workers() == 1:
        yield from fixed_blocks(table, precision, sep=" ")
        return
    step = max(1, BLOCK_VALUES // max(table.shape[1], 1))  # fixed_blocks' blocks
    with ThreadPoolExecutor(workers(), thread_name_prefix="bonefit-bvh-text") as pool:
        pending: deque[Future[str]] = deque()
        for start in range(0, len(table), step):
            pending.append(pool.submit(fixed_text, table[start:start + step], precision,
                                       sep=" "))
            if len(pending) > 2 * workers():
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()


# --------------------------------------------------------------------------- writer helpers

EULER_ORDERS: tuple[str, ...] = ("ZXY", "ZYX", "YXZ", "YZX", "XYZ", "XZY")
"""Intrinsic Euler orders a writer may give a node, in order of preference on ties."""

JUMP_DEG: Final[float] = 60.0
"""Turn between two frames (degrees) above which the step is a jump in the data, not a
motion: no interpolation of rotations can follow it (a take that starts with a T-pose frame
turns segments by 76–180° between its first two frames; the fastest turns of the benchmark
clips' dancers, boxers and runners are 28–45° per frame). Such steps do not count in the
choice of channels, and :func:`jump_steps` reports them."""

MAX_CHOICE_STEPS: Final[int] = 8_000
"""Steps between frames, sampled evenly over a take, on which a node's Euler order and rest
orientation are chosen (every step of takes up to this length). The choice is a statistic
of the take, whose cost sits in few steps (fast turns, spans near gimbal lock): on 36,000-
and 144,000-frame estimates (11 and 15 sensors, simulated takes of three seeds) the options
picked on 8,000 steps cost, over the whole take, at most 3.3 % more than the best option's
for any node, 0.12 % summed over the nodes (20,000 steps: 0.1 %; 4,000: 7 %; 2,000:
25 %)."""


def _wrap(degrees: NDArray[np.float64]) -> NDArray[np.float64]:
    """Angles moved by whole turns into [-180, 180]."""
    out: NDArray[np.float64] = degrees - 360.0 * np.round(degrees / 360.0)
    return out


def euler_degrees(rotation: Rotation, order: str) -> NDArray[np.float64]:
    """``rotation.as_euler(order, degrees=True)`` without scipy's warning at gimbal lock
    (there every split between the outer angles is the same rotation; scipy puts it all on
    the first)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Gimbal lock detected", category=UserWarning)
        angles: NDArray[np.float64] = rotation.as_euler(order, degrees=True)
    return angles


def _twin_states(angles: NDArray[np.float64], big: NDArray[np.bool_]) -> NDArray[np.intp]:
    """Per frame (F, ...), 0 for the given Tait–Bryan triple, 1 for its twin, choosing at each
    frame the one nearest (sum of wrapped differences) to the previous frame's choice; ``big``
    (F-1, ...) the steps that may take the twin (:func:`_big_steps`).

    The choice at frame i depends on frame i−1's only: a map of {0, 1} onto itself per frame.
    A map that sends both states to one decides the state by itself; the others keep or swap
    it. So a frame's state is that of the last deciding step before it (0 at the first frame),
    swapped once per swapping step since: two cumulative passes over the take."""
    maps = _twin_maps(angles, big)  # (F-1, ..., previous state): the next state
    deciding = maps[..., 0] == maps[..., 1]
    swaps = np.cumsum(maps[..., 0] & ~deciding, axis=0)
    step = np.arange(len(maps)).reshape(-1, *([1] * (maps.ndim - 2)))
    last = np.maximum.accumulate(np.where(deciding, step, -1), axis=0)
    at = np.maximum(last, 0)
    decided = np.where(last >= 0, np.take_along_axis(maps[..., 0], at, axis=0), False)
    since = swaps - np.where(last >= 0, np.take_along_axis(swaps, at, axis=0), 0)
    states = np.zeros(angles.shape[:-1], dtype=np.intp)
    states[1:] = decided ^ (since % 2 == 1)
    return states


SMALL_STEP_DEG: Final[float] = 90.0
"""Sum of the wrapped changes of a Tait–Bryan triple between two frames below which the
triple's twin is certainly further away (by at least 360° minus twice this, far beyond
rounding), so the step keeps whichever of the two the previous frame had."""


def _big_steps(wrapped: NDArray[np.float64]) -> NDArray[np.bool_]:
    """The steps (F-1, ...) whose wrapped changes ``wrapped`` (F-1, ..., 3) of the given
    triples sum to :data:`SMALL_STEP_DEG` or more: only these may take the twin."""
    big: NDArray[np.bool_] = np.abs(wrapped).sum(axis=-1) >= SMALL_STEP_DEG
    return big


def _twin_maps(angles: NDArray[np.float64], big_steps: NDArray[np.bool_]
               ) -> NDArray[np.bool_]:
    """Per step (F-1, ..., 2): from each state of the previous frame (0: the given triple,
    1: its twin), whether this frame is nearer as its twin (sum of wrapped differences).

    Only the ``big_steps`` (:func:`_big_steps`) are measured all four ways; every other step
    keeps the state (its twin is at least 270° off)."""
    maps = np.zeros((*big_steps.shape, 2), dtype=bool)
    maps[..., 1] = True
    big = np.nonzero(big_steps)
    if big[0].size:
        later = angles[1:][big]
        earlier = angles[:-1][big]
        cand_later = np.stack([later, _twin(later)], axis=-2)  # (B, 2, 3)
        cand_earlier = np.stack([earlier, _twin(earlier)], axis=-2)
        dist = np.abs(_wrap(cand_later[:, None, :, :] - cand_earlier[:, :, None, :])
                      ).sum(axis=-1)
        maps[big] = dist[..., 1] < dist[..., 0]
    return maps


def _twin(angles: NDArray[np.float64]) -> NDArray[np.float64]:
    """The other Tait–Bryan triple of each rotation: (a + 180, 180 − b, c + 180)."""
    twin: NDArray[np.float64] = angles + np.array([180.0, 0.0, 180.0])
    twin[..., 1] = 180.0 - angles[..., 1]
    return twin


def continuous_euler(angles: NDArray[np.float64]) -> NDArray[np.float64]:
    """Euler angles (F, ..., 3), degrees, without jumps between frames.

    Every intrinsic Tait–Bryan triple (a, b, c) of three distinct axes has a twin
    (a + 180, 180 − b, c + 180) describing the same rotation, and each angle is defined modulo
    360; per frame take the candidate nearest the previous frame, so that players
    interpolating channel values do not spin through wraps. Vectorised over frames (a prefix
    scan of the twin choice, then a cumulative sum of whole turns).

    Parameters
    ----------
    angles : ndarray, shape (F, ..., 3)
        Angles of any Tait–Bryan order, degrees, e.g. from ``Rotation.as_euler``.

    Returns
    -------
    ndarray, shape (F, ..., 3)
        The same rotations, each angle within 180 degrees of the previous frame's.
    """
    angles = np.asarray(angles, dtype=float)
    if len(angles) < 2:
        return angles.copy()
    change = angles[1:] - angles[:-1]
    turns = np.round(change / 360.0)
    big = _big_steps(change - 360.0 * turns)  # _wrap's operations: the wrapped change
    if not big.any():
        chosen = angles  # every step small (the usual case): no frame takes its twin
    else:
        states = _twin_states(angles, big)
        chosen = np.where(states[..., None] == 1, _twin(angles), angles)
        turns = np.round(np.diff(chosen, axis=0) / 360.0)
    out = chosen.copy()
    out[1:] -= 360.0 * np.cumsum(turns, axis=0)
    return out


def half_frame_error(rotation: Rotation, angles: NDArray[np.float64], order: str
                     ) -> NDArray[np.float64]:
    """How far channels interpolated at half frames turn from the true halfway rotation.

    A player that interpolates Euler channels linearly between keys (Blender's importer
    keys them) poses the node at ``angles(t) + ½ (angles(t+1) − angles(t))``; the rotation
    halfway along the shortest path from ``rotation[t]`` to ``rotation[t+1]`` is the one
    meant. Near gimbal lock (middle angle ±90°) the two differ by tens of degrees.

    Parameters
    ----------
    rotation : Rotation, length F
    angles : ndarray, shape (F, 3)
        ``rotation`` as continuous Euler angles of ``order``, degrees.
    order : str
        Intrinsic order such as ``"ZXY"``.

    Returns
    -------
    ndarray, shape (F - 1,)
        Angle between the interpolated and the halfway rotation, degrees.
    """
    if len(angles) < 2:
        return np.zeros(0)
    quats = rotation.as_quat()
    return _quat_angle(_euler_quaternions(order, (angles[:-1] + angles[1:]) / 2),
                       _halfway(quats[:-1], quats[1:]))


_UNIT_AXES: Final[dict[str, int]] = {"X": 0, "Y": 1, "Z": 2}


def _euler_quaternions(order: str, angles: NDArray[np.float64]) -> NDArray[np.float64]:
    """Scalar-last quaternions (S, 4) of intrinsic Euler angles (S, 3), degrees
    (``Rotation.from_euler(order, angles, degrees=True)``, without its overhead)."""
    half = np.radians(angles) / 2
    out = np.tile([0.0, 0.0, 0.0, 1.0], (len(angles), 1))
    for k, axis in enumerate(order):
        turn = np.zeros_like(out)
        turn[:, _UNIT_AXES[axis]] = np.sin(half[:, k])
        turn[:, 3] = np.cos(half[:, k])
        out = _quat_multiply(out, turn)
    return out


def _conjugate(q: NDArray[np.float64]) -> NDArray[np.float64]:
    out: NDArray[np.float64] = q * np.array([-1.0, -1.0, -1.0, 1.0])
    return out


def _quat_angle(p: NDArray[np.float64], q: NDArray[np.float64]) -> NDArray[np.float64]:
    """Degrees (S,) of the rotation from unit quaternions p to q (S, 4), scalar last."""
    rel = _quat_multiply(_conjugate(p), q)
    return np.asarray(np.degrees(2.0 * np.arctan2(rows.norms(rel[:, :3]),
                                                  np.abs(rel[:, 3]))))


def _halfway(p: NDArray[np.float64], q: NDArray[np.float64]) -> NDArray[np.float64]:
    """Quaternions (S, 4) halfway along the shortest path from p to q (S, 4)."""
    sign = np.where(np.einsum("ij,ij->i", p, q) < 0, -1.0, 1.0)
    mid = p + sign[:, None] * q
    out: NDArray[np.float64] = mid / np.maximum(rows.norms(mid), 1e-12)[:, None]
    return out


def jump_steps(rotations: list[Rotation], max_turn_deg: float = JUMP_DEG
               ) -> NDArray[np.bool_]:
    """Steps between frames where any of several rotations turns by more than
    ``max_turn_deg``: jumps in the data (a T-pose frame before the take), not motion.

    Parameters
    ----------
    rotations : list of Rotation
        Rotations of length F each (segment orientations, world frame).
    max_turn_deg : float
        Largest turn between two frames that counts as motion, degrees (:data:`JUMP_DEG`).

    Returns
    -------
    ndarray of bool, shape (F - 1,)
        True where step t → t + 1 is a jump.
    """
    if not rotations or len(rotations[0]) < 2:
        return np.zeros(0, dtype=bool)
    turns = np.stack([(r[:-1].inv() * r[1:]).magnitude() for r in rotations])
    return np.asarray(np.degrees(turns).max(axis=0) > max_turn_deg)


SWING_WEIGHT = 0.01
"""Weight of the squared channel swing against the squared half-frame error in the choice
of an Euler order: the swing (tens of degrees near gimbal lock) outweighed the half-frame
error 50:1 at equal weight and chose, for a dancer's shoulder, an order 2.3x further off at
half frames (9.2° against 4.0°); it now decides between orders that play back alike."""


PRUNE_STRIDE: Final[int] = 8
"""Every how many of a choice's steps a lower bound of an option's cost is summed over
(:func:`_least_option`): options the bounds rule out are not costed in full, the choice is
the same."""


@dataclass(frozen=True, eq=False)
class _Steps:
    """Steps between frames a choice is made on, as contiguous rows (x, y, z, w) of
    scalar-last unit quaternions: the rotations before and after (4, S), the turn (S,
    degrees), which steps are motion (not jumps) and the halfway rotations (4, S)."""

    before: NDArray[np.float64]
    after: NDArray[np.float64]
    turn: NDArray[np.float64]
    keep: NDArray[np.bool_]
    halfway: NDArray[np.float64]

    @classmethod
    def of(cls, before: NDArray[np.float64], after: NDArray[np.float64]) -> _Steps:
        """The steps from ``before`` to ``after`` (S, 4), unit quaternions, scalar last."""
        turn = _quat_angle(before, after)
        return cls(np.ascontiguousarray(before.T), np.ascontiguousarray(after.T), turn,
                   turn <= JUMP_DEG, np.ascontiguousarray(_halfway(before, after).T))

    def every(self, stride: int) -> _Steps:
        """Every ``stride``-th step, the same values."""
        return _Steps(np.ascontiguousarray(self.before[:, ::stride]),
                      np.ascontiguousarray(self.after[:, ::stride]), self.turn[::stride],
                      self.keep[::stride], np.ascontiguousarray(self.halfway[:, ::stride]))


def _step_cost(steps: _Steps, order: str) -> float:
    """Sum over the steps of the squared half-frame error and, weighted by ``SWING_WEIGHT``,
    the squared channel swing beyond the node's own turn (degrees²): both grow near gimbal
    lock. Steps turning more than :data:`JUMP_DEG` (jumps in the data) are left out."""
    before = euler_angle_rows(order, steps.before)
    after = _next_euler(before, euler_angle_rows(order, steps.after))
    change = np.abs(after - before)  # the greatest of three rows, without a reduction
    swing = np.maximum(np.maximum(np.maximum(change[0], change[1]), change[2]) - steps.turn,
                       0.0)
    half = _angle_between(_euler_rows(order, (before + after) / 2), steps.halfway)
    keep = steps.keep
    return float(np.sum(half[keep] ** 2) + SWING_WEIGHT * np.sum(swing[keep] ** 2))


def euler_angle_rows(order: str, quat: NDArray[np.float64]) -> NDArray[np.float64]:
    """Intrinsic Tait–Bryan angles of many rotations given as quaternion rows.

    scipy's method for ``Rotation.as_euler`` (Bernardes and Viollet 2022; at gimbal lock,
    within 1e-7 rad, the third angle is zero) with the middle angle as an arcsine and the
    outer ones left unwrapped, on contiguous rows: cheaper than :func:`euler_degrees` (about
    0.7 of its CPU time on 20,000 rotations, and no Rotation objects to build) for the
    Euler-order choice's many candidates.

    Parameters
    ----------
    order : str
        Intrinsic order of three distinct axes, e.g. ``"ZXY"``.
    quat : ndarray, shape (4, S)
        Rows x, y, z, w of unit quaternions (scalar last).

    Returns
    -------
    ndarray, shape (3, S)
        Angles in degrees, in ``order``: :func:`euler_degrees` up to rounding (1e-11°; 1e-6°
        next to gimbal lock) and whole turns (the outer angles within ±360°).
    """
    i, j, k = (_UNIT_AXES[axis] for axis in order[::-1])
    sign = (i - j) * (j - k) * (k - i) // 2
    w = quat[3]
    a, b = w - quat[j], quat[i] + sign * quat[k]
    c, d = quat[j] + w, sign * quat[k] - quat[i]
    half_sum, half_diff = np.arctan2(b, a), np.arctan2(d, c)
    near, far = a * a + b * b, c * c + d * d  # middle angle 2 atan2(√far, √near) − 90°
    # scipy's lock: the middle angle within 1e-7 rad of 0 or 180° (tan² 5e-8 = 2.5e-15)
    straight, reversed_ = far <= 2.5e-15 * near, near <= 2.5e-15 * far
    angles = np.empty((3, quat.shape[1]))
    angles[0] = sign * np.where(straight, 2.0 * half_sum,
                                np.where(reversed_, 2.0 * half_diff, half_sum + half_diff))
    angles[1] = np.arcsin(np.clip((far - near) / (far + near), -1.0, 1.0))
    angles[2] = np.where(straight | reversed_, 0.0, half_sum - half_diff)
    out: NDArray[np.float64] = np.degrees(angles)
    return out


def _euler_rows(order: str, angles: NDArray[np.float64]) -> NDArray[np.float64]:
    """:func:`_euler_quaternions` of angle rows (3, S), degrees, as rows (4, S) (x, y, z,
    w), each turn about one axis applied in closed form: the choice's hot loop, on
    contiguous rows."""
    half = np.radians(angles) / 2
    sin, cos = np.sin(half), np.cos(half)
    q = np.zeros((4, angles.shape[1]))
    q[_UNIT_AXES[order[0]]] = sin[0]
    q[3] = cos[0]
    for k in (1, 2):  # q · (sin · axis, cos)
        a = _UNIT_AXES[order[k]]
        b, c = (a + 1) % 3, (a + 2) % 3
        turned = np.empty_like(q)
        turned[a] = cos[k] * q[a] + sin[k] * q[3]
        turned[b] = cos[k] * q[b] + sin[k] * q[c]
        turned[c] = cos[k] * q[c] - sin[k] * q[b]
        turned[3] = cos[k] * q[3] - sin[k] * q[a]
        q = turned
    return q


def _angle_between(p: NDArray[np.float64], q: NDArray[np.float64]) -> NDArray[np.float64]:
    """:func:`_quat_angle` of unit quaternions given as rows (4, S) (x, y, z, w)."""
    px, py, pz, pw = p
    qx, qy, qz, qw = q
    vx = pw * qx - qw * px - (py * qz - pz * qy)
    vy = pw * qy - qw * py - (pz * qx - px * qz)
    vz = pw * qz - qw * pz - (px * qy - py * qx)
    w = px * qx + py * qy + pz * qz + pw * qw
    return np.asarray(np.degrees(2.0 * np.arctan2(np.sqrt(vx * vx + vy * vy + vz * vz),
                                                  np.abs(w))))


def _next_euler(before: NDArray[np.float64], after: NDArray[np.float64]
                ) -> NDArray[np.float64]:
    """``continuous_euler(np.stack([before, after]))[1]`` for many two-frame takes, as rows
    (3, S), at once: ``after`` or its twin, whichever is nearer ``before``, moved by whole
    turns to within 180° of it (the same operations, without the prefix scan's
    temporaries)."""
    twin = np.empty_like(after)
    twin[0], twin[1], twin[2] = after[0] + 180.0, 180.0 - after[1], after[2] + 180.0
    off_twin, off = np.abs(_wrap(twin - before)), np.abs(_wrap(after - before))
    near_twin = off_twin[0] + off_twin[1] + off_twin[2] < off[0] + off[1] + off[2]
    chosen = np.where(near_twin, twin, after)
    out: NDArray[np.float64] = chosen - 360.0 * np.round((chosen - before) / 360.0)
    return out


def _choice_steps(n_frames: int, max_steps: int = MAX_CHOICE_STEPS) -> NDArray[np.intp]:
    """First frames of the steps a choice is made on: every step, or ``max_steps`` evenly
    spread over the take."""
    if n_frames - 1 <= max_steps:
        return np.arange(max(n_frames - 1, 0))
    return np.unique(np.linspace(0, n_frames - 2, max_steps).astype(np.intp))


@dataclass(frozen=True, eq=False)
class NodeChannels:
    """Rotation channels of BVH nodes and the rest orientation each is written against.

    Attributes
    ----------
    channels : tuple of tuple of str
        Per node, e.g. ``("Xrotation", "Zrotation", "Yrotation")``.
    values : ndarray, shape (F, N, 3)
        Degrees in channel order, continuous over frames (:func:`continuous_euler`).
    rest : ndarray, shape (N, 4)
        Per node, the constant rotation ``C`` from the node's BVH frame to the frame its
        given rotation is of (scalar-last quaternion): the node's world orientation in the
        file is ``given(t) · C``; identity where the given frame is kept.
    """

    channels: tuple[tuple[str, ...], ...]
    values: NDArray[np.float64]
    rest: NDArray[np.float64]


def _orders(order: str | None) -> tuple[str, ...]:
    if order is not None and order not in EULER_ORDERS:
        raise InputError(f"Euler order must be one of {', '.join(EULER_ORDERS)}, got "
                         f"{order!r}", field="euler_order")
    return EULER_ORDERS if order is None else (order,)


def _best_channels(seen: NDArray[np.float64], orders: tuple[str, ...], centre: bool
                   ) -> tuple[NDArray[np.float64], str]:
    """The rest rotation (identity, or the inverse of the mean of ``seen`` (F, 4), scalar
    last) and the Euler order whose channels of ``seen · rest`` cost least
    (:func:`_step_cost`, ties to the first)."""
    from scipy.spatial.transform import Rotation

    rests = [np.array([0.0, 0.0, 0.0, 1.0])]
    if centre and len(seen) > 1:
        rests.append(Rotation.from_quat(seen).mean().inv().as_quat())
    first = _choice_steps(len(seen))
    if len(first) == 0:
        return rests[0], orders[0]
    steps = [_Steps.of(_quat_multiply(seen[first], rest[None]),
                       _quat_multiply(seen[first + 1], rest[None])) for rest in rests]
    options = [(rest, order) for rest in rests for order in orders]
    return options[_least_option(steps, orders)]


def _least_option(steps: list[_Steps], orders: tuple[str, ...]) -> int:
    """Index (rest-major) of the option (steps of a rest rotation, order) the choice takes:
    the first whose :func:`_step_cost` is within a tie (0.1 %, plus 1e-9) of the least.

    Options are costed in full only until that is decided: each one's cost summed over every
    :data:`PRUNE_STRIDE`-th step is a lower bound (no term is negative), so an option whose
    bound exceeds a tie of a cost already known cannot be taken, and a known cost within a
    tie of every bound and cost is taken if no earlier option can be."""
    options = [(k, order) for k in range(len(steps)) for order in orders]
    coarse = [s.every(PRUNE_STRIDE) for s in steps]
    # the margin covers rounding: a bound sums a subset of the same terms
    bound = np.array([_step_cost(coarse[k], order) for k, order in options]) * (1.0 - 1e-6)
    cost = np.full(len(options), np.nan)  # nan: not costed yet
    while True:
        known = ~np.isnan(cost)
        tie = (np.min(cost[known]) if known.any() else np.inf) * 1.001 + 1e-9
        out = np.where(known, cost > tie, bound > tie * (1.0 + 1e-6))
        first = int(np.argmin(out))
        least = np.min(np.where(known, cost, bound))
        if known[first] and cost[first] <= least * 1.001 + 1e-9:
            return first
        if known[first]:
            first = int(np.argmin(np.where(known, np.inf, bound)))
        cost[first] = _step_cost(steps[options[first][0]], options[first][1])


def rest_euler_channels(parents: tuple[int, ...] | list[int],
                        rotations: list[Rotation] | list[NDArray[np.float64]],
                        order: str | None = None, *, centre: bool = True,
                        out: NDArray[np.float64] | None = None) -> NodeChannels:
    """BVH rotation channels of a tree of nodes, with an Euler order and a constant rest
    rotation per node chosen so that players interpolating the channels follow the motion.

    Node n's channels hold ``L(t) = C_pᵀ · given(t) · C_n`` (``C_p`` its parent's rest
    rotation, identity for the root). ``C_n`` is identity (the given frame) or, with
    ``centre``, the inverse of the mean of ``C_pᵀ · given(t)`` over the take, which centres
    the channels on zero: the middle angle then stays within the node's swing about its mean
    pose from ±90°, gimbal lock. Of the two rest rotations and the six orders of
    :data:`EULER_ORDERS` (or ``order``), each node, parents first, takes the one with the
    least sum of the squared :func:`half_frame_error` plus ``SWING_WEIGHT`` times the squared
    channel swing beyond the node's turn, over the steps of the take that are not jumps
    (:data:`JUMP_DEG`; at most :data:`MAX_CHOICE_STEPS` steps, evenly sampled); ties within
    0.1 % go to the given frame and the first order listed. From ``threads.MIN_FRAMES``
    frames the nodes are handled on ``threads.workers()`` threads, each node once its
    parent's rest rotation is chosen.

    Parameters
    ----------
    parents : sequence of int
        Parent of each node (an earlier index), -1 for a root.
    rotations : list of Rotation or of ndarray, shape (F, 4)
        Per node, its rotation (length F) relative to its parent's given frame (a Rotation
        or its scalar-last unit quaternions).
    order : str, optional
        One intrinsic order for every node instead of the choice per node.
    centre : bool
        Whether rest rotations other than identity may be chosen.
    out : ndarray, shape (F, N, 3), optional
        Where to write the channel values (every one is written), e.g. a view of a BVH's
        table of values; by default a new array.

    Returns
    -------
    NodeChannels

    Raises
    ------
    InputError
        If ``order`` is not one of :data:`EULER_ORDERS`, or a parent does not come before
        its node.

    Notes
    -----
    A player keys each channel and interpolates it linearly; the midpoint of two keys turns
    away from the shortest-path halfway rotation by an amount that grows with the Euler
    chart's curvature, unbounded at gimbal lock (Shoemake, "Animating rotation with
    quaternion curves", SIGGRAPH 1985). A constant change of each node's frame (a rest
    pose) moves the take into the well-conditioned part of the chart.
    """
    orders = _orders(order)
    if any(not -1 <= p < n for n, p in enumerate(parents)):
        raise InputError("each node's parent must come before it (or be -1)", field="parents")
    n_frames = len(rotations[0]) if rotations else 0
    values = np.zeros((n_frames, len(rotations), 3)) if out is None else out
    rests: list[Future[NDArray[np.float64]]] = [Future() for _ in rotations]
    choose = _NodeChoice(tuple(parents), rotations, orders, centre, values, rests)
    if n_frames >= MIN_FRAMES and workers() > 1 and len(rotations) > 1:
        by_depth = _by_depth(parents)
        with ThreadPoolExecutor(workers(), thread_name_prefix="bonefit-euler") as pool:
            found = dict(zip(by_depth, pool.map(choose, by_depth), strict=True))
        chosen = [found[n] for n in range(len(rotations))]
    else:
        chosen = [choose(n) for n in range(len(rotations))]
    return NodeChannels(channels=tuple(tuple(f"{axis}rotation" for axis in o) for o in chosen),
                        values=values,
                        rest=np.array([r.result() for r in rests]).reshape(-1, 4))


def _by_depth(parents: tuple[int, ...] | list[int]) -> list[int]:
    """Nodes (parents before children) ordered by depth in their tree, then index: on two
    threads taking them in turn, a node's parent is chosen by the time it is reached more
    often than in tree order, where a node mostly follows its parent."""
    depth: list[int] = []
    for p in parents:
        depth.append(depth[p] + 1 if p >= 0 else 0)
    return sorted(range(len(parents)), key=depth.__getitem__)


@dataclass(frozen=True, eq=False)
class _NodeChoice:
    """:func:`rest_euler_channels` node by node: each node's rest rotation and order are
    chosen once its parent's rest rotation is known (``rests``, futures set by the parent's
    call), then its channels are written into ``values``. Called parents first, on a pool
    whose threads take the calls in that order, a call waits only for a parent's that is
    running: on a long take the nodes of different branches overlap."""

    parents: tuple[int, ...]
    rotations: list[Rotation] | list[NDArray[np.float64]]
    orders: tuple[str, ...]
    centre: bool
    values: NDArray[np.float64]
    rests: list[Future[NDArray[np.float64]]]

    def __call__(self, n: int) -> str:
        """Choose node ``n``'s rest rotation (setting ``rests[n]``) and order, write its
        channels; returns the order."""
        try:
            parent = self.parents[n]
            above = self.rests[parent].result() if parent >= 0 else np.array(
                [0.0, 0.0, 0.0, 1.0])
            rotation = self.rotations[n]
            given = rotation if isinstance(rotation, np.ndarray) else rotation.as_quat()
            seen = _quat_multiply(_conjugate(above)[None], given)
            rest, best = _best_channels(seen, self.orders, self.centre)
        except BaseException as error:  # the children waiting for this rest fail too
            self.rests[n].set_exception(error)
            raise
        self.rests[n].set_result(rest)
        _put_channels(self.values[:, n], seen, rest, best)
        return best


def _put_channels(out: NDArray[np.float64], seen: NDArray[np.float64],
                  rest: NDArray[np.float64], order: str) -> None:
    """Write into ``out`` (F, 3) the continuous channels of ``order`` of the rotations
    ``seen · rest`` (``seen`` (F, 4) and ``rest`` (4,), scalar-last quaternions)."""
    from scipy.spatial.transform import Rotation

    local = Rotation.from_quat(_quat_multiply(seen, rest[None]))
    out[...] = continuous_euler(euler_degrees(local, order))


def euler_channels(rotations: list[Rotation], order: str | None = None
                   ) -> tuple[list[tuple[str, ...]], NDArray[np.float64]]:
    """BVH rotation channels of several nodes' local rotations, an Euler order per node.

    Each node gets the order of :data:`EULER_ORDERS` whose channels follow the motion best
    (:func:`rest_euler_channels` without rest rotations): that puts a knee's or elbow's
    flexion on an outer axis, never on the middle one, whose ±90° is gimbal lock: there the
    outer channels swing by up to 180° while the joint turns a few degrees, and players
    interpolating them go astray.

    Parameters
    ----------
    rotations : list of Rotation
        Local rotations (parent node frame ← node frame) of N nodes, each of length F.
    order : str, optional
        One intrinsic order for every node (e.g. ``"ZXY"``) instead of the choice per node.

    Returns
    -------
    channels : list of tuple of str
        Per node, e.g. ``("Xrotation", "Zrotation", "Yrotation")``.
    values : ndarray, shape (F, N, 3)
        Degrees in channel order, continuous over frames (:func:`continuous_euler`).
    """
    out = rest_euler_channels([-1] * len(rotations), rotations, order, centre=False)
    return list(out.channels), out.values


def euler_order_for(rotation: Rotation) -> str:
    """The Euler order :func:`euler_channels` gives a node turning by ``rotation`` (F)."""
    channels, _ = euler_channels([rotation])
    return "".join(c[0] for c in channels[0])


def rigid_tree(positions: NDArray[np.float64], root: int, *, max_frames: int = 2000
               ) -> list[int]:
    """A joint tree whose bones keep their length: parent index per joint.

    Prim's spanning tree grown from ``root``: each step adds the joint whose distance to a
    joint already in the tree varies least over the take, attached to the earliest joint
    (in ``positions`` order) whose distance to it is as rigid. Joints of one rigid segment
    (a pelvis with its hips, a chest with its shoulders and neck) hang from the segment's
    first joint, as a suit's own skeleton lists them.

    Parameters
    ----------
    positions : ndarray, shape (F, J, 3)
        Joint positions, any length unit.
    root : int
        Index of the root joint.
    max_frames : int
        Frames sampled evenly to measure distances (memory is F × J² values).

    Returns
    -------
    list of int
        Parent of each joint, -1 for ``root``.
    """
    n_frames, n_joints = positions.shape[:2]
    sample = positions[np.unique(np.linspace(0, n_frames - 1, min(n_frames, max_frames))
                                 .astype(int))]
    dist = np.linalg.norm(sample[:, :, None] - sample[:, None], axis=-1)
    spread = np.ptp(dist, axis=0)
    # a variation below 1e-5 of the typical distance is rounding: call it rigid
    spread[spread <= 1e-5 * max(float(np.median(dist.mean(axis=0))), 1e-12)] = 0.0
    parents = [-1] * n_joints
    inside = [root]
    outside = [j for j in range(n_joints) if j != root]
    while outside:
        _, parent, child = min((float(spread[u, v]), u, v)
                               for v in outside for u in inside)
        parents[child] = parent
        inside.append(child)
        outside.remove(child)
    return parents


def aiming_rotations(vectors: NDArray[np.float64]) -> tuple[NDArray[np.float64],
                                                            NDArray[np.float64]]:
    """World rotations that carry fixed rest vectors onto moving bone vectors.

    Each rotation starts at identity and each frame turns by the shortest arc from the
    previous frame's direction to this frame's (parallel transport), so it has no flip
    wherever the bone points and is continuous over the take.

    Parameters
    ----------
    vectors : ndarray, shape (F, B, 3)
        Bone vectors (child − parent) per frame, world frame.

    Returns
    -------
    quaternions : ndarray, shape (F, B, 4)
        Scalar-last unit quaternions; rotation ``[t, b]`` carries ``rest[b]`` along
        ``vectors[t, b]``.
    rest : ndarray, shape (B, 3)
        Rest vectors: each bone's first non-zero direction scaled to its mean length.
    """
    length = np.linalg.norm(vectors, axis=-1)
    valid = length > 1e-9 * max(float(length.max(initial=0.0)), 1.0)
    unit = np.where(valid[..., None], vectors / np.where(valid, length, 1.0)[..., None], 0.0)
    n_frames, n_bones = vectors.shape[:2]
    bones = np.arange(n_bones)
    direction = np.where(valid.any(axis=0)[:, None], unit[np.argmax(valid, axis=0), bones],
                         [0.0, 1.0, 0.0])
    # the direction each frame turns from: the last valid one before it (forward filled)
    last = np.maximum.accumulate(np.where(valid, np.arange(n_frames)[:, None], -1), axis=0)
    before = np.concatenate([np.full((1, n_bones), -1), last[:-1]])
    prev = np.where((before >= 0)[..., None], unit[np.maximum(before, 0), bones], direction)
    steps = _shortest_arc(prev.reshape(-1, 3), unit.reshape(-1, 3)).reshape(-1, n_bones, 4)
    steps[~valid] = [0.0, 0.0, 0.0, 1.0]
    return _cumulative_product(steps), direction * length.mean(axis=0)[:, None]


def _cumulative_product(steps: NDArray[np.float64]) -> NDArray[np.float64]:
    """Quaternions (F, B, 4), scalar last: ``out[t] = steps[t] · … · steps[0]``, by a prefix
    scan in log₂ F vectorised products (renormalised after each)."""
    out = steps.copy()
    span = 1
    while span < len(out):
        later, earlier = out[span:].reshape(-1, 4), out[:-span].reshape(-1, 4)
        product = _quat_multiply(later, earlier)
        product /= np.linalg.norm(product, axis=-1, keepdims=True)
        out[span:] = product.reshape(out[span:].shape)
        span *= 2
    return out


def _shortest_arc(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Scalar-last quaternions (N, 4) turning unit vectors a onto unit vectors b (N, 3)."""
    cos = np.einsum("ij,ij->i", a, b)
    q = np.concatenate([np.cross(a, b), (1.0 + cos)[:, None]], axis=1)
    opposite = 1.0 + cos < 1e-12
    if opposite.any():  # half turn about any axis perpendicular to a
        helper = np.where(np.abs(a[opposite, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
        q[opposite] = np.concatenate([np.cross(a[opposite], helper),
                                      np.zeros((int(opposite.sum()), 1))], axis=1)
    unit: NDArray[np.float64] = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return unit


def _quat_multiply(p: NDArray[np.float64], q: NDArray[np.float64]) -> NDArray[np.float64]:
    """Hamilton products p·q of scalar-last quaternions (N, 4) (either may be (1, 4)).

    Component by component (``pw qv + qw pv + pv × qv``, ``pw qw − pv · qv`` in that order of
    operations, so the same bits as with ``np.cross``, whose overhead was most of the cost)."""
    out = _vector_parts(p, q)
    out[:, 3] = p[:, 3] * q[:, 3] - np.einsum("...j,...j->...", p[:, :3], q[:, :3])
    return out


def _vector_parts(p: NDArray[np.float64], q: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, 4) holding the vector parts ``pw qv + qw pv + pv × qv`` of the products p·q, the
    scalar part left for the caller (whose order of operations sets its last bits)."""
    n = max(len(p), len(q))
    out = np.empty((n, 4))
    first, second, third = np.empty(n), np.empty(n), np.empty(n)
    for k in range(3):  # into three reused temporaries, the same operations in order
        i, j = (k + 1) % 3, (k + 2) % 3
        np.multiply(p[:, 3], q[:, k], out=first)
        first += np.multiply(q[:, 3], p[:, k], out=second)
        np.multiply(p[:, i], q[:, j], out=second)
        second -= np.multiply(p[:, j], q[:, i], out=third)
        np.add(first, second, out=out[:, k])
    return out


def compose_quaternions(p: NDArray[np.float64], q: NDArray[np.float64]
                        ) -> NDArray[np.float64]:
    """Rotations ``p · q`` (``q`` first) of scalar-last unit quaternions (N, 4) (either may
    be (1, 4)), normalised.

    The same formula and normalisation as scipy's ``Rotation.__mul__``: bit for bit
    ``(P * Q).as_quat()`` for Rotations P, Q holding ``p`` and ``q``, without the cost of
    building Rotation objects (most of a long take's BVH hierarchy).
    """
    px, py, pz, pw = p.T
    qx, qy, qz, qw = q.T
    out = _vector_parts(p, q)
    out[:, 3] = pw * qw - px * qx - py * qy - pz * qz
    out /= rows.norms(out)[:, None]
    return out


def bone_waypoints(start: NDArray[np.float64], end: NDArray[np.float64], *,
                   rigid_rtol: float = 1e-4) -> list[NDArray[np.float64]]:
    """Points a chain of fixed-length links passes through from ``start`` to ``end``.

    A rigid bone is one link; a bone whose length varies (a CSV holding only hips and
    feet) is two equal links of ``0.525 × its longest length`` bent at a middle point on a
    side chosen once for the take (the world axis the bone is least aligned with), so the
    chain reaches every length with rotations alone.

    Parameters
    ----------
    start, end : ndarray, shape (F, 3)
        Positions of the parent and child joints.
    rigid_rtol : float
        Length range, relative to the mean length, below which the bone counts as rigid.

    Returns
    -------
    list of ndarray, shape (F, 3)
        ``[start, end]`` or ``[start, middle, end]``.
    """
    bone = end - start
    length = np.linalg.norm(bone, axis=-1)
    if float(np.ptp(length)) <= rigid_rtol * max(float(length.mean()), 1e-12):
        return [start, end]
    link = 0.525 * float(length.max())
    unit = bone / np.maximum(length, 1e-12)[:, None]
    side = np.eye(3)[int(np.argmin(np.abs(unit).max(axis=0)))]
    normal = side - np.einsum("ij,j->i", unit, side)[:, None] * unit
    normal /= np.maximum(np.linalg.norm(normal, axis=-1), 1e-12)[:, None]
    height = np.sqrt(np.maximum(link ** 2 - (length / 2) ** 2, 0.0))
    return [start, start + bone / 2 + height[:, None] * normal, end]


@dataclass
class _PointNodes:
    """The nodes of a point-joint BVH as they are added: names, parents, OFFSETs, world and
    local rotations (length F each) and which nodes are end sites."""

    names: list[str] = field(default_factory=list)
    parents: list[int] = field(default_factory=list)
    offsets: list[NDArray[np.float64]] = field(default_factory=list)
    world: list[Rotation] = field(default_factory=list)
    local: list[Rotation] = field(default_factory=list)
    end_sites: set[int] = field(default_factory=set)

    def add(self, name: str, parent: int, offset: NDArray[np.float64], rot: Rotation) -> int:
        """Append a node turning to world rotation ``rot``; returns its index."""
        self.names.append(name)
        self.parents.append(parent)
        self.offsets.append(offset)
        self.local.append(rot if parent < 0 else self.world[parent].inv() * rot)
        self.world.append(rot)
        return len(self.names) - 1

    def turn(self, node: int, rot: Rotation) -> None:
        """Make node ``node`` (no children yet) turn to world rotation ``rot``."""
        parent = self.parents[node]
        self.world[node] = rot
        self.local[node] = rot if parent < 0 else self.world[parent].inv() * rot


@dataclass(frozen=True, eq=False)
class _Bones:
    """The bones of a point-joint tree: children per joint, the waypoints of each bone
    (:func:`bone_waypoints`) and the aiming rotation and rest vector of each leg between
    waypoints (:func:`aiming_rotations`), keyed by ((joint, child), leg)."""

    kids: dict[int, list[int]]
    points: dict[tuple[int, int], list[NDArray[np.float64]]]
    aims: dict[tuple[tuple[int, int], int], tuple[Rotation, NDArray[np.float64]]]


def _point_bones(positions: NDArray[np.float64], tree: list[int]) -> _Bones:
    """Waypoints and aiming rotations of the bones of ``tree`` (parent per joint)."""
    from scipy.spatial.transform import Rotation

    kids: dict[int, list[int]] = {j: [] for j in range(len(tree))}
    for j, p in enumerate(tree):
        if p >= 0:
            kids[p].append(j)
    edges = [(j, k) for j in range(len(tree)) for k in kids[j]]
    points = {edge: bone_waypoints(positions[:, edge[0]], positions[:, edge[1]])
              for edge in edges}
    legs = [(edge, i) for edge in edges for i in range(len(points[edge]) - 1)]
    if not legs:
        return _Bones(kids, points, {})
    quats, rests = aiming_rotations(np.stack([points[e][i + 1] - points[e][i]
                                              for e, i in legs], axis=1))
    aims = {leg: (Rotation.from_quat(quats[:, n]), rests[n]) for n, leg in enumerate(legs)}
    return _Bones(kids, points, aims)


def _grow_point_nodes(nodes: _PointNodes, bones: _Bones, names: tuple[str, ...],
                      joint: int, node: int) -> None:
    """Add the nodes below ``joint`` (already node ``node``): a pivot per child where the
    joint has several, a ``_bend`` node where a bone's length varies, the child, and an end
    site under a leaf."""
    kids = bones.kids[joint]
    for k in kids:
        aim, rest = bones.aims[((joint, k), 0)]
        holder = node
        if len(kids) > 1:
            holder = nodes.add(f"{names[joint]}_to_{names[k]}", node, np.zeros(3), aim)
        else:
            nodes.turn(node, aim)
        if len(bones.points[(joint, k)]) == 3:
            bend, rest_bend = bones.aims[((joint, k), 1)]
            holder, rest = nodes.add(f"{names[k]}_bend", holder, rest, bend), rest_bend
        _grow_point_nodes(nodes, bones, names, k,
                          nodes.add(names[k], holder, rest, nodes.world[holder]))
    if not kids:
        nodes.end_sites.add(nodes.add(f"{names[joint]}_end", node, np.zeros(3),
                                      nodes.world[node]))


def point_joint_bvh(names: tuple[str, ...], positions: NDArray[np.float64], root: int,
                    frame_time: float) -> BvhMotion:
    """A BVH of joints known only by their positions, with rotation channels only.

    Every BVH reader agrees on a hierarchy whose root alone has position channels (OFFSET
    zero) and whose other joints have rotation channels and constant OFFSETs; readers
    disagree on position channels below the root (three.js adds them to OFFSET, Blender
    replaces OFFSET by them; pybvh and bvhtoolbox reject them). So the joints are put in a
    tree of near-rigid distances (:func:`rigid_tree`) and turned: a joint with one child
    turns to point at it; a joint with several children keeps its parent's orientation and
    holds one pivot node ``<joint>_to_<child>`` per child (OFFSET zero) that points at that
    child; a leaf joint has an ``End Site`` at zero OFFSET. OFFSETs are the first frame's
    bone vectors; a bone whose length varies gets a middle node ``<child>_bend``
    (:func:`bone_waypoints`). Every joint lands on its given position (to the file's
    rounding) whatever the data.

    Parameters
    ----------
    names : tuple of str
        Joint names, length J.
    positions : ndarray, shape (F, J, 3)
        Joint positions in the file's length unit, world frame.
    root : int
        Index of the root joint (its position channels carry its path).
    frame_time : float
        Seconds per frame.

    Returns
    -------
    BvhMotion
        Root first with ``X/Y/Zposition`` and three rotation channels; every joint named as
        in ``names``, pivots, bends and end sites added. Rotation orders per node by
        :func:`euler_order_for`, channels continuous.
    """
    from scipy.spatial.transform import Rotation

    n_frames = positions.shape[0]
    nodes = _PointNodes()
    _grow_point_nodes(nodes, _point_bones(positions, rigid_tree(positions, root)), names,
                      root, nodes.add(names[root], -1, np.zeros(3),
                                      Rotation.identity(n_frames)))
    turning = [i for i in range(len(nodes.names)) if i not in nodes.end_sites]
    rot_channels, angles = euler_channels([nodes.local[i] for i in turning])
    channels: list[tuple[str, ...]] = [()] * len(nodes.names)
    for i, chans in zip(turning, rot_channels, strict=True):
        channels[i] = chans
    channels[0] = ("Xposition", "Yposition", "Zposition", *channels[0])
    values = [positions[:, root], angles.reshape(n_frames, -1)]
    return BvhMotion(tuple(nodes.names), tuple(nodes.parents),
                     np.asarray(nodes.offsets, dtype=float), tuple(channels),
                     float(frame_time), np.concatenate(values, axis=1))


def fold_position_channels(motion: BvhMotion, *, atol: float = 1e-6) -> BvhMotion:
    """The same motion written so that every BVH reader places the joints alike.

    Readers disagree on a joint that has both an OFFSET and position channels: Blender and
    bonefit replace the OFFSET by the channels, three.js adds them, pybvh and bvhtoolbox
    reject position channels below the root. Position channels that stay constant over the
    take are folded into the OFFSET (Bandai files carry them on every joint, equal to the
    OFFSET); a joint whose position channels move, and the root, keep them with a zero
    OFFSET, where replacing and adding agree. Positions under the replacing reading are
    unchanged.

    Parameters
    ----------
    motion : BvhMotion
    atol : float
        Largest change over the take, in file units, of a position channel called constant.

    Returns
    -------
    BvhMotion
    """
    offsets = motion.offsets.copy()
    channels: list[tuple[str, ...]] = []
    keep: list[int] = []
    for j, chans in enumerate(motion.channels):
        start = motion._starts[j]
        vals = motion.channel_values(j)
        pos = [k for k, c in enumerate(chans) if c in _AXES]
        constant = bool(pos) and motion.parents[j] >= 0 and \
            float(np.ptp(vals[:, pos], axis=0).max()) <= atol
        for k, c in enumerate(chans):
            if c in _AXES and constant:
                offsets[j, _AXES[c]] = vals[0, k]
            else:
                keep.append(start + k)
        if pos and not constant:
            offsets[j, [_AXES[chans[k]] for k in pos]] = 0.0
        channels.append(tuple(c for c in chans if not (constant and c in _AXES)))
    return BvhMotion(motion.names, motion.parents, offsets, tuple(channels),
                     motion.frame_time, motion.values[:, keep])


SLIP_TOL_M: Final[float] = 1e-6
"""Largest distance (metres) between a joint and where a rigid skeleton would put it that a
BVH writer leaves to the rigid skeleton (a micrometre: below the files' rounding)."""

SLIP_NODES: Final[tuple[str, ...]] = ("slip_base", "slip_bend", "slip_tip")
"""Suffixes of the three nodes of a joint's :class:`SlipChain` (``<joint>_slip_base`` …)."""


def is_slip_node(name: str) -> bool:
    """Whether node ``name`` belongs to a slip chain (it carries a joint; it is none)."""
    return name.endswith(tuple(f"_{suffix}" for suffix in SLIP_NODES))


_CYCLIC: Final[dict[int, str]] = {0: "YZX", 1: "ZXY", 2: "XYZ"}
"""Euler order of a slip chain's base and bend nodes, by the axis (x, y, z) they bend about,
which comes last."""


@dataclass(frozen=True, eq=False)
class SlipChain:
    """Three rotation-only nodes that carry a joint off its rigid place.

    The chain hangs from the joint's parent node: ``base`` at OFFSET ``offset − reach``
    (``offset`` the joint's rigid OFFSET), ``bend`` at OFFSET ``links[0]`` under it, ``tip``
    at OFFSET ``links[1]`` under that, and the joint at OFFSET zero under ``tip``. ``base``
    turns the two links, ``bend`` bends them about one axis, and ``tip``'s channels undo
    both exactly (the same angles negated in reverse order), at the frames and at any
    linear interpolation of the channels between them: the joint's own channels, and
    everything below it, turn as they would without the chain.

    Attributes
    ----------
    reach : ndarray, shape (3,)
        Constant part of the span, parent node frame, the residual's unit.
    links : ndarray, shape (2, 3)
        OFFSETs of ``bend`` (in ``base``'s frame) and ``tip`` (in ``bend``'s frame).
    orders : tuple of str
        Intrinsic Euler orders of ``base``, ``bend`` and ``tip``'s channels.
    values : ndarray, shape (F, 3, 3)
        Channel values of ``base``, ``bend`` and ``tip``, degrees, continuous over frames.
    """

    reach: NDArray[np.float64]
    links: NDArray[np.float64]
    orders: tuple[str, str, str]
    values: NDArray[np.float64]


def slip_chain(residual: NDArray[np.float64], direction: NDArray[np.float64]) -> SlipChain:
    """The :class:`SlipChain` that puts a joint ``residual`` off its rigid place.

    Every BVH reader agrees on rotation channels under constant OFFSETs, and disagrees on
    position channels below the root (Blender and bvhio replace the OFFSET by them, three.js
    adds them, bvhtoolbox keeps the OFFSET, pybvh refuses the file): so a joint whose
    distance to its parent varies (an estimate's noise and slip) is reached by two links of
    length ``r = 2 E`` (``E`` the residual's largest norm) spanning ``reach + residual``,
    ``|reach| = r``, in the plane of the parent frame's axis least along the bone: the span
    stays within 30° of ``reach`` and between ``r / 2`` and ``3 r / 2`` long, so the bend
    (120° at rest) stays between 83° and 151°. ``bend`` sets the span's length, ``base``
    turns it by the shortest arc onto its direction.

    Parameters
    ----------
    residual : ndarray, shape (F, 3)
        The joint's position minus its rigid position, in the parent node's frame; not all
        zero.
    direction : ndarray, shape (3,)
        The bone (parent to joint), parent node frame: ``reach`` is its part across the
        bend axis.

    Returns
    -------
    SlipChain
    """
    from scipy.spatial.transform import Rotation

    largest = float(np.linalg.norm(residual, axis=1).max())
    if not largest > 0.0:
        raise InputError("a slip chain needs a residual that is not zero everywhere",
                         field="residual")
    axis, along, across = _slip_plane(direction)
    link = 2.0 * largest
    span = link * along + residual
    length = np.linalg.norm(span, axis=1)
    bend = 120.0 - 2.0 * np.degrees(np.arccos(length / (2.0 * link)))
    half = np.radians(bend / 2.0)[:, None]
    rest_span = np.cos(half) * along + np.sin(half) * across
    values = np.zeros((len(span), 3, 3))
    values[:, 0] = continuous_euler(euler_degrees(
        Rotation.from_quat(_shortest_arc(rest_span, span / length[:, None])), _CYCLIC[axis]))
    values[:, 1, 2] = bend
    values[:, 2] = -values[:, 0, ::-1]
    values[:, 2, 0] -= bend
    links = link * np.array([0.5 * along + 0.75 ** 0.5 * across,
                             0.5 * along - 0.75 ** 0.5 * across])
    return SlipChain(reach=link * along, links=links,
                     orders=(_CYCLIC[axis], _CYCLIC[axis], _CYCLIC[axis][::-1]),
                     values=values)


def _slip_plane(direction: NDArray[np.float64]
                ) -> tuple[int, NDArray[np.float64], NDArray[np.float64]]:
    """The axis (0, 1, 2) a slip chain bends about (the one least along ``direction``), the
    unit direction of its reach (``direction`` across that axis) and the unit vector
    ``axis × reach``."""
    size = np.abs(direction)
    axis = int(np.argmin(size)) if np.isfinite(size).all() else 1
    along = np.where(np.arange(3) == axis, 0.0, direction)
    if not np.linalg.norm(along) > 1e-12 * max(float(size.max()), 1e-300):
        along = np.eye(3)[(axis + 1) % 3]
    along = along / np.linalg.norm(along)
    return axis, along, np.cross(np.eye(3)[axis], along)
