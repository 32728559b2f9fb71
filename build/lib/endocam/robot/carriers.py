"""Build the camera carrier an episode uses, from its :class:`ArmKind` and the config."""

from __future__ import annotations

import numpy as np

from endocam.robot.actuator import Actuator, ArmKind, WorkspaceBound
from endocam.robot.camera_arm import CameraArm
from endocam.robot.cartesian import MotionLimits
from endocam.robot.free_camera import FreeCamera

__all__ = ["make_actuator"]


def make_actuator(
    kind: ArmKind,
    limits: MotionLimits,
    T_tip_cam: object,
    T_world_rcm: object,
    dt: float,
    workspace: WorkspaceBound | None = None,
) -> Actuator:
    """The carrier of ``kind``: a free camera, or the camera on a PSM or an ECM.

    Parameters
    ----------
    kind : ArmKind
    limits : MotionLimits
        Cartesian limits of the free camera.
    T_tip_cam : (4, 4) array_like
        The camera optical frame in the PSM tool-tip frame, m (the ECM's tip is its optical
        frame).
    T_world_rcm : (4, 4) array_like
        The camera arm's RCM frame in world, m.
    dt : float
        Control period, s.
    workspace : WorkspaceBound, optional
        Where the camera may be (cone and floor): once inside, the carrier keeps it there.
    """
    if kind is ArmKind.FREE:
        return FreeCamera(limits, dt, workspace)
    T_cam = T_tip_cam if kind is ArmKind.PSM else np.eye(4)
    return CameraArm(kind, T_world_rcm, T_cam, dt, workspace)
