"""Writers (JSON, CSV, BVH) and JSON file readers of skeleton results (the document
readers, numpy only, are in ``io.result_json`` and importable from here).

The JSON layout is a contract for scripted clients and is documented in
``docs/skeleton-io.md``; the BVH hierarchy is rooted at the ``root`` joint with one node per
joint, driven by the orientation of the segment that joint moves, and a clavicle node above
each shoulder.
"""

from __future__ import annotations

import functools
import io
import itertools
import json
import math
import os
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Final, TypeVar

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from .. import _rows as rows
from ..bvh import (
    SLIP_NODES,
    SLIP_TOL_M,
    BvhMotion,
    NodeChannels,
    SlipChain,
    compose_quaternions,
    rest_euler_channels,
    slip_chain,
    write_bvh,
)
from ..errors import InputError
from ..model import BVH_TREE, JOINTS
from ..numtext import (
    JsonArray,
    JsonLater,
    array_values,
    fixed_blocks,
    json_blocks,
    plain,
    write_text_blocks,
)
from ..progress import Progress, no_progress
from ..results import JointOffset, SkeletonResult, timings_document
from ..rigid import clavicle_heights, clavicle_points
from ..threads import Report, run_each
from .outputs import SkeletonOutputs
from .result_json import SKELETON_KIND, offsets_to_dict
from .result_json import offsets_from_dict as offsets_from_dict  # documented here too
from .result_json import skeleton_from_dict as skeleton_from_dict
from .result_npz import read_document_npz, write_document_npz
from .sensor_common import unit_scale

PathLike = str | os.PathLike[str]
_T = TypeVar("_T")

BVH_NODES: Final[tuple[tuple[str, str | None, str], ...]] = BVH_TREE
"""BVH joints as (node, parent node, segment whose orientation drives it), parents first."""

END_SITES: Final[dict[str, tuple[str, tuple[float, float, float], float]]] = {
    "neck": ("head", (0.0, 1.0, 0.0), 0.20),
    "l_wrist": ("l_hand", (0.0, -1.0, 0.0), 0.08),
    "r_wrist": ("r_hand", (0.0, -1.0, 0.0), 0.08),
    "l_ankle": ("l_foot", (0.0, 0.0, 1.0), 0.15),
    "r_ankle": ("r_foot", (0.0, 0.0, 1.0), 0.15),
}
"""End sites (head top, hand, toe) as node → (segment, direction in the segment frame,
default length in metres). The length is ``bone_lengths[segment]`` when the result has it."""

ROOT_POSITION_CHANNELS: Final[tuple[str, ...]] = ("Xposition", "Yposition", "Zposition")


# --------------------------------------------------------------------------- JSON


def _json_safe(value: Any) -> Any:
    """Plain JSON types: numpy scalars and arrays converted, NaN/inf → None."""
    if isinstance(value, Mapping):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return _json_safe(value.tolist())
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    return _json_scalar(value)


