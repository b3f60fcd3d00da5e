"""The reaper: jobs whose worker was lost, and queued jobs whose queue message was lost."""

from __future__ import annotations

import logging
import time

from .failures import job_url, worker_lost_problem
from .jobs import Job
from .runtime import Runtime

log = logging.getLogger("bonefit.worker")


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
    store = runtime.store
    worker, lease = job.worker, job.lease_until  # still the same lease: nobody took it over
    if job.cancel_requested:
        done = store.cancel(job.id, worker, now, lease_until=lease)
    elif job.attempts >= runtime.settings.max_attempts:
        error = worker_lost_problem(job.attempts).body(job_url(job.id))
        done = store.fail(job.id, worker, error, now, lease_until=lease)
    else:
        done = store.requeue(job.id, worker, "re-queued: its worker was lost",
                             lease_until=lease)
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
            if runtime.store.mark_resent(job):  # the next pass waits another lease period
                runtime.queue.enqueue(job.id)
                log.warning("job %s: no queue message after %.0f s; sent again", job.id,
                            now - job.updated_at)
                sent.append(job.id)
        except Exception:
            log.exception("job %s: could not send it again; retrying on the next pass", job.id)
    return sent
