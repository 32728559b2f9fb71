"""The dVRK's own tip frames for endocam's arms: what a dVRK reports for the same joints.

endocam's DH chains are the dVRK's tables (``tests/test_dvrk_tables.py`` pins them to the
published files). The tip frames:

- **PSM**: the same. endocam appends the tool's ``tooltip_offset``
  (:data:`endocam.robot.psm.PSM_TOOLTIP_OFFSET`), as the dVRK does; ``T_rcm_tip`` at joints
  ``q`` is the dVRK's ``local/measured_cp`` at ``q``.
- **ECM**: the same. For a straight scope the dVRK appends
  :data:`ECM_TOOLTIP_OFFSET_STRAIGHT` = ``Rz(−π/2)`` (``mtsIntuitiveResearchKitECM::
  set_endoscope_type``, jhu-dvrk/sawIntuitiveResearchKit commit 0210eb1a) and reports that
  tip in the ISI camera convention (x left, y up, z away from the viewer; dVRK wiki
  "Coordinate Systems"); endocam's ``ECM_CHAIN`` appends the same offset. endocam's camera
  (OpenCV optical frame) is :data:`T_TIP_CAM_ECM` on that tip (:func:`dvrk_ecm_tip`,
  :func:`ecm_camera_from_dvrk_tip` convert, exactly), and the ECM's RCM frame is the scene's
  turned by :data:`T_RCM_RCMECM` (``Rz(π/2)``: an upright image at zero roll).

Poses are ``(4, 4)``, m, in the arm's RCM frame.

:class:`CrtkFrames` is where the link's CRTK poses are (``measured_cp``, ``setpoint_cp``,
``servo_cp``): the dVRK's tip in the arm's base frame. The dVRK reports ``measured_cp =
base_frame · local/measured_cp``, ``local/measured_cp`` being the forward kinematics in the
arm's RCM frame, and its ``base_frame`` is the identity until a user or the set-up joints set
one; ``servo_cp`` is a pose in the same frame (jhu-dvrk/sawIntuitiveResearchKit commit
5ce5795b, ``core/components/code/mtsIntuitiveResearchKitArm.cpp``: ``Init`` sets
``m_base_frame`` to the identity, ``get_robot_data`` computes ``m_measured_cp_frame =
m_base_frame * m_local_measured_cp_frame``, ``control_servo_cs`` solves the IK for
``m_base_frame.Inverse() * goal``). So for a stand-alone arm, as endocam's are, the base frame
is the RCM frame :func:`endocam.robot.carriers.arm_mount` places, and ``measured_cp`` equals
``local/measured_cp``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from endocam.geometry import FloatArray, as_pose, invert_pose
from endocam.kernels import cross, dot
from endocam.robot.actuator import ArmKind

__all__ = [
    "ARM_NAMESPACES",
    "ECM_TOOLTIP_OFFSET_STRAIGHT",
    "FREE_CAMERA_FRAMES",
    "T_ISI_OPENCV",
    "T_RCM_RCMECM",
    "T_TIP_CAM_ECM",
    "WORLD_FRAME_ID",
    "CrtkFrames",
    "crtk_frame_id",
    "crtk_pose_fields",
    "dvrk_ecm_tip",
    "ecm_camera_from_dvrk_tip",
]

ARM_NAMESPACES = {ArmKind.PSM: "PSM3", ArmKind.ECM: "ECM", ArmKind.FREE: "camera"}
"""The carrier's CRTK namespace, on the link and in MCAP files: the dVRK names its arms PSM1-3
and ECM (PSM1 and PSM2 hold the instruments here: PSM1 the ring, PSM2 the second tool); the free
camera, which has no dVRK counterpart, is ``camera``."""

WORLD_FRAME_ID = "world"
"""``frame_id`` of a pose in the simulation's world frame."""


