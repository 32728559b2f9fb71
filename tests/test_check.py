"""``endocam check``: clean runs pass; each invariant, broken once in a clean log, is reported;
a log a broken controller or logger could write is refused (exit 2), never passed."""

from __future__ import annotations

import csv
import json
import math
import re
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from endocam.cli import main
from endocam.config import ExperimentConfig
from endocam.robot.actuator import ArmKind
from endocam.robot.arm import PSM_MAX_VELOCITY
from endocam.robot.psm import PSM
from endocam.runner.check import CHECK_JSON, INVARIANTS, SCENE_JSON, check_run, read_run
from endocam.runner.episode import EpisodeResult, EpisodeSpec, run_episode
from endocam.runner.log_schema import (
    QUAT_NORM_TOL,
    QUATERNION_PREFIXES,
    MalformedLogError,
    episode_column_names,
)
from endocam.runner.outputs import EPISODE_CSV, METRICS_JSON, episode_columns, write_run
from endocam.task.trajectory import TrajectoryKind

DURATION_S = 3.0  # s: short clean episodes
STEP = 150  # the control step each edit breaks (mid-episode, tracking)
MM = 1e-3  # m


def _config(arm: str) -> ExperimentConfig:
    data = ExperimentConfig().model_dump(mode="json")
    data["task"]["trajectory"]["duration"] = DURATION_S
    data["episode"]["arm"] = arm
    return ExperimentConfig.model_validate(data)


