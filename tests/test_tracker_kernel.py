"""The compiled control steps, pinned to the numpy API by named tolerances, and their invariants.

``control.plan.plan_step`` (the ``endocam`` step's numbers) and ``control.paper_step.paper_step``
(the paper's moving policies') compile the maths of ``control.side_view``, ``control.goal``,
``control.predictor`` and ``control.checks``. The pieces are held to numpy / scipy
(``endocam.geometry``, ``endocam.view``, ``scipy.spatial.transform.Rotation``,
``ConeWorkspace.margin``) over seeded random inputs; whole random episodes (every branch: side
changes, orbits, way-points, height-limited views, shortening, the windows, the paper's side
rule, the wire clearance, degenerate and faulty observations) are held to the safety
invariants: every command finite and a rotation, inside the cone and above the floor, clear of
the wire, the working distance in range and moving one step at most, and every hold the last
command with the last working distance.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numba import njit
from scipy.spatial.transform import Rotation

from endocam.config import CameraConfig
from endocam.control.checks import GATE_REASON, OBS_OK, RING_REASON, Sighting
from endocam.control.config import ControllerConfig, SideRule, TrackerConfig, Transfer
from endocam.control.gate import STALE_REASON
from endocam.control.goal import PreviousAxes, goal_pose_unchecked
from endocam.control.paper_step import PaperResult
from endocam.control.plan import PlanResult, inside_kernel
from endocam.control.policies import (
    CenteringPolicy,
    EndocamPolicy,
    MovingPolicy,
    OraclePolicy,
    OrientationPolicy,
    VisiblePolicy,
)
from endocam.control.policies.endocam import FLOOR_TOL_M
from endocam.control.policies.oracle import OracleConfig
from endocam.control.predictor import RingPredictor
from endocam.control.side_view import ViewRule, pose_of, twist_of, view_of
from endocam.control.types import CameraCommand, Observation, PolicyContext, TrackingState
from endocam.control.windows import WindowGeometry, WindowStatus, window_status_rows
from endocam.task.config import WireConfig
from endocam.task.wire import Wire
from endocam.view import ROLL_LEVEL_ANGLE, look_at_pose, rotation_columns
from endocam.workspace.cone import ConeWorkspace, cone_at

DT = 0.01  # s, control period
LATENCY = 0.05  # s, sensing delay
STEPS = 300  # control steps per random episode
CAMERA = CameraConfig().stereo()
P_RCM = np.array([0.2, 0.0, 0.12])  # m, the default scene's camera port
WIRE = Wire(WireConfig())  # the default task's wire, world, m

ATOL_UNIT = 1e-12  # unitless: unit vectors and rotation entries from the same formula
ATOL_M = 1e-12  # m: positions from the same formula (the compiled and the numpy one)
ATOL_ORTHO = 1e-9  # unitless: a commanded rotation is orthonormal to this
ATOL_INV_M = 1e-9  # m: round-off allowed on the invariants (cone, floor, wire)
ATOL_TWIST = 1e-9  # rad/s: the small-angle twist against scipy's rotation vector, per rad²

# the observation gate opened wide (every bound at its largest): these scenarios jump the ring
GATE_OFF = {
    "ring_max_speed": 10.0,
    "ring_max_rate": 1000.0,
    "ring_max_acceleration": 1e6,
    "ring_max_angular_acceleration": 1e8,
    "ring_gate_position": 10.0,
    "ring_gate_angle": math.pi,
}


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def ring_pose(p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(4, 4) ring pose with unit normal ``n`` as its z axis at ``p`` (m)."""
    z = unit(n)
    x = np.cross([0.0, 1.0, 0.0], z)
    if np.linalg.norm(x) < 1e-6:
        x = np.array([1.0, 0.0, 0.0])
    x = unit(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = p
    return T


def random_unit(rng: np.random.Generator) -> tuple[float, float, float]:
    """A unit vector, now and then (anti)parallel to world up or nearly so (the singularity)."""
    v = rng.normal(size=3)
    r = rng.random()
    if r < 0.1:
        v = np.array([0.0, 0.0, rng.choice([-1.0, 1.0])])
    elif r < 0.3:
        v[:2] *= rng.choice([1e-10, 1e-3, 0.05, 0.2])
    u = (v / np.linalg.norm(v)).tolist()
    return (u[0], u[1], u[2])


def random_observations(seed: int, wire: bool) -> list[tuple[float, np.ndarray, np.ndarray]]:
    """(t s, ring pose (4, 4), tips (K, 3) world m) per step: a ring wandering and tipping.

    The ring walks along (or near) the wire, low over the board, its normal turning smoothly
    with jumps now and then (side changes, height-limited views); the tips sit near the ring,
    sometimes far off, not finite or missing (every window status).
    """
    rng = np.random.default_rng(seed)
    pts = WIRE.search_points
    k = int(rng.integers(200, len(pts) - 200))
    n = unit(rng.normal(size=3) + np.array([0.0, 0.0, 0.5]))
    out = []
    for step in range(STEPS):
        k = int(np.clip(k + rng.integers(-3, 4), 0, len(pts) - 1))
        p = pts[k] if wire else pts[k] + [0.0, 0.0, 0.01]
        p = p + rng.normal(scale=5e-4, size=3)
        if rng.random() < 0.03:  # a jump of the normal (another side may be better)
            n = unit(rng.normal(size=3))
        else:
            n = unit(n + rng.normal(scale=0.05, size=3))
        kind = rng.random()
        if kind < 0.1:
            tips = np.zeros((0, 3))
        else:
            spread = 0.002 if kind < 0.4 else 0.02 if kind < 0.8 else 0.08
            tips = p + rng.normal(scale=spread, size=(int(rng.integers(1, 3)), 3))
            if rng.random() < 0.05:
                tips[0, 1] = math.nan
        T_ring = ring_pose(p, n)
        if rng.random() < 0.02:  # a degenerate ring pose: no normal
            T_ring[:3, 2] = 0.0
        out.append((step * DT, T_ring, tips))
    return out


# -- the invariants of every command ---------------------------------------------------------


class Invariants:
    """Checks every command of an episode against the safety rules; counts what it saw."""

    def __init__(self, policy: MovingPolicy) -> None:
        self.policy = policy
        self.states: set[TrackingState] = set()
        self.reasons: set[str] = set()
        self.last: CameraCommand | None = None

    def check(self, cmd: CameraCommand) -> None:
        policy, cfg = self.policy, self.policy.config
        T = cmd.T_world_cam
        assert T.shape == (4, 4) and np.all(np.isfinite(T))
        R = T[:3, :3]
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=ATOL_ORTHO)
        assert np.linalg.det(R) > 0.0
        assert cfg.d_min - ATOL_INV_M <= cmd.d_f <= cfg.d_max + ATOL_INV_M
        issued = cmd.state in (TrackingState.TRACKING, TrackingState.PLANNING)
        if self.last is not None:
            # the working distance moves one step per control step at most
            assert abs(cmd.d_f - self.last.d_f) <= cfg.d_f_step * (1 + 1e-9) + ATOL_INV_M
            if not issued:  # a hold: the last safe command, and its working distance
                assert cmd.d_f == self.last.d_f
                frozen = cmd.state is TrackingState.FROZEN_OUTSIDE_CONE
                if not (frozen and cmd.reason.startswith(("goal", "no view"))):
                    np.testing.assert_array_equal(T, self.last.T_world_cam)
        if issued:
            p = T[:3, 3].tolist()
            if isinstance(policy, EndocamPolicy):  # the tracker's last gate: cone and floor
                assert policy.cone.margin(p) >= -ATOL_INV_M, (cmd.state, cmd.reason)
                assert p[2] >= cfg.min_camera_height - FLOOR_TOL_M - ATOL_INV_M
            elif cmd.state is TrackingState.TRACKING:  # the paper's: the goal, not its way-points
                assert policy.cone.margin(p) >= -ATOL_INV_M, cmd.reason
            if policy.guard is not None:
                d, _ = policy.guard.wire.nearest_surface(p)
                assert d >= policy.guard.clearance - ATOL_INV_M, cmd.reason
        if cmd.twist is not None:
            assert cmd.twist.shape == (6,) and np.all(np.isfinite(cmd.twist))
        self.states.add(cmd.state)
        self.reasons.add(cmd.reason.split(" ")[0])
        self.last = cmd


