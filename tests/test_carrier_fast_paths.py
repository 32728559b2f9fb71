"""The carriers' compiled shortcuts give the floats and decisions of the code they replaced.

Each reference below is the interpreted code a shortcut replaced, kept here; each comparison
runs on seeded random inputs (reachable and unreachable goals, commands in and out of range).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import ruckig
from scipy.spatial.transform import Rotation

import reference_carrier as ref_carrier
from endocam.config import ExperimentConfig
from endocam.geometry import make_pose
from endocam.kernels import rotation_angle, so3_exp
from endocam.robot.actuator import ActuatorStatus, ArmKind
from endocam.robot.arm import MotionStatus, SimulatedArm
from endocam.robot.camera_arm import (
    _EPS_AXIS,
    PATH_ENGAGE_AIM_RAD,
    PATH_ENGAGE_M,
    PATH_LEAD_M,
    VIEW_STEPS,
    WRIST_JUMP_RAD,
    CameraArm,
    _is_camera_command,
    _look_at_matrix,
    _path_engage_kernel,
    _port_rotvec_kernel,
    _so3_exp,
    _target_error_kernel,
    _turned_kernel,
    _wrist_jump,
    arm_model,
    natural_pose,
)
from endocam.robot.cartesian import CartesianLimiter, MotionLimits, _stop_bound
from endocam.robot.dh import pose12_between, pose12_times
from endocam.robot.kinematics import LIMIT_SLACK
from endocam.view import look_at_unchecked

N_GOALS = 400  # count: random goals per carrier


def _arm(kind: ArmKind) -> CameraArm:
    cfg = ExperimentConfig()
    T_tip_cam = cfg.episode.T_tip_cam if kind is ArmKind.PSM else np.eye(4)
    return CameraArm(kind, cfg.task.scene.T_world_rcm, T_tip_cam, 0.01)


def _goals(arm: CameraArm, seed: int) -> list[np.ndarray]:
    """Camera poses (4, 4), world, m: reachable ones, and ones turned or moved off them."""
    rng = np.random.default_rng(seed)
    model = arm.model
    out = []
    for i in range(N_GOALS):
        q = model.clamp(natural_pose(model) + rng.uniform(-0.6, 0.6, model.n_joints))
        T = arm.camera_pose(q)
        if i % 2:  # off the reachable set (mostly): turned and moved
            R = Rotation.from_rotvec(rng.normal(0.0, 0.2, 3)).as_matrix()
            T = make_pose(R @ T[:3, :3], T[:3, 3] + rng.normal(0.0, 0.01, 3))
        out.append(T)
    return out


def _exact_reference(arm: CameraArm, T_world_cam: np.ndarray) -> list[float] | None:
    """``CameraArm._exact`` as it was: the goal's products on Python floats, then the IK."""
    rows = tuple(map(tuple, T_world_cam[:3].tolist()))
    goal12 = pose12_times(pose12_times(arm._rcm_world12, rows), arm._cam_tip_rows)
    return arm.model.exact12_unchecked(goal12, arm._q)


@pytest.mark.parametrize("kind", [ArmKind.PSM, ArmKind.ECM])
def test_exact_between_is_the_interpreted_goal_then_ik(kind: ArmKind) -> None:
    arm = _arm(kind)
    found = 0
    for T in _goals(arm, 21 if kind is ArmKind.PSM else 22):
        rows = tuple(map(tuple, T[:3].tolist()))
        expected12 = pose12_times(pose12_times(arm._rcm_world12, rows), arm._cam_tip_rows)
        assert pose12_between(arm._rcm_world12, T, arm._cam_tip_rows) == expected12
        expected = _exact_reference(arm, T)
        assert arm._exact(T) == expected
        found += expected is not None
    assert 0 < found < N_GOALS  # both outcomes exercised


def _is_camera_command_reference(T: np.ndarray, p_rcm: np.ndarray, reach: float) -> bool:
    """``CameraArm.step``'s test of a command as it was (numpy)."""
    finite = bool(np.isfinite(T).all())
    return bool(finite and np.abs(T[:3, 3] - p_rcm).max() <= reach)


