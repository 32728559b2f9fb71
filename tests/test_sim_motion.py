"""The camera limiter's float SO(3) kernels against scipy, and its limits."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from endocam.config import MotionLimits
from endocam.kernels import so3_exp, so3_log
from endocam.robot.arm import MotionStatus
from endocam.robot.cartesian import CartesianLimiter

ATOL_RAD = 1e-12  # rad, float round-off on angles of order 1
DT = 0.01  # s


def test_log_exp_match_scipy() -> None:
    rots = Rotation.random(500, random_state=np.random.default_rng(4).integers(1 << 30))
    special = Rotation.from_rotvec(
        [[0, 0, 0], [1e-12, 0, 0], [math.pi - 1e-9, 0, 0], [0, 0, math.pi], [0.3, -2.0, 1.1]]
    )
    for r in [*rots, *special]:
        ref = r.as_rotvec()
        got = np.array(so3_log(r.as_matrix().tolist()))
        if np.linalg.norm(ref) > math.pi - 1e-6:  # ±π: both signs are the same rotation
            err = min(np.linalg.norm(got - ref), np.linalg.norm(got + ref))
        else:
            err = np.linalg.norm(got - ref)
        assert err < 1e-9
        np.testing.assert_allclose(so3_exp(ref.tolist()), r.as_matrix(), atol=ATOL_RAD)


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