def context_for(
    T0: np.ndarray, wire: bool, follows_twist: bool = True, start: np.ndarray | None = None
) -> PolicyContext:
    """The episode's context: a tilted start view of the ring's first pose ``T0``."""
    T_cam = look_at_pose(T0[:3, 3] + [0.03, 0.01, 0.04], T0[:3, 3]) if start is None else start
    return PolicyContext(
        CAMERA,
        T_cam,
        T0,
        P_RCM,
        DT,
        LATENCY,
        follows_twist=follows_twist,
        wire=WIRE if wire else None,
    )


def run_episode(
    policy: MovingPolicy, seed: int, wire: bool, follows_twist: bool = True
) -> Invariants:
    """Step ``policy`` on :func:`random_observations`, checking every command."""
    obs_seq = random_observations(seed, wire)
    context = context_for(obs_seq[0][1], wire, follows_twist)
    policy.reset(context)
    inv = Invariants(policy)
    rng = np.random.default_rng(seed + 1)
    T_cam = context.T_world_cam
    for t, T_ring, tips in obs_seq:
        cmd = policy.step(Observation(t, T_ring, T_cam, tips))
        inv.check(cmd)
        # an imperfect carrier: part of the way to the command, a little off
        T_cam = cmd.T_world_cam.copy()
        if rng.random() < 0.5:
            T_cam[:3, 3] += rng.normal(scale=2e-3, size=3)
    return inv


TRACKERS = {
    "default": {},
    "waypoints": {"side_transfer": Transfer.WAYPOINTS, "first_approach": Transfer.WAYPOINTS},
    "orbit-first": {"first_approach": Transfer.ORBIT, "side_change_angle": 0.5},
    "paper-side": {"keep_side": False},
    "no-shortening": {"shorten_when_low": False},
    "no-prediction": {"predict": False},
    "no-feedforward": {"feedforward": False},
}


