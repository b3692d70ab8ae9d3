"""Prometheus metrics (prometheus-client), each process its own: the API's at ``GET /metrics``, a worker's on
the port ``CANOPY_WORKER_METRICS_PORT`` names.

The API counts what passes through it (request latency by route, bytes of capture files stored) and reads
the queue from the database at each scrape (jobs by state, queue depth, the oldest queued job's age), so
every API process answers the same queue figures however many there are. Job durations are the workers':
only a worker sees a job's stages (``worker/metrics.py``).
"""

from __future__ import annotations

import time
from collections.abc import Iterable

from prometheus_client import CollectorRegistry, Counter, Histogram, generate_latest
from prometheus_client.core import GaugeMetricFamily, Metric
from prometheus_client.registry import Collector
from sqlalchemy import func, select
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.database import Database
from service.models import JOB_STATES, Job, utc_now

__all__ = ["CONTENT_TYPE", "RequestTimer", "ServiceMetrics"]

CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"
_REQUEST_BUCKETS_S = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0)


class ServiceMetrics:
    """The API process's metrics, in a registry of its own (one per app, so tests may build many)."""

    def __init__(self, database: Database) -> None:
        self.registry = CollectorRegistry()
        self.request_seconds = Histogram(
            "canopy_http_request_duration_seconds",
            "Time from a request's arrival to its response's last byte, by route template and status class",
            ["method", "route", "status"],
            buckets=_REQUEST_BUCKETS_S,
            registry=self.registry,
        )
        self.upload_bytes = Counter(
            "canopy_upload_bytes", "Bytes of capture files received and stored", registry=self.registry
        )
        self.registry.register(_QueueCollector(database))

    def exposition(self) -> bytes:
        """The metrics in Prometheus' text format."""
        return generate_latest(self.registry)


class _QueueCollector(Collector):
    """The job queue as the database holds it, read at each scrape."""

    def __init__(self, database: Database) -> None:
        self._database = database

    def collect(self) -> Iterable[Metric]:
        with self._database.reading() as session:
            counts = dict(session.execute(select(Job.state, func.count()).group_by(Job.state)).all())
            oldest = session.scalar(select(func.min(Job.created_at)).where(Job.state == "queued"))
        jobs = GaugeMetricFamily("canopy_jobs", "Jobs by state", labels=["state"])
        for state in JOB_STATES:
            jobs.add_metric([state], counts.get(state, 0))
        yield jobs
        yield GaugeMetricFamily(
            "canopy_queue_depth", "Jobs waiting for a worker", value=counts.get("queued", 0)
        )
        age_s = 0.0 if oldest is None else max(0.0, (utc_now() - oldest).total_seconds())
        yield GaugeMetricFamily(
            "canopy_queue_oldest_age_seconds",
            "How long the oldest queued job has waited (0: none)",
            value=age_s,
        )


class RequestTimer:
    """ASGI middleware: each HTTP request's duration into ``canopy_http_request_duration_seconds``, labelled
    with the route's template (``/v1/jobs/{job_id}``, never the raw path, whose ids would make a label per
    job) or ``unmatched``, and the status class (``2xx``, ``4xx``, ...)."""

    def __init__(self, app: ASGIApp, metrics: ServiceMetrics) -> None:
        self.app = app
        self.metrics = metrics

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = time.perf_counter()
        status = 500

        async def timed_send(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)
            if message["type"] == "http.response.body" and not message.get("more_body", False):
                self._observe(scope, status, time.perf_counter() - started)

        try:
            await self.app(scope, receive, timed_send)
        except Exception:
            self._observe(scope, 500, time.perf_counter() - started)
            raise

    def _observe(self, scope: Scope, status: int, seconds: float) -> None:
        route = scope.get("route")
        template = getattr(route, "path", None) or "unmatched"
        self.metrics.request_seconds.labels(scope["method"], template, f"{status // 100}xx").observe(seconds)
