"""The camera-wire clearance: goals, episodes on every carrier, degenerate inputs."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from endocam import kernels
from endocam.camera import StereoCamera
from endocam.config import ExperimentConfig
from endocam.control import detour, escape
from endocam.control.clearance import WIRE_CLEARANCE, ClearanceGuard
from endocam.control.goal import goal_pose
from endocam.control.policies import DETOUR_REASON, STALL_STEPS, WIRE_REASON, OrientationPolicy
from endocam.control.types import Observation, PolicyContext, TrackingState
from endocam.geometry import invert_pose, make_pose
from endocam.robot.actuator import ArmKind
from endocam.runner.episode import EpisodeSpec, run_episode
from endocam.runner.experiments import paper_paths
from endocam.task.config import WireConfig
from endocam.task.trajectory import TrajectoryKind
from endocam.task.wire import Wire
from endocam.view import look_at_pose, look_at_unchecked, pose_from_columns, rotation_columns
from endocam.workspace.region import Workspace

GRID = np.linspace(0.1, 0.9, 81)  # unitless, ring positions as fractions of the wire's length
ROUND_M = 1e-9  # m, round-off of a rebuilt pose
CAMERA_CLEARANCE_M = 6e-3 + 2e-3  # m: the 12 mm endoscope's radius + the 2 mm margin


def _random_wire(seed: int) -> Wire:
    """A wire through 4-6 random knots over a 0.2 m span, 20-60 mm above the board."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(4, 7))
    x = np.linspace(-0.1, 0.1, n)
    y = rng.uniform(-0.04, 0.04, n)
    z = rng.uniform(0.02, 0.06, n)
    return Wire(WireConfig(knots=tuple(map(tuple, np.column_stack([x, y, z]).tolist()))))


def _exact_surface_distance(wire: Wire, p: np.ndarray) -> float:
    """Distance of a point to the tube surface by exact minimisation on the spline, m."""
    return wire.closest(p)[1] - wire.radius


def test_default_is_the_scope_radius_plus_margin() -> None:
    assert WIRE_CLEARANCE == pytest.approx(CAMERA_CLEARANCE_M, abs=ROUND_M)


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    s_frac=st.floats(0.15, 0.85),
    tilt=st.floats(0.0, 0.5),
    d_f=st.floats(0.03, 0.08),
)
def test_goal_never_closer_than_the_clearance(
    seed: int, s_frac: float, tilt: float, d_f: float
) -> None:
    """Ring on a random wire, normal near its tangent: the guarded goal keeps the clearance."""
    wire = _random_wire(seed)
    rng = np.random.default_rng(seed + 1)
    s = s_frac * wire.length
    p_c = wire.point(s)
    side = np.cross(wire.tangent(s), rng.normal(size=3))
    n = wire.tangent(s) + tilt * side / np.linalg.norm(side)
    T = goal_pose(p_c, n, d_f)
    guard = ClearanceGuard(wire, CAMERA_CLEARANCE_M)
    out = guard.apply(T, tuple(p_c.tolist()))
    assert out is not None, "a ring on the wire always has a clear view within 90°"
    slack = 0.5 * wire.search_spacing + ROUND_M  # the guard measures to the search polyline
    assert _exact_surface_distance(wire, out[:3, 3]) >= CAMERA_CLEARANCE_M - slack
    # the ring centre keeps its place in the camera's frame (centred, same look distance)
    p_cam = invert_pose(T) @ np.append(p_c, 1.0)
    np.testing.assert_allclose(invert_pose(out) @ np.append(p_c, 1.0), p_cam, atol=1e-7)
    # a level horizon: the image x axis stays horizontal
    assert abs(out[2, 0]) < 1e-7
    if _exact_surface_distance(wire, T[:3, 3]) >= CAMERA_CLEARANCE_M + slack:
        np.testing.assert_array_equal(out, T)  # a clear goal passes unchanged


def test_back_off_keeps_the_view_direction() -> None:
    wire = Wire(WireConfig())
    # the ring where the on-tangent view at 50 mm comes closest to the wire (a bend)
    goals = [goal_pose(wire.point(s), wire.tangent(s), 0.05) for s in wire.length * GRID]
    k = int(np.argmin(wire.surface_distance(np.array([T[:3, 3] for T in goals]))))
    T, p_c = goals[k], wire.point(wire.length * GRID[k])
    guard = ClearanceGuard(wire, CAMERA_CLEARANCE_M)
    out = guard.apply(T, tuple(p_c.tolist()), back_off=0.03)
    assert out is not None
    assert _exact_surface_distance(wire, out[:3, 3]) >= CAMERA_CLEARANCE_M - wire.search_spacing
    np.testing.assert_allclose(out[:3, :3], T[:3, :3], atol=ROUND_M)
    assert _exact_surface_distance(wire, T[:3, 3]) < CAMERA_CLEARANCE_M  # it had to move


