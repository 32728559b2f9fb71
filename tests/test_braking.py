"""The compiled braking-path kernels give ruckig's and the replaced Python code's floats.

``robot.braking`` reads a ruckig trajectory's profiles once and samples them compiled; the
references here are what it replaced: one ``Trajectory.at_time`` per control step, the free
camera's interpreted ``_extrema`` / ``_roots`` and its corner list, and the arm's path of joint
rows through ``chain_points``. Each is compared bit for bit on seeded random states, including
states beyond the limits (ruckig's brake pre-trajectory).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
import ruckig

from endocam.config import ExperimentConfig
from endocam.robot import camera_arm
from endocam.robot.actuator import ArmKind
from endocam.robot.arm import (
    ECM_MAX_ACCELERATION,
    ECM_MAX_VELOCITY,
    PSM_MAX_ACCELERATION,
    PSM_MAX_VELOCITY,
)
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
from endocam.robot.camera_arm import (
    _NO_ROWS,
    CameraArm,
    _braking_inside_kernel,
    natural_pose,
)
from endocam.robot.cartesian import CartesianLimiter, MotionLimits, _box_corners
from endocam.robot.dh import chain_points
from endocam.task.wire import Wire
from endocam.workspace.cone import ConeWorkspace
from endocam.workspace.region import NO_WORKSPACE, Workspace

N_STATES = 1500  # count: random states per configuration
DTS = (0.01, 0.001, 0.0333)  # s: control periods sampled
_SQRT3 = math.sqrt(3.0)


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
        assert got.tobytes() == expected.tobytes()
    assert braked > 50  # the brake pre-trajectory was exercised


def test_camera_stop_path_and_box_are_the_replaced_floats() -> None:
    braked = 0
    for traj, dt in _camera_trajectories(13):
        rows = profile_rows(traj)
        braked += _brakes(rows)
        expected = _at_time_path(traj, dt)
        got = path_positions(rows, traj.duration, dt, len(expected))
        assert got.tobytes() == expected.tobytes()
        extrema = [_extrema_reference(pr) for pr in traj.profiles[0]]
        for k in range(3):
            assert profile_extrema(rows, k) == extrema[k]
        xs, ys, zs = extrema
        corners = np.array([[x, y, z] for x in xs for y in ys for z in zs])
        assert _box_corners(rows).tobytes() == corners.tobytes()
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
    T_tip_cam = cfg.episode.T_tip_cam if kind is ArmKind.PSM else np.eye(4)
    arm = CameraArm(kind, cfg.task.scene.T_world_rcm, T_tip_cam, 0.01)
    model = arm.model
    vmax = PSM_MAX_VELOCITY if kind is ArmKind.PSM else ECM_MAX_VELOCITY
    amax = PSM_MAX_ACCELERATION if kind is ArmKind.PSM else ECM_MAX_ACCELERATION
    rng = np.random.default_rng(14)
    inp, traj = arm._brake_inp, arm._brake_traj
    for _ in range(300):
        q = model.clamp(natural_pose(model) + rng.uniform(-0.3, 0.3, model.n_joints))
        qd = rng.uniform(-1.0, 1.0, model.n_joints) * np.array(vmax) * rng.uniform(0.0, 1.0)
        stop = model.clamp(q + qd * np.abs(qd) * (0.5 / (0.99 * np.array(amax)))).tolist()
        inp.current_position, inp.current_velocity = q.tolist(), qd.tolist()
        inp.current_acceleration, inp.target_position = [0.0] * len(stop), stop
        assert arm._brake_otg.calculate(inp, traj) in (
            ruckig.Result.Working,
            ruckig.Result.Finished,
        )
        path = _at_time_path(traj, 0.01).tolist()
        expected = chain_points(model.chain, [*path, stop], arm._world_rcm12, arm._last_cam_point)
        got = np.empty((len(path) + 1, 3))
        q_rows = np.empty((len(path) + 1, model.n_joints))
        assert _braking_inside_kernel(
            *NO_WORKSPACE,
            False,
            model.chain._param_array,
            profile_rows(traj),
            traj.duration,
            0.01,
            np.array(stop),
            arm._world_rcm12,
            arm._last_cam_point,
            q_rows,
            got,
        )
        assert got.tobytes() == expected.tobytes()
        assert q_rows.tobytes() == np.array([*path, stop]).tobytes()
        given = np.array([*path, stop])  # the joints given (ruckig's at_time): the same points
        got[:] = math.nan
        _braking_inside_kernel(
            *NO_WORKSPACE,
            False,
            model.chain._param_array,
            _NO_ROWS,
            traj.duration,
            0.01,
            given[-1],
            arm._world_rcm12,
            arm._last_cam_point,
            given,
            got,
        )
        assert got.tobytes() == expected.tobytes()


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
    T_tip_cam = cfg.episode.T_tip_cam if kind is ArmKind.PSM else np.eye(4)
    arm = CameraArm(kind, cfg.task.scene.T_world_rcm, T_tip_cam, 0.01)
    model = arm.model
    vmax = np.array(PSM_MAX_VELOCITY if kind is ArmKind.PSM else ECM_MAX_VELOCITY)
    rng = np.random.default_rng(15)
    asked: dict[float, _Recorder] = {}
    states = []
    for _ in range(200):
        q = model.clamp(natural_pose(model) + rng.uniform(-0.3, 0.3, model.n_joints))
        qd = rng.uniform(-1.0, 1.0, model.n_joints) * vmax * rng.uniform(0.0, 1.0)
        stop = model.clamp(q + qd * np.abs(qd) * np.array(arm._half_inv_acc)).tolist()
        states.append((q.tolist(), qd.tolist(), stop))
    for read_steps in (0.0, 1e9):  # always from the profiles / always by at_time
        monkeypatch.setattr(camera_arm, "PROFILE_READ_STEPS", read_steps)
        arm.workspace = asked[read_steps] = _Recorder()  # type: ignore[assignment]
        for q, qd, stop in states:
            assert arm._brakes_inside(q, qd, stop)
    for a, b in zip(asked[0.0].points, asked[1e9].points, strict=True):
        assert a.tobytes() == b.tobytes()
    assert len(asked[0.0].points) == len(states)


@pytest.mark.parametrize("kind", [ArmKind.PSM, ArmKind.ECM])
def test_brakes_inside_is_the_workspaces_answer_on_the_path(
    kind: ArmKind, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A ``Workspace`` is asked inside the braking kernel: its ``all_inside`` of the path's
    points (``chain_points`` of ruckig's ``at_time`` path), the same answer and keep-out cache."""
    cfg = ExperimentConfig()
    wire = Wire(cfg.task.wire)
    rcm = np.array(cfg.task.scene.rcm_position)
    feature = wire.point(0.5 * wire.length)
    T_tip_cam = cfg.episode.T_tip_cam if kind is ArmKind.PSM else np.eye(4)
    arm = CameraArm(kind, cfg.task.scene.T_world_rcm, T_tip_cam, 0.01)
    model = arm.model
    vmax = np.array(PSM_MAX_VELOCITY if kind is ArmKind.PSM else ECM_MAX_VELOCITY)
    rng = np.random.default_rng(16)
    answers = set()
    for read_steps in (0.0, 1e9):  # always from the profiles / always by at_time
        monkeypatch.setattr(camera_arm, "PROFILE_READ_STEPS", read_steps)
        compiled = cfg.controller.workspace(rcm, feature, wire)
        reference = cfg.controller.workspace(rcm, feature, wire)  # its own keep-out cache
        arm.workspace = compiled
        for _ in range(300):
            q = model.clamp(natural_pose(model) + rng.uniform(-0.5, 0.5, model.n_joints))
            qd = rng.uniform(-1.0, 1.0, model.n_joints) * vmax * rng.uniform(0.0, 1.0)
            stop = model.clamp(q + qd * np.abs(qd) * np.array(arm._half_inv_acc)).tolist()
            inside = arm._brakes_inside(q.tolist(), qd.tolist(), stop)
            path = _at_time_path(arm._brake_traj, 0.01).tolist()
            points = chain_points(model.chain, [*path, stop], arm._world_rcm12, arm._last_cam_point)
            assert inside == reference.all_inside(points)
            assert compiled.keep_out.refs == reference.keep_out.refs  # type: ignore[union-attr]
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
    v, a, _ = carrier._stop_limits
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
        box_z = float(_box_corners(profile_rows(traj))[:, 2].min())
        path_z = float(path[:, 2].min())
        if not path_z < box_z - 1e-9:
            continue
        beyond += 1
        floor = 0.5 * (box_z + path_z)  # m, between the box and the path
        assert not CartesianLimiter(MotionLimits(), dt, _floor_at(floor))._can_stop_inside(
            p, vel, acc
        )
    assert beyond > 0  # such states were exercised