@pytest.mark.parametrize("wire", [False, True])
@pytest.mark.parametrize("name", sorted(TRACKERS))
def test_random_tracker_episodes_keep_the_safety_invariants(name: str, wire: bool) -> None:
    tracker = TrackerConfig.model_validate(TRACKERS[name])
    states: set[TrackingState] = set()
    for seed, (rule, centre, follows) in enumerate(
        [(SideRule.PORT, True, True), (SideRule.UP, False, True), (SideRule.PORT, True, False)]
    ):
        cfg = ControllerConfig(
            tracker=tracker,
            side_rule=rule,
            centre_left_eye=centre,
            **GATE_OFF,  # the normal jumps: the gate is opened wide
        )
        states |= run_episode(EndocamPolicy(cfg), 10 * seed + len(name), wire, follows).states
    assert states & {TrackingState.TRACKING, TrackingState.PLANNING}  # commands were issued


@pytest.mark.parametrize("wire", [False, True])
def test_random_visible_episodes_keep_the_safety_invariants(wire: bool) -> None:
    """``endocam-visible`` turns the tracker's viewing axis (with a wire model): the same
    invariants hold, and with the wire it tilts the axis and changes side on its own."""
    states: set[TrackingState] = set()
    tilted = changes = 0
    for seed, (rule, centre, follows) in enumerate(
        [(SideRule.PORT, True, True), (SideRule.UP, False, False)]
    ):
        cfg = ControllerConfig(side_rule=rule, centre_left_eye=centre, **GATE_OFF)
        policy = VisiblePolicy(cfg)
        states |= run_episode(policy, 200 + seed, wire, follows).states
        tilted += policy.tilted_steps
        changes += policy.side_changes
    assert states & {TrackingState.TRACKING, TrackingState.PLANNING}  # commands were issued
    assert (tilted > 0 and changes > 0) if wire else (tilted == 0 and changes == 0)


MOVING = {"centering": CenteringPolicy, "orientation": OrientationPolicy}


@pytest.mark.parametrize("wire", [False, True])
@pytest.mark.parametrize("name", sorted(MOVING))
def test_random_paper_episodes_keep_the_safety_invariants(name: str, wire: bool) -> None:
    states: set[TrackingState] = set()
    for seed, (rule, centre) in enumerate(
        [(SideRule.PORT, True), (SideRule.UP, False), (SideRule.UP, True)]
    ):
        cfg = ControllerConfig(side_rule=rule, centre_left_eye=centre, **GATE_OFF)
        states |= run_episode(MOVING[name](cfg), 100 + 10 * seed + len(name), wire).states
    assert states & {TrackingState.TRACKING, TrackingState.PLANNING}  # commands were issued


def test_the_random_episodes_reach_every_branch() -> None:
    """The episodes above change side, orbit, detour, see every window status, and the kernel
    asks the guard itself (a clear view, with and without a detour) or leaves it to Python."""
    cfg = ControllerConfig(**GATE_OFF)
    policy = EndocamPolicy(cfg)
    plan_step = policy._plan_step
    answers: list[PlanResult] = []

    def spy(*args: object) -> PlanResult:
        answer = plan_step(*args)  # type: ignore[arg-type]
        answers.append(answer)
        return answer

    policy._plan_step = spy  # type: ignore[method-assign]
    reasons, statuses, distances = set(), set(), set()
    geometry = WindowGeometry.of(CAMERA, cfg.windows)
    for seed in range(3):
        obs_seq = random_observations(seed, wire=True)
        T0 = obs_seq[0][1]
        T_cam = np.eye(4)
        T_cam[:3, 3] = T0[:3, 3] + [0.03, 0.0, 0.04]
        policy.reset(context_for(T0, True, start=T_cam))
        for t, T_ring, tips in obs_seq:
            statuses.add(window_status_rows(geometry, T_cam.tolist(), tips.tolist()))
            cmd = policy.step(Observation(t, T_ring, T_cam, tips))
            reasons.add(cmd.reason.split(" ")[0])
            distances.add(round(cmd.d_f, 6))
            T_cam = cmd.T_world_cam
    guarded = {(a.guard.cleared, a.guard.detour) for a in answers if a.check == OBS_OK}
    assert statuses == set(WindowStatus)
    assert {"", "orbiting", "detouring"} <= reasons
    assert len(distances) > 10
    assert guarded == {(False, False), (True, False), (True, True)}
    both: set[tuple[bool, bool]] = set()
    for moving in (CenteringPolicy(cfg), OrientationPolicy(cfg)):  # their kernel's guard path
        goal = moving._goal
        seen: list[PaperResult] = []

        def paper_spy(*args: object, goal=goal, seen=seen) -> object:  # type: ignore[no-untyped-def]
            result, pose = goal(*args)
            seen.append(result)
            return result, pose

        moving._goal = paper_spy  # type: ignore[method-assign]
        for seed in range(4):
            obs_seq = random_observations(seed, wire=True)
            moving.reset(context_for(obs_seq[0][1], True))
            T_cam = moving._last_cmd
            for t, T_ring, tips in obs_seq:
                T_cam = moving.step(Observation(t, T_ring, T_cam, tips)).T_world_cam
        guarded_paper = {(r.guard.cleared, r.guard.detour) for r in seen}
        assert (True, False) in guarded_paper, type(moving).__name__
        both |= guarded_paper
    assert (True, True) in both  # a detour traced by the kernel


