"""Compile the control loop's kernels into numba's cache before they are needed.

numba compiles each kernel on its first call and caches it on disk (``cache=True``; the folder
is per version of the kernels' source, see ``endocam._numba_cache``). Every process that finds
the cache empty compiles for itself: the first ``endocam run``, each worker of ``endocam sweep``
or of a process pool, each test worker. ``endocam compile`` pays that once: it runs a short
episode of every registered policy on every carrier it can drive (free camera, PSM, ECM), which
calls every kernel an episode calls with the argument types an episode gives it; later processes
load the compiled code instead (a few ms per kernel).

What it does not reach: a kernel called with other argument types (a test calling a kernel
directly with a read-only array, say) compiles that specialization on its first call, as
before. The episodes' results are discarded.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from endocam.config import ExperimentConfig, config_from_mapping
from endocam.registry import POLICIES
from endocam.robot.actuator import ArmKind

__all__ = [
    "DEFAULT_DURATION_S",
    "PrecompileJob",
    "kernels_cached",
    "precompile",
    "precompile_jobs",
]

DEFAULT_DURATION_S = 2.0
"""s: long enough for every carrier to leave its start pose, plan, transfer and brake."""


@dataclass(frozen=True)
class PrecompileJob:
    """One short episode run for its compiled kernels.

    Attributes
    ----------
    arm : ArmKind
        The carrier.
    policy : str
        A registered policy name that can run on ``arm``.
    """

    arm: ArmKind
    policy: str


def kernels_cached(environ: dict[str, str] | None = None) -> bool:
    """Whether numba's cache folder holds compiled kernels (any index file, ``*.nbi``).

    ``False`` means the next episode compiles its kernels (tens of seconds of CPU) before its
    first step. Without ``NUMBA_CACHE_DIR`` (numba imported before endocam chose its folder)
    the cache sits beside the sources and is not looked at: ``True``.

    Parameters
    ----------
    environ : dict, optional
        The environment to read ``NUMBA_CACHE_DIR`` from (default: this process's).
    """
    folder = (os.environ if environ is None else environ).get("NUMBA_CACHE_DIR")
    if not folder:
        return True
    return next(Path(folder).rglob("*.nbi"), None) is not None


def precompile_jobs(arms: Sequence[ArmKind] = tuple(ArmKind)) -> list[PrecompileJob]:
    """Every registered policy on each of ``arms`` it runs on (one that forces an arm: that)."""
    return [
        PrecompileJob(arm, name)
        for arm in ArmKind
        if arm in arms
        for name, entry in POLICIES.items()
        if entry.arm is None or entry.arm == arm
    ]


def precompile(
    duration_s: float = DEFAULT_DURATION_S,
    *,
    arms: Sequence[ArmKind] = tuple(ArmKind),
    done: Callable[[PrecompileJob], object] | None = None,
) -> int:
    """Run every job of :func:`precompile_jobs` ``(arms)`` for ``duration_s`` of simulated time.

    Parameters
    ----------
    duration_s : float
        Simulated seconds per episode (> 0).
    arms : sequence of ArmKind
        The carriers to compile for (default: all three).
    done : callable, optional
        Called with each job once its episode has run (a progress bar).

    Returns
    -------
    int
        The number of episodes run.
    """
    from endocam.runner.episode import EpisodeSpec, run_episode
    from endocam.task.trajectory import TrajectoryKind

    if not duration_s > 0.0:
        raise ValueError(f"duration must be > 0 s, got {duration_s}")
    jobs = precompile_jobs(arms)
    for job in jobs:
        config: ExperimentConfig = config_from_mapping(
            {"task": {"trajectory": {"duration": duration_s}}, "episode": {"arm": job.arm.value}},
            source="precompile",
        )
        run_episode(config, EpisodeSpec(job.policy, TrajectoryKind.NOISY, 36, seed=1))
        if done is not None:
            done(job)
    return len(jobs)
