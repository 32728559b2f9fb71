"""``endocam check``: clean runs pass; each invariant, broken once in a clean log, is reported."""

from __future__ import annotations

import csv
import json
import math
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from endocam.cli import main
from endocam.config import ExperimentConfig
from endocam.robot.arm import PSM_MAX_VELOCITY
from endocam.robot.psm import PSM
from endocam.runner.check import CHECK_JSON, INVARIANTS, check_run
from endocam.runner.episode import EpisodeSpec, run_episode
from endocam.runner.outputs import EPISODE_CSV, METRICS_JSON, write_run
from endocam.task.trajectory import TrajectoryKind

DURATION_S = 3.0  # s: short clean episodes
STEP = 150  # the control step each edit breaks (mid-episode, tracking)
MM = 1e-3  # m


def _config(arm: str) -> ExperimentConfig:
    data = ExperimentConfig().model_dump(mode="json")
    data["task"]["trajectory"]["duration"] = DURATION_S
    data["episode"]["arm"] = arm
    return ExperimentConfig.model_validate(data)


def _write_clean(arm: str, tmp_path_factory: pytest.TempPathFactory) -> Path:
    result = run_episode(_config(arm), EpisodeSpec("endocam", TrajectoryKind.NOISY, 36, 1))
    out = tmp_path_factory.mktemp(f"clean-{arm}") / "run"
    write_run(result, out, video=False)
    return out


@pytest.fixture(scope="module")
def free_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _write_clean("free", tmp_path_factory)


@pytest.fixture(scope="module")
def psm_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _write_clean("psm", tmp_path_factory)


@pytest.fixture(params=["free_run", "psm_run"])
def clean_run(request: pytest.FixtureRequest) -> Path:
    return Path(request.getfixturevalue(request.param))