def oracle_context() -> PolicyContext:
    duration = STEPS * DT
    rng = np.random.default_rng(7)
    knots = rng.normal(scale=0.02, size=(8, 3)) + np.array([0.0, 0.0, 0.04])
    normals = rng.normal(size=(8, 3)) + np.array([0.0, 0.0, 0.3])

    def future(ts: np.ndarray) -> np.ndarray:
        t = np.clip(np.asarray(ts, dtype=float), 0.0, duration) / duration * 7.0
        out = []
        for ti in t:
            i = min(int(ti), 6)
            f = ti - i
            p = knots[i] + f * (knots[i + 1] - knots[i])
            n = normals[i] + f * (normals[i + 1] - normals[i])
            out.append(ring_pose(p, n))
        return np.stack(out)

    T_cam = np.eye(4)
    T_cam[:3, 3] = knots[0] + [0.05, 0.0, 0.03]
    return PolicyContext(
        CAMERA,
        T_cam,
        future(np.zeros(1))[0],
        P_RCM,
        DT,
        LATENCY,
        future=future,
        future_duration=duration,
    )


@pytest.mark.parametrize("plan", [True, False])
def test_the_oracle_keeps_the_safety_invariants_on_the_true_future(plan: bool) -> None:
    """The oracle's compiled step gets the true future (``_give_predictions``): its commands
    keep the invariants, and its tracking commands look at the true ring ``lead`` ahead."""
    cfg = ControllerConfig(**GATE_OFF)
    policy = OraclePolicy(cfg, OracleConfig(plan=plan))
    context = oracle_context()
    policy.reset(context)
    inv = Invariants(policy)
    T_cam = context.T_world_cam
    rng = np.random.default_rng(3)
    aimed = 0
    lead = policy.tracker.carrier_lead
    for k in range(STEPS):
        tips = context.T_world_ring[:3, 3] + rng.normal(scale=0.02, size=(2, 3))
        cmd = policy.step(Observation(k * DT, context.T_world_ring, T_cam, tips))
        inv.check(cmd)
        if cmd.state is TrackingState.TRACKING:  # the left eye's axis through the true ring
            assert context.future is not None
            p_c = context.future(np.array([k * DT + lead]))[0][:3, 3]
            T = cmd.T_world_cam
            eye = T[:3, 3] - 0.5 * CAMERA.baseline * T[:3, 0]
            off_axis = np.linalg.norm(np.cross(p_c - eye, T[:3, 2]))
            assert off_axis < 1e-9 + 1e-6, k  # m
            aimed += 1
        T_cam = cmd.T_world_cam
    assert aimed > STEPS // 2


# -- the pieces, one by one, against numpy and scipy -------------------------------------------


@njit(cache=False)
def _columns_compiled(z, up, x_prev, has_prev):  # type: ignore[no-untyped-def]
    if has_prev:
        return rotation_columns(z, up, x_prev)
    return rotation_columns(z, up, None)


def test_rotation_columns_compiled_is_interpreted_and_levels_the_horizon() -> None:
    """Compiled and interpreted ``rotation_columns`` agree; the frame is a rotation with the
    given optical axis, and its horizon is level (numpy's ``z × up``) when tilted enough."""
    rng = np.random.default_rng(11)
    up = (0.0, 0.0, 1.0)
    for _ in range(3000):
        z = random_unit(rng)
        has_prev = rng.random() < 0.8
        x_prev = random_unit(rng) if rng.random() < 0.5 else z  # z itself: no reference roll
        got = np.array(rotation_columns(z, up, x_prev if has_prev else None)).T
        np.testing.assert_allclose(
            np.array(_columns_compiled(z, up, x_prev, has_prev)).T, got, atol=ATOL_UNIT
        )
        np.testing.assert_allclose(got.T @ got, np.eye(3), atol=ATOL_ORTHO)
        np.testing.assert_allclose(got[:, 2], z, atol=ATOL_UNIT)
        if np.linalg.norm(np.cross(z, up)) > math.sin(ROLL_LEVEL_ANGLE) + 1e-6:
            assert abs(np.dot(got[:, 0], up)) < ATOL_ORTHO  # a level horizon: x ⟂ up


def test_goal_pose_is_on_the_normal_and_looks_at_the_ring() -> None:
    """``goal_pose_unchecked`` (the compiled ``goal_columns``) against numpy: the camera on
    the normal at ``d``, its optical axis through the ring centre, a rotation."""
    rng = np.random.default_rng(12)
    up = (0.0, 0.0, 1.0)
    for _ in range(3000):
        p_c = np.array(rng.normal(scale=0.05, size=3))
        n = np.array(random_unit(rng))
        d = float(rng.uniform(0.02, 0.1))
        previous = None
        if rng.random() < 0.8:
            previous = np.eye(4)
            previous[:3, :3] = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
        hysteresis = float(rng.uniform(0.0, 1.0))
        min_height = float(rng.choice([-math.inf, rng.uniform(-0.1, 0.1)]))
        toward = random_unit(rng) if rng.random() < 0.5 else None
        T = goal_pose_unchecked(
            tuple(p_c), tuple(n), d, up, previous, hysteresis, min_height, toward
        )
        R, p = T[:3, :3], T[:3, 3]
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=ATOL_ORTHO)
        s = -float(np.dot(R[:, 2], n))  # the side: z = −s n
        assert abs(abs(s) - 1.0) < ATOL_ORTHO
        np.testing.assert_allclose(p, p_c + s * d * n, atol=ATOL_M)
        np.testing.assert_allclose(np.cross(p_c - p, R[:, 2]), 0.0, atol=ATOL_M)


