"""A real browser for the page tests: Debian's Chromium, driven by Playwright for Python."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from contextlib import contextmanager

import pytest
from playwright.sync_api import Browser, sync_playwright

__all__ = ["chromium"]

_FLAGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--no-sandbox"]
"""WebGL without a GPU (SwiftShader, the software renderer Chromium ships), and no sandbox: tests run as
root in containers, where Chromium's sandbox cannot start."""


@contextmanager
def chromium() -> Iterator[Browser]:
    """A headless Chromium; the test is skipped, saying so, where none is installed (``./dev.sh test``
    installs Debian's ``chromium``)."""
    executable = shutil.which("chromium") or shutil.which("chromium-browser")
    if executable is None:
        pytest.skip("SKIPPED LOUDLY: no chromium on PATH (./dev.sh test installs Debian's chromium)")
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=executable, headless=True, args=_FLAGS)
        try:
            yield browser
        finally:
            browser.close()
