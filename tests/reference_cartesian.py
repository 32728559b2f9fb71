"""The free camera's limiter and workspace queries as the interpreter ran them (tests' reference).

``InterpretedLimiter`` is ``endocam.robot.cartesian.CartesianLimiter`` at main before round 7
(r7-free compiled the Python around ruckig: ``_prepare``, ``_advance`` with ``_next_pose`` and
``_stop_start``, ``_path_inside``), with its rotation kernels on Python floats
(``endocam.kernels``: the same source, interpreted) and the brake test on numpy
(``_has_brake``). ``InterpretedWorkspace`` is
``control.safety.Workspace``'s ``margin`` / ``all_inside`` / ``keep_out_margin`` as they were:
the cone's margin interpreted (as ``ConeWorkspace.margin`` was), the keep-out zone asked
through ``ClearanceGuard.margin`` and ``first_outside``. ``tests/test_cartesian_kernels.py``
pins the compiled ones to them bit for bit.
"""

# mypy: ignore-errors

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from ruckig import (
    ControlInterface,
    InputParameter,
    OutputParameter,
    Result,
    Ruckig,
    RuckigError,
    Synchronization,
    Trajectory,
)

from endocam.geometry import FloatArray
from endocam.kernels import Rows, matmul, so3_exp, so3_log, tmatmul
from endocam.robot.actuator import WorkspaceBound
from endocam.robot.arm import MotionStatus
from endocam.robot.braking import _BRAKE, path_positions, profile_rows
from endocam.robot.cartesian import (
    _SNAP_ACC,
    _SNAP_POS,
    _SNAP_VEL,
    _SQRT3,
    MotionLimits,
    _box_corners,
    _snap,
    _stop_bound,
)
from endocam.workspace.cone import ConeWorkspace, cone_margin
from endocam.workspace.keepout import KeepOut


def _has_brake(rows: FloatArray) -> bool:
    """``braking.has_brake`` as it was (numpy)."""
    return bool(np.any(rows[:, _BRAKE] > 0.0))


class InterpretedWorkspace:
    """``control.safety.Workspace``'s queries as they were, over the same cone, floor and zone."""

    def __init__(self, cone: ConeWorkspace, floor: float, keep_out: KeepOut | None) -> None:
        self.cone, self.floor, self.keep_out = cone, floor, keep_out

    @property
    def convex(self) -> bool:
        return self.keep_out is None

    def keep_out_margin(self, p_world: Sequence[float]) -> float:
        return math.inf if self.keep_out is None else self.keep_out.margin(p_world)

    def margin(self, p_world: FloatArray | Sequence[float]) -> float:
        p = p_world.tolist() if isinstance(p_world, np.ndarray) else p_world
        c = self.cone  # ConeWorkspace.margin as it was: cone_margin interpreted
        cone = cone_margin(p[0], p[1], p[2], c._apex, c._axis, c._tan_half, c._cos_half, c.height)
        m = min(cone, p[2] - self.floor)
        if self.keep_out is not None:
            return min(m, self.keep_out.margin(p))
        return m

    def all_inside(self, p_world: FloatArray) -> bool:
        p = np.ascontiguousarray(p_world, dtype=float).reshape(-1, 3)
        n = len(p)
        first = self.cone.first_outside(p, self.floor)
        if self.keep_out is None:
            return first == n
        count = min(first + 1, n)
        return self.keep_out.first_outside(p, count) == count and first == n


