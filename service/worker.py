"""Workers: run jobs under a lease with a heartbeat, report progress, and recover lost jobs."""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from collections.abc import Callable, Mapping
from pathlib import Path
from types import FrameType
from typing import Any

from pydantic import ValidationError

from estimation.errors import BonefitError

from .artifacts import tenant_prefix
from .jobs import PURGE_BATCH, Job
from .kinds import Input, Kind, default_kinds, preload
from .leases import LeaseKeeper
from .limits import MemoryLimitExceeded, memory_limit
from .problems import PROBLEM_TYPE, from_bonefit_error
from .runtime import Runtime, open_runtime
from .settings import Settings

log = logging.getLogger("bonefit.worker")

BLAS_LIMITS = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
               "NUMEXPR_NUM_THREADS": "1", "VECLIB_MAXIMUM_THREADS": "1"}
"""One BLAS thread per worker process: the pool, not BLAS, uses the cores."""

SUPERVISE_POLL = 0.1
"""Seconds between the checks of the thread watching a running job (shutdown grace)."""


class Cancelled(Exception):
    """The client cancelled the job."""


class Requeue(Exception):
    """The worker is shutting down: hand the job back to the queue."""


class LeaseLost(Exception):
    """Another worker or the reaper took the job over."""


class TimedOut(Exception):
    """The job ran longer than ``job_timeout_seconds``."""


def problem(title: str, detail: str, status: int, slug: str, **extensions: Any) -> dict[str, Any]:
    """A problem document for a job's ``error``."""
    return {"type": PROBLEM_TYPE + slug, "title": title, "status": status, "detail": detail,
            **extensions}


class InputFault(Exception):
    """The estimation failed on the job's input with a numerical error (ValueError,
    ArithmeticError) that no reader or check caught: the input's fault, not retried."""


def log_error(job_id: str, exc: BaseException, what: str) -> str:
    """Log ``exc`` with its traceback under a new error id; the id (32 hex digits)."""
    error_id = uuid.uuid4().hex
    log.error("job %s %s [error id %s]", job_id, what, error_id, exc_info=exc)
    return error_id


def input_fault_problem(job_id: str, exc: InputFault, error_id: str) -> dict[str, Any]:
    """422 for a numerical error on the job's input, with the logged error id."""
    return problem("Cannot estimate from this input",
                   f"the estimation failed on this recording or these params ({exc}); check "
                   f"them for extreme or degenerate values. Logged with error id {error_id}",
                   422, "estimation-error", instance=f"/v1/jobs/{job_id}", error_id=error_id)


def memory_problem(job_id: str, limit_mb: int) -> dict[str, Any]:
    """507 for a job that needed more memory than ``job_memory_mb``."""
    return problem("Job exceeded its memory limit",
                   f"the job needed more than the service's limit of {limit_mb} MiB per job "
                   f"(job_memory_mb) and was stopped; use a shorter recording", 507,
                   "memory-limit", instance=f"/v1/jobs/{job_id}", limit_mb=limit_mb)


def reap(runtime: Runtime, now: float | None = None) -> list[str]:
    """Re-queue (or fail, or cancel) running jobs whose lease expired; the ids handled.

    Each job is handled on its own: one that cannot be written (a full disk, a lost
    connection) is retried on the next pass and does not hold the others back.
    """
    now = time.time() if now is None else now
    handled = []
    for job in runtime.store.expired_leases(now):
        try:
            if _reap_one(runtime, job, now):
                handled.append(job.id)
        except Exception:
            log.exception("job %s: could not hand back after its lease expired", job.id)
    return handled + requeue_lost_messages(runtime, now)


def _reap_one(runtime: Runtime, job: Job, now: float) -> bool:
    """Re-queue, fail or cancel one job whose lease expired; whether this call did it."""
    store, settings = runtime.store, runtime.settings
    expect = {"status": "running", "worker": job.worker, "lease_until": job.lease_until}
    lost = {"worker": None, "lease_until": None}
    if job.cancel_requested:
        done = store.update_job(job.id, {**lost, "status": "cancelled", "finished_at": now,
                                         "stage": "cancelled"}, expect=expect)
    elif job.attempts >= settings.max_attempts:
        error = problem("Worker lost", f"the worker running this job stopped responding "
                        f"{job.attempts} times; giving up", 503, "worker-lost",
                        instance=f"/v1/jobs/{job.id}", attempts=job.attempts)
        done = store.update_job(job.id, {**lost, "status": "failed", "finished_at": now,
                                         "stage": "failed", "error": error}, expect=expect)
    else:
        done = store.update_job(job.id, {**lost, "status": "queued", "stage": "queued",
                                         "message": "re-queued: its worker was lost"},
                                expect=expect)
        if done:
            runtime.queue.enqueue(job.id)
    if done:
        log.warning("job %s: lease of %s expired; now %s", job.id, job.worker, done.status)
    return done is not None


