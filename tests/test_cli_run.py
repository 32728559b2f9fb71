"""The ``endocam`` CLI: one-line errors with exit code 2, and complete outputs on success."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from endocam.cli import main
from endocam.config import load_config

SHORT_TOML = """
[task.trajectory]
duration = 2.0

[camera]
width = 160
height = 120

[episode]
video_fps = 10.0
"""


@pytest.fixture
def short_config(tmp_path: Path) -> Path:
    path = tmp_path / "short.toml"
    path.write_text(SHORT_TOML)
    return path


def _err_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip()
    assert "\n" not in err, f"error must be one line, got:\n{err}"
    assert "Traceback" not in err
    return err


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--policy", "zoom", "--trajectory", "noisy"], "invalid choice: 'zoom'"),
        (["--policy", "fixed", "--trajectory", "wavy"], "invalid choice: 'wavy'"),
        (["--policy", "fixed", "--trajectory", "noisy", "--control-points", "1"], "in 2.."),
        (["--policy", "fixed", "--trajectory", "noisy", "--control-points", "x"], "integer"),
        (["--policy", "fixed", "--trajectory", "noisy", "--seed", "-3"], "--seed"),
    ],
)
def test_bad_arguments_exit_2_with_one_line(
    args: list[str], needle: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exc:
        code = main(["run", *args, "--out", str(out)])
        raise SystemExit(code)
    assert exc.value.code == 2
    assert needle in _err_line(capsys)
    assert not out.exists()


@pytest.mark.parametrize(
    ("text", "suffix", "needle"),
    [
        ("[task.trajectory\nduration = 2", ".toml", "malformed"),
        ("[task.trajectory]\nduraton = 2.0\n", ".toml", "duraton"),
        ("[task.trajectory]\nposition_noise = [-0.001, 0.002]\n", ".toml", "position_noise"),
        ("task: {ring: {major_radius: -1}}\n", ".yaml", "major_radius"),
        ("camera: [1, 2]\n", ".yml", "camera"),
        ("x = 1\n", ".ini", "unknown format"),
    ],
)
def test_bad_config_exits_2(
    text: str, suffix: str, needle: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = tmp_path / f"bad{suffix}"
    cfg.write_text(text)
    out = tmp_path / "out"
    code = main(
        [
            "run",
            "--policy",
            "fixed",
            "--trajectory",
            "ideal",
            "--out",
            str(out),
            "--config",
            str(cfg),
        ]
    )
    assert code == 2
    assert needle in _err_line(capsys)
    assert not out.exists()


def test_missing_config_and_unwritable_output(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(
        [
            "run",
            "--policy",
            "fixed",
            "--trajectory",
            "ideal",
            "--out",
            str(tmp_path / "o"),
            "--config",
            str(tmp_path / "nope.toml"),
        ]
    )
    assert code == 2
    assert "cannot read config" in _err_line(capsys)
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code = main(
        ["run", "--policy", "fixed", "--trajectory", "ideal", "--out", str(blocker / "sub")]
    )
    assert code == 2
    assert "output" in _err_line(capsys)


def test_run_writes_everything(short_config: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    code = main(
        [
            "run",
            "--policy",
            "orientation",
            "--trajectory",
            "noisy",
            "--control-points",
            "36",
            "--seed",
            "2",
            "--out",
            str(out),
            "--config",
            str(short_config),
        ]
    )
    assert code == 0
    names = {p.name for p in out.iterdir()}
    assert names == {
        ".endocam-output",  # the marker: endocam may replace this folder
        "scene.json",
        "episode.csv",
        "check.json",
        "metrics.json",
        "video.mp4",
        "tracking.png",
        "report.html",
    }
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["config"] == load_config(short_config).model_dump(mode="json")
    assert metrics["episode"]["seed"] == 2
    # the default carrier is the PSM, and the report says so; the out-of-view share is reported
    assert metrics["arm"] == "psm"
    assert 0.0 <= metrics["ring_out_of_view_fraction"] <= 1.0
    assert "carried by a dVRK PSM" in (out / "report.html").read_text()


def test_console_script_lists_policies() -> None:
    res = subprocess.run(
        [sys.executable, "-m", "endocam.cli", "policies"],
        capture_output=True,
        text=True,
        check=True,
    )
    for name in ("fixed", "centering", "orientation"):
        assert name in res.stdout


def test_config_command_prints_validated_defaults(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["config"]) == 0
    text = capsys.readouterr().out
    assert "cone_base_radius: 0.25" in text
    assert "control_rate: 100.0" in text


def test_the_progress_bars_clock_starts_after_the_first_steps() -> None:
    """The first steps' compile or cache load is not read as the loop's speed."""
    import io
    import time

    from tqdm import tqdm

    from endocam.runner.experiments import clock_from_first_update

    first_steps_s = 0.5  # s: a stand-in for the first steps' kernel loading
    bar = tqdm(total=600, file=io.StringIO(), mininterval=0.0)
    update = clock_from_first_update(bar)
    time.sleep(first_steps_s)
    update(60)
    assert bar.n == 60  # the first steps count
    assert bar.format_dict["elapsed"] < first_steps_s  # but the clock starts after them
    update(60)
    assert bar.n == 120
    bar.close()
