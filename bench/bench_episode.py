"""Headless episode throughput, in simulated seconds per wall second (issue 3, target ≥ 100×).

Run: make bench, or
  MUJOCO_GL=egl .venv/bin/pytest bench/bench_episode.py --benchmark-enable -o addopts="" \
      -p no:cacheprovider
The control loop (policy, limiter, logging, metrics) is measured with the ground-truth touches
precomputed, since they belong to the trajectory, not the episode; a second case includes them.
"""

from __future__ import annotations

import pytest

from endocam.config import ExperimentConfig
from endocam.robot.actuator import ArmKind
from endocam.runner.episode import EpisodeSpec, run_episode
from endocam.runner.experiments import ground_truth
from endocam.task.trajectory import TrajectoryKind

CFG = ExperimentConfig()  # 60 s episodes at 100 Hz, the camera on the PSM (the default)
ARMS = ("free", "psm")  # the free camera (Cartesian limiter) and the default PSM (IK + ruckig)


@pytest.mark.parametrize("arm", ARMS)
@pytest.mark.parametrize("policy", ["fixed", "centering", "orientation", "endocam"])
def test_episode_loop(benchmark, policy: str, arm: str) -> None:
    cfg = CFG.model_copy(update={"episode": CFG.episode.model_copy(update={"arm": ArmKind(arm)})})
    touches = ground_truth(cfg, TrajectoryKind.NOISY, 71, 1)
    spec = EpisodeSpec(policy, TrajectoryKind.NOISY, 71, 1)
    result = benchmark.pedantic(
        run_episode, args=(cfg, spec), kwargs={"touches": touches}, rounds=5, iterations=1
    )
    median = benchmark.stats.stats.median
    benchmark.extra_info["sim_seconds_per_wall_second"] = result.trajectory.duration / median
    print(f"\n{policy} ({arm}): {result.trajectory.duration / median:.0f}x real time")


def test_episode_with_touch_detection(benchmark) -> None:
    spec = EpisodeSpec("orientation", TrajectoryKind.NOISY, 71, 1)
    result = benchmark.pedantic(run_episode, args=(CFG, spec), rounds=3, iterations=1)
    median = benchmark.stats.stats.median
    benchmark.extra_info["sim_seconds_per_wall_second"] = result.trajectory.duration / median
    print(f"\nwith touches: {result.trajectory.duration / median:.0f}x real time")
