"""Process memory: keep freed memory for reuse instead of handing it back to the system.

A long take's estimate and writers allocate and free arrays of a few megabytes thousands of
times (one per numpy temporary over every frame). glibc's malloc serves such blocks from
their own ``mmap`` (from 128 KiB, a threshold it raises as blocks are freed) and returns the
free top of its heaps to the system once it exceeds twice that: every new array then starts
on fresh pages, which the kernel faults in and zeroes one by one. A CLI run on the
144,000-frame 11-sensor take of ``benchmarks/long_take.py`` took 350,000-400,000 minor page
faults and 1.7-2.7 s of system time of its 10-12 s of CPU (100,000-210,000 and 1.0-1.5 s
with these thresholds). :func:`retain_freed_memory` raises both thresholds once, for the estimating
commands (``bonefit skeleton``, ``bonefit translate``): blocks up to
:data:`MMAP_THRESHOLD_BYTES` come from the heap, and up to :data:`TRIM_THRESHOLD_BYTES` of its
free top stay mapped for the next ones.
"""

from __future__ import annotations

import ctypes
import os
from collections.abc import Mapping
from typing import Final

MMAP_THRESHOLD_BYTES: Final[int] = 32 << 20
"""Blocks at least this large get their own ``mmap`` (glibc's largest dynamic threshold, 32
MiB on 64-bit systems: an array of 1.4M float64; a long take's per-frame temporaries are
below it, its whole tables above)."""

TRIM_THRESHOLD_BYTES: Final[int] = 256 << 20
"""Free memory at the top of a heap kept mapped (glibc's dynamic one: twice the mmap
threshold)."""

_M_TRIM_THRESHOLD: Final[int] = -1  # mallopt parameters, <malloc.h>
_M_MMAP_THRESHOLD: Final[int] = -3


def retain_freed_memory(environ: Mapping[str, str] = os.environ) -> bool:
    """Set glibc malloc's mmap and trim thresholds (``mallopt``) to
    :data:`MMAP_THRESHOLD_BYTES` and :data:`TRIM_THRESHOLD_BYTES`, unless ``environ`` sets
    malloc's own (``MALLOC_*_`` variables or a ``glibc.malloc`` tunable: a user's choice
    stays). Whether they were set: False without glibc (no ``mallopt``: other C libraries
    keep their own policy), or when the user's choice stays. Results do not change: only
    where freed blocks go."""
    tunables = environ.get("GLIBC_TUNABLES", "")
    if "glibc.malloc." in tunables or any(
            name.startswith("MALLOC_") and name.endswith("_") for name in environ):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError, TypeError):  # TypeError: no CDLL(None) (Windows)
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    # the mmap threshold first: setting either turns glibc's dynamic thresholds off
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(
        mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
