"""Where things are in the wire-chaser task: its centre, the whole-task view, the instrument tips.

Pure geometry of the task config (no simulator): the episode runner, the scene builder and the
study all take the task's layout from here.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numpy.typing import ArrayLike

from endocam.camera import StereoCamera
from endocam.geometry import UP, FloatArray, as_vector3, make_pose, unit_vector
from endocam.task.config import InstrumentConfig, RingConfig, TaskConfig, Vec3, WireConfig
from endocam.task.wire import Wire

__all__ = ["overview_camera_pose", "psm1_tip_in_ring", "psm2_pose", "task_centre"]


def psm1_tip_in_ring(ring: RingConfig, instruments: InstrumentConfig) -> FloatArray:
    """(3,) PSM1 tool tip (jaw tips, gripping the handle's end) in the ring frame, m."""
    return np.array([ring.major_radius + ring.handle_length - instruments.jaw_length, 0.0, 0.0])


def psm2_pose(instruments: InstrumentConfig, p_world_tip: ArrayLike | None = None) -> FloatArray:
    """(4, 4) ``T_world_psm2``: origin at the PSM2 tip, +x up its shaft, y horizontal.

    ``p_world_tip`` (3,) is the tip in world, m (default ``instruments.psm2_tip``); the shaft
    keeps ``instruments.psm2_direction`` wherever the tip is (``EpisodeLog.p_world_tips[:, 1]``).
    """
    x = unit_vector(instruments.psm2_direction, "psm2_direction")
    y = np.cross(UP, x)
    y = np.array([0.0, 1.0, 0.0]) if np.linalg.norm(y) < 1e-9 else y / np.linalg.norm(y)
    z = np.cross(x, y)
    tip = instruments.psm2_tip if p_world_tip is None else as_vector3(p_world_tip, "p_world_tip")
    return make_pose(np.column_stack([x, y, z]), tip)


def _task_points(task_cfg: TaskConfig) -> FloatArray:
    """(N, 3) points the whole-task view must show: wire, post bases, PSM2's tip, m."""
    return _layout_points(task_cfg.wire, task_cfg.instruments.psm2_tip)


@functools.lru_cache(maxsize=16)
def _layout_points(wire_cfg: WireConfig, psm2_tip: Vec3) -> FloatArray:
    """:func:`_task_points` of a wire and a tip (read-only, cached).

    Building the wire's splines costs milliseconds, and every episode asks for its layout
    several times (the centre, the overview) with the same wire.
    """
    wire = Wire(wire_cfg)
    pts = np.vstack([wire.polyline(), wire.post_bases, np.asarray(psm2_tip, dtype=float)])
    pts.setflags(write=False)
    return pts


def task_centre(task_cfg: TaskConfig) -> FloatArray:
    """(3,) centre of the bounding box of the wire, its posts and PSM2's tip, world, m."""
    pts = _task_points(task_cfg)
    return np.asarray(0.5 * (pts.min(axis=0) + pts.max(axis=0)), dtype=float)


def overview_camera_pose(
    task_cfg: TaskConfig,
    camera: StereoCamera,
    elevation: float = math.radians(50.0),
    margin: float = 0.1,
) -> FloatArray:
    """Fixed whole-task camera pose: horizon level, looking down at the wire from the front.

    The optical axis points along +y (towards the back of the board) and down by
    ``elevation``; the camera's x axis is world x (level horizon). It is placed on the line
    through the centre of the wire's bounding box, at the smallest distance that keeps the wire,
    its posts and PSM2's tip inside the image with ``margin`` (fraction of each half-size) spare.

    Parameters
    ----------
    task_cfg : TaskConfig
    camera : StereoCamera
    elevation : float
        Downward tilt of the optical axis below horizontal, rad, in (0, π/2].
    margin : float
        Spare fraction of the image half-size, in [0, 1).

    Returns
    -------
    (4, 4)
        ``T_world_cam`` (optical frame), m.
    """
    if not 0.0 < elevation <= 0.5 * math.pi:
        raise ValueError(f"elevation must be in (0, π/2] rad, got {elevation}")
    if not 0.0 <= margin < 1.0:
        raise ValueError(f"margin must be in [0, 1), got {margin}")
    pts = _task_points(task_cfg)
    centre = task_centre(task_cfg)
    z = np.array([0.0, math.cos(elevation), -math.sin(elevation)])
    x = np.array([1.0, 0.0, 0.0])
    y = np.cross(z, x)
    k = camera.intrinsics
    tan_x = (1.0 - margin) * 0.5 * k.width / k.fx
    tan_y = (1.0 - margin) * 0.5 * k.height / k.fy
    d = pts - centre
    dist = np.max(np.maximum(np.abs(d @ x) / tan_x, np.abs(d @ y) / tan_y) - d @ z)
    return make_pose(np.column_stack([x, y, z]), centre - dist * z)
