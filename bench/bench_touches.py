"""CPU time of the ground-truth touch detection (``task.touches.touch_events``) of one episode.

Each process builds the episode's trajectory (``bench/paired_episode.py``'s: noisy, 71 control
points, seed 1, the default task; or ``--kind``, ``--points``, ``--seed``), runs
``touch_events`` once to load the compiled kernels, then ``--runs`` times more, and prints
the median CPU time (``time.process_time``), s. With ``--base`` (the ``src/`` of another
checkout) base and this checkout alternate process by process, as in
``bench/paired_episode.py``, so both see the same load::

    .venv/bin/python bench/bench_touches.py                                  # this checkout
    .venv/bin/python bench/bench_touches.py --base /tmp/main/src --pairs 3   # paired
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time

RUNS = 7  # timed touch detections per process: their median is its figure


def one(kind: str, points: int, seed: int, runs: int) -> float:
    """The median CPU time (s) of ``runs`` touch detections of one trajectory in this process."""
    from endocam.config import ExperimentConfig
    from endocam.task.touches import touch_events
    from endocam.task.trajectory import TrajectoryKind, make_trajectory
    from endocam.task.wire import Wire

    task = ExperimentConfig().task
    wire = Wire(task.wire)
    trajectory = make_trajectory(task, TrajectoryKind(kind), points, seed, wire=wire)
    dt = task.trajectory.touch_sample_dt
    touch_events(trajectory, wire, task.ring, dt)  # loads (or compiles) the kernels
    times = []
    for _ in range(runs):
        t0 = time.process_time()
        touch_events(trajectory, wire, task.ring, dt)
        times.append(time.process_time() - t0)
    return statistics.median(times)


def _timed(args: argparse.Namespace, src: str | None) -> float:
    env = dict(os.environ)
    if src is not None:
        env["PYTHONPATH"] = src
    cmd = [sys.executable, __file__, "--one", "--kind", args.kind, "--points", str(args.points)]
    cmd += ["--seed", str(args.seed), "--runs", str(args.runs)]
    return float(subprocess.run(cmd, env=env, capture_output=True, check=True, text=True).stdout)


def main() -> None:
    """Parse the arguments; print the median CPU time, s (paired: base, new and their ratio)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kind", default="noisy", help="trajectory kind: noisy or ideal")
    parser.add_argument("--points", type=int, default=71, help="control points")
    parser.add_argument("--seed", type=int, default=1, help="noise seed")
    parser.add_argument("--runs", type=int, default=RUNS, help="timed runs per process")
    parser.add_argument("--base", help="src/ of the checkout to compare with")
    parser.add_argument("--pairs", type=int, default=3, help="base/new alternations")
    parser.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(f"{one(args.kind, args.points, args.seed, args.runs)!r}")
        return
    case = f"touch_events {args.kind} {args.points} seed {args.seed}"
    if not args.base:
        print(f"{case}: median {one(args.kind, args.points, args.seed, args.runs):.4f} s")
        return
    base, new = [], []
    for _ in range(args.pairs):
        base.append(_timed(args, args.base))
        new.append(_timed(args, None))
    ratio = statistics.median(new) / statistics.median(base)
    print(
        f"{case}: base {' '.join(f'{t:.4f}' for t in base)} s, "
        f"new {' '.join(f'{t:.4f}' for t in new)} s, new/base (medians) {ratio:.2f}",
        flush=True,
    )


if __name__ == "__main__":
    main()
