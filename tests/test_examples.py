"""The numbered examples run and produce what they promise (CI runs them, as ruckig's do).

Each runs as ``__main__`` in this process; ``free_tracking`` (a process pool of its own
functions) in a fresh interpreter.
"""

from __future__ import annotations

import json
import runpy
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
# Both distances are to the nearest vertex of a polyline: scene.json's 1000 points over the
# 273 mm wire (≤ 0.14 mm off) and the wire's 0.25 mm search polyline (≤ 0.125 mm off); 0.05 mm
# is the printed rounding.
POLYLINE_ATOL_MM = 0.14 + 0.125 + 0.05


def _run(*args: str) -> str:
    """Run an example as a script in a fresh interpreter; its standard output."""
    res = subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    return res.stdout


@pytest.fixture
def run_here(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> Callable[..., str]:
    """Run an example as ``__main__`` in this process (endocam already imported); its output.

    One interpreter start (~2 s of imports) less per example; ``free_tracking`` (a process
    pool of its own functions) runs in a fresh interpreter (:func:`_run`).
    """

    def run(script: Path, *args: str) -> str:
        monkeypatch.setattr(sys, "argv", [str(script), *args])
        capsys.readouterr()
        runpy.run_path(str(script), run_name="__main__")
        return capsys.readouterr().out

    return run


def test_goal_pose_example(run_here: Callable[..., str]) -> None:
    out = run_here(EXAMPLES / "01_goal_pose.py")
    assert out.count("horizon level") == 3


def test_controller_demo_writes_a_plot(tmp_path: Path, run_here: Callable[..., str]) -> None:
    png = tmp_path / "demo.png"
    out = run_here(EXAMPLES / "02_controller_demo.py", str(png))
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    errors = {line.split()[0]: float(line.split()[-2]) for line in out.splitlines()[:3]}
    # Only the orientation camera aligns with the normal; the others keep their orientation.
    assert errors["orientation"] < 0.2 * errors["fixed"]
    assert errors["centering"] == errors["fixed"]


def test_touch_distribution_prints_a_table(run_here: Callable[..., str]) -> None:
    out = run_here(EXAMPLES / "touch_distribution.py", "--seeds", "1", "--points", "36")
    row = [line for line in out.splitlines() if line.startswith("| 36 ")]
    assert len(row) == 1 and row[0].count("|") == 5


def test_free_tracking_prints_a_table_per_group() -> None:
    out = _run(
        str(EXAMPLES / "free_tracking.py"),
        *("--groups", "ideal", "--rows", "endocam", "orientation", "--duration", "3"),
        *("--jobs", "1"),
    )
    rows = [line for line in out.splitlines() if line.startswith("| endocam ")]
    assert len(rows) == 1 and rows[0].count("|") == 8


def test_env_policies_reports_returns_side_by_side(run_here: Callable[..., str]) -> None:
    out = run_here(EXAMPLES / "env_policies.py", "--duration", "2", "--policies", "fixed,endocam")
    rows = {
        line.split("|")[1].strip(): float(line.split("|")[2])
        for line in out.splitlines()
        if line.startswith("| ") and not line.startswith("| policy")
    }
    assert set(rows) == {"zero action", "fixed", "endocam"}
    assert rows["fixed"] == rows["zero action"]  # the fixed camera is the do-nothing agent
    assert rows["endocam"] != rows["fixed"]


CLEARANCE_EPISODE_S = 10.0  # s of simulated time per run


def test_camera_wire_clearance_reads_runs(tmp_path: Path, run_here: Callable[..., str]) -> None:
    from endocam.cli import main  # `endocam run` in this process: the example reads its files

    config = tmp_path / "short.toml"  # long enough for the camera to come down to the wire
    config.write_text(f"[task.trajectory]\nduration = {CLEARANCE_EPISODE_S}\n", encoding="utf-8")
    runs = []
    for policy in ("fixed", "endocam"):
        out = tmp_path / policy
        args = [
            "--policy",
            policy,
            "--arm",
            "free",
            "--trajectory",
            "noisy",
            "--config",
            str(config),
        ]
        args += ["--control-points", "36", "--seed", "1", "--out", str(out)]
        assert main(["run", "--no-video", *args]) == 0
        runs.append(str(out))
    text = run_here(EXAMPLES / "camera_wire_clearance.py", *runs)
    rows = {
        Path(line.split("|")[1].strip()).name: float(line.split("|")[2])
        for line in text.splitlines()
        if line.startswith(f"| {tmp_path}")
    }
    # The fixed camera holds the overview, far from the wire; the orientation camera looks
    # along the wire from its side, so it comes far closer (the limit the README names).
    assert rows["fixed"] > 2 * rows["endocam"]
    # metrics.json reports the same minimum, computed in the run from the wire's own spline.
    for policy, from_files_mm in rows.items():
        metrics = json.loads((tmp_path / policy / "metrics.json").read_text(encoding="utf-8"))
        reported_mm = metrics["camera_wire_clearance_mm"]["min"]
        assert abs(reported_mm - from_files_mm) <= POLYLINE_ATOL_MM