def test_camera_command_test_is_the_numpy_one() -> None:
    rng = np.random.default_rng(23)
    p_rcm = rng.normal(0.0, 0.1, 3)
    for _ in range(2000):
        T = make_pose(Rotation.random(random_state=rng).as_matrix(), p_rcm)
        T[:3, 3] += rng.normal(0.0, 1.0, 3) * rng.choice([0.1, 1.0, 10.0, 100.0])
        if rng.random() < 0.2:
            T[rng.integers(4), rng.integers(4)] = rng.choice([np.nan, np.inf, -np.inf])
        for reach in (10.0, float(np.abs(T[:3, 3] - p_rcm).max())):  # also exactly at the reach
            assert _is_camera_command(T, p_rcm, reach) == _is_camera_command_reference(
                T, p_rcm, reach
            )


def _stop_bound_reference(v: list[float], a: list[float], V: float, A: float, J: float) -> float:
    """``CartesianLimiter._stop_bound`` as it was (interpreted)."""
    total = 0.0
    for vi, ai in zip(v, a, strict=True):
        s = min(V, abs(vi) + ai * ai / (2.0 * J))
        d = s * (abs(ai) / J + s / A + A / J)
        total += d * d
    return math.sqrt(total)


def test_stop_bound_is_the_interpreted_one() -> None:
    limiter = CartesianLimiter(MotionLimits(), 0.01)
    V, A, J = limiter._stop_limits
    assert (V, A, J) == (
        limiter._inp.max_velocity[0],
        limiter._inp.max_acceleration[0],
        limiter._inp.max_jerk[0],
    )
    rng = np.random.default_rng(24)
    for _ in range(20000):
        v = (rng.normal(0.0, V, 3) * rng.choice([0.0, 1e-6, 1.0, 3.0], 3)).tolist()
        a = (rng.normal(0.0, A, 3) * rng.choice([0.0, 1e-6, 1.0, 3.0], 3)).tolist()
        assert _stop_bound(*v, *a, V, A, J) == _stop_bound_reference(v, a, V, A, J)


def _path_engage_reference(
    T_cam: np.ndarray, T_target: np.ndarray, look_distance: float
) -> tuple[float, float, list[float], list[float]] | None:
    """``CameraArm._path_target``'s first half as it was: ``None`` or ``(r_cur, alpha, u, c)``."""
    a, b = T_cam.tolist(), T_target.tolist()
    z_t = [b[0][2], b[1][2], b[2][2]]
    c = [b[i][3] + look_distance * z_t[i] for i in range(3)]
    v = [a[i][3] - c[i] for i in range(3)]
    r_cur = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    if not r_cur > _EPS_AXIS:
        return None
    u = [x / r_cur for x in v]
    cos_aim = -(u[0] * a[0][2] + u[1] * a[1][2] + u[2] * a[2][2])
    aim = math.acos(max(-1.0, min(1.0, cos_aim)))
    cos_t = -(u[0] * z_t[0] + u[1] * z_t[1] + u[2] * z_t[2])
    ang = math.acos(max(-1.0, min(1.0, cos_t)))
    travel = math.hypot(look_distance - r_cur, 0.5 * (r_cur + look_distance) * ang)
    if travel <= PATH_ENGAGE_M and aim <= PATH_ENGAGE_AIM_RAD:
        return None
    alpha = min(1.0, PATH_LEAD_M / travel) if travel > 0.0 else 1.0
    if alpha >= 1.0 and aim <= PATH_ENGAGE_AIM_RAD:
        return None
    return r_cur, alpha, u, c


@pytest.mark.parametrize("kind", [ArmKind.PSM, ArmKind.ECM])
def test_path_engage_is_the_interpreted_test(kind: ArmKind) -> None:
    arm = _arm(kind)
    rng = np.random.default_rng(25 if kind is ArmKind.PSM else 26)
    goals = _goals(arm, 27)
    engaged = 0
    for T_target in goals:
        T_cam = goals[rng.integers(len(goals))]
        if rng.random() < 0.3:  # near the target: the path is not taken
            T_cam = T_target.copy()
            T_cam[:3, 3] += rng.normal(0.0, 0.005, 3)
        for look in (0.05, float(rng.uniform(0.001, 0.2))):
            expected = _path_engage_reference(T_cam, T_target, look)
            engage, r_cur, alpha, u0, u1, u2, c0, c1, c2 = _path_engage_kernel(
                T_cam, T_target, look
            )
            assert engage == (expected is not None)
            if expected is not None:
                engaged += 1
                assert (r_cur, alpha, [u0, u1, u2], [c0, c1, c2]) == expected
    assert 0 < engaged < 2 * N_GOALS