def test_non_finite_inputs_give_no_pose() -> None:
    wire = Wire(WireConfig())
    guard = ClearanceGuard(wire, CAMERA_CLEARANCE_M)
    T = look_at_pose([0.0, -0.1, 0.1], [0.0, 0.0, 0.03])
    bad = T.copy()
    bad[0, 3] = math.nan
    assert guard.apply(bad, (0.0, 0.0, 0.03)) is None
    assert guard.apply(T, (math.nan, 0.0, 0.03)) is None
    assert math.isnan(guard.margin([math.nan, 0.0, 0.0]))
    with pytest.raises(ValueError, match="clearance"):
        ClearanceGuard(wire, -1e-3)


def test_policy_holds_its_last_pose_when_no_view_is_clear() -> None:
    """A clearance no view can keep: the orientation policy holds, it never moves closer."""
    wire = Wire(WireConfig())
    s = 0.5 * wire.length
    p_c = wire.point(s)
    ring = look_at_pose(p_c - wire.tangent(s), p_c)  # z, the ring's normal: the tangent
    start = look_at_pose(p_c + np.array([0.0, -0.12, 0.12]), p_c)
    cfg = OrientationPolicy().config.model_copy(update={"wire_clearance": 1.0})
    policy = OrientationPolicy(cfg)
    rcm = p_c + np.array([0.0, -0.1, 0.25])
    policy.reset(PolicyContext(StereoCamera(), start, ring, rcm, 0.01, wire=wire))
    cmd = policy.step(Observation(0.0, ring, start))
    assert cmd.state is TrackingState.FROZEN_OUTSIDE_CONE and cmd.reason == WIRE_REASON
    np.testing.assert_array_equal(cmd.T_world_cam, start)


@pytest.mark.parametrize(
    ("policy", "arm"),
    [("orientation", "free"), ("orientation", "psm"), ("orientation-ecm", "ecm")],
)
def test_a_60_s_episode_keeps_the_clearance(policy: str, arm: str) -> None:
    """The paper-faithful goal (on the wire's continuation) on every carrier, noisy 71 points.

    Without the clearance this camera comes within 1.4 mm of the wire on the PSM and passes
    inside it on the free camera (README, before the constraint).
    """
    data = ExperimentConfig().model_dump(mode="json")
    data["episode"]["arm"] = arm
    config = ExperimentConfig.model_validate(data)
    assert config.task.trajectory.duration >= 60.0
    result = run_episode(config, EpisodeSpec(policy, TrajectoryKind.NOISY, 71, 1))
    wire = result.wire
    p = result.log.T_world_cam[:, :3, 3]
    nearest = np.argsort(wire.surface_distance(p))[:20]  # exact distance at the closest steps
    exact = min(_exact_surface_distance(wire, p[k]) for k in nearest)
    assert exact >= config.controller.wire_clearance - 0.5 * wire.search_spacing - ROUND_M


N_PATH_CHECKS = 400  # count: random braking paths checked at once and point by point


def test_path_check_is_the_point_by_point_check() -> None:
    """``Workspace.all_inside`` answers as ``margin`` on each point in turn, and leaves the
    keep-out cache as those calls do (the cache steers later bounds)."""
    cfg = ExperimentConfig()
    wire = Wire(cfg.task.wire)
    rcm = np.array(cfg.task.scene.rcm_position)
    feature = wire.point(0.5 * wire.length)
    at_once = cfg.controller.workspace(rcm, feature, wire)
    in_turn = cfg.controller.workspace(rcm, feature, wire)
    rng = np.random.default_rng(12)
    p = feature + np.array([0.0, 0.0, 0.02])
    outcomes = set()
    for _ in range(N_PATH_CHECKS):
        s_wire = rng.uniform(0.1, 0.9) * wire.length
        if rng.random() < 0.3:  # jump next to the wire: the cache has to query again
            p = wire.point(s_wire) + rng.normal(0.0, 0.012, 3)
        n = int(rng.integers(1, 40))
        path = p + np.cumsum(rng.normal(0.0, 0.002, (n, 3)), axis=0)
        if rng.random() < 0.05:
            path[int(rng.integers(0, n)), 0] = math.nan
        expected = all(in_turn.margin(row) >= 0.0 for row in path.tolist())
        assert at_once.all_inside(path) == expected
        assert at_once.keep_out.refs == in_turn.keep_out.refs
        outcomes.add(expected)
        p = path[-1] if math.isfinite(path[-1].sum()) else p
    assert outcomes == {True, False}  # both answers were exercised


