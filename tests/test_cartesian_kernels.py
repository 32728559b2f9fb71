"""The free camera's compiled step gives the floats and decisions of the interpreted one.

``CartesianLimiter``'s Python around ruckig (the target's check and rotation vector, the clipped
target velocity, the next pose, the stop check with the workspace's cone, floor and keep-out
zone) and ``Workspace``'s queries are compiled; ``tests/reference_cartesian.py`` keeps the code
they replaced. Both run the same seeded commands (targets held or jumping, moving targets with
their twists, non-finite targets and twists, commands beyond the cone, the floor and the wire)
and must agree bit for bit, step by step, the keep-out zone's cache included.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from endocam.config import ExperimentConfig
from endocam.geometry import make_pose
from endocam.robot.cartesian import CartesianLimiter, MotionLimits
from endocam.task.wire import Wire
from endocam.workspace.cone import cone_margin
from endocam.workspace.region import Workspace
from reference_cartesian import InterpretedLimiter, InterpretedWorkspace

N_STEPS = 2500  # count: control steps per workspace
N_POINTS = 3000  # count: random points asked of the workspace


def _workspaces(kind: str) -> tuple[Workspace | None, InterpretedWorkspace | None, np.ndarray]:
    """Two equal workspaces (own keep-out caches), compiled and interpreted, and a centre, m."""
    cfg = ExperimentConfig()
    wire = Wire(cfg.task.wire)
    rcm = np.array(cfg.task.scene.rcm_position)
    feature = wire.point(0.5 * wire.length)
    if kind == "none":
        return None, None, feature
    a = cfg.controller.workspace(rcm, feature, wire if kind == "wire" else None)
    b = cfg.controller.workspace(rcm, feature, wire if kind == "wire" else None)
    return a, InterpretedWorkspace(b.cone, b.floor, b.keep_out), feature


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
def test_compiled_step_is_the_interpreted_step(kind: str) -> None:
    compiled_ws, interpreted_ws, centre = _workspaces(kind)
    dt = 0.01  # s, control period
    compiled = CartesianLimiter(MotionLimits(), dt, compiled_ws)
    interpreted = InterpretedLimiter(MotionLimits(), dt, interpreted_ws)
    R_down = Rotation.from_rotvec([math.pi, 0.0, 0.0]).as_matrix()  # looking down
    start = make_pose(R_down, centre + np.array([0.0, 0.0, 0.03]))
    compiled.reset(start)
    interpreted.reset(start)
    rng = np.random.default_rng({"none": 31, "cone": 32, "wire": 33}[kind])
    statuses = set()
    for i, (command, twist) in enumerate(_commands(rng, centre, start)):
        a = compiled.step(command, twist)
        b = interpreted.step(command, twist)
        assert a.tobytes() == b.tobytes(), i
        assert compiled.velocity.tobytes() == interpreted.velocity.tobytes(), i
        assert compiled.status is interpreted.status, i
        assert compiled.braked == interpreted.braked, i
        assert compiled.pose.tobytes() == interpreted.pose.tobytes(), i
        if kind == "wire":
            assert compiled_ws is not None and interpreted_ws is not None
            assert compiled_ws.keep_out.refs == interpreted_ws.keep_out.refs, i  # type: ignore[union-attr]
        statuses.add(compiled.status)
        if i % 500 == 499:  # a new episode
            compiled.reset(a)
            interpreted.reset(a)
    assert len(statuses) == 3  # moving, arrived and rejected steps were exercised
    if kind != "none":
        assert compiled.braked > 0  # the workspace made the camera brake


def test_workspace_queries_are_the_interpreted_ones() -> None:
    """``margin`` (the cone's too), ``keep_out_margin``, ``all_inside``: the same floats,
    answers and cache."""
    compiled, interpreted, centre = _workspaces("wire")
    assert compiled is not None and interpreted is not None
    rng = np.random.default_rng(34)
    answers = set()
    for _ in range(N_POINTS):
        p = centre + rng.normal(0.0, 0.02, 3)
        if rng.random() < 0.03:
            p[int(rng.integers(0, 3))] = rng.choice([math.nan, math.inf, -math.inf])
        point = p.tolist() if rng.random() < 0.5 else p
        a, b = compiled.margin(point), interpreted.margin(point)
        assert np.float64(a).tobytes() == np.float64(b).tobytes()
        c = compiled.cone
        a = c.margin(point)
        x, y, z = p.tolist()
        b = cone_margin(x, y, z, c._apex, c._axis, c._tan_half, c._cos_half, c.height)
        assert np.float64(a).tobytes() == np.float64(b).tobytes()
        a, b = compiled.keep_out_margin(point), interpreted.keep_out_margin(point)
        assert np.float64(a).tobytes() == np.float64(b).tobytes()
        path = p + np.cumsum(rng.normal(0.0, 0.002, (int(rng.integers(1, 30)), 3)), axis=0)
        inside = compiled.all_inside(path)
        assert inside == interpreted.all_inside(path)
        answers.add(inside)
        assert compiled.keep_out.refs == interpreted.keep_out.refs  # type: ignore[union-attr]
    assert answers == {True, False}


FLOOR_TOLERANCE = 1e-4  # m: a braked stop settles within ruckig's round-off of the wall (0.1 mm)


def test_a_workspace_given_later_is_the_one_the_stop_check_keeps() -> None:
    """Reassigning ``workspace`` moves the wall the camera brakes at, not the one it was built with.

    The second workspace's floor is 5 mm under the camera; the target is 5 mm under that floor.
    """
    ws_a, _, feature = _workspaces("cone")
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
    ws, _, _ = _workspaces("cone")
    assert ws is not None

    class Stricter(Workspace):
        def margin(self, p_world: object) -> float:
            return -1.0

    with pytest.raises(TypeError, match="workspace"):
        CartesianLimiter(MotionLimits(), 0.01, Stricter(ws.cone, ws.floor, ws.keep_out))


@pytest.mark.parametrize("garbage", ["lost", object(), [["a"] * 4] * 4])
def test_a_command_that_is_not_numbers_is_rejected_and_the_camera_held(garbage: object) -> None:
    ws, _, feature = _workspaces("cone")
    lim = CartesianLimiter(MotionLimits(), 0.01, ws)
    start = make_pose(np.eye(3), feature + np.array([0.0, 0.0, 0.03]))
    lim.reset(start)
    T = lim.step(garbage)  # type: ignore[arg-type]  (it raised TypeError / ValueError)
    np.testing.assert_array_equal(T, start)  # at rest on its last valid target: held there
    T = lim.step(start, twist=garbage)  # type: ignore[arg-type]
    np.testing.assert_array_equal(T, start)
