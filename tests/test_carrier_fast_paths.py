"""The camera arm's compiled targets agree with numpy and scipy, and keep their promises.

Each kernel of ``robot.arm_targets`` is held to the checked numpy API (scipy's ``Rotation``,
``view.look_at_unchecked``, the arm model's FK) by named tolerances on seeded random goals
(reachable and unreachable, at the port view's singular cases), and ``CameraArm``'s targets to
what they promise: an exact target is the goal, a conceded view looks at the goal's look-at
point, every target lies within the joint limits.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import ruckig
from scipy.spatial.transform import Rotation

from endocam.config import ExperimentConfig
from endocam.geometry import make_pose
from endocam.robot.actuator import ActuatorStatus, ArmKind
from endocam.robot.arm import MotionStatus, SimulatedArm
from endocam.robot.arm_targets import (
    EPS_AXIS,
    PATH_ENGAGE_AIM_RAD,
    PATH_ENGAGE_M,
    PATH_LEAD_M,
    VIEW_POSITION_TOL_M,
    VIEW_STEPS,
    WRIST_JUMP_RAD,
    exact_joints,
    is_camera_command,
    look_at_matrix,
    path_start,
    port_rotvec,
    target_error,
    tip_goal12,
    turned_pose,
    wrist_jump,
)
from endocam.robot.camera_arm import CameraArm, arm_model, natural_pose
from endocam.robot.carriers import arm_mount
from endocam.robot.dh import pose12_to_matrix
from endocam.robot.ecm import ECM_IK_MIN_INSERTION
from endocam.robot.ik import IK_ORIENTATION_TOL_RAD, IK_POSITION_TOL_M
from endocam.robot.kinematics import LIMIT_SLACK
from endocam.view import look_at_unchecked

N_GOALS = 400  # count: random goals per carrier
ECM_TIP_BEYOND_SHAFT_M = 0.3829 - 0.3822  # m: the ECM tip's distance from the RCM at insertion 0
ATOL_M = 1e-9  # m: a compiled pose or point vs numpy's, round-off only
ATOL_UNIT = 1e-9  # 1: rotation-matrix entries and unit vectors, round-off only
ATOL_RAD = 1e-9  # rad: angles computed two ways, round-off only
IK_ATOL = 10 * max(IK_POSITION_TOL_M, IK_ORIENTATION_TOL_RAD)  # m / rad: an IK solution's FK
AXIS_MISS = 1e-6  # unitless: sin of an ECM optical axis's miss of the port (its IK's test)
ACOS_ATOL_RAD = 1e-6  # rad: scipy's magnitude() of a near-identity rotation (acos round-off)


def _arm(kind: ArmKind) -> CameraArm:
    cfg = ExperimentConfig()
    T_rcm, T_tip_cam = arm_mount(kind, cfg.episode.T_tip_cam, cfg.task.scene.T_world_rcm)
    return CameraArm(kind, T_rcm, T_tip_cam, 0.01)


def _frozen(a: np.ndarray) -> np.ndarray:
    """A read-only copy of ``a``: the arm hands its kernels read-only joints, poses and targets.

    Calling a kernel with the argument types an episode gives it loads the specialisation
    `endocam compile` cached instead of compiling another one (~1 s each) in the test.
    """
    b = np.array(a)
    b.setflags(write=False)
    return b


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


def _special_goals(arm: CameraArm, rng: np.random.Generator) -> list[tuple[np.ndarray, float]]:
    """Goals (4, 4) and look distances (m) on the port view's singular cases.

    The look-at point at the port, the camera looking straight at it and straight away.
    """
    p = arm.p_world_rcm
    out = []
    for _ in range(20):
        R = Rotation.random(random_state=rng).as_matrix()
        look = float(rng.uniform(0.01, 0.2))
        z = R[:, 2]
        out.append((make_pose(R, p - look * z), look))  # looks at the port
        out.append((make_pose(R, p - 2.0 * look * z), look))  # straight at it, beyond
        out.append((make_pose(R, p + 0.5 * look * z), look))  # straight away from it
    return out


def _look_at_point(T: np.ndarray, look: float) -> np.ndarray:
    return T[:3, 3] + look * T[:3, 2]


def _angle(A: np.ndarray, B: np.ndarray) -> float:
    """The rotation angle between two rotations (3, 3), rad (scipy)."""
    return float((Rotation.from_matrix(A).inv() * Rotation.from_matrix(B)).magnitude())


@pytest.mark.parametrize("kind", [ArmKind.PSM, ArmKind.ECM])
def test_exact_joints_reach_the_goal_within_the_limits(kind: ArmKind) -> None:
    arm = _arm(kind)
    model = arm.model
    out = np.empty(model.n_joints)
    found = 0
    for T in _goals(arm, 21 if kind is ArmKind.PSM else 22):
        tip = np.linalg.inv(arm.T_world_rcm) @ T @ np.linalg.inv(arm.T_tip_cam)  # RCM frame
        np.testing.assert_allclose(pose12_to_matrix(tip_goal12(arm.ik, T)), tip, atol=ATOL_M)
        if exact_joints(arm.ik, T, _frozen(arm.q), out):
            found += 1
            assert model.within_limits(out)
            np.testing.assert_allclose(arm.camera_pose(out), T, atol=IK_ATOL)
        else:  # no exact solution within the limits: the full solve says so too
            assert not model.solve(tip, arm.q).ok
    assert 0 < found < N_GOALS  # both outcomes exercised


def test_camera_command_test_is_the_numpy_one() -> None:
    rng = np.random.default_rng(23)
    p_rcm = rng.normal(0.0, 0.1, 3)
    for _ in range(2000):
        T = make_pose(Rotation.random(random_state=rng).as_matrix(), p_rcm)
        T[:3, 3] += rng.normal(0.0, 1.0, 3) * rng.choice([0.1, 1.0, 10.0, 100.0])
        if rng.random() < 0.2:
            T[rng.integers(4), rng.integers(4)] = rng.choice([np.nan, np.inf, -np.inf])
        for reach in (10.0, float(np.abs(T[:3, 3] - p_rcm).max())):  # also exactly at the reach
            expected = bool(np.isfinite(T).all() and np.abs(T[:3, 3] - p_rcm).max() <= reach)
            assert is_camera_command(T, p_rcm, reach) == expected


@pytest.mark.parametrize("kind", [ArmKind.PSM, ArmKind.ECM])
def test_path_start_is_the_numpy_test(kind: ArmKind) -> None:
    """Whether the path is taken and where it starts, against the same test in numpy."""
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
            c = _look_at_point(T_target, look)
            v = T_cam[:3, 3] - c
            r_cur = float(np.linalg.norm(v))
            u = v / r_cur
            aim = math.acos(np.clip(-u @ T_cam[:3, 2], -1.0, 1.0))
            ang = math.acos(np.clip(-u @ T_target[:3, 2], -1.0, 1.0))
            travel = math.hypot(look - r_cur, 0.5 * (r_cur + look) * ang)
            alpha = min(1.0, PATH_LEAD_M / travel) if travel > 0.0 else 1.0
            expected = not (travel <= PATH_ENGAGE_M and aim <= PATH_ENGAGE_AIM_RAD) and not (
                alpha >= 1.0 and aim <= PATH_ENGAGE_AIM_RAD
            )
            start = path_start(_frozen(T_cam), _frozen(T_target), look)
            assert start.engage == expected
            np.testing.assert_allclose(start.c, c, atol=ATOL_M)
            assert start.r_cur == pytest.approx(r_cur, abs=ATOL_M)
            if expected:
                engaged += 1
                assert start.alpha == pytest.approx(alpha, abs=ATOL_UNIT)
                np.testing.assert_allclose(start.u, u, atol=ATOL_UNIT)
    assert 0 < engaged < 2 * N_GOALS


def test_so3_exp_and_target_error_are_scipys() -> None:
    """``turned_pose``'s turn and ``target_error``'s angle against scipy's rotations."""
    rng = np.random.default_rng(40)
    look = 0.05  # m
    for _ in range(3000):
        A = make_pose(Rotation.random(random_state=rng).as_matrix(), rng.normal(0.0, 0.1, 3))
        turn = rng.normal(0.0, 1.0, 3) * rng.choice([0.0, 1e-12, 1e-9, 1e-4, 0.1, 1.0, 3.0])
        T = turned_pose(A, look, (turn[0], turn[1], turn[2]), 1.0)
        z = Rotation.from_rotvec(turn).apply(A[:3, 2])
        np.testing.assert_allclose(T[:3, 2], z, atol=ATOL_UNIT)  # the optical axis turned
        np.testing.assert_allclose(
            _look_at_point(T, look), _look_at_point(A, look), atol=ATOL_M
        )  # about the look-at point
        shift = rng.normal(0.0, 0.01, 3) * rng.choice([0.0, 1e-9, 1.0])
        B = make_pose(Rotation.from_rotvec(turn).as_matrix() @ A[:3, :3], A[:3, 3] + shift)
        error = target_error(A, B)
        assert error.position == pytest.approx(float(np.linalg.norm(shift)), abs=ATOL_M)
        assert error.angle == pytest.approx(_angle(A[:3, :3], B[:3, :3]), abs=ACOS_ATOL_RAD)


