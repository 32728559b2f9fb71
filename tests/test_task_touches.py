import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

import reference_touches as reference
from endocam.geometry import make_pose, transform_points
from endocam.task.config import RingConfig, TaskConfig, WireConfig
from endocam.task.touches import (
    _coarse_kernel,
    _coarse_minimiser,
    _contact_point,
    _core_distance_kernel,
    _search_polyline,
    clearance,
    clearances,
    touch_events,
)
from endocam.task.trajectory import TrajectoryKind, make_trajectory
from endocam.task.wire import Wire

ATOL_M = 1e-9  # m, exactness of the clearance on analytic cases
BRUTE_ATOL_M = 1e-6  # m, agreement with a brute-force 5.5 µm polyline
T_TOL_S = 1e-6  # s, event start/end root tolerance
Z0 = 0.03  # m, height of the straight test wire
RING = RingConfig()
R, r = RING.major_radius, RING.minor_radius


@pytest.fixture(scope="module")
def straight() -> Wire:
    # straight wire along world x at height Z0
    xs = (-0.05, -0.02, 0.02, 0.05)
    return Wire(WireConfig(knots=[(x, 0.0, Z0) for x in xs]))


@pytest.fixture(scope="module")
def wire() -> Wire:
    return Wire(TaskConfig().wire)


def ring_facing_x(p: tuple[float, float, float], tilt: float = 0.0) -> np.ndarray:
    """Ring with its normal along world x, tilted by ``tilt`` about world y."""
    # ring axes: z = x_world, x = z_world, y = z × x; then tilt about world y
    R0 = np.column_stack([[0, 0, 1.0], np.cross([1.0, 0, 0], [0, 0, 1.0]), [1.0, 0, 0]])
    c, s = math.cos(tilt), math.sin(tilt)
    Ry = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return make_pose(Ry @ R0, p)


def test_centred_straight_wire_clearance_is_R_minus_radii(straight: Wire) -> None:
    c, _ = clearance(ring_facing_x((0.0, 0.0, Z0)), straight, RING)
    assert abs(c - (R - r - straight.radius)) < ATOL_M


@pytest.mark.parametrize("delta", [0.0, 1e-3, 2.5e-3, 2.9e-3, 3.0e-3, 4.5e-3])
def test_offset_wire_clearance(straight: Wire, delta: float) -> None:
    c, p = clearance(ring_facing_x((0.01, -delta, Z0)), straight, RING)
    expected = R - delta - r - straight.radius
    assert abs(c - expected) < ATOL_M
    if delta > 0:
        # contact point: mid-gap between the wire (y = 0) and the near rim (y = R - delta)
        mid = straight.radius + 0.5 * expected
        np.testing.assert_allclose(p, [0.01, mid, Z0], atol=1e-7)


@pytest.mark.parametrize("tilt_deg", [10.0, 30.0, 50.0, 90.0])
def test_tilted_ring_clearance(straight: Wire, tilt_deg: float) -> None:
    tilt = math.radians(tilt_deg)
    c, _ = clearance(ring_facing_x((0.0, 0.0, Z0), tilt), straight, RING)
    expected = R * math.cos(tilt) - r - straight.radius
    assert abs(c - expected) < ATOL_M


def test_batch_matches_scalar_and_brute_force(wire: Wire) -> None:
    rng = np.random.default_rng(7)
    s = rng.uniform(0.0, wire.length, 20)
    T = np.stack(
        [
            make_pose(
                np.linalg.qr(rng.normal(size=(3, 3)))[0] * np.array([1, 1, 1]),
                wire.point(si) + rng.uniform(-5e-3, 5e-3, 3),
            )
            for si in s
        ]
    )
    T[:, :3, :3] *= np.sign(np.linalg.det(T[:, :3, :3]))[:, None, None]
    c_batch, p_batch = clearances(T, wire, RING)
    dense = wire.polyline(50_001)
    for i in range(len(T)):
        c_one, p_one = clearance(T[i], wire, RING)
        assert abs(c_one - c_batch[i]) < BRUTE_ATOL_M
        if c_one < 5e-3:  # near the wire the closest approach is unique: same contact point
            np.testing.assert_allclose(p_one, p_batch[i], atol=1e-5)
        d = dense - T[i, :3, 3]
        h = d @ T[i, :3, 2]
        rho = np.linalg.norm(d - h[:, None] * T[i, :3, 2], axis=1)
        brute = np.min(np.hypot(h, rho - R)) - r - wire.radius
        assert abs(c_one - brute) < BRUTE_ATOL_M
        assert c_one <= brute + ATOL_M  # the refined minimum is never worse than brute force


