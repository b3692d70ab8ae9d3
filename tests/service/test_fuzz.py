"""Schema fuzzing: Schemathesis generates requests from the service's own OpenAPI document, valid and not,
and sends them with an admin key to a real `canopy serve`: no input gets a 5xx, and every answer conforms
to the document (status codes, content types, headers, bodies). Bounded: a few dozen examples per route.

Key revocation is aimed at a throwaway key only: a fuzzer that revoked its own key would lock itself out
and then test nothing but 401s. Not checked: that every schema-valid request is accepted. A cursor is any
string to the schema but only one the service gave out is taken (400 invalid_cursor), and capture.json's
rules reach where a schema does not (a ball's hue on OpenCV's 0-180 scale, a time zone in captured_at);
those requests get a 4xx naming the field, which the other checks hold to the document.
"""

from __future__ import annotations

from collections.abc import Iterator

import httpx
import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from schemathesis import APIOperation
from schemathesis.checks import positive_data_acceptance

from tests.service.running import Service, start_service

EXAMPLES_PER_ROUTE = 30


@pytest.fixture(scope="module")
def fuzzed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    """A service of its own: the fuzzer creates, deletes and revokes things."""
    service = start_service(tmp_path_factory.mktemp("fuzzed"))
    yield service
    service.stop()


@pytest.fixture(scope="module")
def throwaway_prefix(fuzzed: Service) -> str:
    """The prefix of a key made to be revoked."""
    with fuzzed.client() as client:
        created = client.post("/v1/keys", json={"name": "revoked by the fuzzer", "scopes": ["read"]})
    assert created.status_code == 201, created.text
    return str(created.json()["prefix"])


def _fuzz(operation: APIOperation, fuzzed: Service, throwaway_prefix: str) -> None:
    """Send generated requests to one route until Hypothesis is done or one answer fails a check."""

    @given(case=operation.as_strategy())
    @settings(
        max_examples=EXAMPLES_PER_ROUTE,
        deadline=None,
        database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
    )
    def send(case: schemathesis.Case) -> None:
        if case.method == "DELETE" and case.path == "/v1/keys/{prefix}":
            case.path_parameters = {"prefix": throwaway_prefix}
        case.call_and_validate(
            base_url=fuzzed.url,
            headers={"Authorization": f"Bearer {fuzzed.admin_key}"},
            excluded_checks=[positive_data_acceptance],
        )

    send()


def test_no_generated_request_gets_a_5xx_and_every_answer_fits_the_schema(
    fuzzed: Service, throwaway_prefix: str
) -> None:
    """Every route of the document, each with its own generated requests; every failing route is named."""
    schema = schemathesis.openapi.from_url(f"{fuzzed.url}/openapi.json")
    operations = [result.ok() for result in schema.get_all_operations()]
    failures = {}
    for operation in operations:
        try:
            _fuzz(operation, fuzzed, throwaway_prefix)
        except (Exception, BaseExceptionGroup) as failure:  # a check failed: report every route at once
            failures[operation.label] = str(failure)[:2000]
    assert len(operations) > 20  # the whole API was fuzzed, not an empty document
    assert not failures, "\n\n".join(f"{label}:\n{text}" for label, text in failures.items())


def test_the_admin_key_survived_the_fuzzing(fuzzed: Service) -> None:
    """The fuzzer revoked nothing it must not have: its own key still works (run after the fuzzing)."""
    with httpx.Client(base_url=fuzzed.url, headers={"Authorization": f"Bearer {fuzzed.admin_key}"}) as client:
        assert client.get("/v1/keys/current").status_code == 200
