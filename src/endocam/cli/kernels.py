"""CLI subcommand ``endocam compile``: compile the kernels into numba's cache now.

The first process that calls a kernel compiles it (tens of seconds for an episode's kernels);
``endocam compile`` does it once, before a sweep's workers, a test suite or a timed run start.
"""

from __future__ import annotations

import argparse
import math
import os
import time

from endocam.cli.common import UsageError
from endocam.robot.actuator import ArmKind

MAX_DURATION_S = 60.0  # s: longer episodes reach no kernel a 2 s one misses


def _duration(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(value) and 0.0 < value <= MAX_DURATION_S):
        raise argparse.ArgumentTypeError(f"must be in (0, {MAX_DURATION_S:g}] s, got {text}")
    return value


def _arms(text: str) -> str:
    names = [a.strip() for a in text.split(",") if a.strip()]
    choices = [a.value for a in ArmKind]
    bad = [a for a in names if a not in choices]
    if not names or bad:
        raise argparse.ArgumentTypeError(
            f"unknown carrier {(bad or [text])[0]!r}; choose from: {', '.join(choices)}"
        )
    return ",".join(dict.fromkeys(names))


def _compile(args: argparse.Namespace) -> int:
    from endocam.progress import progress_bar
    from endocam.runner.precompile import DEFAULT_DURATION_S, precompile, precompile_jobs

    if os.environ.get("NUMBA_DISABLE_JIT") == "1":
        raise UsageError("NUMBA_DISABLE_JIT=1: numba compiles nothing, there is nothing to cache")
    arms = [ArmKind(a) for a in args.arm.split(",")] if args.arm else list(ArmKind)
    start = time.process_time()
    jobs = precompile_jobs(arms)
    duration_s = args.duration or DEFAULT_DURATION_S
    with progress_bar(total=len(jobs), desc="compile", unit="episode") as bar:
        n = precompile(duration_s, arms=arms, done=lambda job: bar.update(1))
    cpu = time.process_time() - start
    where = os.environ.get("NUMBA_CACHE_DIR", "numba's default (__pycache__)")
    carriers = ", ".join(a.value for a in arms)
    print(f"endocam compile: {n} episodes (every policy on {carriers}), {cpu:.1f} s CPU")
    print(f"cache: {where}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``endocam compile`` to the CLI."""
    p = sub.add_parser(
        "compile",
        help="compile the control loop's kernels into the cache (otherwise done on first use)",
        description=(
            "Runs a short episode of every policy on every carrier, so that every kernel an "
            "episode calls is compiled once into numba's cache; later processes load it."
        ),
    )
    p.add_argument(
        "--duration",
        type=_duration,
        default=None,
        metavar="S",
        help="simulated seconds per episode (default: 2; at most 60)",
    )
    p.add_argument(
        "--arm",
        type=_arms,
        default=None,
        metavar="A[,B]",
        help="only these carriers: free, psm, ecm, comma-separated (default: all three)",
    )
    p.set_defaults(handler=_compile)
