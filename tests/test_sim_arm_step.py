"""The fast paths of the camera arm's control step agree with the plain numpy forms."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from endocam.config import ExperimentConfig
from endocam.geometry import make_pose
from endocam.robot.actuator import ActuatorStatus, ArmKind
from endocam.robot.arm import MotionStatus
from endocam.robot.camera_arm import CameraArm, natural_pose
from endocam.robot.carriers import arm_mount
from endocam.robot.dh import (
    chain_points,
    pose12_from_matrix,
    pose12_point,
    pose12_times,
    pose12_to_matrix,
)
from endocam.robot.ik import pose12_error, pose_error

ATOL_M = 1e-12  # m: float kernels vs numpy products, round-off only
ATOL_RAD = 1e-9  # rad: angle kernels vs numpy (atan2 form), round-off only
N_RANDOM = 50  # count, random poses per check
IK_ATOL = 1e-7  # m / rad: the IK tolerance
LOOK_DISTANCE_M = 0.05  # m: the controller's default working distance
HOLD_STEPS = 400  # count, control steps to come to rest on a held goal (4 s at 100 Hz)


def _random_pose(rng: np.random.Generator) -> np.ndarray:
    R = Rotation.random(random_state=rng).as_matrix()
    return make_pose(R, rng.uniform(-0.3, 0.3, 3))


def _arm(kind: ArmKind) -> CameraArm:
    cfg = ExperimentConfig()
    T_rcm, T_tip_cam = arm_mount(kind, cfg.episode.T_tip_cam, cfg.task.scene.T_world_rcm)
    return CameraArm(kind, T_rcm, T_tip_cam, 0.01)


def test_pose12_kernels_match_numpy():
    rng = np.random.default_rng(4)
    for _ in range(N_RANDOM):
        A, B = _random_pose(rng), _random_pose(rng)
        a12 = pose12_from_matrix(A)
        np.testing.assert_array_equal(pose12_to_matrix(a12), A)
        rows = tuple(tuple(r) for r in B[:3].tolist())
        np.testing.assert_allclose(pose12_to_matrix(pose12_times(a12, rows)), A @ B, atol=ATOL_M)
        np.testing.assert_allclose(pose12_point(a12, rows), (A @ B)[:3, 3], atol=ATOL_M)
        np.testing.assert_allclose(
            pose12_point(a12, rows), pose12_times(a12, rows)[9:], atol=ATOL_M
        )
        pos, ang = pose12_error(a12, pose12_from_matrix(B))
        pos_ref, ang_ref = pose_error(A, B)
        assert pos == pytest.approx(pos_ref, abs=ATOL_M)
        assert ang == pytest.approx(ang_ref, abs=ATOL_RAD)


@pytest.mark.parametrize("kind", [ArmKind.PSM, ArmKind.ECM])
def test_camera_pose_fast_path_is_fk(kind: ArmKind):
    arm = _arm(kind)
    rng = np.random.default_rng(5)
    for _ in range(N_RANDOM):
        q = arm.model.clamp(natural_pose(arm.model) + rng.uniform(-0.3, 0.3, arm.model.n_joints))
        expected = arm.T_world_rcm @ arm.model.forward(q) @ arm.T_tip_cam
        np.testing.assert_allclose(arm.camera_pose(q), expected, atol=ATOL_M)
        # the workspace guard's braking check sees the logged camera position
        g = arm.guard.consts
        point = (float(g.last_cam[0, 3]), float(g.last_cam[1, 3]), float(g.last_cam[2, 3]))
        points = chain_points(arm.model.chain, [q.tolist()], pose12_from_matrix(g.world_rcm), point)
        np.testing.assert_allclose(points[0], arm.camera_pose(q)[:3, 3], atol=ATOL_M)


@pytest.mark.parametrize("kind", [ArmKind.PSM, ArmKind.ECM])
def test_held_goal_lands_on_its_exact_solution(kind: ArmKind):
    arm = _arm(kind)
    q_goal = (
        natural_pose(arm.model) + np.array([0.1, 0.1, 0.01, 0.2, 0.2, 0.1])[: arm.model.n_joints]
    )
    goal = arm.camera_pose(q_goal)
    for _ in range(HOLD_STEPS):
        out = arm.step(goal, LOOK_DISTANCE_M)
    assert out.reachable and out.status is ActuatorStatus.EXACT
    assert arm.arm.motion_status is MotionStatus.FINISHED  # at rest
    np.testing.assert_allclose(out.q, q_goal, atol=IK_ATOL)  # the goal's own joints
    np.testing.assert_allclose(out.T_world_cam, goal, atol=IK_ATOL)
    np.testing.assert_allclose(out.T_world_cam, arm.camera_pose(out.q), atol=ATOL_M)


def test_servo_jp_fast_path_validates_and_clamps():
    arm = _arm(ArmKind.PSM).arm
    with pytest.raises(ValueError, match="q"):
        arm.servo_jp([0.0] * 5)
    with pytest.raises(ValueError, match="q"):
        arm.servo_jp([0.0, 0.0, 0.1, 0.0, 0.0, float("nan")])
    q = arm.model.upper + 1.0
    assert arm.servo_jp(q).value == "clamped_to_limits"
    np.testing.assert_array_equal(arm.setpoint_js(), arm.model.upper)
    assert arm.servo_jp(tuple(natural_pose(arm.model))).value == "ok"


def test_held_goal_is_solved_once(monkeypatch: pytest.MonkeyPatch):
    arm = _arm(ArmKind.PSM)
    goal = arm.camera_pose(natural_pose(arm.model) + 0.05)
    calls = []
    solve = arm._target_errors  # the step's target (and its errors)
    monkeypatch.setattr(arm, "_target_errors", lambda T, d: calls.append(1) or solve(T, d))
    # the runner recomputes the look distance from the moving ring; an exact goal ignores it
    outs = [arm.step(goal, LOOK_DISTANCE_M * (1.0 + 1e-3 * k)) for k in range(HOLD_STEPS)]
    assert len(calls) == 1
    np.testing.assert_allclose(outs[-1].T_world_cam, goal, atol=IK_ATOL)
    moved = goal.copy()
    moved[0, 3] += 1e-3  # a new goal is solved again
    arm.step(moved, LOOK_DISTANCE_M)
    assert len(calls) == 2
