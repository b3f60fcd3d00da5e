"""``threads.run_each``: the independent pieces of an estimate on a small thread pool —
results in order whatever the scheduling, failures and cancels propagating, progress from
the calling thread only, and one thread where the machine or the recording is small."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np
import pytest

from bonefit.estimation import threads
from bonefit.estimation.recording import SensorRecording
from bonefit.estimation.results import SkeletonResult
from bonefit.estimation.skeleton import estimate_skeleton
from bonefit.estimation.threads import MIN_FRAMES, Cancelled, Report, run_each

LONG = MIN_FRAMES


def sleeper(value: int, delay: float, steps: int = 5) -> Callable[[Report], int]:
    def task(report: Report) -> int:
        for k in range(steps):
            time.sleep(delay / steps)
            report((k + 1) / steps)
        return value
    return task


@pytest.fixture
def two_workers(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(threads, "workers", lambda: 2)


@pytest.mark.usefixtures("two_workers")
def test_results_keep_the_order_of_the_tasks_whatever_finishes_first() -> None:
    tasks = [sleeper(0, 0.3), sleeper(1, 0.01), sleeper(2, 0.1), sleeper(3, 0.0)]
    assert run_each(tasks, lambda f, s: None, "x", frames=LONG) == [0, 1, 2, 3]


@pytest.mark.usefixtures("two_workers")
def test_pieces_overlap_and_progress_comes_from_the_calling_thread_in_order() -> None:
    seen: list[tuple[float, str, str]] = []
    names: set[str] = set()

    def task(report: Report) -> str:
        names.add(threading.current_thread().name)
        for k in range(10):
            time.sleep(0.02)
            report((k + 1) / 10)
        return threading.current_thread().name

    def progress(fraction: float, stage: str) -> None:
        seen.append((fraction, stage, threading.current_thread().name))

    ran_on = run_each([task, task], progress, "limbs", frames=LONG, weights=[1.0, 3.0])
    assert len(set(ran_on)) == 2
    assert threading.current_thread().name not in ran_on
    fractions = [f for f, _, _ in seen]
    assert fractions == sorted(fractions)
    assert fractions[-1] == 1.0
    assert len(fractions) >= 3  # reports while the pieces run, not only at the end
    assert {s for _, s, _ in seen} == {"limbs"}
    assert {t for _, _, t in seen} == {threading.current_thread().name}


@pytest.mark.usefixtures("two_workers")
def test_the_first_failure_in_task_order_propagates_after_the_others_stop() -> None:
    stopped: list[int] = []

    def failing(message: str, delay: float) -> Callable[[Report], None]:
        def task(report: Report) -> None:
            time.sleep(delay)
            raise ValueError(message)
        return task

    def long_running(report: Report) -> None:
        try:
            for _ in range(1000):
                time.sleep(0.01)
                report(0.5)
        except Cancelled:
            stopped.append(1)
            raise

    with pytest.raises(ValueError, match="first"):
        run_each([long_running, failing("first", 0.05), failing("second", 0.0)],
                 lambda f, s: None, "x", frames=LONG)
    assert stopped == [1]  # it stopped at its next report, and was waited for


@pytest.mark.usefixtures("two_workers")
def test_a_progress_callback_raising_cancels_promptly() -> None:
    started: list[int] = []

    def task(i: int) -> Callable[[Report], int]:
        def run(report: Report) -> int:
            started.append(i)
            for _ in range(500):
                time.sleep(0.01)
                report(0.1)
            return i
        return run

    class Stop(Exception):
        pass

    def progress(fraction: float, stage: str) -> None:
        if fraction > 0:
            raise Stop

    begin = time.monotonic()
    with pytest.raises(Stop):
        run_each([task(i) for i in range(6)], progress, "x", frames=LONG)
    assert time.monotonic() - begin < 4.0  # each piece alone runs 5 s
    assert len(started) <= 2  # the pieces not started were dropped


def test_one_worker_or_a_short_recording_runs_in_the_calling_thread(
        monkeypatch: pytest.MonkeyPatch) -> None:
    here = threading.current_thread().name

    def name(report: Report) -> str:
        report(0.5)
        return threading.current_thread().name

    seen: list[float] = []
    monkeypatch.setattr(threads, "workers", lambda: 2)
    assert run_each([name, name], lambda f, s: seen.append(f), "x",
                    frames=MIN_FRAMES - 1) == [here, here]
    assert seen == [0.25, 0.5, 0.75, 1.0]
    seen.clear()
    tenths = [name] * 10  # ten shares of 0.1 sum to 0.9999999999999999; the run ends at 1
    run_each(tenths, lambda f, s: seen.append(f), "x", frames=MIN_FRAMES - 1)
    assert seen[-1] == 1.0
    assert run_each([name, name], lambda f, s: None, "x", frames=LONG,
                    threaded=False) == [here, here]
    monkeypatch.setattr(threads, "workers", lambda: 1)
    assert run_each([name, name], lambda f, s: None, "x", frames=LONG) == [here, here]


def test_workers_is_one_on_a_one_core_machine(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("os.sched_getaffinity", lambda pid: {0})
    assert threads.workers() == 1
    monkeypatch.setattr("os.sched_getaffinity", lambda pid: {0, 1, 2, 3})
    assert threads.workers() == threads.MAX_WORKERS == 2


def test_weights_must_match_the_tasks() -> None:
    with pytest.raises(ValueError, match="expected 2 positive weights"):
        run_each([sleeper(0, 0), sleeper(1, 0)], lambda f, s: None, "x", frames=LONG,
                 weights=[1.0])


def estimate_on(workers: int, rec: SensorRecording, method: str,
                monkeypatch: pytest.MonkeyPatch) -> SkeletonResult:
    """``estimate_skeleton`` with ``workers`` threads, whatever the recording's length."""
    monkeypatch.setattr(threads, "MIN_FRAMES", 0)
    monkeypatch.setattr(threads, "workers", lambda: workers)
    return estimate_skeleton(rec, method=method)


