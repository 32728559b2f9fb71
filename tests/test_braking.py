"""The compiled braking-path kernels agree with ruckig itself, within named tolerances.

``robot.braking`` reads a ruckig trajectory's profiles once and samples them compiled; it is
held to ruckig's own ``Trajectory.at_time`` at every control step (``AT_TIME_ATOL``), the free
camera's box to the profiles' extrema found in Python, and the arm's braking points to
``chain_points`` of ruckig's path, on seeded random states, including states beyond the limits
(ruckig's brake pre-trajectory). Any ruckig release whose trajectories these agree with works.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
import ruckig

from endocam.config import ExperimentConfig
from endocam.robot import arm_guard
from endocam.robot.actuator import ArmKind
from endocam.robot.arm import (
    ECM_MAX_ACCELERATION,
    ECM_MAX_VELOCITY,
    PSM_MAX_ACCELERATION,
    PSM_MAX_VELOCITY,
)
from endocam.robot.arm_guard import NO_ROWS, BrakingPath, braking_inside
from endocam.robot.braking import (
    _A,
    _BRAKE,
    _P,
    _T,
    _V,
    ROW_LENGTH,
    path_positions,
    profile_extrema,
    profile_rows,
)
from endocam.robot.camera_arm import CameraArm, natural_pose
from endocam.robot.carriers import arm_mount
from endocam.robot.cartesian import CartesianLimiter, MotionLimits
from endocam.robot.cartesian_stop import CartesianState, box_corners
from endocam.robot.dh import chain_points, pose12_from_matrix
from endocam.task.wire import Wire
from endocam.workspace.cone import ConeWorkspace
from endocam.workspace.region import NO_WORKSPACE, Workspace

N_STATES = 1500  # count: random states per configuration
DTS = (0.01, 0.001, 0.0333)  # s: control periods sampled
_SQRT3 = math.sqrt(3.0)
AT_TIME_ATOL = 1e-9  # m or rad: a compiled sample vs ruckig's at_time (round-off of the cubic)
EXTREMA_ATOL = 1e-12  # m: a profile's extremum found two ways, round-off only
POINT_ATOL_M = 1e-12  # m: the braking points vs chain_points of the same joints
MARGIN_ATOL_M = 1e-9  # m: a point this close to the workspace's wall may be judged either way


# ------------------------------------------------------------------ references (replaced code)
def _at_time_path(traj: Any, dt: float) -> np.ndarray:
    """The positions at every control step, one ``at_time`` each: (steps, n)."""
    duration = traj.duration
    steps = math.ceil(duration / dt - 1e-9)
    n = len(traj.profiles[0])
    path = [traj.at_time(min(i * dt, duration))[0] for i in range(1, steps + 1)]
    return np.array(path, dtype=float).reshape(steps, n)


def _extrema_reference(profile: Any) -> tuple[float, float]:
    """The free camera's interpreted ``_extrema`` (before ``robot.braking``)."""
    p, v, a, j, t = profile.p, profile.v, profile.a, profile.j, profile.t
    lo = hi = p[0]
    for i, T in enumerate(t):
        lo, hi = min(lo, p[i + 1]), max(hi, p[i + 1])
        if not T > 0.0:
            continue
        for s in _roots_reference(0.5 * j[i], a[i], v[i]):
            if 0.0 < s < T:
                x = p[i] + s * (v[i] + s * (0.5 * a[i] + s * j[i] / 6.0))
                lo, hi = min(lo, x), max(hi, x)
    return lo, hi


def _roots_reference(c2: float, c1: float, c0: float) -> list[float]:
    if c2 == 0.0:
        return [-c0 / c1] if c1 != 0.0 else []
    disc = c1 * c1 - 4.0 * c2 * c0
    if disc < 0.0:
        return []
    r = math.sqrt(disc)
    return [(-c1 - r) / (2.0 * c2), (-c1 + r) / (2.0 * c2)]


# ------------------------------------------------------------------ random trajectories
def _arm_trajectories(vmax: tuple[float, ...], amax: tuple[float, ...], seed: int) -> Any:
    """The arm's braking ruckig (synchronised, acceleration-limited) on random states."""
    rng = np.random.default_rng(seed)
    n = len(vmax)
    otg, inp, traj = ruckig.Ruckig(n), ruckig.InputParameter(n), ruckig.Trajectory(n)
    inp.max_velocity, inp.max_acceleration = list(vmax), list(amax)
    inp.max_jerk = [math.inf] * n
    v_lim, a_lim = np.array(vmax), np.array(amax)
    for trial in range(N_STATES):
        q = rng.uniform(-1.0, 1.0, n)
        share = rng.choice([0.0, 1e-3, 0.3, 1.0, 1.5], n)  # 1.5: beyond the limit, a brake
        qd = rng.uniform(-1.0, 1.0, n) * v_lim * share
        stop = q + qd * np.abs(qd) * (0.5 / (0.99 * a_lim))  # as CameraArm plans it
        if trial % 3 == 0:
            stop = q + rng.normal(0.0, 0.1, n)  # any target
        inp.current_position, inp.current_velocity = q.tolist(), qd.tolist()
        inp.current_acceleration, inp.target_position = [0.0] * n, stop.tolist()
        if otg.calculate(inp, traj) in (ruckig.Result.Working, ruckig.Result.Finished):
            yield traj, float(rng.choice(DTS))


