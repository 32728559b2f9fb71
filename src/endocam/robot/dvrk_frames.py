"""The dVRK's own tip frames for endocam's arms: what a dVRK reports for the same joints.

endocam's DH chains are the dVRK's tables (``tests/test_dvrk_tables.py`` pins them to the
published files). The tip frames:

- **PSM**: the same. endocam appends the tool's ``tooltip_offset``
  (:data:`endocam.robot.psm.PSM_TOOLTIP_OFFSET`), as the dVRK does; ``T_rcm_tip`` at joints
  ``q`` is the dVRK's ``local/measured_cp`` at ``q``.
- **ECM**: not the same. endocam's camera is the last DH frame (z along the scope, OpenCV
  optical frame: x right, y down). For a straight scope the dVRK appends
  :data:`ECM_TOOLTIP_OFFSET_STRAIGHT` = ``Rz(−π/2)`` (``mtsIntuitiveResearchKitECM::
  set_endoscope_type``, jhu-dvrk/sawIntuitiveResearchKit commit 0210eb1a) and reports that
  tip in the ISI camera convention (x left, y up, z away from the viewer; dVRK wiki
  "Coordinate Systems"): :func:`dvrk_ecm_tip` and :func:`ecm_camera_from_dvrk_tip` convert,
  exactly (a permutation of axes). With the RCM frame registered as the dVRK defines it, the
  joint values agree; endocam's default RCM frame (``task.scene.rcm_euler_xyz``) is the dVRK's
  turned by ``Rz(−π/2)`` (docs/robot.md, "The dVRK's own ECM camera frame"), so today's ECM
  joint values in an endocam world are not a dVRK's in the same world (issue 25 §2).

Poses are ``(4, 4)``, m, in the arm's RCM frame.
"""

from __future__ import annotations

import numpy as np

from endocam.geometry import FloatArray, as_pose, invert_pose

__all__ = [
    "ECM_TOOLTIP_OFFSET_STRAIGHT",
    "T_ISI_OPENCV",
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


def dvrk_ecm_tip(T_rcm_cam: object) -> FloatArray:
    """The dVRK's ECM tip (``local/measured_cp``, ISI convention) for endocam's ECM camera.

    ``T_rcm_cam`` : (4, 4) endocam's ECM camera (the last DH frame, OpenCV optical), RCM
    frame, m. Returns ``T_rcm_tip`` (4, 4): ``T_rcm_cam · Rz(−π/2)``.
    """
    return as_pose(T_rcm_cam, "T_rcm_cam") @ ECM_TOOLTIP_OFFSET_STRAIGHT


def ecm_camera_from_dvrk_tip(T_rcm_tip: object) -> FloatArray:
    """Endocam's ECM camera for the dVRK's ECM tip (the inverse of :func:`dvrk_ecm_tip`).

    ``T_rcm_tip`` : (4, 4) the dVRK's ``local/measured_cp`` of a straight scope, RCM frame, m.
    Returns ``T_rcm_cam`` (4, 4), OpenCV optical frame.
    """
    return as_pose(T_rcm_tip, "T_rcm_tip") @ invert_pose(ECM_TOOLTIP_OFFSET_STRAIGHT)
