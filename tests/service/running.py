"""Real service processes for the tests: `canopy serve` and `canopy worker` on a temporary data folder.

Nothing is mocked: the server is uvicorn in its own process, workers are their own processes, the database
is a SQLite file, and the tests talk HTTP.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
from sqlalchemy import create_engine, text

from service.client.upload import files_to_send

CANOPY = str(Path(sys.executable).parent / "canopy")
START_TIMEOUT_S = 60.0


KEYLESS = {("DELETE", "/v1/session")}
"""Signing out needs no key: it forgets the session the browser's own cookie names, if any, and clears the
cookie, also when the session has expired (then no key would be accepted)."""


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def content_digest(data: bytes) -> str:
    """The RFC 9530 Content-Digest header value of ``data``."""
    return f"sha-256=:{base64.b64encode(hashlib.sha256(data).digest()).decode()}:"


@dataclass
class Service:
    """A running `canopy serve` with an admin key, and the workers a test starts beside it."""

    data_dir: Path
    environment: dict[str, str]
    url: str
    admin_key: str
    server: subprocess.Popen[bytes]
    workers: list[subprocess.Popen[bytes]] = field(default_factory=list)

    def query(self, sql: str, **parameters: Any) -> list[tuple[Any, ...]]:
        """The rows of ``sql`` (named parameters as ``:name``) read straight from the service's database,
        SQLite or PostgreSQL, as an auditor would."""
        url = self.environment.get("CANOPY_DATABASE_URL") or f"sqlite:///{self.data_dir / 'canopy.db'}"
        engine = create_engine(url)
        try:
            with engine.connect() as connection:
                return [tuple(row) for row in connection.execute(text(sql), parameters)]
        finally:
            engine.dispose()

    def client(self, key: str | None = None) -> httpx.Client:
        """An HTTP client with ``key`` (default: the admin key) as bearer token."""
        headers = {"Authorization": f"Bearer {key or self.admin_key}"}
        return httpx.Client(base_url=self.url, headers=headers, timeout=30.0)

    def canopy(self, *args: str) -> subprocess.CompletedProcess[str]:
        """Run a `canopy` command with this service's settings."""
        return subprocess.run(
            [CANOPY, *args], env=self.environment, capture_output=True, text=True, timeout=120, check=False
        )

    def create_key(self, *scopes: str) -> str:
        """A new key with these scopes, made by `canopy keys create` (its last line is the key)."""
        arguments = [part for scope in scopes for part in ("--scope", scope)]
        done = self.canopy("keys", "create", *arguments)
        assert done.returncode == 0, done.stderr
        return done.stdout.strip().splitlines()[-1]

    def start_worker(self) -> subprocess.Popen[bytes]:
        """Start a `canopy worker` process and wait until it takes jobs; it is stopped with the service."""
        log_path = self.data_dir / f"worker-{len(self.workers)}.log"
        with log_path.open("wb") as log:
            process = subprocess.Popen([CANOPY, "worker"], env=self.environment, stdout=log, stderr=log)
        self.workers.append(process)
        deadline = time.monotonic() + START_TIMEOUT_S
        while b"waiting for jobs" not in log_path.read_bytes():
            if process.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"canopy worker did not start: {log_path.read_text()}")
            time.sleep(0.05)
        return process

    def kill_server(self) -> None:
        """SIGKILL the server: no shutdown, no flushing, as a power cut or an OOM kill would."""
        self.server.send_signal(signal.SIGKILL)
        self.server.wait()

    def start_server(self) -> None:
        """Start `canopy serve` again on the same data folder and port."""
        self.server = _start_server(self.data_dir, self.environment, int(self.url.rsplit(":", 1)[1]))

    def stop(self) -> None:
        for process in [*self.workers, self.server]:
            if process.poll() is None:
                process.send_signal(signal.SIGTERM)
        for process in [*self.workers, self.server]:
            try:
                process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