def _write_clean(result: EpisodeResult, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp(f"clean-{result.log.arm}") / "run"
    write_run(result, out, video=False)
    return out


@pytest.fixture(scope="module")
def free_result() -> EpisodeResult:
    return run_episode(_config("free"), EpisodeSpec("endocam", TrajectoryKind.NOISY, 36, 1))


@pytest.fixture(scope="module")
def free_run(free_result: EpisodeResult, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _write_clean(free_result, tmp_path_factory)


@pytest.fixture(scope="module")
def psm_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    result = run_episode(_config("psm"), EpisodeSpec("endocam", TrajectoryKind.NOISY, 36, 1))
    return _write_clean(result, tmp_path_factory)


@pytest.fixture(scope="module")
def ecm_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    result = run_episode(_config("ecm"), EpisodeSpec("endocam", TrajectoryKind.NOISY, 36, 1))
    return _write_clean(result, tmp_path_factory)


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


@pytest.mark.parametrize("carrier", ["free", "psm", "ecm"])
def test_clean_runs_hold_every_invariant(carrier: str, request: pytest.FixtureRequest) -> None:
    clean_run = Path(request.getfixturevalue(f"{carrier}_run"))
    result = check_run(clean_run)
    assert result.arm == carrier
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
    with pytest.raises(MalformedLogError, match="missing columns"):
        check_run(copy)


# ------------------------------------------------------------------------- malformed logs
Table = tuple[list[str], list[list[str]]]  # episode.csv: header, rows of cells
FIELD_LIMIT = 128 * 1024  # bytes: csv.field_size_limit()'s default, the largest cell read


def _drop(*columns: str) -> Callable[[Table], Table]:
    def edit(table: Table) -> Table:
        names, rows = table
        keep = [j for j, n in enumerate(names) if n not in columns]
        assert len(keep) == len(names) - len(columns), columns
        return [names[j] for j in keep], [[r[j] for j in keep] for r in rows]

    return edit


def _cells(column: str, f: Callable[[int, str], str]) -> Callable[[Table], Table]:
    """Rewrite one column: cell ``k`` (step ``k``) becomes ``f(k, cell)``."""

    def edit(table: Table) -> Table:
        names, rows = table
        j = names.index(column)
        for k, row in enumerate(rows):
            row[j] = f(k, row[j])
        return names, rows

    return edit


def _scaled(prefix: str, factor: float, step: int | None = None) -> Callable[[Table], Table]:
    """Multiply a logged quaternion by ``factor`` at ``step`` (every step if None)."""

    def edit(table: Table) -> Table:
        for a in "wxyz":

            def scale(k: int, cell: str) -> str:
                return repr(float(cell) * factor) if step in (None, k) else cell

            table = _cells(f"{prefix}_q{a}", scale)(table)
        return table

    return edit


def _rows(f: Callable[[list[list[str]]], list[list[str]]]) -> Callable[[Table], Table]:
    return lambda table: (table[0], f(table[1]))


def _with_column(name: str, value: str) -> Callable[[Table], Table]:
    return lambda table: ([*table[0], name], [[*r, value] for r in table[1]])


def _repeat(name: str) -> Callable[[Table], Table]:
    def edit(table: Table) -> Table:
        j = table[0].index(name)
        return [*table[0], name], [[*r, r[j]] for r in table[1]]

    return edit


PSM_Q = [f"q_{n}" for n in PSM().joint_names]
TAMPERED = {  # case: (carrier, edit of episode.csv, what the one-line refusal names)
    "truncated to 10 rows": ("free", _rows(lambda r: r[:10]), "10 rows, but 3 s"),
    "truncated to half": ("psm", _rows(lambda r: r[: len(r) // 2]), "150 rows, but 3 s"),
    "rows reversed": ("free", _rows(lambda r: r[::-1]), "t = 3.0 s at step 0"),
    "stamp duplicated": (
        "ecm",
        _cells("t", lambda k, c: repr((k - (k == STEP)) * DT)),  # t[STEP] = t[STEP - 1]
        f"at step {STEP}, expected",
    ),
    "times all zero": ("psm", _cells("t", lambda k, c: "0.0"), "t = 0.0 s at step 1"),
    "quaternion x2 on one row": (
        "free",
        _scaled("cam", 2.0, STEP),
        f"cam_q* at step {STEP} has norm 2",
    ),
    "quaternions x1.3 on all rows": ("psm", _scaled("cmd", 1.3), "cmd_q* at step 0 has norm 1.3"),
    "state relabelled": ("free", _cells("state", lambda k, c: c.upper()), "unknown state"),
    "unknown fault": (
        "psm",
        _cells("fault", lambda k, c: "ring_melt" if k == STEP else c),
        "unknown fault 'ring_melt'",
    ),
    "fault missing": ("free", _drop("fault"), "missing columns (carrier free): fault"),
    "cmd_qw missing": ("psm", _drop("cmd_qw"), "missing columns (carrier psm): cmd_qw"),
    "cam_z missing": ("free", _drop("cam_z"), "missing columns (carrier free): cam_z"),
    "cam_qz missing": ("ecm", _drop("cam_qz"), "missing columns (carrier ecm): cam_qz"),
    "q_roll missing": ("ecm", _drop("q_roll"), "missing columns (carrier ecm): q_roll"),
    "two q_ of a PSM dropped": ("psm", _drop(*PSM_Q[-2:]), "missing columns (carrier psm)"),
    "every q_ of a PSM dropped": ("psm", _drop(*PSM_Q), ", ".join(PSM_Q)),
    "an ECM's q_ in a free log": (
        "free",
        _with_column("q_yaw", "0.0"),
        "unexpected columns (carrier free): q_yaw",
    ),
    "column repeated": ("free", _repeat("cam_x"), "column cam_x appears more than once"),
    "field over 128 kB": (
        "psm",
        _cells("reason", lambda k, c: "x" * (FIELD_LIMIT + 1) if k == STEP else c),
        "field larger than field limit",
    ),
}


@pytest.fixture(scope="module")
def clean_tables(
    free_run: Path, psm_run: Path, ecm_run: Path
) -> dict[str, tuple[Path, list[list[str]]]]:
    """Each carrier's run and its episode.csv as rows of cells (header first), read once."""
    out = {}
    for carrier, run in (("free", free_run), ("psm", psm_run), ("ecm", ecm_run)):
        with open(run / EPISODE_CSV, newline="", encoding="utf-8") as fh:
            out[carrier] = (run, list(csv.reader(fh)))
    return out


def _tampered_run(
    clean: tuple[Path, list[list[str]]], edit: Callable[[Table], Table], tmp_path: Path
) -> Path:
    """A run folder holding the clean scene.json and the edited episode.csv."""
    run, rows = clean
    names, body = edit((list(rows[0]), [list(r) for r in rows[1:]]))
    copy = tmp_path / "tampered"
    copy.mkdir()
    shutil.copy(run / SCENE_JSON, copy / SCENE_JSON)
    with open(copy / EPISODE_CSV, "w", newline="", encoding="utf-8") as fh:
        csv.writer(fh).writerows([names, *body])
    return copy


@pytest.mark.parametrize("case", list(TAMPERED))
def test_a_tampered_log_is_refused_in_one_line_exit_2(
    case: str,
    clean_tables: dict[str, tuple[Path, list[list[str]]]],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    carrier, edit, named = TAMPERED[case]
    run = _tampered_run(clean_tables[carrier], edit, tmp_path)
    assert main(["check", str(run)]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert "\n" not in err and named in err and EPISODE_CSV in err, err
    assert "internal error" not in err and not captured.out
    assert not (run / CHECK_JSON).exists()


def _scene_edited(run: Path, tmp_path: Path, edit: Callable[[dict[str, Any]], None]) -> Path:
    copy = tmp_path / "scene-edited"
    copy.mkdir()
    shutil.copy(run / EPISODE_CSV, copy / EPISODE_CSV)
    scene = json.loads((run / SCENE_JSON).read_text())
    edit(scene)
    (copy / SCENE_JSON).write_text(json.dumps(scene))
    return copy


SCENE_TAMPERED: dict[str, tuple[Callable[[dict[str, Any]], None], str]] = {
    "no log section (an old run)": (lambda s: s.pop("log"), "no 'log' section"),
    "another log format": (lambda s: s["log"].update(format=99), "log format 99"),
    "carrier changed": (lambda s: s["log"].update(carrier="ecm"), "missing columns (carrier ecm)"),
    "unknown carrier": (lambda s: s["log"].update(carrier="hand"), "log carrier 'hand'"),
    "longer duration": (lambda s: s["log"].update(duration=4.0), "301 rows, but 4 s"),
    "period not the control rate's": (
        lambda s: s["log"].update(control_period=0.02),
        "not 1 / episode.control_rate",
    ),
}


@pytest.mark.parametrize("case", list(SCENE_TAMPERED))
def test_a_scene_json_that_does_not_describe_the_log_is_refused(
    case: str, psm_run: Path, tmp_path: Path
) -> None:
    edit, named = SCENE_TAMPERED[case]
    with pytest.raises(MalformedLogError, match=re.escape(named)):
        check_run(_scene_edited(psm_run, tmp_path, edit))


def test_clean_runs_of_every_carrier_pass_the_cli(
    free_run: Path, psm_run: Path, ecm_run: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["check", "-q", str(free_run), str(psm_run), str(ecm_run)]) == 0
    assert "3 of 3 runs hold every invariant" in capsys.readouterr().out


def test_the_writer_refuses_columns_other_than_the_schema(
    free_result: EpisodeResult, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The writer and the checker share one column list; the writer cannot drift from it."""
    assert list(episode_columns(free_result)) == list(episode_column_names(ArmKind.FREE))
    monkeypatch.setattr(
        "endocam.runner.outputs.episode_column_names",
        lambda carrier: (*episode_column_names(carrier), "cam_speed"),
    )
    with pytest.raises(RuntimeError, match="cam_speed"):
        episode_columns(free_result)


def test_the_quaternion_tolerance_sits_between_round_off_and_a_9_digit_print(
    free_run: Path,
) -> None:
    """Clean quaternions are unit to round-off; one printed to 9 digits would be refused."""
    log = read_run(free_run)
    for prefix in QUATERNION_PREFIXES:
        norm = np.linalg.norm(log.quat(prefix), axis=1)
        assert np.all(np.abs(norm - 1.0) <= QUAT_NORM_TOL)
    q = np.array([0.5, 0.5, 0.5, 0.5 + 0.5e-9])  # one component off by half a 9th digit
    assert abs(np.linalg.norm(q) - 1.0) > QUAT_NORM_TOL


def test_an_outlier_is_judged_against_the_gate_of_the_runs_own_source(
    free_run: Path, tmp_path: Path
) -> None:
    """A ring outlier between the truth gate's cap and the stereo gate's (raised by its noise
    floor): a hold is owed on truth, not on stereo, whose gate does not promise to see it."""
    truth = ExperimentConfig().controller.ring_limits
    stereo_cfg = ExperimentConfig.model_validate(
        {"perception": {"source": "stereo"}, "faults": {"ring_outlier": {"angle": 0.0}}}
    )
    stereo = stereo_cfg.controller_on_source.ring_limits
    assert stereo.position_gate > truth.position_gate
    distance = 0.5 * (truth.position_gate + stereo.position_gate)  # m, between the two caps

    def edit(rows: list[dict[str, str]]) -> None:
        assert rows[STEP]["state"] != "lost_tracking"
        rows[STEP]["fault"] = "ring_outlier"

    reported = {}
    for source in ("truth", "stereo"):
        run = _edited(free_run, tmp_path / source, edit)
        scene = json.loads((run / SCENE_JSON).read_text())
        scene["config"]["perception"]["source"] = source
        scene["config"]["faults"]["ring_outlier"].update(distance=distance, angle=0.0)
        (run / SCENE_JSON).write_text(json.dumps(scene))
        reported[source] = _steps(run, "lost_hold")
    assert reported == {"truth": {STEP}, "stereo": set()}
