"""The capture client at a crew's edges, against real processes: the wrong address, no server, a key that
may not do what was asked, and a watch that reports each measurement as it completes. Each run says what
is wrong in one line, at once, whether or not it has a terminal."""

from __future__ import annotations

import http.server
import json
import shutil
import signal
import sqlite3
import subprocess
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import IO

import pytest

from tests.service.running import CANOPY, Service, free_port
from tests.service.test_client import _wait_for


@pytest.fixture
def one_capture(tree_capture: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(tree_capture, tmp_path / "row" / "T-a"))


def _run(service: Service, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [CANOPY, *args], env=service.environment, capture_output=True, text=True, timeout=120, check=False
    )


def _captures(service: Service) -> int:
    with sqlite3.connect(service.data_dir / "canopy.db") as database:
        return int(database.execute("SELECT count(*) FROM captures").fetchone()[0])


class _Lines:
    """Collects a process's output lines as they come, so a test can wait for one while it runs."""

    def __init__(self, stream: IO[str] | None) -> None:
        self.lines: list[str] = []
        assert stream is not None
        threading.Thread(target=lambda: self.lines.extend(iter(stream.readline, "")), daemon=True).start()

    def holds(self, text: str) -> bool:
        return any(text in line for line in list(self.lines))


def test_no_server_is_said_at_the_first_failure_without_a_terminal(
    service: Service, one_capture: Path
) -> None:
    """Before, the client stayed silent for its whole --retry-for (300 s) without a terminal."""
    address = f"http://127.0.0.1:{free_port()}"
    client = subprocess.Popen(
        [CANOPY, "upload", str(one_capture), "--server", address, "--key", service.admin_key],
        env=service.environment,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    output = _Lines(client.stderr)
    try:
        expected = f"cannot reach {address}: connection refused"
        _wait_for(lambda: output.holds(expected), timeout_s=60)
        assert client.poll() is None, "the message must come while the client still retries"
        assert output.holds("retrying for up to 300 s (Ctrl-C to stop)")
    finally:
        client.kill()
        client.wait()


def test_an_address_without_a_scheme_fails_at_once_in_one_line(service: Service, one_capture: Path) -> None:
    bare = service.url.removeprefix("http://")
    done = _run(service, "upload", str(one_capture), "--server", bare, "--key", service.admin_key)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        f"✗ --server '{bare}' is not an http:// or https:// address; did you mean http://{bare}?"
    ]
    assert _captures(service) == 0


def test_tls_spoken_to_the_plain_http_service_fails_at_once(service: Service, one_capture: Path) -> None:
    tls = service.url.replace("http://", "https://")
    done = _run(service, "upload", str(one_capture), "--server", tls, "--key", service.admin_key)
    assert done.returncode == 2
    assert f"cannot speak TLS with {tls}" in done.stderr
    assert f"use {service.url}" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1


class _NotCanopy(http.server.BaseHTTPRequestHandler):
    def do_GET(self) -> None:
        body = b"<html>router login</html>"
        self.send_response(200)
        self.send_header("Content-Type", "text/html")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *_args: object) -> None:
        pass


@pytest.fixture
def not_canopy() -> Iterator[str]:
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _NotCanopy)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()


def test_a_server_that_is_not_canopy_fails_at_once(
    service: Service, one_capture: Path, not_canopy: str
) -> None:
    done = _run(service, "upload", str(one_capture), "--server", not_canopy, "--key", service.admin_key)
    assert done.returncode == 2
    assert f"{not_canopy} answers, but not as a Canopy service; check --server" in done.stderr


def test_wait_with_a_key_that_may_not_read_is_refused_before_anything_is_sent(
    service: Service, one_capture: Path
) -> None:
    """Before, such a run sent everything and showed the trees as succeeded with empty H, W and D."""
    capture_only = service.create_key("capture")
    done = _run(service, "upload", str(one_capture), "--server", service.url, "--key", capture_only, "--wait")
    assert done.returncode == 2
    assert "--wait shows the measurements, which needs a key with the read scope; this key has capture" in (
        done.stderr
    )
    assert _captures(service) == 0


def test_a_revoked_key_is_refused_before_anything_is_sent(service: Service, one_capture: Path) -> None:
    key = service.create_key("capture")
    assert _run(service, "keys", "revoke", key.split("_")[1]).returncode == 0
    done = _run(service, "upload", str(one_capture), "--server", service.url, "--key", key)
    assert done.returncode == 2
    assert f"{service.url} refused the key: HTTP 401" in done.stderr
    assert _captures(service) == 0


def test_watch_prints_each_measurement_as_it_completes(service: Service, one_capture: Path) -> None:
    service.start_worker()
    day = one_capture.parent.parent / "today"
    day.mkdir()
    watcher = subprocess.Popen(
        [CANOPY, "watch", str(day), "--server", service.url, "--key", service.admin_key]
        + ["--interval", "0.2", "--settle", "0.5"],
        env=service.environment,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    output = _Lines(watcher.stdout)
    try:
        shutil.copytree(one_capture, day / "T-a")
        _wait_for(lambda: output.holds(": measured H "), timeout_s=300)
    finally:
        watcher.send_signal(signal.SIGINT)
        watcher.communicate(timeout=60)
    measured = [line for line in output.lines if ": measured H " in line]
    assert len(measured) == 1, f"one measurement printed once; the watcher said: {output.lines}"
    assert measured[0].rstrip().endswith(" m") and " W " in measured[0] and " D " in measured[0]


def test_a_misspelt_camera_key_is_refused_with_the_key_meant_by_upload_and_measure(
    service: Service, one_capture: Path
) -> None:
    """`depth_scael` for `depth_scale`: read as absent, the default scale would have given wrong metres.
    The client refuses the capture before sending anything, and `canopy measure` refuses it too, each
    naming the file, the key and the key meant (the server's answer: tests/service/test_bad_input.py)."""
    camera_path = one_capture / "views" / "2" / "camera.json"
    camera = json.loads(camera_path.read_text())
    camera["depth_scael"] = camera.pop("depth_scale")
    camera_path.write_text(json.dumps(camera))

    upload = _run(service, "upload", str(one_capture), "--server", service.url, "--key", service.admin_key)
    offline = _run(service, "measure", str(one_capture))

    expected = "depth_scael: unknown field; did you mean 'depth_scale'?"
    assert upload.returncode != 0
    assert expected in upload.stdout + upload.stderr
    assert "views/2/camera.json" in upload.stdout + upload.stderr
    assert _captures(service) == 0
    assert offline.returncode == 2
    assert expected in offline.stderr and "views/2/camera.json" in offline.stderr


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_watch_stops_on_ctrl_c_or_sigterm_even_started_with_sigint_ignored(
    service: Service, tmp_path: Path, stop: signal.Signals
) -> None:
    """A watch started in the background of a script inherits SIGINT ignored, and a service manager
    stops it with SIGTERM: either way it says so and ends, where before only SIGKILL stopped it."""
    day = tmp_path / "today"
    day.mkdir()
    watcher = subprocess.Popen(
        [CANOPY, "watch", str(day), "--server", service.url, "--key", service.admin_key, "--interval", "0.2"],
        env=service.environment,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )
    output = _Lines(watcher.stdout)
    try:
        _wait_for(lambda: output.holds("watching "), timeout_s=60)
        watcher.send_signal(stop)
        assert watcher.wait(timeout=30) == 0
    finally:
        watcher.kill()
    assert output.holds("stopped")
