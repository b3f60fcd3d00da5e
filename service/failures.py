"""How a job fails: the problem document each failure records in the job's ``error``.

The problems are :class:`~bonefit.service.problems.Problem` objects, the type the API answers with;
:class:`InputFault` wraps a numerical error on the job's input.
"""

from __future__ import annotations

import logging
import uuid
from collections.abc import Collection

from bonefit.estimation.errors import BonefitError

from .errors import StorageFull, chain
from .job_lease import TimedOut
from .limits import MemoryLimitExceeded
from .problems import Problem, from_bonefit_error
from .storage import is_storage_full, storage_full

log = logging.getLogger("bonefit.worker")


class InputFault(Exception):
    """The estimation failed on the job's input with a numerical error (ValueError,
    ArithmeticError) that no reader or check caught: the input's fault, not retried."""


def job_url(job_id: str) -> str:
    """The job's URL, the ``instance`` of its problems."""
    return f"/v1/jobs/{job_id}"


def log_error(job_id: str, exc: BaseException, what: str) -> str:
    """Log ``exc`` with its traceback under a new error id; the id (32 hex digits)."""
    error_id = uuid.uuid4().hex
    log.error("job %s %s [error id %s]", job_id, what, error_id, exc_info=exc)
    return error_id


def input_fault_problem(exc: InputFault, error_id: str) -> Problem:
    """422 for a numerical error on the job's input, with the logged error id."""
    return Problem(422, "Cannot estimate from this input",
                   f"the estimation failed on this recording or these params ({exc}); check "
                   f"them for extreme or degenerate values. Logged with error id {error_id}",
                   slug="estimation-error", error_id=error_id)


def memory_problem(limit_mb: int) -> Problem:
    """507 for a job that needed more memory than ``job_memory_mb``."""
    return Problem(507, "Job exceeded its memory limit",
                   f"the job needed more than the service's limit of {limit_mb} MiB per job "
                   f"(job_memory_mb) and was stopped; use a shorter recording",
                   slug="memory-limit", limit_mb=limit_mb)


def timeout_problem(limit: float) -> Problem:
    """504 for a job stopped after ``job_timeout_seconds``."""
    return Problem(504, "Job timed out", f"the job ran longer than the service's limit of "
                   f"{limit:g} s (job_timeout_seconds) and was stopped", slug="job-timeout",
                   limit_seconds=limit)


def worker_lost_problem(attempts: int) -> Problem:
    """503 for a job whose workers were lost ``attempts`` times."""
    return Problem(503, "Worker lost", f"the worker running this job stopped responding "
                   f"{attempts} times; giving up", slug="worker-lost", attempts=attempts)


def internal_problem(exc: Exception, attempts: int, error_id: str) -> Problem:
    """500 for a job an internal error stopped ``attempts`` times."""
    return Problem(500, "Job failed", f"an internal error stopped the job "
                   f"({type(exc).__name__}) after {attempts} attempts; it is logged "
                   f"with error id {error_id}", slug="internal", error_id=error_id)


def queue_refused_problem() -> Problem:
    """503 recorded on a job the queue refused (its client got a 503 or 507 answer)."""
    return Problem(503, "Queue unavailable", "the job could not be queued",
                   slug="queue-unavailable")


def input_problem(exc: BonefitError, params: Collection[str]) -> Problem:
    """422 naming the field, sensor, line and column; a field of the job's ``params`` is
    named as the client sent it (``params.fps``)."""
    if exc.field is not None and exc.field.split(".")[0] in params:
        exc.field = f"params.{exc.field}"
    return from_bonefit_error(exc)


def job_problem(exc: Exception, job_id: str, params: Collection[str],
                timeout: float) -> Problem | None:
    """The problem ending the job that raised ``exc`` for good (an input's fault, a limit,
    a full disk, which another attempt would meet again); None for an internal error, which
    may pass on another attempt."""
    if isinstance(exc, TimedOut):
        log.warning("job %s: stopped after its %g s limit", job_id, timeout)
        return timeout_problem(timeout)
    if isinstance(exc, BonefitError):
        return input_problem(exc, params)
    if isinstance(exc, MemoryLimitExceeded):
        log.warning("job %s: over its memory limit of %d MiB", job_id, exc.limit_mb)
        return memory_problem(exc.limit_mb)
    if isinstance(exc, InputFault):
        error_id = log_error(job_id, exc.__cause__ or exc, "could not process its input")
        return input_fault_problem(exc, error_id)
    if is_storage_full(exc):
        storage = full_storage(exc)
        log.warning("job %s: the %s is full (%s)", job_id, storage, type(exc).__name__)
        return storage_full(storage)
    return None


def full_storage(exc: BaseException) -> str:
    """The name of the storage a job found full: the back-end's (results, job database), else
    the worker's own disk (its job folder: inputs fetched, results written)."""
    for e in chain(exc):
        if isinstance(e, StorageFull):
            return e.storage
    return "worker's scratch disk"
