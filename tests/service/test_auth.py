"""API keys over real HTTP: `Authorization: Bearer <key>` on every route but /healthz, scopes (capture,
read, admin) enforced per route, keys made and revoked with `canopy keys` or the admin API taking effect at
once (DESIGN.md, "HTTP contract, v1").
"""

from __future__ import annotations

import re
import time
import uuid
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from typing import Any

import httpx
import pytest

from tests.service.running import KEYLESS, Service, content_digest

PROBLEM_JSON = "application/problem+json"
KEY_PATTERN = re.compile(r"canopy_([0-9a-f]{8})_\S+")


def prefix_of(key: str) -> str:
    """The 8 hex digits naming a key in lists (``canopy_<prefix>_<secret>``)."""
    match = KEY_PATTERN.fullmatch(key)
    assert match, f"not a canopy key: {key!r}"
    return match.group(1)


def manifest() -> dict[str, Any]:
    """A valid one-view capture.json of a tree of its own."""
    unique = uuid.uuid4().hex[:12]
    return {
        "format": "canopy-capture/1",
        "orchard": f"Auth {unique}",
        "row": "R1",
        "tree": f"T-{unique}",
        "captured_at": "2026-11-20T08:31:00Z",
        "views": ["views/1"],
    }


def assert_problem(response: httpx.Response, status: int, **members: Any) -> dict[str, Any]:
    """``response`` is an RFC 9457 problem of ``status`` holding ``members``; its body."""
    assert response.status_code == status, response.text
    assert response.headers["content-type"].startswith(PROBLEM_JSON)
    body = dict(response.json())
    assert {"type", "title", "status", "detail"} <= body.keys(), body
    assert body["status"] == status
    for key, value in members.items():
        assert body.get(key) == value, f"{key}: {body.get(key)!r} != {value!r} in {body}"
    return body


def assert_unauthorized(response: httpx.Response) -> None:
    """A 401 problem with a Bearer challenge (RFC 6750)."""
    assert_problem(response, 401, code="unauthorized")
    assert response.headers["www-authenticate"].startswith("Bearer")


@pytest.fixture(scope="module")
def anonymous(shared_service: Service) -> Iterator[httpx.Client]:
    """A client sending no Authorization header."""
    with httpx.Client(base_url=shared_service.url, timeout=30.0) as client:
        yield client


@pytest.fixture(scope="module")
def admin(shared_service: Service) -> Iterator[httpx.Client]:
    """A client with the service's admin key."""
    with shared_service.client() as client:
        yield client


@pytest.fixture(scope="module")
def read_key(shared_service: Service) -> str:
    """A read-scope key made by `canopy keys create --scope read`."""
    return shared_service.create_key("read")


@pytest.fixture(scope="module")
def capture_key(admin: httpx.Client) -> str:
    """A capture-scope key made through the admin API."""
    created = admin.post("/v1/keys", json={"name": "capture client", "scopes": ["capture"]})
    assert created.status_code == 201, created.text
    return str(created.json()["key"])


# --- no key, or a key that is not one ----------------------------------------------------------------------


def test_request_without_a_key_is_refused_with_401_and_a_bearer_challenge(anonymous: httpx.Client) -> None:
    assert_unauthorized(anonymous.get("/v1/orchards"))


def test_request_with_an_unknown_key_is_refused_with_401(anonymous: httpx.Client) -> None:
    response = anonymous.get(
        "/v1/orchards", headers={"Authorization": "Bearer canopy_0badc0de_notAKeyThisServiceEverGaveOut"}
    )
    assert_unauthorized(response)


def test_known_prefix_with_a_wrong_secret_is_refused_with_401(anonymous: httpx.Client, read_key: str) -> None:
    forged = f"canopy_{prefix_of(read_key)}_{'A' * 43}"
    assert_unauthorized(anonymous.get("/v1/orchards", headers={"Authorization": f"Bearer {forged}"}))


