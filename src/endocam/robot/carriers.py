"""Build the camera carrier an episode uses, from its :class:`ArmKind` and the config."""

from __future__ import annotations

import numpy as np

from endocam.geometry import FloatArray
from endocam.robot.actuator import Actuator, ArmKind, WorkspaceBound
from endocam.robot.camera_arm import CameraArm
from endocam.robot.cartesian import MotionLimits
from endocam.robot.dvrk_frames import (
    FREE_CAMERA_FRAMES,
    T_RCM_RCMECM,
    T_TIP_CAM_ECM,
    CrtkFrames,
    crtk_frame_id,
)
from endocam.robot.free_camera import FreeCamera

__all__ = ["arm_mount", "crtk_frames", "make_actuator"]


def arm_mount(
    kind: ArmKind, T_tip_cam: object, T_world_rcm: object
) -> tuple[FloatArray, FloatArray]:
    """Where an arm of ``kind`` sits and carries its camera: ``(T_world_rcm_arm, T_tip_cam_arm)``.

    ``T_tip_cam`` (4, 4), m: the PSM's camera in its tool-tip frame (``episode.tip_cam_*``).
    ``T_world_rcm`` (4, 4), m: the scene's RCM frame (the port). The PSM takes both as given.
    The ECM's tip is the dVRK's (ISI camera frame): its camera is
    :data:`~endocam.robot.dvrk_frames.T_TIP_CAM_ECM` on it, under the RCM frame turned by
    :data:`~endocam.robot.dvrk_frames.T_RCM_RCMECM`.
    """
    T_rcm = np.asarray(T_world_rcm, dtype=float)
    if kind is ArmKind.ECM:
        return T_rcm @ T_RCM_RCMECM, T_TIP_CAM_ECM.copy()
    return T_rcm, np.asarray(T_tip_cam, dtype=float)


def crtk_frames(kind: ArmKind, T_tip_cam: object, T_world_rcm: object) -> CrtkFrames:
    """The frames of carrier ``kind``'s CRTK poses (arguments as :func:`arm_mount`'s).

    An arm's base frame is its RCM frame and its tip the dVRK's, as :func:`arm_mount` mounts
    them, named ``<ARM>_base``; the free camera's are the world and the camera
    (:data:`FREE_CAMERA_FRAMES`).
    """
    if kind is ArmKind.FREE:
        return FREE_CAMERA_FRAMES
    return CrtkFrames(*arm_mount(kind, T_tip_cam, T_world_rcm), crtk_frame_id(kind))


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
    T_rcm, T_cam = arm_mount(kind, T_tip_cam, T_world_rcm)
    return CameraArm(kind, T_rcm, T_cam, dt, workspace)
