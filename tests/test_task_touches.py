import math

import numpy as np
import pytest
from scipy.optimize import minimize_scalar
from scipy.spatial import cKDTree

from endocam.geometry import make_pose, transform_points
from endocam.task.config import RingConfig, TaskConfig, WireConfig
from endocam.task.study_paths import (
    DEFAULT_STUDY_SEED,
    STUDY_TRAJECTORIES,
    study_task_config,
    study_trajectory_seeds,
)
from endocam.task.touches import (
    DEPTH_TOL,
    T_TOL,
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
SCIPY_ATOL_M = 1e-8  # m, agreement with scipy's bounded minimiser on the spline (xatol 1e-10 m)
CONTACT_ATOL_M = 1e-7  # m, contact points: the clearance's tolerance over a ~1 mm lever
CORE_ATOL_M = 1e-10  # m, the core distance's round-off: on the ring's axis ρ = √(|d|² − h²)
# loses half its digits (√ of ~1e-22 m² of round-off), elsewhere ~1e-18 m
KERNEL_ATOL_M = 1e-12  # m, the contact kernel against the numpy formula away from its axis
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


N_COARSE = 300  # count: random coarse searches compared with numpy's argmin


def _core_distance(p: np.ndarray, c: np.ndarray, n: np.ndarray, major: float) -> np.ndarray:
    """Distance, m, of points ``p`` (..., 3) to the core circles (centres ``c``, normals ``n``).

    numpy, written from the module docstring: ``√(h² + (ρ − R)²)``, ``ρ = |d − h n|``.
    """
    d = p - c
    h = np.sum(d * n, axis=-1)
    rho = np.linalg.norm(d - h[..., None] * n, axis=-1)
    return np.hypot(h, rho - major)


@pytest.mark.parametrize("step", [1, 2, 5])
def test_coarse_search_is_the_numpy_argmin(step: int) -> None:
    """The compiled coarse search (branch and bound) finds the least core distance of the window.

    Whatever it skips, the point it returns is as near as numpy's argmin over the whole window
    (to round-off; equal distances may pick either).
    """
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
        d = _core_distance(pts[idx], c[:, None, :], n[:, None, :], major)
        got = _coarse_minimiser(xyz, start, offsets, c, n, major, reach)
        assert np.all(np.any(idx == got[:, None], axis=1))  # a point of each pose's window
        d_got = _core_distance(pts[got], c, n, major)
        np.testing.assert_allclose(d_got, d.min(axis=1), rtol=0.0, atol=CORE_ATOL_M)


def test_coarse_search_ties_keep_the_first() -> None:
    """Equal least distances keep the first column, as numpy's argmin (synthetic polyline)."""
    x = np.array([1.0, -1.0, 0.0, 3.0])  # m: points 0 and 1 are both 0.5 from the circle
    y, z = np.zeros(4), np.zeros(4)
    c, n = np.zeros((3, 3)), np.tile([0.0, 0.0, 1.0], (3, 1))
    for window, first in (([0, 1, 3], 0), ([3, 1, 0], 1), ([1, 3, 3], 1)):  # middle one first
        idx = np.array([window])
        got = _coarse_kernel(x, y, z, np.zeros(1, np.intp), idx[0], c[:1], n[:1], 0.5, 10.0)
        assert got[0] == first


def test_core_distance_kernel_is_the_numpy_formula() -> None:
    """Random points near random circles, points on the axis included (ρ² clamped at 0)."""
    rng = np.random.default_rng(33)
    count = 20_000
    k = rng.integers(0, 50, count)
    c = rng.normal(0.0, 0.02, (50, 3))
    n = rng.normal(size=(50, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    p = c[k] + rng.normal(0.0, 0.01, (count, 3)) * rng.uniform(0.0, 1.0, (count, 1))
    p[:50] = c[k[:50]] + 1e-3 * n[k[:50]]  # on the axis
    major = 0.00575
    got = _core_distance_kernel(p, c, n, k, major)
    np.testing.assert_allclose(got, _core_distance(p, c[k], n[k], major), rtol=0, atol=CORE_ATOL_M)
    np.testing.assert_allclose(got[:50], math.hypot(1e-3, major), rtol=0, atol=CORE_ATOL_M)


def test_contact_point_kernel_is_the_numpy_formula() -> None:
    """Clearances and contact points of random poses, on-axis and on-core points included."""
    rng = np.random.default_rng(12)
    count = 20_000
    R_ring = np.linalg.qr(rng.normal(size=(count, 3, 3)))[0]
    T = np.zeros((count, 4, 4))
    T[:, :3, :3] = R_ring
    T[:, :3, 3] = rng.normal(0.0, 0.05, (count, 3))
    T[:, 3, 3] = 1.0
    p = T[:, :3, 3] + rng.normal(0.0, 0.01, (count, 3)) * rng.uniform(0.0, 1.0, (count, 1))
    along = rng.normal(0.0, 0.01, (20, 1))
    p[:20] = T[:20, :3, 3] + along * T[:20, :3, 2]  # on the axis: radial along the ring's x
    p[20:40] = T[20:40, :3, 3]  # at the centre
    T[40:50, :3, :3], T[40:50, :3, 3] = np.eye(3), 0.0
    p[40:50] = [0.5, 0.0, 0.0]  # on the core circle (R = 0.5): the gap is along n
    wire_radius = 0.7e-3  # m; on the core: r_w + clearance / 2 ≠ 0
    for ring in (RingConfig(), RingConfig(major_radius=0.5)):
        major, minor = ring.major_radius, ring.minor_radius
        got_c, got_p = _contact_point(p, T, ring, wire_radius)
        c, n = T[:, :3, 3], T[:, :3, 2]
        d = p - c
        radial = d - np.sum(d * n, axis=1)[:, None] * n
        rho = np.linalg.norm(radial, axis=1)
        on_axis = rho < 1e-9
        radial[on_axis], rho[on_axis] = T[on_axis, :3, 0], 1.0
        gap = c + major * radial / rho[:, None] - p
        dist = np.linalg.norm(gap, axis=1)
        want_c = dist - minor - wire_radius
        on_core = dist < 1e-9
        gap[on_core], dist[on_core] = n[on_core], 1.0
        want_p = p + gap / dist[:, None] * (wire_radius + 0.5 * want_c)[:, None]
        # on the axis the radial direction is round-off: those points are checked apart
        regular = ~on_axis
        regular[:40] = False
        np.testing.assert_allclose(got_c[regular], want_c[regular], rtol=0, atol=KERNEL_ATOL_M)
        np.testing.assert_allclose(got_p[regular], want_p[regular], rtol=0, atol=KERNEL_ATOL_M)
        # on the axis every core point is as near: the clearance is √(h² + R²) − r − r_w
        h = np.sum((p[:40] - c[:40]) * n[:40], axis=1)
        np.testing.assert_allclose(
            got_c[:40], np.hypot(h, major) - minor - wire_radius, rtol=0, atol=CORE_ATOL_M
        )
    # on the core circle (the last ring): the gap along n, half-way across the overlap
    scale = wire_radius + 0.5 * (-minor - wire_radius)
    np.testing.assert_allclose(got_p[40:50], p[40:50] + scale * np.array([0.0, 0.0, 1.0]))


def _scipy_clearance(T: np.ndarray, wire: Wire, ring: RingConfig) -> tuple[float, np.ndarray]:
    """Clearance and contact point of one ring pose: a dense scan, then scipy's minimiser.

    The wire's spline sampled every ~1.5 µm (the core distance is smooth between), the best
    sample's neighbourhood refined by ``minimize_scalar`` (bounded, xatol 1e-10 m).
    """
    c, n = T[:3, 3], T[:3, 2]
    s = np.linspace(0.0, wire.length, 200_001)
    d = _core_distance(wire.points(s), c, n, ring.major_radius)
    j = int(np.argmin(d))
    lo, hi = s[max(j - 1, 0)], s[min(j + 1, s.size - 1)]
    res = minimize_scalar(
        lambda x: float(_core_distance(wire.point(x), c, n, ring.major_radius)),
        bounds=(lo, hi),
        method="bounded",
        options={"xatol": 1e-10},
    )
    s_best = float(res.x) if res.fun <= d[j] else float(s[j])
    p_wire = wire.point(s_best)
    dist = float(_core_distance(p_wire, c, n, ring.major_radius))
    cl = dist - ring.minor_radius - wire.radius
    # the core point nearest the wire point, and the contact point half-way across the gap
    radial = (p_wire - c) - ((p_wire - c) @ n) * n
    q = c + ring.major_radius * radial / np.linalg.norm(radial)
    return cl, p_wire + (q - p_wire) / dist * (wire.radius + 0.5 * cl)


def test_clearances_are_scipys_minimum_for_any_batch(wire: Wire) -> None:
    """Batches of every size (scalar Brent up to 4 poses, chunks of 2048) and one pose."""
    cfg = TaskConfig()
    traj = make_trajectory(cfg, TrajectoryKind.NOISY, 71, 3, wire=wire)
    rng = np.random.default_rng(4)
    t_all = np.sort(rng.uniform(0.0, traj.duration, 2053))
    T_all = traj.poses(t_all)
    c_all, p_all = clearances(T_all, wire, cfg.ring)
    for count in (1, 2, 4, 5, 16, 2051):
        pick = np.sort(rng.choice(t_all.size, count, replace=False))
        c_some, p_some = clearances(T_all[pick], wire, cfg.ring)
        np.testing.assert_allclose(c_some, c_all[pick], rtol=0, atol=ATOL_M)
        np.testing.assert_allclose(p_some, p_all[pick], rtol=0, atol=CONTACT_ATOL_M)
    near = np.argsort(c_all)[:6]  # the closest approaches (touches), and a few others
    for i in [*near.tolist(), *rng.choice(t_all.size, 4, replace=False).tolist()]:
        want_c, want_p = _scipy_clearance(T_all[i], wire, cfg.ring)
        assert math.isclose(c_all[i], want_c, rel_tol=0, abs_tol=SCIPY_ATOL_M)
        assert c_all[i] <= want_c + ATOL_M  # never worse than the independent minimum
        np.testing.assert_allclose(p_all[i], want_p, rtol=0, atol=CONTACT_ATOL_M)
        one_c, one_p = clearance(T_all[i], wire, cfg.ring)
        assert math.isclose(one_c, want_c, rel_tol=0, abs_tol=SCIPY_ATOL_M)
        np.testing.assert_allclose(one_p, want_p, rtol=0, atol=CONTACT_ATOL_M)


DENSE_DT = 1e-3  # s: the independent scan's sampling (the detector samples every 2 ms)


@pytest.mark.parametrize(("n", "seed"), [(71, 1), (36, 4), (12, 6)])
def test_touch_events_miss_no_touch_and_add_up(wire: Wire, n: int, seed: int) -> None:
    """Against a dense independent scan: every overlap deeper than DEPTH_TOL lies in an event.

    And the report is consistent: events ordered and disjoint, their start and end where the
    clearance crosses zero, the contact flags the clearance's sign, the fraction their sum.
    """
    cfg = TaskConfig()
    traj = make_trajectory(cfg, TrajectoryKind.NOISY, n, seed, wire=wire)
    rep = touch_events(traj, wire, cfg.ring, cfg.trajectory.touch_sample_dt)
    t = np.arange(0.0, traj.duration, DENSE_DT)
    c, _ = clearances(traj.poses(t), wire, cfg.ring)
    inside = np.zeros(t.size, dtype=bool)
    for e in rep.events:
        inside |= (t >= e.t_start - T_TOL) & (t <= e.t_end + T_TOL)
    assert not np.any((c < -DEPTH_TOL) & ~inside), "a touch was missed"
    assert not np.any((c > DEPTH_TOL) & inside & _away_from_edges(t, rep)), "a gap inside a touch"
    starts = np.array([e.t_start for e in rep.events])
    ends = np.array([e.t_end for e in rep.events])
    assert np.all(starts < ends) and np.all(ends[:-1] < starts[1:])
    assert all(e.min_clearance <= 0.0 for e in rep.events)
    np.testing.assert_array_equal(rep.in_contact, rep.clearance <= 0.0)
    assert rep.count == len(rep.events) > 0
    assert rep.contact_fraction == pytest.approx(np.sum(ends - starts) / traj.duration)
    # each event's deepest point is a sample's, and its contact point that sample's
    for e in rep.events:
        k = int(np.argmin(np.abs(rep.clearance - e.min_clearance)))
        assert e.t_start - T_TOL <= rep.t[k] <= e.t_end + T_TOL


def _away_from_edges(t: np.ndarray, rep) -> np.ndarray:
    """Times farther than T_TOL from every event's start and end."""
    far = np.ones(t.size, dtype=bool)
    for e in rep.events:
        for edge in (e.t_start, e.t_end):
            far &= np.abs(t - edge) > T_TOL
    return far


# The study's touch counts (paper Sec. IV-B: noise makes "a number of collisions"): a
# regression on the ground truth the study's videos are scored against, its three trajectories
# at the default seed (60 s each).
STUDY_TOUCH_COUNTS = {"t1-36-low": 9, "t2-36-high": 10, "t3-71-high": 17}


@pytest.mark.parametrize("index", range(len(STUDY_TRAJECTORIES)))
def test_touch_counts_of_the_studys_trajectories_are_unchanged(wire: Wire, index: int) -> None:
    path = STUDY_TRAJECTORIES[index]
    seed = study_trajectory_seeds(DEFAULT_STUDY_SEED)[index]
    cfg = study_task_config(TaskConfig(), path)
    traj = make_trajectory(cfg, TrajectoryKind.NOISY, path.control_points, seed, wire=wire)
    rep = touch_events(traj, wire, cfg.ring, cfg.trajectory.touch_sample_dt)
    assert rep.count == STUDY_TOUCH_COUNTS[path.name]