class _InterpretedGuard:
    """The guard's queries as the interpreter ran them before they were compiled (reference).

    ``math.dist`` for the Lipschitz bounds and the KD-tree for the nearest search point (the
    compiled cell search is the tree's answer bit for bit, ``tests/test_task_wire.py``).
    """

    def __init__(self, wire: Wire, clearance: float) -> None:
        self.wire, self.clearance = wire, clearance
        self.points = wire.search_points
        self.refs: list[tuple[list[float], float]] = []

    def nearest_surface(self, p: list[float]) -> tuple[float, int]:
        d, k = self.wire._tree.query(np.array(p, dtype=float))
        return float(d) - self.wire.radius, int(k)

    def distance(self, p: list[float]) -> float:
        if not math.isfinite(p[0] + p[1] + p[2]):
            return math.nan
        for ref, d_ref in self.refs:
            bound = d_ref - math.dist(p, ref)
            if bound >= self.clearance + 0.0:
                return bound
        d, _ = self.nearest_surface(p)
        self.refs.insert(0, (list(p), d))
        del self.refs[2:]
        return d

    def trace(self, a: list[float], b: list[float]) -> list[float] | None:
        seg = (b[0] - a[0], b[1] - a[1], b[2] - a[2])
        length = kernels.norm(seg)
        if not math.isfinite(length) or length <= 1e-9:
            return None
        t, x = 0.0, [a[0], a[1], a[2]]
        for _ in range(detour.MAX_TRACE_STEPS):
            free = self.distance(x) - self.clearance
            if not free > detour.DETOUR_TOL:
                if not (free >= -detour.DETOUR_TOL and self.leaving(x, seg)):
                    return x
                free = detour.DETOUR_CREEP
            t += free / length
            if t >= 1.0:
                return None
            x = [a[0] + t * seg[0], a[1] + t * seg[1], a[2] + t * seg[2]]
        return None

    def leaving(self, x: list[float], direction: kernels.Vec) -> bool:
        _, k = self.nearest_surface(x)
        q = self.points[k].tolist()
        return kernels.dot((x[0] - q[0], x[1] - q[1], x[2] - q[2]), direction) > 0.0

    def lifted(self, p: list[float]) -> list[float] | None:
        d, k = self.nearest_surface(p)
        want = self.clearance + detour.DETOUR_PUSH
        if d >= want:
            return p
        q = self.points[k].tolist()
        out = kernels.unit_or_none((p[0] - q[0], p[1] - q[1], p[2] - q[2]))
        if out is None:
            return None
        lift = want - d
        return [p[0] + lift * out[0], p[1] + lift * out[1], p[2] + lift * out[2]]

    def detour(self, a: list[float], b: list[float]) -> kernels.Vec | None:
        x = self.trace(a, b)
        if x is None:
            return None
        _, k = self.nearest_surface(x)
        pts = self.points
        q = pts[k].tolist()
        out = kernels.unit_or_none((x[0] - q[0], x[1] - q[1], x[2] - q[2]))
        tangent = kernels.unit_or_none(
            tuple((pts[min(k + 1, len(pts) - 1)] - pts[max(k - 1, 0)]).tolist())
        )
        if out is None or tangent is None:
            return None
        around = kernels.cross(tangent, out)
        g = kernels.reject((b[0] - q[0], b[1] - q[1], b[2] - q[2]), tangent)
        phi = math.atan2(kernels.dot(g, around), kernels.dot(g, out))
        rest = (b[0] - x[0], b[1] - x[1], b[2] - x[2])
        step = min(detour.DETOUR_STEP, kernels.norm(rest))
        if abs(phi) < detour.SAME_SIDE_ANGLE:
            move = kernels.scaled(kernels.unit_or_none(kernels.reject(rest, out)) or out, step)
        else:
            sign = 1.0 if phi > 0.0 else -1.0
            if abs(phi) > math.pi - detour.SAME_SIDE_ANGLE:
                sign = 1.0 if around[2] >= 0.0 else -1.0
            along = max(-step, min(step, kernels.dot(rest, tangent)))
            move = (
                sign * step * around[0] + along * tangent[0],
                sign * step * around[1] + along * tangent[1],
                sign * step * around[2] + along * tangent[2],
            )
        for scale in detour.DETOUR_SCALES:
            via = self.lifted([x[i] + scale * move[i] for i in range(3)])
            if via is not None and self.trace(a, via) is None:
                return (via[0], via[1], via[2])
        lift = detour.DETOUR_PUSH + max(0.0, self.clearance - self.distance(x))
        return (x[0] + lift * out[0], x[1] + lift * out[1], x[2] + lift * out[2])

    # ``ClearanceGuard.apply`` and its search as they were before r7-ctrl compiled them
    # (``_apply_kernel``), with a ``feasible`` callable

    escape: kernels.Vec | None = None
    adjusted = 0
    blocked = 0

    def remember(self, p: list[float], d: float) -> None:
        self.refs.insert(0, (list(p), d))
        del self.refs[2:]

    def apply(self, T, pivot, feasible=None, p_now=None, back_off=0.0):
        rows = T.tolist()
        p = [rows[0][3], rows[1][3], rows[2][3]]
        if not math.isfinite(p[0] + p[1] + p[2] + sum(pivot)):
            return None
        if self.distance(p) >= self.clearance:
            self.escape = None
            return T
        found = None
        if back_off > 0.0:
            found = self.backed_off(rows, p, back_off, feasible)
        if found is None:
            found = self.rotated(rows, p, pivot, feasible, p_now)
        if found is None:
            self.blocked += 1
            return None
        self.adjusted += 1
        return found

    def rotated(self, rows, p, c, feasible, p_now):
        x = (rows[0][0], rows[1][0], rows[2][0])
        y = (rows[0][1], rows[1][1], rows[2][1])
        z = (rows[0][2], rows[1][2], rows[2][2])
        rel = (p[0] - c[0], p[1] - c[1], p[2] - c[2])
        r = kernels.norm(rel)
        if not r > 1e-9:
            return None
        a, b, w = kernels.dot(rel, x), kernels.dot(rel, y), kernels.dot(rel, z)
        u = kernels.scaled(rel, 1.0 / r)
        for e in self.directions(p, u, c, p_now):
            T = self.search(u, e, r, c, (a, b, w), (x, z), feasible)
            if T is not None:
                self.escape = e
                return T
        return None

    def backed_off(self, rows, p, back_off, feasible):
        z = (rows[0][2], rows[1][2], rows[2][2])
        target = self.clearance + escape.AIM_BEYOND
        s = 0.0
        back = (-z[0], -z[1], -z[2])
        for _ in range(escape.MAX_ESCAPE_STEPS):
            pos = [p[0] - s * z[0], p[1] - s * z[1], p[2] - s * z[2]]
            d, k = self.nearest_surface(pos)
            if d >= target:
                if feasible is not None and not feasible(pos):
                    return None
                self.remember(pos, d)
                T = np.array(rows)
                T[:3, 3] = pos
                return T
            s += self.newton(target - d, pos, k, back)
            if s > back_off:
                return None
        return None

    def newton(self, short, pos, k, velocity):
        q = self.points[k].tolist()
        g = (pos[0] - q[0], pos[1] - q[1], pos[2] - q[2])
        speed = kernels.norm(velocity)
        conservative = short / speed if speed > 1e-9 else short
        length = kernels.norm(g)
        if not length > 1e-9:
            return max(conservative, 1e-7)
        rate = kernels.dot(g, velocity) / length
        if rate * escape.NEWTON_GAIN <= speed:
            return max(escape.NEWTON_GAIN * conservative, 1e-7)
        return max(short / rate, conservative, 1e-7)

    def directions(self, p, u, c, p_now):
        out = []
        _, k = self.nearest_surface(p)
        q = self.points[k].tolist()
        candidates = [] if self.escape is None else [self.escape]
        if p_now is not None:
            candidates.append((p_now[0] - c[0], p_now[1] - c[1], p_now[2] - c[2]))
        candidates += [(p[0] - q[0], p[1] - q[1], p[2] - q[2]), (0.0, 0.0, 1.0), (1.0, 0.0, 0.0)]
        for cand in candidates:
            e = kernels.reject(cand, u)
            length = kernels.norm(e)
            if length > 1e-6:
                out.append(kernels.scaled(e, 1.0 / length))
                break
        if not out:
            return out
        e0 = out[0]
        e1 = kernels.cross(u, e0)
        return [e0, e1, kernels.scaled(e1, -1.0), kernels.scaled(e0, -1.0)]

    def search(self, u, e, r, c, local, xz, feasible):
        a, b, w = local
        x0, z0 = xz
        k = kernels.cross(u, e)
        theta = 0.0
        target = self.clearance + escape.AIM_BEYOND
        for _ in range(escape.MAX_ESCAPE_STEPS):
            ct, st = math.cos(theta), math.sin(theta)
            z = _rotate(z0, k, ct, st)
            x_prev = _rotate(x0, k, ct, st)
            xc, yc, zc = rotation_columns(z, (0.0, 0.0, 1.0), x_prev)
            pos = [c[i] + a * xc[i] + b * yc[i] + w * zc[i] for i in range(3)]
            d, near = self.nearest_surface(pos)
            if d >= target and (feasible is None or feasible(pos)):
                self.remember(pos, d)
                return pose_from_columns(xc, yc, zc, (pos[0], pos[1], pos[2]))
            if d < target:
                rel = (pos[0] - c[0], pos[1] - c[1], pos[2] - c[2])
                step = self.newton(target - d, pos, near, kernels.cross(k, rel))
            else:
                step = escape.MIN_ESCAPE_STEP
            theta += max(step, escape.MIN_ESCAPE_STEP * 0.1)
            if theta > escape.MAX_ESCAPE_ANGLE:
                return None
        return None


