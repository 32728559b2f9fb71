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


# A state recorded from a free-camera run on perceived ring poses (round 12): the position
# DoFs' accelerations sit exactly at their limits while the target moves, and ruckig refused
# the step and its round-off retry, which stopped the episode with a RuckigError.
AT_LIMIT_POSITION = [-0.0004108749806447322, -0.02889753118491466, 0.04699222599498799]
AT_LIMIT_VELOCITY = [-0.002126317145498256, -0.002638410293111119, 0.001777035009708182]
AT_LIMIT_ANGULAR = [-0.204765733922626, 0.1894483011061032, -0.08139023933281636]
AT_LIMIT_ANGULAR_ACC = [-7.255197456936871, -5.502395015569256, 4.83679830462458]
TARGET_POSITION = [-0.0002957880165682246, -0.02863693021113831, 0.04978422865606902]
TARGET_ROTVEC = [-0.09610292972457797, -0.01101124055849538, 0.0002365469742786982]
TARGET_TWIST = [0.005785693364825074, 0.002389925516427076, 0.0009699822150866649]
TARGET_TWIST += [-0.03606283256364067, -0.1153601624848698, 0.04639792322887287]


def test_a_state_at_its_acceleration_limit_gets_a_step_within_the_limits() -> None:
    limits = MotionLimits()
    lim = CartesianLimiter(limits, DT)
    start = np.eye(4)
    start[:3, 3] = AT_LIMIT_POSITION
    lim.reset(start)
    a_max = limits.max_linear_acceleration / np.sqrt(3.0)  # per axis, m/s²
    lim._v = AT_LIMIT_VELOCITY + AT_LIMIT_ANGULAR
    lim._acc = [a_max] * 3 + AT_LIMIT_ANGULAR_ACC
    target = np.eye(4)
    target[:3, :3] = Rotation.from_rotvec(TARGET_ROTVEC).as_matrix()
    target[:3, 3] = TARGET_POSITION
    T = lim.step(target, np.array(TARGET_TWIST))
    assert np.all(np.isfinite(T))
    v_max = limits.max_linear_speed / np.sqrt(3.0)  # per axis, m/s
    step_m = np.abs(T[:3, 3] - start[:3, 3])
    assert np.all(step_m <= v_max * DT * (1 + 1e-9))  # within the per-axis speed limit
    for _ in range(300):  # and it goes on to the target
        T = lim.step(target, np.array(TARGET_TWIST))
    assert np.linalg.norm(T[:3, 3] - TARGET_POSITION) < 0.05  # m: following, not stuck
