"""A progress bar on stderr, fed by the estimation ``progress(fraction, stage)`` callback."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TextIO

LOG_INTERVAL = 10.0
"""Seconds between the lines of an unchanged stage on a non-terminal stream (a log)."""

QUIET_START = frozenset({"reading"})
"""Stages whose report at 0 a log gets no line for (a run's first report, before anything
is known: a bad input's error message then stays the log's only line)."""


def clock(seconds: float) -> str:
    """``m:ss`` (or ``h:mm:ss``) of a duration."""
    minutes, secs = divmod(round(seconds), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


class ProgressBar:
    """Callable progress reporter drawing ``stage [#####     ]  42%  9,800 frames/s  ETA 0:07``
    on a terminal (``42% stage  9,800 frames/s  ETA 0:07`` lines elsewhere).

    The rate and the remaining time are those of the work reported through the callback
    (a whole run of ``pipeline``: read, estimate, writes), from its first report on; the rate
    needs the take's length (:attr:`frames`, set once the recording is read). :meth:`stage`
    shows a stage that reports no fraction on a terminal, with the take's length once
    known. On a non-terminal
    stream it prints a line per reported stage, and every :data:`LOG_INTERVAL` seconds within
    one, instead of redrawing.
    """

    def __init__(self, stream: TextIO | None = None, width: int = 30,
                 min_interval: float = 0.1,
                 now: Callable[[], float] = time.monotonic) -> None:
        self.stream = stream or sys.stderr
        self.width = width
        self.min_interval = min_interval
        self.frames: int | None = None
        self._now = now
        self._last = 0.0
        self._stage = ""
        self._started: float | None = None
        self._tty = self.stream.isatty()

    def __call__(self, fraction: float, stage: str) -> None:
        now = self._now()
        if self._started is None:
            self._started = now
        new_stage = stage != self._stage
        interval = self.min_interval if self._tty else LOG_INTERVAL
        if not new_stage and fraction < 1.0 and now - self._last < interval:
            return
        if not self._tty and fraction <= 0.0 and stage in QUIET_START:
            self._last, self._stage = now, stage
            return
        self._last = now
        self._stage = stage
        rate = self._rate(fraction, now - self._started)
        if self._tty:
            self._draw(f"{stage:<12} [{self._bar(fraction)}] {fraction:4.0%}{rate}")
        else:
            self._draw(f"{fraction:4.0%} {stage}{rate}")

    def stage(self, name: str) -> None:
        """A stage without fractions starts (``"reading"``, ``"writing"``): drawn on a
        terminal; a log (or an error message) gets no line for it."""
        self._last = self._now()
        self._stage = name
        if self._tty:
            frames = f" ({self.frames:,} frames)" if self.frames is not None else ""
            self._draw(f"{name}{frames}")

    def _bar(self, fraction: float) -> str:
        done = round(min(max(fraction, 0.0), 1.0) * self.width)
        return "#" * done + " " * (self.width - done)

    def _rate(self, fraction: float, elapsed: float) -> str:
        """``  9,800 frames/s  ETA 0:07`` (what is known of it)."""
        if fraction <= 0.0 or elapsed <= 0.0:
            return ""
        rate = (f"  {fraction * self.frames / elapsed:,.0f} frames/s"
                if self.frames is not None else "")
        if fraction >= 1.0:
            return f"{rate}  in {clock(elapsed)}"
        return f"{rate}  ETA {clock(elapsed * (1.0 - fraction) / fraction)}"

    def _draw(self, text: str) -> None:
        if self._tty:
            self.stream.write(f"\r{text:<79}")
            self.stream.flush()
        else:
            self.stream.write(f"{text}\n")

    def close(self) -> None:
        """End the bar's line."""
        if self._tty:
            self.stream.write("\n")
            self.stream.flush()
