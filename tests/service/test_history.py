"""A tree's growth over real measurements: its history oldest capture first as JSON, CSV and a plot of H,
W and D against the date, and in its report."""

from __future__ import annotations

import csv
import io
import json
import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest
from PIL import Image

from tests.service.running import Service, start_service, upload_capture, wait_for_job

CAPTURED = ["2026-08-20T10:00:00Z", "2026-05-02T09:00:00Z", "2026-06-15T16:30:00Z"]  # sent out of order
TREE = "=T1<script>alert(1)</script>"
"""A name from the field that a spreadsheet would run and a browser would execute, were it not guarded."""


@pytest.fixture(scope="module")
def grown(
    tree_capture: Path, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[tuple[Service, list[dict]]]:
    """One tree captured on three dates (each measured with another region of interest, so they differ):
    the service and the measurement documents in the order sent."""
    service = start_service(tmp_path_factory.mktemp("history"))
    service.start_worker()
    folder = tmp_path_factory.mktemp("captures")
    documents = []
    try:
        with service.client() as client:
            for number, captured_at in enumerate(CAPTURED):
                copy = Path(shutil.copytree(tree_capture, folder / str(number)))
                manifest = json.loads((copy / "capture.json").read_text())
                (copy / "capture.json").write_text(
                    json.dumps({**manifest, "tree": TREE, "captured_at": captured_at})
                )
                capture_id = upload_capture(client, copy)
                config = {"config": {"roi": {"radius_m": 0.9 + 0.2 * number}}}
                job = wait_for_job(
                    client, client.post(f"/v1/captures/{capture_id}/jobs", json=config).headers["location"]
                )
                assert job["state"] == "succeeded", job
                documents.append(client.get(f"/v1/measurements/{job['measurement_id']}").json())
        yield service, documents
    finally:
        service.stop()


def test_the_history_lists_the_measurements_oldest_capture_first(grown: tuple[Service, list[dict]]) -> None:
    service, documents = grown
    tree_id = documents[0]["tree_id"]
    by_date = sorted(documents, key=lambda document: document["captured_at"])
    with service.client() as client:
        history = client.get(f"/v1/trees/{tree_id}/history").json()
        table = client.get(f"/v1/trees/{tree_id}/history.csv").text
        plot = client.get(f"/v1/trees/{tree_id}/history.png")
    assert history["tree"] == TREE
    assert [point["measurement_id"] for point in history["measurements"]] == [d["id"] for d in by_date]
    assert [point["width_m"] for point in history["measurements"]] == [d["width_m"] for d in by_date]
    lines = list(csv.DictReader(io.StringIO(table)))
    assert [line["captured_at"] for line in lines] == [d["captured_at"] for d in by_date]
    assert lines[0]["tree"] == "'" + TREE  # a spreadsheet shows it as text, never runs it
    assert [float(line["height_m"]) for line in lines] == [d["height_m"] for d in by_date]
    assert plot.headers["content-type"] == "image/png" and Image.open(io.BytesIO(plot.content)).size[0] > 400


def test_the_report_shows_the_tree_s_growth(grown: tuple[Service, list[dict]]) -> None:
    service, documents = grown
    with service.client() as client:
        page = client.get(f"/v1/measurements/{documents[0]['id']}/report").text
    growth = page[
        page.index('<table id="growth">') : page.index("</table>", page.index('<table id="growth">'))
    ]
    assert growth.count("<tr>") == 1 + len(documents)
    assert growth.index("2026-05-02") < growth.index("2026-06-15") < growth.index("2026-08-20")
    assert 'alt="growth"' in page
    assert "<script>alert(1)</script>" not in page and "=T1&lt;script&gt;alert(1)&lt;/script&gt;" in page
    assert f"/v1/trees/{documents[0]['tree_id']}/history.csv" in page