def _camera_trajectories(seed: int) -> Any:
    """The free camera's stop ruckig (velocity control, jerk-limited, unsynchronised)."""
    rng = np.random.default_rng(seed)
    otg, inp, traj = ruckig.Ruckig(3), ruckig.InputParameter(3), ruckig.Trajectory(3)
    inp.control_interface = ruckig.ControlInterface.Velocity
    inp.synchronization = ruckig.Synchronization.No
    v, a, j = 0.15 / _SQRT3, 0.47 / _SQRT3, 20.0 / _SQRT3  # MotionLimits' defaults per axis
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [v] * 3, [a] * 3, [j] * 3
    for _ in range(N_STATES):
        inp.current_position = rng.uniform(-1.0, 1.0, 3).tolist()
        inp.current_velocity = (rng.uniform(-v, v, 3) * rng.choice([0.0, 1e-3, 1.0], 3)).tolist()
        share = rng.choice([0.0, 1e-3, 1.0, 1.5], 3)  # 1.5: beyond the limit, a brake
        inp.current_acceleration = (rng.uniform(-a, a, 3) * share).tolist()
        if otg.calculate(inp, traj) in (ruckig.Result.Working, ruckig.Result.Finished):
            yield traj, 0.01


def _brakes(rows: np.ndarray) -> bool:
    return bool((rows[:, _BRAKE] > 0.0).any())


# ------------------------------------------------------------------ tests
@pytest.mark.parametrize(
    ("vmax", "amax", "seed"),
    [(PSM_MAX_VELOCITY, PSM_MAX_ACCELERATION, 11), (ECM_MAX_VELOCITY, ECM_MAX_ACCELERATION, 12)],
)
def test_arm_braking_path_is_ruckigs_at_time(
    vmax: tuple[float, ...], amax: tuple[float, ...], seed: int
) -> None:
    braked = 0
    for traj, dt in _arm_trajectories(vmax, amax, seed):
        rows = profile_rows(traj)
        braked += _brakes(rows)
        expected = _at_time_path(traj, dt)
        got = path_positions(rows, traj.duration, dt, len(expected))
        np.testing.assert_allclose(got, expected, rtol=0.0, atol=AT_TIME_ATOL)
    assert braked > 50  # the brake pre-trajectory was exercised


def test_camera_stop_path_and_box_are_the_replaced_floats() -> None:
    braked = 0
    for traj, dt in _camera_trajectories(13):
        rows = profile_rows(traj)
        braked += _brakes(rows)
        expected = _at_time_path(traj, dt)
        got = path_positions(rows, traj.duration, dt, len(expected))
        np.testing.assert_allclose(got, expected, rtol=0.0, atol=AT_TIME_ATOL)
        extrema = [_extrema_reference(pr) for pr in traj.profiles[0]]
        for k in range(3):
            np.testing.assert_allclose(profile_extrema(rows, k), extrema[k], atol=EXTREMA_ATOL)
        xs, ys, zs = extrema
        corners = np.array([[x, y, z] for x in xs for y in ys for z in zs])
        np.testing.assert_allclose(box_corners(rows), corners, atol=EXTREMA_ATOL)
    assert braked > 50


def test_roots_cover_lines_and_no_roots() -> None:
    rows = np.zeros((1, ROW_LENGTH))
    rows[0, _V], rows[0, _T] = 1.0, 2.0  # v = 1, a = j = 0: a line without a turn
    rows[0, _P + 1] = 2.0
    assert profile_extrema(rows, 0) == (0.0, 2.0)
    rows[0, _A] = -1.0  # a = −1: the velocity 1 − s reaches 0 at s = 1 inside [0, 2]
    assert profile_extrema(rows, 0) == (0.0, 2.0)  # 0.5 at s = 1 lies inside the ends


