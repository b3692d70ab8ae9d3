"""Validation against manual measurements over real measurements: each manual line paired with the tree's
measurement nearest in time, the unmatched ones named with the reason, and Table 1 (n, R², RMSE, ARE per
view mode and merged) equal to the figures computed here from the measurement documents."""

from __future__ import annotations

import csv
import io
import json
import math
import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from service.validation.schemas import Metrics
from service.validation.service import calculated_metrics
from tests.service.running import Service, start_service, upload_capture, wait_for_job

ORCHARD, ROW = "Validation orchard", "R7"
CAPTURES = {  # tree -> capture times (T0 twice, three weeks apart)
    "T0": ["2026-06-01T09:00:00Z", "2026-06-22T15:00:00Z"],
    "T1": ["2026-06-02T10:30:00Z"],
    "T2": ["2026-06-02T11:00:00Z"],
}
MANUAL = [  # orchard,row,tree,date,height_m,width_m,thickness_m
    (ORCHARD, ROW, "T0", "2026-06-03", "2.61", "1.70", "1.80"),  # nearest: 06-01 (1.9 days)
    (ORCHARD, ROW, "T0", "2026-06-20", "2.64", "1.66", "1.75"),  # nearest: 06-22 (2.1 days)
    (ORCHARD, ROW, "T1", "2026-06-02", "2.45", "", "1.69"),  # width not measured
    (ORCHARD, ROW, "T2", "2026-06-01", "2.70", "1.59", "1.84"),
    (ORCHARD, ROW, "T2", "2026-09-01", "2.90", "1.80", "1.90"),  # 91 days after its capture
    (ORCHARD, ROW, "T9", "2026-06-01", "2.00", "1.00", "1.00"),  # never captured
]
HEADER = "orchard,row,tree,date,height_m,width_m,thickness_m"


def _csv(lines: list[tuple[str, ...]]) -> bytes:
    return (HEADER + "\n" + "".join(",".join(line) + "\n" for line in lines)).encode()


@pytest.fixture(scope="module")
def validated(tree_capture: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Service, dict]]:
    """The service with three trees measured (T0 twice) and the manual CSV sent; the measurement documents
    by capture time."""
    service = start_service(tmp_path_factory.mktemp("validation"))
    service.start_worker()
    folder = tmp_path_factory.mktemp("trees")
    documents = {}
    try:
        with service.client() as client:
            for tree, times in CAPTURES.items():
                for number, captured_at in enumerate(times):
                    copy = Path(shutil.copytree(tree_capture, folder / f"{tree}-{number}"))
                    manifest = json.loads((copy / "capture.json").read_text())
                    (copy / "capture.json").write_text(
                        json.dumps(
                            {
                                **manifest,
                                "orchard": ORCHARD,
                                "row": ROW,
                                "tree": tree,
                                "captured_at": captured_at,
                            }
                        )
                    )
                    # Each capture measured with another region of interest, so the trees differ.
                    config = {"config": {"roi": {"radius_m": 1.0 + 0.15 * len(documents)}}}
                    capture_id = upload_capture(client, copy)
                    job = wait_for_job(
                        client,
                        client.post(f"/v1/captures/{capture_id}/jobs", json=config).headers["location"],
                    )
                    assert job["state"] == "succeeded", job
                    documents[(tree, captured_at)] = client.get(
                        f"/v1/measurements/{job['measurement_id']}"
                    ).json()
            receipt = client.post(
                "/v1/validation/manual", content=_csv(MANUAL), headers={"Content-Type": "text/csv"}
            )
            assert receipt.status_code == 200, receipt.text
            assert receipt.json() == {"lines": len(MANUAL), "created": len(MANUAL), "replaced": 0}
        yield service, documents
    finally:
        service.stop()