@pytest.mark.parametrize("kind", [ArmKind.PSM, ArmKind.ECM])
def test_port_turn_takes_the_optical_axis_onto_the_port_direction(kind: ArmKind) -> None:
    arm = _arm(kind)
    rng = np.random.default_rng(28)
    p_rcm = arm.p_world_rcm
    turned = missing = 0
    cases = [(T, float(rng.uniform(0.001, 0.2))) for T in _goals(arm, 29)]
    for T, look in cases + _special_goals(arm, rng):
        c = _look_at_point(T, look)
        turn = port_rotvec(T, look, p_rcm)
        assert turn.found == (np.linalg.norm(c - p_rcm) > EPS_AXIS)
        if not turn.found:
            missing += 1
            continue
        direction = (c - p_rcm) / np.linalg.norm(c - p_rcm)
        rotvec = np.array(turn.rotvec)
        np.testing.assert_allclose(  # scipy's rotation by the vector: z onto the port direction
            Rotation.from_rotvec(rotvec).apply(T[:3, 2]), direction, atol=ATOL_UNIT
        )
        assert np.linalg.norm(rotvec) <= math.pi + ATOL_RAD  # the smallest turn
        for fraction in (1.0, float(rng.integers(0, VIEW_STEPS + 1)) / VIEW_STEPS):
            got = turned_pose(T, look, turn.rotvec, fraction)
            z = Rotation.from_rotvec(fraction * rotvec).apply(T[:3, 2])
            np.testing.assert_allclose(got[:3, 2], z, atol=ATOL_UNIT)
            np.testing.assert_allclose(_look_at_point(got, look), c, atol=ATOL_M)
            want = look_at_unchecked(c - look * z, c, T, T)  # view's numpy look-at
            np.testing.assert_allclose(got, want, atol=ATOL_M)
            turned += 1
    assert turned > N_GOALS and missing > 0