def test_view_of_is_feasible_and_its_margin_is_the_cones() -> None:
    """``view_of``: a unit direction keeping the camera at the aim floor; ``s n`` itself when
    that is high enough; its margin ``ConeWorkspace.margin`` of the camera (numpy API)."""
    rng = np.random.default_rng(15)
    cone = ConeWorkspace.from_rcm(P_RCM, [0.0, 0.0, 0.02], 0.3, 0.25)
    rule = ViewRule(0.01, 0.0025, 1.0, cone_at(cone.constants, 0))
    found = set()
    for _ in range(3000):
        p_c = np.array([0.0, 0.0, 0.02]) + rng.normal(scale=0.02, size=3)
        n = np.array(random_unit(rng))
        s, d = float(rng.choice([-1.0, 1.0])), float(rng.uniform(0.03, 0.08))
        view = view_of(rule, tuple(p_c), tuple(n), s, d)
        found.add(view.found)
        if not view.found:
            assert (rule.aim_floor - p_c[2]) / d > 1.0 or np.hypot(n[0], n[1]) < 1e-6
            continue
        u = np.array(view.u)
        assert abs(np.linalg.norm(u) - 1.0) < ATOL_ORTHO
        camera = p_c + d * u
        assert camera[2] >= rule.aim_floor - ATOL_INV_M
        if s * n[2] * d >= rule.aim_floor - p_c[2]:
            np.testing.assert_allclose(u, s * n, atol=ATOL_UNIT)
            assert view.error == 0.0
        else:
            assert view.error == pytest.approx(math.acos(np.clip(np.dot(u, s * n), -1, 1)))
        assert view.margin == pytest.approx(cone.margin(camera.tolist()), abs=ATOL_M)
    assert found == {True, False}


def test_pose_of_puts_the_left_eye_on_the_axis() -> None:
    """``pose_of`` with a left-eye offset: the eye ``b/2`` left of the centre looks through
    the ring centre from ``r`` along ``u``."""
    rng = np.random.default_rng(16)
    half_b = 0.5 * CAMERA.baseline
    for _ in range(1000):
        p_c, u = rng.normal(scale=0.05, size=3), np.array(random_unit(rng))
        r = float(rng.uniform(0.02, 0.1))
        axes = PreviousAxes(True, random_unit(rng), random_unit(rng))
        x, _, z, p = pose_of(tuple(p_c), tuple(u), r, axes, half_b)
        eye = np.array(p) - half_b * np.array(x)
        np.testing.assert_allclose(eye, p_c + r * u, atol=ATOL_M)
        np.testing.assert_allclose(z, -u, atol=ATOL_UNIT)


def test_twist_of_is_scipys_rotation_vector_over_small_steps() -> None:
    """``twist_of``: the position difference over ``δ`` and, for small turns, scipy's rotation
    vector of ``R_b R_aᵀ`` over ``δ`` (the small-angle skew form: error ~θ³)."""
    rng = np.random.default_rng(17)
    for _ in range(1000):
        Ra = Rotation.random(random_state=rng.integers(1 << 31))
        theta = float(rng.uniform(0.0, 1e-3))  # rad, one control period's turn
        turn = Rotation.from_rotvec(theta * unit(rng.normal(size=3)))
        a, b = np.eye(4), np.eye(4)
        a[:3, :3], b[:3, :3] = Ra.as_matrix(), (turn * Ra).as_matrix()
        a[:3, 3], b[:3, 3] = rng.normal(size=3), rng.normal(size=3)
        delta = float(rng.uniform(1e-3, 0.05))
        v = np.array(twist_of(a, b, delta))
        np.testing.assert_allclose(v[:3], (b[:3, 3] - a[:3, 3]) / delta, rtol=1e-12)
        np.testing.assert_allclose(
            v[3:], turn.as_rotvec() / delta, atol=ATOL_TWIST + theta**3 / delta
        )


