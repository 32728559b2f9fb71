"""The view a camera on a dVRK arm starts an episode from: the whole task, seen from the port.

:func:`arm_start_view` is :meth:`~endocam.robot.camera_arm.CameraArm.start_view`; it asks the
arm only what :class:`StartViewArm` names.
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np

from endocam.camera import StereoCamera
from endocam.geometry import UP, FloatArray
from endocam.robot.actuator import ActuatorStatus, ArmKind, WorkspaceBound
from endocam.task.config import TaskConfig
from endocam.task.layout import FramingError, port_view
from endocam.view import rotation_looking_along, vec

__all__ = ["ARM_START_GAP", "START_ROLL_TOL_RAD", "StartViewArm", "arm_start_view"]


class StartViewArm(Protocol):
    """What the start view asks of a camera arm (``robot.camera_arm.CameraArm``)."""

    kind: ArmKind
    workspace: WorkspaceBound | None

    @property
    def shortest_reach(self) -> float:
        """Distance from the RCM to the camera at the shortest insertion, m."""
        ...

    @property
    def p_world_rcm(self) -> FloatArray:
        """(3,) the RCM in world, m."""
        ...

    def target(
        self, T_world_goal: FloatArray, look_distance: float
    ) -> tuple[list[float], FloatArray, ActuatorStatus]:
        """Joint target, the camera pose put in the goal's place, and the status."""
        ...


# m: the start view keeps the camera at least this far beyond the port (the RCM, in the body
# wall). A scope's view starts where its tip leaves the cannula, whose tip reaches a few cm
# beyond the remote centre (assumed: 3 cm); the arm's own shortest reach may be longer (the
# PSM-held camera with its wrist straight: 0.061 m), and then that is the bound.
ARM_START_GAP = 0.03
START_ROLL_TOL_RAD = 1e-3  # rad: the start view's roll is iterated until the arm's agrees this well
_START_ROLL_ITERATIONS = 6  # count: the default ECM levels its view in 1 framing (roll 0.094 rad)


def arm_start_view(
    arm: StartViewArm, task_cfg: TaskConfig, camera: StereoCamera
) -> tuple[FloatArray, float]:
    """The whole-task view a camera on an arm starts from, and the distance it looks at.

    The free camera starts at the overview pose. A camera on an arm starts where a surgeon
    would aim a scope just inserted: looking along a line through the port (the RCM), as near
    to the task as still frames all of it (:func:`~endocam.task.layout.port_view`: the wire,
    its post bases and PSM2's tip in both eyes with ``VIEW_MARGIN`` spare), the camera at least
    ``ARM_START_GAP`` beyond the port and no nearer than the arm reaches with its wrist
    straight. The horizon is level where the arm can level it; a carrier whose roll is at a
    limit there (the 4-DoF ECM) is framed with the roll it takes, found by iterating.

    Parameters
    ----------
    arm : StartViewArm
        A camera arm (``robot.camera_arm.CameraArm``).
    task_cfg : TaskConfig
    camera : StereoCamera

    Returns
    -------
    T_world_cam : (4, 4) ndarray
        The start view, world, optical frame, m.
    look_distance : float
        m.

    Raises
    ------
    FramingError
        When no view from the port frames the task, or the arm cannot take the view, or the
        view lies outside the arm's workspace (one line naming the problem).
    """
    gap = max(ARM_START_GAP, arm.shortest_reach)
    port = arm.p_world_rcm
    roll = 0.0
    for _ in range(_START_ROLL_ITERATIONS):
        T, look = port_view(task_cfg, camera, vec(port), gap, roll=roll)
        _, T_reached, status = arm.target(T, look)
        reached_roll = _roll_from_level(T_reached)
        if status is ActuatorStatus.NEAREST:
            raise FramingError(
                f"start view: the {arm.kind.value} cannot take the view of the whole task "
                f"from its port {float(np.linalg.norm(T[:3, 3] - port)):.3f} m ahead"
            )
        if abs(_wrap(reached_roll - roll)) <= START_ROLL_TOL_RAD:
            break
        roll = reached_roll
    else:
        raise FramingError(f"start view: the {arm.kind.value}'s roll did not settle")
    if arm.workspace is not None and arm.workspace.margin(T[:3, 3].tolist()) < 0.0:
        raise FramingError("start view: the view of the whole task is outside the workspace")
    return T, look


def _roll_from_level(T: FloatArray) -> float:
    """Image roll of a camera pose (4, 4) about its optical axis from the level horizon, rad."""
    x_level = rotation_looking_along(T[:3, 2], UP, None)[:, 0]
    x = T[:3, 0]
    return math.atan2(float(np.cross(x_level, x) @ T[:3, 2]), float(x_level @ x))


def _wrap(angle: float) -> float:
    """An angle in (−π, π], rad."""
    return math.atan2(math.sin(angle), math.cos(angle))
