"""Housekeeping between jobs and in the API process: each step on its own, failures logged."""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping

from .reaper import reap
from .retention import purge
from .runtime import Runtime

log = logging.getLogger("bonefit.worker")

Step = Callable[[Runtime], object]


def housekeeping(runtime: Runtime, steps: Mapping[str, Step]) -> list[str]:
    """Run each step (reap, purge, ...) on its own; the names of those that failed, logged."""
    failed = []
    for name, step in steps.items():
        try:
            step(runtime)
        except Exception:
            log.exception("housekeeping: %s failed; retrying on the next pass", name)
            failed.append(name)
    return failed


WORKER_STEPS: Mapping[str, Step] = {"reap": reap, "purge": purge}
"""The housekeeping every worker does between jobs."""
