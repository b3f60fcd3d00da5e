"""Prometheus metrics read from the job store, so every replica reports the same totals."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from typing import Any

from prometheus_client import CollectorRegistry, Counter
from prometheus_client.core import GaugeMetricFamily, HistogramMetricFamily

from .jobs import Histogram, Status
from .runtime import Runtime

log = logging.getLogger("bonefit.service")
BUCKETS = (0.1, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0, 120.0, 300.0, 600.0, 1800.0, 3600.0)


class StoreCollector:
    """Jobs by kind and status, job durations, queue depth, stored recordings."""

    def __init__(self, runtime: Runtime, kinds: list[str]) -> None:
        self.runtime = runtime
        self.kinds = kinds

    def collect(self) -> Iterator[Any]:
        """Read the store and queue at scrape time."""
        store = self.runtime.store
        try:
            counts, durations = store.counts(), store.durations(BUCKETS)
            n_recordings, recording_bytes = store.recording_totals()
        except Exception:
            log.exception("metrics: job store unreachable")
            return
        jobs = GaugeMetricFamily("bonefit_jobs", "Jobs in the store by kind and status.",
                                 labels=["kind", "status"])
        for kind in sorted({k for k, _ in counts} | set(self.kinds)):
            for status in Status:
                jobs.add_metric([kind, status.value], counts.get((kind, status.value), 0))
        yield jobs
        hist = HistogramMetricFamily("bonefit_job_duration_seconds",
                                     "Run time of succeeded jobs (start to finish).",
                                     labels=["kind"])
        for kind in sorted(set(durations) | set(self.kinds)):
            h = durations.get(kind, Histogram([0] * len(BUCKETS), 0, 0.0))
            buckets = [(str(b), n) for b, n in zip(BUCKETS, h.counts, strict=True)]
            buckets.append(("+Inf", h.count))
            hist.add_metric([kind], buckets, h.total)
        yield hist
        yield GaugeMetricFamily("bonefit_recordings", "Recordings stored.", value=n_recordings)
        yield GaugeMetricFamily("bonefit_recording_bytes", "Bytes of recordings stored.",
                                value=recording_bytes)
        try:
            depth = self.runtime.queue.depth()
        except Exception:
            log.exception("metrics: queue unreachable")
        else:
            yield GaugeMetricFamily("bonefit_queue_depth", "Job messages waiting in the queue.",
                                    value=depth)


def build_registry(runtime: Runtime, kinds: list[str]) -> tuple[CollectorRegistry, Counter]:
    """A registry for one app and its upload-bytes counter (this replica's uploads)."""
    registry = CollectorRegistry(auto_describe=False)
    registry.register(StoreCollector(runtime, kinds))
    uploads = Counter("bonefit_upload_bytes", "Bytes received in uploads by this replica.",
                      registry=registry)
    return registry, uploads
