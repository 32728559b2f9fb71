"""Paired before/after CPU time of whole episodes: base and this checkout in turn, per process.

On a shared machine the load moves between two benchmark runs by more than a change does; in
turn, one process each, both see the same load. Each process times ``ROUNDS`` whole 60 s
episodes (``run_episode``, touch detection included, as ``endocam run --no-video``; noisy
trajectory, 71 control points, seed 1) and prints the least CPU time.

Run (``BASE``: the ``src/`` of another checkout, e.g. ``git archive main | tar -x -C /tmp/main``)::

    MUJOCO_GL=egl .venv/bin/python bench/paired_episode.py --base /tmp/main/src \\
        --pairs 4 endocam:psm endocam:ecm orientation-ecm:ecm
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time

ROUNDS = 3  # episodes per process: the least CPU time of these is its figure


def one(policy: str, arm: str, rounds: int = ROUNDS) -> float:
    """The least CPU time (s) of ``rounds`` whole episodes in this process."""
    from endocam.config import ExperimentConfig
    from endocam.robot.actuator import ArmKind
    from endocam.runner.episode import EpisodeSpec, run_episode
    from endocam.task.trajectory import TrajectoryKind

    base = ExperimentConfig()
    episode = base.episode.model_copy(update={"arm": ArmKind(arm)})
    config = base.model_copy(update={"episode": episode})
    spec = EpisodeSpec(policy, TrajectoryKind.NOISY, 71, 1)
    best = float("inf")
    for _ in range(rounds):
        t0 = time.process_time()
        run_episode(config, spec)
        best = min(best, time.process_time() - t0)
    return best


def _timed(case: str, src: str | None) -> float:
    env = dict(os.environ)
    if src is not None:
        env["PYTHONPATH"] = src
    args = [sys.executable, __file__, "--one", case]
    return float(subprocess.run(args, env=env, capture_output=True, check=True, text=True).stdout)


def main() -> None:
    """Parse the arguments; print base and new times and their ratio per case."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cases", nargs="*", help="POLICY:ARM, e.g. endocam:psm")
    parser.add_argument("--base", help="src/ of the checkout to compare with")
    parser.add_argument("--pairs", type=int, default=2, help="base/new alternations per case")
    parser.add_argument("--one", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(f"{one(*args.one.split(':'))!r}")
        return
    if not args.base or not args.cases:
        parser.error("give --base and at least one POLICY:ARM")
    for case in args.cases:
        base, new = [], []
        for _ in range(args.pairs):
            base.append(_timed(case, args.base))
            new.append(_timed(case, None))
        ratio = statistics.median(new) / statistics.median(base)
        print(
            f"{case}: base {' '.join(f'{t:.3f}' for t in base)} s, "
            f"new {' '.join(f'{t:.3f}' for t in new)} s, new/base (medians) {ratio:.2f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
