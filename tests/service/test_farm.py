"""The farm management system's lists: cursor pagination, not-found, filters."""

from __future__ import annotations

import csv
import io
import json
import uuid

from tests.service.running import Service, create_tree


def test_trees_of_a_row_come_in_pages_that_cover_each_once(shared_service: Service) -> None:
    orchard = f"Paging {uuid.uuid4().hex[:8]}"
    with shared_service.client() as client:
        tree_ids = [create_tree(client, orchard, "R1", f"T{n}") for n in range(5)]
        orchards = client.get("/v1/orchards", params={"limit": 1000}).json()["items"]
        orchard_id = next(item["id"] for item in orchards if item["name"] == orchard)
        [row] = client.get(f"/v1/orchards/{orchard_id}/rows").json()["items"]
        pages, cursor = [], None
        while True:
            params = {"limit": 2} | ({"cursor": cursor} if cursor else {})
            page = client.get(f"/v1/rows/{row['id']}/trees", params=params).json()
            pages.append([tree["id"] for tree in page["items"]])
            cursor = page["next_cursor"]
            if cursor is None:
                break
    assert pages == [tree_ids[0:2], tree_ids[2:4], tree_ids[4:5]]


def test_same_capture_sent_twice_is_one_capture(shared_service: Service) -> None:
    orchard = f"Twice {uuid.uuid4().hex[:8]}"
    with shared_service.client() as client:
        manifest = json.dumps(
            {
                "format": "canopy-capture/1",
                "orchard": orchard,
                "row": "R1",
                "tree": "T1",
                "captured_at": "2026-11-20T09:31:00+01:00",
                "views": ["views/1"],
            }
        )
        first = client.post("/v1/captures", content=manifest)
        second = client.post("/v1/captures", content=manifest)
    assert (first.status_code, second.status_code) == (201, 200)
    assert first.json()["id"] == second.json()["id"]
    assert second.headers["location"] == f"/v1/captures/{first.json()['id']}"


def test_a_cursor_not_given_out_by_the_service_is_refused(shared_service: Service) -> None:
    with shared_service.client() as client:
        answer = client.get("/v1/orchards", params={"cursor": "not-a-cursor"})
    assert answer.status_code == 400
    assert answer.headers["content-type"].startswith("application/problem+json")
    assert answer.json()["field"] == "cursor"


def test_lists_of_unknown_parents_are_404_problems(shared_service: Service) -> None:
    with shared_service.client() as client:
        answers = [
            client.get(path)
            for path in ("/v1/orchards/999999/rows", "/v1/rows/999999/trees", "/v1/trees/999999/measurements")
        ]
        measurement = client.get("/v1/measurements/999999")
    assert [answer.status_code for answer in answers] == [404, 404, 404]
    assert measurement.status_code == 404
    assert all(a.headers["content-type"].startswith("application/problem+json") for a in answers)


def test_csv_export_without_measurements_is_its_header(shared_service: Service) -> None:
    with shared_service.client() as client:
        export = client.get("/v1/measurements.csv", params={"orchard": f"Empty {uuid.uuid4().hex}"})
    [header] = list(csv.reader(io.StringIO(export.text)))
    assert header[:8] == [
        "measurement_id",
        "orchard",
        "row",
        "tree",
        "captured_at",
        "height_m",
        "width_m",
        "thickness_m",
    ]


def test_csv_since_needs_a_time_zone(shared_service: Service) -> None:
    with shared_service.client() as client:
        naive = client.get("/v1/measurements.csv", params={"since": "2026-11-01T00:00:00"})
        aware = client.get("/v1/measurements.csv", params={"since": "2026-11-01T00:00:00Z"})
    assert naive.status_code == 422
    assert naive.json()["field"] == "since"
    assert aware.status_code == 200


def test_openapi_documents_every_route(shared_service: Service) -> None:
    with shared_service.client() as client:
        spec = client.get("/openapi.json").json()
        docs = client.get("/docs")
    assert docs.status_code == 200
    assert {
        "/v1/captures",
        "/v1/captures/{capture_id}/files/{path}",
        "/v1/captures/{capture_id}/jobs",
        "/v1/jobs/{job_id}",
        "/v1/jobs",
        "/v1/measurements/{measurement_id}",
        "/v1/measurements/{measurement_id}/cloud.ply",
        "/v1/orchards",
        "/v1/measurements.csv",
    } <= set(spec["paths"])
