"""Sweep throughput: episodes per minute on each backend, and the overhead per task (issue 13).

Run (``-s`` prints the summary with the ratios, all measured in the same run):
  MUJOCO_GL=egl .venv/bin/pytest bench/bench_sweep.py --benchmark-enable -o addopts="" \
      -p no:cacheprovider -s

Every case runs the same ``N_EPISODES`` 60 s episodes (``endocam`` on the free camera, noisy
71-point trajectories, touch detection included), each writing what ``endocam run --no-video``
writes. The **bare loop** does just that in this process, with no sweep machinery; the
backends run the same tasks: **local** inline (one worker) and on a process pool of two,
**Ray** on a local Ray with one CPU (one task at a time) and with two. Each round writes into a
fresh folder. The **overhead per task** of a one-at-a-time backend is measured within each
round, so the shared machine's speed cancels out: the round's wall time minus the episodes' own
wall times (``task.json``: run and write, timed inside the worker), per task. The gather
(``results.parquet``, ``summary.html``) is a fixed cost per sweep, measured on its own.
Medians over the rounds; Ray's workers are warmed up by one round first.
"""

from __future__ import annotations

import itertools
import json
import statistics
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from endocam.config import ExperimentConfig
from endocam.runner.episode import run_episode
from endocam.runner.outputs import write_run
from endocam.runner.sweep import (
    EPISODES,
    TASK_JSON,
    Backend,
    expand,
    make_backend,
    run_sweep,
)

N_EPISODES = 4  # episodes per round
ROUNDS = 5
TASKS = expand(
    ExperimentConfig(),  # 60 s episodes at 100 Hz
    {"policy": ["endocam"], "arm": ["free"], "seed": list(range(1, N_EPISODES + 1))},
)
MEDIANS: dict[str, float] = {}  # case -> median wall time of a round, s
OVERHEAD: dict[str, tuple[float, float]] = {}  # case -> median (overhead, episode time), s
_fresh = itertools.count()


def bare_loop(out: Path) -> None:
    """What a sweep runs, without it: each episode run and written in turn."""
    for task in TASKS:
        config, spec = task.episode()
        write_run(run_episode(config, spec), out / task.name, video=False)


@pytest.fixture(scope="module", autouse=True)
def report() -> Iterator[None]:
    yield
    if "bare loop" not in MEDIANS:
        return
    bare = MEDIANS["bare loop"] / N_EPISODES
    print(f"\n{N_EPISODES} episodes of 60 s per round; medians of {ROUNDS} rounds")
    print("| case | episodes per minute | wall time per episode (s) | vs bare loop |")
    print("|---|---|---|---|")
    for case, median in MEDIANS.items():
        per = median / N_EPISODES
        print(f"| {case} | {60.0 / per:.1f} | {per:.2f} | {per / bare:.2f} |")
    for case, (extra, episode) in OVERHEAD.items():
        print(
            f"{case}: overhead {1e3 * extra:.0f} ms per task = {100 * extra / episode:.1f} % "
            f"of the episode's {episode:.2f} s"
        )


def _rounds(benchmark: Any, case: str, target: Any, warmup: int = 0) -> list[Path]:
    """Run ``target(folder)`` in fresh folders; returns the folders of the measured rounds."""
    folders: list[Path] = []
    with tempfile.TemporaryDirectory() as tmp:

        def setup() -> tuple[tuple[Path], dict[str, Any]]:
            folder = Path(tmp) / f"round-{next(_fresh)}"
            folders.append(folder)
            return (folder,), {}

        benchmark.pedantic(target, setup=setup, rounds=ROUNDS, iterations=1, warmup_rounds=warmup)
        times = list(benchmark.stats.stats.data)
        MEDIANS[case] = statistics.median(times)
        benchmark.extra_info["episodes_per_minute"] = 60.0 * N_EPISODES / MEDIANS[case]
        measured = folders[warmup:]
        if case.endswith(("1 worker", "1 CPU")):  # one task at a time: overhead per task
            per_round = []
            for folder, t in zip(measured, times, strict=True):
                walls = [
                    json.loads((folder / EPISODES / k.name / TASK_JSON).read_text())["wall_time_s"]
                    for k in TASKS
                ]
                per_round.append(((t - sum(walls)) / N_EPISODES, sum(walls) / N_EPISODES))
            OVERHEAD[case] = (
                statistics.median(o for o, _ in per_round),
                statistics.median(e for _, e in per_round),
            )
            benchmark.extra_info["overhead_per_task_s"] = OVERHEAD[case][0]
    return measured


def _backend_round(backend: Backend) -> Any:
    def run(folder: Path) -> None:
        (folder / EPISODES).mkdir(parents=True)
        backend(TASKS, folder / EPISODES, lambda k: None)

    return run


def test_bare_loop(benchmark: Any) -> None:
    _rounds(benchmark, "bare loop", bare_loop)


@pytest.mark.parametrize("workers", [1, 2])
def test_local_backend(benchmark: Any, workers: int) -> None:
    case = f"local, {workers} worker{'s' if workers > 1 else ''}"
    _rounds(benchmark, case, _backend_round(make_backend("local", workers=workers)))


@pytest.mark.parametrize("cpus", [1, 2])
def test_ray_backend(benchmark: Any, cpus: int) -> None:
    import ray

    ray.init(num_cpus=cpus, include_dashboard=False, log_to_driver=False)
    try:
        case = f"ray, {cpus} CPU{'s' if cpus > 1 else ''}"
        _rounds(benchmark, case, _backend_round(make_backend("ray")), warmup=1)
    finally:
        ray.shutdown()


def test_gather_and_summary(benchmark: Any) -> None:
    """The fixed cost of a sweep over finished episodes: resume check, table, summary."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "sweep"
        backend = make_backend("local", workers=1)
        run_sweep(TASKS, out, backend)
        benchmark.pedantic(run_sweep, args=(TASKS, out, backend), rounds=ROUNDS, iterations=1)
