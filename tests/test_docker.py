"""The container files in docker/, checked without a container engine: the compose file parses and names
only images, settings and commands that exist, the image runs as a user of its own, and the image's own
commands and health checks work when run in a plain virtual environment."""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path

import httpx
import yaml

from service.settings import Settings
from tests.service.running import CANOPY, free_port

ROOT = Path(__file__).resolve().parents[1]
DOCKER = ROOT / "docker"
AWS_SDK_VARIABLES = {"AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY", "AWS_REGION"}
"""The environment variables boto3 reads the object store's credentials and region from."""


def _instructions() -> list[tuple[str, str]]:
    """The Dockerfile's instructions, continuation lines joined, comments dropped: (keyword, arguments)."""
    text = re.sub(r"\\\n\s*", " ", (DOCKER / "Dockerfile").read_text())
    lines = [line.strip() for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    return [(line.split(None, 1)[0].upper(), line.split(None, 1)[1]) for line in lines]


def _final_stage() -> list[tuple[str, str]]:
    instructions = _instructions()
    last_from = max(index for index, (keyword, _) in enumerate(instructions) if keyword == "FROM")
    return instructions[last_from:]


def _exec_form(arguments: str) -> list[str]:
    """A JSON exec-form argument list (``CMD ["canopy", ...]``), the form signals reach the process in."""
    argv = json.loads(arguments)
    assert isinstance(argv, list) and all(isinstance(part, str) for part in argv), arguments
    return argv


def _compose() -> dict:
    return yaml.safe_load((DOCKER / "compose.yaml").read_text())


def _with_port(argv: list[str], port: int, default: int) -> list[str]:
    return [part.replace(str(default), str(port)) for part in argv]


def test_the_image_copies_what_exists_and_runs_as_its_own_user() -> None:
    instructions = _instructions()
    for keyword, arguments in instructions:
        if keyword == "COPY" and not arguments.startswith("--from"):
            *sources, _destination = shlex.split(arguments)
            for source in sources:
                assert (ROOT / source).exists(), f"COPY {source}: not in the repository"
    users = [arguments for keyword, arguments in _final_stage() if keyword == "USER"]
    assert users and users[-1] not in ("root", "0")
    kept = (DOCKER / "Dockerfile.dockerignore").read_text().splitlines()
    for keyword, arguments in instructions:
        if keyword == "COPY" and not arguments.startswith("--from"):
            for source in shlex.split(arguments)[:-1]:
                assert f"!{source}" in kept, f"{source} is copied but the .dockerignore leaves it out"


def test_the_compose_file_names_only_images_settings_and_commands_that_exist() -> None:
    compose = _compose()
    services = compose["services"]
    assert set(services) == {"postgres", "minio", "bucket", "api", "worker"}
    build = services["api"]["build"]
    assert (DOCKER / build["context"] / build["dockerfile"]).resolve() == (DOCKER / "Dockerfile").resolve()
    assert services["worker"]["image"] == services["api"]["image"]
    assert re.fullmatch(r"postgres:\d+(-bookworm)?", services["postgres"]["image"])
    assert re.fullmatch(r"minio/minio:RELEASE\.\d{4}-\d\d-\d\dT\d\d-\d\d-\d\dZ", services["minio"]["image"])
    assert services["bucket"]["image"] == services["minio"]["image"]
    fields = set(Settings.model_fields)
    for name in ("api", "worker"):
        for variable in services[name]["environment"]:
            if variable.startswith("AWS_"):
                assert variable in AWS_SDK_VARIABLES, (name, variable)
            else:
                assert variable.startswith("CANOPY_") and variable[7:].lower() in fields, (name, variable)
        assert services[name]["volumes"] in (["spool-api:/data"], ["/data"])
    commands = [services["worker"]["command"], _exec_form(dict(_final_stage())["CMD"])]
    for argv in commands:
        assert argv[0] == "canopy"
        helped = subprocess.run([CANOPY, argv[1], "--help"], capture_output=True, text=True, timeout=60)
        assert helped.returncode == 0, (argv, helped.stderr)
    environment = services["api"]["environment"]
    url = environment["CANOPY_DATABASE_URL"]
    assert url.startswith("postgresql+psycopg://") and "@postgres:5432/" in url
    assert environment["CANOPY_S3_ENDPOINT_URL"] == "http://minio:9000"
    assert (
        f"mc mb --ignore-existing canopy/{environment['CANOPY_S3_BUCKET']}"
        in services["bucket"]["command"][0]
    )
    assert environment["AWS_ACCESS_KEY_ID"] == services["minio"]["environment"]["MINIO_ROOT_USER"]
    assert environment["AWS_SECRET_ACCESS_KEY"] == services["minio"]["environment"]["MINIO_ROOT_PASSWORD"]


def test_the_image_s_commands_and_health_checks_work_in_a_plain_venv(tmp_path: Path) -> None:
    """The image's default command serves, its health check passes against it; the compose file's worker
    command runs a worker whose health check (its metrics port) passes too."""
    stage = dict(_final_stage())
    healthcheck = _exec_form(stage["HEALTHCHECK"].split("CMD", 1)[1].strip())
    command = _exec_form(stage["CMD"])
    port, metrics_port = free_port(), free_port()
    environment = {**os.environ, "CANOPY_DATA_DIR": str(tmp_path / "data"), "CANOPY_WORKER_POLL_S": "0.1"}
    environment.pop("CANOPY_DATABASE_URL", None)
    worker_service = _compose()["services"]["worker"]
    worker_environment = {
        **environment,
        "CANOPY_WORKER_METRICS_PORT": str(metrics_port),
    }
    assert worker_service["environment"]["CANOPY_WORKER_METRICS_PORT"] == "9100"
    worker_check = _with_port(worker_service["healthcheck"]["test"][1:], metrics_port, 9100)
    server = subprocess.Popen(
        [CANOPY, *_with_port(command, port, 8000)[1:]], env=environment, stderr=subprocess.DEVNULL
    )
    worker = None
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                if httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=1).status_code == 200:
                    break
            except httpx.TransportError:
                assert server.poll() is None and time.monotonic() < deadline, "canopy serve did not start"
                time.sleep(0.1)
        assert _run_check(_with_port(healthcheck, port, 8000)) == 0
        worker = subprocess.Popen(
            [CANOPY, *worker_service["command"][1:]], env=worker_environment, stderr=subprocess.DEVNULL
        )
        deadline = time.monotonic() + 60
        while _run_check(worker_check) != 0:
            assert worker.poll() is None and time.monotonic() < deadline, (
                "the worker's health check never passed"
            )
            time.sleep(0.2)
    finally:
        for process in (worker, server):
            if process is not None:
                process.terminate()
                process.wait(timeout=30)
    assert _run_check(_with_port(healthcheck, port, 8000)) != 0  # the check fails once the server is gone


def _run_check(argv: list[str]) -> int:
    """Run a health check's command here, ``python`` being this environment's."""
    program = sys.executable if argv[0] == "python" else argv[0]
    return subprocess.run([program, *argv[1:]], capture_output=True, timeout=30).returncode
