"""``endocam experiment faults``: its rows, its recovery measure, and its files (a small matrix)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from endocam.cli import EXIT_UNSAFE, main
from endocam.faults import ARM_FAULTS, FAULT_NAMES
from endocam.robot.actuator import ArmKind
from endocam.runner import fault_matrix
from endocam.runner.tracking import ARRIVED_M

DT = 0.01  # s


def test_rows_each_fault_twice_then_all() -> None:
    rows = fault_matrix.matrix_rows()
    free = [r for r in rows if r[0] is ArmKind.FREE]
    psm = [r for r in rows if r[0] is ArmKind.PSM]
    n_sev = len(fault_matrix.SEVERITIES)
    assert len(psm) == 2 + n_sev * len(FAULT_NAMES) + len(fault_matrix.SMALL_OUTLIERS)
    assert free[0][1] == "none" and free[-1][1] == "all"
    n_small = len(fault_matrix.SMALL_OUTLIERS)
    assert len(free) == 2 + n_sev * (len(FAULT_NAMES) - len(ARM_FAULTS)) + n_small
    outliers = {
        fault_matrix.row_faults(f, s).ring_outlier for _, f, s in free if s in ("1cm", "5deg")
    }
    assert {(o.distance, round(math.degrees(o.angle))) for o in outliers} == {(0.01, 0), (0.0, 5)}
    every = fault_matrix.row_faults("all", "high")
    assert all(getattr(every, name).rate > 0 for name in FAULT_NAMES)
    assert not fault_matrix.row_faults("none", "").any


def test_recovery_is_measured_from_the_end_of_each_burst() -> None:
    n = 100
    t = np.arange(n) * DT
    ref = np.tile(np.eye(4), (n, 1, 1))
    cam = ref.copy()
    cam[10:40, 0, 3] += 10 * ARRIVED_M  # off the reference until step 40
    cam[80:, 0, 3] += 10 * ARRIVED_M  # and from step 80 to the end
    fault = np.array([""] * n, dtype=object)
    fault[10:20] = "ring_dropout"  # ends at step 20: back at step 40 → 0.2 s
    fault[80:90] = "ring_outlier+tip_dropout"  # two faults end at 90, never back
    times = fault_matrix.recovery_times(t, fault, cam, ref)
    assert times[0] == pytest.approx(0.2)
    assert len(times) == 3 and all(math.isinf(x) for x in times[1:])


def test_a_small_matrix_writes_every_row(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(fault_matrix, "MATRIX_DURATION_S", 2.0)
    rows = [
        (ArmKind.FREE, "none", ""),
        (ArmKind.FREE, "ring_outlier", "high"),
        (ArmKind.FREE, "all", "high"),
    ]
    monkeypatch.setattr(fault_matrix, "matrix_rows", lambda carriers: rows)
    out = tmp_path / "faults"
    assert main(["experiment", "faults", "--out", str(out), "--workers", "1"]) == 0
    table = capsys.readouterr().out
    assert "ring_outlier" in table
    data = json.loads((out / fault_matrix.FAULTS_JSON).read_text())
    assert [(r["carrier"], r["fault"], r["severity"]) for r in data["rows"]] == [
        (c.value, f, s) for c, f, s in rows
    ]
    for row in data["rows"]:
        assert row["violations"] == 0
        header = (out / row["episode"] / "episode.csv").read_text().splitlines()[0]
        assert "fault" in header.split(",")
    everything = (out / "free-all-high" / "episode.csv").read_text()
    assert "step_overrun" in everything  # 5 bursts/s: some in the second after start_after
    assert data["rows"][-1]["bursts"] > 0
    assert (out / fault_matrix.FAULTS_HTML).is_file()


def test_an_unsafe_experiment_exits_3_and_says_so(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An experiment whose written runs break an invariant: exit 3, the last line says so."""

    def unsafe_matrix(config: object, out_dir: Path, **kwargs: object) -> str:
        run = Path(out_dir) / "free-ring_outlier-2cm"
        run.mkdir(parents=True)
        check = {"ok": False, "violations": 216, "counts": {"lost_hold": 216}}
        (run / "metrics.json").write_text(json.dumps({"check": check}))
        return "| table |"

    monkeypatch.setattr(fault_matrix, "run_fault_matrix", unsafe_matrix)
    out = tmp_path / "faults"
    assert main(["experiment", "faults", "--out", str(out), "--workers", "1"]) == EXIT_UNSAFE
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert last.startswith("safety check: 216 violations (lost_hold 216)") and str(out) in last
