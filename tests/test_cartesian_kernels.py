"""The free camera's compiled step keeps its promises: limits, the workspace, rejected targets.

``CartesianLimiter``'s Python around ruckig (the target's check and rotation vector, the clipped
target velocity, the next pose, the stop check with the workspace's cone, floor and keep-out
zone) is compiled. It runs seeded commands (targets held or jumping, moving targets with their
twists, non-finite targets and twists, commands beyond the cone, the floor and the wire) and
must keep every pose rigid, the speed norms within the limits, a camera that could stop inside
the workspace inside it, and a rejected target's camera on its last valid one.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from endocam.config import ExperimentConfig
from endocam.geometry import make_pose
from endocam.robot.arm import MotionStatus
from endocam.robot.cartesian import CartesianLimiter, MotionLimits
from endocam.task.wire import Wire
from endocam.workspace.region import Workspace

N_STEPS = 2500  # count: control steps per workspace
N_POINTS = 3000  # count: random points asked of the workspace
SPEED_RTOL = 1e-9  # unitless: ruckig's round-off on a speed at its limit
RIGID_ATOL = 1e-9  # unitless: RᵀR against the identity (a rigid pose)
WALL_ATOL_M = 1e-4  # m: a braked camera settles within ruckig's round-off of a wall (0.1 mm)


def _workspaces(kind: str) -> tuple[Workspace | None, np.ndarray]:
    """The workspace of ``kind`` (none, the cone and floor, with the wire) and a centre, m."""
    cfg = ExperimentConfig()
    wire = Wire(cfg.task.wire)
    rcm = np.array(cfg.task.scene.rcm_position)
    feature = wire.point(0.5 * wire.length)
    if kind == "none":
        return None, feature
    return cfg.controller.workspace(rcm, feature, wire if kind == "wire" else None), feature


def _commands(rng: np.random.Generator, centre: np.ndarray, start: np.ndarray):  # type: ignore[no-untyped-def]
    """Seeded commands ``(T_world_target, twist)``: held, jumping, moving, broken."""
    T = start
    hold, moving = 0, False
    for _ in range(N_STEPS):
        if hold <= 0:
            hold, moving = int(rng.integers(1, 250)), rng.random() < 0.4
            R = Rotation.from_rotvec(rng.normal(0.0, 0.6, 3)).as_matrix() @ start[:3, :3]
            offset = rng.normal(0.0, 0.03, 3)
            if rng.random() < 0.3:
                offset[2] -= rng.uniform(0.0, 0.08)  # towards or below the floor
            T = make_pose(R, centre + np.array([0.0, 0.0, 0.02]) + offset)
        hold -= 1
        r = rng.random() if moving else 1.0
        twist = None
        if r < 0.9:
            twist = rng.normal(0.0, 0.1, 6) * rng.choice([0.0, 1.0], 6)
        elif r < 0.93:
            twist = np.zeros(6)
        elif r < 0.96:
            twist = np.array([0.1, math.nan, 0.0, 0.0, 0.0, 0.0])
        elif r < 0.98:
            twist = np.ones(5)  # not a twist: ignored
        command = T
        r = rng.random()
        if r < 0.01:
            command = T.copy()
            command[int(rng.integers(0, 4)), int(rng.integers(0, 4))] = math.nan
        elif r < 0.015:
            command = np.full((4, 4), math.inf)
        elif r < 0.02:
            command = np.ones(5)  # not a pose: rejected
        elif r < 0.04:
            command = T.ravel().copy()  # 16 entries, flat
        yield command, twist


@pytest.mark.parametrize("kind", ["none", "cone", "wire"])
def test_limiter_keeps_its_limits_and_the_workspace(kind: str) -> None:
    ws, centre = _workspaces(kind)
    dt = 0.01  # s, control period
    limits = MotionLimits()
    limiter = CartesianLimiter(limits, dt, ws)
    R_down = Rotation.from_rotvec([math.pi, 0.0, 0.0]).as_matrix()  # looking down
    start = make_pose(R_down, centre + np.array([0.0, 0.0, 0.03]))
    limiter.reset(start)
    rng = np.random.default_rng({"none": 31, "cone": 32, "wire": 33}[kind])
    statuses = set()
    last_valid = start
    safe = ws is not None and ws.margin(start[:3, 3]) >= 0.0
    for i, (command, twist) in enumerate(_commands(rng, centre, start)):
        braked = limiter.braked
        T = limiter.step(command, twist)
        braking = limiter.braked > braked  # (a braking step says MOVING, whatever the target)
        R = T[:3, :3]
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=RIGID_ATOL)
        np.testing.assert_array_equal(T[3], [0.0, 0.0, 0.0, 1.0])
        v = limiter.velocity
        assert np.linalg.norm(v[:3]) <= limits.max_linear_speed * (1.0 + SPEED_RTOL), i
        assert np.linalg.norm(v[3:]) <= limits.max_angular_speed * (1.0 + SPEED_RTOL), i
        command_arr = np.asarray(command, dtype=float)
        finite = command_arr.size == 16 and bool(np.isfinite(command_arr).all())
        if finite:
            last_valid = command_arr.reshape(4, 4)
            assert limiter.status is not MotionStatus.REJECTED
        else:  # rejected: on to the last valid target (at rest on it: held there)
            held = np.array_equal(T, last_valid)
            assert limiter.status is MotionStatus.REJECTED or held or braking, i
        if limiter.status is MotionStatus.FINISHED:
            np.testing.assert_array_equal(T, last_valid)  # at rest: the target itself
        if safe:
            assert ws is not None
            assert ws.margin(T[:3, 3]) >= -WALL_ATOL_M, i  # once it could stop inside: inside
        statuses.add(limiter.status)
        if i % 500 == 499:  # a new episode
            limiter.reset(T)
            last_valid = T
            safe = ws is not None and ws.margin(T[:3, 3]) >= 0.0
    assert len(statuses) == 3  # moving, arrived and rejected steps were exercised
    if ws is not None:
        assert limiter.braked > 0  # the workspace made the camera brake


def test_workspace_queries_agree_with_each_other() -> None:
    """``margin`` is the least of the cone's, the floor's and the keep-out zone's; ``all_inside``
    says whether every point's margin is ≥ 0."""
    ws, centre = _workspaces("wire")
    assert ws is not None
    rng = np.random.default_rng(34)
    answers = set()
    for _ in range(N_POINTS):
        p = centre + rng.normal(0.0, 0.02, 3)
        if rng.random() < 0.03:
            p[int(rng.integers(0, 3))] = rng.choice([math.nan, math.inf, -math.inf])
        point = p.tolist() if rng.random() < 0.5 else p
        margin = ws.margin(point)
        expected = min(ws.cone.margin(point), p[2] - ws.floor, ws.keep_out_margin(point))
        if np.isfinite(p).all():
            assert margin == pytest.approx(expected, abs=1e-12)
        path = p + np.cumsum(rng.normal(0.0, 0.002, (int(rng.integers(1, 30)), 3)), axis=0)
        margins = np.array([ws.margin(q) for q in path])
        if np.isfinite(path).all() and np.abs(margins).min() > 1e-12:
            inside = ws.all_inside(path)
            assert inside == bool((margins >= 0.0).all())
            answers.add(inside)
    assert answers == {True, False}


