"""Distribution of ground-truth touches over noisy trajectories (docs/world.md, "Trajectories").

Measures, per seed, the touch count, the contact fraction (time in contact / duration) and the
minimum clearance of a noisy trajectory with ``n`` control points, using the exact detection of
:func:`endocam.task.touches.touch_events`. ``examples/touch_distribution.py`` prints the table.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from endocam.geometry import FloatArray
from endocam.task.config import TaskConfig
from endocam.task.touches import touch_events
from endocam.task.trajectory import TrajectoryKind, make_trajectory
from endocam.task.wire import Wire


@dataclass(frozen=True)
class TouchStats:
    """Touches of noisy trajectories with one number of control points, one entry per seed.

    Attributes
    ----------
    control_points : int
        Control points of every trajectory, count.
    seeds : (S,)
        Noise seeds.
    count : (S,)
        Touch events, count.
    contact_fraction : (S,)
        Time in contact over the duration, unitless.
    min_clearance : (S,)
        Smallest sampled clearance, m (negative: overlap depth).
    position_threshold : (S,)
        Drawn position threshold t_p, m.
    angle_threshold : (S,)
        Drawn angular threshold t_a, rad.
    """

    control_points: int
    seeds: NDArray[np.int64]
    count: NDArray[np.int64]
    contact_fraction: FloatArray
    min_clearance: FloatArray
    position_threshold: FloatArray
    angle_threshold: FloatArray


def touch_stats(task_cfg: TaskConfig, n: int, seeds: Iterable[int]) -> TouchStats:
    """Touch statistics of the noisy ``n``-point trajectories of ``seeds``.

    Parameters
    ----------
    task_cfg : TaskConfig
        Wire, ring and trajectory (noise ranges, duration, touch sampling step).
    n : int
        Control points (≥ 2).
    seeds : iterable of int
        Noise seeds (at least one).

    Returns
    -------
    TouchStats
    """
    seed_list = [int(s) for s in seeds]
    if not seed_list:
        raise ValueError("seeds must hold at least one seed")
    wire = Wire(task_cfg.wire)
    rows = []
    for seed in seed_list:
        traj = make_trajectory(task_cfg, TrajectoryKind.NOISY, n, seed=seed, wire=wire)
        rep = touch_events(traj, wire, task_cfg.ring, task_cfg.trajectory.touch_sample_dt)
        cps = traj.control_points
        rows.append(
            (
                rep.count,
                rep.contact_fraction,
                float(rep.clearance.min()),
                cps.position_threshold,
                cps.angle_threshold,
            )
        )
    cols = list(zip(*rows, strict=True))
    return TouchStats(
        control_points=int(n),
        seeds=np.asarray(seed_list, dtype=np.int64),
        count=np.asarray(cols[0], dtype=np.int64),
        contact_fraction=np.asarray(cols[1], dtype=float),
        min_clearance=np.asarray(cols[2], dtype=float),
        position_threshold=np.asarray(cols[3], dtype=float),
        angle_threshold=np.asarray(cols[4], dtype=float),
    )
