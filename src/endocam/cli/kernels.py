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

MAX_DURATION_S = 60.0  # s: longer episodes reach no kernel a 2 s one misses


def _duration(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(value) and 0.0 < value <= MAX_DURATION_S):
        raise argparse.ArgumentTypeError(f"must be in (0, {MAX_DURATION_S:g}] s, got {text}")
    return value


def _compile(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from endocam.runner.precompile import DEFAULT_DURATION_S, precompile, precompile_jobs

    if os.environ.get("NUMBA_DISABLE_JIT") == "1":
        raise UsageError("NUMBA_DISABLE_JIT=1: numba compiles nothing, there is nothing to cache")
    start = time.process_time()
    jobs = precompile_jobs()
    with tqdm(total=len(jobs), desc="compile", unit="episode", leave=False) as bar:
        n = precompile(args.duration or DEFAULT_DURATION_S, done=lambda job: bar.update(1))
    cpu = time.process_time() - start
    where = os.environ.get("NUMBA_CACHE_DIR", "numba's default (__pycache__)")
    print(f"endocam compile: {n} episodes (every policy on every carrier), {cpu:.1f} s CPU")
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
    p.set_defaults(handler=_compile)
