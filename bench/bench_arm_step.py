"""Benchmarks of the camera arm's control step (issue 4): IK alone, and one full step.

Run: ``.venv/bin/pytest bench/bench_arm_step.py --benchmark-enable -o addopts=""``

The ``full_control_step`` benchmarks hold one goal (after the first steps the limiter rests on
it and the second IK is skipped); the ``moving_goal`` ones move the goal every step, so the
limiter is always moving and both IK solves run.
"""

from __future__ import annotations

import itertools
import math
import os

import numpy as np
import pytest
from pytest_benchmark.fixture import BenchmarkFixture

from endocam.config import ExperimentConfig
from endocam.sim.arm import ArmKind, CameraArm, natural_pose
from endocam.sim.motion import MotionStatus


def _arm(kind: ArmKind) -> CameraArm:
    cfg = ExperimentConfig()
    T_tip_cam = cfg.episode.T_tip_cam if kind is ArmKind.PSM else np.eye(4)
    return CameraArm(kind, cfg.task.scene.T_world_rcm, T_tip_cam, cfg.episode.limits, 0.01)


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
    """One runner step: goal IK, Cartesian limiter (ruckig), IK, joint ruckig step, FK."""
    arm = _arm(ArmKind.PSM)
    goal = _reachable_goal(arm)
    out = benchmark(arm.step, goal)
    assert out.reachable


def test_ecm_full_control_step(benchmark: BenchmarkFixture) -> None:
    """One runner step with the ECM (orientation residual, position reached)."""
    arm = _arm(ArmKind.ECM)
    goal = _reachable_goal(arm)
    out = benchmark(arm.step, goal)
    assert out.reachable


def test_psm_full_control_step_moving_goal(benchmark: BenchmarkFixture) -> None:
    """One runner step towards a goal that moves every step (both IK solves run)."""
    arm = _arm(ArmKind.PSM)
    goals = itertools.cycle(_moving_goals(arm))
    for _ in range(MOVING_GOALS):  # settle onto the path
        arm.step(next(goals))
    out = benchmark(lambda: arm.step(next(goals)))
    assert out.reachable
    assert arm._limiter.status is MotionStatus.MOVING  # the second IK ran


def test_ecm_full_control_step_moving_goal(benchmark: BenchmarkFixture) -> None:
    """One ECM runner step towards a goal that moves every step."""
    arm = _arm(ArmKind.ECM)
    goals = itertools.cycle(_moving_goals(arm))
    for _ in range(MOVING_GOALS):
        arm.step(next(goals))
    out = benchmark(lambda: arm.step(next(goals)))
    assert out.reachable


RENDER_FPS_TARGET = 30.0  # frames/s at 640x480 (issue 3), with the arm drawn


@pytest.mark.parametrize("kind", [ArmKind.PSM, ArmKind.ECM])
def test_render_frame_with_arm_640x480(benchmark: BenchmarkFixture, kind: ArmKind) -> None:
    """One video frame of an arm episode: pose ring, camera and arm links, render the left eye."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    from endocam.sim.render import WireChaserScene

    cfg = ExperimentConfig()
    arm = _arm(kind)
    goals = _moving_goals(arm)
    qs = [arm.step(g).q for g in goals[:50]]
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