@pytest.mark.parametrize(
    "header",
    [
        pytest.param("{key}", id="no-scheme"),
        pytest.param("Basic {key}", id="basic-scheme"),
        pytest.param("Bearer", id="bearer-without-key"),
    ],
)
def test_authorization_that_is_not_a_bearer_key_is_refused_with_401(
    anonymous: httpx.Client, read_key: str, header: str
) -> None:
    response = anonymous.get("/v1/orchards", headers={"Authorization": header.format(key=read_key)})
    assert_unauthorized(response)


def test_bearer_scheme_is_matched_without_regard_to_case(anonymous: httpx.Client, read_key: str) -> None:
    response = anonymous.get("/v1/orchards", headers={"Authorization": f"bearer {read_key}"})
    assert response.status_code == 200, response.text


def _without_a_key(anonymous: httpx.Client, method: str, template: str) -> httpx.Response:
    """Call an OpenAPI path with every path parameter filled in, no key and no body."""
    url = re.sub(r"\{path\}", "views/1/depth.png", template)
    url = re.sub(r"\{[a-z_]+\}", "1", url)
    return anonymous.request(method, url)


def test_every_v1_route_refuses_a_request_without_a_key(admin: httpx.Client, anonymous: httpx.Client) -> None:
    document = admin.get("/openapi.json").json()
    routes = [
        (method.upper(), template)
        for template, operations in document["paths"].items()
        if template.startswith("/v1/")
        for method in operations
        if (method.upper(), template) not in KEYLESS
    ]
    assert len(routes) >= 10, routes
    answered = {
        f"{method} {template}": _without_a_key(anonymous, method, template) for method, template in routes
    }
    not_refused = {
        route: response.status_code for route, response in answered.items() if response.status_code != 401
    }
    assert not_refused == {}
    for response in answered.values():
        assert_unauthorized(response)


# --- routes without a key ---------------------------------------------------------------------------------


def test_healthz_answers_without_a_key(anonymous: httpx.Client) -> None:
    response = anonymous.get("/healthz")
    assert response.status_code == 200
    assert response.json() == {"status": "ok"}


def test_readyz_requires_a_key(anonymous: httpx.Client) -> None:
    assert_unauthorized(anonymous.get("/readyz"))


@pytest.mark.parametrize("scope", ["read", "capture", "admin"])
def test_readyz_and_the_current_key_answer_any_valid_key(shared_service: Service, scope: str) -> None:
    key = shared_service.create_key(scope)
    with shared_service.client(key) as client:
        ready = client.get("/readyz")
        current = client.get("/v1/keys/current")
    assert ready.status_code == 200
    assert ready.json() == {"status": "ready"}
    assert current.status_code == 200
    body = current.json()
    assert body["service"] == "canopy" and body["version"]
    assert body["key"]["scopes"] == [scope] and body["key"]["prefix"] == key.split("_")[1]
    assert key not in current.text


# --- scopes -----------------------------------------------------------------------------------------------


def test_read_key_can_list_orchards(shared_service: Service, read_key: str) -> None:
    with shared_service.client(read_key) as client:
        response = client.get("/v1/orchards")
    assert response.status_code == 200, response.text
    assert "items" in response.json()


def test_read_key_cannot_create_a_capture(
    shared_service: Service, admin: httpx.Client, read_key: str
) -> None:
    document = manifest()
    with shared_service.client(read_key) as client:
        response = client.post("/v1/captures", json=document)
    assert_problem(response, 403, code="forbidden", scope="capture")
    orchards = admin.get("/v1/orchards", params={"limit": 1000}).json()["items"]
    assert document["orchard"] not in {orchard["name"] for orchard in orchards}


def test_read_key_cannot_create_keys(shared_service: Service, read_key: str) -> None:
    with shared_service.client(read_key) as client:
        response = client.post("/v1/keys", json={"name": "escalation", "scopes": ["admin"]})
    assert_problem(response, 403, code="forbidden", scope="admin")