def _rotate(v: kernels.Vec, k: kernels.Vec, c: float, s: float) -> kernels.Vec:
    kv = kernels.cross(k, v)
    kd = kernels.dot(k, v) * (1.0 - c)
    return (
        v[0] * c + kv[0] * s + k[0] * kd,
        v[1] * c + kv[1] * s + k[1] * kd,
        v[2] * c + kv[2] * s + k[2] * kd,
    )


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_compiled_guard_is_the_interpreted_one(seed: int) -> None:
    """Detours, distances and path checks: the compiled guard's floats and cache, bit for bit.

    A random walk of the camera near a random wire, commands around and across it (a
    property test: hypothesis draws the seed of numpy's generator).
    """
    rng = np.random.default_rng(seed)
    wire = _random_wire(int(rng.integers(2**31)))
    guard = ClearanceGuard(wire, WIRE_CLEARANCE)
    ref = _InterpretedGuard(wire, WIRE_CLEARANCE)
    p = wire.point(rng.uniform(0.2, 0.8) * wire.length) + rng.normal(0.0, 0.01, 3)
    for _ in range(40):
        cmd = wire.point(rng.uniform(0.0, 1.0) * wire.length) + rng.normal(0.0, 0.012, 3)
        a, b = p.tolist(), cmd.tolist()
        assert guard.detour(a, b) == ref.detour(a, b)
        assert guard.refs == ref.refs
        path = p + np.cumsum(rng.normal(0.0, 0.002, (int(rng.integers(1, 20)), 3)), axis=0)
        expected = next(
            (i for i, row in enumerate(path.tolist()) if not ref.distance(row) >= WIRE_CLEARANCE),
            len(path),
        )
        assert guard.first_outside(path, len(path)) == expected
        assert guard.refs == ref.refs
        q = (p + rng.normal(0.0, 0.005, 3)).tolist()
        assert guard.distance(q) == ref.distance(q)
        p = p + rng.normal(0.0, 0.004, 3)
    assert math.isnan(guard.distance([math.nan, 0.0, 0.0]))


