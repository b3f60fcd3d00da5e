"""The Python client of the bonefit REST service.

``pip install 'bonefit[client]'`` (httpx and numpy; not the service stack)::

    from bonefit.client import Client

    with Client("http://127.0.0.1:8000", api_key=None) as client:
        result = client.run("walk.csv", "skeleton", {"method": "auto"})
        print(result.bone_lengths["l_thigh"], result.joints["l_knee"].shape)

Results are the library's dataclasses (``bonefit.estimation.results.SkeletonResult``,
``TranslationResult``), read from the JSON by the library's numpy-only reader
(:func:`result_from_dict`). :class:`AsyncClient` offers the same calls to ``await``. Every
problem answer of the service is a :class:`ProblemError` carrying the RFC 9457 document.
"""

from __future__ import annotations

from .aio import AsyncClient
from .errors import ProblemError
from .results import (
    Job,
    JointOffset,
    JointQuality,
    Recording,
    Result,
    SkeletonResult,
    TranslationQuality,
    TranslationResult,
    result_from_dict,
)
from .sync import Client
from .transport import RetryPolicy

__all__ = [
    "AsyncClient",
    "Client",
    "Job",
    "JointOffset",
    "JointQuality",
    "ProblemError",
    "Recording",
    "Result",
    "RetryPolicy",
    "SkeletonResult",
    "TranslationQuality",
    "TranslationResult",
    "result_from_dict",
]