def requeue_lost_messages(runtime: Runtime, now: float) -> list[str]:
    """Send again queued jobs that have waited a lease period without a message in the queue.

    A message is lost when a process dies between taking it and claiming the job, between
    storing a job and queueing it, or when the queue or the disk failed at that moment. A
    duplicate is harmless: claiming is compare-and-set.
    """
    stale = runtime.store.stale_queued(now - runtime.settings.lease_seconds)
    if not stale:
        return []
    waiting = runtime.queue.pending()
    sent = []
    for job in stale:
        if job.id in waiting:
            continue
        try:
            touched = runtime.store.update_job(job.id, {}, expect={"status": "queued",
                                                                   "version": job.version})
            if touched:  # updated_at moved on: the next pass waits another lease period
                runtime.queue.enqueue(job.id)
                log.warning("job %s: no queue message after %.0f s; sent again", job.id,
                            now - job.updated_at)
                sent.append(job.id)
        except Exception:
            log.exception("job %s: could not send it again; retrying on the next pass", job.id)
    return sent


def purge(runtime: Runtime, now: float | None = None) -> int:
    """Delete recordings, results and job records older than the retention; how many.

    Rows go in batches of ``PURGE_BATCH`` (each its own transaction, its artifacts deleted
    right after it), so any number of expired rows is purged and a failure keeps what is done.
    """
    ttl = runtime.settings.retention_seconds
    if ttl <= 0:
        return 0
    before = (time.time() if now is None else now) - ttl
    total = 0
    while True:
        recordings, jobs = runtime.store.purge(before, PURGE_BATCH)
        for key in [r.key for r in recordings] + [k for j in jobs for k in j.results.values()]:
            try:
                runtime.artifacts.delete(key)
            except Exception:
                log.exception("could not delete artifact %s", key)
        total += len(recordings) + len(jobs)
        if len(recordings) < PURGE_BATCH and len(jobs) < PURGE_BATCH:
            return total


def housekeeping(runtime: Runtime, steps: Mapping[str, Callable[[Runtime], object]]
                 ) -> list[str]:
    """Run each step (reap, purge, ...) on its own; the names of those that failed, logged."""
    failed = []
    for name, step in steps.items():
        try:
            step(runtime)
        except Exception:
            log.exception("housekeeping: %s failed; retrying on the next pass", name)
            failed.append(name)
    return failed