APPLY_CALLS = 300  # guard.apply calls per random walk


@pytest.mark.parametrize("seed", range(4))
def test_compiled_search_is_the_interpreted_one(seed: int) -> None:
    """``ClearanceGuard.apply`` (``_apply_kernel``: the check, the back-off and the rotation's
    search, the workspace's feasibility) and the interpreted search: the same poses, escape
    directions, counts and caches (the guard's and the workspace keep-out's), bit for bit."""
    cfg = ExperimentConfig()
    rng = np.random.default_rng(seed)
    wire = Wire(cfg.task.wire) if seed % 2 else _random_wire(seed)
    rcm = np.array(cfg.task.scene.rcm_position)
    feature = wire.point(0.5 * wire.length)
    guard, ref = ClearanceGuard(wire, WIRE_CLEARANCE), _InterpretedGuard(wire, WIRE_CLEARANCE)
    ws, ws_ref = (cfg.controller.workspace(rcm, feature, wire) for _ in range(2))
    answers = set()
    for _ in range(APPLY_CALLS):
        p_c = wire.point(rng.uniform(0.05, 0.95) * wire.length) + rng.normal(0.0, 0.003, 3)
        p_cam = p_c + rng.normal(0.0, 0.03, 3) + [0.0, 0.0, 0.02]
        if rng.random() < 0.4:  # on the wire's continuation: too close
            s = rng.uniform(0.1, 0.9) * wire.length
            p_c = wire.point(s)
            p_cam = p_c + wire.tangent(s) * rng.uniform(0.02, 0.08) + rng.normal(0.0, 0.002, 3)
        T = look_at_pose(p_cam, p_c)
        pivot = tuple(p_c.tolist())
        now = None if rng.random() < 0.3 else tuple((p_cam + rng.normal(0.0, 0.02, 3)).tolist())
        back_off = float(rng.choice([0.0, 0.01, 0.04]))
        use_ws = rng.random() < 0.7
        if rng.random() < 0.02:
            T[1, 3] = math.nan
        got = guard.apply(T, pivot, ws if use_ws else None, now, back_off)
        feasible = (lambda p: ws_ref.margin(p) >= 0.0) if use_ws else None
        want = ref.apply(T, pivot, feasible, now, back_off)
        assert (got is None) == (want is None)
        if got is not None:
            assert got.tobytes() == want.tobytes()
            answers.add("same" if got is T else "moved")
        else:
            answers.add("none")
        assert guard.refs == ref.refs
        assert ws.keep_out.refs == ws_ref.keep_out.refs
        escape = guard._escape.tolist()
        assert (escape[0] != 0.0) == (ref.escape is not None)
        if ref.escape is not None:
            assert tuple(escape[1:]) == ref.escape
        assert (guard.adjusted, guard.blocked) == (ref.adjusted, ref.blocked)
    assert answers == {"same", "moved", "none"}


