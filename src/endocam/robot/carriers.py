"""Build the camera carrier an episode uses, from its :class:`ArmKind` and the config."""

from __future__ import annotations

import numpy as np

from endocam.config import EpisodeConfig
from endocam.robot.actuator import Actuator, ArmKind
from endocam.robot.camera_arm import CameraArm
from endocam.robot.cartesian import FreeCamera

__all__ = ["make_actuator"]


def make_actuator(
    kind: ArmKind, episode: EpisodeConfig, T_world_rcm: object, dt: float
) -> Actuator:
    """The carrier of ``kind``: a free camera, or the camera on a PSM or an ECM.

    Parameters
    ----------
    kind : ArmKind
    episode : EpisodeConfig
        Motion limits of the free camera, camera mount on the PSM tool tip.
    T_world_rcm : (4, 4) array_like
        The camera arm's RCM frame in world, m.
    dt : float
        Control period, s.
    """
    if kind is ArmKind.FREE:
        return FreeCamera(episode.limits, dt)
    T_tip_cam = episode.T_tip_cam if kind is ArmKind.PSM else np.eye(4)
    return CameraArm(kind, T_world_rcm, T_tip_cam, dt)
