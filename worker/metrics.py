"""A worker's Prometheus metrics (prometheus-client), answered from its own port
(``CANOPY_WORKER_METRICS_PORT``): only a worker sees how long a job's attempts and stages take. The API's
metrics, the queue among them, are in ``service/metrics.py``.
"""

from __future__ import annotations

from prometheus_client import CollectorRegistry, Histogram, start_http_server

__all__ = ["WorkerMetrics"]

_JOB_BUCKETS_S = (0.1, 0.25, 0.5, 1.0, 2.0, 5.0, 10.0, 30.0, 60.0, 120.0, 300.0, 600.0)


class WorkerMetrics:
    """A worker's metrics: each finished attempt's duration by outcome, and each measured job's stages."""

    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        self.attempt_seconds = Histogram(
            "canopy_job_duration_seconds",
            "Time a worker spent on a job attempt, by outcome (ok, error, crash, timeout, stopped, no_space)",
            ["outcome"],
            buckets=_JOB_BUCKETS_S,
            registry=self.registry,
        )
        self.stage_seconds = Histogram(
            "canopy_job_stage_duration_seconds",
            "Time a measured job spent in each pipeline stage (load, balls, register, refine, metrics)",
            ["stage"],
            buckets=_JOB_BUCKETS_S,
            registry=self.registry,
        )

    def serve(self, port: int, *, host: str = "0.0.0.0") -> None:
        """Answer Prometheus on ``port`` (``/metrics``) from a thread of this process."""
        start_http_server(port, addr=host, registry=self.registry)
