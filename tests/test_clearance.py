"""The camera-wire clearance: goals, episodes on every carrier, degenerate inputs."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

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
from endocam.view import ROLL_LEVEL_ANGLE, look_at_pose, look_at_unchecked
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


ATOL_M = 1e-9  # m: round-off of distances and positions at the 0.1 m scale
ATOL_UNIT = 1e-9  # unitless: rotation-matrix entries, unit vectors
SAMPLE_M = 1e-4  # m: spacing of the points a straight move is checked at


def _surface(wire: Wire, p: object) -> np.ndarray:
    """The numpy API's surface distance (KD-tree to the search polyline, the guard's), m."""
    return wire.surface_distance(np.asarray(p, dtype=float).reshape(-1, 3))


def _segment(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Points every ``SAMPLE_M`` along the segment ``a → b`` (both ends included), m."""
    n = max(2, int(np.linalg.norm(b - a) / SAMPLE_M) + 2)
    return a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_guard_queries_agree_with_the_wire_distance(seed: int) -> None:
    """Distances, path checks and detours against ``Wire.surface_distance`` (the numpy API).

    A random walk of the camera near a random wire, commands around and across it (a
    property test: hypothesis draws the seed of numpy's generator). ``distance`` is exact
    below the clearance and a lower bound above it (the Lipschitz cache); ``first_outside``
    finds the first point closer than the clearance; a detour's way-point lies outside the
    zone, and a move the detour lets pass keeps the clearance.
    """
    rng = np.random.default_rng(seed)
    wire = _random_wire(int(rng.integers(2**31)))
    c = WIRE_CLEARANCE
    guard = ClearanceGuard(wire, c)
    p = wire.point(rng.uniform(0.2, 0.8) * wire.length) + rng.normal(0.0, 0.01, 3)
    answers = set()
    for _ in range(40):
        q = p + rng.normal(0.0, 0.005, 3)
        d, exact = guard.distance(q.tolist()), float(_surface(wire, q)[0])
        if d < c:
            assert d == pytest.approx(exact, abs=ATOL_M)
        else:
            assert d <= exact + ATOL_M
        path = p + np.cumsum(rng.normal(0.0, 0.002, (int(rng.integers(1, 20)), 3)), axis=0)
        i = guard.first_outside(path, len(path))
        near = _surface(wire, path)
        assert np.all(near[:i] >= c - ATOL_M)
        assert i == len(path) or near[i] < c + ATOL_M
        cmd = wire.point(rng.uniform(0.0, 1.0) * wire.length) + rng.normal(0.0, 0.012, 3)
        via = guard.detour(p.tolist(), cmd.tolist())
        if via is None:
            if _surface(wire, p)[0] >= c:  # a start outside the zone: the move stays out
                assert _surface(wire, _segment(p, cmd)).min() >= c - detour.DETOUR_TOL - ATOL_M
            answers.add("straight")
        else:
            assert _surface(wire, via)[0] >= c - ATOL_M
            answers.add("detour")
        p = p + rng.normal(0.0, 0.004, 3)
    assert math.isnan(guard.distance([math.nan, 0.0, 0.0]))


def _check_guarded(
    wire: Wire, T: np.ndarray, pivot: np.ndarray, out: np.ndarray, clearance: float, back_off: float
) -> str:
    """The invariants of a pose the guard moved; which way it moved ("backed off", "turned")."""
    p, p_out = T[:3, 3], out[:3, 3]
    R = out[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=ATOL_UNIT)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=ATOL_UNIT)
    np.testing.assert_array_equal(out[3], [0.0, 0.0, 0.0, 1.0])
    assert _surface(wire, p_out)[0] >= clearance + escape.AIM_BEYOND - ATOL_M
    if np.allclose(R, T[:3, :3], atol=ATOL_UNIT):  # moved back along the optical axis
        s = float(np.dot(p - p_out, T[:3, 2]))
        np.testing.assert_allclose(p_out, p - s * T[:3, 2], atol=ATOL_M)
        assert 0.0 < s <= back_off + ATOL_M
        return "backed off"
    # turned about the pivot: it keeps its place in the camera frame, the horizon stays level
    np.testing.assert_allclose(
        invert_pose(out) @ np.append(pivot, 1.0), invert_pose(T) @ np.append(pivot, 1.0), atol=1e-7
    )
    if np.linalg.norm(np.cross(out[:3, 2], [0.0, 0.0, 1.0])) >= math.sin(ROLL_LEVEL_ANGLE):
        assert abs(out[2, 0]) <= ATOL_UNIT  # not near the vertical: a level horizon
    u0, u1 = p - pivot, p_out - pivot
    turn = math.acos(np.clip(np.dot(u0, u1) / (np.linalg.norm(u0) * np.linalg.norm(u1)), -1, 1))
    assert turn <= escape.MAX_ESCAPE_ANGLE + 2 * escape.MIN_ESCAPE_STEP
    return "turned"


def _feasible(ws: Workspace, wire: Wire, p: np.ndarray) -> bool:
    """``Workspace.margin(p) >= 0`` from its parts: the cone, the floor, the wire's distance."""
    assert ws.keep_out is not None
    clear = _surface(wire, p)[0] >= ws.keep_out.clearance  # type: ignore[attr-defined]
    return ws.cone.contains(p) and p[2] >= ws.floor and bool(clear)