@pytest.mark.parametrize("n", [36, 71])
def test_ideal_trajectories_never_touch(wire: Wire, n: int) -> None:
    cfg = TaskConfig()
    traj = make_trajectory(cfg, TrajectoryKind.IDEAL, n, wire=wire)
    rep = touch_events(traj, wire, cfg.ring, dt=0.05)
    assert rep.count == 0
    assert rep.clearance.min() > 0.5 * (R - r - wire.radius)


def test_more_control_points_touch_more_often(wire: Wire) -> None:
    cfg = TaskConfig()
    seeds = range(6)
    counts = {
        n: [
            touch_events(
                make_trajectory(cfg, TrajectoryKind.NOISY, n, seed=seed, wire=wire),
                wire,
                cfg.ring,
                dt=0.05,
            ).count
            for seed in seeds
        ]
        for n in (36, 71)
    }
    assert min(counts[36]) > 0  # noisy paths do touch
    assert np.mean(counts[71]) > np.mean(counts[36])


def test_touches_deterministic_and_consistent(wire: Wire) -> None:
    cfg = TaskConfig()
    traj = make_trajectory(cfg, TrajectoryKind.NOISY, 71, seed=5, wire=wire)
    a = touch_events(traj, wire, cfg.ring, dt=0.01)
    b = touch_events(traj, wire, cfg.ring, dt=0.01)
    assert a.count == b.count > 0
    np.testing.assert_array_equal(a.clearance, b.clearance)
    for ea, eb in zip(a.events, b.events, strict=True):
        assert (ea.t_start, ea.t_end, ea.min_clearance) == (eb.t_start, eb.t_end, eb.min_clearance)
        np.testing.assert_array_equal(ea.p_world_contact, eb.p_world_contact)
    # every in-contact sample lies inside exactly one event, and runs equal events
    runs = np.count_nonzero(np.diff(np.concatenate([[0], a.in_contact.astype(int)])) == 1)
    assert runs == a.count
    np.testing.assert_array_equal(a.in_contact, a.clearance <= 0.0)
    assert np.all(np.diff(a.t) > 0)
    for e in a.events:
        assert e.t_start < e.t_end and e.min_clearance <= 0.0
        inside = (a.t > e.t_start + T_TOL_S) & (a.t < e.t_end - T_TOL_S)
        assert np.all(a.in_contact[inside])
        for t_edge in (e.t_start, e.t_end):
            if 0.0 < t_edge < traj.duration:
                assert abs(clearance(traj.pose(t_edge), wire, cfg.ring)[0]) < 1e-6


def test_noisy_71_point_path_touches_in_discrete_events(wire: Wire) -> None:
    # paper Sec. IV-B: noise introduces "a number of collisions" a viewer can count; the old
    # signed-magnitude reading kept the ring on the wire ~75 % of the time.
    cfg = TaskConfig()
    max_contact = 0.25  # unitless, the ring is in contact at most a quarter of the time
    traj = make_trajectory(cfg, TrajectoryKind.NOISY, 71, seed=0, wire=wire)
    rep = touch_events(traj, wire, cfg.ring, dt=0.01)
    assert rep.count >= 5
    assert 0.0 < rep.contact_fraction <= max_contact
    assert rep.contact_fraction == pytest.approx(
        sum(e.duration for e in rep.events) / traj.duration, abs=T_TOL_S / traj.duration
    )
    assert rep.duration == pytest.approx(traj.duration, abs=T_TOL_S)


def test_contact_fraction_of_an_ideal_path_is_zero(wire: Wire) -> None:
    cfg = TaskConfig()
    traj = make_trajectory(cfg, TrajectoryKind.IDEAL, 36, wire=wire)
    assert touch_events(traj, wire, cfg.ring, dt=0.05).contact_fraction == 0.0


def test_coarse_sampling_misses_no_touch(wire: Wire) -> None:
    cfg = TaskConfig()
    traj = make_trajectory(cfg, TrajectoryKind.NOISY, 71, seed=11, wire=wire)
    fine = touch_events(traj, wire, cfg.ring, dt=0.004)
    coarse = touch_events(traj, wire, cfg.ring, dt=1.5)  # refinement must recover every touch
    assert coarse.count == fine.count
    for ec, ef in zip(coarse.events, fine.events, strict=True):
        assert abs(ec.t_start - ef.t_start) < 1e-5 and abs(ec.t_end - ef.t_end) < 1e-5


def test_bad_input(wire: Wire) -> None:
    with pytest.raises(ValueError, match="T_world_ring"):
        clearance(np.eye(3), wire, RING)
    with pytest.raises(ValueError, match="T_world_ring"):
        clearances(np.eye(4), wire, RING)
    traj = make_trajectory(TaskConfig(), TrajectoryKind.IDEAL, 2, wire=wire)
    with pytest.raises(ValueError, match="dt"):
        touch_events(traj, wire, RING, dt=0.0)