@pytest.mark.parametrize("seed", range(4))
def test_compiled_look_at_is_the_interpreted_one(seed: int) -> None:
    """``ClearanceGuard.apply_look_at`` (``_look_at_kernel``) and what the policies' detour
    did before: ``look_at_unchecked``, the workspace's check of the way-point, the
    interpreted guard's ``apply``; the same poses (the fallback itself when the points
    coincide), escape directions, counts and caches, bit for bit."""
    cfg = ExperimentConfig()
    rng = np.random.default_rng(100 + seed)
    wire = Wire(cfg.task.wire) if seed % 2 else _random_wire(seed)
    rcm = np.array(cfg.task.scene.rcm_position)
    feature = wire.point(0.5 * wire.length)
    wider = WIRE_CLEARANCE + 0.003  # m: a feasible way-point may still need turning
    guard, ref = ClearanceGuard(wire, wider), _InterpretedGuard(wire, wider)
    ws, ws_ref = (cfg.controller.workspace(rcm, feature, wire) for _ in range(2))
    previous = look_at_pose(feature + np.array([0.0, -0.05, 0.05]), feature)
    answers = set()
    for _ in range(APPLY_CALLS):
        s = rng.uniform(0.05, 0.95) * wire.length
        p_c = wire.point(s) + rng.normal(0.0, 0.003, 3)
        via = p_c + rng.normal(0.0, 0.03, 3) + [0.0, 0.0, 0.015]
        if rng.random() < 0.4:  # near the wire's continuation: too close
            via = wire.point(s) + wire.tangent(s) * rng.uniform(0.01, 0.06)
        if rng.random() < 0.03:
            via = p_c.copy()  # no direction to look along: the fallback
        fallback = look_at_pose(p_c + np.array([0.0, 0.0, 0.05]), p_c)
        pivot = tuple(p_c.tolist())
        via_t = tuple(via.tolist())
        now = tuple((via + rng.normal(0.0, 0.01, 3)).tolist())
        back_off = float(rng.choice([0.0, 0.02]))
        check = rng.random() < 0.7  # the detour's way-point is checked; a path's is not
        got = guard.apply_look_at(via_t, pivot, fallback, previous, ws, now, back_off, check)
        T = look_at_unchecked(np.array(via_t), np.asarray(pivot), fallback, previous)
        feasible = lambda p: ws_ref.margin(p) >= 0.0  # noqa: E731
        checked = not check or feasible(list(via_t))
        want = ref.apply(T, pivot, feasible, now, back_off) if checked else None
        assert (got is None) == (want is None)
        if got is not None:
            assert got.tobytes() == want.tobytes()
            assert (got is fallback) == (want is fallback)
            answers.add("fallback" if got is fallback else "same" if want is T else "moved")
            previous = got
        else:
            answers.add("none")
        assert guard.refs == ref.refs
        assert ws.keep_out.refs == ws_ref.keep_out.refs
        escape = guard._escape.tolist()
        assert (escape[0] != 0.0) == (ref.escape is not None)
        if ref.escape is not None:
            assert tuple(escape[1:]) == ref.escape
        assert (guard.adjusted, guard.blocked) == (ref.adjusted, ref.blocked)
    assert {"same", "moved", "none"} <= answers


