import math

import numpy as np
import pytest

from endocam.geometry import R_from_euler_xyz, angle_between
from endocam.task.config import TaskConfig, TrajectoryConfig
from endocam.task.trajectory import (
    ControlPoints,
    RingTrajectory,
    TrajectoryKind,
    control_points,
    ideal_ring_rotations,
    make_trajectory,
)
from endocam.task.wire import Wire

ATOL_M = 1e-9  # m
ATOL_RAD = 1e-9  # rad


@pytest.fixture(scope="module")
def wire() -> Wire:
    return Wire(TaskConfig().wire)


@pytest.mark.parametrize("n", [2, 36, 71])
def test_control_points_evenly_spaced(wire: Wire, n: int) -> None:
    cfg = TrajectoryConfig()
    cps = control_points(wire, n, TrajectoryKind.IDEAL, cfg)
    assert len(cps) == n
    ds = np.diff(cps.arc_length)
    np.testing.assert_allclose(ds, (wire.length - 2 * cfg.end_margin) / (n - 1), atol=ATOL_M)
    np.testing.assert_allclose(cps.positions, wire.points(cps.arc_length), atol=ATOL_M)


def test_ideal_ring_centred_normal_along_tangent_handle_up(wire: Wire) -> None:
    cfg = TaskConfig()
    traj = make_trajectory(cfg, TrajectoryKind.IDEAL, 36, wire=wire)
    cps = traj.control_points
    T = traj.poses(traj.times)
    tangents = wire.tangent(cps.arc_length)
    for i in range(len(cps)):
        assert np.linalg.norm(T[i, :3, 3] - wire.point(cps.arc_length[i])) < 1e-9
        assert angle_between(T[i, :3, 2], tangents[i]) < 1e-7
        # handle (ring +x) is the most-upward direction in the ring plane
        x = T[i, :3, 0]
        up_in_plane = np.array([0, 0, 1.0]) - tangents[i][2] * tangents[i]
        assert angle_between(x, up_in_plane) < 1e-7
    np.testing.assert_allclose(R_from_euler_xyz(cps.euler_xyz), T[:, :3, :3], atol=1e-9)


def test_ideal_rotation_falls_back_when_tangent_vertical() -> None:
    class Vertical:
        def tangent(self, s: np.ndarray) -> np.ndarray:
            return np.tile([0.0, 0.0, 1.0], (len(s), 1))

    R = ideal_ring_rotations(Vertical(), np.array([0.0]))  # type: ignore[arg-type]
    np.testing.assert_allclose(R[0], np.eye(3), atol=ATOL_RAD)


def test_noisy_offsets_within_thresholds(wire: Wire) -> None:
    cfg = TrajectoryConfig()
    ideal = control_points(wire, 71, TrajectoryKind.IDEAL, cfg)
    for seed in range(5):
        noisy = control_points(wire, 71, TrajectoryKind.NOISY, cfg, seed=seed)
        dp = np.abs(noisy.positions - ideal.positions)
        da = np.abs(noisy.euler_xyz - ideal.euler_xyz)
        lo, hi = cfg.position_noise
        assert dp.min() >= lo - ATOL_M and dp.max() <= hi + ATOL_M
        lo, hi = cfg.angle_noise
        assert da.min() >= lo - ATOL_RAD and da.max() <= hi + ATOL_RAD
        # both signs occur
        d = noisy.positions - ideal.positions
        assert (d > 0).any() and (d < 0).any()


def test_noise_seeded_and_deterministic(wire: Wire) -> None:
    cfg = TrajectoryConfig()
    a = control_points(wire, 36, TrajectoryKind.NOISY, cfg, seed=3)
    b = control_points(wire, 36, TrajectoryKind.NOISY, cfg, seed=3)
    c = control_points(wire, 36, TrajectoryKind.NOISY, cfg, seed=4)
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.euler_xyz, b.euler_xyz)
    assert not np.array_equal(a.positions, c.positions)
    with pytest.raises(ValueError, match="seed"):
        control_points(wire, 36, TrajectoryKind.NOISY, cfg)


def test_trajectory_passes_through_control_points_and_clamps(wire: Wire) -> None:
    cfg = TaskConfig()
    traj = make_trajectory(cfg, TrajectoryKind.NOISY, 36, seed=1, wire=wire)
    assert traj.duration == cfg.trajectory.duration
    T = traj.poses(traj.times)
    np.testing.assert_allclose(T[:, :3, 3], traj.control_points.positions, atol=ATOL_M)
    np.testing.assert_allclose(T[:, :3, :3], traj.control_points.rotations, atol=1e-9)
    np.testing.assert_allclose(traj.pose(-5.0), traj.pose(0.0))
    np.testing.assert_allclose(traj.pose(1e6), traj.pose(traj.duration))
    assert traj.poses(np.linspace(0, 60, 7)).shape == (7, 4, 4)
    # smooth: velocity continuous, starts and ends at rest
    v = traj.linear_velocity(np.array([0.0, traj.duration]))
    np.testing.assert_allclose(v, 0.0, atol=1e-12)


def test_ring_speed_is_realistic(wire: Wire) -> None:
    traj = make_trajectory(TaskConfig(), TrajectoryKind.IDEAL, 36, wire=wire)
    ts = np.linspace(0, traj.duration, 3001)
    speed = np.linalg.norm(traj.linear_velocity(ts), axis=1)
    mean_speed = np.mean(speed)
    assert 2e-3 < mean_speed < 10e-3  # m/s: a few mm/s, as a trainee moves the ring


def test_bad_input() -> None:
    wire = Wire(TaskConfig().wire)
    with pytest.raises(ValueError, match="n must be"):
        control_points(wire, 1, TrajectoryKind.IDEAL, TrajectoryConfig())
    cps = control_points(wire, 3, TrajectoryKind.IDEAL, TrajectoryConfig())
    with pytest.raises(ValueError, match="duration"):
        RingTrajectory(cps, 0.0)
    with pytest.raises(ValueError, match="euler_xyz"):
        ControlPoints(np.zeros((3, 3)), np.zeros((2, 3)), np.zeros(3))
    with pytest.raises(ValueError):
        TrajectoryKind("wobbly")
    assert math.isclose(cps.arc_length[0], TrajectoryConfig().end_margin)