def test_ideal_handle_never_meets_the_wire(wire: Wire) -> None:
    cfg = TaskConfig()
    ring = cfg.ring
    tree = cKDTree(wire.polyline(20_001))  # 14 µm spacing
    x_end = ring.major_radius + ring.handle_length
    # handle axis from the ring's outer rim to its end (where PSM1's jaws are), ring frame
    handle = np.column_stack(
        [np.linspace(ring.major_radius + ring.minor_radius, x_end, 30), np.zeros(30), np.zeros(30)]
    )
    for n in (36, 71):
        traj = make_trajectory(cfg, TrajectoryKind.IDEAL, n, wire=wire)
        for T in traj.poses(np.linspace(0.0, traj.duration, 1201)):
            d, _ = tree.query(transform_points(T, handle))
            assert d.min() > ring.handle_radius + wire.radius + 1e-3


N_COARSE = 300  # count: random coarse searches compared with the numpy arithmetic


@pytest.mark.parametrize("step", [1, 2, 5])
def test_coarse_search_is_the_numpy_argmin(step: int) -> None:
    """The compiled coarse search (branch and bound) picks numpy's argmin of the interpreted
    core distance over the whole window, first of equal values included."""
    wire = Wire(WireConfig())
    pts = wire.search_points
    xyz, reach = _search_polyline(wire, step)
    rng = np.random.default_rng(21 + step)
    m = len(pts)
    for _ in range(N_COARSE):
        n_poses, k = int(rng.integers(1, 20)), int(rng.integers(1, 90))
        start = rng.integers(-5 * step, m + 5 * step, n_poses)
        offsets = step * (np.arange(k) - int(rng.integers(0, k)))
        idx = np.clip(start[:, None] + offsets, 0, m - 1)
        spread = rng.uniform(0.0, 0.01)  # m: centres near the window's points, or far
        c = pts[idx[:, rng.integers(0, k)]] + rng.normal(0.0, spread, (n_poses, 3))
        n = rng.normal(size=(n_poses, 3))
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        major = float(rng.uniform(0.002, 0.02))
        d = reference._core_distance(pts[idx], c[:, None, :], n[:, None, :], major)
        expected = idx[np.arange(n_poses), np.argmin(d, axis=1)]
        got = _coarse_minimiser(xyz, start, offsets, c, n, major, reach)
        np.testing.assert_array_equal(got, expected)  # clipped windows repeat points: ties
        np.testing.assert_array_equal(
            _coarse_kernel.py_func(*xyz, start, offsets, c, n, major, reach), expected
        )


def test_coarse_search_ties_keep_the_first() -> None:
    """Equal least distances keep the first column, as numpy's argmin (synthetic polyline)."""
    x = np.array([1.0, -1.0, 0.0, 3.0])  # m: points 0 and 1 are both 0.5 from the circle
    y, z = np.zeros(4), np.zeros(4)
    c, n = np.zeros((3, 3)), np.tile([0.0, 0.0, 1.0], (3, 1))
    pts = np.column_stack([x, y, z])
    for window, first in (([0, 1, 3], 0), ([3, 1, 0], 1), ([1, 3, 3], 1)):  # middle one first
        idx = np.array([window])
        d = reference._core_distance(pts[idx], c[:1, None, :], n[:1, None, :], 0.5)
        assert idx[0, np.argmin(d[0])] == first
        got = _coarse_kernel(x, y, z, np.zeros(1, np.intp), idx[0], c[:1], n[:1], 0.5, 10.0)
        assert got[0] == first


def _bits(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a, dtype=float).tobytes()


N_DISTANCE = 20_000  # count: random points per form of the compiled core distance


