"""Threads of the numerical libraries: one BLAS thread per process.

The estimators multiply many small matrices (a 4096 × 49 product per joint and block); a
threaded BLAS gains nothing on them and, on a machine whose cores are busy, made such a product
60× slower. The service's workers and the ``bonefit skeleton`` / ``bonefit translate`` commands
run with one BLAS thread; the variables must be set before numpy is first imported.
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping
from typing import Final

BLAS_LIMITS: Final[dict[str, str]] = {
    "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
    "NUMEXPR_NUM_THREADS": "1", "VECLIB_MAXIMUM_THREADS": "1"}
"""The environment of a process using one BLAS thread (OpenBLAS, MKL, Accelerate, OpenMP)."""


def limit_blas_threads(environ: MutableMapping[str, str] = os.environ) -> None:
    """Set each variable of :data:`BLAS_LIMITS` that ``environ`` does not set already (a
    user's own choice stays). Effective in this process only before numpy is imported."""
    for name, value in BLAS_LIMITS.items():
        environ.setdefault(name, value)
