"""The progress-callback convention shared by every long-running estimation function."""

from __future__ import annotations

from collections.abc import Callable

Progress = Callable[[float, str], None]
"""``progress(fraction, stage)``: ``fraction`` in [0, 1], non-decreasing; ``stage`` a short
lower-case label such as ``"joints"``. A callback may raise to abort the computation."""


def no_progress(fraction: float, stage: str) -> None:
    """Progress callback that ignores every report."""


def scaled(progress: Progress | None, start: float, stop: float) -> Progress:
    """A callback mapping [0, 1] onto [start, stop] of ``progress`` (for nested stages)."""
    target = progress or no_progress

    def report(fraction: float, stage: str) -> None:
        # exactly ``stop`` at 1 (``start + (stop − start)`` may round above it, and a caller's
        # next report at ``stop`` would then go backwards)
        share = min(max(fraction, 0.0), 1.0)
        target(stop if share == 1.0 else start + (stop - start) * share, stage)

    return report
