"""The report page in a real browser against a live service: the numbers, the figures and a 3D viewer
whose canvas is drawn with the tree's points (checked on a screenshot's pixels, not only in the DOM)."""

from __future__ import annotations

import io
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from tests.service.browser import chromium
from tests.service.running import Service, start_service, upload_capture, wait_for_job


@pytest.fixture(scope="module")
def measured(tree_capture: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Service, dict]]:
    service = start_service(tmp_path_factory.mktemp("report"))
    service.start_worker()
    try:
        with service.client() as client:
            capture_id = upload_capture(client, tree_capture)
            job = wait_for_job(client, client.post(f"/v1/captures/{capture_id}/jobs").headers["location"])
            assert job["state"] == "succeeded", job
            yield service, client.get(f"/v1/measurements/{job['measurement_id']}").json()
    finally:
        service.stop()


def _pixels(png: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)


def test_the_report_shows_the_numbers_the_figures_and_a_drawn_3d_view(
    measured: tuple[Service, dict], tmp_path: Path
) -> None:
    service, document = measured
    with chromium() as browser:
        page = browser.new_page(
            viewport={"width": 1100, "height": 900},
            extra_http_headers={"Authorization": f"Bearer {service.admin_key}"},
        )
        errors: list[str] = []
        page.on("pageerror", lambda error: errors.append(str(error)))
        page.goto(f"{service.url}/v1/measurements/{document['id']}/report")
        page.wait_for_selector("body[data-viewer=ready]", timeout=30_000)
        assert errors == []
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
        colours = _pixels(canvas.screenshot())
        page.check("input[value=height]")
        by_height = _pixels(canvas.screenshot())
        page.screenshot(path=str(tmp_path / "report.png"), full_page=False)
    # The canvas shows the tree: many pixels that are not the white background, in the points' own colours
    # (greens and browns), and others once coloured by height.
    drawn = (colours < 235).any(axis=2)
    assert drawn.mean() > 0.02, f"only {drawn.mean():.3%} of the canvas is drawn"
    greenish = (colours[:, :, 1] > colours[:, :, 2] + 15) & drawn
    assert greenish.sum() > 500
    assert np.abs(by_height - colours).sum(axis=2).astype(bool).mean() > 0.01