def test_look_at_matrix_is_views_look_at() -> None:
    rng = np.random.default_rng(41)
    for i in range(5000):
        T = make_pose(Rotation.random(random_state=rng).as_matrix(), rng.normal(0.0, 0.1, 3))
        p = rng.normal(0.0, 0.1, 3)
        scale = [1.0, 1e-10, 1e-8, 0.0][i % 4]
        c = p + scale * rng.normal(0.0, 0.1, 3)
        if i % 7 == 0:  # straight down or up: the roll of T is kept
            c = p + np.array([0.0, 0.0, rng.choice([-1.0, 1.0])]) * rng.uniform(0.01, 0.1)
            c[:2] += rng.normal(0.0, 1e-3, 2) * rng.choice([0.0, 1.0])
        got = look_at_matrix(tuple(p.tolist()), tuple(c.tolist()), T)
        np.testing.assert_allclose(got, look_at_unchecked(p, c, T, T), atol=ATOL_M)


@pytest.mark.parametrize("kind", [ArmKind.PSM, ArmKind.ECM])
def test_targets_keep_their_promises(kind: ArmKind) -> None:
    """Exact: the goal itself; a view: the goal's look-at point, reached; nearest: in limits."""
    arm = _arm(kind)
    rng = np.random.default_rng(42 if kind is ArmKind.PSM else 43)
    model = arm.model
    statuses: dict[ActuatorStatus, int] = {}
    goals = [(T, None) for T in _goals(arm, 44)] + _special_goals(arm, rng)
    for i, (T, look_given) in enumerate(goals):
        if i % 5 == 0:  # a new measured configuration (the IK's seed), and a cold search
            q = model.clamp(natural_pose(model) + rng.uniform(-0.8, 0.8, model.n_joints))
            arm.reset(arm.camera_pose(q))
        if i % 3 == 0:  # far off: beyond the reach, out of the axes' limits
            T = T.copy()
            T[:3, 3] += rng.normal(0.0, 0.1, 3)
        look = look_given or float(rng.uniform(0.01, 0.3))
        for _ in range(2):  # then nearby: the warm search
            found = arm._target_errors(T, look)
            q = np.array(found.q)
            assert model.within_limits(q)
            T_q = arm.camera_pose(q)
            if found.status is ActuatorStatus.EXACT:
                np.testing.assert_allclose(found.T, T, atol=0.0)
                np.testing.assert_allclose(T_q, T, atol=IK_ATOL)
                assert found.error == (0.0, 0.0)
            else:
                assert found.error.position == pytest.approx(
                    float(np.linalg.norm(found.T[:3, 3] - T[:3, 3])), abs=ATOL_M
                )
                assert found.error.angle == pytest.approx(
                    _angle(found.T[:3, :3], T[:3, :3]), abs=ACOS_ATOL_RAD
                )
            if found.status is ActuatorStatus.VIEW:
                np.testing.assert_allclose(T_q[:3, 3], found.T[:3, 3], atol=VIEW_POSITION_TOL_M)
                if kind is ArmKind.PSM:  # the turned view itself: the same look-at point
                    np.testing.assert_allclose(
                        _look_at_point(found.T, look), _look_at_point(T, look), atol=ATOL_M
                    )
                    np.testing.assert_allclose(T_q, found.T, atol=IK_ATOL)
                else:  # the ECM's port view: its optical axis passes through the port
                    to_port = arm.p_world_rcm - found.T[:3, 3]
                    to_port /= np.linalg.norm(to_port)
                    assert np.linalg.norm(np.cross(found.T[:3, 2], to_port)) <= AXIS_MISS

            if found.status is ActuatorStatus.NEAREST:
                np.testing.assert_allclose(found.T, T_q, atol=IK_ATOL)
            statuses[found.status] = statuses.get(found.status, 0) + 1
            T = T.copy()
            T[:3, 3] += rng.normal(0.0, 0.002, 3)
    assert set(statuses) == set(ActuatorStatus)


