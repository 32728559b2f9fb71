"""The nearest-feasible solve's callbacks as the interpreter ran them before r7-psm compiled them.

Copies of ``endocam.robot.dh.geometric_jacobian`` and of ``RcmArm._pose_residual`` /
``_pose_residual_jac`` at main before r7-psm (numpy: ``chain_frames``'s 4×4 products,
``np.cross``, ``R_goal^T @ ...``): ``tests/test_robot_kinematics.py`` pins the compiled
``dh.jacobian_into`` and ``kinematics._residual_into`` / ``_residual_jac_into`` to them bit for
bit.
"""

# mypy: ignore-errors

from __future__ import annotations

import numpy as np

from endocam.geometry import FloatArray
from endocam.kernels import so3_log as so3_log_rows
from endocam.robot.dh import DHChain, JointType, chain_forward, chain_frames


def geometric_jacobian(chain: DHChain, q: FloatArray) -> FloatArray:
    """Geometric Jacobian (6, n) of the tool tip in the base frame (rows v, then ω)."""
    frames = chain_frames(chain, q)
    p_tip = frames[-1, :3, 3]
    n = chain.n_joints
    J = np.zeros((6, n))
    for i, link in enumerate(chain.links):
        z = frames[i, :3, 2]
        if link.joint_type is JointType.REVOLUTE:
            J[:3, i] = np.cross(z, p_tip - frames[i, :3, 3])
            J[3:, i] = z
        else:
            J[:3, i] = z
    return J


def pose_residual(chain: DHChain, q: FloatArray, T_goal: FloatArray, weight: float) -> FloatArray:
    """``[p(q) - p_goal, w · rotvec(R_goal^T R(q))]`` (6,), m."""
    T = chain_forward(chain, q)
    rot_err = np.array(so3_log_rows((T_goal[:3, :3].T @ T[:3, :3]).tolist()))
    return np.concatenate([T[:3, 3] - T_goal[:3, 3], weight * rot_err])


def pose_residual_jac(
    chain: DHChain, q: FloatArray, T_goal: FloatArray, weight: float
) -> FloatArray:
    """Jacobian (6, n) of :func:`pose_residual`: ``[J_v; w · R_goal^T J_ω]``."""
    J = geometric_jacobian(chain, q)
    return np.vstack([J[:3], weight * (T_goal[:3, :3].T @ J[3:])])
