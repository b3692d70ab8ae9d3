"""A measurement's figures show where its numbers were read: read back from the drawn artists, the W segment
is the diameter of the top view's hull, the density curve first reaches the threshold at the reported crown
base, the elevation's lines stand at H and the crown base; and the worker stores them with the measurement,
served as PNG."""

from __future__ import annotations

import io
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from PIL import Image

from canopy_core.measure import Measurement, measure
from service.farm.history import TreeHistory
from service.reports.figures import draw_elevation, draw_height_density, draw_modes, draw_top_view
from service.reports.page import report_html
from tests.service.running import Service, start_service, upload_capture, wait_for_job


@pytest.fixture(scope="module")
def measured(tree_capture: Path) -> Measurement:
    return measure(tree_capture)


def _axes() -> Axes:
    return Figure().subplots()


def _artist(ax: Axes, gid: str) -> object:
    [found] = [artist for artist in ax.get_children() if artist.get_gid() == gid]
    return found


def test_the_w_segment_is_the_diameter_of_the_drawn_hull(measured: Measurement) -> None:
    ax = _axes()
    draw_top_view(ax, measured.cloud, measured.merged, measured.config.metrics)
    hull = np.asarray(_artist(ax, "hull").get_xydata())[:-1]  # the ring closes on its first vertex
    ends = np.asarray(_artist(ax, "width").get_xydata())
    gaps = np.linalg.norm(hull[:, None] - hull[None, :], axis=2)
    first, second = np.unravel_index(np.argmax(gaps), gaps.shape)
    diameter = hull[[first, second]]
    assert np.linalg.norm(ends[1] - ends[0]) == pytest.approx(measured.merged.width_m, abs=1e-9)
    # Each end lies on the diameter's line, at most a depth pixel (1 cm at 4 m) beyond its hull vertex.
    direction = (diameter[1] - diameter[0]) / np.linalg.norm(diameter[1] - diameter[0])
    for end in ends:
        nearest = diameter[np.argmin(np.linalg.norm(diameter - end, axis=1))]
        offset = end - nearest
        assert abs(offset[0] * direction[1] - offset[1] * direction[0]) < 1e-9
        assert 0.0 <= np.linalg.norm(offset) < 0.01
    points = np.asarray(_artist(ax, "tree-points").get_offsets())
    assert points.shape[0] > 1000


def test_the_density_curve_reaches_the_threshold_at_the_reported_crown_base(measured: Measurement) -> None:
    ax = _axes()
    draw_height_density(ax, measured.cloud, measured.merged, measured.config.metrics)
    density, heights = np.asarray(_artist(ax, "density").get_xydata()).T
    threshold = _artist(ax, "threshold").get_xdata()[0]
    base = _artist(ax, "crown-base-kde").get_ydata()[0]
    assert threshold == measured.config.metrics.kde_threshold
    assert base == measured.merged.crown_base_kde_m
    first = int(np.argmax(density >= threshold))
    assert density[first] >= threshold and (density[:first] < threshold).all()
    assert heights[first] == pytest.approx(base, abs=1e-12)
    assert _artist(ax, "crown-base").get_ydata()[0] == measured.merged.crown_base_m


def test_the_elevation_marks_h_the_crown_base_and_the_ground(measured: Measurement) -> None:
    ax = _axes()
    draw_elevation(ax, measured.cloud, measured.merged)
    assert _artist(ax, "height").get_ydata()[0] == measured.merged.height_m
    assert _artist(ax, "crown-base").get_ydata()[0] == measured.merged.crown_base_m
    assert _artist(ax, "ground").get_ydata()[0] == 0.0
    z = np.asarray(_artist(ax, "tree-points").get_offsets())[:, 1]
    assert measured.merged.height_m - 0.03 < z.max() <= measured.merged.height_m  # a sample of the points


def test_the_modes_panel_has_each_view_and_the_merged_views(measured: Measurement) -> None:
    ax = _axes()
    draw_modes(ax, measured.modes)
    for mode, metrics in measured.modes.items():
        bars = [patch for patch in ax.patches if patch.get_gid() == f"mode-{mode}"]
        assert [bar.get_height() for bar in bars] == [metrics.height_m, metrics.width_m, metrics.thickness_m]


@pytest.fixture(scope="module")
def measured_by_worker(
    tree_capture: Path, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[tuple[Service, dict]]:
    service = start_service(tmp_path_factory.mktemp("figures"))
    service.start_worker()
    try:
        with service.client() as client:
            capture_id = upload_capture(client, tree_capture)
            job = wait_for_job(client, client.post(f"/v1/captures/{capture_id}/jobs").headers["location"])
            assert job["state"] == "succeeded", job
            yield service, client.get(f"/v1/measurements/{job['measurement_id']}").json()
    finally:
        service.stop()


def test_the_worker_stores_every_figure_with_the_measurement(
    measured_by_worker: tuple[Service, dict],
) -> None:
    service, document = measured_by_worker
    figures = document["figures"]
    assert set(figures) == {
        "report",
        "elevation",
        "top",
        "density",
        "modes",
        "balls-views-1",
        "balls-views-2",
    }
    with service.client() as client:
        for name, href in figures.items():
            answer = client.get(href)
            assert answer.status_code == 200 and answer.headers["content-type"] == "image/png", name
            image = Image.open(io.BytesIO(answer.content))
            assert image.format == "PNG" and min(image.size) > 200, name
        report = client.get(f"/v1/measurements/{document['id']}/report.png")
        again = client.get(
            f"/v1/measurements/{document['id']}/report.png", headers={"If-None-Match": report.headers["etag"]}
        )
        missing = client.get(f"/v1/measurements/{document['id']}/figures/nothing.png")
        assert report.status_code == 200 and report.content == client.get(figures["report"]).content
    assert again.status_code == 304
    assert missing.status_code == 404 and missing.json()["code"] == "unknown_figure"


def test_the_report_marks_a_view_s_metrics_its_frame_cut_as_bounds(measured: Measurement) -> None:
    """A view whose image the tree runs out of reads at least its H (and at most its crown base): the
    report's table says so beside the number instead of showing it as a measurement like the others."""
    document = {**measured.to_dict(), "id": 1, "job_id": 1, "tree_id": 1}
    document["modes"]["views/2"]["cut_by_frame"] = ["crown_base_m", "height_m", "thickness_m"]
    growth = TreeHistory(tree_id=1, orchard="o", row="r", tree="t", measurements=[])
    page = report_html(document, {}, measured.cloud, growth)
    table = page[page.index("<h2>Per view and merged</h2>") : page.index("<h2>Registration</h2>")]
    rows = {row.split("</td>", 1)[0]: row for row in table.split("<tr><td>")[1:]}
    cut, whole = rows["views/2"], rows["views/1"]
    assert f"&ge; {measured.modes['views/2'].height_m:.3f}" in cut
    assert f"&le; {measured.modes['views/2'].crown_base_m:.3f}" in cut
    assert f"<td>{measured.modes['views/2'].width_m:.3f}</td>" in cut
    assert "&ge;" not in whole and "&le;" not in whole
    assert "runs out of that view's image" in table
