"""``endocam sweep``: the grid, the tidy table, the summary, resume after a kill, failures, Ray."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from endocam.cli import EXIT_UNSAFE, main
from endocam.config import ExperimentConfig
from endocam.runner import experiments, sweep
from endocam.runner.episode import LOG_STATES
from endocam.runner.outputs import OUTPUT_MARKER
from endocam.runner.summary import mean_ci
from endocam.runner.sweep import (
    LOST,
    RAY_MISSING,
    SweepError,
    expand,
    import_ray,
    make_backend,
    parse_seeds,
    run_sweep,
    trajectory_order,
)

SHORT_S = 2.0  # s: episode length of these tests (the sweep machinery does not depend on it)
SHORT = ExperimentConfig.model_validate({"task": {"trajectory": {"duration": SHORT_S}}})
SHORT_TOML = f"[task.trajectory]\nduration = {SHORT_S}\n"
METRICS = [
    *(
        f"{e}_{s}"
        for e in ("image_error_px", "center_error_mm", "orientation_error_deg")
        for s in ("mean", "p95", "max")
    ),
    "ring_out_of_view_fraction",
    "touches",
    "contact_fraction",
    *(f"state_{s}" for s in LOG_STATES),
    "duration_s",
]


def _err_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err, err
    return err


def test_seed_ranges() -> None:
    assert parse_seeds("0-3") == [0, 1, 2, 3]
    assert parse_seeds("5,1-2") == [5, 1, 2]
    for bad in ("3-1", "a", "1,1", "-2"):
        with pytest.raises(SweepError):
            parse_seeds(bad)


def test_grid_is_the_product_and_names_are_unique() -> None:
    tasks = expand(SHORT, {"policy": ["fixed", "centering"], "seed": "0-2", "arm": ["free"]})
    assert len(tasks) == 2 * 3
    assert len({t.name for t in tasks}) == 6
    assert {(t.params["policy"], t.params["seed"]) for t in tasks} == {
        (p, s) for p in ("fixed", "centering") for s in range(3)
    }
    # a changed base config is a different sweep: new names, so a resume never mixes them
    other = SHORT.model_copy(update={"camera": SHORT.camera.model_copy(update={"width": 320})})
    assert not {t.name for t in tasks} & {t.name for t in expand(other, {"policy": ["fixed"]})}


def test_the_confidence_interval_is_students() -> None:
    mean, half, n = mean_ci([1.0, 2.0, 3.0])
    # t(0.975, 2 dof) = 4.303 (any table); sd = 1, n = 3
    assert (mean, n) == (2.0, 3)
    assert half == pytest.approx(4.303 / math.sqrt(3.0), rel=1e-3)


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--policy", "zoom"], "unknown policy 'zoom'"),
        (["--policy", "fixed", "--seeds", "3-1"], "seeds"),
        (["--policy", "fixed", "--set", "episode.latency=0.1"], "episode has control_rate"),
        (["--policy", "fixed", "--set", "episode=1"], "is a section"),
        (["--policy", "fixed", "--arm", "ufo"], "unknown arm"),
        (["--seeds", "1"], "names no policy"),
        (["--policy", "fixed", "--address", "x:1"], "--backend ray"),
        (["--config", "missing.toml"], "cannot read sweep"),
        # grids bounded before a list is built: MAX_SWEEP_EPISODES = 100000
        (["--policy", "fixed", "--seeds", "0-300000000"], "names 300000001 seeds, more than"),
        (["--policy", "fixed,centering", "--seeds", "0-99999"], "1 = 200000 episodes, more than"),
    ],
)
def test_mistakes_exit_2_with_one_line(
    args: list[str], needle: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["sweep", *args, "--out", str(tmp_path / "out")]) == 2
    assert needle in _err_line(capsys)
    assert not (tmp_path / "out").exists()


def test_missing_ray_names_the_extra(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` now fails
    with pytest.raises(SweepError, match=r"pip install endocam\[ray\]"):
        import_ray()
    args = ["sweep", "--policy", "fixed", "--backend", "ray", "--out", str(tmp_path / "o")]
    assert main(args) == 2
    assert _err_line(capsys).endswith(RAY_MISSING)


def test_sweep_file_table_summary_and_a_recorded_failure(tmp_path: Path) -> None:
    """A sweep file's grid × list; one row per episode; a bad value fails only its episode."""
    (tmp_path / "base.toml").write_text(SHORT_TOML)
    (tmp_path / "sweep.toml").write_text(
        'config = "base.toml"\n'
        "[grid]\n"
        'policy = ["fixed", "centering"]\n'
        '"episode.sensing_latency" = [0.05, -1.0]\n'  # -1 s: invalid, recorded per episode
        "[[list]]\n"
        'arm = "free"\nseed = 3\n'
    )
    out = tmp_path / "sweep"
    args = ["sweep", "--config", str(tmp_path / "sweep.toml"), "--out", str(out), "--workers", "1"]
    assert main(args) == 0
    table = pq.read_table(out / "results.parquet")
    params = ["policy", "trajectory", "control_points", "seed", "arm", "episode.sensing_latency"]
    assert table.column_names == ["episode", *params, *METRICS, "wall_time_s", "error"]
    assert table.schema.field("touches").type == pa.int64()
    assert table.schema.field("seed").type == pa.int64()
    assert table.schema.field("error").type == pa.string()
    assert all(table.schema.field(m).type == pa.float64() for m in METRICS if m != "touches")
    rows = table.to_pylist()
    assert len(rows) == 4
    assert {(r["policy"], r["episode.sensing_latency"]) for r in rows} == {
        (p, lat) for p in ("fixed", "centering") for lat in (0.05, -1.0)
    }
    for r in rows:
        assert (r["trajectory"], r["control_points"], r["seed"], r["arm"]) == (
            "noisy",
            71,
            3,
            "free",
        )
        assert r["wall_time_s"] > 0
        folder = out / "episodes" / r["episode"]
        if r["episode.sensing_latency"] < 0:
            assert "sensing_latency" in r["error"] and "greater than or equal to 0" in r["error"]
            assert all(r[m] is None for m in METRICS)
            assert json.loads((folder / "task.json").read_text())["error"] == r["error"]
            continue
        assert r["error"] is None
        files = {"scene.json", "episode.csv", "metrics.json", "tracking.png", "report.html"}
        assert files <= {p.name for p in folder.iterdir()}
        metrics = json.loads((folder / "metrics.json").read_text())
        assert r["orientation_error_deg_p95"] == metrics["orientation_error_deg"]["p95"]
        assert r["touches"] == len(metrics["touch_events"])
        assert r["duration_s"] == SHORT_S
        assert sum(r[f"state_{s}"] for s in LOG_STATES) == pytest.approx(1.0)
    html = (out / "summary.html").read_text()
    assert "<strong>2 failed</strong>" in html
    assert html.count("greater than or equal to 0") == 2  # both failures listed
    for swept in ("policy", "episode.sensing_latency"):
        png = out / "plots" / f"{swept}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"plots/{swept}.png" in html


