"""The camera's actuator model: Cartesian motion under speed and acceleration limits (ruckig).

A policy commands a pose; the camera does not teleport there. Each control step,
:class:`CartesianLimiter` asks ruckig (online trajectory generation) for the next state of six
degrees of freedom, the position and the rotation vector relative to the current orientation,
under per-axis velocity, acceleration and jerk limits. The per-axis limits are the configured
norms divided by √3, so the speed and acceleration *norms* never exceed the configured limits.
The limiter steps once per control period (100 Hz by default, ``EpisodeConfig.control_rate``):
everything around ruckig's ``update`` (the target's check, the rotation-vector map of
:mod:`endocam.kernels`, the next pose, the workspace's stop check) runs in a few compiled
calls (docs/conventions.md, "Compiled kernels").
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit
from pydantic import BaseModel, ConfigDict, Field
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
from endocam.kernels import kernel_array, matmul, so3_exp, so3_log, tmatmul
from endocam.robot.actuator import WorkspaceBound
from endocam.robot.arm import MotionStatus
from endocam.robot.braking import profile_rows
from endocam.robot.cartesian_stop import (
    STOP_ASK_PATH,
    STOP_INSIDE,
    CartesianState,
    StopCheck,
    StopStart,
    path_inside,
    stop_start,
)
from endocam.workspace.region import NO_WORKSPACE, Workspace


class MotionLimits(BaseModel):
    """Limits on the free camera's Cartesian motion (norms): it never teleports.

    The paper's 6-DoF camera is "a stereo camera attached to the end of the surgical tool tip"
    (Sec. III-D): a camera carried by a dVRK PSM. Its limits are therefore ones that PSM can
    deliver in every direction, from the dVRK's joint-trajectory defaults (sawIntuitiveResearchKit
    ``mtsIntuitiveResearchKitPSM.cpp``, the values of ``robot.arm.PSM_MAX_VELOCITY`` /
    ``PSM_MAX_ACCELERATION``), at a camera ≈ 0.15 m from the RCM: the outer yaw/pitch joints
    (π rad/s, π rad/s²) move the tip ≈ 0.47 m/s and 0.47 m/s², the insertion stage 0.2 m/s, and
    the wrist turns at 6π rad/s with 4π rad/s². The jerk limits are ours, for smooth video (the
    dVRK's defaults limit no jerk).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    max_linear_speed: float = Field(
        0.15,
        gt=0.0,
        description="Camera speed limit, m/s: under the PSM's slowest translational axis "
        "(insertion, 0.2 m/s).",
    )
    max_linear_acceleration: float = Field(
        0.47,
        gt=0.0,
        description="Acceleration limit, m/s²: the PSM's outer joints (π rad/s²) at 0.15 m.",
    )
    max_angular_speed: float = Field(
        math.radians(120.0),
        gt=0.0,
        description="Angular speed limit, rad/s: a third of a turn per second, far under the "
        "PSM wrist's 6π rad/s, so the view never whips.",
    )
    max_angular_acceleration: float = Field(
        4.0 * math.pi,
        gt=0.0,
        description="Angular acceleration limit, rad/s²: the PSM wrist's 4π rad/s².",
    )
    max_linear_jerk: float = Field(20.0, gt=0.0, description="Jerk limit, m/s³ (smooth video).")
    max_angular_jerk: float = Field(
        math.radians(24000.0), gt=0.0, description="Angular jerk limit, rad/s³ (smooth video)."
    )


_SQRT3 = math.sqrt(3.0)
_SNAP_POS = 1e-12  # m or rad: smaller target offsets are round-off
_SNAP_VEL = 1e-12  # m/s or rad/s: smaller velocities are round-off
_SNAP_ACC = 1e-10  # m/s² or rad/s²: smaller accelerations are round-off
_INSIDE_ACC = 1.0 - 1e-9  # an acceleration at its limit, as a share of it: round-off kept inside


def _snap(values: list[float], tol: float) -> list[float]:
    """Values with magnitude below ``tol`` set to exactly 0."""
    return [0.0 if abs(v) < tol else v for v in values]


# Enum members read once: a class attribute of a Python 3.11 enum costs ~0.3 µs per access.
_FINISHED, _MOVING, _REJECTED = MotionStatus.FINISHED, MotionStatus.MOVING, MotionStatus.REJECTED
_RUCKIG_OK = (Result.Working, Result.Finished)
_RUCKIG_FINISHED = Result.Finished
_F64 = np.dtype(np.float64)
_NO_TWIST = np.zeros(0)  # writable as a given twist (one compiled type); it has no entries
_ZERO6 = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
_Six = tuple[float, float, float, float, float, float]