def crtk_frame_id(kind: ArmKind) -> str:
    """``frame_id`` of carrier ``kind``'s CRTK poses (``measured_cp``, ``setpoint_cp``, ...).

    An arm's: its base frame as the dVRK names it, ``<ARM>_base`` (``m_measured_cp.
    SetReferenceFrame(GetName() + "_base")`` in ``mtsIntuitiveResearchKitArm::Init``,
    jhu-dvrk/sawIntuitiveResearchKit commit 9e535e68); the free camera's: the world.
    """
    return WORLD_FRAME_ID if kind is ArmKind.FREE else f"{ARM_NAMESPACES[kind]}_base"


def crtk_pose_fields(T: FloatArray) -> tuple[float, ...]:
    """A pose's ``geometry_msgs/Pose`` fields ``(x, y, z, qx, qy, qz, qw)`` (m; ROS's order).

    ``T`` : (4, 4) the pose, m. The one conversion of a pose to its message: the link and the
    MCAP export both write poses through it.
    """
    R = T[:3, :3]
    x, y, z, w = Rotation.from_matrix(R, assume_valid=_valid_rotation(R.tolist())).as_quat()
    p = T[:3, 3]
    return (float(p[0]), float(p[1]), float(p[2]), float(x), float(y), float(z), float(w))


_GRAM_ATOL = 1e-12  # scipy's ``from_matrix`` test: |R Rᵀ − I| ≤ atol + rtol · |I|, elementwise
_GRAM_RTOL = 1e-5  # (numpy ``isclose``'s default rtol, which scipy's test keeps)


def _valid_rotation(R: list[list[float]]) -> bool:
    """Whether scipy's ``Rotation.from_matrix`` takes the 3×3 ``R`` as it is.

    scipy's own test (determinant > 0, Gram matrix ``isclose`` to I with atol 1e-12), done
    here on one matrix's nine floats: a valid rotation then skips scipy's general path (~5× its
    cost per call) for the same conversion and the same bits; anything else takes that path
    (orthogonalised, or refused) exactly as before. With the Gram matrix that close to I the
    determinant is ±1 to ~1e-5, so the sign of r0 · (r1 × r2) is the sign scipy's LU gives.
    """
    rows = [(r[0], r[1], r[2]) for r in R]
    for i in range(3):
        for j in range(i, 3):
            if abs(dot(rows[i], rows[j]) - (i == j)) > _GRAM_ATOL + _GRAM_RTOL * (i == j):
                return False
    return dot(rows[0], cross(rows[1], rows[2])) > 0.0  # the determinant


