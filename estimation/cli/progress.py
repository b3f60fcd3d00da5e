"""A progress bar on stderr, fed by the estimation ``progress(fraction, stage)`` callback."""

from __future__ import annotations

import sys
import time
from typing import TextIO


class ProgressBar:
    """Callable progress reporter drawing ``stage [#####     ]  42%`` on a terminal.

    On a non-terminal stream it prints one line per stage instead of redrawing.
    """

    def __init__(self, stream: TextIO | None = None, width: int = 30,
                 min_interval: float = 0.1) -> None:
        self.stream = stream or sys.stderr
        self.width = width
        self.min_interval = min_interval
        self._last = 0.0
        self._stage = ""
        self._tty = self.stream.isatty()

    def __call__(self, fraction: float, stage: str) -> None:
        now = time.monotonic()
        new_stage = stage != self._stage
        if not new_stage and fraction < 1.0 and now - self._last < self.min_interval:
            return
        self._last = now
        self._stage = stage
        if self._tty:
            done = round(fraction * self.width)
            bar = "#" * done + " " * (self.width - done)
            self.stream.write(f"\r{stage:<12} [{bar}] {fraction:4.0%}")
            self.stream.flush()
        elif new_stage:
            self.stream.write(f"{fraction:4.0%} {stage}\n")

    def close(self) -> None:
        """End the bar's line."""
        if self._tty:
            self.stream.write("\n")
            self.stream.flush()
