"""The capture laptop's install: the base package alone (no extras) uploads to a live service and holds
neither the service's libraries nor the simulator's."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

from tests.service.running import Service

REPOSITORY = Path(__file__).resolve().parents[2]
SOURCES = ("pyproject.toml", "README.md", "canopy_core", "service", "worker", "migrations")
NOT_IN_THE_BASE = {
    "fastapi",
    "starlette",
    "uvicorn",
    "sqlalchemy",
    "alembic",
    "psycopg",
    "open3d",
    "matplotlib",
}


def _base_install(into: Path) -> Path:
    """A fresh virtual environment with ``pip install canopy`` (no extras) from a copy of the sources (the
    build leaves nothing in the repository); its bin folder."""
    source = into / "source"
    source.mkdir()
    for name in SOURCES:
        original = REPOSITORY / name
        if original.is_dir():
            shutil.copytree(original, source / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(original, source / name)
    venv = into / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    installed = subprocess.run(
        [str(venv / "bin" / "pip"), "install", "--quiet", str(source)],
        capture_output=True,
        text=True,
        timeout=900,
        check=False,
    )
    assert installed.returncode == 0, installed.stderr
    return venv / "bin"


def test_the_base_install_uploads_to_a_live_service_without_the_service_or_simulator_libraries(
    service: Service, tree_capture: Path, tmp_path: Path
) -> None:
    bin_dir = _base_install(tmp_path)
    listed = subprocess.run(
        [str(bin_dir / "python"), "-m", "pip", "list", "--format", "json"],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    distributions = {package["name"].lower() for package in json.loads(listed.stdout)}
    assert "canopy" in distributions and "numpy" in distributions
    assert distributions & NOT_IN_THE_BASE == set()

    canopy = str(bin_dir / "canopy")
    assert subprocess.run([canopy, "upload", "--help"], capture_output=True, timeout=60).returncode == 0
    refused = subprocess.run([canopy, "serve"], capture_output=True, text=True, timeout=60)
    assert refused.returncode == 2
    assert "pip install 'canopy[service]'" in refused.stderr

    service.start_worker()
    key = service.create_key("capture", "read")
    capture = Path(shutil.copytree(tree_capture, tmp_path / "row" / "tree"))
    uploaded = subprocess.run(
        [canopy, "upload", str(capture.parent), "--server", service.url, "--key", key, "--wait"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert uploaded.returncode == 0, uploaded.stderr
    assert service.query("SELECT state FROM jobs") == [("succeeded",)]
    assert service.query("SELECT COUNT(*) FROM measurements") == [(1,)]
