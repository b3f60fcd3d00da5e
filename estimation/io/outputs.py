"""The files a skeleton result is written to (standard library only: the CLI builds them
before it imports numpy's writers)."""

from __future__ import annotations

import os
from dataclasses import dataclass

PathLike = str | os.PathLike[str]


@dataclass(frozen=True)
class SkeletonOutputs:
    """Files a skeleton result is written to; None: skip. JSON (metres), BVH (cm), CSV
    (metres), NPZ (the JSON's names, arrays binary; metres)."""

    json: PathLike | None = None
    bvh: PathLike | None = None
    csv: PathLike | None = None
    npz: PathLike | None = None
    bvh_slip_chains: bool = True
    """The BVH's joints exactly where the JSON has them (``skeleton_to_bvh``'s slip chains,
    only where a joint strays from the rigid skeleton: none for ``auto``)."""
