"""Tests of the CRTK-style SimulatedArm (ruckig-limited joint motion)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from endocam.robot import (
    ECM,
    PSM,
    CrtkArm,
    IKStatus,
    MotionStatus,
    SimulatedArm,
    UnreachablePolicy,
)
from endocam.robot.dh import chain_forward

DT = 1e-3  # s, control cycle
EPS = np.finfo(np.float64).eps
ATOL_M = 1e-9  # m
ATOL_RAD = 1e-9  # rad
LIMIT_TOL = 1e-12  # rad or m: joint positions may touch a limit, never cross it
RATE_RTOL = 1e-6  # relative slack on velocity / acceleration bounds (ruckig round-off)

PSM_MODEL = PSM()
ECM_MODEL = ECM()


def _run(arm: SimulatedArm, cycles: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, list]:
    qs, qds, qdds, statuses = [], [], [], []
    for _ in range(cycles):
        statuses.append(arm.step())
        q, qd = arm.measured_js()
        qs.append(q)
        qds.append(qd)
        qdds.append(arm.measured_ja())
    return np.array(qs), np.array(qds), np.array(qdds), statuses


def _assert_within_limits(arm: SimulatedArm, qs: np.ndarray) -> None:
    assert np.all(qs >= arm.model.lower - LIMIT_TOL)
    assert np.all(qs <= arm.model.upper + LIMIT_TOL)


def test_simulated_arm_satisfies_crtk_protocol() -> None:
    assert isinstance(SimulatedArm(PSM_MODEL), CrtkArm)
    assert isinstance(SimulatedArm(ECM_MODEL), CrtkArm)


def test_out_of_limit_target_is_clamped_and_never_exceeded() -> None:
    arm = SimulatedArm(PSM_MODEL, dt=DT)
    target = PSM_MODEL.upper + np.array([1.0, 0.5, 0.1, 1.0, 0.5, 0.5])
    assert arm.servo_jp(target) is IKStatus.CLAMPED_TO_LIMITS
    np.testing.assert_array_equal(arm.setpoint_js(), PSM_MODEL.upper)
    qs, _, _, statuses = _run(arm, 20000)
    _assert_within_limits(arm, qs)
    assert MotionStatus.LIMIT_STOP not in statuses  # ruckig + clamped target suffice
    assert statuses[-1] is MotionStatus.FINISHED
    np.testing.assert_allclose(qs[-1], PSM_MODEL.upper, atol=1e-9)


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_switching_targets_never_cross_limits(seed: int) -> None:
    rng = np.random.default_rng(seed)
    arm = SimulatedArm(PSM_MODEL, dt=DT)
    span = PSM_MODEL.upper - PSM_MODEL.lower
    all_q = []
    for _ in range(8):
        # targets up to 30 % of the range beyond either limit, switched mid-motion
        target = rng.uniform(PSM_MODEL.lower - 0.3 * span, PSM_MODEL.upper + 0.3 * span)
        arm.servo_jp(target)
        qs, _, _, statuses = _run(arm, int(rng.integers(50, 400)))
        assert MotionStatus.LIMIT_STOP not in statuses
        all_q.append(qs)
    _assert_within_limits(arm, np.concatenate(all_q))


def test_velocity_and_acceleration_limits_respected() -> None:
    vmax = np.array([0.5, 0.4, 0.05, 1.0, 1.5, 2.0])
    amax = np.array([1.0, 0.8, 0.1, 3.0, 4.0, 5.0])
    arm = SimulatedArm(PSM_MODEL, dt=DT, max_velocity=vmax, max_acceleration=amax)
    rng = np.random.default_rng(11)
    qs_all, qds_all = [arm.measured_js()[0][None]], [arm.measured_js()[1][None]]
    for _ in range(4):
        arm.servo_jp(rng.uniform(PSM_MODEL.lower, PSM_MODEL.upper))
        qs, qds, qdds, _ = _run(arm, 1500)
        assert np.all(np.abs(qds) <= vmax * (1 + RATE_RTOL))
        assert np.all(np.abs(qdds) <= amax * (1 + RATE_RTOL))
        qs_all.append(qs)
        qds_all.append(qds)
    q = np.concatenate(qs_all)
    qd = np.concatenate(qds_all)
    # the sampled trajectory itself (finite differences), not just the reported rates
    v_fd = np.diff(q, axis=0) / DT
    a_fd = np.diff(qd, axis=0) / DT
    assert np.all(np.abs(v_fd) <= vmax * (1 + RATE_RTOL))
    assert np.all(np.abs(a_fd) <= amax * (1 + RATE_RTOL))
    assert np.max(np.abs(v_fd[:, 0])) > 0.9 * vmax[0]  # limits were actually active


def test_hard_stop_when_moving_too_fast_towards_a_limit() -> None:
    arm = SimulatedArm(PSM_MODEL, dt=DT)
    q0 = np.zeros(6)
    q0[2] = PSM_MODEL.upper[2] - 1e-3  # 1 mm from full insertion ...
    qd0 = np.zeros(6)
    qd0[2] = 0.2  # ... at 0.2 m/s: braking needs 5 cm at 0.4 m/s²
    arm.reset(q0, qd0)
    arm.servo_jp(q0 + np.array([0, 0, 1.0, 0, 0, 0]))
    qs, qds, _, statuses = _run(arm, 100)
    _assert_within_limits(arm, qs)
    assert MotionStatus.LIMIT_STOP in statuses
    stop = statuses.index(MotionStatus.LIMIT_STOP)
    assert qs[stop, 2] == PSM_MODEL.upper[2]
    assert qds[stop, 2] == 0.0


def test_servo_cp_reaches_reachable_pose() -> None:
    arm = SimulatedArm(PSM_MODEL, dt=DT)
    q_goal = np.array([0.3, -0.2, 0.12, 0.5, 0.3, -0.4])
    T_goal = PSM_MODEL.forward(q_goal)
    res = arm.servo_cp(T_goal)
    assert res.status is IKStatus.OK
    assert arm.command_status is IKStatus.OK
    for _ in range(10000):
        if arm.step() is MotionStatus.FINISHED:
            break
    assert arm.motion_status is MotionStatus.FINISHED
    np.testing.assert_allclose(arm.measured_cp(), T_goal, atol=ATOL_M)
    q, _ = arm.measured_js()
    np.testing.assert_allclose(PSM_MODEL.forward(q), arm.measured_cp(), atol=ATOL_M)


def test_servo_cp_unreachable_policies() -> None:
    q_far = np.array([0.2, 0.1, 0.35, 0.0, 0.1, 0.1])
    T_far = chain_forward(PSM_MODEL.chain, q_far)  # insertion beyond its limit
    near = SimulatedArm(PSM_MODEL, dt=DT)
    res = near.servo_cp(T_far)
    assert res.status is IKStatus.CLAMPED_TO_LIMITS
    assert near.command_status is IKStatus.CLAMPED_TO_LIMITS
    np.testing.assert_allclose(near.setpoint_js(), res.q)
    hold = SimulatedArm(PSM_MODEL, dt=DT, unreachable=UnreachablePolicy.HOLD)
    before = hold.setpoint_js()
    res_hold = hold.servo_cp(T_far)
    assert res_hold.status is IKStatus.CLAMPED_TO_LIMITS
    np.testing.assert_array_equal(hold.setpoint_js(), before)
    assert hold.last_ik is res_hold


def test_base_frame_is_applied_to_cartesian_io() -> None:
    T_base_rcm = np.eye(4)
    T_base_rcm[:3, :3] = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    T_base_rcm[:3, 3] = [0.1, -0.2, 0.3]
    arm = SimulatedArm(PSM_MODEL, dt=DT, T_base_rcm=T_base_rcm)
    q, _ = arm.measured_js()
    np.testing.assert_allclose(arm.measured_cp(), T_base_rcm @ PSM_MODEL.forward(q))
    q_goal = np.array([-0.2, 0.1, 0.08, -0.3, 0.2, 0.1])
    res = arm.servo_cp(T_base_rcm @ PSM_MODEL.forward(q_goal))
    assert res.ok
    np.testing.assert_allclose(res.q, q_goal, atol=1e-7)


def test_move_jp_settles_and_ecm_arm_works() -> None:
    arm = SimulatedArm(ECM_MODEL, dt=DT)
    goal = np.array([0.2, 0.1, 0.05, -0.3])
    assert arm.move_jp(goal) is IKStatus.OK
    arm.step(5.0)
    assert arm.motion_status is MotionStatus.FINISHED
    assert arm.time == pytest.approx(5.0)
    np.testing.assert_allclose(arm.measured_js()[0], goal, atol=ATOL_RAD)


def test_step_rejects_non_multiple_dt() -> None:
    arm = SimulatedArm(PSM_MODEL, dt=DT)
    arm.step(5 * DT)
    assert arm.time == pytest.approx(5 * DT)
    for bad in (1.5 * DT, 0.0, -DT, float("nan")):
        with pytest.raises(ValueError, match="dt"):
            arm.step(bad)


def test_bad_input_rejected() -> None:
    arm = SimulatedArm(PSM_MODEL, dt=DT)
    with pytest.raises(ValueError, match="q"):
        arm.servo_jp([0.0, 0.0, np.nan, 0.0, 0.0, 0.0])
    T = np.eye(4)
    T[1, 3] = np.inf
    with pytest.raises(ValueError, match="T_base_tip"):
        arm.servo_cp(T)
    with pytest.raises(ValueError, match="max_velocity"):
        SimulatedArm(PSM_MODEL, max_velocity=[1.0, 1.0, -1.0, 1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="dt"):
        SimulatedArm(PSM_MODEL, dt=0.0)
