"""Headless episode throughput, in simulated seconds per wall second (issue 13, target ≥ 100×).

Run: make bench, or
  MUJOCO_GL=egl .venv/bin/pytest bench/bench_episode.py --benchmark-enable -o addopts="" \
      -p no:cacheprovider -s

Every built-in policy on every carrier it runs on (``orientation-ecm`` only on the ECM), one
60 s noisy episode (71 control points, seed 1), as ``endocam run --no-video`` computes it:
``test_episode`` includes the ground-truth touch detection (what one episode of a sweep
costs); ``test_episode_loop`` is given the touches precomputed (the control loop, logging and
metrics alone); ``test_touch_detection`` is the touch detection alone. Each prints its
real-time factor (``sim_seconds_per_wall_second`` in the JSON's ``extra_info``), from the
median of its rounds.
"""

from __future__ import annotations

import pytest
from pytest_benchmark.fixture import BenchmarkFixture

from endocam.config import ExperimentConfig
from endocam.registry import POLICIES
from endocam.robot.actuator import ArmKind
from endocam.runner.episode import EpisodeSpec, run_episode
from endocam.runner.experiments import ground_truth
from endocam.task.touches import touch_events
from endocam.task.trajectory import TrajectoryKind, make_trajectory
from endocam.task.wire import Wire

CFG = ExperimentConfig()  # 60 s episodes at 100 Hz
TRAJECTORY = (TrajectoryKind.NOISY, 71, 1)  # kind, control points, seed
BUILT_IN = ("fixed", "centering", "orientation", "orientation-ecm", "endocam")
CASES = [  # (policy, carrier): each policy on every carrier it runs on
    (policy, arm.value)
    for policy in BUILT_IN
    for arm in ArmKind
    if POLICIES[policy].arm in (None, arm)
]
ROUNDS = 5  # count: the median of these is reported


def _config(arm: str) -> ExperimentConfig:
    return CFG.model_copy(update={"episode": CFG.episode.model_copy(update={"arm": ArmKind(arm)})})


def _report(benchmark: BenchmarkFixture, duration: float, label: str) -> None:
    factor = duration / benchmark.stats.stats.median
    benchmark.extra_info["sim_seconds_per_wall_second"] = factor
    print(f"\n{label}: {factor:.0f}x real time")


@pytest.mark.parametrize(("policy", "arm"), CASES)
def test_episode(benchmark: BenchmarkFixture, policy: str, arm: str) -> None:
    """One whole episode, touch detection included."""
    spec = EpisodeSpec(policy, *TRAJECTORY)
    result = benchmark.pedantic(run_episode, args=(_config(arm), spec), rounds=ROUNDS)
    _report(benchmark, result.trajectory.duration, f"{policy} ({arm}), with touches")


@pytest.mark.parametrize(("policy", "arm"), CASES)
def test_episode_loop(benchmark: BenchmarkFixture, policy: str, arm: str) -> None:
    """The same episode with its touches precomputed: control loop, logging and metrics."""
    cfg = _config(arm)
    touches = ground_truth(cfg, *TRAJECTORY)
    spec = EpisodeSpec(policy, *TRAJECTORY)
    result = benchmark.pedantic(
        run_episode, args=(cfg, spec), kwargs={"touches": touches}, rounds=ROUNDS
    )
    _report(benchmark, result.trajectory.duration, f"{policy} ({arm}), loop only")


def test_touch_detection(benchmark: BenchmarkFixture) -> None:
    """The ground-truth touches of one trajectory alone (shared by every policy on it)."""
    wire = Wire(CFG.task.wire)
    trajectory = make_trajectory(CFG.task, *TRAJECTORY, wire=wire)
    dt = CFG.task.trajectory.touch_sample_dt
    benchmark.pedantic(touch_events, args=(trajectory, wire, CFG.task.ring, dt), rounds=ROUNDS)
    _report(benchmark, trajectory.duration, "touch detection alone")