@pytest.mark.parametrize(("suit", "method"), [("sim15", "auto"), ("sim11", "auto"),
                                              ("sim11", "reduced"), ("sim15", "llsf")])
def test_the_estimate_on_threads_is_the_estimate_in_one_thread(
        suit: str, method: str, request: pytest.FixtureRequest,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Bit for bit, warnings and quality figures in the same order: the pieces are
    independent and merged in a fixed order, whatever the scheduling."""
    rec = request.getfixturevalue(suit)[0]
    one = estimate_on(1, rec, method, monkeypatch)
    for _ in range(2):
        two = estimate_on(2, rec, method, monkeypatch)
        assert list(two.joints) == list(one.joints)
        for name, path in one.joints.items():
            assert np.array_equal(two.joints[name], path), name
            assert np.array_equal(two.offsets[name].local, one.offsets[name].local), name
        assert two.warnings == one.warnings
        assert [dict(q) for q in two.quality.values()] == [dict(q) for q in one.quality.values()]
        for seg, rot in one.orientations.items():
            assert np.array_equal(two.orientations[seg], rot), seg


def test_a_cancel_in_a_threaded_stage_stops_the_estimate(
        sim15: tuple[SensorRecording, object], monkeypatch: pytest.MonkeyPatch) -> None:
    """The progress callback raising in the limbs (two limbs running) propagates, and no
    piece goes on running behind it."""
    monkeypatch.setattr(threads, "MIN_FRAMES", 0)
    monkeypatch.setattr(threads, "workers", lambda: 2)
    before = threading.active_count()
    seen: list[str] = []

    class Stop(Exception):
        pass

    def progress(fraction: float, stage: str) -> None:
        seen.append(stage)
        if seen.count("limbs") == 3:  # the first is before the pool starts
            raise Stop

    with pytest.raises(Stop):
        estimate_skeleton(sim15[0], progress=progress)
    assert seen.count("limbs") == 3
    assert threading.active_count() == before


@pytest.mark.usefixtures("two_workers")
def test_batches_are_one_piece_on_a_short_recording_only(monkeypatch: pytest.MonkeyPatch
                                                         ) -> None:
    assert threads.batches(3, frames=MIN_FRAMES - 1) == [range(3)]
    assert threads.batches(3, frames=LONG) == [range(0, 1), range(1, 2), range(2, 3)]
    assert threads.batches(0, frames=1) == threads.batches(0, frames=LONG) == []
    # one worker: a long take's items still one by one, each reporting when it is done
    monkeypatch.setattr(threads, "workers", lambda: 1)
    assert threads.batches(3, frames=LONG) == [range(0, 1), range(1, 2), range(2, 3)]
