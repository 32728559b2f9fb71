"""The free camera's Cartesian limiter: it reaches rotations within its angular limits."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from endocam.robot.arm import MotionStatus
from endocam.robot.cartesian import CartesianLimiter, MotionLimits

DT = 0.01  # s


def test_rotation_reaches_target_within_angular_limits() -> None:
    limits = MotionLimits()
    lim = CartesianLimiter(limits, DT)
    lim.reset(np.eye(4))
    target = np.eye(4)
    target[:3, :3] = Rotation.from_rotvec([0.0, 0.0, 2.5]).as_matrix()  # 143° about z
    prev = lim.pose
    for _ in range(1000):
        T = lim.step(target)
        step = Rotation.from_matrix(prev[:3, :3].T @ T[:3, :3]).magnitude()
        assert step <= limits.max_angular_speed * DT * (1 + 1e-9)
        prev = T
        if lim.status is MotionStatus.FINISHED:
            break
    assert lim.status is MotionStatus.FINISHED
    np.testing.assert_array_equal(lim.pose, target)
