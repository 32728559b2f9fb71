"""``endocam experiment tracking``: files, schema, means that add up, phases, CLI errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from endocam.cli import main
from endocam.config import ExperimentConfig
from endocam.robot.actuator import ArmKind
from endocam.runner.tracking import (
    ARRIVED_M,
    PHASES,
    TRACKING_HTML,
    TRACKING_JSON,
    TRACKING_MD,
    PathSpec,
    episode_phases,
    run_tracking_experiment,
)
from endocam.task.trajectory import TrajectoryKind

DURATION_S = 2.0  # s, short episodes
MEAN_RTOL = 1e-9  # relative: a row mean is the plain mean of its episodes' metrics.json means
SHORT_TOML = f"""
[task.trajectory]
duration = {DURATION_S}

[camera]
width = 160
height = 120
"""
ROW_KEYS = {
    "speed_ratio",
    "controller",
    "carrier",
    "set",
    "image_error_px",
    "center_error_mm",
    "center_error_mid_mm",
    "orientation_error_deg",
    "ring_out_of_view_fraction",
    "episodes",
    "by_phase",
    "violations",
}


def short_config() -> ExperimentConfig:
    data = ExperimentConfig().model_dump()
    data["task"]["trajectory"]["duration"] = DURATION_S
    return ExperimentConfig.model_validate(data)


def test_phases_follow_the_logged_states() -> None:
    state = np.array(
        ["planning", "planning", "tracking", "planning", "frozen_outside_cone", "unreachable"]
    )
    assert list(episode_phases(state)) == [
        "approach",
        "approach",
        "tracking",
        "transfer",
        "frozen",
        "unreachable",
    ]
    assert set(episode_phases(np.array(["planning", "tracking"]))) <= set(PHASES)


def test_approach_lasts_until_the_camera_reaches_its_command() -> None:
    # a direct move logged as tracking is still the approach until the camera gets there
    n = 6
    cmd = np.tile(np.eye(4), (n, 1, 1))
    cam = np.tile(np.eye(4), (n, 1, 1))
    cam[:, 0, 3] = [0.10, 0.05, 0.02, ARRIVED_M / 2, 0.0, 0.0]  # m, closing in
    state = np.array(["tracking"] * n)
    assert list(episode_phases(state, cam, cmd)) == ["approach"] * 3 + ["tracking"] * 3


def test_rows_have_the_schema_and_average_the_episode_metrics(tmp_path: Path) -> None:
    paths = [
        PathSpec("ideal-10", "ideal", TrajectoryKind.IDEAL, 10, 0),
        PathSpec("noisy-10-s1", "noisy", TrajectoryKind.NOISY, 10, 1),
        PathSpec("noisy-10-s2", "noisy", TrajectoryKind.NOISY, 10, 2),
    ]
    out = tmp_path / "trk"
    run_tracking_experiment(
        short_config(),
        out,
        controllers=["paper", "oracle"],
        carriers=["free"],
        workers=1,
        paths=paths,
    )
    data = json.loads((out / TRACKING_JSON).read_text())
    rows = data["rows"]
    assert len(rows) == 2 * 2  # controllers × sets
    for row in rows:
        assert set(row) == ROW_KEYS
        assert set(row["by_phase"]) == set(PHASES)
        metrics = [json.loads((out / e / "metrics.json").read_text()) for e in row["episodes"]]
        assert len(metrics) == (1 if row["set"] == "ideal" else 2)
        for key in ("image_error_px", "center_error_mm", "orientation_error_deg"):
            want = np.mean([m[key]["mean"] for m in metrics])
            assert row[key] == pytest.approx(want, rel=MEAN_RTOL)
        want = np.mean([m["ring_out_of_view_fraction"] for m in metrics])
        assert row["ring_out_of_view_fraction"] == pytest.approx(want, rel=MEAN_RTOL, abs=0.0)
        fractions = sum(row["by_phase"][p]["fraction"] for p in PHASES)
        assert fractions == pytest.approx(1.0)
    for name in ("paper-free-ideal-10", "oracle-free-noisy-10-s2"):
        assert {"scene.json", "episode.csv", "metrics.json"} <= {
            p.name for p in (out / name).iterdir()
        }
        assert not (out / name / "video.mp4").exists()
    table = (out / TRACKING_MD).read_text()
    assert "paper, Sec. V" in table
    # the ratio printed beside a controller's figure is its mean over the oracle's (same set)
    for row in rows:
        oracle = next(r for r in rows if r["controller"] == "oracle" and r["set"] == row["set"])
        ratio = row["image_error_px"] / oracle["image_error_px"]
        assert f"{row['image_error_px']:.1f} (×{ratio:.2f})" in table


def test_cli_writes_the_files(tmp_path: Path) -> None:
    cfg = tmp_path / "short.toml"
    cfg.write_text(SHORT_TOML)
    out = tmp_path / "trk"
    code = main(
        [
            "experiment",
            "tracking",
            "--out",
            str(out),
            "--controllers",
            "oracle",
            "--carriers",
            "free",
            "--workers",
            "1",
            "--config",
            str(cfg),
        ]
    )
    assert code == 0
    for name in (TRACKING_JSON, TRACKING_MD, TRACKING_HTML, "image_error.png"):
        assert (out / name).stat().st_size > 0
    rows = json.loads((out / TRACKING_JSON).read_text())["rows"]
    assert [len(r["episodes"]) for r in rows] == [3, 3]  # 3 ideal, the 3 study paths


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--controllers", "zoom"], "unknown controller 'zoom'"),
        (["--carriers", "free,ecm"], "unknown carrier 'ecm'"),
        (["--seeds", "-1"], "--seeds"),
        (["--seeds", "x"], "integer"),
    ],
)
def test_bad_input_exits_2_with_one_line(
    args: list[str], needle: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        raise SystemExit(main(["experiment", "tracking", "--out", str(tmp_path / "o"), *args]))
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and needle in err


def test_unwritable_folder_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["experiment", "tracking", "--out", str(blocker / "sub")]) == 2
    assert "\n" not in capsys.readouterr().err.strip()


SPEED_RTOL = 1e-6  # relative round-off of ruckig's profiles on a speed limit


@pytest.mark.parametrize("arm", ["free", "psm"])
def test_speed_ratio_holds_and_catches_a_teleport(arm: str) -> None:
    from dataclasses import replace

    from endocam.runner.episode import EpisodeSpec, run_episode
    from endocam.runner.tracking import speed_ratio
    from endocam.task.trajectory import TrajectoryKind

    cfg = short_config().model_copy(
        update={"episode": short_config().episode.model_copy(update={"arm": ArmKind(arm)})}
    )
    r = run_episode(cfg, EpisodeSpec("endocam", TrajectoryKind.NOISY, 36, 1))
    assert 0.0 < speed_ratio(r) <= 1.0 + SPEED_RTOL
    # a camera that jumps 1 cm (1 m/s), or a joint that jumps 0.1 rad (10 rad/s), in one
    # control step breaks the limits (0.15 m/s; π rad/s)
    if arm == "free":
        T = r.log.T_world_cam.copy()
        T[len(T) // 2 :, 0, 3] += 0.01
        broken = replace(r, log=replace(r.log, T_world_cam=T))
    else:
        assert r.log.joints is not None
        q = r.log.joints.copy()
        q[len(q) // 2 :, 0] += 0.1
        broken = replace(r, log=replace(r.log, joints=q))
    assert speed_ratio(broken) > 1.0
