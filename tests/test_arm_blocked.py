"""A PSM camera on the floor whose every step towards the command dips below it must not sit still.

The scene of the noisy 71-point path, seed 7, at 33 s (from its log): the camera rests on the
floor (``min_camera_height``), the command is 60 mm away, 1 mm above the floor. Every joint
step towards it, on the camera path or the straight joint line, first dips below the floor, so
the braking guard refused each one and the arm sat frozen for seconds while the episode logged
``tracking``. Now the carrier takes the admissible step nearest to the refused one (slid along
the floor) or, when none is, says so (``GuardAction.BRAKED``); the camera never leaves the
workspace either way.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from endocam.config import ExperimentConfig
from endocam.robot.actuator import ArmKind, GuardAction
from endocam.robot.camera_arm import CameraArm

# the logged state (seed 7, t = 33 s): joints, rad / m; poses: position m, quaternion (w, x, y, z)
Q0 = (-0.22659276754862095, -0.21753787135235725, 0.15944024944770632, 0.2210735544353001,
      0.4921247352709502, 1.1205295127176405)  # fmt: skip
CMD = (0.07934359007677727, -0.04315589153149917, 0.016, 0.6115622542383954,
       -0.5022722701336706, -0.38799193398573967, 0.472415532140537)  # fmt: skip
P_RING0 = (-0.09852118506266606, 0.006247840513151708, 0.034356889653032595)  # m: the cone's aim
LOOK_M = 0.08  # m: the command's working distance (d_max)
STEPS = 50  # count: 0.5 s at 100 Hz
PROGRESS_M = 5e-3  # m: the camera comes at least this much closer to the command in 0.5 s
STILL_TOL = 1e-9  # rad / m: a joint step smaller than this is standing still
INSIDE_TOL_M = 1e-9  # m: round-off on the workspace margin


def _pose(row: tuple[float, ...]) -> np.ndarray:
    T = np.eye(4)
    w, x, y, z = row[3:]
    T[:3, :3] = Rotation.from_quat([x, y, z, w]).as_matrix()
    T[:3, 3] = row[:3]
    return T


def test_a_blocked_arm_slides_or_reports_it() -> None:
    cfg = ExperimentConfig()
    workspace = cfg.controller.workspace(np.array(cfg.task.scene.rcm_position), np.array(P_RING0))
    arm = CameraArm(ArmKind.PSM, cfg.task.scene.T_world_rcm, cfg.episode.T_tip_cam, 0.01, workspace)
    arm.reset(arm.camera_pose(np.array(Q0)), LOOK_M)
    np.testing.assert_allclose(arm.q, Q0, atol=1e-6)  # the logged configuration, at rest
    T_cmd = _pose(CMD)
    gap0 = float(np.linalg.norm(arm.camera_pose(arm.q)[:3, 3] - T_cmd[:3, 3]))
    q_before = arm.q
    for _ in range(STEPS):
        out = arm.step(T_cmd, LOOK_M)
        assert workspace.margin(out.T_world_cam[:3, 3]) >= -INSIDE_TOL_M  # never out
        if np.max(np.abs(out.q - q_before)) < STILL_TOL:  # standing still: it must say why
            assert out.guard is GuardAction.BRAKED
        q_before = out.q
    gap = float(np.linalg.norm(out.T_world_cam[:3, 3] - T_cmd[:3, 3]))
    assert gap < gap0 - PROGRESS_M  # and it makes its way along the floor
