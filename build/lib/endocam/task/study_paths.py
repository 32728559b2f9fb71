"""The study's three noisy ring paths (paper Sec. IV-D): also the noisy half of the paper's table.

The paper's noisy tracking test "used the same trajectories as the user study" (Sec. V, Paths
1–3). They are defined here, in the task, so the study, ``experiment paper`` and
``experiment tracking`` share them. The noise seed of path ``k`` is the ``k``-th draw of
``numpy.random.default_rng(seed).integers(0, 2**31)``.

The study's paths are **legible** (``STUDY_LEGIBLE_BAND``): every approach of the ring to the wire
is a touch at least 0.25 mm deep or a pass at least 1 mm clear
(:func:`endocam.task.trajectory.legible_control_points`). A participant counts touches; a
0.05 mm graze or a 0.05 mm near miss is under a pixel in any of the study's views, so with the
noise as drawn no video could say which it was (docs/world.md, "Legible trajectories").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from endocam.task.config import TaskConfig

__all__ = [
    "DEFAULT_STUDY_SEED",
    "STUDY_LEGIBLE_BAND",
    "STUDY_TRAJECTORIES",
    "StudyTrajectory",
    "study_task_config",
    "study_trajectory_seeds",
]

DEFAULT_STUDY_SEED = 2024  # the study's default seed (``endocam study make --seed``)
# (d, g), m: a touch at least d deep or a pass at least g clear. g = 1 mm is 3 px in the fixed
# view (~3 px/mm), the observer's "clearly open" gap; d = 0.25 mm keeps a touch ≥ ~0.25 s long.
STUDY_LEGIBLE_BAND = (0.25e-3, 1.0e-3)


@dataclass(frozen=True)
class StudyTrajectory:
    """One study trajectory: a noisy ring path of a given difficulty.

    Attributes
    ----------
    name : str
        Name in the manifest.
    difficulty : int
        1..3, 3 = most difficult.
    control_points : int
        Control points along the wire.
    angle_noise : (2,) or None
        Range [lo, hi] of the angular threshold, rad; None keeps the config's.
    """

    name: str
    difficulty: int
    control_points: int
    angle_noise: tuple[float, float] | None = None


STUDY_TRAJECTORIES = (
    StudyTrajectory("t1-36-low", 1, 36, (math.radians(5.0), math.radians(10.0))),
    StudyTrajectory("t2-36-high", 2, 36),
    StudyTrajectory("t3-71-high", 3, 71),
)


def study_task_config(task: TaskConfig, trajectory: StudyTrajectory) -> TaskConfig:
    """``task`` with the study path's noise: its angular range (if any) and legibility."""
    data = task.model_dump()
    if trajectory.angle_noise is not None:
        data["trajectory"]["angle_noise"] = trajectory.angle_noise
    data["trajectory"]["legible_band"] = STUDY_LEGIBLE_BAND
    return TaskConfig.model_validate(data)


def study_trajectory_seeds(seed: int, n: int = len(STUDY_TRAJECTORIES)) -> tuple[int, ...]:
    """Noise seeds of the ``n`` trajectories, drawn from ``default_rng(seed)`` (each ≥ 0)."""
    if seed < 0:
        raise ValueError(f"seed must be ≥ 0, got {seed}")
    rng = np.random.default_rng(seed)
    return tuple(int(s) for s in rng.integers(0, 2**31, size=n))
