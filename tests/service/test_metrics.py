"""Prometheus metrics from real processes: the API's /metrics (no key) counts requests by route template,
the bytes of stored capture files and the queue as the database holds it; a worker's own port its job
durations by outcome and by pipeline stage."""

from __future__ import annotations

import time
from pathlib import Path

import httpx
from prometheus_client.parser import text_string_to_metric_families

from tests.service.running import capture_files, free_port, start_service, upload_capture, wait_for_job


def _samples(text: str) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    """Every sample of a scrape by name and sorted labels."""
    return {
        (sample.name, tuple(sorted(sample.labels.items()))): sample.value
        for family in text_string_to_metric_families(text)
        for sample in family.samples
    }


def test_the_api_and_a_worker_report_the_queue_requests_uploads_and_job_stages(
    tree_capture: Path, tmp_path: Path
) -> None:
    worker_port = free_port()
    service = start_service(tmp_path, worker_metrics_port=str(worker_port))
    try:
        with service.client() as client:
            capture_id = upload_capture(client, tree_capture)
            job_url = client.post(f"/v1/captures/{capture_id}/jobs").headers["location"]
            time.sleep(0.3)
            waiting = _samples(httpx.get(f"{service.url}/metrics").text)  # no key needed
            service.start_worker()
            assert wait_for_job(client, job_url)["state"] == "succeeded"
            client.get(job_url)
            done = _samples(httpx.get(f"{service.url}/metrics").text)
        worker = _samples(httpx.get(f"http://127.0.0.1:{worker_port}/metrics").text)
    finally:
        service.stop()

    assert waiting[("canopy_jobs", (("state", "queued"),))] == 1
    assert waiting[("canopy_queue_depth", ())] == 1
    assert waiting[("canopy_queue_oldest_age_seconds", ())] >= 0.3
    assert done[("canopy_jobs", (("state", "succeeded"),))] == 1
    assert done[("canopy_queue_depth", ())] == 0 and done[("canopy_queue_oldest_age_seconds", ())] == 0

    sent = {path: data for path, data in capture_files(tree_capture).items() if path != "capture.json"}
    assert done[("canopy_upload_bytes_total", ())] == sum(len(data) for data in sent.values())
    counts = {
        labels: value
        for (name, labels), value in done.items()
        if name.endswith("request_duration_seconds_count")
    }
    routes = {dict(labels)["route"] for labels in counts}
    assert all(not any(ch.isdigit() for ch in route.removeprefix("/v1")) for route in routes), routes
    files = [value for labels, value in counts.items() if dict(labels)["method"] == "PUT"]
    assert files == [len(sent)]
    job_polls = [
        value
        for labels, value in counts.items()
        if dict(labels)["route"] == "/v1/jobs/{job_id}" and dict(labels)["status"] == "2xx"
    ]
    assert job_polls and job_polls[0] >= 2

    assert worker[("canopy_job_duration_seconds_count", (("outcome", "ok"),))] == 1
    for stage in ("load", "balls", "register", "refine", "metrics"):
        assert worker[("canopy_job_stage_duration_seconds_count", (("stage", stage),))] == 1, stage
    assert worker[("canopy_job_stage_duration_seconds_sum", (("stage", "balls"),))] > 0