class RuckigInput(NamedTuple):
    """:func:`prepare_step`'s answer: the target's flags and ruckig's input for the step.

    Attributes
    ----------
    rejected : bool
        The target is not finite: the last valid one is used (its twist dropped).
    moving : bool
        The twist gives a target velocity.
    same : bool
        The target is the one the camera rests on.
    current : 6 floats
        Ruckig's current position: the camera's (m, world), rotation vector 0.
    target : 6 floats
        The target position (m, world) and ``so3_log(Rᵀ R_target)`` (rad, camera frame).
    velocity : 6 floats
        The target velocity (m/s world, rad/s camera frame); zero unless ``moving``.
    """

    rejected: bool
    moving: bool
    same: bool
    current: _Six
    target: _Six
    velocity: _Six


class LimiterStep(NamedTuple):
    """Ruckig's state after one step, as :func:`advance` takes it.

    ``position`` (m, world) and ``rotvec`` (rad, camera frame) of the new pose; the position
    DoFs' ``velocity`` (m/s) and ``acceleration`` (m/s²), world; 3 floats each.
    """

    position: tuple[float, float, float]
    rotvec: tuple[float, float, float]
    velocity: tuple[float, float, float]
    acceleration: tuple[float, float, float]


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _clip(v: float, m: float) -> float:
    """``v`` clipped into ``[−m, m]``."""
    return min(max(v, -m), m)


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def prepare_step(
    flat: FloatArray,
    last: FloatArray,
    arrived: FloatArray,
    twist: FloatArray,
    T: FloatArray,
    vmax: FloatArray,
) -> RuckigInput:
    """Ruckig's input for a step from ``T`` (4, 4), world, m, towards the target ``flat`` (16,).

    A target with a non-finite entry is replaced by ``last`` (16,), the last valid one.
    ``twist`` (6,): linear velocity in world (m/s), angular velocity in world (rad/s), or
    ``(0,)`` for none; a finite, non-zero one gives the target velocity, the angular part in
    the current camera frame, each clipped to ``±vmax`` (6,). ``same`` when the target equals
    ``arrived`` (16,), entry by entry.
    """
    rejected = False
    for i in range(16):
        if not math.isfinite(flat[i]):
            flat = last
            rejected = True
            break
    moving = False
    velocity = _ZERO6
    if not rejected and twist.shape[0] == 6:
        finite, nonzero = True, False
        for i in range(6):
            finite = finite and math.isfinite(twist[i])
            nonzero = nonzero or twist[i] != 0.0
        if finite and nonzero:
            w3, w4, w5 = twist[3], twist[4], twist[5]
            velocity = (
                _clip(twist[0], vmax[0]),
                _clip(twist[1], vmax[1]),
                _clip(twist[2], vmax[2]),
                _clip(T[0, 0] * w3 + T[1, 0] * w4 + T[2, 0] * w5, vmax[3]),
                _clip(T[0, 1] * w3 + T[1, 1] * w4 + T[2, 1] * w5, vmax[4]),
                _clip(T[0, 2] * w3 + T[1, 2] * w4 + T[2, 2] * w5, vmax[5]),
            )
            moving = True
    same = True
    for i in range(16):
        same = same and flat[i] == arrived[i]
    R = ((T[0, 0], T[0, 1], T[0, 2]), (T[1, 0], T[1, 1], T[1, 2]), (T[2, 0], T[2, 1], T[2, 2]))
    R_tgt = ((flat[0], flat[1], flat[2]), (flat[4], flat[5], flat[6]), (flat[8], flat[9], flat[10]))
    theta = so3_log(tmatmul(R, R_tgt))
    current = (T[0, 3], T[1, 3], T[2, 3], 0.0, 0.0, 0.0)
    target = (flat[3], flat[7], flat[11], theta[0], theta[1], theta[2])
    return RuckigInput(rejected, moving, same, current, target, velocity)


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def advance(
    check: StopCheck,
    checking: bool,
    out: FloatArray,
    T: FloatArray,
    flat: FloatArray,
    arriving: bool,
    step: LimiterStep,
) -> StopStart:
    """Writes the pose after a step into ``out`` (4, 4); with ``checking``, its stop check.

    The pose: the target ``flat`` (16,) if ``arriving``, else ruckig's new state from ``T``
    (4, 4): position ``step.position`` (world, m), orientation ``R so3_exp(step.rotvec)``. The
    state reached is checked by :func:`~endocam.robot.cartesian_stop.stop_start` (at rest on
    the target when ``arriving``); without ``checking`` the answer is ``STOP_INSIDE``.
    """
    if arriving:
        for r in range(3):
            for c in range(4):
                out[r, c] = flat[4 * r + c]
    else:
        R = ((T[0, 0], T[0, 1], T[0, 2]), (T[1, 0], T[1, 1], T[1, 2]), (T[2, 0], T[2, 1], T[2, 2]))
        M = matmul(R, so3_exp(step.rotvec))
        for r in range(3):
            for c in range(3):
                out[r, c] = M[r][c]
            out[r, 3] = step.position[r]
    out[3, 0], out[3, 1], out[3, 2], out[3, 3] = 0.0, 0.0, 0.0, 1.0
    if not checking:
        return StopStart(STOP_INSIDE, 0.0)
    if arriving:
        rest = (0.0, 0.0, 0.0)
        return stop_start(check, CartesianState((flat[3], flat[7], flat[11]), rest, rest))
    return stop_start(check, CartesianState(step.position, step.velocity, step.acceleration))