def test_ring_predictor_extrapolates_a_quadratic_exactly() -> None:
    """``RingPredictor`` (compiled): a centre on a quadratic in time (and a normal turning
    slowly) is extrapolated as numpy's finite differences say: exactly for the centre."""
    rng = np.random.default_rng(14)
    for spacing in (1, 2, 3):
        pred = RingPredictor(spacing)
        c0, c1, c2 = rng.normal(scale=0.05, size=(3, 3))

        def centre(t: float, c0=c0, c1=c1, c2=c2) -> np.ndarray:  # type: ignore[no-untyped-def]
            return c0 + c1 * t + c2 * t * t

        n0 = np.array(random_unit(rng))
        for k in range(2 * spacing + 1):
            t = k * DT
            pred.push(t, tuple(centre(t)), tuple(n0))
        for h in (0.0, 0.01, float(rng.uniform(0.0, 0.2))):
            p, n = pred.predict(h)
            np.testing.assert_allclose(p, centre(2 * spacing * DT + h), atol=1e-12)
            np.testing.assert_allclose(n, n0, atol=ATOL_UNIT)
    pred = RingPredictor(2)  # fewer samples: the newest one (0), then a line (1)
    pred.push(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    assert pred.predict(0.1)[0] == (0.0, 0.0, 0.0)
    pred.push(0.01, (0.001, 0.0, 0.0), (0.0, 0.0, 1.0))
    pred.push(0.02, (0.002, 0.0, 0.0), (0.0, 0.0, 1.0))
    np.testing.assert_allclose(pred.predict(0.1)[0], (0.012, 0.0, 0.0), atol=ATOL_M)
    pred.reset()
    with pytest.raises(IndexError):
        pred.predict(0.0)


class _GoalNearTheWire(CenteringPolicy):
    """A subclass that moves the compiled step's goal to 2 mm from the wire's surface."""

    NEAR_M = 0.002  # m, well inside the keep-out zone

    def _goal(self, seen: Sighting, previous: np.ndarray) -> tuple[PaperResult, np.ndarray | None]:
        result, goal = super()._goal(seen, previous)
        if goal is None:
            return result, None
        assert self.guard is not None
        goal = goal.copy()
        d, i = self.guard.wire.nearest_surface(goal[:3, 3].tolist())
        toward = self.guard.wire.search_points[i] - goal[:3, 3]
        goal[:3, 3] += toward / np.linalg.norm(toward) * max(d - self.NEAR_M, 0.0)
        return result, goal


def test_a_subclass_changing_the_goal_does_not_skip_the_wire_guard() -> None:
    """The kernel's "cleared" answer is for the pose it checked; a changed goal is checked again.

    Found in review: before the fix half of these commands were inside the keep-out zone.
    """
    cfg = ControllerConfig(**GATE_OFF, jump_threshold=0.2)
    observations = random_observations(0, wire=False)
    T0 = observations[0][1]
    policy = _GoalNearTheWire(cfg)
    policy.reset(context_for(T0, True))
    T_cam = policy._last_cmd
    assert policy.guard is not None and T_cam is not None
    inside = 0
    for t, T_ring, tips in observations:
        cmd = policy.step(Observation(t, T_ring, T_cam, tips))
        d, _ = policy.guard.wire.nearest_surface(cmd.T_world_cam[:3, 3].tolist())
        inside += d < policy.guard.clearance
        T_cam = cmd.T_world_cam
    assert inside == 0


# -- the input checks and the ring gate ------------------------------------------------------


def faulty_observations(seed: int) -> list[tuple[Observation, bool]]:
    """Observations with every fault the checks answer, and whether each is faulty: non-finite
    or missing poses, stale and future stamps, wild jumps the gate rejects (and
    re-acquisitions after ``ring_reacquire``), degenerate normals."""
    rng = np.random.default_rng(seed)
    out = []
    t_lost = -1.0
    for t, T_ring, tips in random_observations(seed, True):
        T_ring = T_ring.copy()
        t_ring: float | None = t - LATENCY
        kind = rng.random()
        faulty = True
        if kind < 0.03:
            T_ring[int(rng.integers(0, 3)), int(rng.integers(0, 4))] = math.nan
        elif kind < 0.05:
            T_ring[int(rng.integers(0, 3)), 3] = rng.choice([math.inf, -math.inf])
        elif kind < 0.07:
            T_ring = None  # type: ignore[assignment]
        elif kind < 0.10:
            t_ring = t - rng.choice([0.5, 5.0, -0.01, math.nan])  # stale, or from the future
        else:
            faulty = False
            if kind < 0.12:
                t_ring = None  # unstamped
            elif kind < 0.17 or t < t_lost:  # far off: the gate rejects, then re-acquires
                T_ring[:3, 3] += [0.05, -0.03, 0.01]
                if kind < 0.135:
                    t_lost = t + float(rng.uniform(0.1, 1.5))
            elif kind < 0.20:
                T_ring[:3, :3] = T_ring[:3, :3] @ np.diag([1.0, -1.0, -1.0])  # the normal flips
            elif kind < 0.22:
                T_ring[:3, 2] = 0.0  # degenerate
        obs = Observation(t, T_ring, None, tips, None, t_ring)  # type: ignore[arg-type]
        out.append((obs, faulty))
    return out


FAULTY = {"endocam": EndocamPolicy, "endocam-visible": VisiblePolicy, **MOVING}


@pytest.mark.parametrize("name", sorted(FAULTY))
def test_faulty_observations_are_answered_by_holding(name: str) -> None:
    """Non-finite, missing, stale and wild observations: each check answers at least once, a
    faulty observation (or camera pose) is answered by holding the last command and working
    distance (``lost_tracking``), and the gate rejects the wild jumps."""
    reasons: set[str] = set()
    rejected = 0
    for seed in range(4):
        policy = FAULTY[name](ControllerConfig())
        obs_seq = faulty_observations(100 + seed)
        T0 = obs_seq[0][0].T_world_ring
        assert T0 is not None
        policy.reset(context_for(T0, True))
        inv = Invariants(policy)
        rng = np.random.default_rng(seed + 7)
        T_cam = policy._last_cmd
        assert T_cam is not None
        for obs, faulty in obs_seq:
            T_obs: object = T_cam
            kind = rng.random()
            if kind < 0.03:
                T_obs = T_cam.copy()
                T_obs[int(rng.integers(0, 4)), int(rng.integers(0, 4))] = math.nan  # type: ignore[index]
                faulty = True
            elif kind < 0.04:
                T_obs = T_cam.tolist()  # a list: converted
            elif kind < 0.05:
                T_obs = np.zeros((3, 4))  # the wrong shape: not a pose
                faulty = True
            cmd = policy.step(obs._replace(T_world_cam=T_obs))
            inv.check(cmd)
            if faulty:
                assert cmd.state is TrackingState.LOST_TRACKING, cmd.reason
            reasons.add(cmd.reason)
            T_cam = cmd.T_world_cam.copy()
            T_cam[:3, 3] += rng.normal(scale=1e-3, size=3)
        rejected += policy._gate.rejected
    expected = {"camera pose not finite; holding", RING_REASON, STALE_REASON, GATE_REASON}
    if name.startswith("endocam"):
        expected.add("ring pose degenerate (zero normal)")
    assert expected <= reasons, expected - reasons  # every check answered at least once
    assert rejected > 0


SLOW_M_S = 0.01  # m/s: the default task's ring speed


def test_the_ring_gate_rejects_jumps_and_reacquires_inside_the_cone() -> None:
    """``RingGate`` (compiled): slow motion passes; a jump beyond the innovation cap is
    rejected and counted; after ``reacquire`` s of agreeing observations, they are accepted
    inside the cone, not outside it."""
    cfg = ControllerConfig()
    cone = ConeWorkspace.from_rcm(P_RCM, [0.0, 0.0, 0.02], 0.3, 0.25)
    n = (0.0, 0.0, 1.0)
    for inside in (True, False):
        gate = cfg.ring_gate()
        gate.reset(cone=cone)
        p = np.array([0.0, 0.0, 0.02])
        t = 0.0
        for _ in range(10):  # slow, steady motion
            t += DT
            p = p + np.array([SLOW_M_S * DT, 0.0, 0.0])
            assert gate.accept(t, p.tolist(), n)
        # beyond the innovation cap: rejected until re-acquired
        far = p + ([0.0, 0.08, 0.0] if inside else [0.0, 0.0, 0.5])
        assert cone.contains(far.tolist()) is inside
        t_accepted = t
        accepted = []
        while t < t_accepted + cfg.ring_reacquire + 3 * DT:  # lost: the far pose, steadily
            t += DT
            accepted.append(gate.accept(t, far.tolist(), n))
        assert not accepted[0] and gate.rejected >= 1
        # re-acquired after ``reacquire`` s, only inside the cone; then it stays accepted
        assert any(accepted) is inside
        if inside:
            first = accepted.index(True)
            assert first * DT >= cfg.ring_reacquire - DT and all(accepted[first:])


# -- the last gate and the goals' margins ----------------------------------------------------


def test_the_last_gate_and_the_goals_margin_are_the_cones() -> None:
    """The tracker's last gate (``inside_kernel``) is ``cone.margin(p) >= 0`` and ``p[2] >=
    min_camera_height − FLOOR_TOL_M``; the paper step's goal margin is ``cone.margin`` of the
    goal (numpy API) to ``ATOL_M``."""
    cfg = ControllerConfig(**GATE_OFF)  # the random ring jitters: the gate opened wide
    policy = EndocamPolicy(cfg)
    obs_seq = random_observations(3, wire=False)
    policy.reset(context_for(obs_seq[0][1], False))
    floor = cfg.min_camera_height - FLOOR_TOL_M
    rng = np.random.default_rng(11)
    apex = np.array(policy.cone.apex)
    cone = cone_at(policy.cone.constants, 0)
    answers = set()
    for _ in range(20_000):
        T = np.eye(4)
        T[:3, 3] = apex + rng.normal(scale=0.15, size=3)
        if rng.random() < 0.3:  # on the floor, within round-off
            T[2, 3] = floor + float(rng.choice([-1e-12, 0.0, 1e-12]))
        if rng.random() < 0.01:
            T[int(rng.integers(0, 3)), 3] = math.nan
        p = T[:3, 3].tolist()
        want = policy.cone.margin(p) >= 0.0 and p[2] >= floor
        assert policy._in_workspace(T) == want
        assert bool(inside_kernel(T, cone, floor)) == want
        answers.add(want)
    assert answers == {True, False}
    for moving in (CenteringPolicy(cfg), OrientationPolicy(cfg)):
        goal = moving._goal
        checked = 0

        def spy(*args: object, goal=goal, moving=moving) -> object:  # type: ignore[no-untyped-def]
            nonlocal checked
            result, pose = goal(*args)
            if pose is not None:
                want = moving.cone.margin(pose[:3, 3].tolist())
                assert result.margin == pytest.approx(want, abs=ATOL_M)
                checked += 1
            return result, pose

        moving._goal = spy  # type: ignore[method-assign]
        for seed in range(2):
            obs_seq = random_observations(seed, wire=False)
            moving.reset(context_for(obs_seq[0][1], False))
            T_cam = moving._last_cmd
            for t, T_ring, tips in obs_seq:
                T_cam = moving.step(Observation(t, T_ring, T_cam, tips)).T_world_cam
        assert checked > STEPS


def test_the_plan_steps_last_gate_on_its_view_is_the_trackers() -> None:
    """``plan_step``'s ``inside`` (the step's last gate when the view is the command) is
    ``inside_kernel`` of the view it wrote, for every view found in random episodes."""
    answers = set()
    for seed, height in enumerate((0.10, 0.25)):
        cfg = ControllerConfig(cone_height=height, **GATE_OFF)
        policy = EndocamPolicy(cfg)
        plan_step = policy._plan_step
        seen: list[tuple[PlanResult, np.ndarray]] = []

        def spy(*args: object, plan_step=plan_step, seen=seen, policy=policy) -> PlanResult:  # type: ignore[no-untyped-def]
            answer = plan_step(*args)
            seen.append((answer, policy._view_T.copy()))
            return answer

        policy._plan_step = spy  # type: ignore[method-assign]
        obs_seq = random_observations(20 + seed, wire=True)
        policy.reset(context_for(obs_seq[0][1], True))
        T_cam = policy._last_cmd
        for t, T_ring, tips in obs_seq:
            T_cam = policy.step(Observation(t, T_ring, T_cam, tips)).T_world_cam
        cone = cone_at(policy.cone.constants, 0)
        for answer, view in seen:
            if answer.check != OBS_OK or not answer.found:
                continue
            want = bool(inside_kernel(view, cone, policy._cmd_floor))
            assert answer.inside == want
            answers.add(want)
    assert answers == {True, False}


def test_the_orientation_waypoint_is_the_cleared_look_at() -> None:
    """``OrientationPolicy._cleared_waypoint`` (one compiled call) is ``_clear`` of
    ``_waypoint_pose`` (two): way-points near the wire, with back-off from ``d_f``."""
    cfg = ControllerConfig()
    new, old = OrientationPolicy(cfg), OrientationPolicy(cfg)
    rng = np.random.default_rng(21)
    pts = WIRE.search_points
    T0 = ring_pose(pts[len(pts) // 2], np.array([0.0, 0.3, 1.0]))
    for policy in (new, old):
        policy.reset(context_for(T0, True))
    answers = set()
    for _ in range(2000):
        k = int(rng.integers(100, len(pts) - 100))
        T_ring = ring_pose(pts[k] + rng.normal(scale=0.002, size=3), rng.normal(size=3))
        tangent = unit(pts[k + 5] - pts[k - 5])
        p = pts[k] + tangent * rng.uniform(0.0, 0.05) + rng.normal(scale=0.01, size=3)
        goal = look_at_pose(T_ring[:3, 3] + [0.0, 0.02, 0.05], T_ring[:3, 3])
        p_ring, p_now = T_ring[:3, 3].tolist(), (p + rng.normal(scale=0.01, size=3)).tolist()
        d_f = float(rng.uniform(cfg.d_min, cfg.d_max))
        got = new._cleared_waypoint(p, T_ring, goal, p_ring, p_now, d_f)
        want = PaperPolicyClear(old, p, T_ring, goal, p_ring, p_now, d_f)
        assert (got is None) == (want is None)
        if want is not None and got is not None:
            np.testing.assert_allclose(got, want, atol=ATOL_M)
        assert new.guard is not None and old.guard is not None
        assert (new.guard.adjusted, new.guard.blocked) == (old.guard.adjusted, old.guard.blocked)
        new._last_cmd = old._last_cmd = got if got is not None else new._last_cmd
        answers.add("none" if want is None else "moved" if new.guard.adjusted else "same")
    assert new.guard is not None and new.guard.adjusted > 0


def PaperPolicyClear(
    policy: OrientationPolicy,
    p: np.ndarray,
    T_ring: np.ndarray,
    goal: np.ndarray,
    p_ring: list[float],
    p_now: list[float],
    d_f: float,
) -> np.ndarray | None:
    """``_clear(_waypoint_pose(p, T_ring, goal), p_ring, p_now, d_f)`` on ``policy``."""
    return policy._clear(policy._waypoint_pose(p, T_ring, goal), p_ring, p_now, d_f)


# -- the working distance: committed only with a command -------------------------------------


def test_a_freeze_does_not_commit_the_working_distance() -> None:
    """With every tip outside the outer window the windows' rule lengthens ``d_f`` each step;
    while the goal is outside the cone the camera freezes and ``d_f`` holds; once back inside
    it resumes from the held value, one step at a time."""
    cfg = ControllerConfig(**GATE_OFF)  # the gate lets it jump
    for policy in (EndocamPolicy(cfg), OrientationPolicy(cfg), CenteringPolicy(cfg)):
        T0 = ring_pose(np.array([0.0, 0.0, 0.03]), np.array([0.0, 0.0, 1.0]))
        policy.reset(context_for(T0, False))
        T_cam = policy._last_cmd
        assert T_cam is not None
        far_tips = np.array([[0.5, 0.5, 0.5]])  # outside every window: d_f grows
        distances, states = [], []
        for k in range(60):
            outside = 10 <= k < 30  # the ring far outside the cone: the goal freezes
            p = [0.0, 0.0, 0.03] if not outside else [0.0, 0.4, 0.03]
            T_ring = ring_pose(np.array(p), np.array([0.0, 0.0, 1.0]))
            obs = Observation(k * DT, T_ring, T_cam, far_tips)
            cmd = policy.step(obs)
            distances.append(cmd.d_f)
            states.append(cmd.state)
            T_cam = cmd.T_world_cam
        frozen = [k for k, s in enumerate(states) if s is TrackingState.FROZEN_OUTSIDE_CONE]
        assert frozen, type(policy).__name__
        for k in frozen:
            assert distances[k] == distances[k - 1]
        issued = (TrackingState.TRACKING, TrackingState.PLANNING)
        moved = [k for k in range(1, 60) if states[k] in issued]
        assert any(distances[k] > distances[k - 1] for k in moved), type(policy).__name__
        for k in moved:
            assert distances[k] - distances[k - 1] <= cfg.d_f_step + ATOL_INV_M
