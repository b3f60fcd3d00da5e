"""The worker: takes job ids from the queue and runs each job under a lease to an end.

A job's life: claimed (compare-and-set, so one worker wins), run in a thread of its own while
its lease is renewed, then succeeded, failed (the input's fault or a limit), cancelled, handed
back on shutdown, or re-queued after an internal error. The lease is ``job_lease.py`` (and the
keeper process ``leases.py``), the problems ``failures.py``; the reaper (``reaper.py``)
recovers the jobs of lost workers; ``housekeeping.py``, ``retention.py``, ``tempdirs.py`` and
``pool.py`` hold the rest of a worker process's life.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import signal
import socket
import tempfile
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from types import FrameType
from typing import Any

from pydantic import ValidationError

from bonefit.estimation import memory
from bonefit.estimation.errors import BonefitError

from .artifacts import tenant_prefix
from .failures import InputFault, internal_problem, job_problem, job_url, log_error
from .housekeeping import WORKER_STEPS, housekeeping
from .job_lease import Cancelled, JobLease, LeaseLost, Requeue
from .jobs import Job, Status
from .kinds import Input, Kind, default_kinds, preload
from .leases import LeaseKeeper
from .limits import memory_limit
from .runtime import Runtime, open_runtime
from .settings import Settings
from .tempdirs import private_tmp

log = logging.getLogger("bonefit.worker")

IDLE_POLL = 1.0
"""Longest wait of an idle worker between looks at the queue: enqueuing wakes it at once,
this is the fallback (and the pace of its heartbeat and housekeeping checks while idle)."""

SUPERVISE_POLL = 0.1
"""Seconds between the checks of the thread watching a running job (shutdown grace)."""


class Worker:
    """Runs the jobs it takes from the queue, one at a time."""

    def __init__(self, runtime: Runtime, kinds: Mapping[str, Kind] | None = None, *,
                 worker_id: str | None = None, clock: Callable[[], float] = time.time,
                 keeper: LeaseKeeper | None = None) -> None:
        self.runtime = runtime
        self.kinds = dict(kinds or default_kinds())
        self.id = worker_id or f"{socket.gethostname()}:{os.getpid()}"
        self.clock = clock
        self.keeper = keeper
        self.stop = threading.Event()
        self.deadline: float | None = None
        self._next_beat = 0.0

    def beat(self) -> None:
        """Register this worker as alive in the store (``/readyz`` counts live workers), at
        most every ``worker_heartbeat_seconds``; a failure is logged, not raised."""
        if time.monotonic() < self._next_beat:
            return
        self._next_beat = time.monotonic() + self.runtime.settings.worker_heartbeat_seconds
        try:
            self.runtime.store.beat_worker(self.id, time.time())
        except Exception:
            log.exception("worker %s: could not record its heartbeat", self.id)

    def _unregister(self) -> None:
        try:
            self.runtime.store.drop_worker(self.id)
        except Exception:
            log.exception("worker %s: could not unregister", self.id)

    def shutdown(self, grace: float | None = None) -> None:
        """Take no new job; hand the running one back after ``grace`` seconds."""
        grace = self.runtime.settings.shutdown_grace_seconds if grace is None else grace
        self.deadline = self.clock() + grace
        self.stop.set()
        self.runtime.queue.interrupt()

    def serve(self, *, poll: float = IDLE_POLL, parent_pid: int | None = None) -> None:
        """Take and run jobs until :meth:`shutdown`; reap and purge periodically.

        An idle worker waits for the queue's wake-up on enqueue, at most ``poll`` seconds.
        """
        try:
            self._serve(poll, parent_pid)
        finally:
            self.runtime.queue.close()
            self._unregister()

    def _serve(self, poll: float, parent_pid: int | None) -> None:
        settings = self.runtime.settings
        next_reap = 0.0
        while not self.stop.is_set():
            if parent_pid is not None and os.getppid() != parent_pid:
                log.warning("parent process %d is gone; worker exits", parent_pid)
                break
            self.beat()
            if self.clock() >= next_reap:
                housekeeping(self.runtime, WORKER_STEPS)
                next_reap = self.clock() + min(settings.lease_seconds / 2, 30.0)
            try:
                worked = self.runtime.queue.run_next(self.run_job)
            except Exception:
                log.exception("queue error; retrying")
                self.stop.wait(1.0)
                continue
            if not worked and not self.stop.is_set():
                self.runtime.queue.idle(poll)

    def run_job(self, job_id: str) -> None:
        """Claim the job and run it to an end (or hand it back); never raises."""
        store, settings = self.runtime.store, self.runtime.settings
        claimed = store.claim(job_id, self.id, self.clock(), settings.lease_seconds)
        if claimed is None:
            self._unclaimed(job_id)
            return
        log.info("job %s (%s): attempt %d on %s", job_id, claimed.kind, claimed.attempts,
                 self.id)
        lease = JobLease(self, claimed)
        lease.start()
        try:
            self._run_claimed(claimed, lease)
        finally:
            lease.stop()

    def _unclaimed(self, job_id: str) -> None:
        """Log why a message's job was not claimed: a duplicate message, or a job cancelled,
        finished or purged meanwhile; or no such job, as when the database crashed before
        the submission became durable (its client was answered with a problem, not 202)."""
        job = self.runtime.store.get_job(job_id)
        if job is None:
            log.warning("job %s: not in the job store; message dropped", job_id)
        else:
            log.info("job %s: %s, not queued; message dropped", job_id, job.status)

    def _run_claimed(self, job: Job, lease: JobLease) -> None:
        """Run the job this worker claimed and record how it ended."""
        store = self.runtime.store
        try:
            results = self._supervise(job, lease)
            # inside the try: a store that cannot record the success is an internal error
            self._recorded(job, Status.SUCCEEDED,
                           store.succeed(job.id, self.id, results, self.clock()))
        except Cancelled:
            self._recorded(job, Status.CANCELLED, store.cancel(job.id, self.id, self.clock()))
        except Requeue:
            if store.hand_back(job, self.id, "re-queued: worker shut down"):
                self.runtime.queue.enqueue(job.id)
                log.info("job %s: handed back to the queue (worker shutting down)", job.id)
        except LeaseLost:
            log.warning("job %s: lease lost; another worker owns it", job.id)
        except Exception as exc:
            self._failed(job, exc)

    def _failed(self, job: Job, exc: Exception) -> None:
        """Fail the job for good when ``exc`` is the input's fault, a limit or a full disk;
        else retry."""
        kind = self.kinds.get(job.kind)
        params = kind.params.model_fields if kind is not None else {}
        error = job_problem(exc, job.id, params, self.runtime.settings.job_timeout_seconds)
        if error is None:
            self._crashed(job, exc, log_error(job.id, exc, "crashed"))
        else:
            self._fail(job, error.body(job_url(job.id)))

    def _supervise(self, job: Job, lease: JobLease) -> dict[str, str]:
        """Run :meth:`_execute` in a thread of its own and watch it from this one.

        This thread keeps the worker's heartbeat and, once the shutdown grace is over, raises
        :class:`Requeue` even when the job never reports progress (a long numerical step), so
        SIGTERM always hands the job back. The job's thread, if still running, is abandoned:
        the process is exiting, and the job's compare-and-set writes name this worker, which
        no longer owns it.
        """
        outcome: dict[str, Any] = {}
        finished = threading.Event()

        def target() -> None:
            try:
                outcome["result"] = self._execute(job, lease)
            except BaseException as exc:
                outcome["error"] = exc
            finally:
                finished.set()

        threading.Thread(target=target, name=f"job-{job.id}", daemon=True).start()
        while not finished.wait(SUPERVISE_POLL):
            self.beat()
            if self.deadline is not None and self.clock() >= self.deadline:
                raise Requeue
        if "error" in outcome:
            raise outcome["error"]
        result: dict[str, str] = outcome["result"]
        return result

    def _execute(self, job: Job, lease: JobLease) -> dict[str, str]:
        store, artifacts = self.runtime.store, self.runtime.artifacts
        kind = self.kinds.get(job.kind)
        if kind is None:
            raise BonefitError(f"unknown job kind {job.kind!r}", field="kind")
        try:
            params = kind.params.model_validate(job.params)
        except ValidationError as exc:
            first = exc.errors()[0]
            field = ".".join(["params", *(str(p) for p in first["loc"])])
            raise BonefitError(f"{field}: {first['msg']}", field=field) from None
        names = {"recording": job.recording_id, **job.inputs}
        with tempfile.TemporaryDirectory(prefix="bonefit-job-") as tmp, \
                contextlib.ExitStack() as stack:
            inputs = {}
            for name, rec_id in names.items():
                rec = store.get_recording(job.tenant, rec_id)
                if rec is None:
                    field = "recording_id" if name == "recording" else f"inputs.{name}"
                    raise BonefitError(f"recording {rec_id!r} was deleted", field=field)
                try:
                    path = stack.enter_context(artifacts.as_file(rec.key))
                except FileNotFoundError:
                    raise BonefitError(f"the bytes of recording {rec_id!r} are gone",
                                       field=name) from None
                inputs[name] = Input(path, rec.format)
            outputs = self._run(kind, inputs, params, lease, Path(tmp))
            lease.check_finished()
            results = {}
            for fmt, path in outputs.items():
                key = f"{tenant_prefix(job.tenant)}/jobs/{job.id}/result.{fmt}"
                artifacts.put_file(key, path)
                results[fmt] = key
        return results

    def _run(self, kind: Kind, inputs: Mapping[str, Input], params: Any, lease: JobLease,
             outdir: Path) -> dict[str, Path]:
        """``kind.run`` under the job's memory limit; a numerical error is the input's."""
        try:
            with memory_limit(self.runtime.settings.job_memory_mb):
                return kind.run(inputs, params, lease.progress, outdir)
        except BonefitError:
            raise
        except (ValueError, ArithmeticError) as exc:
            # numpy and scipy raise these on data they cannot process (non-finite values,
            # singular systems, overflow); the same input fails the same way on every attempt
            raise InputFault(type(exc).__name__) from exc

    def _fail(self, job: Job, error: dict[str, Any]) -> None:
        self._recorded(job, Status.FAILED,
                       self.runtime.store.fail(job.id, self.id, error, self.clock()))

    @staticmethod
    def _recorded(job: Job, status: Status, done: Job | None) -> None:
        """Log the end of ``job``: ``done`` as stored, or None when the lease was lost."""
        if done is None:
            log.warning("job %s: could not record %s (lease lost)", job.id, status)
        else:
            log.info("job %s: %s", job.id, done.status)

    def _crashed(self, job: Job, exc: Exception, error_id: str) -> None:
        """An unexpected error: re-queue (a machine fault may pass) up to ``max_attempts``,
        then fail with a 500 naming the logged ``error_id``."""
        if job.attempts < self.runtime.settings.max_attempts:
            message = (f"re-queued after an internal error ({type(exc).__name__}, "
                       f"error id {error_id})")
            if self.runtime.store.requeue(job.id, self.id, message):
                self.runtime.queue.enqueue(job.id)
            return
        self._fail(job, internal_problem(exc, job.attempts, error_id).body(job_url(job.id)))


def run_worker(settings: Settings, *, parent_pid: int | None = None,
               kinds: Mapping[str, Kind] | None = None) -> int:
    """The body of ``bonefit worker --concurrency 1``: serve until SIGTERM/SIGINT.

    Freed memory is kept for the next job's arrays (``memory.retain_freed_memory``), as the
    CLI's estimating commands keep it: without it every estimate faults in its pages anew."""
    memory.retain_freed_memory()
    # job folders and downloaded inputs go here, so that a killed worker's are found again
    tmp = private_tmp(settings.data_dir)
    previous_tempdir, tempfile.tempdir = tempfile.tempdir, str(tmp)
    runtime = open_runtime(settings)
    worker = Worker(runtime, kinds)
    keeper = worker.keeper = LeaseKeeper(settings, worker.id)
    keeper.start()

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        log.info("worker %s: signal %d, shutting down", worker.id, signum)
        worker.shutdown()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    try:
        preload()
        if not worker.stop.is_set():  # a signal during the preload: never ready, just leave
            log.info("worker %s ready (queue %s)", worker.id,
                     settings.resolved_queue_url.split("@")[-1])
        worker.serve(parent_pid=parent_pid)
    finally:
        keeper.close()
        tempfile.tempdir = previous_tempdir  # the directory is going: callers must not use it
        shutil.rmtree(tmp, ignore_errors=True)
    return 0