class CartesianLimiter:
    """Moves a pose towards a (moving) target under speed, acceleration and jerk limits.

    With a ``workspace`` (cone and floor), a camera that can stop inside it never leaves it:
    each step's next state is accepted only if the camera could still brake to rest inside
    (the box spanned by its braking path, per axis, with its eight corners inside the convex
    cone and above the floor); otherwise the camera brakes along the braking path of the
    state before, which was checked the same way. A jerk-limited camera arriving at a goal on
    the floor therefore no longer overshoots below it.

    The Python around ruckig is compiled: the target's finite check, its rotation vector and
    the clipped target velocity (:func:`prepare_step`), the next pose and the start of the
    stop check (:func:`advance`), the braking path's check
    (:func:`~endocam.robot.cartesian_stop.path_inside`), with the workspace's compiled queries
    (``workspace.region.workspace_margin`` and the others).

    Parameters
    ----------
    limits : MotionLimits
        Speed and acceleration norms (m/s, m/s², rad/s, rad/s²).
    dt : float
        Control period, s.
    workspace : WorkspaceBound, optional
        Where the camera may be (``workspace.region.Workspace``).
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
        self._vmax = np.array(self._inp.max_velocity)
        self._stop_limits = (v, a, j)  # the position DoFs' limits, m/s, m/s², m/s³
        self._check = StopCheck(NO_WORKSPACE, v, a, j)
        # Each DoF is limited on its own (no time synchronisation): the target moves every step,
        # so synchronised arrival buys nothing, and it halves ruckig's cost.
        self._inp.synchronization = Synchronization.No
        self._T = np.eye(4)  # the current pose, world, m
        self._T_next = np.eye(4)  # the next one (_advance), then swapped in
        self._v = [0.0] * 6  # linear velocity (world) and angular velocity (body), SI
        self._acc = [0.0] * 6
        self._target = np.eye(4)
        self._target_flat = self._target.reshape(16)
        self._arrived_at = np.full(16, math.nan)  # flattened target the camera rests on
        self._moving_target = False  # the last step had a target velocity
        self.status = _FINISHED
        self._workspace: WorkspaceBound | None = None
        self.workspace = workspace  # (checked, and its compiled state taken, by the setter)
        self._safe = False  # the camera can brake to rest inside the workspace
        self.braked = 0  # steps on which the workspace made the camera brake
        # the braking machinery, ready for a workspace given now or later
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

    @property
    def workspace(self) -> WorkspaceBound | None:
        """Where the camera may be (a ``workspace.region.Workspace``), or ``None`` for anywhere."""
        return self._workspace

    @workspace.setter
    def workspace(self, workspace: WorkspaceBound | None) -> None:
        # The stop check is compiled for a Workspace's cone, floor and keep-out zone: another
        # type (a subclass with its own margin, say) would be checked as if it were one.
        if workspace is not None and type(workspace) is not Workspace:
            raise TypeError(
                "workspace: the free camera's stop check is compiled for a "
                f"workspace.region.Workspace, got {type(workspace).__name__}"
            )
        self._workspace = workspace
        state = NO_WORKSPACE if workspace is None else workspace.kernel_state
        self._check = self._check._replace(workspace=state)

    def can_stop_inside(self, state: CartesianState) -> bool:
        """Whether a camera in ``state`` (world: m, m/s, m/s²) can brake to rest inside."""
        return self._stoppable(state, stop_start(self._check, state))

    def _stoppable(self, state: CartesianState, start: StopStart) -> bool:
        """The stop check's answer from its start (:func:`~.cartesian_stop.stop_start`)."""
        if start.code != STOP_ASK_PATH:
            return start.code == STOP_INSIDE
        return self._path_inside(state, start.bound)

    def _path_inside(self, state: CartesianState, bound: float) -> bool:
        """Whether the braking path from ``state`` stays inside.

        ``bound``: its :func:`~endocam.robot.cartesian_stop.stop_bound`, m.
        """
        inp = self._stop_inp
        inp.current_position = state.p
        inp.current_velocity = state.v
        inp.current_acceleration = state.a
        if self._stop_otg.calculate(inp, self._stop_traj) not in _RUCKIG_OK:
            return False
        # (ruckig's position_extrema counts the target position 0 under velocity control)
        traj = self._stop_traj
        rows = profile_rows(traj)
        ws = self._check.workspace
        return bool(path_inside(ws, rows, traj.duration, self.dt, state.p, bound))

    def _brake(self) -> FloatArray:
        """One step along the braking path of the current state (checked the step before)."""
        inp = self._brake_inp
        T = self._T
        inp.current_position = [*T[:3, 3].tolist(), 0.0, 0.0, 0.0]
        inp.current_velocity = self._v
        inp.current_acceleration = self._acc
        if self._brake_otg.update(inp, self._brake_out) not in _RUCKIG_OK:
            raise RuntimeError("ruckig failed to brake")
        x, y, z, rx, ry, rz = self._brake_out.new_position
        rest = (0.0, 0.0, 0.0)
        step = LimiterStep((x, y, z), (rx, ry, rz), rest, rest)
        advance(self._check, False, self._T_next, T, self._target_flat, False, step)
        self._T, self._T_next = self._T_next, T
        self._v = self._brake_out.new_velocity
        self._acc = self._brake_out.new_acceleration
        self.braked += 1
        self.status = _MOVING
        return self._T.copy()

    def reset(self, T_world_cam: FloatArray) -> None:
        """Start at rest at ``T_world_cam`` (4, 4)."""
        T = np.asarray(T_world_cam, dtype=float)
        self._T = np.eye(4)
        self._T[:3] = T[:3]
        self._v = [0.0] * 6
        self._acc = [0.0] * 6
        self._target = np.array(T_world_cam, dtype=float)
        self._target_flat = self._target.reshape(16)
        self._arrived_at = self._target_flat.copy()
        self.status = _FINISHED
        self._safe = self.workspace is not None and self.workspace.margin(T[:3, 3].tolist()) >= 0.0
        if self._moving_target:
            self._inp.target_velocity = [0.0] * 6
            self._moving_target = False

    @property
    def pose(self) -> FloatArray:
        """Current ``T_world_cam`` (4, 4)."""
        return self._T.copy()

    @property
    def velocity(self) -> FloatArray:
        """(6,) linear velocity in world (m/s), then angular velocity in the camera (rad/s)."""
        return np.array(self._v)

    def _retry(self, inp: InputParameter) -> Result:
        """Ruckig refused the state: the round-off it trips on removed, then a target at rest.

        Ruckig fails on rare round-off residue near rest (~1e-16), snapped to 0, and on an
        acceleration that sits exactly at its limit while the target moves (seen with a noisy
        perceived ring): it is kept ``_INSIDE_ACC`` inside the limit. If ruckig still refuses,
        the camera arrives at the target at rest (always a solution from a state within the
        limits) rather than stop the episode; the next step asks again.
        """
        amax = inp.max_acceleration
        inp.current_velocity = _snap(self._v, _SNAP_VEL)
        inp.current_acceleration = [
            max(-_INSIDE_ACC * m, min(_INSIDE_ACC * m, a))
            for a, m in zip(_snap(self._acc, _SNAP_ACC), amax, strict=True)
        ]
        inp.target_position = [
            c if abs(t - c) < _SNAP_POS else t
            for t, c in zip(inp.target_position, inp.current_position, strict=True)
        ]
        try:
            return self._otg.update(inp, self._out)
        except RuckigError:
            inp.target_velocity = [0.0] * 6
            self._moving_target = False
            return self._otg.update(inp, self._out)

    def step(self, T_world_target: FloatArray, twist: FloatArray | None = None) -> FloatArray:
        """Advance one control period towards ``T_world_target`` (4, 4); returns the new pose.

        A non-finite target is rejected: the camera keeps going to the last valid target,
        within its limits, and ``status`` says ``REJECTED``.

        ``twist`` (6,), optional: the target's velocity, linear in world (m/s) then angular in
        world (rad/s). The camera then reaches the target moving with it (clipped to the
        per-axis speed limits), so a steadily moving target is followed without lag. ``None``
        (the default), a non-finite or an all-zero one arrives at rest, exactly as without
        the argument.
        """
        T_new = T_world_target
        if type(T_new) is not np.ndarray or T_new.dtype is not _F64:
            try:
                T_new = np.asarray(T_world_target, dtype=float)
            except (TypeError, ValueError):  # not numbers at all: rejected like a NaN target
                T_new = _NOT_A_POSE
        flat = kernel_array(T_new.reshape(16) if T_new.size == 16 else _NOT_A_POSE)
        tw = _NO_TWIST
        if twist is not None:
            tw = twist
            if type(tw) is np.ndarray and tw.dtype is _F64 and tw.ndim == 1:
                tw = kernel_array(tw)
            else:
                try:
                    tw = kernel_array(np.ravel(np.asarray(twist, dtype=float)))
                except (TypeError, ValueError):  # not numbers: no twist, as a NaN one
                    tw = _NO_TWIST
        prepared = prepare_step(flat, self._target_flat, self._arrived_at, tw, self._T, self._vmax)
        rejected, moving = prepared.rejected, prepared.moving
        if rejected:
            flat = self._target_flat
        else:
            self._target, self._target_flat = T_new, flat
        if moving or self._moving_target:
            self._inp.target_velocity = prepared.velocity
            self._moving_target = moving
            if moving:
                self.status = _MOVING
        if self.status is _FINISHED and prepared.same:
            return self._T.copy()  # at rest on an unchanged target: nothing to do
        # Re-anchor the orientation DoFs at the current orientation: current rotation vector 0,
        # target = log(R_cur^T R_target) (body frame, |θ| ≤ π) (prepare_step).
        inp = self._inp
        inp.current_position = prepared.current
        inp.target_position = prepared.target
        inp.current_velocity = self._v
        inp.current_acceleration = self._acc
        try:
            result = self._otg.update(inp, self._out)
        except RuckigError:
            result = self._retry(inp)
        if result not in _RUCKIG_OK:
            raise RuntimeError(f"ruckig failed with {result} for a finite target")
        arriving = result is _RUCKIG_FINISHED and not moving
        out = self._out
        new, v, a = out.new_position, out.new_velocity, out.new_acceleration
        check = self.workspace is not None
        step = LimiterStep(
            (new[0], new[1], new[2]),
            (new[3], new[4], new[5]),
            (v[0], v[1], v[2]),
            (a[0], a[1], a[2]),
        )
        start = advance(self._check, check, self._T_next, self._T, flat, arriving, step)
        if check:
            # (arriving: at rest, never ask the path)
            if start.code == STOP_ASK_PATH:
                state = CartesianState(step.position, step.velocity, step.acceleration)
                stoppable = self._path_inside(state, start.bound)
            else:
                stoppable = start.code == STOP_INSIDE
            if self._safe and not stoppable:
                return self._brake()  # the braking path of a safe state stays safe
            self._safe = stoppable
        self._T, self._T_next = self._T_next, self._T
        if arriving:
            # at rest on the target: take it exactly (no round-off)
            self._v = [0.0] * 6
            self._acc = [0.0] * 6
            self.status = _REJECTED if rejected else _FINISHED
            self._arrived_at = flat.copy()
        else:
            self._v = v
            self._acc = a
            self.status = _REJECTED if rejected else _MOVING
        return self._T.copy()


_NOT_A_POSE = np.full(16, math.nan)  # a command without 16 entries: rejected
_NOT_A_POSE.setflags(write=False)
