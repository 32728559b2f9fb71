"""The CLI's last tracebacks (issue 12, section 4): unwritable outputs caught before any work,
every size bounded, and any exception at the top level one line (exit 1 internal, 2 usage)."""

from __future__ import annotations

from pathlib import Path

import pytest

from endocam.cli import main

UNWRITABLE = "/proc/endocam-out"  # os.access says writable to root; mkdir still fails


def _one_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err, err
    return err


def _never(*_args: object, **_kwargs: object) -> None:
    raise AssertionError("work started before the output folder was checked")


def test_run_into_an_unwritable_place_fails_before_simulating(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr("endocam.runner.experiments.run_and_write", _never)
    args = ["run", "--policy", "fixed", "--trajectory", "ideal", "--out", UNWRITABLE]
    assert main(args) == 2
    assert UNWRITABLE in _one_line(capsys)


def test_study_make_into_an_unwritable_place_fails_before_rendering(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr("endocam.study.make.make_study", _never)
    assert main(["study", "make", "--out", UNWRITABLE]) == 2
    assert UNWRITABLE in _one_line(capsys)


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["run", "--policy", "fixed", "--trajectory", "ideal", "--control-points",
          "99999999999"], "--control-points must be in 2..10000"),
        (["demo", "--control-points", "99999999999"], "--control-points must be in 2..10000"),
        (["experiment", "tracking", "--seeds", "1000000000"], "--seeds must be in 0..1000"),
        (["experiment", "tracking", "--workers", "100000"], "--workers must be in 1..64"),
        (["experiment", "faults", "--workers", "0"], "--workers must be in 1..64"),
    ],
)  # fmt: skip
def test_sizes_from_the_command_line_are_bounded(
    args: list[str], needle: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main([*args, "--out", str(tmp_path / "out")]) == 2
    assert needle in _one_line(capsys)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("toml", "needle"),
    [
        ("[task.trajectory]\nduration = 1e9\n", "task.trajectory.duration"),
        ("[task.trajectory]\ncontrol_points = 99999999999\n", "task.trajectory.control_points"),
        ("[task.trajectory]\nduration = 3000.0\n[episode]\ncontrol_rate = 2000.0\n",
         "control steps"),
        ("[task.trajectory]\ntouch_sample_dt = 1e-9\n", "clearance samples"),
        ("[camera]\nwidth = 100000\n", "camera.width"),
        ("[episode]\nvideo_fps = 1e6\n", "episode.video_fps"),
        ("[task.wire]\nsamples = 100000000000\n", "task.wire.samples"),
        ("[faults]\nring_dropout = {rate = 1e9}\n", "faults.ring_dropout.rate"),
    ],
)  # fmt: skip
def test_sizes_from_the_config_are_bounded(
    toml: str, needle: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = tmp_path / "big.toml"
    cfg.write_text(toml)
    assert main(["config", "--config", str(cfg)]) == 2
    assert needle in _one_line(capsys)


def test_faults_file_errors_are_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "faults.toml"
    bad.write_text("ring_outlier = {distance = -1.0}\n")
    args = ["run", "--policy", "fixed", "--trajectory", "ideal", "--faults", str(bad)]
    assert main([*args, "--out", str(tmp_path / "out")]) == 2
    assert "faults.ring_outlier.distance" in _one_line(capsys)


def test_internal_error_is_one_line_exit_1_and_traced_with_debug(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    def boom(_run: Path) -> None:
        raise RuntimeError("boom")

    monkeypatch.setattr("endocam.runner.check.check_run", boom)
    assert main(["check", str(tmp_path)]) == 1
    err = _one_line(capsys)
    assert "internal error: RuntimeError: boom" in err and "--debug" in err
    assert main(["--debug", "check", str(tmp_path)]) == 1
    assert "Traceback" in capsys.readouterr().err


def test_os_error_at_the_edge_is_one_line_exit_2(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    def refuse(_run: Path) -> None:
        raise PermissionError(13, "Permission denied", "/somewhere/check.json")

    monkeypatch.setattr("endocam.runner.check.check_run", refuse)
    assert main(["check", str(tmp_path)]) == 2
    assert "/somewhere/check.json: Permission denied" in _one_line(capsys)
