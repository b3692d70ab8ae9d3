"""The API's conventions, as an integrator or a dashboard relies on them: one orchard, row or tree by id,
filters by name, unknown query parameters refused, jobs newest first with several states and names, lists
that answer 304 while unchanged."""

from __future__ import annotations

import base64
import re
import uuid
from pathlib import Path

from tests.service.running import KEYLESS, Service, create_tree, upload_capture


def test_one_orchard_row_and_tree_are_read_by_id(shared_service: Service) -> None:
    orchard = f"One {uuid.uuid4().hex[:8]}"
    with shared_service.client() as client:
        tree_id = create_tree(client, orchard, "R7", "T3")
        tree = client.get(f"/v1/trees/{tree_id}").json()
        row = client.get(f"/v1/rows/{tree['row_id']}").json()
        one = client.get(f"/v1/orchards/{row['orchard_id']}").json()
        missing = [client.get(f"/v1/{kind}/999999") for kind in ("orchards", "rows", "trees")]
    assert (one["name"], row["name"], tree["name"]) == (orchard, "R7", "T3")
    assert tree["latest_measurement"] is None
    assert [answer.status_code for answer in missing] == [404, 404, 404]
    assert [answer.json()["detail"] for answer in missing] == [
        "no orchard with id 999999",
        "no row with id 999999",
        "no tree with id 999999",
    ]


def test_lists_filter_by_exact_name(shared_service: Service) -> None:
    orchard = f"Names {uuid.uuid4().hex[:8]}"
    with shared_service.client() as client:
        for row, tree in (("R1", "T1"), ("R1", "T2"), ("R2", "T1")):
            create_tree(client, orchard, row, tree)
        [found] = client.get("/v1/orchards", params={"name": orchard}).json()["items"]
        rows = client.get(f"/v1/orchards/{found['id']}/rows", params={"name": "R1"}).json()["items"]
        trees = client.get(f"/v1/rows/{rows[0]['id']}/trees", params={"name": "T2"}).json()["items"]
        nothing = client.get("/v1/orchards", params={"name": orchard.lower()}).json()["items"]
    assert found["name"] == orchard
    assert [row["name"] for row in rows] == ["R1"]
    assert [tree["name"] for tree in trees] == ["T2"]
    assert nothing == []


def test_an_unknown_query_parameter_is_refused_naming_it(shared_service: Service) -> None:
    """A misspelt filter silently ignored would answer the whole list as if it were the filtered one."""
    with shared_service.client() as client:
        orchards = client.get("/v1/orchards", params={"sort": "name"})
        jobs = client.get("/v1/jobs", params={"stat": "failed", "state": "queued"})
    assert orchards.status_code == 400
    assert orchards.headers["content-type"].startswith("application/problem+json")
    assert orchards.json()["code"] == "unknown_parameter"
    assert orchards.json()["unknown"] == ["sort"]
    assert "cursor, limit, name" in orchards.json()["detail"]
    assert jobs.status_code == 400
    assert jobs.json()["field"] == "stat"


def test_jobs_come_newest_first_in_several_states_with_their_tree(
    shared_service: Service, tree_capture: Path
) -> None:
    """No worker runs beside this service: every job stays queued."""
    with shared_service.client() as client:
        capture_id = upload_capture(client, tree_capture)
        jobs_url = f"/v1/captures/{capture_id}/jobs"
        started = [
            client.post(jobs_url, headers={"Idempotency-Key": uuid.uuid4().hex}).json() for _ in range(3)
        ]
        ids = [job["id"] for job in started]
        since = started[1]["created_at"]

        def listed(**params: object) -> list[int]:
            answer = client.get("/v1/jobs", params={"capture_id": capture_id} | params)
            assert answer.status_code == 200, answer.text
            return [job["id"] for job in answer.json()["items"]]

        newest = listed()
        oldest = listed(order="oldest")
        waiting = listed(state=["running", "queued"])
        done = listed(state=["succeeded", "failed"])
        recent = listed(since=since, order="oldest")
        paged = client.get("/v1/jobs", params={"capture_id": capture_id, "limit": 2}).json()
        rest = listed(cursor=paged["next_cursor"])
        [job] = client.get("/v1/jobs", params={"capture_id": capture_id, "limit": 1}).json()["items"]
        capture = client.get(f"/v1/captures/{capture_id}").json()
    assert newest == ids[::-1]
    assert oldest == ids
    assert waiting == ids[::-1]
    assert done == []
    assert recent == ids[1:]
    assert [item["id"] for item in paged["items"]] + rest == ids[::-1]
    assert (job["orchard"], job["row"], job["tree"], job["tree_id"]) == (
        capture["orchard"],
        capture["row"],
        capture["tree"],
        capture["tree_id"],
    )


def test_a_list_s_etag_changes_when_the_list_does(shared_service: Service) -> None:
    """A dashboard polling with If-None-Match gets 304 until a tree is added, then the new list."""
    orchard = f"Poll {uuid.uuid4().hex[:8]}"
    with shared_service.client() as client:
        tree_id = create_tree(client, orchard, "R1", "T1")
        row_id = client.get(f"/v1/trees/{tree_id}").json()["row_id"]
        first = client.get(f"/v1/rows/{row_id}/trees")
        unchanged = client.get(f"/v1/rows/{row_id}/trees", headers={"If-None-Match": first.headers["etag"]})
        create_tree(client, orchard, "R1", "T2")
        changed = client.get(f"/v1/rows/{row_id}/trees", headers={"If-None-Match": first.headers["etag"]})
    assert unchanged.status_code == 304
    assert changed.status_code == 200
    assert changed.headers["etag"] != first.headers["etag"]
    assert [tree["name"] for tree in changed.json()["items"]] == ["T1", "T2"]


