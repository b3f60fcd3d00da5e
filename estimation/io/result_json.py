"""The result JSON documents read back into the result dataclasses, with numpy only.

One reader per document kind (``skeleton``: docs/skeleton-io.md; ``translation``:
docs/translation.md) for the library, the service and the Python client (``bonefit.client``
imports this module without scipy). The writers live beside the other formats of each
result (``io.skeleton``, ``io.translation_files``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Final

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..model import JOINTS
from ..results import (
    JointOffset,
    JointQuality,
    SkeletonResult,
    TranslationQuality,
    TranslationResult,
)

SKELETON_KIND: Final[str] = "skeleton"
TRANSLATION_KIND: Final[str] = "translation"


def read_array(value: Any, shape_tail: tuple[int, ...], field: str) -> NDArray[np.float64]:
    """``value`` as a float array of shape (F, *shape_tail).

    Raises
    ------
    InputError
        ``field=field`` when it is not numbers of that shape.
    """
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{field} must be numbers", field=field) from None
    if arr.ndim != len(shape_tail) + 1 or arr.shape[1:] != shape_tail:
        tail = "".join(f", {n}" for n in shape_tail)
        raise InputError(f"{field} must have shape (F{tail}), got {arr.shape}", field=field)
    return arr


def read_number(value: Any, field: str) -> float:
    """A JSON number as float (a boolean is not a number); InputError naming ``field``."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InputError(f"{field} must be a number, got {_json_type(value)}", field=field)
    return float(value)


def _json_type(value: Any) -> str:
    return {dict: "an object", list: "a list", str: "a string", bool: "a boolean",
            type(None): "null"}.get(type(value), type(value).__name__)


def _check_document(data: Any, kind: str, required: tuple[str, ...],
                    objects: tuple[str, ...]) -> Mapping[str, Any]:
    """``data`` if it is a ``kind`` document in metres with ``required`` members and the
    members ``objects`` (where present) JSON objects."""
    if not isinstance(data, Mapping) or data.get("kind") != kind:
        raise InputError(f"not a bonefit {kind} document (kind must be {kind!r})",
                         field="kind")
    for key in required:
        if key not in data:
            raise InputError(f"{kind} document lacks {key!r}", field=key)
    if data.get("units", "m") != "m":
        raise InputError(f"{kind} document units must be 'm', got {data['units']!r}",
                         field="units")
    for key in objects:
        if not isinstance(data.get(key, {}), Mapping):
            raise InputError(f"{key} must be an object", field=key)
    if not isinstance(data.get("warnings", []), list):
        raise InputError("warnings must be a list", field="warnings")
    return data


def _numbers(data: Mapping[str, Any], key: str) -> dict[str, float]:
    """The object ``data[key]`` of numbers (null members dropped: a non-finite value)."""
    return {str(k): read_number(v, f"{key}.{k}")
            for k, v in data.get(key, {}).items() if v is not None}


def _quality(data: Mapping[str, Any]) -> dict[str, JointQuality]:
    quality = {}
    for k, v in data.get("quality", {}).items():
        if not isinstance(v, Mapping):
            raise InputError(f"quality.{k} must be an object", field=f"quality.{k}")
        quality[str(k)] = JointQuality.of(dict(v))
    return quality


def skeleton_from_dict(data: Mapping[str, Any]) -> SkeletonResult:
    """Rebuild a SkeletonResult from its JSON document (``io.skeleton_to_dict``).

    Parameters
    ----------
    data : mapping
        The parsed document (docs/skeleton-io.md): positions in metres, quaternions
        ``w, x, y, z``, per-frame arrays time-first.

    Returns
    -------
    SkeletonResult

    Raises
    ------
    InputError
        If ``data`` is not a skeleton document or a member has the wrong type or shape
        (``field`` names it, e.g. ``joints.l_knee``).
    """
    data = _check_document(data, SKELETON_KIND, ("method", "fps", "joints", "orientations"),
                           ("joints", "orientations", "offsets", "bone_lengths", "quality",
                            "timings"))
    joints = {str(k): read_array(v, (3,), f"joints.{k}") for k, v in data["joints"].items()}
    if not joints:
        raise InputError("skeleton document has no joints", field="joints")
    return SkeletonResult(
        method=str(data["method"]),
        fps=read_number(data["fps"], "fps"),
        joints=joints,
        offsets=offsets_from_dict(data.get("offsets", {})),
        bone_lengths=_numbers(data, "bone_lengths"),
        orientations={str(k): read_array(v, (4,), f"orientations.{k}")
                      for k, v in data["orientations"].items()},
        quality=_quality(data),
        warnings=tuple(str(w) for w in data.get("warnings", [])),
        timings=_numbers(data, "timings"),
    )