def start_service(root: Path, *, database_url: str | None = None, **settings: str) -> Service:
    """Start `canopy serve` on a fresh data folder under ``root`` (settings as CANOPY_<NAME> values), its
    records in ``database_url`` (an empty database) or, by default, the data folder's SQLite file."""
    data_dir = root / "data"
    environment = {
        **os.environ,
        "CANOPY_DATA_DIR": str(data_dir),
        "CANOPY_WORKER_POLL_S": "0.1",
        **{f"CANOPY_{name.upper()}": value for name, value in settings.items()},
    }
    environment.pop("CANOPY_DATABASE_URL", None)
    if database_url is not None:
        environment["CANOPY_DATABASE_URL"] = database_url
    keys = subprocess.run(
        [CANOPY, "keys", "create", "--scope", "admin", "--name", "tests", "--init"],
        env=environment,
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    admin_key = keys.stdout.strip().splitlines()[-1]
    port = free_port()
    server = _start_server(data_dir, environment, port)
    return Service(data_dir, environment, f"http://127.0.0.1:{port}", admin_key, server)


def _start_server(data_dir: Path, environment: dict[str, str], port: int) -> subprocess.Popen[bytes]:
    """`canopy serve` on ``port``, once it answers /healthz."""
    with (data_dir / "server.log").open("ab") as log:
        server = subprocess.Popen(
            [CANOPY, "serve", "--port", str(port)], env=environment, stdout=log, stderr=log
        )
    deadline = time.monotonic() + START_TIMEOUT_S
    while True:
        try:
            if httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=1.0).status_code == 200:
                return server
        except httpx.TransportError:
            pass
        if server.poll() is not None or time.monotonic() > deadline:
            server.kill()
            raise RuntimeError(f"canopy serve did not start: {(data_dir / 'server.log').read_text()}")
        time.sleep(0.1)


def capture_files(folder: Path) -> dict[str, bytes]:
    """The bytes of the files the capture client sends, by their path in the capture folder."""
    return {path: file.read_bytes() for path, file in files_to_send(folder).items()}


def upload_capture(client: httpx.Client, folder: Path) -> int:
    """Create the capture of ``folder`` and upload every file; the capture's id."""
    created = client.post("/v1/captures", content=(folder / "capture.json").read_bytes())
    assert created.status_code in (200, 201), created.text
    capture_id = int(created.json()["id"])
    for path, data in capture_files(folder).items():
        sent = client.put(
            f"/v1/captures/{capture_id}/files/{path}",
            content=data,
            headers={"Content-Digest": content_digest(data)},
        )
        assert sent.status_code in (200, 201), sent.text
    return capture_id


def wait_for_job(client: httpx.Client, job_url: str, *, timeout_s: float = 120.0) -> dict[str, Any]:
    """Poll a job until it succeeds or fails; its last state."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        job = client.get(job_url).json()
        if job["state"] in ("succeeded", "failed"):
            return dict(job)
        time.sleep(0.1)
    raise AssertionError(f"job {job_url} did not finish in {timeout_s} s: {job}")


def create_tree(client: httpx.Client, orchard: str, row: str, tree: str) -> int:
    """Create a two-view capture (no files) of a tree, making its orchard and row on first sight; the
    tree's id."""
    manifest = {
        "format": "canopy-capture/1",
        "orchard": orchard,
        "row": row,
        "tree": tree,
        "captured_at": "2026-11-20T08:31:00Z",
        "views": ["views/1", "views/2"],
    }
    created = client.post("/v1/captures", content=json.dumps(manifest))
    assert created.status_code == 201, created.text
    return int(created.json()["tree_id"])


def start_up(data_dir: Path, port: int) -> tuple[subprocess.Popen[str], list[str]]:
    """Start `canopy up` and read its output until the API answers; the process and the lines read."""
    process = subprocess.Popen(
        [CANOPY, "up", "--port", str(port), "--data", str(data_dir)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "CANOPY_WORKER_POLL_S": "0.1"},
    )
    assert process.stdout is not None
    lines = []
    while "API on http://" not in "".join(lines):
        line = process.stdout.readline()
        assert line, f"canopy up ended: {''.join(lines)}"
        lines.append(line)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=1.0)
            break
        except httpx.TransportError:
            time.sleep(0.1)
    return process, lines


def stop_up(process: subprocess.Popen[str]) -> None:
    """Stop `canopy up` as Ctrl-C does, and wait for it."""
    process.send_signal(signal.SIGINT)
    process.wait(timeout=30)