def _turned_reference(
    T: np.ndarray, look_distance: float, rotvec: np.ndarray, fraction: float
) -> np.ndarray:
    """``camera_arm._turned`` before r6 (numpy element-wise)."""
    R_turn = so3_exp((fraction * rotvec).tolist())
    z = T[:3, 2].tolist()
    z_t = [R_turn[i][0] * z[0] + R_turn[i][1] * z[1] + R_turn[i][2] * z[2] for i in range(3)]
    c = T[:3, 3] + look_distance * T[:3, 2]
    p_t = c - look_distance * np.array(z_t)
    return look_at_unchecked(p_t, c, T, T)


def test_so3_exp_kernel_is_the_interpreted_one() -> None:
    rng = np.random.default_rng(40)
    for _ in range(20000):
        r = rng.normal(0.0, 1.0, 3) * rng.choice([0.0, 1e-12, 1e-9, 1e-4, 0.1, 1.0, 3.0])
        assert _so3_exp(*r.tolist()).tobytes() == np.array(so3_exp(r.tolist())).tobytes()


def _special_goals(arm: CameraArm, rng: np.random.Generator) -> list[tuple[np.ndarray, float]]:
    """Goals (4, 4) and look distances (m) on the port view's edge cases.

    The look-at point at the port, the camera looking straight at it and straight away.
    """
    p = arm._p_world_rcm
    out = []
    for _ in range(20):
        R = Rotation.random(random_state=rng).as_matrix()
        look = float(rng.uniform(0.01, 0.2))
        z = R[:, 2]
        out.append((make_pose(R, p - look * z), look))  # looks at the port
        out.append((make_pose(R, p - 2.0 * look * z), look))  # straight at it, beyond
        out.append((make_pose(R, p + 0.5 * look * z), look))  # straight away from it
    return out


@pytest.mark.parametrize("kind", [ArmKind.PSM, ArmKind.ECM])
def test_port_view_kernels_are_the_numpy_ones(kind: ArmKind) -> None:
    arm = _arm(kind)
    rng = np.random.default_rng(28)
    turned = missing = 0
    cases = [(T, float(rng.uniform(0.001, 0.2))) for T in _goals(arm, 29)]
    for T, look in cases + _special_goals(arm, rng):
        expected = ref_carrier.port_rotvec(T, look, arm._p_world_rcm)
        found, r0, r1, r2 = _port_rotvec_kernel(T, look, arm._p_world_rcm)
        assert found == (expected is not None)
        if expected is None:
            missing += 1
            continue
        assert np.array([r0, r1, r2]).tobytes() == expected.tobytes()
        for fraction in (1.0, float(rng.integers(0, VIEW_STEPS + 1)) / VIEW_STEPS):
            got = _turned_kernel(T, look, r0, r1, r2, fraction)
            want = ref_carrier.turned(T, look, expected, fraction)
            assert got.tobytes() == want.tobytes()
            assert want.tobytes() == _turned_reference(T, look, expected, fraction).tobytes()
            turned += 1
    assert turned > N_GOALS and missing > 0


def test_look_at_matrix_is_the_interpreted_one() -> None:
    rng = np.random.default_rng(41)
    for i in range(5000):
        T = make_pose(Rotation.random(random_state=rng).as_matrix(), rng.normal(0.0, 0.1, 3))
        p = rng.normal(0.0, 0.1, 3)
        scale = [1.0, 1e-10, 1e-8, 0.0][i % 4]
        c = p + scale * rng.normal(0.0, 0.1, 3)
        if i % 7 == 0:  # straight down or up: the roll of T is kept
            c = p + np.array([0.0, 0.0, rng.choice([-1.0, 1.0])]) * rng.uniform(0.01, 0.1)
            c[:2] += rng.normal(0.0, 1e-3, 2) * rng.choice([0.0, 1.0])
        want = ref_carrier.look_at_unchecked(p, c, T, T)
        got = _look_at_matrix(tuple(p.tolist()), tuple(c.tolist()), T)
        assert got.tobytes() == want.tobytes()
        assert look_at_unchecked(p, c, T, T).tobytes() == want.tobytes()


def _twin_arms(kind: ArmKind) -> tuple[CameraArm, CameraArm]:
    return _arm(kind), _arm(kind)


