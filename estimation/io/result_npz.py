"""Results as NPZ: the JSON document's per-frame arrays as binary members, the rest as JSON.

An NPZ result holds one ``.npy`` member per array of the JSON document, named by its path in
the document (``joints/l_knee``, ``orientations/pelvis``, ``root``), at full precision
(float64, not rounded as in the JSON), and a member ``document``: the JSON document itself
(a string) with each such array replaced by its member's name. Plain numpy reads it::

    import json
    import numpy as np

    with np.load("take.npz") as npz:
        document = json.loads(str(npz["document"]))
        knee = npz[document["joints"]["l_knee"]]        # (F, 3), metres

The archive is written uncompressed (the arrays at disk speed; float64 samples of motion
barely compress) and read back within the limits of :mod:`bonefit.estimation.io.limits`.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from typing import Any, Final

import numpy as np

from ..errors import InputError
from ..numtext import JsonArray
from . import limits

PathLike = str | os.PathLike[str]

DOCUMENT: Final[str] = "document"
"""Name of the member holding the JSON document."""


def _members(document: Any, path: str, arrays: dict[str, Any]) -> Any:
    """``document`` with each JsonArray replaced by its member name (collected in
    ``arrays``)."""
    if isinstance(document, JsonArray):
        arrays[path] = np.ascontiguousarray(document.values, dtype=float)
        return path
    if isinstance(document, Mapping):
        return {k: _members(v, f"{path}/{k}" if path else str(k), arrays)
                for k, v in document.items()}
    if isinstance(document, list | tuple):
        return [_members(v, f"{path}/{i}", arrays) for i, v in enumerate(document)]
    return document


def write_document_npz(document: Mapping[str, Any], path: PathLike) -> None:
    """Write a result document (JSON types and
    :class:`~bonefit.estimation.numtext.JsonArray`) as an NPZ archive.

    Parameters
    ----------
    document : mapping
        A result's JSON document whose per-frame arrays are ``JsonArray``.
    path : path
        Written as given (no ``.npz`` appended).
    """
    arrays: dict[str, Any] = {}
    arrays[DOCUMENT] = np.asarray(json.dumps(_members(document, "", arrays), allow_nan=False))
    with open(path, "wb") as handle:
        np.savez(handle, allow_pickle=False, **arrays)


def read_document_npz(path: PathLike) -> dict[str, Any]:
    """The document of an NPZ result, its arrays in place (numpy arrays).

    Raises
    ------
    InputError
        Not an NPZ archive, no ``document`` member, a document that is not a JSON object,
        a member it names missing or unreadable; LimitError beyond the archive limits.
    """
    with limits.open_npz(path) as archive:
        text = str(limits.load_npy(archive, DOCUMENT, kinds="U"))
        try:
            document = json.loads(text)
        except (json.JSONDecodeError, RecursionError):
            raise InputError("the NPZ member 'document' is not a JSON document",
                             field=DOCUMENT) from None
        if not isinstance(document, dict):
            raise InputError("the NPZ member 'document' is not a JSON object", field=DOCUMENT)
        names = set(archive.namelist())
        return dict(_resolve(document, archive, names))


def _resolve(document: Any, archive: Any, names: set[str]) -> Any:
    """``document`` with every string naming an array member replaced by that array."""
    if isinstance(document, str) and f"{document}.npy" in names and document != DOCUMENT:
        return limits.load_npy(archive, document)
    if isinstance(document, Mapping):
        return {k: _resolve(v, archive, names) for k, v in document.items()}
    if isinstance(document, list):
        return [_resolve(v, archive, names) for v in document]
    return document