APPLY_CALLS = 300  # guard.apply calls per random walk


@pytest.mark.parametrize("seed", range(4))
def test_a_guarded_pose_keeps_the_clearance_and_the_view(seed: int) -> None:
    """``ClearanceGuard.apply`` over random poses near the wire, with and without a workspace.

    A pose that passes is clear; a moved one is clear by ``AIM_BEYOND``, a rotation, either
    backed off along its optical axis (at most ``back_off``) or turned about the pivot (which
    keeps its place in the camera frame, the horizon level, at most ``MAX_ESCAPE_ANGLE``), and
    feasible in the workspace; ``None`` for a non-finite pose. The counts follow the answers,
    and the same request asked twice gets the same answer (the remembered escape direction).
    """
    cfg = ExperimentConfig()
    rng = np.random.default_rng(seed)
    wire = Wire(cfg.task.wire) if seed % 2 else _random_wire(seed)
    rcm = np.array(cfg.task.scene.rcm_position)
    feature = wire.point(0.5 * wire.length)
    guard = ClearanceGuard(wire, WIRE_CLEARANCE)
    ws = cfg.controller.workspace(rcm, feature, wire)
    answers: dict[str, int] = {}
    repeats = 0  # moved poses asked again
    for _ in range(APPLY_CALLS):
        p_c = wire.point(rng.uniform(0.05, 0.95) * wire.length) + rng.normal(0.0, 0.003, 3)
        p_cam = p_c + rng.normal(0.0, 0.03, 3) + [0.0, 0.0, 0.02]
        if rng.random() < 0.4:  # on the wire's continuation: too close
            s = rng.uniform(0.1, 0.9) * wire.length
            p_c = wire.point(s)
            p_cam = p_c + wire.tangent(s) * rng.uniform(0.02, 0.08) + rng.normal(0.0, 0.002, 3)
        T = look_at_pose(p_cam, p_c)
        now = None if rng.random() < 0.3 else tuple((p_cam + rng.normal(0.0, 0.02, 3)).tolist())
        back_off = float(rng.choice([0.0, 0.01, 0.04]))
        use_ws = rng.random() < 0.7
        if rng.random() < 0.02:
            T[1, 3] = math.nan
        pivot = tuple(p_c.tolist())
        got = guard.apply(T, pivot, ws if use_ws else None, now, back_off)
        if got is None:
            kind = "none"
        elif got is T:
            kind = "same"
            assert _surface(wire, T[:3, 3])[0] >= WIRE_CLEARANCE - ATOL_M
        else:
            kind = _check_guarded(wire, T, p_c, got, WIRE_CLEARANCE, back_off)
            assert not use_ws or _feasible(ws, wire, got[:3, 3])
            again = guard.apply(T, pivot, ws if use_ws else None, now, back_off)
            assert again is not None
            np.testing.assert_allclose(again, got, atol=ATOL_M)
            repeats += 1
        if not np.isfinite(T).all():
            assert got is None
        answers[kind] = answers.get(kind, 0) + 1
    assert {"same", "turned", "backed off", "none"} <= answers.keys()
    assert guard.adjusted == answers["turned"] + answers["backed off"] + repeats
    assert guard.blocked <= answers["none"]


@pytest.mark.parametrize("seed", range(4))
def test_a_guarded_look_at_pose_keeps_the_clearance_and_the_view(seed: int) -> None:
    """``ClearanceGuard.apply_look_at``: the look-at pose (``view.look_at_unchecked``, the
    fallback itself when the points coincide) when it is clear; ``None`` when the way-point
    is outside the workspace (if checked); else ``apply``'s invariants."""
    cfg = ExperimentConfig()
    rng = np.random.default_rng(100 + seed)
    wire = Wire(cfg.task.wire) if seed % 2 else _random_wire(seed)
    rcm = np.array(cfg.task.scene.rcm_position)
    feature = wire.point(0.5 * wire.length)
    wider = WIRE_CLEARANCE + 0.003  # m: a feasible way-point may still need turning
    guard = ClearanceGuard(wire, wider)
    ws = cfg.controller.workspace(rcm, feature, wire)
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
        now = tuple((via + rng.normal(0.0, 0.01, 3)).tolist())
        back_off = float(rng.choice([0.0, 0.02]))
        check = rng.random() < 0.7  # the detour's way-point is checked; a path's is not
        feasible = _feasible(ws, wire, via)
        T = look_at_unchecked(via, p_c, fallback, previous)
        got = guard.apply_look_at(
            tuple(via.tolist()), tuple(p_c.tolist()), fallback, previous, ws, now, back_off, check
        )
        if check and not feasible:
            assert got is None
            answers.add("infeasible")
            continue
        if got is None:
            answers.add("none")
            continue
        if _surface(wire, T[:3, 3])[0] >= wider + ATOL_M:  # clear: the look-at pose itself
            np.testing.assert_allclose(got, T, atol=ATOL_UNIT)
            assert (got is fallback) == (T is fallback)
            answers.add("fallback" if got is fallback else "same")
        elif _surface(wire, T[:3, 3])[0] < wider - ATOL_M:
            answers.add(_check_guarded(wire, T, p_c, got, wider, back_off))
            assert _feasible(ws, wire, got[:3, 3])
        previous = got
    assert {"same", "turned", "none", "infeasible"} <= answers


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