def test_capture_key_can_create_a_capture(shared_service: Service, capture_key: str) -> None:
    with shared_service.client(capture_key) as client:
        response = client.post("/v1/captures", json=manifest())
    assert response.status_code == 201, response.text
    assert response.json()["files_received"] == []


def test_capture_key_can_see_which_files_its_capture_misses_but_not_read_results(
    shared_service: Service, capture_key: str
) -> None:
    with shared_service.client(capture_key) as client:
        capture_id = client.post("/v1/captures", json=manifest()).json()["id"]
        capture = client.get(f"/v1/captures/{capture_id}")
        orchards = client.get("/v1/orchards")
    assert capture.status_code == 200
    assert capture.json()["files_missing"] == capture.json()["files_expected"]
    assert_problem(orchards, 403, code="forbidden", scope="read")


def test_capture_key_cannot_list_keys(shared_service: Service, capture_key: str) -> None:
    with shared_service.client(capture_key) as client:
        response = client.get("/v1/keys")
    assert_problem(response, 403, code="forbidden", scope="admin")


def test_admin_key_may_do_what_read_and_capture_keys_do(admin: httpx.Client) -> None:
    assert admin.post("/v1/captures", json=manifest()).status_code == 201
    assert admin.get("/v1/orchards").status_code == 200


# --- making and revoking keys -----------------------------------------------------------------------------


def test_key_made_with_the_cli_works_at_once(shared_service: Service, read_key: str) -> None:
    assert KEY_PATTERN.fullmatch(read_key)
    with shared_service.client(read_key) as client:
        assert client.get("/v1/orchards").status_code == 200


def test_cli_lists_keys_by_prefix_and_never_shows_the_key(shared_service: Service, read_key: str) -> None:
    listed = shared_service.canopy("keys", "list")
    assert listed.returncode == 0, listed.stderr
    rows = {line.split()[0]: line for line in listed.stdout.splitlines()[1:] if line.strip()}
    assert prefix_of(read_key) in rows
    assert prefix_of(shared_service.admin_key) in rows
    assert "read" in rows[prefix_of(read_key)].split()
    assert read_key not in listed.stdout


def test_key_revoked_with_the_cli_is_refused_afterwards(shared_service: Service, admin: httpx.Client) -> None:
    # Made through the API, which is quicker than the CLI; `canopy keys create` is what read_key tests.
    key = admin.post("/v1/keys", json={"name": "revoked by cli", "scopes": ["read"]}).json()["key"]
    with shared_service.client(key) as client:
        assert client.get("/v1/orchards").status_code == 200
        revoked = shared_service.canopy("keys", "revoke", prefix_of(key))
        assert revoked.returncode == 0, revoked.stderr
        assert_unauthorized(client.get("/v1/orchards"))


def test_key_created_through_the_api_works_and_is_listed_without_its_value(
    shared_service: Service, admin: httpx.Client
) -> None:
    created = admin.post("/v1/keys", json={"name": "dashboard", "scopes": ["read"]})
    assert created.status_code == 201, created.text
    body = created.json()
    key = body["key"]
    assert body["prefix"] == prefix_of(key) and body["scopes"] == ["read"]
    with shared_service.client(key) as client:
        assert client.get("/v1/orchards").status_code == 200
        assert_problem(client.post("/v1/captures", json=manifest()), 403, scope="capture")
    listed = admin.get("/v1/keys")
    assert listed.status_code == 200
    [record] = [record for record in listed.json() if record["prefix"] == body["prefix"]]
    assert record["revoked_at"] is None and "key" not in record
    assert key not in listed.text


def test_key_revoked_through_the_api_is_refused_afterwards(
    shared_service: Service, admin: httpx.Client
) -> None:
    key = admin.post("/v1/keys", json={"name": "short-lived", "scopes": ["read"]}).json()["key"]
    with shared_service.client(key) as client:
        assert client.get("/v1/orchards").status_code == 200
        revoked = admin.delete(f"/v1/keys/{prefix_of(key)}")
        assert revoked.status_code == 200, revoked.text
        assert revoked.json()["revoked_at"] is not None
        assert_unauthorized(client.get("/v1/orchards"))


