"""The compiled control steps are the interpreted ones, bit for bit (docs/conventions.md).

``endocam.control.tracker._plan_kernel`` compiles the ``endocam`` step's maths from the working
distance to the view and its feed-forward twist, ``control.policies._step_kernel`` the moving
policies' working distance and goal (``orientation_goal``); with them ``view.rotation_columns``,
``control.goal``'s ``choose_side`` / ``goal_columns``, ``control.safety``'s ``window_code`` /
``adjusted_distance`` / ``cone_margin`` and the tracker's ``_view_of``, ``_choose_of``,
``_shortened_of``, ``_pose_of``, ``_twist_of``, ``_ring_push``, ``_ring_predict``. Each is
compared here with the interpreted code it replaced (``tests/reference_control.py``, a copy of
main before the change) on seeded random inputs: whole random episodes step by step (every
branch of the step: side changes, orbits, way-points, height-limited views, shortening, the
windows, the paper's side rule, the wire clearance, degenerate ring poses), the centering and
orientation policies', the oracle's, and the pieces one by one.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numba import njit

import reference_control as ref
from endocam.config import CameraConfig
from endocam.control import policies, tracker
from endocam.control.config import ControllerConfig, SideRule, TrackerConfig, Transfer
from endocam.control.goal import goal_pose_unchecked
from endocam.control.oracle import OraclePolicy
from endocam.control.policies import CenteringPolicy, OrientationPolicy, _MovingPolicy
from endocam.control.tracker import EndocamPolicy, RingPredictor
from endocam.control.types import CameraCommand, Observation, PolicyContext
from endocam.control.windows import (
    ImageWindows,
    WindowGeometry,
    WindowStatus,
    adjust_working_distance,
    window_status_rows,
)
from endocam.task.config import WireConfig
from endocam.task.wire import Wire
from endocam.view import look_at_pose, rotation_columns
from endocam.workspace.cone import ConeWorkspace

DT = 0.01  # s, control period
LATENCY = 0.05  # s, sensing delay
STEPS = 300  # control steps per random episode
CAMERA = CameraConfig().stereo()
P_RCM = np.array([0.2, 0.0, 0.12])  # m, the default scene's camera port
WIRE = Wire(WireConfig())  # the default task's wire, world, m


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


def same_command(a: CameraCommand, b: CameraCommand) -> bool:
    """Whether two commands are equal bit for bit (pose, state, look distance, reason, twist)."""
    if (a.twist is None) != (b.twist is None):
        return False
    twist = a.twist is None or a.twist.tobytes() == np.asarray(b.twist).tobytes()
    return bool(
        a.T_world_cam.tobytes() == np.asarray(b.T_world_cam, dtype=float).tobytes()
        and a.state is b.state
        and repr(a.d_f) == repr(b.d_f)
        and a.reason == b.reason
        and twist
    )


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


def run_both(
    policy: _MovingPolicy, reference: object, seed: int, wire: bool, follows_twist: bool
) -> int:
    """Step both policies on the same observations; assert equal commands; return the count."""
    obs_seq = random_observations(seed, wire)
    T0 = obs_seq[0][1]
    T_cam = look_at_pose(T0[:3, 3] + [0.03, 0.01, 0.04], T0[:3, 3])  # a tilted start view
    context = PolicyContext(
        CAMERA,
        T_cam,
        T0,
        P_RCM,
        DT,
        LATENCY,
        follows_twist=follows_twist,
        wire=WIRE if wire else None,
    )
    policy.reset(context)
    reference.reset(context)  # type: ignore[attr-defined]
    rng = np.random.default_rng(seed + 1)
    for k, (t, T_ring, tips) in enumerate(obs_seq):
        obs = Observation(t, T_ring, T_cam, tips)
        got, want = policy.step(obs), reference.step(obs)  # type: ignore[attr-defined]
        assert same_command(got, want), f"step {k}: {got} != {want}"
        if isinstance(policy, EndocamPolicy):
            assert policy._side == reference._side  # type: ignore[attr-defined]
            assert policy.transfers == reference.transfers  # type: ignore[attr-defined]
        # an imperfect carrier: part of the way to the command, a little off
        T_cam = got.T_world_cam.copy()
        if rng.random() < 0.5:
            T_cam[:3, 3] += rng.normal(scale=2e-3, size=3)
    return len(obs_seq)


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
def test_random_episodes_match_the_interpreted_tracker(name: str, wire: bool) -> None:
    tracker = TrackerConfig.model_validate(TRACKERS[name])
    for seed, (rule, centre, follows) in enumerate(
        [
            (SideRule.PORT, True, True),
            (SideRule.UP, False, True),
            (SideRule.PORT, True, False),
        ]
    ):
        cfg = ControllerConfig(
            tracker=tracker,
            side_rule=rule,
            centre_left_eye=centre,
            ring_max_speed=10.0,  # the normal jumps: the gate is opened wide
            ring_max_rate=1000.0,
        )
        policy, reference = EndocamPolicy(cfg), ref.InterpretedEndocamPolicy(cfg)
        assert run_both(policy, reference, 10 * seed + len(name), wire, follows) == STEPS


MOVING = {
    "centering": (CenteringPolicy, ref.InterpretedCenteringPolicy),
    "orientation": (OrientationPolicy, ref.InterpretedOrientationPolicy),
}


@pytest.mark.parametrize("wire", [False, True])
@pytest.mark.parametrize("name", sorted(MOVING))
def test_random_episodes_match_the_interpreted_moving_policies(name: str, wire: bool) -> None:
    new, old = MOVING[name]
    for seed, (rule, centre) in enumerate(
        [(SideRule.PORT, True), (SideRule.UP, False), (SideRule.UP, True)]
    ):
        cfg = ControllerConfig(
            side_rule=rule, centre_left_eye=centre, ring_max_speed=10.0, ring_max_rate=1000.0
        )
        policy, reference = new(cfg), old(cfg)
        assert run_both(policy, reference, 100 + 10 * seed + len(name), wire, True) == STEPS


def test_the_random_episodes_reach_every_branch() -> None:
    """The episodes above change side, orbit, detour, see every window status, and the kernel
    checks the guard itself (a clear view, with and without a detour) or leaves it to Python."""
    cfg = ControllerConfig(ring_max_speed=10.0, ring_max_rate=1000.0)
    policy = EndocamPolicy(cfg)
    reasons, statuses, distances, guarded = set(), set(), set(), set()
    geometry = WindowGeometry.of(CAMERA, cfg.windows)
    for seed in range(3):
        obs_seq = random_observations(seed, wire=True)
        T0 = obs_seq[0][1]
        T_cam = np.eye(4)
        T_cam[:3, 3] = T0[:3, 3] + [0.03, 0.0, 0.04]
        policy.reset(PolicyContext(CAMERA, T_cam, T0, P_RCM, DT, LATENCY, wire=WIRE))
        for t, T_ring, tips in obs_seq:
            statuses.add(window_status_rows(geometry, T_cam.tolist(), tips.tolist()))
            cmd = policy.step(Observation(t, T_ring, T_cam, tips))
            reasons.add(cmd.reason.split(" ")[0])
            out = policy._out  # the kernel's own guard check and trace (the plain path)
            guarded.add((out[tracker._OUT_CLEARED], out[tracker._OUT_DETOUR]))
            distances.add(round(cmd.d_f, 6))
            T_cam = cmd.T_world_cam
    assert statuses == set(WindowStatus)
    assert {"", "orbiting", "detouring"} <= reasons
    assert len(distances) > 10
    assert guarded == {(0.0, 0.0), (1.0, 0.0), (1.0, 1.0)}
    both: set[tuple[float, float]] = set()
    for moving in (CenteringPolicy(cfg), OrientationPolicy(cfg)):  # their kernel's guard path
        guarded = set()
        for seed in range(4):
            obs_seq = random_observations(seed, wire=True)
            T0 = obs_seq[0][1]
            T_cam = look_at_pose(T0[:3, 3] + [0.03, 0.01, 0.04], T0[:3, 3])
            moving.reset(PolicyContext(CAMERA, T_cam, T0, P_RCM, DT, LATENCY, wire=WIRE))
            for t, T_ring, tips in obs_seq:
                T_cam = moving.step(Observation(t, T_ring, T_cam, tips)).T_world_cam
                out = moving._step_out
                guarded.add((out[policies._OUT_CLEARED], out[policies._OUT_DETOUR]))
        assert (1.0, 0.0) in guarded, type(moving).__name__
        both |= guarded
    assert (1.0, 1.0) in both  # a detour traced by the kernel


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
def test_the_oracle_matches_the_interpreted_oracle(plan: bool) -> None:
    from endocam.control.oracle import OracleConfig

    cfg = ControllerConfig(ring_max_speed=10.0, ring_max_rate=1000.0)
    oracle_cfg = OracleConfig(plan=plan)
    policy, reference = OraclePolicy(cfg, oracle_cfg), ref.InterpretedOraclePolicy(cfg, oracle_cfg)
    context = oracle_context()
    policy.reset(context)
    reference.reset(context)
    assert policy._plan == reference._plan
    T_cam = context.T_world_cam
    rng = np.random.default_rng(3)
    for k in range(STEPS):
        tips = context.T_world_ring[:3, 3] + rng.normal(scale=0.02, size=(2, 3))
        obs = Observation(k * DT, context.T_world_ring, T_cam, tips)
        got, want = policy.step(obs), reference.step(obs)
        assert same_command(got, want), f"step {k}"
        T_cam = got.T_world_cam


# -- the pieces, one by one ----------------------------------------------------------------------


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


@njit(cache=False)
def _columns_compiled(z, up, x_prev, has_prev):  # type: ignore[no-untyped-def]
    if has_prev:
        return rotation_columns(z, up, x_prev)
    return rotation_columns(z, up, None)


def test_rotation_columns_interpreted_and_compiled_match_the_reference() -> None:
    rng = np.random.default_rng(11)
    up = (0.0, 0.0, 1.0)
    for _ in range(3000):
        z = random_unit(rng)
        has_prev = rng.random() < 0.8
        x_prev = random_unit(rng) if rng.random() < 0.5 else z  # z itself: no reference roll
        want = ref.rotation_columns(z, up, x_prev if has_prev else None)
        assert rotation_columns(z, up, x_prev if has_prev else None) == want
        assert _columns_compiled(z, up, x_prev, has_prev) == want


def test_goal_pose_matches_the_reference() -> None:
    rng = np.random.default_rng(12)
    up = (0.0, 0.0, 1.0)
    for _ in range(3000):
        p_c = tuple(rng.normal(scale=0.05, size=3).tolist())
        n = random_unit(rng)
        d = float(rng.uniform(0.02, 0.1))
        previous = None
        if rng.random() < 0.8:
            previous = np.eye(4)
            previous[:3, 0] = random_unit(rng)
            previous[:3, 2] = random_unit(rng)
        hysteresis = float(rng.uniform(0.0, 1.0))
        min_height = float(rng.choice([-math.inf, rng.uniform(-0.1, 0.1)]))
        toward = random_unit(rng) if rng.random() < 0.5 else None
        args = (p_c, n, d, up, previous, hysteresis, min_height, toward)
        got = goal_pose_unchecked(*args)
        assert got.tobytes() == ref.goal_pose_unchecked(*args).tobytes()


def test_windows_cone_and_distance_match_the_reference() -> None:
    rng = np.random.default_rng(13)
    geometry = WindowGeometry.of(CAMERA, ImageWindows())
    cone = ConeWorkspace.from_rcm(P_RCM, [0.0, 0.0, 0.04], 0.3)
    for _ in range(2000):
        T = ring_pose(rng.normal(scale=0.05, size=3), rng.normal(size=3))
        tips = T[:3, 3] + rng.normal(scale=rng.choice([0.005, 0.02, 0.1]), size=(3, 3))
        tips[: int(rng.integers(0, 4))] += [0.0, 0.0, 0.2]
        if rng.random() < 0.1:
            tips[0, 0] = math.nan
        rows, tip_rows = T.tolist(), tips.tolist()
        status = window_status_rows(geometry, rows, tip_rows)
        assert status is ref.window_status_rows(geometry, rows, tip_rows)
        d = float(rng.uniform(0.0, 0.1))
        args = (d, status, 0.03, 0.08, 1e-3)
        assert repr(adjust_working_distance(*args)) == repr(ref.adjust_working_distance(*args))
        p = (P_RCM + rng.normal(scale=0.2, size=3)).tolist()
        assert repr(cone.margin(p)) == repr(ref.cone_margin(cone, p))
    assert math.isnan(cone.margin([math.nan, 0.0, 0.0]))


def test_ring_predictor_matches_the_reference() -> None:
    rng = np.random.default_rng(14)
    for spacing in (1, 2, 3):
        got, want = RingPredictor(spacing), ref.InterpretedRingPredictor(spacing)
        t = 0.0
        for k in range(40):
            if rng.random() < 0.1:
                got.reset()
                want.reset()
            t += float(rng.choice([DT, 0.0, 0.02]))  # repeated stamps: no velocity
            p = tuple(rng.normal(scale=0.05, size=3).tolist())
            n = random_unit(rng) if rng.random() < 0.9 else (0.0, 0.0, 0.0)
            got.push(t, p, n)
            want.push(t, p, n)
            for h in (0.0, 0.01, float(rng.uniform(0.0, 0.2))):
                assert got.predict(h) == want.predict(h), (spacing, k, h)


class _GoalNearTheWire(CenteringPolicy):
    """A subclass that moves the compiled step's goal to 2 mm from the wire's surface."""

    NEAR_M = 0.002  # m, well inside the keep-out zone

    def _goal(self, obs: Observation, T_cam: np.ndarray, T_ring: np.ndarray) -> np.ndarray | None:
        goal = super()._goal(obs, T_cam, T_ring)
        if goal is None:
            return None
        assert self.guard is not None
        goal = goal.copy()
        d, i = self.guard.wire.nearest_surface(goal[:3, 3].tolist())
        toward = self.guard.wire.search_points[i] - goal[:3, 3]
        goal[:3, 3] += toward / np.linalg.norm(toward) * max(d - self.NEAR_M, 0.0)
        return goal


def test_a_subclass_changing_the_goal_does_not_skip_the_wire_guard() -> None:
    """The kernel's "cleared" answer is for the pose it checked; a changed goal is checked again.

    Found in review: before the fix half of these commands were inside the keep-out zone.
    """
    cfg = ControllerConfig(ring_max_speed=10.0, ring_max_rate=1000.0, jump_threshold=0.2)
    observations = random_observations(0, wire=False)
    T0 = observations[0][1]
    T_cam = look_at_pose(T0[:3, 3] + [0.03, 0.01, 0.04], T0[:3, 3])
    policy = _GoalNearTheWire(cfg)
    policy.reset(PolicyContext(CAMERA, T_cam, T0, P_RCM, DT, LATENCY, wire=WIRE))
    assert policy.guard is not None
    inside = 0
    for t, T_ring, tips in observations:
        cmd = policy.step(Observation(t, T_ring, T_cam, tips))
        d, _ = policy.guard.wire.nearest_surface(cmd.T_world_cam[:3, 3].tolist())
        inside += d < policy.guard.clearance
        T_cam = cmd.T_world_cam
    assert inside == 0


# -- the input checks and the ring gate (r7-ctrl: compiled into the steps) -------------------


def faulty_observations(seed: int) -> list[Observation]:
    """Observations with every fault the checks answer: non-finite or missing poses, stale
    and future stamps, wild jumps the gate rejects (and re-acquisitions after
    ``ring_reacquire``), degenerate normals; the camera pose given as the command before."""
    rng = np.random.default_rng(seed)
    out = []
    base = random_observations(seed, True)
    t_lost = -1.0
    for t, T_ring, tips in base:
        T_ring = T_ring.copy()
        t_ring: float | None = t - LATENCY
        kind = rng.random()
        if kind < 0.03:
            T_ring[int(rng.integers(0, 3)), int(rng.integers(0, 4))] = math.nan
        elif kind < 0.05:
            T_ring[int(rng.integers(0, 3)), 3] = rng.choice([math.inf, -math.inf])
        elif kind < 0.07:
            T_ring = None  # type: ignore[assignment]
        elif kind < 0.10:
            t_ring = t - rng.choice([0.5, 5.0, -0.01, math.nan])  # stale, or from the future
        elif kind < 0.12:
            t_ring = None  # unstamped
        elif kind < 0.17 or t < t_lost:  # far off: the gate rejects, then re-acquires
            T_ring[:3, 3] += [0.05, -0.03, 0.01]
            if kind < 0.135:
                t_lost = t + float(rng.uniform(0.1, 1.5))
        elif kind < 0.20:
            T_ring[:3, :3] = T_ring[:3, :3] @ np.diag([1.0, -1.0, -1.0])  # the normal flips
        elif kind < 0.22:
            T_ring[:3, 2] = 0.0  # degenerate
        out.append(Observation(t, T_ring, None, tips, None, t_ring))  # type: ignore[arg-type]
    return out


def run_faulty(policy: _MovingPolicy, reference: object, seed: int) -> list[str]:
    """Step both on :func:`faulty_observations`; assert equal commands; return the reasons."""
    obs_seq = faulty_observations(seed)
    T0 = obs_seq[0].T_world_ring
    T_cam = look_at_pose(T0[:3, 3] + [0.03, 0.01, 0.04], T0[:3, 3])
    context = PolicyContext(CAMERA, T_cam, T0, P_RCM, DT, LATENCY, wire=WIRE)
    policy.reset(context)
    reference.reset(context)  # type: ignore[attr-defined]
    rng = np.random.default_rng(seed + 7)
    reasons = []
    for k, obs in enumerate(obs_seq):
        T_obs: object = T_cam
        kind = rng.random()
        if kind < 0.03:
            T_obs = T_cam.copy()
            T_obs[int(rng.integers(0, 4)), int(rng.integers(0, 4))] = math.nan  # type: ignore[index]
        elif kind < 0.04:
            T_obs = T_cam.tolist()  # a list: converted
        elif kind < 0.05:
            T_obs = np.zeros((3, 4))  # the wrong shape: not a pose
        obs = obs._replace(T_world_cam=T_obs)
        got, want = policy.step(obs), reference.step(obs)  # type: ignore[attr-defined]
        assert same_command(got, want), f"step {k}: {got} != {want}"
        assert policy._gate.rejected == reference._gate.rejected  # type: ignore[attr-defined]
        reasons.append(got.reason)
        T_cam = got.T_world_cam.copy()
        T_cam[:3, 3] += rng.normal(scale=1e-3, size=3)
    return reasons


FAULTY = {
    "endocam": (EndocamPolicy, ref.InterpretedEndocamPolicy),
    **MOVING,
}


@pytest.mark.parametrize("name", sorted(FAULTY))
def test_faulty_observations_match_the_interpreted_checks(name: str) -> None:
    """Non-finite, missing, stale and wild observations: the compiled checks and gate answer
    as the interpreted ones did, command for command, with the same rejections."""
    new, old = FAULTY[name]
    reasons: set[str] = set()
    for seed in range(4):
        cfg = ControllerConfig()
        reasons |= set(run_faulty(new(cfg), old(cfg), 100 + seed))
    expected = {
        "camera pose not finite; holding",
        "ring pose missing or not finite",
        policies.STALE_REASON,
        policies.GATE_REASON,
    }
    if name == "endocam":
        expected.add("ring pose degenerate (zero normal)")
    assert expected <= reasons, expected - reasons  # every check answered at least once


def test_compiled_gate_is_the_interpreted_gate() -> None:
    """``RingGate`` (compiled) and the interpreted gate: the same answers and rejections on
    random observations, jumps, turns, gaps and re-acquisitions inside and outside a cone."""
    cfg = ControllerConfig()
    cone = ConeWorkspace.from_rcm(P_RCM, [0.0, 0.0, 0.02], 0.3, 0.25)
    rng = np.random.default_rng(5)
    answers = set()
    for trial in range(20):
        gate, old = cfg.ring_gate(), ref.InterpretedRingGate.of(cfg)
        if trial % 2:
            gate.reset(cone=cone)
            old.reset(cone.contains)
        p, n = np.array([0.0, 0.0, 0.03]), np.array([0.0, 0.0, 1.0])
        t = 0.0
        for _ in range(300):
            t += float(rng.choice([DT, DT, DT, 0.0, 0.3, 2.0, -DT]))
            kind = rng.random()
            if kind < 0.1:
                q = p + rng.normal(scale=0.3, size=3)  # a wild pose (maybe outside the cone)
            else:
                q = p + rng.normal(scale=1e-3, size=3)
            m = unit(n + rng.normal(scale=0.3 if kind > 0.9 else 0.01, size=3))
            if rng.random() < 0.5:
                p, n = q, m
            x_p, x_n = q.tolist(), m.tolist()
            a, b = gate.accept(t, x_p, x_n), old.accept(t, x_p, x_n)
            assert a == b
            assert gate.rejected == old.rejected
            answers.add(a)
    assert answers == {True, False}


def test_the_last_gate_and_the_goals_margin_are_the_cones() -> None:
    """The tracker's last gate (``_inside_kernel``) is ``cone.margin(p) >= 0`` and ``p[2] >=
    min_camera_height − FLOOR_TOL_M``; the moving policies' goal margin (``_OUT_MARGIN``) is
    ``cone.margin`` of the goal, bit for bit."""
    cfg = ControllerConfig()
    policy = EndocamPolicy(cfg)
    obs_seq = random_observations(3, wire=False)
    T0 = obs_seq[0][1]
    T_cam = look_at_pose(T0[:3, 3] + [0.03, 0.01, 0.04], T0[:3, 3])
    policy.reset(PolicyContext(CAMERA, T_cam, T0, P_RCM, DT, LATENCY))
    floor = cfg.min_camera_height - tracker.FLOOR_TOL_M
    rng = np.random.default_rng(11)
    apex = np.array(policy.cone.apex)
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
        answers.add(want)
    assert answers == {True, False}
    for moving in (CenteringPolicy(cfg), OrientationPolicy(cfg)):
        checked = 0
        for seed in range(2):
            obs_seq = random_observations(seed, wire=False)
            T0 = obs_seq[0][1]
            T_cam = look_at_pose(T0[:3, 3] + [0.03, 0.01, 0.04], T0[:3, 3])
            moving.reset(PolicyContext(CAMERA, T_cam, T0, P_RCM, DT, LATENCY))
            for t, T_ring, tips in obs_seq:
                T_cam = moving.step(Observation(t, T_ring, T_cam, tips)).T_world_cam
                margin = float(moving._step_out[policies._OUT_MARGIN])
                if not math.isnan(margin):
                    assert repr(margin) == repr(moving.cone.margin(moving._kernel_p))
                    checked += 1
        assert checked > STEPS


def test_the_plan_kernels_last_gate_on_its_view_is_the_trackers() -> None:
    """``_plan_kernel``'s ``_OUT_INSIDE`` (the step's last gate when the view is the command)
    is ``_inside_kernel`` of the view it wrote, for every view found in random episodes."""
    answers = set()
    for seed, height in enumerate((0.10, 0.25)):
        cfg = ControllerConfig(cone_height=height, ring_max_speed=10.0, ring_max_rate=1000.0)
        policy = EndocamPolicy(cfg)
        plan_view = policy._plan_view
        seen: list[tuple[list[float], np.ndarray]] = []

        def spy(*args: object, plan_view=plan_view, seen=seen) -> object:  # type: ignore[no-untyped-def]
            out, view, twist = plan_view(*args)
            seen.append((out, view.copy()))
            return out, view, twist

        policy._plan_view = spy  # type: ignore[method-assign]
        obs_seq = random_observations(20 + seed, wire=True)
        T0 = obs_seq[0][1]
        T_cam = look_at_pose(T0[:3, 3] + [0.03, 0.01, 0.04], T0[:3, 3])
        policy.reset(PolicyContext(CAMERA, T_cam, T0, P_RCM, DT, LATENCY, wire=WIRE))
        for t, T_ring, tips in obs_seq:
            T_cam = policy.step(Observation(t, T_ring, T_cam, tips)).T_world_cam
        floor = policy._cmd_floor
        for out, view in seen:
            if out[tracker._OUT_CHECK] != policies.OBS_OK or not out[tracker._OUT_FOUND]:
                continue
            want = bool(tracker._inside_kernel(view, policy._params, floor))
            assert (out[tracker._OUT_INSIDE] == 1.0) == want
            answers.add(want)
    assert answers == {True, False}


def test_the_orientation_waypoint_is_the_cleared_look_at() -> None:
    """``OrientationPolicy._cleared_waypoint`` (one compiled call) is ``_clear`` of
    ``_waypoint_pose``, as the step asked before: way-points near the wire, with back-off."""
    cfg = ControllerConfig()
    new, old = OrientationPolicy(cfg), OrientationPolicy(cfg)
    rng = np.random.default_rng(21)
    pts = WIRE.search_points
    T0 = ring_pose(pts[len(pts) // 2], np.array([0.0, 0.3, 1.0]))
    T_cam = look_at_pose(T0[:3, 3] + [0.03, 0.01, 0.04], T0[:3, 3])
    for policy in (new, old):
        policy.reset(PolicyContext(CAMERA, T_cam, T0, P_RCM, DT, LATENCY, wire=WIRE))
    answers = set()
    for _ in range(2000):
        k = int(rng.integers(100, len(pts) - 100))
        T_ring = ring_pose(pts[k] + rng.normal(scale=0.002, size=3), rng.normal(size=3))
        tangent = unit(pts[k + 5] - pts[k - 5])
        p = pts[k] + tangent * rng.uniform(0.0, 0.05) + rng.normal(scale=0.01, size=3)
        goal = look_at_pose(T_ring[:3, 3] + [0.0, 0.02, 0.05], T_ring[:3, 3])
        p_ring, p_now = T_ring[:3, 3].tolist(), (p + rng.normal(scale=0.01, size=3)).tolist()
        d_f = float(rng.uniform(cfg.d_min, cfg.d_max))
        new.d_f = old.d_f = d_f
        got = new._cleared_waypoint(p, T_ring, goal, p_ring, p_now)
        want = old._clear(old._waypoint_pose(p, T_ring, goal), p_ring, p_now)
        assert (got is None) == (want is None)
        if want is not None:
            assert got.tobytes() == want.tobytes()
        assert new.guard.refs == old.guard.refs  # type: ignore[union-attr]
        assert (new.guard.adjusted, new.guard.blocked) == (old.guard.adjusted, old.guard.blocked)  # type: ignore[union-attr]
        new._last_cmd = old._last_cmd = got if got is not None else new._last_cmd
        answers.add("none" if want is None else "moved" if new.guard.adjusted else "same")
    assert new.guard.adjusted > 0 and new.guard.blocked >= 0  # type: ignore[union-attr]
