"""One full control step of each moving policy: windows, goal, planner, cone and command.

Run: make bench, or
  .venv/bin/pytest bench/bench_control.py --benchmark-enable -o addopts="" -p no:cacheprovider
Targets: median under 50 µs for the paper's policies (issue 2), under 100 µs for endocam's
(issue 10), so a 100 Hz loop spends under 1 % of its period in the controller.
"""

from __future__ import annotations

import numpy as np
import pytest

from endocam import ControllerConfig, StereoCamera, look_at_pose, make_policy
from endocam.control.types import CameraCommand, Observation, PolicyContext
from endocam.geometry import make_pose

DT = 0.001  # s, 1 kHz


def _ring(p, n):
    z = np.asarray(n, float) / np.linalg.norm(n)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    return make_pose(np.column_stack([x, np.cross(z, x), z]), p)


def _setup(name: str, planning: bool):
    """The policy settled (or just after a goal jump) and a step function for the benchmark.

    Every observation is one control period later than the last: the ring gate rejects a ring
    pose that does not advance in time (a Δt of 0), so a repeated observation would benchmark
    the hold path instead of the step.
    """
    cam = StereoCamera()
    ring = _ring([0.0, 0.0, 0.05], [1.0, 0.2, 0.3])
    tips = np.array([[0.0, 0.0, 0.05], [0.01, 0.01, 0.04]])
    overview = look_at_pose([0.0, -0.15, 0.25], ring[:3, 3])
    cfg = ControllerConfig(cone_height=0.5, cone_base_radius=0.5)
    policy = make_policy(name, cfg)
    policy.reset(PolicyContext(cam, overview, ring, np.array([0.0, -0.05, 0.3]), DT))
    # Settle with an ideal camera that follows every command; "planning" benchmarks the steps
    # right after a goal jump (the camera stays far from the goal and follows way-points).
    T_cam = overview
    k = 0
    for k in range(1, 1 if planning else 6001):
        T_cam = policy.step(Observation(k * DT, ring, T_cam, tips)).T_world_cam
    clock = [k]
    expected = "planning" if planning else "tracking"

    def step() -> CameraCommand:
        clock[0] += 1
        cmd = policy.step(Observation(clock[0] * DT, ring, T_cam, tips))
        assert cmd.state.value == expected, cmd.reason
        return cmd

    step()
    return step


@pytest.mark.parametrize("planning", [False, True], ids=["tracking", "planning"])
@pytest.mark.parametrize("name", ["centering", "orientation"])
def test_control_step(benchmark, name: str, planning: bool) -> None:
    cmd = benchmark(_setup(name, planning))
    assert np.all(np.isfinite(cmd.T_world_cam))


def test_endocam_tracking_step(benchmark) -> None:
    """endocam's step while tracking: windows, prediction, side keeping, goal and twist."""
    cmd = benchmark(_setup("endocam", planning=False))
    assert np.all(np.isfinite(cmd.T_world_cam))
