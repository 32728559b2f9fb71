"""Benchmarks of the robot kinematics: PSM IK and one SimulatedArm control step."""

from __future__ import annotations

from typing import Any

import numpy as np

from endocam.robot import ECM, PSM, SimulatedArm

Q_GOAL = np.array([0.3, -0.2, 0.12, 0.5, 0.3, -0.4])  # rad / m, a mid-workspace pose


def test_psm_forward(benchmark: Any) -> None:
    psm = PSM()
    benchmark(psm.forward, Q_GOAL)


def test_psm_ik(benchmark: Any) -> None:
    psm = PSM()
    T = psm.forward(Q_GOAL)
    seed = Q_GOAL + 0.01
    result = benchmark(psm.solve, T, seed)
    assert result.ok


def test_ecm_ik(benchmark: Any) -> None:
    ecm = ECM()
    q = np.array([0.2, 0.1, 0.1, -0.3])
    T = ecm.forward(q)
    result = benchmark(ecm.solve, T, q)
    assert result.ok


def test_simulated_arm_step(benchmark: Any) -> None:
    """One 1 kHz control step: IK of a moving goal (servo_cp) plus one ruckig update."""
    psm = PSM()
    arm = SimulatedArm(psm, dt=1e-3, q0=Q_GOAL)
    rng = np.random.default_rng(0)
    goals = [psm.forward(Q_GOAL + rng.normal(scale=0.01, size=6)) for _ in range(256)]
    counter = iter(range(10**9))

    def control_step() -> None:
        arm.servo_cp(goals[next(counter) % len(goals)])
        arm.step()

    benchmark(control_step)
