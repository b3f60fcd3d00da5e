"""Threads: one BLAS thread per process, and a small pool for the independent pieces of one
estimate (``run_each``).

The estimators multiply many small matrices (a 4096 × 49 product per joint and block); a
threaded BLAS gains nothing on them and, on a machine whose cores are busy, made such a product
60× slower. The service's workers and the ``bonefit skeleton`` / ``bonefit translate`` commands
run with one BLAS thread; the variables must be set before numpy is first imported.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, MutableMapping, Sequence
from concurrent.futures import FIRST_EXCEPTION, Future, ThreadPoolExecutor, wait
from typing import Any, Final, TypeVar

from .progress import Progress, scaled

BLAS_LIMITS: Final[dict[str, str]] = {
    "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
    "NUMEXPR_NUM_THREADS": "1", "VECLIB_MAXIMUM_THREADS": "1"}
"""The environment of a process using one BLAS thread (OpenBLAS, MKL, Accelerate, OpenMP)."""


def limit_blas_threads(environ: MutableMapping[str, str] = os.environ) -> None:
    """Set each variable of :data:`BLAS_LIMITS` that ``environ`` does not set already (a
    user's own choice stays). Effective in this process only before numpy is imported."""
    for name, value in BLAS_LIMITS.items():
        environ.setdefault(name, value)


MAX_WORKERS: Final[int] = 2
"""Threads of :func:`run_each`: the independent pieces of one estimate (sensors, joints,
limbs) run two at a time, on a long take the two cores this service was sized for; more
would only share them."""

MIN_FRAMES: Final[int] = 20_000
"""Frames below which :func:`run_each` runs its pieces in the calling thread: on shorter
recordings numpy's operations are too short to overlap, and the threads only cost."""

POLL_S: Final[float] = 0.05
"""How often :func:`run_each`'s calling thread passes the pieces' progress on, seconds."""

T = TypeVar("T")
Report = Callable[[float], None]
"""A piece's ``report(fraction)``: its own progress in [0, 1]."""


def workers() -> int:
    """Threads for :func:`run_each`: ``MAX_WORKERS``, at most the CPUs this process may
    use (one on a one-core machine: the pieces then run in the calling thread)."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not on every platform
        cpus = os.cpu_count() or 1
    return max(1, min(MAX_WORKERS, cpus))


def batches(n: int, *, frames: int) -> list[range]:
    """Items ``0 .. n - 1`` grouped into the pieces of :func:`run_each`: one group of all of
    them on a short recording (fewer than ``MIN_FRAMES`` frames), as one vectorised step over
    all costs less than ``n`` small ones; one group per item on a long one, so that the pieces
    overlap on two workers and, on one, each reports progress when it is done."""
    if frames < MIN_FRAMES:
        return [range(n)] if n else []
    return [range(k, k + 1) for k in range(n)]


class Cancelled(Exception):
    """Raised by a piece's ``report`` in :func:`run_each` once another piece failed or the
    progress callback raised: the piece stops there."""


def run_each(tasks: Sequence[Callable[[Report], T]], progress: Progress, stage: str, *,
             frames: int, weights: Sequence[float] | None = None,
             threaded: bool = True) -> list[T]:
    """Run independent pieces of work on a few threads; their results in the order of
    ``tasks``, whatever the order they finish in.

    Parameters
    ----------
    tasks : sequence of callable
        Each called as ``task(report)``, ``report(fraction)`` its progress in [0, 1]. numpy
        releases the GIL in operations on large arrays: the pieces of a long take overlap.
        A piece must not depend on another's result or side effects.
    progress : callable
        ``progress(fraction, stage)``, called from the calling thread only: the weighted sum
        of the pieces' fractions whenever it grew (checked every ``POLL_S`` seconds), and 1
        at the end. It may raise to cancel: the pieces not started are dropped, the running
        ones stop at their next report, and its exception propagates.
    stage : str
        The stage passed to ``progress``.
    frames : int
        Frames of the recording: below ``MIN_FRAMES`` (or with one worker, ``workers``) the
        pieces run one after the other in the calling thread, with the same results.
    weights : sequence of float, optional
        Each piece's share of the work, positive (default equal).
    threaded : bool, default True
        False: in the calling thread, whatever the length (pieces that mostly hold the GIL,
        such as an optimiser's many small steps, only contend for it on threads).

    Returns
    -------
    list
        ``tasks[i](report)`` at ``i``.

    Raises
    ------
    Exception
        The exception of the first piece that failed (in the order of ``tasks``), once the
        running pieces have stopped; or the exception of ``progress``.
    """
    shares = _shares(len(tasks), weights)
    if not threaded or workers() == 1 or len(tasks) <= 1 or frames < MIN_FRAMES:
        return _run_inline(tasks, shares, progress, stage)
    done = [0.0] * len(tasks)
    stop = threading.Event()

    def piece(i: int) -> T:
        def report(fraction: float) -> None:
            if stop.is_set():
                raise Cancelled
            done[i] = max(done[i], min(max(fraction, 0.0), 1.0))

        report(0.0)
        result = tasks[i](report)
        done[i] = 1.0
        return result

    with ThreadPoolExecutor(workers(), thread_name_prefix="bonefit") as pool:
        futures = [pool.submit(piece, i) for i in range(len(tasks))]
        try:
            _follow(futures, done, shares, progress, stage)
        finally:
            stop.set()  # nothing left to stop when every piece succeeded
            for future in futures:
                future.cancel()
            wait(futures)
    for future in futures:
        error = None if future.cancelled() else future.exception()
        if error is not None and not isinstance(error, Cancelled):
            raise error
    results = [future.result() for future in futures]
    progress(1.0, stage)
    return results


def _shares(n: int, weights: Sequence[float] | None) -> list[float]:
    """Each piece's share of the whole, summing to 1."""
    if weights is None:
        return [1.0 / max(n, 1)] * n
    if len(weights) != n or not all(w > 0 for w in weights):
        raise ValueError(f"expected {n} positive weights, got {list(weights)}")
    total = float(sum(weights))
    return [w / total for w in weights]


def _run_inline(tasks: Sequence[Callable[[Report], T]], shares: Sequence[float],
                progress: Progress, stage: str) -> list[T]:
    """``run_each`` in the calling thread: the pieces one after the other."""
    results = []
    start = 0.0
    for k, (task, share) in enumerate(zip(tasks, shares, strict=True)):
        # the last piece ends at 1 exactly, as the threaded run does (the shares' sum may not)
        stop = 1.0 if k == len(tasks) - 1 else min(start + share, 1.0)
        outer = scaled(progress, start, stop)
        results.append(task(staged(outer, stage)))
        outer(1.0, stage)
        start = stop
    return results


def staged(progress: Progress, stage: str) -> Report:
    """``progress(fraction, stage)`` as a piece's ``report(fraction)``."""
    def report(fraction: float) -> None:
        progress(fraction, stage)
    return report


def unstaged(report: Report) -> Progress:
    """A piece's ``report(fraction)`` as a progress callback (the stage dropped)."""
    def progress(fraction: float, _stage: str) -> None:
        report(fraction)
    return progress


def ignore(fraction: float) -> None:
    """A ``Report`` that ignores every report."""


def _follow(futures: Sequence[Future[Any]], done: Sequence[float], shares: Sequence[float],
            progress: Progress, stage: str) -> None:
    """Pass the pieces' progress on until every one finished or one failed."""
    reported = 0.0
    pending: set[Future[Any]] = set(futures)
    while pending:
        _finished, pending = wait(pending, timeout=POLL_S, return_when=FIRST_EXCEPTION)
        if any(f.done() and f.exception() is not None for f in futures):
            return
        fraction = min(sum(d * s for d, s in zip(done, shares, strict=True)), 1.0)
        if fraction > reported:
            progress(fraction, stage)
            reported = fraction