def test_key_with_an_unknown_scope_is_not_created(admin: httpx.Client) -> None:
    before = len(admin.get("/v1/keys").json())
    response = admin.post("/v1/keys", json={"name": "root", "scopes": ["superuser"]})
    assert_problem(response, 422)
    assert len(admin.get("/v1/keys").json()) == before


# --- a capture key writes to its own captures; keys expire -------------------------------------------------


def _capture_client(shared_service: Service, admin: httpx.Client, name: str) -> httpx.Client:
    created = admin.post("/v1/keys", json={"name": name, "scopes": ["capture"]})
    assert created.status_code == 201, created.text
    return shared_service.client(created.json()["key"])


def test_a_capture_key_writes_and_reads_only_the_captures_it_created(
    shared_service: Service, admin: httpx.Client, read_key: str
) -> None:
    document = manifest()
    camera = b'{"depth_scale": 1000}'
    with (
        _capture_client(shared_service, admin, "laptop A") as owner,
        _capture_client(shared_service, admin, "laptop B") as other,
        shared_service.client(read_key) as reader,
    ):
        created = owner.post("/v1/captures", json=document)
        capture_id = created.json()["id"]
        file_url = f"/v1/captures/{capture_id}/files/views/1/camera.json"
        digest = {"Content-Digest": content_digest(camera)}
        refusals = [
            other.post("/v1/captures", json=document),  # the same capture.json: the owner's capture
            other.put(file_url, content=camera, headers=digest),
            other.post(f"/v1/captures/{capture_id}/jobs"),
            other.get(f"/v1/captures/{capture_id}"),
        ]
        own = owner.get(f"/v1/captures/{capture_id}")
        read = reader.get(f"/v1/captures/{capture_id}")
        admins = admin.get(f"/v1/captures/{capture_id}")
    assert created.status_code == 201, created.text
    for refused in refusals:
        body = assert_problem(refused, 403, code="not_capture_owner", capture_id=capture_id)
        assert "created by another API key" in body["detail"]
    assert (own.status_code, read.status_code, admins.status_code) == (200, 200, 200)
    assert own.json()["files_received"] == []  # the other key's file was not stored


def test_a_key_with_an_expiry_works_until_then_and_is_refused_after_saying_so(
    shared_service: Service, admin: httpx.Client
) -> None:
    created = admin.post("/v1/keys", json={"name": "season", "scopes": ["read"], "expires_in_s": 2})
    assert created.status_code == 201, created.text
    body = created.json()
    with shared_service.client(body["key"]) as client:
        before = client.get("/v1/orchards")
        time.sleep(2.5)
        after = client.get("/v1/orchards")
    assert body["expires_at"] is not None and body["expires_at"].endswith("Z")
    assert before.status_code == 200
    assert_unauthorized(after)
    assert f"API key {body['prefix']} expired at " in after.json()["detail"]


def test_keys_create_takes_a_lifetime_and_lists_its_expiry(shared_service: Service) -> None:
    made = shared_service.canopy("keys", "create", "--scope", "read", "--expires-in", "90d")
    refused = shared_service.canopy("keys", "create", "--scope", "read", "--expires-in", "soon")
    listed = shared_service.canopy("keys", "list")
    key = made.stdout.strip().splitlines()[-1]
    assert made.returncode == 0, made.stderr
    assert "valid until " in made.stderr
    line = next(line for line in listed.stdout.splitlines() if line.startswith(prefix_of(key)))
    in_90_days = datetime.now(UTC) + timedelta(days=90)
    assert (
        in_90_days.strftime("%Y-%m-%d") in line
        or (in_90_days - timedelta(minutes=1)).strftime("%Y-%m-%d") in line
    )
    assert refused.returncode == 2
    assert "--expires-in: 'soon' is not a lifetime such as 90d" in refused.stderr
    with shared_service.client(key) as client:
        assert client.get("/v1/orchards").status_code == 200
