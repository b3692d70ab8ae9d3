"""Fixtures of the service tests: a running service per test or per module, and simulated captures."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest

from canopy_core.simulate import simulate_captures
from tests.service.running import Service, start_service


@pytest.fixture(scope="session")
def tree_capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A simulated two-view capture (native 1920x1080 JPEG colour) that measures, with ground truth."""
    [capture] = simulate_captures(tmp_path_factory.mktemp("simulated"), seed=7, count=1)
    return capture


@pytest.fixture
def capture_copy(tree_capture: Path, tmp_path: Path) -> Path:
    """A copy of the simulated capture that a test may change."""
    return Path(shutil.copytree(tree_capture, tmp_path / "capture"))


@pytest.fixture
def service(tmp_path: Path) -> Iterator[Service]:
    """A fresh `canopy serve` with its own SQLite file; start workers with ``service.start_worker()``."""
    running = start_service(tmp_path, job_lease_s="3", shutdown_grace_s="2")
    yield running
    running.stop()


@pytest.fixture(scope="module")
def shared_service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    """One `canopy serve` for a module of tests that each make their own captures."""
    running = start_service(tmp_path_factory.mktemp("service"), max_upload_bytes=str(4 * 1024 * 1024))
    yield running
    running.stop()