def _json_scalar(value: Any) -> Any:
    """A scalar as a plain JSON value: numpy numbers converted, NaN/inf → None, anything
    else but None and strings as its ``str``."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        f = float(value)
        return f if math.isfinite(f) else None
    if value is None or isinstance(value, str):
        return value
    return str(value)


def _rows(array: NDArray[np.float64], decimals: int, name: str) -> JsonArray:
    arr = np.asarray(array, dtype=float)
    if not np.isfinite(arr).all():
        raise InputError(f"{name} has NaN or infinite values; the JSON contract has none",
                         field=name)
    return JsonArray(arr, decimals)


def _ordered(keys: Mapping[str, Any], order: tuple[str, ...]) -> list[str]:
    return [k for k in order if k in keys] + [k for k in keys if k not in order]


def skeleton_to_dict(result: SkeletonResult, *, decimals: int = 6) -> dict[str, Any]:
    """The JSON document of ``result`` as plain Python objects (:func:`skeleton_document`
    with its arrays as lists).

    Parameters
    ----------
    result : SkeletonResult
    decimals : int
        As in :func:`skeleton_document`.

    Returns
    -------
    dict
        Only JSON types; no NaN.
    """
    return dict(plain(skeleton_document(result, decimals=decimals)))


def skeleton_document(result: SkeletonResult, *, decimals: int = 6) -> dict[str, Any]:
    """The JSON document of ``result``, its per-frame arrays as
    :class:`~bonefit.estimation.numtext.JsonArray` (written in bulk by the writers).

    Parameters
    ----------
    result : SkeletonResult
    decimals : int
        Decimal places of positions (metres: 6 is a micrometre) and quaternion components
        (``decimals + 2``).

    Returns
    -------
    dict
        ``kind, method, fps, frames, units, joints, offsets, bone_lengths, orientations,
        quality, warnings, timings`` (see ``docs/skeleton-io.md``). JSON types and
        ``JsonArray``; no NaN.

    Raises
    ------
    InputError
        If a joint trajectory or orientation holds NaN.
    """
    joints = {name: _rows(result.joints[name], decimals, f"joints.{name}")
              for name in _ordered(result.joints, JOINTS)}
    return {
        "kind": SKELETON_KIND,
        "method": result.method,
        "fps": float(result.fps),
        "frames": result.n_frames,
        "units": "m",
        "joints": joints,
        "offsets": offsets_to_dict(result.offsets, decimals=decimals),
        "bone_lengths": _json_safe(dict(result.bone_lengths)),
        "orientations": {name: _rows(q, decimals + 2, f"orientations.{name}")
                         for name, q in result.orientations.items()},
        "quality": _json_safe({k: dict(v) for k, v in result.quality.items()}),
        "warnings": [str(w) for w in result.warnings],
        "timings": timings_document(result.timings),
    }


def write_skeleton_json(result: SkeletonResult, path: PathLike | io.TextIOBase, *,
                        decimals: int = 6, indent: int | None = None) -> None:
    """Write ``result`` as a JSON document (the contract of ``docs/skeleton-io.md``).

    Parameters
    ----------
    result : SkeletonResult
    path : path or text stream
    decimals : int
        Decimal places of positions in metres.
    indent : int, optional
        Pretty-print indentation; compact by default.

    Notes
    -----
    ``timings`` always has ``read_s``, ``estimate_s`` and ``write_s``; when ``result`` has no
    ``write_s``, it is the time spent building the document here (the final dump is not
    timed). :func:`write_skeleton_files` writes BVH, CSV and JSON with one ``write_s``.
    """
    started = time.perf_counter()
    document = skeleton_document(result, decimals=decimals)
    if "write_s" not in result.timings:
        document["timings"]["write_s"] = time.perf_counter() - started
    _dump(document, path, indent)


JSON_WEIGHT: Final[float] = 2.0
"""Weight of the JSON in the progress of :func:`write_skeleton_files` against 1 for each other
file (at 144k frames the JSON took 1.37× ``numpy.loadtxt`` of the take, the BVH 0.28×, the
CSV 0.53×, the NPZ 0.18×)."""


class _WriteProgress:
    """Progress of :func:`write_skeleton_files`, always reported from the calling thread:
    the JSON's numbers written there and the other files finished by the second thread
    (which only counts them)."""

    def __init__(self, report: Progress, json_values: int, files: int) -> None:
        self.report = report
        self.json_values = json_values
        self.json_weight = JSON_WEIGHT if json_values else 0.0
        self.total = self.json_weight + files
        self.values = 0
        self.files = 0

    def json_done(self, values: int) -> None:
        """``values`` more numbers of the JSON written (this thread): report."""
        self.values += values
        self.show()

    def file_done(self) -> None:
        """One more other file written (the second thread: reported by the next ``show``)."""
        self.files += 1

    def file_shown(self) -> None:
        """One more other file written (this thread): report."""
        self.files += 1
        self.show()

    def show(self) -> None:
        """Report the share done, below 1 (the caller reports the end)."""
        json_share = self.values / self.json_values if self.json_values else 0.0
        done = self.json_weight * json_share + self.files
        self.report(min(done / self.total, 0.99) if self.total else 0.0, "writing")


def write_skeleton_files(result: SkeletonResult, outputs: SkeletonOutputs, *,
                         decimals: int = 6,
                         progress: Progress | None = None) -> SkeletonResult:
    """Write the BVH, the CSV and the NPZ and, meanwhile, the JSON, whose ``timings.write_s``
    covers all.

    The JSON is streamed in this thread while a second one writes the other files, the BVH
    first (numpy formats and computes outside the interpreter lock, so on two cores the two
    overlap); this thread, done with the JSON's arrays, takes the other files the second
    has not started. The JSON's timings, written last, wait for all of them.

    Parameters
    ----------
    result : SkeletonResult
        With ``read_s`` and ``estimate_s`` in its timings when the caller measured them.
    outputs : SkeletonOutputs
        Files to write (None: skip; the NPZ's ``timings`` stop before it) and whether the
        BVH has slip chains (:func:`skeleton_to_bvh`).
    decimals : int
        Decimal places of JSON positions in metres.
    progress : callable, optional
        ``progress(fraction, "writing")``, from the calling thread only: at the start, per
        block of JSON numbers, as each other file is finished (every 0.25 s while the JSON
        waits for them) and 1 at the end.

    Returns
    -------
    SkeletonResult
        ``result`` with ``timings["write_s"]``: seconds from the start to the end of the
        writes (in the JSON: up to its timings, the last thing in it).

    Raises
    ------
    OSError
        A file could not be written (a JSON left unfinished by it is removed).
    """
    started = time.perf_counter()
    report = progress or no_progress
    report(0.0, "writing")
    files = _OtherFiles(result, outputs, started)
    json_path = outputs.json
    if json_path is None:
        tally = _WriteProgress(report, 0, files.count)
        files.write(tally.file_shown)
    else:
        document = skeleton_document(result, decimals=decimals)
        tally = _WriteProgress(report, array_values(document), files.count)
        with ThreadPoolExecutor(1, thread_name_prefix="bonefit-write") as pool:
            others = pool.submit(files.write, tally.file_done)

            def timings() -> dict[str, float]:
                files.write(tally.file_shown)  # what the other thread has not started
                _wait(others, tally)  # raises what the other writes raised
                return timings_document({**result.timings,
                                         "write_s": time.perf_counter() - started})

            document["timings"] = JsonLater(timings)
            try:
                _dump(document, json_path, None, done=tally.json_done)
            except BaseException:
                Path(json_path).unlink(missing_ok=True)
                raise
    report(1.0, "writing")
    return replace(result, timings={**result.timings, "write_s": time.perf_counter() - started})


def _wait(others: Future[None], tally: _WriteProgress) -> None:
    """Wait for the other files, reporting every 0.25 s meanwhile (the JSON is done)."""
    while True:
        try:
            others.result(timeout=0.25)
            return
        except TimeoutError:
            tally.show()


class _OtherFiles:
    """The BVH, CSV and NPZ of :func:`write_skeleton_files` (those with a path), the
    longest first, each written by whichever thread takes it first."""

    def __init__(self, result: SkeletonResult,
                 outputs: SkeletonOutputs, started: float) -> None:
        chains = outputs.bvh_slip_chains
        writes: list[tuple[PathLike | None, Callable[[PathLike], None]]] = [
            (outputs.bvh, lambda path: write_skeleton_bvh(result, path, slip_chains=chains)),
            (outputs.csv, lambda path: write_skeleton_csv(result, path)),
            (outputs.npz, lambda path: write_skeleton_npz(replace(result, timings={
                **result.timings, "write_s": time.perf_counter() - started}), path))]
        self._todo = deque((path, write) for path, write in writes if path is not None)
        self.count = len(self._todo)
        self._lock = threading.Lock()

    def write(self, done: Callable[[], None]) -> None:
        """Write the files no thread has taken yet, one at a time; ``done()`` after each."""
        while True:
            with self._lock:
                if not self._todo:
                    return
                path, write = self._todo.popleft()
            write(path)
            done()


def _dump(document: Mapping[str, Any], path: PathLike | io.TextIOBase,
          indent: int | None, *, done: Callable[[int], None] | None = None) -> None:
    end = "" if isinstance(path, io.TextIOBase) else "\n"
    write_text_blocks(json_blocks(document, indent=indent, done=done), path, end=end)


def _read_json(path: PathLike) -> Any:
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except UnicodeDecodeError as exc:
        raise InputError(f"not a UTF-8 JSON document: byte {exc.start} cannot be decoded",
                         field="input") from None
    except RecursionError:
        raise InputError("JSON nested too deeply", field="input") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"invalid JSON: {exc.msg} at line {exc.lineno}, column {exc.colno}",
                         line=exc.lineno, column=exc.colno) from None


def read_skeleton_json(path: PathLike) -> SkeletonResult:
    """Read a skeleton JSON document written by :func:`write_skeleton_json`.

    Raises
    ------
    InputError
        On invalid JSON (with its line and column) or a document that is not a skeleton.
    """
    return skeleton_from_dict(_read_json(path))


def read_skeleton_offsets(path: PathLike) -> dict[str, JointOffset]:
    """The joint offsets of a calibration: a skeleton JSON document's ``offsets``, or a
    document holding only ``{"offsets": {...}}``; for ``estimate_skeleton_from_offsets``.

    Raises
    ------
    InputError
        Invalid JSON (line and column), no ``offsets`` object, a malformed entry.
    """
    data = _read_json(path)
    if not isinstance(data, Mapping) or "offsets" not in data:
        raise InputError("not a calibration: the document has no \"offsets\" object (write "
                         "one with bonefit skeleton -o)", field="offsets")
    if data.get("units", "m") != "m":
        raise InputError(f"offsets must be in metres (units 'm'), got {data['units']!r}",
                         field="units")
    return offsets_from_dict(data["offsets"])


# --------------------------------------------------------------------------- NPZ


def write_skeleton_npz(result: SkeletonResult, path: PathLike) -> None:
    """Write ``result`` as an NPZ archive: the JSON document's names, arrays at full
    precision (see :mod:`bonefit.estimation.io.result_npz`; ``docs/skeleton-io.md``).

    Parameters
    ----------
    result : SkeletonResult
    path : path
        Written as given (no ``.npz`` appended).

    Raises
    ------
    InputError
        If a joint trajectory or orientation holds NaN (as the JSON).
    """
    write_document_npz(skeleton_document(result), path)


def read_skeleton_npz(path: PathLike) -> SkeletonResult:
    """Read a skeleton NPZ archive written by :func:`write_skeleton_npz`.

    Raises
    ------
    InputError
        Not an NPZ result, or a document that is not a skeleton (as
        :func:`skeleton_from_dict`).
    """
    return skeleton_from_dict(read_document_npz(path))


# --------------------------------------------------------------------------- CSV


def write_skeleton_csv(result: SkeletonResult, path: PathLike | io.TextIOBase, *,
                       decimals: int = 6) -> None:
    """Write the joint trajectories as CSV: ``time,<joint>.x,<joint>.y,<joint>.z,...``.

    One row per frame; ``time`` = frame / fps in seconds, positions in metres, joints in
    ``bonefit.estimation.model.JOINTS`` order (others after).
    """
    names = _ordered(result.joints, JOINTS)
    n = result.n_frames
    table = np.empty((n, 1 + 3 * len(names)))
    table[:, 0] = np.arange(n) / result.fps
    for j, name in enumerate(names):
        table[:, 1 + 3 * j:4 + 3 * j] = result.joints[name]
    header = ",".join(["time"] + [f"{name}.{c}" for name in names for c in "xyz"])
    write_text_blocks(itertools.chain([header + "\n"], fixed_blocks(table, decimals)), path)


# --------------------------------------------------------------------------- BVH


def _rotation(result: SkeletonResult, segment: str) -> Rotation:
    if segment not in result.orientations:
        raise InputError(f"the result has no orientation for segment {segment!r}, needed "
                         f"by the BVH hierarchy", field=f"orientations.{segment}")
    q = np.asarray(result.orientations[segment], dtype=float)
    if q.shape != (result.n_frames, 4) or not np.isfinite(q).all():
        raise InputError(f"orientation of {segment!r} must be finite (F, 4) quaternions",
                         field=f"orientations.{segment}")
    return Rotation.from_quat(q, scalar_first=True)


def _joint(result: SkeletonResult, name: str) -> NDArray[np.float64]:
    if name not in result.joints:
        raise InputError(f"the result has no joint {name!r}, needed by the BVH hierarchy",
                         field=f"joints.{name}")
    p = np.asarray(result.joints[name], dtype=float)
    if not np.isfinite(p).all():
        raise InputError(f"joint {name!r} has NaN positions", field=f"joints.{name}")
    return p


@dataclass(frozen=True, eq=False)
class _Nodes:
    """The skeleton BVH's nodes before channels: names, parents, OFFSETs in the parent's
    node frame (metres) and, per node that turns, its rotation relative to its parent's
    node frame (scalar-last quaternions, F × 4) and, below the root, its path as seen from
    the parent's node frame in every frame (F × 3, metres; the OFFSET is its mean)."""

    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: NDArray[np.float64]
    local: dict[str, NDArray[np.float64]]
    bones: dict[str, NDArray[np.float64]]


CLAVICLES: Final[dict[str, str]] = {"l_shoulder": "l_clavicle", "r_shoulder": "r_clavicle"}
"""The node inserted between ``chest`` and each shoulder: at the shoulder's clavicle point on
the chest–neck line (``rigid.clavicle_heights``), so the shoulder moves on the chest."""


def skeleton_tree() -> tuple[tuple[str, str | None], ...]:
    """The skeleton BVH's (node, parent) pairs, parents first: ``BVH_NODES`` with a
    clavicle node (``CLAVICLES``) above each shoulder."""
    out: list[tuple[str, str | None]] = []
    for node, parent, _ in BVH_NODES:
        if node in CLAVICLES:
            out.append((CLAVICLES[node], parent))
            parent = CLAVICLES[node]
        out.append((node, parent))
    return tuple(out)


def _in_frame(quats: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.float64]:
    """``R(t)ᵀ v(t)``: vectors ``v`` (F × 3) in the frames of the rotations ``quats``
    (scalar-last, F × 4), without building a ``Rotation`` (``v + w·t + u × t``,
    ``t = 2 u × v``, ``u`` the negated vector part). Component by component: the same
    operations in the same order as with ``np.cross``, so the same bits, without its
    temporaries (on a long take most of the BVH hierarchy's CPU time went to them)."""
    u = [-quats[:, k] for k in range(3)]
    t = [_cross_row(u, [v[:, k] for k in range(3)], k) for k in range(3)]
    for row in t:
        row *= 2.0
    out = np.empty((len(v), 3))
    w = quats[:, 3]
    for k in range(3):
        row = _cross_row(u, t, k)
        row += v[:, k]
        row += w * t[k]
        out[:, k] = row
    return out


def _cross_row(a: list[NDArray[np.float64]], b: list[NDArray[np.float64]], k: int
               ) -> NDArray[np.float64]:
    """Component ``k`` of the cross products of rows ``a`` and ``b`` (each three arrays of
    components), as ``np.cross`` computes it: ``a[i] b[j] − a[j] b[i]``."""
    i, j = (k + 1) % 3, (k + 2) % 3
    out = a[i] * b[j]
    out -= a[j] * b[i]
    return out


def _swung(base: NDArray[np.float64], seen: NDArray[np.float64]) -> NDArray[np.float64]:
    """``base`` (scalar-last quaternions, F × 4) turned, in its own frame, by the smallest
    rotation that takes the mean direction ``m`` of a target seen in it (``seen``, F × 3,
    ``_in_frame`` of the target) onto the target's direction in every frame: the turned
    frame holds the target along ``m`` exactly, its twist about ``m`` kept. ``base``
    itself where it already does (a limb segment's y axis runs along its bone)."""
    local = seen / np.maximum(rows.norms(seen), 1e-300)[:, None]
    mean = local.mean(axis=0)
    mean /= max(float(np.linalg.norm(mean)), 1e-300)
    if float(np.abs(local - mean).max(initial=0.0)) <= 1e-12:
        return base
    swing = np.empty((len(local), 4))
    swing[:, :3] = np.cross(mean, local)
    swing[:, 3] = 1.0 + local @ mean
    flip = swing[:, 3] <= 1e-12  # opposite directions: a half turn about any axis ⟂ m
    swing[flip] = [*np.cross(mean, np.eye(3)[int(np.argmin(np.abs(mean)))]), 0.0]
    swing /= rows.norms(swing)[:, None]
    return compose_quaternions(base, swing)


def _node_positions(result: SkeletonResult) -> dict[str, NDArray[np.float64]]:
    """Every node's path (F × 3, metres): the joints and the clavicle points."""
    positions = {node: _joint(result, node) for node, _, _ in BVH_NODES}
    points = clavicle_points(positions["chest"], positions["neck"], clavicle_heights(
        positions["chest"], positions["neck"], positions["l_shoulder"],
        positions["r_shoulder"]))
    positions.update(zip(CLAVICLES.values(), points, strict=True))
    return positions


_DRIVERS: Final[dict[str, str]] = {node: seg for node, _, seg in BVH_NODES}
"""The segment each joint's node turns with (a clavicle node has none: its parent's)."""


def _each_node(task: Callable[[str], _T], nodes: list[str], frames: int) -> dict[str, _T]:
    """``task(node)`` per node, as independent pieces of ``threads.run_each``: on its
    threads from ``threads.MIN_FRAMES`` frames (numpy releases the interpreter lock on a
    long take's arrays: the nodes' products overlap), else one after the other."""
    pieces = [functools.partial(_for_node, task, node) for node in nodes]
    return dict(zip(nodes, run_each(pieces, no_progress, "writing", frames=frames),
                    strict=True))


def _for_node(task: Callable[[str], _T], node: str, _report: Report) -> _T:
    """``task(node)`` as a piece of ``threads.run_each`` (it reports no progress)."""
    return task(node)


@dataclass(frozen=True, eq=False)
class _FrameTask:
    """What a node's frame (:func:`_node_frames`) is made of: the result, the node paths,
    the parent and children per node and the frames already known (a clavicle's parent's)."""

    result: SkeletonResult
    positions: Mapping[str, NDArray[np.float64]]
    parent: Mapping[str, str]
    children: Mapping[str, list[str]]
    quats: Mapping[str, NDArray[np.float64]]

    def __call__(self, node: str) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
        """The node's frame and, when it was not turned, its first child's path in it."""
        base = (_rotation(self.result, _DRIVERS[node]).as_quat() if node in _DRIVERS
                else self.quats[self.parent[node]])
        if not self.children[node]:
            return base, None
        child = self.children[node][0]
        local = _in_frame(base, self.positions[child] - self.positions[node])
        turned = _swung(base, local)
        return turned, local if turned is base else None


def _node_frames(result: SkeletonResult, positions: Mapping[str, NDArray[np.float64]],
                 parent: Mapping[str, str], children: Mapping[str, list[str]]
                 ) -> tuple[dict[str, NDArray[np.float64]], dict[str, NDArray[np.float64]]]:
    """Per node of ``skeleton_tree``, its frame (scalar-last quaternions, F × 4): its
    segment's (a clavicle's: its parent's) turned by ``_swung`` toward its first child;
    and per first child whose parent's frame was not turned (most limb nodes), its path
    from the parent in that frame (F × 3), which the child's OFFSET reuses. The nodes with
    a segment first, then the clavicles (:func:`_each_node`)."""
    quats: dict[str, NDArray[np.float64]] = {}
    seen: dict[str, NDArray[np.float64]] = {}
    nodes = [node for node, _ in skeleton_tree()]
    for group in ([n for n in nodes if n in _DRIVERS], [n for n in nodes if n not in _DRIVERS]):
        frames = _each_node(_FrameTask(result, positions, parent, children, dict(quats)), group,
                            result.n_frames)
        for node, (quat, local) in frames.items():
            quats[node] = quat
            if local is not None:
                seen[children[node][0]] = local
    return quats, seen


@dataclass(frozen=True, eq=False)
class _LinkTask:
    """What a node's link to its parent (:func:`_skeleton_nodes`) is made of: the node
    paths, the parent per node, the frames and the paths already seen in them."""

    positions: Mapping[str, NDArray[np.float64]]
    parent: Mapping[str, str]
    quats: Mapping[str, NDArray[np.float64]]
    seen: Mapping[str, NDArray[np.float64]]

    def __call__(self, node: str
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """The node's path in its parent's frame, its mean (the OFFSET) and the node's
        rotation relative to that frame."""
        parent = self.parent[node]
        bone = self.seen[node] if node in self.seen else _in_frame(
            self.quats[parent], self.positions[node] - self.positions[parent])
        turn = compose_quaternions(self.quats[parent] * [-1.0, -1.0, -1.0, 1.0],
                                   self.quats[node])
        return bone, bone.mean(axis=0), turn


def _skeleton_nodes(result: SkeletonResult) -> _Nodes:
    """Nodes in ``skeleton_tree`` order, end sites ``<node>_end`` after their parents.

    A node's frame is its segment's (a clavicle's: its parent's) turned by ``_swung``
    toward its first child, which it then holds exactly along its OFFSET's direction."""
    positions = _node_positions(result)
    children: dict[str, list[str]] = {node: [] for node, _ in skeleton_tree()}
    above = {node: parent for node, parent in skeleton_tree() if parent is not None}
    for node, holder in above.items():
        children[holder].append(node)
    quats, seen = _node_frames(result, positions, above, children)
    links = _each_node(_LinkTask(positions, above, quats, seen), list(above), result.n_frames)
    names: list[str] = []
    parents: list[int] = []
    offsets: list[NDArray[np.float64]] = []
    local: dict[str, NDArray[np.float64]] = {"root": quats["root"]}
    bones: dict[str, NDArray[np.float64]] = {}
    stack: list[tuple[str, str | None]] = [("root", None)]
    while stack:
        node, parent = stack.pop()
        parents.append(names.index(parent) if parent is not None else -1)
        names.append(node)
        if node.endswith("_end"):
            segment, direction, default = END_SITES[node[:-4]]
            offsets.append(np.asarray(direction, float) * float(
                result.bone_lengths.get(segment, default)))
            continue
        if parent is None:
            offsets.append(np.zeros(3))
        else:
            bones[node], offset, local[node] = links[node]
            offsets.append(offset)
        after = [*children[node], *([f"{node}_end"] if node in END_SITES else [])]
        stack.extend((child, node) for child in reversed(after))
    return _Nodes(tuple(names), tuple(parents), np.asarray(offsets, dtype=float), local,
                  bones)


BVH_REST: Final[tuple[str, ...]] = ("auto", "segment")
"""Rest poses of the skeleton BVH: per node the better playing of its segment frame and the
take's mean pose (``auto``), or every node in its segment frame (``segment``)."""


def skeleton_to_bvh(result: SkeletonResult, *, units: str = "cm",
                    euler_order: str | None = None, rest: str = "auto",
                    slip_chains: bool = True) -> BvhMotion:
    """The BVH hierarchy and motion of a skeleton result.

    The hierarchy is ``root`` → ``waist`` → ``chest`` → ``neck`` (head end site); ``chest`` →
    clavicle → shoulder → elbow → wrist (hand end site) per side; ``root`` → hip → knee →
    ankle (toe end site) per side (``skeleton_tree``). Each joint's node turns with the
    segment it drives (root: pelvis, waist: spine, chest: chest, neck: head, shoulder: upper
    arm, elbow: forearm, wrist: hand, hip: thigh, knee: shank, ankle: foot) turned by the
    smallest swing (no twist about the OFFSET) that puts its first child on the child's
    path: ``Q(t) = R_seg(t) S(t)``; a clavicle node (``CLAVICLES``), at its shoulder's
    clavicle point (``rigid.clavicle_heights``), turns with the chest's swung onto the
    shoulder. A node's frame in the file is ``Q`` turned by a constant rest rotation ``C``
    (``bvh.rest_euler_channels``): identity or the take's mean pose of the node relative to
    its parent, whichever plays back better between frames. A node's OFFSET is ``C_parentᵀ``
    times the frame mean of ``Q_parent(t)ᵀ (node(t) − parent(t))``. Rotation channels hold
    ``C_parentᵀ Q_parent(t)⁻¹ Q(t) C`` as intrinsic Euler angles in degrees, in an order
    per node that keeps its channels off gimbal lock, unwrapped over time; the root's
    position channels hold the ``root`` joint at OFFSET zero (three.js and Blender agree).

    Every joint is where the result has it if its paths lie on a rigid tree of bones, as
    ``auto``'s do (``rigid.rigid_paths``); else off by its bone-length variation. With
    ``slip_chains``, a joint ever over ``SLIP_TOL_M`` off hangs from a slip chain
    (``bvh.slip_chain``): three rotation-only nodes that carry it to its position and turn
    back exactly, at the frames and between them.

    Parameters
    ----------
    result : SkeletonResult
        Needs the 16 joints of ``bonefit.estimation.model.JOINTS`` and the orientations of the
        driving segments, including ``spine``.
    units : {"cm", "m", "mm", "in"}
        Length unit of offsets and root positions.
    euler_order : str, optional
        One intrinsic rotation order for every skeleton node, for tools that need a single
        order; by default per node. Slip chains keep their own orders.
    rest : {"auto", "segment"}
        ``"segment"`` keeps every node in its segment frame (the rest pose upright, arms
        down, as before rest rotations), for tools that retarget from that pose.
    slip_chains : bool
        Slip chains where a joint strays (none for ``auto``): every joint where the result
        has it. ``False``: the rigid skeleton of mean OFFSETs only.

    Returns
    -------
    BvhMotion
        Nodes in ``skeleton_tree`` order with end sites ``<node>_end`` after their parents
        and a joint's slip chain (``<joint>_slip_base``, ``_slip_bend``, ``_slip_tip``), if
        any, just before it.

    Raises
    ------
    InputError
        If a joint or orientation the hierarchy needs is missing or not finite, or
        ``euler_order`` is not one of ``bonefit.estimation.bvh.EULER_ORDERS``, or ``rest`` is not
        one of ``BVH_REST``.
    """
    if rest not in BVH_REST:
        raise InputError(f"rest must be one of {', '.join(BVH_REST)}, got {rest!r}",
                         field="rest")
    per_m = 1.0 / unit_scale(units)
    nodes = _skeleton_nodes(result)
    turning = [j for j, name in enumerate(nodes.names) if name in nodes.local]
    table, chans = _motion_table(result, nodes, turning, per_m, euler_order,
                                 centre=rest == "auto")
    frame = np.tile([0.0, 0.0, 0.0, 1.0], (len(nodes.names), 1))
    frame[turning] = chans.rest
    above = frame[[max(p, 0) for p in nodes.parents]]
    offsets = Rotation.from_quat(above).inv().apply(nodes.offsets)
    by_node = dict(zip(turning, chans.channels, strict=True))
    channels = [by_node.get(j, ()) for j in range(len(nodes.names))]
    channels[0] = (*ROOT_POSITION_CHANNELS, *channels[0])
    slips = _slips(nodes, frame, offsets) if slip_chains else {}
    out = _with_slips(nodes, offsets * per_m, slips, per_m, channels=channels,
                      values=(turning, chans.values))
    values = np.concatenate([table[:, :3], *out.columns], axis=1) if slips else table
    return BvhMotion(out.names, out.parents, out.offsets, out.channels, 1.0 / float(result.fps),
                     values)


def _motion_table(result: SkeletonResult, nodes: _Nodes, turning: list[int], per_m: float,
                  euler_order: str | None, *, centre: bool
                  ) -> tuple[NDArray[np.float64], NodeChannels]:
    """The MOTION table (F, 3 + 3N) without slip chains: the root's positions (file units,
    ``per_m`` per metre), then the rotation channels of the N ``turning`` nodes, which
    ``rest_euler_channels`` writes in place; and those channels."""
    tree = tuple(turning.index(nodes.parents[j]) if nodes.parents[j] >= 0 else -1
                 for j in turning)
    table = np.empty((result.n_frames, 3 + 3 * len(turning)))
    np.multiply(_joint(result, "root"), per_m, out=table[:, :3])
    chans = rest_euler_channels(tree, [nodes.local[nodes.names[j]] for j in turning],
                                euler_order, centre=centre,
                                out=table[:, 3:].reshape(result.n_frames, len(turning), 3))
    return table, chans


def _slips(nodes: _Nodes, frame: NDArray[np.float64], offsets: NDArray[np.float64]
           ) -> dict[int, SlipChain]:
    """Per node whose joint strays from its rigid place (its OFFSET under its parent node,
    ``offsets`` in metres, parent frames turned by their rest rotations ``frame``) by more
    than ``SLIP_TOL_M``, the slip chain that carries it there."""
    out: dict[int, SlipChain] = {}
    for j, name in enumerate(nodes.names):
        if name not in nodes.bones:
            continue
        # the joint in the parent node's frame, C_parentᵀ · bone, minus the OFFSET
        rest = Rotation.from_quat(frame[nodes.parents[j]]).as_matrix()
        residual = nodes.bones[name] @ rest - offsets[j]
        if float(np.sqrt(np.einsum("ij,ij->i", residual, residual).max())) > SLIP_TOL_M:
            out[j] = slip_chain(residual, offsets[j])
    return out


@dataclass(frozen=True, eq=False)
class _Tree:
    """The skeleton BVH's nodes with slip chains: names, parents, OFFSETs (file units),
    channels and the value columns (F, 3) of every rotation channel triple, in node order."""

    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: NDArray[np.float64]
    channels: tuple[tuple[str, ...], ...]
    columns: tuple[NDArray[np.float64], ...]


def _with_slips(nodes: _Nodes, offsets: NDArray[np.float64], slips: dict[int, SlipChain],
                per_m: float, *, channels: list[tuple[str, ...]],
                values: tuple[list[int], NDArray[np.float64]]) -> _Tree:
    """``nodes`` (with their ``channels``, and the rotation channel values (F, N, 3) of the
    N nodes listed in ``values``) with each slip chain inserted above its joint, which then
    sits at OFFSET zero under the chain's tip; parents before children."""
    turning, block = values
    columns = {j: block[:, k] for k, j in enumerate(turning)}
    tree = _Hierarchy()
    placed: dict[int, int] = {}
    for j, name in enumerate(nodes.names):
        parent = placed[nodes.parents[j]] if nodes.parents[j] >= 0 else -1
        offset = offsets[j]
        if j in slips:
            chain = slips[j]
            steps = (offset - chain.reach * per_m, *(chain.links * per_m))
            for k, (suffix, step) in enumerate(zip(SLIP_NODES, steps, strict=True)):
                parent = tree.add(f"{name}_{suffix}", parent, step,
                                  tuple(f"{a}rotation" for a in chain.orders[k]),
                                  chain.values[:, k])
            offset = np.zeros(3)
        placed[j] = tree.add(name, parent, offset, channels[j], columns.get(j))
    # without chains the columns are the (F, N, 3) block as it is (no copy)
    return _Tree(tuple(tree.names), tuple(tree.parents), np.asarray(tree.offsets, dtype=float),
                 tuple(tree.channels),
                 tuple(tree.columns) if slips else (block.reshape(len(block), -1),))


@dataclass
class _Hierarchy:
    """Nodes as they are added (see :class:`_Tree`)."""

    names: list[str] = field(default_factory=list)
    parents: list[int] = field(default_factory=list)
    offsets: list[NDArray[np.float64]] = field(default_factory=list)
    channels: list[tuple[str, ...]] = field(default_factory=list)
    columns: list[NDArray[np.float64]] = field(default_factory=list)

    def add(self, name: str, parent: int, offset: NDArray[np.float64],
            channels: tuple[str, ...], column: NDArray[np.float64] | None) -> int:
        """Append a node (its rotation values ``column``, None without rotations); returns
        its index."""
        self.names.append(name)
        self.parents.append(parent)
        self.offsets.append(offset)
        self.channels.append(channels)
        if column is not None:
            self.columns.append(column)
        return len(self.names) - 1


def write_skeleton_bvh(result: SkeletonResult, path: PathLike | io.TextIOBase, *,
                       units: str = "cm", precision: int = 6,
                       euler_order: str | None = None, rest: str = "auto",
                       slip_chains: bool = True) -> None:
    """Write ``result`` as a BVH file (see :func:`skeleton_to_bvh`).

    Parameters
    ----------
    result : SkeletonResult
    path : path or text stream
    units : {"cm", "m", "mm", "in"}
        Length unit of the file (centimetres by default, as most BVH tools expect).
    precision : int
        Decimal places of offsets and channel values.
    euler_order : str, optional
        One rotation order for every node instead of per-node orders.
    rest : {"auto", "segment"}
        Rest pose: per node the better playing of segment frame and mean pose, or every
        node in its segment frame.
    slip_chains : bool
        Put every joint exactly where the JSON has it, through slip chains where the result
        is not rigid (see :func:`skeleton_to_bvh`; ``auto`` estimates need none); ``False``:
        the rigid skeleton only, off other results' joints by their bone-length variation.
    """
    write_bvh(skeleton_to_bvh(result, units=units, euler_order=euler_order, rest=rest,
                              slip_chains=slip_chains), path, precision=precision)