def test_episodes_sharing_a_trajectory_detect_its_touches_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Two policies on two trajectories in one worker: touch detection runs once per trajectory."""
    detected: list[object] = []
    touch_events = experiments.touch_events

    def counted(*args: Any) -> Any:
        detected.append(args[0])
        return touch_events(*args)

    monkeypatch.setattr(experiments, "touch_events", counted)
    monkeypatch.setattr(sweep, "_TOUCHES", {})  # nothing from other tests
    tasks = expand(SHORT, {"policy": ["fixed", "centering"], "seed": [5, 6], "arm": ["free"]})
    order = [(t.params["seed"], t.params["policy"]) for t in trajectory_order(tasks)]
    assert [seed for seed, _ in order] == [5, 5, 6, 6]  # the grid's order was policy first
    outcome = run_sweep(tasks, tmp_path / "sweep", make_backend("local", workers=1))
    assert outcome.failed == 0
    assert len(detected) == 2  # four episodes, two trajectories


def test_resume_after_a_kill_runs_only_the_missing_episodes(tmp_path: Path) -> None:
    base = tmp_path / "base.toml"
    base.write_text(SHORT_TOML)
    out = tmp_path / "sweep"
    n = 4  # the kill comes after 2 finished episodes, long before the last
    args = ["sweep", "--policy", "centering", "--arm", "free", "--seeds", f"0-{n - 1}"]
    args += ["--base-config", str(base), "--out", str(out), "--workers", "1"]
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    proc = subprocess.Popen(
        [sys.executable, "-m", "endocam.cli", *args],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=env,
    )
    episodes = out / "episodes"
    deadline = time.monotonic() + 120.0
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if episodes.is_dir() and len(list(episodes.glob("[!.]*"))) >= 2:
                break
            time.sleep(0.01)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait()
    before = {p.name: (p / "task.json").stat().st_mtime_ns for p in episodes.glob("[!.]*")}
    assert 2 <= len(before) < n, "kill the sweep half-way"
    assert all((episodes / name / "metrics.json").is_file() for name in before)
    assert not (out / "results.parquet").exists()

    assert main(args) == 0
    after = {p.name: (p / "task.json").stat().st_mtime_ns for p in episodes.glob("[!.]*")}
    assert len(after) == n
    assert {k: after[k] for k in before} == before  # the finished ones were not run again
    assert not list(episodes.glob(".*"))  # nothing half-written left behind
    table = pq.read_table(out / "results.parquet")
    assert sorted(table.column("seed").to_pylist()) == list(range(n))
    assert table.column("error").null_count == n


def test_same_metrics_on_ray_locally_and_alone(tmp_path: Path) -> None:
    """One small grid on a local Ray and on the local pool; one episode also by `endocam run`."""
    import ray

    grid = {"policy": ["orientation", "centering"], "seed": [2], "arm": ["free"]}
    tasks = expand(SHORT, grid)
    ray.init(
        num_cpus=1,  # one Ray worker (one more endocam import) runs both remote episodes
        include_dashboard=False,
        log_to_driver=False,
        object_store_memory=80 * 2**20,
    )
    try:
        on_ray = run_sweep(tasks, tmp_path / "ray", make_backend("ray"))
    finally:
        ray.shutdown()
    local = run_sweep(tasks, tmp_path / "local", make_backend("local", workers=1))
    assert on_ray.ran == local.ran == 2 and on_ray.failed == local.failed == 0
    ray_rows = {r["episode"]: r for r in pq.read_table(on_ray.results).to_pylist()}
    local_rows = {r["episode"]: r for r in pq.read_table(local.results).to_pylist()}
    assert ray_rows.keys() == local_rows.keys()
    for name, r in ray_rows.items():
        assert {m: r[m] for m in METRICS} == {m: local_rows[name][m] for m in METRICS}

    base = tmp_path / "base.toml"
    base.write_text(SHORT_TOML)
    alone = tmp_path / "alone"
    run_args = ["run", "--policy", "orientation", "--trajectory", "noisy", "--seed", "2"]
    run_args += ["--arm", "free", "--no-video", "--config", str(base), "--out", str(alone)]
    assert main(run_args) == 0
    metrics = json.loads((alone / "metrics.json").read_text())
    (row,) = [r for r in ray_rows.values() if r["policy"] == "orientation"]
    assert row["image_error_px_mean"] == metrics["image_error_px"]["mean"]
    assert row["center_error_mm_p95"] == metrics["center_error_mm"]["p95"]
    assert row["orientation_error_deg_mean"] == metrics["orientation_error_deg"]["mean"]
    assert row["touches"] == metrics["touches"]
    ray_csv = (tmp_path / "ray" / "episodes" / row["episode"] / "episode.csv").read_text()
    assert ray_csv == (alone / "episode.csv").read_text()


def _die(task: object, episodes_dir: object) -> str:
    os._exit(3)  # a worker process killed mid-episode (e.g. out of memory)


def test_a_dead_worker_loses_its_episode_not_the_sweep(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    tasks = expand(SHORT, {"policy": ["fixed"], "seed": [0, 1], "arm": ["free"]})
    monkeypatch.setattr("endocam.runner.sweep.run_task", _die)
    lost = run_sweep(tasks, tmp_path / "s", make_backend("local", workers=2))
    rows = pq.read_table(lost.results).to_pylist()
    assert [r["error"] for r in rows] == [LOST] * 2
    monkeypatch.undo()
    assert (tmp_path / "s" / OUTPUT_MARKER).is_file()  # endocam's folder: resumed, not refused
    again = run_sweep(tasks, tmp_path / "s", make_backend("local", workers=1))
    assert (again.ran, again.failed) == (2, 0)  # a rerun retries exactly the lost ones


def test_list_valued_overrides_from_the_command_line(tmp_path: Path) -> None:
    out = tmp_path / "s"
    noise = "task.trajectory.angle_noise"
    args = ["sweep", "--policy", "fixed", "--arm", "free", "--workers", "1", "--out", str(out)]
    args += ["--set", f"{noise}=[0.1,0.2],[0.2,0.3]", "--set", "task.trajectory.duration=1.0"]
    assert main(args) == 0
    table = pq.read_table(out / "results.parquet")
    assert sorted(table.column(noise).to_pylist()) == [[0.1, 0.2], [0.2, 0.3]]
    assert table.column("duration_s").to_pylist() == [1.0, 1.0]
    for name in table.column("episode").to_pylist():
        scene = json.loads((out / "episodes" / name / "scene.json").read_text())
        assert scene["config"]["task"]["trajectory"]["angle_noise"] in ([0.1, 0.2], [0.2, 0.3])


def test_a_sweep_with_an_unsafe_episode_exits_3_and_says_so(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """As `run` and every experiment: an episode whose safety check failed makes exit 3."""

    def unsafe_sweep(tasks: object, out_dir: Path, backend: object, **kwargs: object) -> object:
        for name, violations in (("a", 0), ("b", 7)):
            run = Path(out_dir) / "episodes" / name
            run.mkdir(parents=True)
            check = {"ok": not violations, "violations": violations, "counts": {"cone": violations}}
            (run / "metrics.json").write_text(json.dumps({"check": check}))
        return sweep.SweepOutcome(2, 0, 0, Path(out_dir) / "r.parquet", Path(out_dir) / "s.html")

    monkeypatch.setattr(sweep, "run_sweep", unsafe_sweep)
    out = tmp_path / "grid"
    args = ["sweep", "--policy", "fixed", "--seeds", "0", "--out", str(out), "--workers", "1"]
    assert main(args) == EXIT_UNSAFE
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert last.startswith("safety check: 7 violations (cone 7)") and "(2 runs)" in last