FLOOR_TOLERANCE = 1e-4  # m: a braked stop settles within ruckig's round-off of the wall (0.1 mm)


def test_a_workspace_given_later_is_the_one_the_stop_check_keeps() -> None:
    """Reassigning ``workspace`` moves the wall the camera brakes at, not the one it was built with.

    The second workspace's floor is 5 mm under the camera; the target is 5 mm under that floor.
    """
    ws_a, feature = _workspaces("cone")
    assert ws_a is not None
    start = make_pose(np.eye(3), feature + np.array([0.0, 0.0, 0.03]))
    ws_b = Workspace(ws_a.cone, float(start[2, 3]) - 0.005, ws_a.keep_out)
    lim = CartesianLimiter(MotionLimits(), 0.01, ws_a)
    lim.workspace = ws_b
    lim.reset(start)
    target = make_pose(np.eye(3), feature + np.array([0.0, 0.0, -0.005]))
    for _ in range(200):
        T = lim.step(target)
    assert T[2, 3] >= ws_b.floor - FLOOR_TOLERANCE
    assert lim.braked > 0


def test_a_workspace_the_compiled_check_cannot_honour_is_refused() -> None:
    """A ``Workspace`` subclass (its own ``margin``) would be checked as a plain one: refused."""
    ws, _ = _workspaces("cone")
    assert ws is not None

    class Stricter(Workspace):
        def margin(self, p_world: object) -> float:
            return -1.0

    with pytest.raises(TypeError, match="workspace"):
        CartesianLimiter(MotionLimits(), 0.01, Stricter(ws.cone, ws.floor, ws.keep_out))


@pytest.mark.parametrize("garbage", ["lost", object(), [["a"] * 4] * 4])
def test_a_command_that_is_not_numbers_is_rejected_and_the_camera_held(garbage: object) -> None:
    ws, feature = _workspaces("cone")
    lim = CartesianLimiter(MotionLimits(), 0.01, ws)
    start = make_pose(np.eye(3), feature + np.array([0.0, 0.0, 0.03]))
    lim.reset(start)
    T = lim.step(garbage)  # type: ignore[arg-type]  (it raised TypeError / ValueError)
    np.testing.assert_array_equal(T, start)  # at rest on its last valid target: held there
    T = lim.step(start, twist=garbage)  # type: ignore[arg-type]
    np.testing.assert_array_equal(T, start)