def _same_answer(got: tuple, want: tuple) -> None:
    assert got[0] == want[0]
    assert np.asarray(got[1]).tobytes() == np.asarray(want[1]).tobytes()
    assert got[2] is want[2]


@pytest.mark.parametrize("kind", [ArmKind.PSM, ArmKind.ECM])
def test_target_is_the_interpreted_one(kind: ArmKind) -> None:
    arm, ref = _twin_arms(kind)
    rng = np.random.default_rng(42 if kind is ArmKind.PSM else 43)
    model = arm.model
    calls = {"solve": 0}
    solve = model.solve_unchecked

    def counted(T, seed):  # the nearest position (scipy) and the rest stay interpreted
        calls["solve"] += 1
        return solve(T, seed)

    model.solve_unchecked = counted  # type: ignore[method-assign]
    statuses: dict[ActuatorStatus, int] = {}
    goals = _goals(arm, 44) + [T for T, _ in _special_goals(arm, rng)]
    for i, T in enumerate(goals):
        if i % 5 == 0:  # a new measured configuration (the IK's seed), and a cold search
            q = model.clamp(natural_pose(model) + rng.uniform(-0.8, 0.8, model.n_joints))
            arm._q, ref._q = q.copy(), q.copy()
            arm._k_prev = ref._k_prev = None
        if i % 3 == 0:  # far off: beyond the reach, out of the axes' limits
            T = T.copy()
            T[:3, 3] += rng.normal(0.0, 0.1, 3)
        look = float(rng.uniform(0.01, 0.3))
        for _ in range(2):  # then nearby: the warm search
            want = ref_carrier.target(ref, T, look)
            got = arm._target_errors(T, look)
            _same_answer(got, want)
            assert got[3:] == ref_carrier.target_errors(want, T)
            assert arm._k_prev == ref._k_prev
            statuses[got[2]] = statuses.get(got[2], 0) + 1
            T = T.copy()
            T[:3, 3] += rng.normal(0.0, 0.002, 3)
    assert set(statuses) == set(ActuatorStatus)
    if kind is ArmKind.ECM:
        assert calls["solve"] > 0  # the nearest in-limit position (scipy) was needed


@pytest.mark.parametrize("kind", [ArmKind.PSM, ArmKind.ECM])
def test_path_target_is_the_interpreted_one(kind: ArmKind) -> None:
    arm, ref = _twin_arms(kind)
    rng = np.random.default_rng(45 if kind is ArmKind.PSM else 46)
    model = arm.model
    goals = _goals(arm, 47)
    taken = 0
    for i, T_target in enumerate(goals):
        q = model.clamp(natural_pose(model) + rng.uniform(-0.6, 0.6, model.n_joints))
        arm._q, ref._q = q.copy(), q.copy()
        T_cam = arm.camera_pose(q) if i % 2 else goals[rng.integers(len(goals))]
        if i % 11 == 0:  # straight behind the look-at point: over the top
            T_cam = T_target.copy()
            T_cam[:3, 3] += (0.05 + 2.0 * 0.05) * T_target[:3, 2]
        arm._T_cam, ref._T_cam = T_cam, T_cam
        for look in (0.05, float(rng.uniform(0.001, 0.2))):
            want = ref_carrier.path_target(ref, T_target, look)
            got = arm._path_target(T_target, look)
            assert got == want
            taken += want is not None
    assert 0 < taken < 2 * N_GOALS


class _ReferenceArm(SimulatedArm):
    """``SimulatedArm`` with its control cycle as it was (the limit loop on every cycle)."""

    def _cycle(self) -> bool:
        inp, out = self._inp, self._out
        try:
            result = self._otg.update(inp, out)
        except ruckig.RuckigError:
            result = self._retry(inp, out)
        if result not in (ruckig.Result.Working, ruckig.Result.Finished):
            raise RuntimeError(f"ruckig failed: {result}")
        pos = list(out.new_position)
        vel = list(out.new_velocity)
        acc = list(out.new_acceleration)
        hit = False
        rounded = False
        for i, (lo, hi) in enumerate(zip(self._lower, self._upper, strict=True)):
            if pos[i] < lo or pos[i] > hi:
                overshoot = lo - pos[i] if pos[i] < lo else pos[i] - hi
                pos[i] = lo if pos[i] < lo else hi
                if overshoot <= LIMIT_SLACK:
                    rounded = True
                    continue
                vel[i] = 0.0
                acc[i] = 0.0
                hit = True
        if hit or rounded:
            inp.current_position = pos
            inp.current_velocity = vel
            inp.current_acceleration = acc
        else:
            out.pass_to_input(inp)
        self._q = np.array(pos)
        self._qd = np.array(vel)
        self._qdd = np.array(acc)
        self._time += self._dt
        if hit:
            self._motion_status = MotionStatus.LIMIT_STOP
        elif result == ruckig.Result.Finished:
            self._motion_status = MotionStatus.FINISHED
        else:
            self._motion_status = MotionStatus.MOVING
        return hit