def test_step_out_leaves_the_zone_by_the_push() -> None:
    wire = Wire(WireConfig())
    guard = ClearanceGuard(wire, CAMERA_CLEARANCE_M)
    s = 0.4 * wire.length
    q = wire.points(np.array([s]))[0]
    tangent = wire.tangent(s)
    side = np.cross(tangent, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    on_edge = q + (wire.radius + CAMERA_CLEARANCE_M) * side  # on the zone's edge
    out = guard.step_out(on_edge.tolist())
    assert out is not None
    moved = np.asarray(out) - on_edge
    assert np.linalg.norm(np.cross(moved, side)) < ROUND_M * 1e3  # straight away from the wire
    exact = _exact_surface_distance(wire, np.asarray(out))
    push = detour.DETOUR_PUSH
    assert exact == pytest.approx(CAMERA_CLEARANCE_M + push, abs=0.5 * wire.search_spacing)
    assert guard.step_out((q + 0.05 * side).tolist()) is None  # already far out: nothing to do


STILL_STEPS_ALLOWED = 2 * STALL_STEPS  # steps: the stall rule acts after STALL_STEPS


def test_a_detour_never_deadlocks_on_the_zones_edge() -> None:
    """Round 5: the free camera stood 57 s on the zone's edge on the study's legible t1 path.

    At rest 2 µm from the clearance zone, the carrier refused every slide the detour asked for
    (its braking path grazed the zone) and the policy asked again every step. Now a camera that
    stands still while detouring first steps straight out of the zone.
    """
    base = ExperimentConfig()
    t1 = next(p for p in paper_paths() if p.name == "t1-36-low")
    config = t1.config(base)
    config = config.model_copy(
        update={"episode": config.episode.model_copy(update={"arm": ArmKind.FREE})}
    )
    result = run_episode(config, t1.spec("endocam"))
    log = result.log
    still = np.all(np.diff(log.T_world_cam[:, :3, 3], axis=0) == 0.0, axis=1)
    detouring = np.asarray(log.reason[1:]) == DETOUR_REASON
    run = longest = 0
    for stuck in (still & detouring).tolist():
        run = run + 1 if stuck else 0
        longest = max(longest, run)
    assert longest <= STILL_STEPS_ALLOWED
    assert np.mean(log.state == TrackingState.TRACKING.value) > 0.5  # it tracks the ring


def test_a_workspace_the_compiled_check_cannot_honour_is_refused() -> None:
    """A ``Workspace`` subclass with its own ``margin`` would be checked as a plain one: refused."""
    cfg = ExperimentConfig()
    wire = Wire(cfg.task.wire)
    rcm, feature = np.array(cfg.task.scene.rcm_position), wire.point(0.5 * wire.length)
    ws = cfg.controller.workspace(rcm, feature, wire)

    class Stricter(Workspace):
        def margin(self, p_world: object) -> float:
            return -1.0

    guard = ClearanceGuard(wire, WIRE_CLEARANCE)
    T = make_pose(np.eye(3), feature + np.array([0.0, 0.0, 0.05]))
    pivot = (float(feature[0]), float(feature[1]), float(feature[2]))
    assert guard.apply(T, pivot, ws) is not None  # the plain Workspace is taken
    with pytest.raises(TypeError, match="workspace"):
        guard.apply(T, pivot, Stricter(ws.cone, ws.floor, ws.keep_out))
