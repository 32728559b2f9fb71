"""``endocam experiment perception``'s report on hand-made pairs (no rendering) and its CLI
bound: targets over the pairs at least half visible, wild estimates over all, one CSV row per
pair and condition; ``--frames`` under one per episode is a one-line usage error."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest

from endocam.cli import main
from endocam.runner.perception_experiment import (
    CONDITIONS,
    WILD_M,
    report_table,
    summarise,
    write_pairs_csv,
)

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)


def pair(occluded: float, centre_mm: float | None, normal_deg: float | None) -> dict:
    """One pair's row, the same errors in both conditions (``None``: no estimate)."""
    row = {
        "path": "ideal-36",
        "carrier": "free",
        "t_s": 1.0,
        "distance_mm": 50.0,
        "view_angle_deg": 10.0,
        "occluded_fraction": occluded,
        "blur_px": 0.1,
    }
    for c in CONDITIONS:
        row |= {
            c + "_centre_mm": centre_mm,
            c + "_normal_deg": normal_deg,
            c + "_status": "ok" if centre_mm is not None else "ambiguous",
            c + "_wall_ms": 8.0,
            c + "_cpu_ms": 4.0,
        }
    return row


ROWS = [
    pair(0.0, 0.2, 2.0),
    pair(0.1, 0.4, 3.0),
    pair(0.2, None, None),  # half visible, no estimate: counts against the share
    pair(0.9, 1e3 * WILD_M * 2, 50.0),  # mostly hidden and wild: only in the wild count
]


def test_the_report_counts_half_visible_pairs_and_every_wild_one() -> None:
    s = summarise(ROWS, "image_model")
    assert s["pairs"] == 4 and s["half_visible_pairs"] == 3
    assert s["estimate_share"] == pytest.approx(2 / 3)
    assert s["center_error_mm"]["max"] == pytest.approx(0.4)
    assert s["normal_error_deg"]["median"] == pytest.approx(2.5)
    assert s["wild_estimates_all_pairs"] == 1
    assert s["missing_reasons"] == {"ambiguous": 1}
    table = report_table({c: summarise(ROWS, c) for c in CONDITIONS})
    assert table.count("\n") == 1 + len(CONDITIONS)


def test_the_csv_has_a_row_per_pair_and_condition(tmp_path: Path) -> None:
    path = tmp_path / "pairs.csv"
    write_pairs_csv(ROWS, path)
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(ROWS) * len(CONDITIONS)
    assert {r["condition"] for r in rows} == set(CONDITIONS)
    missing = [r for r in rows if r["status"] == "ambiguous"]
    assert missing and all(r["center_error_mm"] == "" for r in missing)
    assert math.isclose(float(rows[0]["normal_error_deg"]), 2.0)


def test_too_few_frames_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["experiment", "perception", "--out", "unused", "--frames", "3"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--frames must be in 12.." in err and "\n" not in err
