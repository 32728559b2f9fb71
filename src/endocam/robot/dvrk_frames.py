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
"""

from __future__ import annotations

import numpy as np

from endocam.geometry import FloatArray, as_pose, invert_pose

__all__ = [
    "ECM_TOOLTIP_OFFSET_STRAIGHT",
    "T_ISI_OPENCV",
    "T_RCM_RCMECM",
    "T_TIP_CAM_ECM",
    "dvrk_ecm_tip",
    "ecm_camera_from_dvrk_tip",
]

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
