"""Where the controller's CPU goes in a link cycle: ``bench/link_latency.py`` run, profiled.

Two views of the same paced run (``link_latency``'s options, one rate):

- ``--mode split`` (default): the controller thread's CPU (``time.thread_time``) in each part
  of the cycle — the policy's step, ``ZenohArm.step`` in all, its ``receive`` (waiting and
  decoding the state) and ``_state`` (decoding), encoding ``servo_cp`` — p50 / mean / p99 per
  cycle, µs. No profiler: the parts' own cost, plus the few µs of the timing wrappers.
- ``--mode profile``: cProfile with the thread's CPU clock as its timer, from the link's
  ``connect`` to its ``close`` (not the warm-up), the top functions by own time. The profiler
  inflates many small Python calls: read shares, not times.

Zenoh's callbacks run on Zenoh's threads, which neither view counts (as ``link_latency``'s
own CPU does not).

Run (docs/performance.md, round 17)::

    MUJOCO_GL=egl OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 PYTHONPATH=src \\
        .venv/bin/python bench/link_profile.py --mode split --duration 30 --rates 200 \\
        --arm psm --policy endocam --watchdog 2 --timeout 3
"""

from __future__ import annotations

import cProfile
import functools
import pstats
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np

import link_latency  # bench/
from endocam.control.policies.endocam import EndocamPolicy
from endocam.link import client, messages

WARM_CYCLES = 1000  # the first cycles (and the warm-up episode's steps) are not counted


def _timed(cls: type, name: str, label: str, parts: dict[str, list[float]]) -> None:
    """Wrap ``cls.name`` so that each call's thread CPU time (s) is appended to ``parts``."""
    f: Callable[..., Any] = getattr(cls, name)

    @functools.wraps(f)
    def wrapped(*args: Any, **kwargs: Any) -> Any:
        c0 = time.thread_time()
        try:
            return f(*args, **kwargs)
        finally:
            parts.setdefault(label, []).append(time.thread_time() - c0)

    setattr(cls, name, wrapped)


def split(argv: list[str]) -> None:
    """``--mode split``: each part's CPU per cycle."""
    parts: dict[str, list[float]] = {}
    _timed(EndocamPolicy, "step", "policy step", parts)
    _timed(client.ZenohArm, "step", "ZenohArm.step (all)", parts)
    _timed(client.ZenohArm, "receive", "  receive (wait + decode)", parts)
    _timed(client.ZenohArm, "_state", "    _state (decode)", parts)
    _timed(messages.Codec, "pose", "  Codec.pose (servo_cp)", parts)
    sys.argv = ["link_latency.py", *argv]
    link_latency.main()
    print("part | cycles | p50 us | mean us | p99 us")
    for label, v in parts.items():
        us = np.array(v[WARM_CYCLES:]) * 1e6
        print(
            f"{label} | {us.size} | {np.median(us):.1f} | {us.mean():.1f} | "
            f"{np.percentile(us, 99):.1f}"
        )


def profile(argv: list[str], top: int = 30) -> None:
    """``--mode profile``: cProfile on the thread's CPU clock, from connect to close."""
    prof = cProfile.Profile(time.thread_time)
    connect, close = client.ZenohArm.connect, client.ZenohArm.close

    def profiled_connect(self: client.ZenohArm, wait: float) -> client.RobotState:
        state = connect(self, wait)
        prof.enable()
        return state

    def profiled_close(self: client.ZenohArm) -> None:
        prof.disable()
        close(self)

    client.ZenohArm.connect = profiled_connect  # type: ignore[method-assign]
    client.ZenohArm.close = profiled_close  # type: ignore[method-assign]
    sys.argv = ["link_latency.py", *argv]
    link_latency.main()
    stats = pstats.Stats(prof)
    stats.sort_stats("tottime").print_stats(top)
    stats.sort_stats("cumulative").print_stats(top)


def main() -> None:
    """``--mode split|profile``, then ``link_latency``'s own options."""
    argv = sys.argv[1:]
    mode = "split"
    if argv[:1] == ["--mode"]:
        mode, argv = argv[1], argv[2:]
    if mode not in ("split", "profile"):
        raise SystemExit(f"link_profile.py: --mode is split or profile, not {mode!r}")
    (split if mode == "split" else profile)(argv)


if __name__ == "__main__":
    main()
