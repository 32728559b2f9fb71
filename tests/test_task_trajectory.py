import math

import numpy as np
import pytest

from endocam.geometry import R_from_euler_xyz, angle_between
from endocam.task.config import TaskConfig, TrajectoryConfig
from endocam.task.touches import clearances, touch_events
from endocam.task.trajectory import (
    ControlPoints,
    RingTrajectory,
    TrajectoryKind,
    angle_offsets,
    control_points,
    ideal_ring_rotations,
    make_trajectory,
    position_offsets,
)
from endocam.task.wire import Wire

ATOL_M = 1e-9  # m
ATOL_RAD = 1e-9  # rad
BEND_TOL_M = 1e-3  # m, clearance lost by a centred ring on the bent wire (≤ R²/2ρ ≈ 0.8 mm)


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


def test_noisy_thresholds_drawn_within_ranges(wire: Wire) -> None:
    cfg = TrajectoryConfig()
    ideal = control_points(wire, 71, TrajectoryKind.IDEAL, cfg)
    assert ideal.position_threshold == 0.0 and ideal.angle_threshold == 0.0
    drawn_p, drawn_a = [], []
    for seed in range(20):
        noisy = control_points(wire, 71, TrajectoryKind.NOISY, cfg, seed=seed)
        lo, hi = cfg.position_noise
        assert lo <= noisy.position_threshold <= hi
        lo, hi = cfg.angle_noise
        assert lo <= noisy.angle_threshold <= hi
        drawn_p.append(noisy.position_threshold)
        drawn_a.append(noisy.angle_threshold)
    # one threshold per trajectory, not a constant: the seeds draw different ones
    assert len(set(drawn_p)) == 20 and len(set(drawn_a)) == 20


def test_noisy_offsets_bounded_by_the_drawn_thresholds(wire: Wire) -> None:
    cfg = TrajectoryConfig()
    ideal = control_points(wire, 71, TrajectoryKind.IDEAL, cfg)
    for seed in range(5):
        noisy = control_points(wire, 71, TrajectoryKind.NOISY, cfg, seed=seed)
        dist = np.linalg.norm(noisy.positions - ideal.positions, axis=1)
        da = np.abs(noisy.euler_xyz - ideal.euler_xyz)
        assert dist.max() <= noisy.position_threshold + ATOL_M
        assert da.max() <= noisy.angle_threshold + ATOL_RAD
        # both signs occur on every axis
        d = noisy.positions - ideal.positions
        assert np.all((d > 0).any(axis=0)) and np.all((d < 0).any(axis=0))


def test_noise_is_a_limit_not_a_magnitude(wire: Wire) -> None:
    # The old reading drew every |offset| in [lo, hi]: no small offsets, and a position moved
    # by ≥ √3·lo. Under the limit reading small offsets are common.
    cfg = TrajectoryConfig()
    ideal = control_points(wire, 71, TrajectoryKind.IDEAL, cfg)
    noisy = control_points(wire, 71, TrajectoryKind.NOISY, cfg, seed=0)
    dist = np.linalg.norm(noisy.positions - ideal.positions, axis=1)
    da = np.abs(noisy.euler_xyz - ideal.euler_xyz)
    assert np.any(dist < cfg.position_noise[0])
    assert np.any(da < cfg.angle_noise[0])


def test_offsets_uniform_in_ball_and_interval() -> None:
    rng = np.random.default_rng(0)
    n = 20_000
    sigmas = 5.0  # unitless, binomial standard deviations allowed
    t_p, dp = position_offsets(rng, (3e-3, 3.5e-3), n)
    t_a, da = angle_offsets(rng, (0.2, 0.5), n)
    assert dp.shape == (n, 3) and da.shape == (n, 3)
    # uniform in the ball: P(|d| < t/2) = 1/8; uniform in [−t, t]: P(|a| < t/2) = 1/2
    for frac, p, k in (
        (np.mean(np.linalg.norm(dp, axis=1) < t_p / 2), 1 / 8, n),
        (np.mean(np.abs(da) < t_a / 2), 1 / 2, 3 * n),
    ):
        assert abs(frac - p) < sigmas * math.sqrt(p * (1 - p) / k)
    # isotropic: no world axis preferred
    np.testing.assert_allclose(np.mean(dp, axis=0), 0.0, atol=sigmas * t_p / math.sqrt(5 * n))
    with pytest.raises(ValueError, match="threshold_range"):
        position_offsets(rng, (3e-3, 2e-3), 3)
    with pytest.raises(ValueError, match="threshold_range"):
        angle_offsets(rng, (-0.1, 0.2), 3)


def test_study_angle_override_bounds_the_angles(wire: Wire) -> None:
    low = (math.radians(5.0), math.radians(10.0))  # the study's easiest trajectory
    cfg = TrajectoryConfig(angle_noise=low)
    ideal = control_points(wire, 36, TrajectoryKind.IDEAL, cfg)
    noisy = control_points(wire, 36, TrajectoryKind.NOISY, cfg, seed=7)
    assert low[0] <= noisy.angle_threshold <= low[1]
    assert np.abs(noisy.euler_xyz - ideal.euler_xyz).max() <= low[1] + ATOL_RAD


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


def test_noisy_paths_start_and_end_clear_of_the_wire(wire: Wire) -> None:
    # issue 11: a touch already under way at t = 0 (the ring starting pushed into the wire) is
    # not an event an assessor can count; every trajectory starts and ends clear of the wire.
    cfg = TaskConfig()
    clear_m = cfg.ring.major_radius - cfg.ring.minor_radius - cfg.wire.radius  # centred ring
    for seed, n in ((0, 36), (1, 71), (2, 71), (3, 36)):
        traj = make_trajectory(cfg, TrajectoryKind.NOISY, n, seed=seed, wire=wire)
        ends, _ = clearances(traj.poses([0.0, traj.duration]), wire, cfg.ring)
        # the wire bends (radius ≥ 16 mm) inside the 5 mm ring: its centre line leaves the ring's
        # centre by up to R²/(2·16 mm) ≈ 0.8 mm, so the centred ring's clearance is within 1 mm
        assert np.all(ends > clear_m - BEND_TOL_M)
        rep = touch_events(traj, wire, cfg.ring, dt=0.01)
        assert rep.count > 0  # still a noisy path with touches
        assert all(0.0 < e.t_start < e.t_end < traj.duration for e in rep.events)
