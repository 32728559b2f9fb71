"""Benchmarks of the camera arm's control step (issue 4): IK alone, and one full step.

Run: ``.venv/bin/pytest bench/bench_arm_step.py --benchmark-enable -o addopts=""``

Each control step is one IK (closed form), one ruckig joint-limited step and FK. The
``full_control_step`` benchmarks hold one reachable goal; the ``moving_goal`` ones move it every
step along a closed joint-space path; ``unreachable_goal`` asks for views the wrist cannot
bend to, moving every step, so each step also searches the nearest feasible view (warm-started
from the last step's). A held goal reuses its joint target (no IK).
"""

from __future__ import annotations

import itertools
import math
import os

import numpy as np
import pytest
from pytest_benchmark.fixture import BenchmarkFixture

from endocam.config import ExperimentConfig
from endocam.robot.actuator import ActuatorStatus, ArmKind
from endocam.robot.arm import MotionStatus
from endocam.robot.camera_arm import CameraArm, natural_pose

LOOK_DISTANCE_M = 0.05  # m: the controller's default working distance


def _arm(kind: ArmKind) -> CameraArm:
    cfg = ExperimentConfig()
    T_tip_cam = cfg.episode.T_tip_cam if kind is ArmKind.PSM else np.eye(4)
    return CameraArm(kind, cfg.task.scene.T_world_rcm, T_tip_cam, 0.01)


def _reachable_goal(arm: CameraArm) -> np.ndarray:
    q = natural_pose(arm.model) + np.array([0.1, 0.1, 0.0, 0.2, 0.2, 0.1][: arm.model.n_joints])
    return arm.camera_pose(q)


MOVING_GOALS = 500  # count, goals along a closed path in joint space, one per control step
MOVING_AMPLITUDE_RAD = 0.1  # rad (m × 0.1 for the insertion), path amplitude per joint


def _moving_goals(arm: CameraArm) -> list[np.ndarray]:
    """Reachable camera goals on a closed joint-space path: the limiter never comes to rest."""
    q0 = natural_pose(arm.model)
    n = arm.model.n_joints
    scale = np.where(arm.model.prismatic, 0.1, 1.0) * MOVING_AMPLITUDE_RAD
    goals = []
    for k in range(MOVING_GOALS):
        phase = 2.0 * math.pi * k / MOVING_GOALS
        q = q0 + scale * np.sin(phase + np.arange(n))
        goals.append(arm.camera_pose(q))
    return goals


def test_psm_camera_ik(benchmark: BenchmarkFixture) -> None:
    """Closed-form PSM IK of a reachable camera pose (with the T_tip_cam mount)."""
    arm = _arm(ArmKind.PSM)
    T_rcm_cam = arm.model.forward_camera(natural_pose(arm.model) + 0.1, arm.T_tip_cam)
    result = benchmark(arm.model.solve_camera, T_rcm_cam, arm.T_tip_cam, arm.q)
    assert result.ok


def test_psm_full_control_step(benchmark: BenchmarkFixture) -> None:
    """One runner step towards a held goal: its joint target is reused (no IK), ruckig, FK."""
    arm = _arm(ArmKind.PSM)
    goal = _reachable_goal(arm)
    out = benchmark(arm.step, goal, LOOK_DISTANCE_M)
    assert out.reachable


def test_ecm_full_control_step(benchmark: BenchmarkFixture) -> None:
    """One runner step with the ECM (orientation residual, position reached)."""
    arm = _arm(ArmKind.ECM)
    goal = _reachable_goal(arm)
    out = benchmark(arm.step, goal, LOOK_DISTANCE_M)
    assert out.reachable


def test_psm_full_control_step_moving_goal(benchmark: BenchmarkFixture) -> None:
    """One runner step towards a goal that moves every step."""
    arm = _arm(ArmKind.PSM)
    goals = itertools.cycle(_moving_goals(arm))
    for _ in range(MOVING_GOALS):  # settle onto the path
        arm.step(next(goals), LOOK_DISTANCE_M)
    out = benchmark(lambda: arm.step(next(goals), LOOK_DISTANCE_M))
    assert out.reachable
    assert arm.arm.motion_status is MotionStatus.MOVING


def test_ecm_full_control_step_moving_goal(benchmark: BenchmarkFixture) -> None:
    """One ECM runner step towards a goal that moves every step."""
    arm = _arm(ArmKind.ECM)
    goals = itertools.cycle(_moving_goals(arm))
    for _ in range(MOVING_GOALS):
        arm.step(next(goals), LOOK_DISTANCE_M)
    out = benchmark(lambda: arm.step(next(goals), LOOK_DISTANCE_M))
    assert out.reachable


def _side_views(arm: CameraArm) -> list[np.ndarray]:
    """Views of one point from ~90° beside the mid-range camera, swaying ±5° (a closed cycle)."""
    T = arm.camera_pose(natural_pose(arm.model))
    c = T[:3, 3] + LOOK_DISTANCE_M * T[:3, 2]
    goals = []
    for k in range(MOVING_GOALS):
        a = math.radians(90.0 + 5.0 * math.sin(2.0 * math.pi * k / MOVING_GOALS))
        R_side = np.array(
            [[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]]
        )
        goal = T.copy()
        goal[:3, :3] = T[:3, :3] @ R_side
        goal[:3, 3] = c - LOOK_DISTANCE_M * goal[:3, 2]  # the same point, seen from the side
        goals.append(goal)
    return goals


def test_psm_full_control_step_unreachable_goal(benchmark: BenchmarkFixture) -> None:
    """A goal that needs more wrist bend than ±80°, moving every step: the view search runs
    each step, warm-started from the last one."""
    arm = _arm(ArmKind.PSM)
    goals = itertools.cycle(_side_views(arm))
    for _ in range(MOVING_GOALS):
        arm.step(next(goals), LOOK_DISTANCE_M)
    out = benchmark(lambda: arm.step(next(goals), LOOK_DISTANCE_M))
    assert out.status is ActuatorStatus.VIEW


RENDER_FPS_TARGET = 30.0  # frames/s at 640x480 (issue 3), with the arm drawn


@pytest.mark.parametrize("kind", [ArmKind.PSM, ArmKind.ECM])
def test_render_frame_with_arm_640x480(benchmark: BenchmarkFixture, kind: ArmKind) -> None:
    """One video frame of an arm episode: pose ring, camera and arm links, render the left eye."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    from endocam.sim.render import WireChaserScene

    cfg = ExperimentConfig()
    arm = _arm(kind)
    goals = _moving_goals(arm)
    qs = [arm.step(g, LOOK_DISTANCE_M).q for g in goals[:50]]
    cams = [arm.camera_pose(q) for q in qs]
    frames = itertools.cycle(range(len(qs)))
    with WireChaserScene(cfg.task, cfg.camera.stereo(), arm=kind) as scene:

        def frame() -> np.ndarray:
            i = next(frames)
            scene.set_camera_pose(cams[i])
            scene.set_arm_joints(qs[i])
            return scene.render("left")

        image = benchmark(frame)
    assert image.shape == (cfg.camera.height, cfg.camera.width, 3)