def _expected_row(pairs: list[tuple[float, float]]) -> tuple[int, float | None, float, float]:
    """n, R² (against the 1:1 line), RMSE (m) and ARE (%), computed here without the service's code."""
    n = len(pairs)
    mean_manual = sum(m for _, m in pairs) / n
    ss_res = sum((c - m) ** 2 for c, m in pairs)
    ss_tot = sum((m - mean_manual) ** 2 for _, m in pairs)
    r2 = 1 - ss_res / ss_tot if n > 1 and ss_tot > 0 else None
    return n, r2, math.sqrt(ss_res / n), 100 * sum(abs(c - m) / m for c, m in pairs) / n


def test_table_1_matches_r2_rmse_and_are_computed_independently(validated: tuple[Service, dict]) -> None:
    service, documents = validated
    with service.client() as client:
        answer = client.get("/v1/validation", params={"orchard": ORCHARD}).json()
    # Which measurement each manual line must meet: the capture nearest in time, within 14 days.
    nearest = {
        ("T0", "2026-06-03"): documents[("T0", CAPTURES["T0"][0])],
        ("T0", "2026-06-20"): documents[("T0", CAPTURES["T0"][1])],
        ("T1", "2026-06-02"): documents[("T1", CAPTURES["T1"][0])],
        ("T2", "2026-06-01"): documents[("T2", CAPTURES["T2"][0])],
    }
    assert {(p["tree"], p["measured_on"]): p["measurement_id"] for p in answer["pairs"]} == {
        key: document["id"] for key, document in nearest.items()
    }
    manual = {(line[2], line[3]): line[4:] for line in MANUAL}
    rows = {(row["mode"], row["metric"]): row for row in answer["table"]}
    assert {mode for mode, _ in rows} == {"views/1", "views/2", "merged"}
    for mode in ("views/1", "views/2", "merged"):
        for column, metric in enumerate(("height_m", "width_m", "thickness_m")):
            pairs = [
                (document["modes"][mode][metric], float(manual[key][column]))
                for key, document in nearest.items()
                if manual[key][column]
            ]
            n, r2, rmse_m, are_pct = _expected_row(pairs)
            row = rows[(mode, metric)]
            assert row["n"] == n == (3 if metric == "width_m" else 4)
            assert row["r2"] == pytest.approx(r2, rel=1e-9)
            assert row["rmse_m"] == pytest.approx(rmse_m, rel=1e-9)
            assert row["are_pct"] == pytest.approx(are_pct, rel=1e-9)


def test_unmatched_lines_are_reported_with_the_reason(validated: tuple[Service, dict]) -> None:
    service, _ = validated
    with service.client() as client:
        answer = client.get("/v1/validation").json()
        wider = client.get("/v1/validation", params={"window_days": 120}).json()
    unmatched = {(u["tree"], u["measured_on"]): u["reason"] for u in answer["unmatched"]}
    assert set(unmatched) == {("T2", "2026-09-01"), ("T9", "2026-06-01")}
    assert "91.0 days away, beyond the window of 14 days" in unmatched[("T2", "2026-09-01")]
    assert "no tree of this name" in unmatched[("T9", "2026-06-01")]
    assert answer["window_days"] == 14
    assert [(u["tree"], u["measured_on"]) for u in wider["unmatched"]] == [("T9", "2026-06-01")]
    assert len(wider["pairs"]) == 5


def test_table_1_as_csv_and_the_scatter_plot(validated: tuple[Service, dict]) -> None:
    service, _ = validated
    with service.client() as client:
        answer = client.get("/v1/validation").json()
        table = client.get("/v1/validation.csv")
        plot = client.get("/v1/validation.png")
        again = client.get("/v1/validation.png", headers={"If-None-Match": plot.headers["etag"]})
    lines = list(csv.DictReader(io.StringIO(table.text)))
    assert [(line["mode"], line["metric"], int(line["n"])) for line in lines] == [
        (row["mode"], row["metric"], row["n"]) for row in answer["table"]
    ]
    assert float(lines[-1]["are_pct"]) == pytest.approx(answer["table"][-1]["are_pct"])
    assert plot.headers["content-type"] == "image/png" and again.status_code == 304
    image = np.asarray(Image.open(io.BytesIO(plot.content)).convert("RGB")).astype(int)
    green = (image[:, :, 1] > 100) & (image[:, :, 0] < 80) & (image[:, :, 2] < 80)
    assert green.sum() > 50, "the merged pairs are drawn as filled green markers"


