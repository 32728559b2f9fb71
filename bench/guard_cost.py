"""CPU cost of the carriers' workspace guard: one episode with and without it, interleaved.

Run: .venv/bin/python bench/guard_cost.py free|psm|ecm
Prints the minimum CPU time of three noisy 71-point 60 s ``endocam`` episodes each way, with the
carrier built with its workspace (as the runner builds it) and without, and their ratio.
"""

from __future__ import annotations

import sys
import time
from typing import Any

import endocam.runner.episode as episode
from endocam.config import ExperimentConfig
from endocam.robot.actuator import ArmKind
from endocam.runner.episode import EpisodeSpec, run_episode
from endocam.task.trajectory import TrajectoryKind

RUNS = 3  # count: episodes each way


def main(arm: str) -> None:
    """Time the episodes and print the comparison."""
    guarded = episode.make_actuator

    def unguarded(*args: Any) -> Any:
        return guarded(*args[:5])  # the same carrier without its workspace

    cfg = ExperimentConfig()
    cfg = cfg.model_copy(update={"episode": cfg.episode.model_copy(update={"arm": ArmKind(arm)})})
    spec = EpisodeSpec("endocam", TrajectoryKind.NOISY, 71, 1)
    cpu: dict[str, list[float]] = {"guard": [], "none": []}
    for _ in range(RUNS):
        for name, make in (("guard", guarded), ("none", unguarded)):
            episode.make_actuator = make  # type: ignore[assignment]
            t0 = time.process_time()
            run_episode(cfg, spec)
            cpu[name].append(time.process_time() - t0)
    episode.make_actuator = guarded
    g, n = min(cpu["guard"]), min(cpu["none"])
    print(f"{arm}: with the guard {g:.2f} s CPU, without {n:.2f} s, ratio {g / n:.3f}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "free")
