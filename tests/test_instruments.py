"""Where the instruments are: PSM1 grips the ring's handle, PSM2 idles beside the work."""

from __future__ import annotations

import math

import numpy as np
import pytest

from endocam.camera import StereoCamera
from endocam.control.config import ControllerConfig
from endocam.control.goal import goal_pose
from endocam.control.windows import WindowStatus, window_status
from endocam.geometry import transform_points
from endocam.task.config import Psm2Idle, TaskConfig
from endocam.task.instruments import instrument_tips, lagged_path
from endocam.task.layout import psm1_tip_in_ring
from endocam.task.trajectory import TrajectoryKind, make_trajectory
from endocam.task.wire import Wire

TASK = TaskConfig()
FIXED = TaskConfig.model_validate({"instruments": {"psm2_idle": "fixed"}})
ATOL_M = 1e-12  # m, float round-off on mm-sized positions
DT = 0.05  # s, sample spacing of the test episodes
PSM2_WIRE_CLEARANCE = 0.010  # m: the idle instrument stays at least 1 cm from the wire
LAG_RTOL = 1e-9  # relative, exact discretisation of the first-order lag
FIXED_OUTSIDE_FRACTION = 0.25  # the old world: PSM2 leaves the outer window this often or more


def _episode(task: TaskConfig, kind: TrajectoryKind, points: int, seed: int = 0):
    traj = make_trajectory(task, kind, points, seed)
    t = np.arange(0.0, traj.duration + 1e-9, DT)
    T = traj.poses(t)
    return t, T, instrument_tips(task, t, T)


def test_psm1_grips_the_handle() -> None:
    _, T, tips = _episode(TASK, TrajectoryKind.NOISY, 71, 1)
    tip = psm1_tip_in_ring(TASK.ring, TASK.instruments)
    expected = np.array([transform_points(Tk, tip) for Tk in T])
    np.testing.assert_allclose(tips[:, 0], expected, atol=ATOL_M)


def test_fixed_psm2_waits_at_its_tip() -> None:
    _, _, tips = _episode(FIXED, TrajectoryKind.IDEAL, 36)
    np.testing.assert_allclose(
        tips[:, 1], np.broadcast_to(FIXED.instruments.psm2_tip, (len(tips), 3))
    )


def test_lag_is_the_exact_first_order_response() -> None:
    tau = 0.7  # s
    t = np.linspace(0.0, 3.0, 50)  # s, a control grid
    p = np.zeros((50, 3))
    p[1:] = [0.01, -0.02, 0.005]  # a step right after t = 0
    q = lagged_path(t, p, tau)
    np.testing.assert_allclose(q[0], 0.0)
    expected = p[1] * (1.0 - np.exp(-(t[1:] - t[0]) / tau))[:, None]
    np.testing.assert_allclose(q[1:], expected, rtol=LAG_RTOL)
    with pytest.raises(ValueError, match="time_constant"):
        lagged_path(t, p, 0.0)
    with pytest.raises(ValueError, match="non-decreasing"):
        lagged_path(t[::-1], p, tau)
    uneven = np.sort(np.random.default_rng(0).uniform(0.0, 3.0, 50))
    with pytest.raises(ValueError, match="evenly spaced"):
        lagged_path(uneven, p, tau)


@pytest.mark.parametrize(("kind", "points", "seed"), [("ideal", 71, 0), ("noisy", 71, 1)])
def test_following_psm2_stays_clear_of_the_wire_and_board(
    kind: str, points: int, seed: int
) -> None:
    _, _, tips = _episode(TASK, TrajectoryKind(kind), points, seed)
    wire = Wire(TASK.wire)
    clearance = min(wire.closest(p)[1] for p in tips[:, 1]) - TASK.wire.radius
    assert clearance > PSM2_WIRE_CLEARANCE
    assert np.all(tips[:, 1, 2] > PSM2_WIRE_CLEARANCE)


def _psm2_outside_outer(task: TaskConfig) -> float:
    """Fraction of an ideal 71-point episode with PSM2 outside the outer window of a camera on
    the ring normal at the initial working distance (the paper's goal, side above the ring)."""
    ctrl = ControllerConfig()
    camera = StereoCamera()
    _, T, tips = _episode(task, TrajectoryKind.IDEAL, 71)
    outside = [
        window_status(camera, goal_pose(Tk[:3, 3], Tk[:3, 2], ctrl.d_f), tip[1:], ctrl.windows)
        is WindowStatus.OUTSIDE_OUTER
        for Tk, tip in zip(T, tips, strict=True)
    ]
    return float(np.mean(outside))


def test_following_psm2_stays_in_the_outer_window_of_the_tracking_camera() -> None:
    assert TASK.instruments.psm2_idle is Psm2Idle.FOLLOW
    assert _psm2_outside_outer(TASK) == 0.0
    # the fact depends on the idle behaviour: PSM2 parked at its fixed tip leaves the window
    assert _psm2_outside_outer(FIXED) > FIXED_OUTSIDE_FRACTION


def test_psm2_follow_time_validated() -> None:
    with pytest.raises(ValueError, match="psm2_follow_time"):
        TaskConfig.model_validate({"instruments": {"psm2_follow_time": -1.0}})
    assert math.isclose(TASK.instruments.psm2_follow_time, 1.0)