@pytest.mark.parametrize("kind", [ArmKind.PSM, ArmKind.ECM])
def test_arm_cycle_is_the_interpreted_one(kind: ArmKind) -> None:
    model = arm_model(kind)
    arm, ref = SimulatedArm(model, dt=0.01), _ReferenceArm(model, dt=0.01)
    rng = np.random.default_rng(30)
    stops = 0
    for step in range(3000):
        if step % 40 == 0:  # a new set point: inside, at a limit, or beyond one
            q = rng.uniform(model.lower, model.upper)
            at_limit = rng.random(model.n_joints) < 0.3
            side = np.where(rng.random(model.n_joints) < 0.5, model.lower, model.upper)
            q[at_limit] = side[at_limit]
            arm.servo_jp(q)
            ref.servo_jp(q)
        if step % 500 == 250:  # a state moving into a limit: a hard stop
            q0 = model.lower + 1e-4
            qd0 = -np.ones(model.n_joints) * 0.05
            arm.reset(q0, qd0)
            ref.reset(q0, qd0)
            arm.servo_jp(model.lower)
            ref.servo_jp(model.lower)
        status, status_ref = arm.step(), ref.step()
        assert status is status_ref
        stops += status is MotionStatus.LIMIT_STOP
        for got, want in zip(arm.measured_js(), ref.measured_js(), strict=True):
            assert got.tobytes() == want.tobytes()
        assert arm.measured_ja().tobytes() == ref.measured_ja().tobytes()
    assert stops > 0


def test_target_error_is_the_interpreted_one() -> None:
    """``CameraArm.step``'s errors as they were: numpy's norm, the interpreted rotation angle."""
    rng = np.random.default_rng(31)
    for _ in range(5000):
        A = make_pose(Rotation.random(random_state=rng).as_matrix(), rng.normal(0.0, 0.1, 3))
        turn = rng.normal(0.0, 1.0, 3) * rng.choice([1e-9, 1e-4, 0.1, 3.0])
        shift = rng.normal(0.0, 0.01, 3) * rng.choice([0.0, 1e-9, 1.0])
        B = make_pose(Rotation.from_rotvec(turn).as_matrix() @ A[:3, :3], A[:3, 3] + shift)
        d = A[:3, 3] - B[:3, 3]
        expected = (math.sqrt(d.dot(d)), rotation_angle(A[:3, :3].tolist(), B[:3, :3].tolist()))
        assert _target_error_kernel(A, B, 2.0) == expected
        assert expected[0] == float(np.linalg.norm(d))
        assert _target_error_kernel(B, B, 2.0) == (0.0, rotation_angle(B.tolist(), B.tolist()))


def test_wrist_jump_is_the_interpreted_max() -> None:
    """``_wrist_jump`` unrolled: the answer of ``max([|a - b| ...]) > WRIST_JUMP_RAD``.

    Python's ``max`` keeps its first item unless a later one compares greater, so a NaN
    first wins and a NaN later loses: the unrolled comparisons keep that order.
    """
    rng = np.random.default_rng(41)
    special = [0.0, 1.0, math.nan, math.inf, -math.inf]
    for _ in range(5000):
        a, b = rng.normal(0.0, 0.8, 6).tolist(), rng.normal(0.0, 0.8, 6).tolist()
        for q in (a, b):
            if rng.random() < 0.3:
                q[int(rng.integers(3, 6))] = special[int(rng.integers(0, len(special)))]
        expected = max([abs(x - y) for x, y in zip(a[3:], b[3:], strict=True)]) > WRIST_JUMP_RAD
        assert _wrist_jump(ArmKind.PSM, a, b) == expected
        assert not _wrist_jump(ArmKind.ECM, a[:4], b[:4])