@pytest.mark.parametrize("kind", [ArmKind.PSM, ArmKind.ECM])
def test_path_target_looks_at_the_targets_look_at_point(kind: ArmKind) -> None:
    arm = _arm(kind)
    rng = np.random.default_rng(45 if kind is ArmKind.PSM else 46)
    model = arm.model
    goals = _goals(arm, 47)
    taken = 0
    for i, T_target in enumerate(goals):
        if kind is ArmKind.ECM and i % 2 == 0:  # on a reachable target's optical axis (the
            # 4-DoF scope's exact paths are zooms: the axis stays through the port), at a
            # depth the dVRK's IK allows (insertion ≥ 40 mm)
            T_start = T_target.copy()
            depth = rng.uniform(ECM_IK_MIN_INSERTION, 0.2) + ECM_TIP_BEYOND_SHAFT_M
            T_start[:3, 3] = arm.p_world_rcm + T_target[:3, 2] * depth
            arm.reset(T_start)
        else:
            q = model.clamp(natural_pose(model) + rng.uniform(-0.6, 0.6, model.n_joints))
            if kind is ArmKind.ECM:  # a depth the dVRK's IK allows
                q[2] = max(q[2], ECM_IK_MIN_INSERTION)
            arm.reset(arm.camera_pose(q))
        T_cam = arm.camera_pose(arm.q)
        for look in (0.05, float(rng.uniform(0.001, 0.2))):
            got = arm._path_target(_frozen(T_target), look)
            start = path_start(_frozen(T_cam), _frozen(T_target), look)
            if got is None:
                continue
            assert start.engage
            taken += 1
            T_via = arm.camera_pose(np.array(got))
            c = np.array(start.c)
            to_c = c - T_via[:3, 3]
            r = float(np.linalg.norm(to_c))
            np.testing.assert_allclose(to_c / r, T_via[:3, 2], atol=1e-6)  # looks at c
            lo, hi = sorted((start.r_cur, look))
            assert lo - 1e-6 <= r <= hi + 1e-6  # the distance changes linearly
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
def test_arm_cycle_is_the_plain_limit_loop(kind: ArmKind) -> None:
    """The arm's cycle (its fast path when no limit is near) is the limit loop on every cycle."""
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
            np.testing.assert_allclose(got, want, atol=ATOL_M)
        np.testing.assert_allclose(arm.measured_ja(), ref.measured_ja(), atol=ATOL_M)
    assert stops > 0


def test_wrist_jump_is_the_largest_wrist_change() -> None:
    """``wrist_jump``: ``max([|a - b| ...]) > WRIST_JUMP_RAD`` over the PSM's wrist joints.

    Python's ``max`` keeps its first item unless a later one compares greater, so a NaN
    first wins and a NaN later loses.
    """
    rng = np.random.default_rng(41)
    special = [0.0, 1.0, math.nan, math.inf, -math.inf]
    for _ in range(5000):
        a, b = rng.normal(0.0, 0.8, 6).tolist(), rng.normal(0.0, 0.8, 6).tolist()
        for q in (a, b):
            if rng.random() < 0.3:
                q[int(rng.integers(3, 6))] = special[int(rng.integers(0, len(special)))]
        expected = max([abs(x - y) for x, y in zip(a[3:], b[3:], strict=True)]) > WRIST_JUMP_RAD
        assert wrist_jump(ArmKind.PSM, a, b) == expected
        assert not wrist_jump(ArmKind.ECM, a[:4], b[:4])