@pytest.mark.parametrize("kind", [ArmKind.PSM, ArmKind.ECM])
def test_arm_braking_points_are_chain_points_of_the_path(kind: ArmKind) -> None:
    cfg = ExperimentConfig()
    T_rcm, T_tip_cam = arm_mount(kind, cfg.episode.T_tip_cam, cfg.task.scene.T_world_rcm)
    arm = CameraArm(kind, T_rcm, T_tip_cam, 0.01)
    model = arm.model
    vmax = PSM_MAX_VELOCITY if kind is ArmKind.PSM else ECM_MAX_VELOCITY
    amax = PSM_MAX_ACCELERATION if kind is ArmKind.PSM else ECM_MAX_ACCELERATION
    rng = np.random.default_rng(14)
    guard = arm.guard
    g = guard.consts
    point = (float(g.last_cam[0, 3]), float(g.last_cam[1, 3]), float(g.last_cam[2, 3]))
    inp, traj = guard.inp, guard.trajectory
    for _ in range(300):
        q = model.clamp(natural_pose(model) + rng.uniform(-0.3, 0.3, model.n_joints))
        qd = rng.uniform(-1.0, 1.0, model.n_joints) * np.array(vmax) * rng.uniform(0.0, 1.0)
        stop = model.clamp(q + qd * np.abs(qd) * (0.5 / (0.99 * np.array(amax)))).tolist()
        inp.current_position, inp.current_velocity = q.tolist(), qd.tolist()
        inp.current_acceleration, inp.target_position = [0.0] * len(stop), stop
        assert guard.otg.calculate(inp, traj) in (
            ruckig.Result.Working,
            ruckig.Result.Finished,
        )
        path = _at_time_path(traj, 0.01).tolist()
        expected = chain_points(model.chain, [*path, stop], pose12_from_matrix(g.world_rcm), point)
        got = np.empty((len(path) + 1, 3))
        q_rows = np.empty((len(path) + 1, model.n_joints))
        sampled = BrakingPath(profile_rows(traj), traj.duration, 0.01, np.array(stop))
        assert braking_inside(g, NO_WORKSPACE, False, sampled, q_rows, got)
        np.testing.assert_allclose(got, expected, atol=POINT_ATOL_M + AT_TIME_ATOL)
        np.testing.assert_allclose(q_rows, [*path, stop], atol=AT_TIME_ATOL)
        given = np.array([*path, stop])  # the joints given (ruckig's at_time): the same points
        got[:] = math.nan
        braking_inside(
            g, NO_WORKSPACE, False, BrakingPath(NO_ROWS, traj.duration, 0.01, given[-1]), given, got
        )
        np.testing.assert_allclose(got, expected, atol=POINT_ATOL_M)


class _Recorder:
    """A workspace stub that records the camera positions a braking check asks about."""

    def __init__(self) -> None:
        self.points: list[np.ndarray] = []

    def all_inside(self, p_world: np.ndarray) -> bool:
        self.points.append(np.array(p_world))
        return True


@pytest.mark.parametrize("kind", [ArmKind.PSM, ArmKind.ECM])
def test_brakes_inside_asks_the_same_points_either_way(
    kind: ArmKind, monkeypatch: pytest.MonkeyPatch
) -> None:
    cfg = ExperimentConfig()
    T_rcm, T_tip_cam = arm_mount(kind, cfg.episode.T_tip_cam, cfg.task.scene.T_world_rcm)
    arm = CameraArm(kind, T_rcm, T_tip_cam, 0.01)
    model = arm.model
    vmax = np.array(PSM_MAX_VELOCITY if kind is ArmKind.PSM else ECM_MAX_VELOCITY)
    rng = np.random.default_rng(15)
    asked: dict[float, _Recorder] = {}
    states = []
    for _ in range(200):
        q = model.clamp(natural_pose(model) + rng.uniform(-0.3, 0.3, model.n_joints))
        qd = rng.uniform(-1.0, 1.0, model.n_joints) * vmax * rng.uniform(0.0, 1.0)
        stop = model.clamp(q + qd * np.abs(qd) * arm.guard.consts.half_inv_acc).tolist()
        states.append((q.tolist(), qd.tolist(), stop))
    for read_steps in (0.0, 1e9):  # always from the profiles / always by at_time
        monkeypatch.setattr(arm_guard, "PROFILE_READ_STEPS", read_steps)
        asked[read_steps] = recorder = _Recorder()
        for q, qd, stop in states:
            assert arm.guard.brakes_inside(recorder, q, qd, stop)  # type: ignore[arg-type]
    for a, b in zip(asked[0.0].points, asked[1e9].points, strict=True):
        np.testing.assert_allclose(a, b, atol=POINT_ATOL_M + AT_TIME_ATOL)
    assert len(asked[0.0].points) == len(states)