def _edited(run: Path, tmp_path: Path, edit: Callable[[list[dict[str, str]]], None]) -> Path:
    """A copy of ``run`` whose episode.csv rows went through ``edit``."""
    copy = tmp_path / "edited"
    shutil.copytree(run, copy)
    with open(copy / EPISODE_CSV, newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        names = list(reader.fieldnames or [])
        rows = list(reader)
    edit(rows)
    with open(copy / EPISODE_CSV, "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, names)
        writer.writeheader()
        writer.writerows(rows)
    return copy


def _add(row: dict[str, str], column: str, delta: float) -> None:
    row[column] = repr(float(row[column]) + delta)


def _steps(run: Path, invariant: str) -> set[int]:
    return {v.step for v in check_run(run).violations if v.invariant == invariant}


def test_clean_runs_hold_every_invariant(clean_run: Path) -> None:
    result = check_run(clean_run)
    assert result.ok, result.summary()
    assert set(result.counts) == set(INVARIANTS)
    metrics = json.loads((clean_run / METRICS_JSON).read_text())
    assert metrics["check"] == {"ok": True, "violations": 0, "counts": {}}
    assert json.loads((clean_run / CHECK_JSON).read_text())["ok"] is True


def test_camera_below_the_floor_is_reported(clean_run: Path, tmp_path: Path) -> None:
    floor = _config("free").controller.min_camera_height

    def edit(rows: list[dict[str, str]]) -> None:
        rows[STEP]["cam_z"] = repr(floor - 0.1 * MM)  # a tenth of a millimetre under

    assert STEP in _steps(_edited(clean_run, tmp_path, edit), "floor")


def test_camera_outside_the_cone_is_reported(clean_run: Path, tmp_path: Path) -> None:
    def edit(rows: list[dict[str, str]]) -> None:
        assert rows[STEP]["state"] in ("tracking", "planning")
        for i in range(STEP, len(rows)):  # the camera and its command 1 m away from then on
            _add(rows[i], "cam_x", 1.0)
            _add(rows[i], "cmd_x", 1.0)

    assert STEP in _steps(_edited(clean_run, tmp_path, edit), "cone")


def test_camera_near_the_wire_is_reported(clean_run: Path, tmp_path: Path) -> None:
    """The camera and its command put 3 mm beside the wire's surface: inside the clearance."""
    scene = json.loads((clean_run / "scene.json").read_text())
    points = np.asarray(scene["wire"]["points"])
    k = len(points) // 2
    tangent = points[k + 1] - points[k - 1]
    side = np.cross(tangent, [0.0, 0.0, 1.0])  # horizontal, perpendicular to the wire
    radius = scene["wire"]["wire_radius"]
    p = points[k] + (radius + 3 * MM) * side / np.linalg.norm(side)
    assert 3 * MM < _config("free").controller.wire_clearance

    def edit(rows: list[dict[str, str]]) -> None:
        assert rows[STEP]["state"] in ("tracking", "planning")
        for prefix in ("cam", "cmd"):
            for axis, value in zip("xyz", p.tolist(), strict=True):
                rows[STEP][f"{prefix}_{axis}"] = repr(value)

    found = [v for v in check_run(_edited(clean_run, tmp_path, edit)).violations]
    near = [v for v in found if v.invariant == "wire_clearance"]
    assert {v.step for v in near} == {STEP}
    assert {v.detail for v in near} == {"camera to the wire", "command to the wire"}
    assert [v.value for v in near] == pytest.approx([3 * MM] * 2, abs=0.2 * MM)


def test_a_missing_pose_value_is_reported(clean_run: Path, tmp_path: Path) -> None:
    def edit(rows: list[dict[str, str]]) -> None:
        rows[STEP]["cmd_qx"] = ""  # episode.csv writes NaN and inf as empty cells

    assert STEP in _steps(_edited(clean_run, tmp_path, edit), "finite")


def test_free_camera_teleport_breaks_its_cartesian_limits(free_run: Path, tmp_path: Path) -> None:
    def edit(rows: list[dict[str, str]]) -> None:
        _add(rows[STEP], "cam_x", 5 * MM)  # 5 mm in one 10 ms step: 0.5 m/s
        q = [float(rows[STEP + 20][f"cam_q{a}"]) for a in "xyzw"]
        turned = (Rotation.from_quat(q) * Rotation.from_rotvec([0.0, 0.0, 0.3])).as_quat()
        for a, v in zip("xyzw", turned, strict=True):
            rows[STEP + 20][f"cam_q{a}"] = repr(float(v))  # 0.3 rad in one step: 30 rad/s

    run = _edited(free_run, tmp_path, edit)
    for name in ("linear_speed", "linear_acceleration", "linear_jerk"):
        assert STEP in _steps(run, name), name
    for name in ("angular_speed", "angular_acceleration"):
        assert STEP + 20 in _steps(run, name), name


DT = 1.0 / ExperimentConfig().episode.control_rate  # s


def test_joint_beyond_its_range_is_reported(psm_run: Path, tmp_path: Path) -> None:
    upper = float(PSM().upper[0])

    def edit(rows: list[dict[str, str]]) -> None:
        rows[STEP]["q_outer_yaw"] = repr(upper + 0.01)

    assert STEP in _steps(_edited(psm_run, tmp_path, edit), "joint_position")


def test_joint_too_fast_is_reported(psm_run: Path, tmp_path: Path) -> None:
    jump = 2.0 * PSM_MAX_VELOCITY[2] * DT  # m: twice the insertion's speed limit for one step

    def edit(rows: list[dict[str, str]]) -> None:
        for row in rows[STEP:]:
            _add(row, "q_outer_insertion", -jump)

    assert STEP in _steps(_edited(psm_run, tmp_path, edit), "joint_velocity")


def test_joint_acceleration_beyond_its_limit_is_reported(psm_run: Path, tmp_path: Path) -> None:
    dv = 0.1 * PSM_MAX_VELOCITY[0]  # rad/s: a tenth of the speed limit, gained in one step

    def edit(rows: list[dict[str, str]]) -> None:
        for k in range(STEP, len(rows)):
            _add(rows[k], "q_outer_yaw", min(k - STEP, 3) * dv * DT)

    run = _edited(psm_run, tmp_path, edit)
    assert STEP in _steps(run, "joint_acceleration")
    assert not _steps(run, "joint_velocity")


def test_pose_not_at_fk_of_the_joints_is_reported(psm_run: Path, tmp_path: Path) -> None:
    def edit(rows: list[dict[str, str]]) -> None:
        _add(rows[STEP], "cam_y", 1e-3 * MM)  # a micrometre off FK(q)

    run = _edited(psm_run, tmp_path, edit)
    assert _steps(run, "fk") == {STEP}


def test_an_invalid_observation_not_held_is_reported(clean_run: Path, tmp_path: Path) -> None:
    def edit(rows: list[dict[str, str]]) -> None:
        assert rows[STEP]["state"] != "lost_tracking"
        rows[STEP]["fault"] = "ring_outlier"  # the log says the ring pose was wild here

    assert _steps(_edited(clean_run, tmp_path, edit), "lost_hold") == {STEP}


def test_a_frozen_tracker_acted_on_when_stale_is_reported(clean_run: Path, tmp_path: Path) -> None:
    """Frozen for 30 steps while the camera kept tracking: the steps past ring_max_age."""
    cfg = ExperimentConfig()
    first = STEP - 30
    # the repeated pose is at least (k - first) dt + latency old at step k
    fresh_steps = round((cfg.controller.ring_max_age - cfg.episode.sensing_latency) / DT)

    def edit(rows: list[dict[str, str]]) -> None:
        for k in range(first, STEP):
            assert rows[k]["state"] != "lost_tracking"
            rows[k]["fault"] = "tracker_frozen"

    reported = _steps(_edited(clean_run, tmp_path, edit), "lost_hold")
    assert reported == set(range(first + fresh_steps + 1, STEP))


def test_cli_exit_codes_and_check_json(
    free_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["check", str(free_run)]) == 0
    assert "OK" in capsys.readouterr().out

    def edit(rows: list[dict[str, str]]) -> None:
        rows[STEP]["cam_z"] = repr(-1.0)

    broken = _edited(free_run, tmp_path, edit)
    assert main(["check", str(free_run), str(broken)]) == 1
    out = capsys.readouterr().out
    assert f"step {STEP} " in out and "floor" in out
    written = json.loads((broken / CHECK_JSON).read_text())
    assert written["ok"] is False and written["counts"]["floor"] == 1
    floor = [v for v in written["violations"] if v["invariant"] == "floor"]
    assert floor[0]["step"] == STEP and math.isclose(floor[0]["t"], STEP * DT)

    assert main(["check", str(tmp_path / "nowhere")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "nowhere" in err


def test_read_rejects_foreign_files(free_run: Path, tmp_path: Path) -> None:
    copy = tmp_path / "foreign"
    shutil.copytree(free_run, copy)
    (copy / EPISODE_CSV).write_text("a,b\n1,2\n")
    with pytest.raises(ValueError, match="missing columns"):
        check_run(copy)