def test_the_api_docs_load_nothing_from_the_internet(shared_service: Service) -> None:
    """Swagger UI and ReDoc in an offline field office: every script and style sheet they name is served
    by the service itself."""
    with shared_service.client() as client:
        pages = {path: client.get(path) for path in ("/docs", "/redoc")}
        assets: set[str] = set()
        for path, page in pages.items():
            assert page.status_code == 200, path
            named = re.findall(r'(?:src|href)="([^"]+\.(?:js|css|png))"', page.text)
            assert named, path
            assert not [url for url in named if "://" in url or url.startswith("//")], (path, named)
            assets.update(named)
        answers = {asset: client.get(asset).status_code for asset in assets}
    assert answers == dict.fromkeys(assets, 200)


def test_every_invalid_parameter_of_a_request_is_named(shared_service: Service) -> None:
    with shared_service.client() as client:
        answer = client.get("/v1/jobs", params={"limit": 0, "capture_id": "seven", "order": "latest"})
    assert answer.status_code == 422
    problem = answer.json()
    assert sorted(item["field"] for item in problem["errors"]) == ["capture_id", "limit", "order"]
    for field in ("capture_id", "limit", "order"):
        assert f"{field}: " in problem["detail"]


def test_an_id_beyond_64_bits_is_refused_naming_it_not_a_server_error(shared_service: Service) -> None:
    """The database's driver cannot send an integer of 2^63 or more: it was a 500 on every route with an
    id. Now such an id, or 0, is refused as invalid, naming the parameter."""
    huge = 2**63
    cursor = base64.urlsafe_b64encode(f"id:{huge}".encode()).decode().rstrip("=")
    with shared_service.client() as client:
        answers = {
            (path, field): client.get(path)
            for path, field in (
                (f"/v1/jobs/{huge}", "job_id"),
                (f"/v1/captures/{huge}", "capture_id"),
                (f"/v1/orchards/{huge}", "orchard_id"),
                (f"/v1/orchards/{huge}/rows", "orchard_id"),
                (f"/v1/rows/{huge}/trees", "row_id"),
                (f"/v1/trees/{huge}/measurements", "tree_id"),
                (f"/v1/measurements/{huge}", "measurement_id"),
                (f"/v1/measurements/{huge}/cloud.ply", "measurement_id"),
                ("/v1/jobs/0", "job_id"),
                (f"/v1/jobs?capture_id={huge}", "capture_id"),
            )
        }
        started = client.post(f"/v1/captures/{huge}/jobs")
        paged = client.get("/v1/orchards", params={"cursor": cursor})
    for (path, field), answer in answers.items():
        assert answer.status_code == 422, (path, answer.text)
        assert answer.json()["field"] == field, path
    assert started.status_code == 422
    assert (paged.status_code, paged.json()["code"]) == (400, "invalid_cursor")


def test_a_since_beyond_what_utc_can_hold_is_refused_not_a_server_error(shared_service: Service) -> None:
    """Year 1 at +05:00 is before year 1 in UTC: it was a 500 (OverflowError) on both lists that take it."""
    with shared_service.client() as client:
        answers = [
            client.get(path, params={"since": "0001-01-01T00:00:00+05:00"})
            for path in ("/v1/jobs", "/v1/measurements.csv")
        ]
    assert [answer.status_code for answer in answers] == [422, 422]
    assert [answer.json()["field"] for answer in answers] == ["since", "since"]


def test_the_openapi_document_resolves_and_declares_the_key_and_the_problem_schema(
    shared_service: Service,
) -> None:
    """Client generators need every $ref to resolve (capture.json's body pointed at #/$defs/BallSet), the
    bearer key declared (Swagger UI then offers to send it), and errors described as problem details."""
    with shared_service.client() as client:
        document = client.get("/openapi.json").json()

    def refs(node: object) -> list[str]:
        if isinstance(node, dict):
            own = [node["$ref"]] if isinstance(node.get("$ref"), str) else []
            return own + [ref for value in node.values() for ref in refs(value)]
        if isinstance(node, list):
            return [ref for value in node for ref in refs(value)]
        return []

    unresolved = []
    for ref in set(refs(document)):
        node: object = document
        for part in ref.removeprefix("#/").split("/"):
            node = node.get(part) if isinstance(node, dict) else None
        if node is None:
            unresolved.append(ref)
    assert unresolved == []
    assert document["components"]["securitySchemes"]["apiKey"]["scheme"] == "bearer"
    operations = [
        (path, operation)
        for path, item in document["paths"].items()
        if path.startswith("/v1/")
        for method, operation in item.items()
        if (method.upper(), path) not in KEYLESS
    ]
    assert operations and all(operation.get("security") == [{"apiKey": []}] for _, operation in operations)
    conflict = document["paths"]["/v1/captures"]["post"]["responses"]["409"]["content"]
    assert conflict["application/problem+json"]["schema"]["$ref"] == "#/components/schemas/Problem"
    problem = document["components"]["schemas"]["Problem"]
    assert {"type", "title", "status", "detail", "code"} <= set(problem["required"])
    body = document["paths"]["/v1/captures"]["post"]["requestBody"]["content"]["application/json"]
    assert body["schema"]["$ref"] == "#/components/schemas/CaptureManifest"