@pytest.mark.parametrize("kind", [ArmKind.PSM, ArmKind.ECM])
def test_brakes_inside_is_the_workspaces_answer_on_the_path(
    kind: ArmKind, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A ``Workspace`` is asked inside the braking kernel: its ``all_inside`` of the path's
    points (``chain_points`` of ruckig's ``at_time`` path), the same answer."""
    cfg = ExperimentConfig()
    wire = Wire(cfg.task.wire)
    rcm = np.array(cfg.task.scene.rcm_position)
    feature = wire.point(0.5 * wire.length)
    T_rcm, T_tip_cam = arm_mount(kind, cfg.episode.T_tip_cam, cfg.task.scene.T_world_rcm)
    arm = CameraArm(kind, T_rcm, T_tip_cam, 0.01)
    model = arm.model
    vmax = np.array(PSM_MAX_VELOCITY if kind is ArmKind.PSM else ECM_MAX_VELOCITY)
    rng = np.random.default_rng(16)
    answers = set()
    for read_steps in (0.0, 1e9):  # always from the profiles / always by at_time
        monkeypatch.setattr(arm_guard, "PROFILE_READ_STEPS", read_steps)
        compiled = cfg.controller.workspace(rcm, feature, wire)
        reference = cfg.controller.workspace(rcm, feature, wire)  # its own keep-out cache
        g = arm.guard.consts
        point = (float(g.last_cam[0, 3]), float(g.last_cam[1, 3]), float(g.last_cam[2, 3]))
        for _ in range(300):
            q = model.clamp(natural_pose(model) + rng.uniform(-0.5, 0.5, model.n_joints))
            qd = rng.uniform(-1.0, 1.0, model.n_joints) * vmax * rng.uniform(0.0, 1.0)
            stop = model.clamp(q + qd * np.abs(qd) * g.half_inv_acc).tolist()
            inside = arm.guard.brakes_inside(compiled, q.tolist(), qd.tolist(), stop)
            path = _at_time_path(arm.guard.trajectory, 0.01).tolist()
            points = chain_points(
                model.chain, [*path, stop], pose12_from_matrix(g.world_rcm), point
            )
            margins = np.array([reference.margin(p) for p in points])
            if np.abs(margins).min() > MARGIN_ATOL_M:  # (a point on the wall could go either way)
                assert inside == reference.all_inside(points)
            answers.add(inside)
    assert answers == {True, False}


def _floor_at(z_min: float) -> Workspace:
    """The region z ≥ ``z_min`` (m) inside a cone far wider than the states: a convex workspace."""
    cone = ConeWorkspace.from_rcm([0.0, 0.0, -5.0], [0.0, 0.0, 0.0], height=10.0, base_radius=10.0)
    return Workspace(cone, z_min)


def test_free_camera_never_claims_a_stop_whose_brake_leaves_the_workspace() -> None:
    """A state beyond the limits brakes first; the profiles' box does not hold that part.

    For every random state whose braking path (ruckig's ``at_time``, brake included) reaches
    lower than the profiles' box, a floor between the two must make the stop check say no.
    Found in review: the box alone said yes.
    """
    dt = 0.01  # s, control period
    carrier = CartesianLimiter(MotionLimits(), dt, _floor_at(-1.0))
    v, a = carrier._check.velocity, carrier._check.acceleration
    rng = np.random.default_rng(21)
    beyond = 0
    for _ in range(N_STATES):
        p = rng.uniform(-0.01, 0.01, 3).tolist()
        vel = (rng.uniform(-v, v, 3) * rng.choice([0.0, 1.0], 3)).tolist()
        acc = (rng.uniform(-a, a, 3) * rng.choice([0.0, 1.0, 1.5], 3)).tolist()
        inp = carrier._stop_inp
        inp.current_position, inp.current_velocity, inp.current_acceleration = p, vel, acc
        traj = ruckig.Trajectory(3)
        if carrier._stop_otg.calculate(inp, traj) not in (
            ruckig.Result.Working,
            ruckig.Result.Finished,
        ):
            continue
        path = _at_time_path(traj, dt)
        if not len(path):
            continue  # at rest already
        box_z = float(box_corners(profile_rows(traj))[:, 2].min())
        path_z = float(path[:, 2].min())
        if not path_z < box_z - 1e-9:
            continue
        beyond += 1
        floor = 0.5 * (box_z + path_z)  # m, between the box and the path
        state = CartesianState(
            (p[0], p[1], p[2]), (vel[0], vel[1], vel[2]), (acc[0], acc[1], acc[2])
        )
        assert not CartesianLimiter(MotionLimits(), dt, _floor_at(floor)).can_stop_inside(state)
    assert beyond > 0  # such states were exercised
