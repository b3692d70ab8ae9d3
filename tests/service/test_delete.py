"""Deleting a capture (admin scope): its records go, its measurements with it; never while its job runs."""

from __future__ import annotations

import csv
import io
from pathlib import Path

from tests.service.running import Service, upload_capture, wait_for_job


def test_admin_deletes_a_measured_capture_and_everything_recorded_of_it(
    service: Service, tree_capture: Path
) -> None:
    service.start_worker()
    capture_key = service.create_key("capture", "read")
    with service.client() as admin, service.client(capture_key) as laptop:
        capture_id = upload_capture(admin, tree_capture)
        job = wait_for_job(admin, admin.post(f"/v1/captures/{capture_id}/jobs").headers["location"])
        tree_id = admin.get(f"/v1/captures/{capture_id}").json()["tree_id"]
        forbidden = laptop.delete(f"/v1/captures/{capture_id}")
        deleted = admin.delete(f"/v1/captures/{capture_id}")
        capture = admin.get(f"/v1/captures/{capture_id}")
        measurement = admin.get(f"/v1/measurements/{job['measurement_id']}")
        history = admin.get(f"/v1/trees/{tree_id}/measurements").json()
        export = admin.get("/v1/measurements.csv").text
        again = admin.delete(f"/v1/captures/{capture_id}")
        sent_again = upload_capture(admin, tree_capture)
    assert job["state"] == "succeeded"
    assert forbidden.status_code == 403
    assert deleted.status_code == 204
    assert (capture.status_code, measurement.status_code, again.status_code) == (404, 404, 404)
    assert history["items"] == []
    assert list(csv.reader(io.StringIO(export)))[1:] == []
    assert sent_again != capture_id


def test_capture_is_not_deleted_while_its_job_waits(service: Service, tree_capture: Path) -> None:
    with service.client() as admin:
        capture_id = upload_capture(admin, tree_capture)
        job = admin.post(f"/v1/captures/{capture_id}/jobs").json()
        refused = admin.delete(f"/v1/captures/{capture_id}")
        still = admin.get(f"/v1/captures/{capture_id}")
    assert refused.status_code == 409
    assert refused.headers["content-type"].startswith("application/problem+json")
    assert refused.json()["code"] == "job_active"
    assert refused.json()["job_id"] == job["id"]
    assert still.status_code == 200