def test_core_distance_kernel_is_the_numpy_arithmetic() -> None:
    """The compiled core distance gives numpy's floats: arrays (``square``), scalars (``pow``)."""
    rng = np.random.default_rng(33)
    k = rng.integers(0, 50, N_DISTANCE)
    c = rng.normal(0.0, 0.02, (50, 3))
    n = rng.normal(size=(50, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    p = c[k] + rng.normal(0.0, 0.01, (N_DISTANCE, 3)) * rng.uniform(0.0, 1.0, (N_DISTANCE, 1))
    p[:50] = c[k[:50]] + 1e-3 * n[k[:50]]  # on the axis: ρ² rounds to ≤ 0 (clamped)
    major = 0.00575
    expected = reference._core_distance(p, c[k], n[k], major)
    assert _bits(_core_distance_kernel(p, c, n, k, major, 0.0)) == _bits(expected)
    # one point at a time (numpy scalars, libm's pow for ``** 2``), as the scalar refinement
    each = range(N_DISTANCE)
    scalar = np.array([reference._core_distance(p[i], c[k[i]], n[k[i]], major) for i in each])
    got = [_core_distance_kernel(p[i : i + 1], c, n, k[i : i + 1], major, 2.0)[0] for i in each]
    assert _bits(np.array(got)) == _bits(scalar)
    assert _bits(expected) != _bits(scalar)  # the forms differ: a kernel must tell them apart


def _same_report(a, b) -> None:
    """Two touch reports are equal bit for bit: samples, clearances, events."""
    assert _bits(a.t) == _bits(b.t)
    assert _bits(a.clearance) == _bits(b.clearance)
    np.testing.assert_array_equal(a.in_contact, b.in_contact)
    assert (a.dt, a.max_point_speed) == (b.dt, b.max_point_speed)
    assert len(a.events) == len(b.events)
    for ea, eb in zip(a.events, b.events, strict=True):
        assert _bits(np.array([ea.t_start, ea.t_end, ea.min_clearance])) == _bits(
            np.array([eb.t_start, eb.t_end, eb.min_clearance])
        )
        assert _bits(ea.p_world_contact) == _bits(eb.p_world_contact)


@pytest.mark.parametrize(
    ("kind", "n", "seeds", "dt"),
    [
        (TrajectoryKind.NOISY, 71, (1, 2, 3), 2e-3),  # the episodes' sampling
        (TrajectoryKind.NOISY, 36, (4, 5), 2e-3),
        (TrajectoryKind.NOISY, 12, (6, 10), 2e-3),  # 2 and 1 events: scalar root calls
        (TrajectoryKind.NOISY, 71, (7, 8), 0.05),  # coarse: deep refinement, few roots
        (TrajectoryKind.NOISY, 36, (9,), 1.5),
        (TrajectoryKind.IDEAL, 71, (None,), 2e-3),
        (TrajectoryKind.IDEAL, 36, (None,), 0.05),
    ],
)
def test_touch_events_are_the_interpreted_detection(
    wire: Wire, kind: TrajectoryKind, n: int, seeds: tuple, dt: float
) -> None:
    """The batched detection gives the samples, clearances and events of the one before."""
    cfg = TaskConfig()
    for seed in seeds:
        traj = make_trajectory(cfg, kind, n, seed, wire=wire)
        _same_report(
            touch_events(traj, wire, cfg.ring, dt), reference.touch_events(traj, wire, cfg.ring, dt)
        )


def test_clearances_are_the_interpreted_ones(wire: Wire) -> None:
    """Batches of every size (scalar Brent up to 4 poses, chunks of 2048) and one pose."""
    cfg = TaskConfig()
    traj = make_trajectory(cfg, TrajectoryKind.NOISY, 71, 3, wire=wire)
    rng = np.random.default_rng(4)
    for count in (1, 2, 4, 5, 16, 2051, 2053):
        T = traj.poses(np.sort(rng.uniform(0.0, traj.duration, count)))
        got, expected = clearances(T, wire, cfg.ring), reference.clearances(T, wire, cfg.ring)
        assert _bits(got[0]) == _bits(expected[0]) and _bits(got[1]) == _bits(expected[1])
    for T in traj.poses(rng.uniform(0.0, traj.duration, 5)):
        got_one, expected_one = clearance(T, wire, cfg.ring), reference.clearance(T, wire, cfg.ring)
        assert got_one[0] == expected_one[0] and _bits(got_one[1]) == _bits(expected_one[1])


def test_contact_point_kernel_is_the_numpy_arithmetic() -> None:
    """Clearances and contact points of random poses, on-axis and on-core points included."""
    rng = np.random.default_rng(12)
    count = 20_000
    R_ring = np.linalg.qr(rng.normal(size=(count, 3, 3)))[0]
    T = np.zeros((count, 4, 4))
    T[:, :3, :3] = R_ring
    T[:, :3, 3] = rng.normal(0.0, 0.05, (count, 3))
    T[:, 3, 3] = 1.0
    p = T[:, :3, 3] + rng.normal(0.0, 0.01, (count, 3)) * rng.uniform(0.0, 1.0, (count, 1))
    p[:20] = T[:20, :3, 3] + rng.normal(0.0, 0.01, (20, 1)) * T[:20, :3, 2]  # on the axis
    p[20:40] = T[20:40, :3, 3]  # at the centre
    T[40:50, :3, :3], T[40:50, :3, 3] = np.eye(3), 0.0
    p[40:50] = [0.5, 0.0, 0.0]  # on the core circle (R = 0.5): q − p is exactly 0
    for ring in (RingConfig(), RingConfig(major_radius=0.5)):
        got = _contact_point(p, T, ring, 0.7e-3)  # on the core: r_w + clearance / 2 ≠ 0
        expected = reference._contact_point(p, T, ring, 0.7e-3)
        assert _bits(got[0]) == _bits(expected[0]) and _bits(got[1]) == _bits(expected[1])
