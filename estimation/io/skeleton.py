"""Writers (JSON, CSV, BVH) and JSON file readers of skeleton results (the document
readers, numpy only, are in ``io.result_json`` and importable from here).

The JSON layout is a contract for scripted clients and is documented in
``docs/skeleton-io.md``; the BVH hierarchy is rooted at the ``root`` joint with one node per
joint, driven by the orientation of the segment that joint moves.
"""

from __future__ import annotations

import io
import json
import math
import os
import time
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any, Final

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from ..bvh import BvhMotion, euler_channels, write_bvh
from ..errors import InputError
from ..model import BVH_TREE, JOINTS
from ..results import JointOffset, SkeletonResult, timings_document
from .result_json import SKELETON_KIND, offsets_to_dict
from .result_json import offsets_from_dict as offsets_from_dict  # documented here too
from .result_json import skeleton_from_dict as skeleton_from_dict
from .sensor_common import unit_scale

PathLike = str | os.PathLike[str]

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


def _rows(array: NDArray[np.float64], decimals: int, name: str) -> list[list[float]]:
    arr = np.asarray(array, dtype=float)
    if not np.isfinite(arr).all():
        raise InputError(f"{name} has NaN or infinite values; the JSON contract has none",
                         field=name)
    rows: list[list[float]] = np.round(arr, decimals).tolist()
    return rows


def _ordered(keys: Mapping[str, Any], order: tuple[str, ...]) -> list[str]:
    return [k for k in order if k in keys] + [k for k in keys if k not in order]


