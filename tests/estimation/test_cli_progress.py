"""The command line's progress bar: rate and remaining time from the reports."""

from __future__ import annotations

import io

from bonefit.estimation.cli.progress import LOG_INTERVAL, ProgressBar, clock


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_a_terminal_shows_frames_per_second_and_the_time_left() -> None:
    out, now = Terminal(), Clock()
    bar = ProgressBar(out, width=10, now=now)
    bar.stage("reading")
    bar.frames = 24_000
    bar(0.0, "joints")
    now.now += 2.0
    bar(0.25, "joints")  # 6,000 frames in 2 s: 3,000 frames/s, 6 s to go
    last = out.getvalue().rsplit("\r", 1)[-1]
    assert last.startswith("joints       [##        ]  25%  3,000 frames/s  ETA 0:06")
    now.now += 6.0
    bar(1.0, "joints")
    assert "3,000 frames/s  in 0:08" in out.getvalue().rsplit("\r", 1)[-1]
    bar.stage("writing")
    assert out.getvalue().rsplit("\r", 1)[-1].rstrip() == "writing (24,000 frames)"


def test_a_log_gets_a_line_per_stage_and_every_interval() -> None:
    out, now = io.StringIO(), Clock()
    bar = ProgressBar(out, now=now)
    bar(0.0, "joints")
    now.now += 1.0
    bar(0.1, "joints")  # within the interval: no line
    now.now += LOG_INTERVAL
    bar(0.5, "joints")  # no frame count known: the time left only
    bar(0.6, "orientations")
    assert out.getvalue().splitlines() == [
        "  0% joints", " 50% joints  ETA 0:11", " 60% orientations  ETA 0:07"]


def test_durations_read_as_a_clock() -> None:
    assert [clock(s) for s in (0, 59.6, 61, 3600 * 2 + 5)] == ["0:00", "1:00", "1:01",
                                                               "2:00:05"]


def test_a_log_gets_no_line_for_the_start_of_the_read() -> None:
    """A run's first report (reading at 0) draws nothing on a log; its later reports do, and
    the time left is that of the whole run."""
    out, now = io.StringIO(), Clock()
    bar = ProgressBar(out, now=now)
    bar(0.0, "reading")
    assert out.getvalue() == ""
    now.now += LOG_INTERVAL
    bar(0.05, "reading")  # same stage, an interval later: 5 % of the run in 10 s
    bar.frames = 1000
    bar(0.1, "gaps")
    assert out.getvalue().splitlines() == [
        "  5% reading  ETA 3:10", " 10% gaps  10 frames/s  ETA 1:30"]
