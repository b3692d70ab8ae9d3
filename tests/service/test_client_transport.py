"""The capture client's retry policy against a real (small, scripted) HTTP server, and its light imports."""

from __future__ import annotations

import http.server
import subprocess
import sys
import threading
from collections.abc import Iterator

import pytest

from service.client.transport import RequestRefused, ServerUnreachable, ServerUnusable, Transport


class _Scripted(http.server.BaseHTTPRequestHandler):
    """Answers each request with the next (status, headers) of the server's script, then 200."""

    def do_GET(self) -> None:
        server = self.server
        assert isinstance(server, _ScriptedServer)
        status, headers = server.script.pop(0) if server.script else (200, {})
        server.seen += 1
        body = b'{"detail": "scripted answer", "code": "scripted"}'
        self.send_response(status)
        for name, value in {"Content-Type": "application/json", **headers}.items():
            self.send_header(name, value)
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *_args: object) -> None:
        pass


class _ScriptedServer(http.server.ThreadingHTTPServer):
    script: list[tuple[int, dict[str, str]]]
    seen: int


@pytest.fixture
def scripted() -> Iterator[_ScriptedServer]:
    server = _ScriptedServer(("127.0.0.1", 0), _Scripted)
    server.script, server.seen = [], 0
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield server
    server.shutdown()
    server.server_close()


class _SimulatedTime:
    """A clock that advances only when slept on, recording each wait."""

    def __init__(self) -> None:
        self.now = 0.0
        self.waits: list[float] = []

    def sleep(self, seconds: float) -> None:
        self.waits.append(seconds)
        self.now += seconds

    def clock(self) -> float:
        return self.now


def _transport(
    server: _ScriptedServer, waits: list[float], retry_for_s: float = 60.0, notices: list[str] | None = None
) -> Transport:
    host, port = server.server_address[:2]
    simulated = _SimulatedTime()
    simulated.waits = waits
    return Transport(
        f"http://{host!s}:{port}",
        "key",
        retry_for_s=retry_for_s,
        sleep=simulated.sleep,
        clock=simulated.clock,
        notice=None if notices is None else notices.append,
    )


def test_server_errors_and_throttling_are_retried_honouring_retry_after(scripted: _ScriptedServer) -> None:
    scripted.script = [(503, {"Retry-After": "7"}), (429, {"Retry-After": "3"}), (502, {}), (408, {})]
    waits: list[float] = []
    response = _transport(scripted, waits).request("GET", "/v1/jobs/1")
    assert response.status_code == 200
    assert scripted.seen == 5
    assert waits[0] >= 7 and waits[1] >= 3
    assert all(wait >= 0 for wait in waits[2:])


def test_backoff_grows_exponentially_and_stays_capped(scripted: _ScriptedServer) -> None:
    scripted.script = [(500, {})] * 12
    waits: list[float] = []
    _transport(scripted, waits, retry_for_s=1e6).request("GET", "/x")
    bounds = [min(5.0, 0.25 * 2**attempt) for attempt in range(12)]
    assert all(0 <= wait <= bound for wait, bound in zip(waits, bounds, strict=True))


def test_client_errors_are_final_and_carry_the_problem(scripted: _ScriptedServer) -> None:
    scripted.script = [(409, {})]
    waits: list[float] = []
    with pytest.raises(RequestRefused) as refused:
        _transport(scripted, waits).request("GET", "/v1/captures/1")
    assert refused.value.status == 409
    assert refused.value.problem["code"] == "scripted"
    assert "scripted answer" in str(refused.value)
    assert (scripted.seen, waits) == (1, [])


def test_a_server_that_never_recovers_is_given_up_after_retry_for(scripted: _ScriptedServer) -> None:
    scripted.script = [(503, {"Retry-After": "40"})] * 5
    waits: list[float] = []
    with pytest.raises(ServerUnreachable, match="HTTP 503"):
        _transport(scripted, waits, retry_for_s=100.0).request("GET", "/x")
    assert scripted.seen == 3
    assert sum(waits) <= 100.0


def test_nothing_listening_is_retried_until_given_up() -> None:
    simulated = _SimulatedTime()
    transport = Transport(
        "http://127.0.0.1:9", "key", retry_for_s=5.0, sleep=simulated.sleep, clock=simulated.clock
    )
    with pytest.raises(ServerUnreachable, match="connection refused"):
        transport.request("GET", "/x")
    assert len(simulated.waits) >= 3
    assert sum(simulated.waits) <= 5.0


def test_an_outage_is_said_once_as_it_begins_and_once_as_it_ends(scripted: _ScriptedServer) -> None:
    scripted.script = [(503, {}), (502, {}), (503, {})]
    notices: list[str] = []
    transport = _transport(scripted, [], notices=notices)
    transport.request("GET", "/x")
    transport.request("GET", "/y")
    server = transport.server
    assert len(notices) == 2, notices
    assert notices[0] == (
        f"cannot reach {server}: HTTP 503 Service Unavailable; retrying for up to 60 s (Ctrl-C to stop)"
    )
    assert notices[1].startswith(f"reached {server} again after ")


@pytest.mark.parametrize("address", ["127.0.0.1:8201", "localhost:8000", "ftp://host", "http://"])
def test_an_address_without_http_or_https_is_refused_at_once(address: str) -> None:
    with pytest.raises(ServerUnusable, match="not an http:// or https:// address"):
        Transport(address, "key")


def test_a_server_that_answers_but_not_as_canopy_is_unusable(scripted: _ScriptedServer) -> None:
    with pytest.raises(ServerUnusable, match="not as a Canopy service"):
        _transport(scripted, []).identify()
    scripted.script = [(404, {})]
    with pytest.raises(ServerUnusable, match="HTTP 404"):
        _transport(scripted, []).identify()


def test_client_imports_neither_open3d_nor_the_server_stack() -> None:
    heavy = ("open3d", "fastapi", "sqlalchemy", "uvicorn", "scipy")
    probe = f"import sys, service.client.commands; print(sorted(set({heavy!r}) & set(sys.modules)))"
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]"