def test_sending_the_file_again_replaces_and_a_bad_line_stores_nothing(
    validated: tuple[Service, dict],
) -> None:
    service, _ = validated
    with service.client() as client:
        before = client.get("/v1/validation").json()
        again = client.post("/v1/validation/manual", content=_csv(MANUAL))
        bad = client.post(
            "/v1/validation/manual",
            content=_csv(
                [(ORCHARD, ROW, "T1", "2026-06-02", "9.9", "", "")]
                + [(ORCHARD, ROW, "T1", "2026-06-05", "245", "", "")]
            ),
        )
        after = client.get("/v1/validation").json()
    assert again.json() == {"lines": len(MANUAL), "created": 0, "replaced": len(MANUAL)}
    assert bad.status_code == 422 and bad.headers["content-type"] == "application/problem+json"
    problem = bad.json()
    assert (problem["line"], problem["column"]) == (3, "height_m")
    assert "'245' is not a length in metres" in problem["detail"]
    assert after == before


@pytest.mark.parametrize(
    ("body", "expected"),
    [
        (b"orchard,row,tree,date,height_m\n", "lacks the column(s) width_m, thickness_m"),
        (_csv([(ORCHARD, ROW, "T1", "02/06/2026", "2.4", "", "")]), "line 2, column date: '02/06/2026'"),
        (_csv([(ORCHARD, ROW, "", "2026-06-02", "2.4", "", "")]), "line 2, column tree"),
        (_csv([(ORCHARD, ROW, "T1", "2026-06-02", "", "", "")]), "line 2 holds none of"),
        (_csv([(ORCHARD, ROW, "T1", "2026-06-02", "2.4", "", "")] * 2), "line 3 repeats line 2"),
        (
            "orchard,row,tree,date,height_m,width_m,thickness_m\nÅ,R,T,2026-06-02,2,,\n".encode("latin-1"),
            "not UTF-8",
        ),
    ],
)
def test_a_bad_manual_file_is_a_422_naming_what_is_wrong(
    validated: tuple[Service, dict], body: bytes, expected: str
) -> None:
    service, _ = validated
    with service.client() as client:
        answer = client.post("/v1/validation/manual", content=body)
    assert answer.status_code == 422, answer.text
    assert expected in answer.json()["detail"]


def test_a_view_s_metric_its_frame_cut_is_left_out_of_table_1_like_one_not_measured() -> None:
    """A view that the tree runs out of reads a bound on H, not H: Table 1 leaves it out of that view's
    row (as a value the manual file lacks), and keeps the view's other metrics and the merged ones."""
    modes = {
        "views/1": {
            "height_m": 2.2,
            "width_m": 1.5,
            "thickness_m": 1.1,
            "cut_by_frame": ["height_m", "thickness_m"],
        },
        "views/2": {"height_m": 2.6, "width_m": 1.6, "thickness_m": 1.5, "cut_by_frame": []},
        "merged": {"height_m": 2.6, "width_m": 1.6, "thickness_m": 1.5},  # measured before the field existed
    }
    calculated = calculated_metrics(modes)
    assert calculated["views/1"] == Metrics(height_m=None, width_m=1.5, thickness_m=None)
    assert calculated["views/2"] == Metrics(height_m=2.6, width_m=1.6, thickness_m=1.5)
    assert calculated["merged"] == Metrics(height_m=2.6, width_m=1.6, thickness_m=1.5)