ECM_TOOLTIP_OFFSET_STRAIGHT = np.array(
    [[0.0, 1.0, 0.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)
"""``T_last_tip`` the dVRK appends to the ECM chain for a straight scope (Classic SD/HD, Si HD):
``Rz(−π/2)``, no translation (a Custom scope adds 0.18 m along z; 30° UP/DOWN scopes then turn
∓30° about x)."""

T_ISI_OPENCV = np.diag([-1.0, -1.0, 1.0, 1.0])
"""``T_isi_opencv``: the OpenCV optical frame (x right, y down, z forward) in the ISI camera
frame (x left, y up, z forward): ``Rz(π)``."""

T_TIP_CAM_ECM = T_ISI_OPENCV
"""``T_tip_cam`` of the ECM: endocam's camera (OpenCV optical frame) on the dVRK's ECM tip (ISI
camera frame), ``Rz(π)``; with :data:`ECM_TOOLTIP_OFFSET_STRAIGHT` the camera is the last DH
frame turned by ``Rz(π/2)``. The one place this mount is defined (docs/conventions.md)."""

T_RCM_RCMECM = np.array(
    [[0.0, -1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)
"""The ECM's RCM frame in the scene's RCM frame (``task.scene.rcm_euler_xyz``): ``Rz(π/2)``, so
the ECM at zero joints sees what the last DH frame saw before the dVRK's tip was adopted (an
upright image at zero roll; the PSM keeps the scene's RCM frame)."""


def dvrk_ecm_tip(T_rcm_cam: object) -> FloatArray:
    """The dVRK's ECM tip (``local/measured_cp``, ISI convention) for endocam's ECM camera.

    ``T_rcm_cam`` : (4, 4) endocam's ECM camera (OpenCV optical frame), RCM frame, m. Returns
    ``T_rcm_tip`` (4, 4): ``T_rcm_cam · T_TIP_CAM_ECM⁻¹`` (= ``ECM.forward(q)`` at its joints).
    """
    return as_pose(T_rcm_cam, "T_rcm_cam") @ invert_pose(T_TIP_CAM_ECM)


def ecm_camera_from_dvrk_tip(T_rcm_tip: object) -> FloatArray:
    """Endocam's ECM camera for the dVRK's ECM tip (the inverse of :func:`dvrk_ecm_tip`).

    ``T_rcm_tip`` : (4, 4) the dVRK's ``local/measured_cp`` of a straight scope, RCM frame, m.
    Returns ``T_rcm_cam`` (4, 4), OpenCV optical frame: ``T_rcm_tip · T_TIP_CAM_ECM``.
    """
    return as_pose(T_rcm_tip, "T_rcm_tip") @ T_TIP_CAM_ECM


@dataclass(frozen=True, eq=False)
class CrtkFrames:
    """Where a carrier's CRTK poses are: the dVRK's tip in the arm's base frame.

    endocam works with the camera's optical frame in the world (``T_world_cam``); a dVRK's
    ``measured_cp``, ``setpoint_cp`` and ``servo_cp`` carry the tool tip in the arm's base
    frame (``T_base_tip``; see the module docstring). ``T_world_cam = T_world_base ·
    T_base_tip · T_tip_cam``: this class converts both ways, the one place it is done.

    Attributes
    ----------
    T_world_base : (4, 4)
        The arm's base frame in world, m: its RCM frame as
        :func:`endocam.robot.carriers.arm_mount` places it (on a rig: the registration).
    T_tip_cam : (4, 4)
        The camera optical frame in the dVRK's tip frame, m (the PSM's pickup mount, or
        :data:`T_TIP_CAM_ECM`).
    frame_id : str
        The base frame's name, the poses' ``header.frame_id`` (:func:`crtk_frame_id`).
    """

    T_world_base: FloatArray
    T_tip_cam: FloatArray
    frame_id: str = WORLD_FRAME_ID
    _T_base_world: FloatArray = field(init=False, repr=False)
    _T_cam_tip: FloatArray = field(init=False, repr=False)
    identity: bool = field(init=False)
    """World is the base frame and the camera is the tip (the free camera): no conversion."""

    def __post_init__(self) -> None:
        T_world_base = as_pose(self.T_world_base, "T_world_base").copy()
        T_tip_cam = as_pose(self.T_tip_cam, "T_tip_cam").copy()
        object.__setattr__(self, "T_world_base", T_world_base)
        object.__setattr__(self, "T_tip_cam", T_tip_cam)
        object.__setattr__(self, "_T_base_world", invert_pose(T_world_base))
        object.__setattr__(self, "_T_cam_tip", invert_pose(T_tip_cam))
        eye = np.eye(4)
        same = np.array_equal(T_world_base, eye) and np.array_equal(T_tip_cam, eye)
        object.__setattr__(self, "identity", same)

    def tip_from_camera(self, T_world_cam: FloatArray) -> FloatArray:
        """``T_base_tip`` (4, 4), m, of the camera pose ``T_world_cam`` (4, 4), world, m."""
        if self.identity:
            return np.array(T_world_cam, dtype=float)
        return self._T_base_world @ T_world_cam @ self._T_cam_tip

    def camera_from_tip(self, T_base_tip: FloatArray) -> FloatArray:
        """``T_world_cam`` (4, 4), world, m, of the tip pose ``T_base_tip`` (4, 4), m."""
        if self.identity:
            return np.array(T_base_tip, dtype=float)
        return self.T_world_base @ T_base_tip @ self.T_tip_cam


FREE_CAMERA_FRAMES = CrtkFrames(np.eye(4), np.eye(4))
"""The free camera's: it has no dVRK counterpart; its base is the world, its tip the camera."""