class InterpretedLimiter:
    """Moves a pose towards a (moving) target under speed, acceleration and jerk limits.

    With a ``workspace`` (cone and floor), a camera that can stop inside it never leaves it:
    each step's next state is accepted only if the camera could still brake to rest inside
    (the box spanned by its braking path, per axis, with its eight corners inside the convex
    cone and above the floor); otherwise the camera brakes along the braking path of the
    state before, which was checked the same way. A jerk-limited camera arriving at a goal on
    the floor therefore no longer overshoots below it.

    Parameters
    ----------
    limits : MotionLimits
        Speed and acceleration norms (m/s, m/s², rad/s, rad/s²).
    dt : float
        Control period, s.
    workspace : WorkspaceBound, optional
        Where the camera may be (``control.safety.Workspace``).
    """

    def __init__(
        self, limits: MotionLimits, dt: float, workspace: WorkspaceBound | None = None
    ) -> None:
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be > 0 s, got {dt}")
        self.limits = limits
        self.dt = dt
        self._otg = Ruckig(6, dt)
        self._inp = InputParameter(6)
        self._out = OutputParameter(6)
        v, a = limits.max_linear_speed / _SQRT3, limits.max_linear_acceleration / _SQRT3
        w, al = limits.max_angular_speed / _SQRT3, limits.max_angular_acceleration / _SQRT3
        self._inp.max_velocity = [v, v, v, w, w, w]
        self._inp.max_acceleration = [a, a, a, al, al, al]
        j, jr = limits.max_linear_jerk / _SQRT3, limits.max_angular_jerk / _SQRT3
        self._inp.max_jerk = [j, j, j, jr, jr, jr]  # jerk-limited: smooth for the viewer
        self._stop_limits = (v, a, j)  # the position DoFs' limits, m/s, m/s², m/s³
        # Each DoF is limited on its own (no time synchronisation): the target moves every step,
        # so synchronised arrival buys nothing, and it halves ruckig's cost.
        self._inp.synchronization = Synchronization.No
        self._p = [0.0, 0.0, 0.0]
        self._R: Rows = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
        self._v = [0.0] * 6  # linear velocity (world) and angular velocity (body), SI
        self._acc = [0.0] * 6
        self._target = np.eye(4)
        self._arrived_at: list[float] = []  # flattened target the camera rests on
        self._moving_target = False  # the last step had a target velocity
        self._pose_array = np.eye(4)
        self.status = MotionStatus.FINISHED
        self.workspace = workspace
        self._safe = False  # the camera can brake to rest inside the workspace
        self.braked = 0  # steps on which the workspace made the camera brake
        if workspace is not None:
            self._stop_otg = Ruckig(3)  # the braking path of the position DoFs (extrema)
            self._stop_inp = InputParameter(3)
            self._stop_inp.control_interface = ControlInterface.Velocity
            self._stop_inp.synchronization = Synchronization.No
            self._stop_inp.max_velocity = self._inp.max_velocity[:3]
            self._stop_inp.max_acceleration = self._inp.max_acceleration[:3]
            self._stop_inp.max_jerk = self._inp.max_jerk[:3]
            self._stop_traj = Trajectory(3)
            self._brake_otg = Ruckig(6, dt)  # one braking step of all six DoFs
            self._brake_inp = InputParameter(6)
            self._brake_inp.control_interface = ControlInterface.Velocity
            self._brake_inp.synchronization = Synchronization.No
            self._brake_inp.max_velocity = self._inp.max_velocity
            self._brake_inp.max_acceleration = self._inp.max_acceleration
            self._brake_inp.max_jerk = self._inp.max_jerk
            self._brake_out = OutputParameter(6)

    def _can_stop_inside(self, p: list[float], v: list[float], a: list[float]) -> bool:
        """Whether a camera at ``p`` (m) moving with ``v``, ``a`` (world) can brake inside."""
        ws = self.workspace
        assert ws is not None
        margin = ws.margin(p)
        if not any(v) and not any(a):
            return margin >= 0.0
        bound = _stop_bound(v[0], v[1], v[2], a[0], a[1], a[2], *self._stop_limits)
        if margin > bound:
            return True  # farther inside than any braking from this state can carry it
        inp = self._stop_inp
        inp.current_position = p
        inp.current_velocity = v
        inp.current_acceleration = a
        if self._stop_otg.calculate(inp, self._stop_traj) not in (Result.Working, Result.Finished):
            return False
        # (ruckig's position_extrema counts the target position 0 under velocity control)
        rows = profile_rows(self._stop_traj)
        if not ws.all_inside(_box_corners(rows)):
            return False
        # The box holds the profiles, not a brake pre-trajectory before them (a state beyond
        # the limits): then the path itself is checked too.
        braked = _has_brake(rows)
        if ws.convex and not braked:
            return True  # a convex region holding the path's box's corners holds the path
        if not braked and ws.keep_out_margin(p) > bound:
            return True  # farther from the keep-out zone than the braking can carry it
        # a keep-out zone (the wire's) or a brake: the braking path itself, at every control step
        duration, dt = self._stop_traj.duration, self.dt
        steps = math.ceil(duration / dt - 1e-9)
        return ws.all_inside(path_positions(rows, duration, dt, steps))

    def _brake(self) -> FloatArray:
        """One step along the braking path of the current state (checked the step before)."""
        inp = self._brake_inp
        inp.current_position = [*self._p, 0.0, 0.0, 0.0]
        inp.current_velocity = self._v
        inp.current_acceleration = self._acc
        if self._brake_otg.update(inp, self._brake_out) not in (Result.Working, Result.Finished):
            raise RuntimeError("ruckig failed to brake")
        new = self._brake_out.new_position
        self._p = new[:3]
        self._R = matmul(self._R, so3_exp(new[3:]))
        self._v = self._brake_out.new_velocity
        self._acc = self._brake_out.new_acceleration
        self.braked += 1
        self.status = MotionStatus.MOVING
        return self.pose

    def reset(self, T_world_cam: FloatArray) -> None:
        """Start at rest at ``T_world_cam`` (4, 4)."""
        T = np.asarray(T_world_cam, dtype=float)
        self._p = T[:3, 3].tolist()
        self._R = T[:3, :3].tolist()
        self._v = [0.0] * 6
        self._acc = [0.0] * 6
        self._target = np.array(T_world_cam, dtype=float)
        self._arrived_at = self._target.ravel().tolist()
        self._pose_array = self.pose
        self.status = MotionStatus.FINISHED
        self._safe = self.workspace is not None and self.workspace.margin(self._p) >= 0.0
        if self._moving_target:
            self._inp.target_velocity = [0.0] * 6
            self._moving_target = False

    @property
    def pose(self) -> FloatArray:
        """Current ``T_world_cam`` (4, 4)."""
        R, p = self._R, self._p
        return np.array(
            [
                [R[0][0], R[0][1], R[0][2], p[0]],
                [R[1][0], R[1][1], R[1][2], p[1]],
                [R[2][0], R[2][1], R[2][2], p[2]],
                [0.0, 0.0, 0.0, 1.0],
            ]
        )

    @property
    def velocity(self) -> FloatArray:
        """(6,) linear velocity in world (m/s), then angular velocity in the camera (rad/s)."""
        return np.array(self._v)

    def _retry(self, inp: InputParameter) -> Result:
        """Ruckig fails on rare round-off residue near rest (~1e-16): snap it to 0 and retry."""
        inp.current_velocity = _snap(self._v, _SNAP_VEL)
        inp.current_acceleration = _snap(self._acc, _SNAP_ACC)
        inp.target_position = [
            c if abs(t - c) < _SNAP_POS else t
            for t, c in zip(inp.target_position, inp.current_position, strict=True)
        ]
        return self._otg.update(inp, self._out)

    def _target_velocity(self, twist: FloatArray | None) -> list[float] | None:
        """Target velocity in ruckig's coordinates, clipped to the per-axis limits, or ``None``.

        ``twist`` (6,): linear velocity in world (m/s), angular velocity in world (rad/s); the
        angular part is expressed in the current camera frame (the orientation DoFs' frame).
        ``None`` for no twist, a non-finite one or an all-zero one (arrive at rest).
        """
        if twist is None:
            return None
        w = np.ravel(twist).tolist()
        if len(w) != 6 or not math.isfinite(math.fsum(w)) or not any(w):
            return None
        R = self._R
        body = [
            R[0][0] * w[3] + R[1][0] * w[4] + R[2][0] * w[5],
            R[0][1] * w[3] + R[1][1] * w[4] + R[2][1] * w[5],
            R[0][2] * w[3] + R[1][2] * w[4] + R[2][2] * w[5],
        ]
        vmax = self._inp.max_velocity
        return [min(max(v, -m), m) for v, m in zip([w[0], w[1], w[2], *body], vmax, strict=True)]

    def step(self, T_world_target: FloatArray, twist: FloatArray | None = None) -> FloatArray:
        """Advance one control period towards ``T_world_target`` (4, 4); returns the new pose.

        A non-finite target is rejected: the camera keeps going to the last valid target,
        within its limits, and ``status`` says ``REJECTED``.

        ``twist`` (6,), optional: the target's velocity, linear in world (m/s) then angular in
        world (rad/s). The camera then reaches the target moving with it (clipped to the
        per-axis speed limits), so a steadily moving target is followed without lag. ``None``
        (the default) arrives at rest, exactly as without the argument.
        """
        flat = np.ravel(T_world_target).tolist()
        rejected = len(flat) != 16 or not math.isfinite(math.fsum(flat))
        if rejected:
            T_world_target = self._target
            flat = T_world_target.ravel().tolist()
            twist = None
        else:
            self._target = T_world_target
        v_target = self._target_velocity(twist)
        if v_target is not None or self._moving_target:
            self._inp.target_velocity = v_target if v_target is not None else [0.0] * 6
            self._moving_target = v_target is not None
            if v_target is not None:
                self.status = MotionStatus.MOVING
        if self.status is MotionStatus.FINISHED and flat == self._arrived_at:
            return self._pose_array.copy()  # at rest on an unchanged target: nothing to do
        # Re-anchor the orientation DoFs at the current orientation: current rotation vector 0,
        # target = log(R_cur^T R_target) (body frame, |θ| ≤ π).
        R_tgt = [flat[0:3], flat[4:7], flat[8:11]]
        theta = so3_log(tmatmul(self._R, R_tgt))
        p = self._p
        inp = self._inp
        inp.current_position = [p[0], p[1], p[2], 0.0, 0.0, 0.0]
        inp.target_position = [flat[3], flat[7], flat[11], *theta]
        inp.current_velocity = self._v
        inp.current_acceleration = self._acc
        try:
            result = self._otg.update(inp, self._out)
        except RuckigError:
            result = self._retry(inp)
        if result not in (Result.Working, Result.Finished):
            raise RuntimeError(f"ruckig failed with {result} for a finite target")
        arriving = result == Result.Finished and v_target is None
        if self.workspace is not None:
            if arriving:
                p_next, v_next, a_next = [flat[3], flat[7], flat[11]], [0.0] * 3, [0.0] * 3
            else:
                out = self._out
                p_next = out.new_position[:3]
                v_next, a_next = out.new_velocity[:3], out.new_acceleration[:3]
            stoppable = self._can_stop_inside(p_next, v_next, a_next)
            if self._safe and not stoppable:
                return self._brake()  # the braking path of a safe state stays safe
            self._safe = stoppable
        if arriving:
            # at rest on the target: take it exactly (no round-off)
            self._p = [flat[3], flat[7], flat[11]]
            self._R = R_tgt
            self._v = [0.0] * 6
            self._acc = [0.0] * 6
            self.status = MotionStatus.REJECTED if rejected else MotionStatus.FINISHED
            self._arrived_at = flat
            self._pose_array = self.pose
            return self._pose_array
        new = self._out.new_position
        self._p = new[:3]
        self._R = matmul(self._R, so3_exp(new[3:]))
        self._v = self._out.new_velocity
        self._acc = self._out.new_acceleration
        self.status = MotionStatus.REJECTED if rejected else MotionStatus.MOVING
        return self.pose
