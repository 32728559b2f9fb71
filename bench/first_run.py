"""CPU of a fresh checkout's first ``endocam run``: imports, numba's compile and the episode.

Issue 23's target: the first ``endocam run --policy endocam --arm psm --no-video`` of a fresh
checkout (an empty compile cache) costs ≤ 12 s of CPU in total. Each round runs the command in
a new process with an empty ``NUMBA_CACHE_DIR`` (cold), then again with the cache it wrote
(warm), and prints the children's user + system CPU of each; the medians close the output::

    MUJOCO_GL=egl .venv/bin/python bench/first_run.py --rounds 3
    MUJOCO_GL=egl .venv/bin/python bench/first_run.py --rounds 3 --arm ecm --policy orientation-ecm
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path


def child_cpu(cmd: list[str], env: dict[str, str]) -> float:
    """User + system CPU (s) of one child process running ``cmd``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(cmd, env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main() -> int:
    """Run the rounds and print cold and warm CPU, s."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--arm", default="psm")
    parser.add_argument("--policy", default="endocam")
    args = parser.parse_args()
    endocam = str(Path(sys.executable).with_name("endocam"))
    cold, warm = [], []
    for _ in range(args.rounds):
        with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as out:
            env = dict(os.environ, NUMBA_CACHE_DIR=cache)
            cmd = [endocam, "run", "--policy", args.policy, "--arm", args.arm, "--no-video"]
            cmd += ["--trajectory", "noisy", "--out", out]
            cold.append(child_cpu(cmd, env))
            warm.append(child_cpu(cmd, env))
            print(f"cold {cold[-1]:.1f} s CPU, warm {warm[-1]:.1f} s CPU", flush=True)
    print(
        f"{args.policy} on {args.arm}: median cold {statistics.median(cold):.1f} s, "
        f"warm {statistics.median(warm):.1f} s CPU ({args.rounds} rounds)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
