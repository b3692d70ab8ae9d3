"""Row and orchard summaries over real measurements: statistics per metric over each tree's latest
measurement, the tree far from its row named, the same as CSV (names safe for spreadsheets), with ETags."""

from __future__ import annotations

import csv
import io
import json
import shutil
import statistics
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from service.database import Database
from service.farm.summaries import row_figure
from tests.service.running import Service, start_service, upload_capture, wait_for_job

TREES = 6
ORCHARD, ROW = "Summary orchard", "+R1"


@pytest.fixture(scope="module")
def summarised(
    tree_capture: Path, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[tuple[Service, dict]]:
    """Six trees of one row measured from the same capture; the last without moving its extremes out by
    half a pixel pitch (``metrics.edge_px`` 0), so its width is a centimetre less than the other five's,
    which are equal: with five equal values, the sixth stands 5/sqrt(6), about 2.04, sample standard
    deviations from the mean, whatever the difference. The service and the trees' measurements."""
    service = start_service(tmp_path_factory.mktemp("summaries"))
    service.start_worker()
    folder = tmp_path_factory.mktemp("trees")
    measurements = {}
    try:
        with service.client() as client:
            for number in range(TREES):
                copy = Path(shutil.copytree(tree_capture, folder / f"T{number}"))
                manifest = json.loads((copy / "capture.json").read_text())
                tree = f"T{number}"
                (copy / "capture.json").write_text(
                    json.dumps({**manifest, "orchard": ORCHARD, "row": ROW, "tree": tree})
                )
                capture_id = upload_capture(client, copy)
                config = {"config": {"metrics": {"edge_px": 0.0}}} if number == TREES - 1 else None
                job = wait_for_job(
                    client, client.post(f"/v1/captures/{capture_id}/jobs", json=config).headers["location"]
                )
                assert job["state"] == "succeeded", job
                measurements[tree] = client.get(f"/v1/measurements/{job['measurement_id']}").json()
        yield service, measurements
    finally:
        service.stop()


def _the_row(client: httpx.Client) -> dict:
    """The one row of the summarised orchard."""
    [orchard] = client.get("/v1/orchards", params={"name": ORCHARD}).json()["items"]
    [row] = client.get(f"/v1/orchards/{orchard['id']}/rows").json()["items"]
    return dict(row)


def test_a_row_summary_gives_each_metric_s_statistics_and_names_the_tree_far_from_its_row(
    summarised: tuple[Service, dict],
) -> None:
    service, measurements = summarised
    with service.client() as client:
        row = _the_row(client)
        summary = client.get(f"/v1/rows/{row['id']}/summary").json()
    widths = [measurement["width_m"] for measurement in measurements.values()]
    assert (summary["scope"], summary["name"], summary["orchard"]) == ("row", ROW, ORCHARD)
    assert (summary["trees"], summary["measured_trees"]) == (TREES, TREES)
    width = summary["metrics"]["width_m"]
    assert width["count"] == TREES
    assert width["mean"] == pytest.approx(statistics.mean(widths))
    assert width["median"] == pytest.approx(statistics.median(widths))
    assert (width["min"], width["max"]) == (pytest.approx(min(widths)), pytest.approx(max(widths)))
    assert width["std"] == pytest.approx(statistics.stdev(widths))
    assert set(summary["metrics"]) == {
        "height_m",
        "width_m",
        "thickness_m",
        "volume_hull_m3",
        "projected_area_m2",
    }
    narrow = [outlier for outlier in summary["outliers"] if outlier["metric"] == "width_m"]
    assert [outlier["tree"] for outlier in narrow] == [f"T{TREES - 1}"]
    assert narrow[0]["deviations"] < -2


def test_an_orchard_summary_holds_its_rows_and_the_csv_is_safe_to_open_in_a_spreadsheet(
    summarised: tuple[Service, dict],
) -> None:
    service, _ = summarised
    with service.client() as client:
        [orchard] = client.get("/v1/orchards", params={"name": ORCHARD}).json()["items"]
        summary = client.get(f"/v1/orchards/{orchard['id']}/summary").json()
        exported = client.get(f"/v1/orchards/{orchard['id']}/summary.csv")
        again = client.get(
            f"/v1/orchards/{orchard['id']}/summary.csv", headers={"If-None-Match": exported.headers["etag"]}
        )
        missing = client.get("/v1/rows/999999/summary")
    assert summary["scope"] == "orchard" and [row["name"] for row in summary["rows"]] == [ROW]
    assert summary["metrics"]["height_m"] == summary["rows"][0]["metrics"]["height_m"]
    lines = list(csv.DictReader(io.StringIO(exported.text)))
    assert len(lines) == 2 * 5  # the orchard and its row, five metrics each
    row_lines = [line for line in lines if line["scope"] == "row"]
    assert {line["row"] for line in row_lines} == {"'" + ROW}  # "+R1" would be a formula
    assert float(next(line for line in row_lines if line["metric"] == "width_m")["mean"]) == pytest.approx(
        summary["metrics"]["width_m"]["mean"]
    )
    assert again.status_code == 304
    assert missing.status_code == 404 and missing.json()["code"] == "not_found"


def test_the_row_figure_draws_each_tree_s_h_and_w_and_outlines_the_far_one(
    summarised: tuple[Service, dict],
) -> None:
    service, measurements = summarised
    with service.client() as client:
        row = _the_row(client)
        png = client.get(f"/v1/rows/{row['id']}/summary.png")
        outliers = client.get(f"/v1/rows/{row['id']}/summary").json()["outliers"]
    assert png.headers["content-type"] == "image/png" and png.content.startswith(b"\x89PNG")
    database = Database(f"sqlite:///{service.data_dir / 'canopy.db'}")
    try:
        with database.reading() as session:
            ax = row_figure(session, row["id"]).axes[0]
    finally:
        database.dispose()
    bars = {patch.get_gid(): patch for patch in ax.patches}
    for tree, measurement in measurements.items():
        assert bars[f"height_m-{tree}"].get_height() == measurement["height_m"]
        assert bars[f"width_m-{tree}"].get_height() == measurement["width_m"]
    outlined = {gid for gid, bar in bars.items() if bar.get_linewidth() == 2}
    far = {f"{o['metric']}-{o['tree']}" for o in outliers if o["metric"] in ("height_m", "width_m")}
    assert f"width_m-T{TREES - 1}" in outlined and outlined == far
    mean = next(line for line in ax.lines if line.get_gid() == "mean-width_m")
    assert mean.get_ydata()[0] == pytest.approx(statistics.mean(m["width_m"] for m in measurements.values()))