def skeleton_to_dict(result: SkeletonResult, *, decimals: int = 6) -> dict[str, Any]:
    """The JSON document of ``result`` as plain Python objects.

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
        quality, warnings, timings`` (see ``docs/skeleton-io.md``). Only JSON types; no NaN.

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
    document = skeleton_to_dict(result, decimals=decimals)
    if "write_s" not in result.timings:
        document["timings"]["write_s"] = time.perf_counter() - started
    _dump(document, path, indent)


def write_skeleton_files(result: SkeletonResult, *, json_path: PathLike | None = None,
                         bvh_path: PathLike | None = None, csv_path: PathLike | None = None,
                         decimals: int = 6) -> SkeletonResult:
    """Write the BVH, the CSV, then the JSON whose ``timings.write_s`` covers all three.

    Parameters
    ----------
    result : SkeletonResult
        With ``read_s`` and ``estimate_s`` in its timings when the caller measured them.
    json_path, bvh_path, csv_path : path, optional
        Files to write; None: skip.
    decimals : int
        Decimal places of JSON positions in metres.

    Returns
    -------
    SkeletonResult
        ``result`` with ``timings["write_s"]``: seconds from the start to the end of the
        writes (in the JSON: up to building its document; the final dump is not timed).
    """
    started = time.perf_counter()
    if bvh_path is not None:
        write_skeleton_bvh(result, bvh_path)
    if csv_path is not None:
        write_skeleton_csv(result, csv_path)
    if json_path is not None:
        document = skeleton_to_dict(result, decimals=decimals)
        document["timings"]["write_s"] = time.perf_counter() - started
        _dump(document, json_path, None)
    return replace(result, timings={**result.timings, "write_s": time.perf_counter() - started})


def _dump(document: Mapping[str, Any], path: PathLike | io.TextIOBase,
          indent: int | None) -> None:
    text = json.dumps(document, indent=indent, allow_nan=False)
    if isinstance(path, io.TextIOBase):
        path.write(text)
    else:
        Path(path).write_text(text + "\n", encoding="utf-8")


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
    out = io.StringIO()
    np.savetxt(out, table, fmt=f"%.{decimals}f", delimiter=",", header=header, comments="")
    if isinstance(path, io.TextIOBase):
        path.write(out.getvalue())
    else:
        Path(path).write_text(out.getvalue(), encoding="utf-8")


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


def skeleton_to_bvh(result: SkeletonResult, *, units: str = "cm",
                    euler_order: str | None = None) -> BvhMotion:
    """The BVH hierarchy and motion of a skeleton result.

    The hierarchy is ``root`` → ``waist`` → ``chest`` → ``neck`` (head end site); ``chest`` →
    shoulder → elbow → wrist (hand end site) per side; ``root`` → hip → knee → ankle (toe end
    site) per side. Each node turns with the segment it drives (root: pelvis, waist: spine,
    chest: chest, neck: head, shoulder: upper arm, elbow: forearm, wrist: hand, hip: thigh,
    knee: shank, ankle: foot). In the rest pose every segment frame equals the world frame;
    a node's OFFSET is the frame mean of ``R_seg(t)ᵀ (child(t) − joint(t))``, in the parent
    node's segment frame. Rotation channels hold ``R_parent(t)⁻¹ R_seg(t)`` as intrinsic
    Euler angles in degrees, in an order per node that keeps its channels off gimbal lock
    (``bonefit.estimation.bvh.euler_channels``: a knee or elbow flexing about x gets x first or
    last, never in the middle), unwrapped over time; the root's position channels hold the
    ``root`` joint and its OFFSET is zero, so readers that add position channels to the
    OFFSET (three.js) and readers that replace it (Blender) agree.

    Parameters
    ----------
    result : SkeletonResult
        Needs the 16 joints of ``bonefit.estimation.model.JOINTS`` and the orientations of the
        driving segments, including ``spine``.
    units : {"cm", "m", "mm", "in"}
        Length unit of offsets and root positions.
    euler_order : str, optional
        One intrinsic rotation order for every node (``"ZXY"`` was the only one before
        per-node orders) for tools that need a single order; by default per node.

    Returns
    -------
    BvhMotion
        Nodes in ``BVH_NODES`` order with end sites ``<node>_end`` after their parents.

    Raises
    ------
    InputError
        If a joint or orientation the hierarchy needs is missing or not finite, or
        ``euler_order`` is not one of ``bonefit.estimation.bvh.EULER_ORDERS``.
    """
    per_m = 1.0 / unit_scale(units)
    rotations = {node: _rotation(result, seg) for node, _, seg in BVH_NODES}
    positions = {node: _joint(result, node) for node, _, _ in BVH_NODES}
    children: dict[str, list[str]] = {node: [] for node, _, _ in BVH_NODES}
    for node, parent, _ in BVH_NODES:
        if parent is not None:
            children[parent].append(node)

    names: list[str] = []
    parents: list[int] = []
    offsets: list[NDArray[np.float64]] = []
    local: dict[str, Rotation] = {}

    def add(name: str, parent: str | None, offset: NDArray[np.float64]) -> None:
        parents.append(names.index(parent) if parent is not None else -1)
        names.append(name)
        offsets.append(offset * per_m)

    def visit(node: str, parent: str | None) -> None:
        if parent is None:
            add(node, None, np.zeros(3))
            local[node] = rotations[node]
        else:
            delta = positions[node] - positions[parent]
            add(node, parent, rotations[parent].inv().apply(delta).mean(axis=0))
            local[node] = rotations[parent].inv() * rotations[node]
        for child in children[node]:
            visit(child, node)
        if node in END_SITES:
            segment, direction, default = END_SITES[node]
            length = float(result.bone_lengths.get(segment, default))
            add(f"{node}_end", node, np.asarray(direction, dtype=float) * length)

    visit("root", None)
    turning = [name for name in names if name in local]
    rot_channels, angles = euler_channels([local[name] for name in turning], euler_order)
    by_node = dict(zip(turning, rot_channels, strict=True))
    channels = tuple(by_node.get(name, ()) for name in names)
    channels = ((*ROOT_POSITION_CHANNELS, *channels[0]), *channels[1:])
    values = np.concatenate([positions["root"] * per_m,
                             angles.reshape(len(angles), -1)], axis=1)
    return BvhMotion(tuple(names), tuple(parents), np.asarray(offsets, dtype=float),
                     channels, 1.0 / float(result.fps), values)


def write_skeleton_bvh(result: SkeletonResult, path: PathLike | io.TextIOBase, *,
                       units: str = "cm", precision: int = 6,
                       euler_order: str | None = None) -> None:
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
    """
    write_bvh(skeleton_to_bvh(result, units=units, euler_order=euler_order), path,
              precision=precision)
