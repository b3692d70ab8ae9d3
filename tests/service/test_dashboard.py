"""The dashboard in a real browser against a live service: sign in with a key, see a job go from
queued to succeeded, open its report, find its numbers and figures and the 3D viewer drawn with the tree's
points (screenshot pixels); signing out ends the session. Session cookies read with their key's scopes
and never write."""

from __future__ import annotations

import io
import os
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest
from PIL import Image
from playwright.sync_api import Page

from tests.service.browser import chromium
from tests.service.running import Service, start_service, upload_capture

SCREENSHOTS = os.environ.get("CANOPY_SCREENSHOTS_DIR")
"""Where the test leaves its screenshots (the README's come from here: CANOPY_SCREENSHOTS_DIR=docs/images)."""


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[Service, str, str]]:
    """`canopy serve` alone on a fresh data folder, a read key and a capture key: the test starts the
    worker when it wants jobs to run, so that a queued job stays queued until the page has shown it (a
    two-second poll can miss a job that runs in one)."""
    service = start_service(tmp_path)
    try:
        keys = []
        for scope in ("read", "capture"):
            made = service.canopy("keys", "create", "--scope", scope, "--name", f"dashboard {scope}")
            assert made.returncode == 0, made.stderr
            keys.append(made.stdout.strip().splitlines()[-1])
        yield service, keys[0], keys[1]
    finally:
        service.stop()


def _shot(page: Page, name: str, tmp_path: Path) -> None:
    """A screenshot of the page's viewport, kept under CANOPY_SCREENSHOTS_DIR when set."""
    folder = Path(SCREENSHOTS) if SCREENSHOTS else tmp_path
    folder.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(folder / name))


def test_sign_in_follow_a_job_to_its_report_and_see_the_tree_in_3d(
    served: tuple[Service, str, str], tree_capture: Path, tmp_path: Path
) -> None:
    service, read_key, capture_key = served
    server = service.url
    with chromium() as browser:
        page = browser.new_page(viewport={"width": 1100, "height": 800})
        errors: list[str] = []
        page.on("pageerror", lambda error: errors.append(str(error)))
        page.goto(server + "/")
        page.fill("#key", read_key)
        page.click("button[type=submit]")
        page.wait_for_selector("#signed-in:not([hidden])")
        assert "dashboard read" in page.inner_text("#who")

        with httpx.Client(base_url=server, headers={"Authorization": f"Bearer {capture_key}"}) as client:
            capture_id = upload_capture(client, tree_capture)
            job_id = client.post(f"/v1/captures/{capture_id}/jobs").json()["id"]
        row = f"tr[data-job='{job_id}']"
        page.wait_for_selector(f"{row}[data-state=queued]", timeout=20_000)  # no worker runs yet
        service.start_worker()
        page.wait_for_selector(f"{row}[data-state=succeeded]", timeout=120_000)
        page.wait_for_selector("#farm tr[data-tree] a", timeout=10_000)  # the tree's latest H, W, D
        _shot(page, "dashboard.png", tmp_path)
        _fits_a_phone(page)

        page.click(f"{row} a")
        page.wait_for_selector("body[data-viewer=ready]", timeout=30_000)
        with httpx.Client(base_url=server, headers={"Authorization": f"Bearer {read_key}"}) as client:
            [measured] = client.get("/v1/jobs").json()["items"]
            document = client.get(f"/v1/measurements/{measured['measurement_id']}").json()
        assert page.inner_text("#height") == f"{document['height_m']:.2f} m"
        assert page.inner_text("#width") == f"{document['width_m']:.2f} m"
        assert page.inner_text("#thickness") == f"{document['thickness_m']:.2f} m"
        figures = page.eval_on_selector_all(
            ".figures img", "images => images.map(i => [i.alt, i.naturalWidth])"
        )
        assert {name for name, _ in figures} == set(document["figures"]) - {"report"}
        assert all(width > 200 for _, width in figures)
        canvas = page.locator("#viewer")
        canvas.scroll_into_view_if_needed()
        pixels = _pixels(canvas.screenshot())
        page.check("input[value=height]")
        by_height = _pixels(canvas.screenshot())
        page.evaluate("window.scrollTo(0, 0)")
        _shot(page, "report.png", tmp_path)
        _fits_a_phone(page)

        page.goto(server + "/")
        page.wait_for_selector("#sign-out:not([hidden])")
        page.click("#sign-out")
        page.wait_for_selector("#sign-in:not([hidden])")
        assert page.request.get(server + "/v1/jobs").status == 401
        assert errors == []
    # The canvas shows the tree: many pixels that are not the white background, in the points' own colours
    # (leaf greens among them), and others once coloured by height.
    drawn = (pixels < 235).any(axis=2)
    assert drawn.mean() > 0.02, f"only {drawn.mean():.3%} of the canvas is drawn"
    assert ((pixels[:, :, 1] > pixels[:, :, 2] + 15) & drawn).sum() > 500, "no leaf-green points drawn"
    assert np.abs(by_height - pixels).sum(axis=2).astype(bool).mean() > 0.01


def _fits_a_phone(page: Page) -> None:
    """On a phone's screen (390 px wide) the page needs no sideways scrolling: wide tables scroll alone."""
    size = page.viewport_size
    page.set_viewport_size({"width": 390, "height": 844})
    try:
        assert page.evaluate("document.documentElement.scrollWidth") <= 390
    finally:
        assert size is not None
        page.set_viewport_size(size)


def _pixels(png: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)


def test_a_session_reads_with_its_key_s_scopes_and_never_writes(served: tuple[Service, str, str]) -> None:
    service, read_key, _ = served
    server = service.url
    with httpx.Client(base_url=server) as browser:
        signed_in = browser.post("/v1/session", headers={"Authorization": f"Bearer {read_key}"})
        assert signed_in.status_code == 200 and signed_in.json()["key"]["scopes"] == ["read"]
        cookie = signed_in.headers["set-cookie"]
        assert "HttpOnly" in cookie and "SameSite=strict" in cookie and "Path=/" in cookie
        assert browser.get("/v1/jobs").status_code == 200
        assert (
            browser.get("/v1/keys").status_code == 403
        )  # the key has no admin scope: neither has its session
        writing = browser.post("/v1/captures", content=b"{}")
        assert writing.status_code == 401 and "reads only" in writing.json()["detail"]
        assert browser.post("/v1/session").status_code == 401  # a session cannot open another
        assert browser.delete("/v1/session").status_code == 204
        assert browser.get("/v1/jobs").status_code == 401