def offsets_from_dict(data: Mapping[str, Any]) -> dict[str, JointOffset]:
    """Joint offsets from the ``offsets`` object of a skeleton document,
    ``{"<joint>": {"sensor": "<segment>", "local": [x, y, z]}}`` (metres).

    Raises
    ------
    InputError
        ``field="offsets.<joint>"`` for an entry that is not a sensor name and three finite
        numbers.
    """
    if not isinstance(data, Mapping):
        raise InputError("offsets must be an object", field="offsets")
    offsets = {}
    for k, v in data.items():
        try:
            local = np.asarray(v["local"], dtype=float)
            sensor = v["sensor"]
        except (TypeError, KeyError, ValueError):
            local, sensor = np.empty(0), None
        if local.shape != (3,) or not np.isfinite(local).all() or not isinstance(sensor, str):
            raise InputError(f"offsets.{k} must be {{\"sensor\": ..., \"local\": [x, y, z]}}",
                             field=f"offsets.{k}")
        offsets[str(k)] = JointOffset(sensor=sensor, local=local)
    return offsets


def offsets_to_dict(offsets: Mapping[str, JointOffset], *,
                    decimals: int = 6) -> dict[str, dict[str, Any]]:
    """The ``offsets`` object of a skeleton document (and the ``offsets`` job parameter
    that reuses a calibration), joints in ``model.JOINTS`` order.

    Parameters
    ----------
    offsets : mapping of str to JointOffset
    decimals : int
        Decimal places of the local positions in metres.

    Raises
    ------
    InputError
        ``field="offsets.<joint>"`` for a local position that is not three finite numbers.
    """
    out = {}
    for name in [k for k in JOINTS if k in offsets] + [k for k in offsets if k not in JOINTS]:
        local = np.asarray(offsets[name].local, dtype=float)
        if local.shape != (3,) or not np.isfinite(local).all():
            raise InputError(f"offsets.{name} must be three finite numbers",
                             field=f"offsets.{name}")
        out[name] = {"sensor": offsets[name].sensor, "local": np.round(local, decimals).tolist()}
    return out


def _contacts(value: Any, frames: int) -> NDArray[np.str_]:
    if not isinstance(value, list) or not all(isinstance(c, str) for c in value):
        raise InputError("contacts must be a list of labels", field="contacts")
    if len(value) != frames:
        raise InputError(f"contacts has {len(value)} labels for {frames} frames",
                         field="contacts")
    return np.asarray(value, dtype=np.str_)


def _frame_count(data: Mapping[str, Any], arrays: Mapping[str, NDArray[np.float64]]) -> int:
    """F: the document's ``frames`` (the first array's rows without it); InputError naming
    an array of another length."""
    frames = data.get("frames", next(iter(arrays.values())).shape[0])
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        raise InputError(f"frames must be a positive count, got {frames!r}", field="frames")
    for key, array in arrays.items():
        if array.shape[0] != frames:
            raise InputError(f"{key} has {array.shape[0]} rows for {frames} frames", field=key)
    return frames


def translation_from_dict(data: Mapping[str, Any]) -> TranslationResult:
    """Rebuild a TranslationResult from its JSON document (``io.translation_to_dict``).

    Parameters
    ----------
    data : mapping
        The parsed document (docs/translation.md): ``root``, ``translation`` (F, 3) and
        ``floor`` (F,) in metres, +Y up; ``contacts`` (F labels); ``quality``; ``timings``.

    Returns
    -------
    TranslationResult
        With ``positions`` None: the document does not carry every joint's path. The
        members that describe the input rather than the result (``root_joint``, ``time``,
        ``feet``, ``foot_heights``, ``input_length_unit_m``, ``notes``) are not read.

    Raises
    ------
    InputError
        If ``data`` is not a translation document, or a member has the wrong type, shape or
        number of frames (``field`` names it).
    """
    data = _check_document(data, TRANSLATION_KIND,
                           ("method", "fps", "root", "translation", "floor", "contacts"),
                           ("quality", "timings"))
    if data.get("up", "+Y") != "+Y":
        raise InputError(f"translation document up must be '+Y', got {data['up']!r}",
                         field="up")
    arrays = {"root": read_array(data["root"], (3,), "root"),
              "translation": read_array(data["translation"], (3,), "translation"),
              "floor": read_array(data["floor"], (), "floor")}
    frames = _frame_count(data, arrays)
    return TranslationResult(
        root=arrays["root"], translation=arrays["translation"], positions=None,
        contacts=_contacts(data["contacts"], frames), floor=arrays["floor"],
        quality=TranslationQuality.of(dict(data.get("quality", {}))), method=str(data["method"]),
        fps=read_number(data["fps"], "fps"), timings=_numbers(data, "timings"))


def result_from_dict(data: Mapping[str, Any]) -> SkeletonResult | TranslationResult:
    """The result of a result JSON document, by its ``kind`` (``skeleton`` or
    ``translation``).

    Raises
    ------
    InputError
        ``field="kind"`` for another kind; otherwise as the reader of that kind.
    """
    kind = data.get("kind") if isinstance(data, Mapping) else None
    if kind == TRANSLATION_KIND:
        return translation_from_dict(data)
    if kind == SKELETON_KIND:
        return skeleton_from_dict(data)
    raise InputError(f"result document of kind {kind!r}: expected 'skeleton' or "
                     "'translation'", field="kind")
