"""The free 6-DoF camera (the paper's simulated endoscope) behind the ``Actuator`` interface."""

from __future__ import annotations

import numpy as np

from endocam.camera import StereoCamera
from endocam.geometry import FloatArray, as_pose
from endocam.robot.actuator import ActuatorStatus, ActuatorStep, ArmKind, WorkspaceBound
from endocam.robot.cartesian import CartesianLimiter, MotionLimits
from endocam.task.config import TaskConfig
from endocam.task.layout import overview_camera_pose, task_centre

__all__ = ["FreeCamera"]

_NO_JOINTS = np.zeros(0)
_NO_JOINTS.setflags(write=False)
_EXACT = ActuatorStatus.EXACT  # (an enum member read once)


class FreeCamera:
    """The free 6-DoF camera (the paper's simulated endoscope) behind the ``Actuator`` interface.

    It has no joints and reaches every command, within the Cartesian limits of its
    :class:`CartesianLimiter`; it starts at the whole-task overview pose.

    Parameters
    ----------
    limits : MotionLimits
        Speed, acceleration and jerk norms.
    dt : float
        Control period, s.
    workspace : WorkspaceBound, optional
        Where the camera may be: once it can stop inside, it never leaves
        (:class:`CartesianLimiter`).
    """

    kind = ArmKind.FREE
    follows_twist = True  # the limiter tracks the command's velocity

    def __init__(
        self, limits: MotionLimits, dt: float, workspace: WorkspaceBound | None = None
    ) -> None:
        self.limiter = CartesianLimiter(limits, dt, workspace)

    @property
    def joint_names(self) -> tuple[str, ...]:
        """No joints."""
        return ()

    @property
    def q(self) -> FloatArray:
        """No joints: ``(0,)``."""
        return _NO_JOINTS

    def start_view(self, task_cfg: TaskConfig, camera: StereoCamera) -> tuple[FloatArray, float]:
        """The free camera starts at the overview pose itself, looking at the task centre."""
        T_overview = overview_camera_pose(task_cfg, camera)
        look = float(np.linalg.norm(task_centre(task_cfg) - T_overview[:3, 3]))
        return T_overview, look

    def reset(self, T_world_cam: object, look_distance: float | None = None) -> FloatArray:
        """Start at rest at ``T_world_cam`` (4, 4); returns it."""
        T = as_pose(T_world_cam, "T_world_cam")
        self.limiter.reset(T)
        return T

    def stall(self, joint: int | None) -> None:
        """No joint to stall: only ``None`` is accepted."""
        if joint is not None:
            raise ValueError(f"joint: the free camera has no joint {joint}")

    def step(
        self, T_world_cmd: FloatArray, look_distance: float, twist: FloatArray | None = None
    ) -> ActuatorStep:
        """One limiter step towards the command (a non-finite one keeps the last valid target).

        ``twist`` (6,): the command's velocity, linear then angular, world, m/s and rad/s.
        """
        T = self.limiter.step(T_world_cmd, twist)
        return ActuatorStep(T, _NO_JOINTS, T_world_cmd, _EXACT, 0.0, 0.0, True)
