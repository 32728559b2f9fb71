"""The CLI's last tracebacks (issue 12, section 4): unwritable outputs caught before any work,
every size bounded, and any exception at the top level one line (exit 1 internal, 2 usage).
Output folders and user mistakes (issue 24, section 3): ``--out`` never replaces a folder endocam
did not write, and no user mistake ends as an internal error."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from endocam.cli import main
from endocam.runner.outputs import OUTPUT_MARKER, atomic_dir

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)

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
        (["sweep", "--policy", "fixed", "--workers", "100000"], "--workers must be in 1..64"),
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
        ("[task.trajectory]\nduration = nan\n", "task.trajectory.duration: not a number"),
        ("[faults]\nring_dropout = {rate = nan}\n", "faults.ring_dropout.rate: not a number"),
        # 50 cm of position noise: beyond the ring's reach of the wire, R + r + wire radius
        ("[task.trajectory]\nposition_noise = [0.5, 0.6]\n",
         "beyond 0.007 m = ring.major_radius + ring.minor_radius + wire.radius"),
        # the default wire is 0.273 m long: margins of 2 × 0.2 m leave none of it
        ("[task.trajectory]\nend_margin = 0.2\n", "end_margin 0.2 m leaves no wire to follow"),
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


# --- output folders (issue 24, section 3) ---------------------------------------------------
WORK = (  # what each command does once its arguments are checked: never reached here
    "endocam.runner.experiments.run_and_write",
    "endocam.runner.experiments.run_demo",
    "endocam.runner.experiments.run_paper_experiment",
    "endocam.runner.tracking.run_tracking_experiment",
    "endocam.runner.fault_matrix.run_fault_matrix",
    "endocam.runner.sweep.run_sweep",
    "endocam.study.make.make_study",
    "endocam.study.analysis.analyze",
)
COMMANDS = {  # every command that takes --out, with its other required arguments
    "run": ["run", "--policy", "fixed", "--trajectory", "ideal"],
    "demo": ["demo"],
    "paper": ["experiment", "paper"],
    "tracking": ["experiment", "tracking"],
    "faults": ["experiment", "faults"],
    "sweep": ["sweep", "--policy", "fixed"],
    "study make": ["study", "make"],
    "study analyze": ["study", "analyze", "--responses", "r.csv", "--manifest", "m.json"],
}
BAD_OUT = {  # --out → the words of its refusal
    ".": "is the current folder",
    "": "the path is empty",
    "..": "contains the current folder",
    "HOME": "is your home folder",
    "victim": "endocam did not write it",
    "victim/important.txt": "is not a folder",
}


@pytest.mark.parametrize("command", list(COMMANDS))
@pytest.mark.parametrize("out", list(BAD_OUT))
def test_out_is_refused_before_any_work_unless_endocam_may_replace_it(
    command: str,
    out: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    cwd, home = tmp_path / "cwd", tmp_path / "home"
    (cwd / "victim").mkdir(parents=True)
    (cwd / "victim" / "important.txt").write_text("keep\n")
    (home / "notes").mkdir(parents=True)
    monkeypatch.chdir(cwd)
    monkeypatch.setenv("HOME", str(home))
    for work in WORK:
        monkeypatch.setattr(work, _never)
    target = str(home) if out == "HOME" else out
    assert main([*COMMANDS[command], "--out", target]) == 2
    assert BAD_OUT[out] in _one_line(capsys)
    assert (cwd / "victim" / "important.txt").read_text() == "keep\n"
    assert sorted(p.name for p in cwd.iterdir()) == ["victim"]  # no temporary folder left
    assert sorted(p.name for p in home.iterdir()) == ["notes"]


def test_atomic_dir_replaces_only_an_endocam_or_an_empty_folder(tmp_path: Path) -> None:
    ours = tmp_path / "ours"
    with atomic_dir(ours) as tmp:
        (tmp / "a.txt").write_text("1")
    assert (ours / OUTPUT_MARKER).is_file()  # marked: endocam may replace it
    with atomic_dir(ours) as tmp:
        (tmp / "b.txt").write_text("2")
    assert sorted(p.name for p in ours.iterdir()) == [OUTPUT_MARKER, "b.txt"]
    empty = tmp_path / "empty"
    empty.mkdir()
    with atomic_dir(empty) as tmp:
        (tmp / "c.txt").write_text("3")
    assert (empty / "c.txt").is_file()
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "important.txt").write_text("keep")
    with pytest.raises(ValueError, match="endocam did not write it"), atomic_dir(theirs):
        raise AssertionError("the block ran")
    assert [p.name for p in theirs.iterdir()] == ["important.txt"]
    # filled by someone else while the block ran: both kept, the finished one named
    with pytest.raises(ValueError, match=r"the finished output is in .*\.ours\.tmp-"):
        with atomic_dir(ours) as tmp:
            (ours / OUTPUT_MARKER).unlink()
            (tmp / "d.txt").write_text("4")
    assert (ours / "b.txt").is_file()
    kept = [p for p in tmp_path.iterdir() if p.name.startswith(".ours.tmp-")]
    assert len(kept) == 1 and (kept[0] / "d.txt").is_file()


# --- user mistakes are never internal errors (issue 24, section 3) --------------------------
def test_a_sweep_file_of_garbage_bytes_names_the_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    garbage = tmp_path / "sweep.toml"
    garbage.write_bytes(bytes(range(128, 256)))
    assert main(["sweep", "--config", str(garbage), "--out", str(tmp_path / "out")]) == 2
    err = _one_line(capsys)
    assert f"sweep {garbage} is not UTF-8 text (byte 0: 0x80)" in err


def test_config_encodings(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A byte-order mark is read (alone: an empty config); another encoding names the file."""
    bom = b"\xef\xbb\xbf"
    only = tmp_path / "only-bom.toml"
    only.write_bytes(bom)
    assert main(["config", "--config", str(only)]) == 0
    marked = tmp_path / "bom.yaml"
    marked.write_bytes(bom + b"episode:\n  control_rate: 50.0\n")
    assert main(["config", "--config", str(marked)]) == 0
    assert "control_rate: 50.0" in capsys.readouterr().out
    utf16 = tmp_path / "utf16.toml"
    utf16.write_bytes("[episode]\ncontrol_rate = 50.0\n".encode("utf-16"))
    assert main(["config", "--config", str(utf16)]) == 2
    assert f"config {utf16} is not UTF-8 text (byte 0: 0xff)" in _one_line(capsys)


def test_a_csv_field_over_the_limit_is_a_user_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import csv
    import json

    from study_helpers import manifest_dict

    manifest = tmp_path / "manifest.json"
    manifest.write_text(json.dumps(manifest_dict()), encoding="utf-8")
    responses = tmp_path / "responses.csv"
    field = "x" * (csv.field_size_limit() + 1)
    header = "participant_id,video_id,reported_touches,attention_passed"
    responses.write_text(f"{header}\np1,{field},3,true\n", encoding="utf-8")
    args = ["study", "analyze", "--manifest", str(manifest), "--responses", str(responses)]
    assert main([*args, "--out", str(tmp_path / "out")]) == 2
    assert f"{responses}: line 2: field larger than field limit" in _one_line(capsys)
    assert not (tmp_path / "out").exists()


def test_a_full_standard_output_is_one_clean_line(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    with open("/dev/full", "w", encoding="utf-8") as full:
        monkeypatch.setattr(sys, "stdout", full)
        assert main(["config"]) == 2
        err = _one_line(capsys)
    assert err == "endocam: error: standard output: No space left on device"