WORKER_STEPS: Mapping[str, Callable[[Runtime], object]] = {"reap": reap, "purge": purge}
"""The housekeeping every worker does between jobs."""


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

    def serve(self, *, poll: float = 0.2, parent_pid: int | None = None) -> None:
        """Take and run jobs until :meth:`shutdown`; reap and purge periodically."""
        try:
            self._serve(poll, parent_pid)
        finally:
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
            if not worked:
                self.stop.wait(poll)

    def run_job(self, job_id: str) -> None:
        """Claim the job and run it to an end (or hand it back); never raises."""
        store, settings = self.runtime.store, self.runtime.settings
        job = store.get_job(job_id)
        if job is None or job.status != "queued":
            return  # cancelled, finished, or a duplicate message
        now = self.clock()
        claimed = store.update_job(job_id, {
            "status": "running", "worker": self.id, "attempts": job.attempts + 1,
            "started_at": now, "lease_until": now + settings.lease_seconds,
            "stage": "starting", "message": None, "fraction": 0.0,
        }, expect={"status": "queued", "attempts": job.attempts})
        if claimed is None:
            return
        log.info("job %s (%s): attempt %d on %s", job_id, job.kind, claimed.attempts, self.id)
        lease = _Lease(self, claimed)
        lease.start()
        try:
            self._finish(claimed, self._supervise(claimed, lease))
        except Cancelled:
            self._finish(claimed, {"status": "cancelled", "stage": "cancelled"})
        except Requeue:
            back = store.update_job(job_id, {
                "status": "queued", "worker": None, "lease_until": None, "stage": "queued",
                "attempts": claimed.attempts - 1, "message": "re-queued: worker shut down"},
                expect={"status": "running", "worker": self.id})
            if back:
                self.runtime.queue.enqueue(job_id)
                log.info("job %s: handed back to the queue (worker shutting down)", job_id)
        except LeaseLost:
            log.warning("job %s: lease lost; another worker owns it", job_id)
        except TimedOut:
            limit = settings.job_timeout_seconds
            log.warning("job %s: stopped after its %g s limit", job_id, limit)
            error = problem("Job timed out", f"the job ran longer than the service's limit of "
                            f"{limit:g} s (job_timeout_seconds) and was stopped", 504,
                            "job-timeout", instance=f"/v1/jobs/{job_id}", limit_seconds=limit)
            self._finish(claimed, {"status": "failed", "stage": "failed", "error": error})
        except BonefitError as exc:
            kind = self.kinds.get(job.kind)
            if kind is not None and exc.field is not None \
                    and exc.field.split(".")[0] in kind.params.model_fields:
                exc.field = f"params.{exc.field}"  # name it as the client sent it
            error = from_bonefit_error(exc).body(f"/v1/jobs/{job_id}")
            self._finish(claimed, {"status": "failed", "stage": "failed", "error": error})
        except MemoryLimitExceeded as exc:
            log.warning("job %s: over its memory limit of %d MiB", job_id, exc.limit_mb)
            self._finish(claimed, {"status": "failed", "stage": "failed",
                                   "error": memory_problem(job_id, exc.limit_mb)})
        except InputFault as exc:
            error_id = log_error(job_id, exc.__cause__ or exc, "could not process its input")
            self._finish(claimed, {"status": "failed", "stage": "failed",
                                   "error": input_fault_problem(job_id, exc, error_id)})
        except Exception as exc:
            self._crashed(claimed, exc, log_error(job_id, exc, "crashed"))
        finally:
            lease.stop()

    def _supervise(self, job: Job, lease: _Lease) -> dict[str, Any]:
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
        result: dict[str, Any] = outcome["result"]
        return result

    def _execute(self, job: Job, lease: _Lease) -> dict[str, Any]:
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
            lease.check(timeout=False)  # finished: over the limit or not, keep the results
            results = {}
            for fmt, path in outputs.items():
                key = f"{tenant_prefix(job.tenant)}/jobs/{job.id}/result.{fmt}"
                artifacts.put_file(key, path)
                results[fmt] = key
        return {"status": "succeeded", "stage": "done", "fraction": 1.0, "results": results}

    def _run(self, kind: Kind, inputs: Mapping[str, Input], params: Any, lease: _Lease,
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

    def _finish(self, job: Job, changes: dict[str, Any]) -> None:
        done = self.runtime.store.update_job(
            job.id, {**changes, "finished_at": self.clock(), "worker": None, "lease_until": None},
            expect={"status": "running", "worker": self.id})
        if done is None:
            log.warning("job %s: could not record %s (lease lost)", job.id, changes["status"])
        else:
            log.info("job %s: %s", job.id, done.status)

    def _crashed(self, job: Job, exc: Exception, error_id: str) -> None:
        """An unexpected error: re-queue (a machine fault may pass) up to ``max_attempts``,
        then fail with a 500 naming the logged ``error_id``."""
        if job.attempts < self.runtime.settings.max_attempts:
            back = self.runtime.store.update_job(job.id, {
                "status": "queued", "worker": None, "lease_until": None, "stage": "queued",
                "message": f"re-queued after an internal error ({type(exc).__name__}, "
                           f"error id {error_id})"},
                expect={"status": "running", "worker": self.id})
            if back:
                self.runtime.queue.enqueue(job.id)
            return
        error = problem("Job failed", f"an internal error stopped the job "
                        f"({type(exc).__name__}) after {job.attempts} attempts; it is logged "
                        f"with error id {error_id}", 500, "internal",
                        instance=f"/v1/jobs/{job.id}", error_id=error_id)
        self._finish(job, {"status": "failed", "stage": "failed", "error": error})


class _Lease:
    """A running job's lease: a heartbeat thread and the throttled progress callback."""

    def __init__(self, worker: Worker, job: Job) -> None:
        self.worker = worker
        self.job = job
        self.lost = threading.Event()
        self.cancelled = threading.Event()
        self.done = threading.Event()
        self.started = self.last_write = worker.clock()
        self.fraction = 0.0
        self.thread = threading.Thread(target=self._beat, name=f"lease-{job.id}", daemon=True)

    def start(self) -> None:
        """Start renewing the lease (here and, when there is one, in the lease keeper)."""
        if self.worker.keeper is not None:
            self.worker.keeper.hold(self.job.id)
        self.thread.start()

    def stop(self) -> None:
        """Stop renewing it."""
        self.done.set()
        if self.worker.keeper is not None:
            self.worker.keeper.drop()
        self.thread.join()

    def _renew(self, changes: dict[str, Any]) -> None:
        w = self.worker
        job = w.runtime.store.update_job(
            self.job.id, {**changes, "lease_until": w.clock() + w.runtime.settings.lease_seconds},
            expect={"status": "running", "worker": w.id})
        if job is None:
            self.lost.set()
        elif job.cancel_requested:
            self.cancelled.set()

    def _beat(self) -> None:
        interval = self.worker.runtime.settings.lease_seconds / 3
        while not self.done.wait(interval):
            try:
                self._renew({})
            except Exception:
                log.exception("job %s: heartbeat failed", self.job.id)

    def check(self, *, timeout: bool = True) -> None:
        """Raise if the job must stop: lease lost, cancelled, shutdown grace or (with
        ``timeout``) the job's time limit over."""
        w = self.worker
        if self.lost.is_set():
            raise LeaseLost
        if self.cancelled.is_set():
            raise Cancelled
        now = w.clock()
        if w.deadline is not None and now >= w.deadline:
            raise Requeue
        limit = w.runtime.settings.job_timeout_seconds
        if timeout and limit > 0 and now - self.started >= limit:
            raise TimedOut

    def progress(self, fraction: float, stage: str) -> None:
        """The estimation callback: store progress at most every interval; stop if asked."""
        self.check()
        self.fraction = max(self.fraction, min(max(float(fraction), 0.0), 1.0))
        now = self.worker.clock()
        if now - self.last_write < self.worker.runtime.settings.progress_interval_seconds:
            return
        self.last_write = now
        self._renew({"fraction": self.fraction, "stage": stage[:100]})
        self.check()


def private_tmp(data_dir: Path) -> Path:
    """This process's own temporary directory, ``data_dir/tmp/<host>-<pid>``, made after
    removing the ones of this host's processes that died without cleaning up (kill -9)."""
    root = data_dir / "tmp"
    root.mkdir(parents=True, exist_ok=True)
    host = socket.gethostname()
    for entry in root.iterdir():
        owner, _, pid = entry.name.rpartition("-")
        if owner == host and pid.isdigit() and not _alive(int(pid)):
            shutil.rmtree(entry, ignore_errors=True)
    own = root / f"{host}-{os.getpid()}"
    shutil.rmtree(own, ignore_errors=True)  # a recycled pid's leftovers
    own.mkdir()
    return own


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def run_worker(settings: Settings, *, parent_pid: int | None = None,
               kinds: Mapping[str, Kind] | None = None) -> int:
    """The body of ``bonefit worker --concurrency 1``: serve until SIGTERM/SIGINT."""
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


class WorkerPool:
    """Worker processes (``bonefit worker --concurrency 1``) kept alive by a supervisor thread."""

    def __init__(self, settings: Settings, size: int) -> None:
        self.settings = settings
        self.size = size
        self.procs: list[subprocess.Popen[bytes]] = []
        self._stopping = threading.Event()
        self._supervisor = threading.Thread(target=self._supervise, name="worker-pool",
                                            daemon=True)

    def _spawn(self) -> subprocess.Popen[bytes]:
        env = {**os.environ, **self.settings.to_env(), **BLAS_LIMITS}
        cmd = [sys.executable, "-m", "service.cli", "worker", "--concurrency", "1",
               "--parent-pid", str(os.getpid())]
        return subprocess.Popen(cmd, env=env)

    def start(self) -> None:
        """Start the processes and the supervisor."""
        self.procs = [self._spawn() for _ in range(self.size)]
        self._supervisor.start()

    @property
    def pids(self) -> list[int]:
        """Process ids of the live workers."""
        return [p.pid for p in self.procs if p.poll() is None]

    def _supervise(self) -> None:
        started = [time.monotonic()] * len(self.procs)
        failures = [0] * len(self.procs)
        respawn_at: list[float | None] = [None] * len(self.procs)
        while not self._stopping.wait(1.0):
            for i, proc in enumerate(self.procs):
                if proc.poll() is None or self._stopping.is_set():
                    continue
                now = time.monotonic()
                if respawn_at[i] is None:  # a worker dying right after its start backs off
                    quick = now - started[i] < 10
                    failures[i] = failures[i] + 1 if quick else 0
                    respawn_at[i] = now + (min(2.0 ** failures[i], 60.0) if quick else 0.0)
                    log.warning("worker %d exited with %s; starting another", proc.pid,
                                proc.returncode)
                if now >= (respawn_at[i] or 0.0):
                    self.procs[i] = self._spawn()
                    started[i], respawn_at[i] = time.monotonic(), None

    def stop(self, timeout: float | None = None) -> None:
        """SIGTERM every worker (they finish or hand back their job), then wait; kill late ones."""
        self._stopping.set()
        timeout = self.settings.shutdown_grace_seconds + 5 if timeout is None else timeout
        for proc in self.procs:
            if proc.poll() is None:
                proc.terminate()
        end = time.monotonic() + timeout
        for proc in self.procs:
            try:
                proc.wait(max(end - time.monotonic(), 0.1))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if self._supervisor.is_alive():
            self._supervisor.join()
