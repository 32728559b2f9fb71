"""Benchmarks of the camera arm's control step (issue 4): IK alone, and one full step.

Run: ``.venv/bin/pytest bench/bench_arm_step.py --benchmark-enable -o addopts=""``
"""

from __future__ import annotations

import numpy as np
from pytest_benchmark.fixture import BenchmarkFixture

from endocam.config import ExperimentConfig
from endocam.sim.arm import ArmKind, CameraArm, natural_pose


def _arm(kind: ArmKind) -> CameraArm:
    cfg = ExperimentConfig()
    T_tip_cam = cfg.episode.T_tip_cam if kind is ArmKind.PSM else np.eye(4)
    return CameraArm(kind, cfg.task.scene.T_world_rcm, T_tip_cam, cfg.episode.limits, 0.01)


def _reachable_goal(arm: CameraArm) -> np.ndarray:
    q = natural_pose(arm.model) + np.array([0.1, 0.1, 0.0, 0.2, 0.2, 0.1][: arm.model.n_joints])
    return arm.camera_pose(q)


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
