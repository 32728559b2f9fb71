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

import numpy as np
from numba import njit
from numba.extending import register_jitable
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

from endocam.camera import StereoCamera
from endocam.geometry import FloatArray, as_pose
from endocam.kernels import matmul, so3_exp, so3_log, tmatmul
from endocam.robot.actuator import ActuatorStatus, ActuatorStep, ArmKind, WorkspaceBound
from endocam.robot.arm import MotionStatus
from endocam.robot.braking import has_brake, path_positions, profile_extrema, profile_rows
from endocam.task.config import TaskConfig
from endocam.task.layout import overview_camera_pose, task_centre
from endocam.workspace.region import (
    NO_WORKSPACE,
    Workspace,
    WorkspaceState,
    workspace_all_inside,
    workspace_keep_out_margin,
    workspace_margin,
)


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


def _snap(values: list[float], tol: float) -> list[float]:
    """Values with magnitude below ``tol`` set to exactly 0."""
    return [0.0 if abs(v) < tol else v for v in values]


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _box_corners(rows: FloatArray) -> FloatArray:
    """The eight corners (8, 3), m, of the box a 3-DoF braking path spans.

    ``rows``: the path's :func:`~endocam.robot.braking.profile_rows` (3, 49); per axis its
    lowest and highest position (:func:`~endocam.robot.braking.profile_extrema`, brake part
    not counted), corners in the order ``[[x, y, z] for x in xs for y in ys for z in zs]``.
    """
    xs, ys, zs = profile_extrema(rows, 0), profile_extrema(rows, 1), profile_extrema(rows, 2)
    out = np.empty((8, 3))
    for i in range(2):
        for j in range(2):
            for k in range(2):
                row = 4 * i + 2 * j + k
                out[row, 0], out[row, 1], out[row, 2] = xs[i], ys[j], zs[k]
    return out


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _stop_bound(
    v0: float, v1: float, v2: float, a0: float, a1: float, a2: float, V: float, A: float, J: float
) -> float:
    """An upper bound of the braking distance from velocity ``v`` and acceleration ``a``, m.

    ``v`` (m/s), ``a`` (m/s²): world, per axis. Per axis (limits ``V``, ``A``, ``J``: m/s,
    m/s², m/s³): the speed peaks below ``s = |v| + a²/2J`` (≤ V) and braking lasts under
    ``|a|/J + s/A + A/J``, so the axis travels less than their product.
    """
    total = 0.0
    for vi, ai in ((v0, a0), (v1, a1), (v2, a2)):
        x = abs(vi) + ai * ai / (2.0 * J)
        s = x if x < V else V  # Python's min(V, x)
        d = s * (abs(ai) / J + s / A + A / J)
        total += d * d
    return math.sqrt(total)


# The limiter's state around ruckig, compiled (CartesianLimiter.step). ``T``: the current pose
# (4, 4), world, m; ``flat``: a target pose's 16 entries, row by row; ``buf`` (18,): ruckig's
# current position (6), target position (6) and target velocity (6) for the step, SI.
_TARGET_REJECTED = 1  # _prepare's flags: the target is not finite (the last valid one is used)
_TARGET_MOVING = 2  # the twist gives a target velocity (buf[12:18])
_TARGET_SAME = 4  # the target is the one the camera rests on
_F64 = np.dtype(np.float64)
# Enum members read once: a class attribute of a Python 3.11 enum costs ~0.3 µs per access.
_FINISHED, _MOVING, _REJECTED = MotionStatus.FINISHED, MotionStatus.MOVING, MotionStatus.REJECTED
_RUCKIG_OK = (Result.Working, Result.Finished)
_RUCKIG_FINISHED = Result.Finished
_NO_TWIST = np.zeros(0)
_NO_TWIST.setflags(write=False)


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _prepare(
    flat: FloatArray,
    last: FloatArray,
    arrived: FloatArray,
    twist: FloatArray,
    T: FloatArray,
    vmax: FloatArray,
    buf: FloatArray,
) -> int:
    """Ruckig's input for a step towards the target ``flat`` (16,); flags (``_TARGET_…``).

    A target with a non-finite entry is replaced by ``last`` (16,), the last valid one (its
    twist dropped). ``twist`` (6,): linear velocity in world (m/s), angular velocity in world
    (rad/s), or ``(0,)`` for none; a finite, non-zero one gives the target velocity, the
    angular part in the current camera frame, each clipped to ``±vmax`` (6,) (Python's
    ``min(max(v, −m), m)``). ``_TARGET_SAME`` when the target equals ``arrived`` (16,), entry
    by entry.
    Writes ``buf``: the current position ``T``'s (m) and rotation vector 0; the target
    position (m) and ``so3_log(Rᵀ R_target)`` (rad, body); the target velocity.
    """
    code = 0
    for i in range(16):
        if not math.isfinite(flat[i]):
            flat = last
            code = _TARGET_REJECTED
            break
    if code == 0 and twist.shape[0] == 6:
        finite, moving = True, False
        for i in range(6):
            finite = finite and math.isfinite(twist[i])
            moving = moving or twist[i] != 0.0
        if finite and moving:
            w3, w4, w5 = twist[3], twist[4], twist[5]
            buf[12], buf[13], buf[14] = twist[0], twist[1], twist[2]
            buf[15] = T[0, 0] * w3 + T[1, 0] * w4 + T[2, 0] * w5
            buf[16] = T[0, 1] * w3 + T[1, 1] * w4 + T[2, 1] * w5
            buf[17] = T[0, 2] * w3 + T[1, 2] * w4 + T[2, 2] * w5
            for i in range(6):
                buf[12 + i] = min(max(buf[12 + i], -vmax[i]), vmax[i])
            code |= _TARGET_MOVING
    same = True
    for i in range(16):
        same = same and flat[i] == arrived[i]
    if same:
        code |= _TARGET_SAME
    R = ((T[0, 0], T[0, 1], T[0, 2]), (T[1, 0], T[1, 1], T[1, 2]), (T[2, 0], T[2, 1], T[2, 2]))
    R_tgt = ((flat[0], flat[1], flat[2]), (flat[4], flat[5], flat[6]), (flat[8], flat[9], flat[10]))
    theta = so3_log(tmatmul(R, R_tgt))
    buf[0], buf[1], buf[2], buf[3], buf[4], buf[5] = T[0, 3], T[1, 3], T[2, 3], 0.0, 0.0, 0.0
    buf[6], buf[7], buf[8] = flat[3], flat[7], flat[11]
    buf[9], buf[10], buf[11] = theta[0], theta[1], theta[2]
    return code


@register_jitable  # also callable from compiled kernels (the same source)
def _next_pose(
    out: FloatArray,
    T: FloatArray,
    flat: FloatArray,
    arriving: bool,
    x: float,
    y: float,
    z: float,
    rx: float,
    ry: float,
    rz: float,
) -> None:
    """Writes into ``out`` (4, 4) the pose after a step: the target ``flat`` (16,) if ``arriving``.

    Else ruckig's new state from ``T`` (4, 4): position ``(x, y, z)``, world, m, orientation
    ``R so3_exp(rx, ry, rz)`` (rotation vector in the camera frame, rad).
    """
    if arriving:
        for r in range(3):
            for c in range(4):
                out[r, c] = flat[4 * r + c]
    else:
        R = ((T[0, 0], T[0, 1], T[0, 2]), (T[1, 0], T[1, 1], T[1, 2]), (T[2, 0], T[2, 1], T[2, 2]))
        M = matmul(R, so3_exp((rx, ry, rz)))
        for r in range(3):
            for c in range(3):
                out[r, c] = M[r][c]
        out[0, 3], out[1, 3], out[2, 3] = x, y, z
    out[3, 0], out[3, 1], out[3, 2], out[3, 3] = 0.0, 0.0, 0.0, 1.0


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _advance(
    ws: WorkspaceState,
    out: FloatArray,
    T: FloatArray,
    flat: FloatArray,
    arriving: bool,
    check: bool,
    x: float,
    y: float,
    z: float,
    rx: float,
    ry: float,
    rz: float,
    v0: float,
    v1: float,
    v2: float,
    a0: float,
    a1: float,
    a2: float,
    V: float,
    A: float,
    J: float,
) -> tuple[int, float]:
    """The pose after a step into ``out`` (:func:`_next_pose`); with ``check``, its stop check.

    The state reached: the target ``flat`` at rest when ``arriving``, else ruckig's new
    position ``(x, y, z)`` (m) with velocity ``v`` (m/s) and acceleration ``a`` (m/s²), world;
    its :func:`_stop_start` in the workspace ``state`` (first eleven arguments), limits ``V``,
    ``A``, ``J``. Without ``check``: ``(1, 0.0)``.
    """
    _next_pose(out, T, flat, arriving, x, y, z, rx, ry, rz)
    if not check:
        return 1, 0.0
    if arriving:
        x, y, z = flat[3], flat[7], flat[11]
        v0, v1, v2, a0, a1, a2 = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    return _stop_start(
        ws,
        x, y, z, v0, v1, v2, a0, a1, a2, V, A, J,
    )  # fmt: skip


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _stop_start(
    ws: WorkspaceState,
    x: float,
    y: float,
    z: float,
    v0: float,
    v1: float,
    v2: float,
    a0: float,
    a1: float,
    a2: float,
    V: float,
    A: float,
    J: float,
) -> tuple[int, float]:
    """The stop check's start: 1 it can stop inside, 0 it cannot, 2 ask the braking path.

    A camera at ``(x, y, z)`` (m) moving with ``v`` (m/s), ``a`` (m/s²), world, in the
    workspace ``state`` (``workspace.region.Workspace.kernel_state``): at rest, its margin
    decides; farther inside than :func:`_stop_bound` (limits ``V``, ``A``, ``J``), yes. Also
    returns that bound, m.
    """
    margin = workspace_margin(ws, x, y, z)
    if not (v0 != 0.0 or v1 != 0.0 or v2 != 0.0 or a0 != 0.0 or a1 != 0.0 or a2 != 0.0):
        return (1 if margin >= 0.0 else 0), 0.0
    bound = _stop_bound(v0, v1, v2, a0, a1, a2, V, A, J)
    if margin > bound:
        return 1, bound  # farther inside than any braking from this state can carry it
    return 2, bound


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _path_inside(
    ws: WorkspaceState,
    rows: FloatArray,
    duration: float,
    dt: float,
    x: float,
    y: float,
    z: float,
    bound: float,
) -> bool:
    """Whether the braking path ``rows`` (3, 49) from ``(x, y, z)`` (m) stays in the workspace.

    ``rows``: the path's :func:`~endocam.robot.braking.profile_rows`, ``duration`` its length
    (s), ``dt`` the control period (s), ``bound`` its :func:`_stop_bound` (m). The corners of
    the box the path's profiles span must be inside; then a convex region holds the path,
    unless a brake pre-trajectory precedes the profiles; a camera farther from the keep-out
    zone than ``bound`` cannot reach it either; else the path is checked at every control
    step (:func:`~endocam.robot.braking.path_positions`).
    """
    corners = _box_corners(rows)
    if not workspace_all_inside(ws, corners):
        return False
    # The box holds the profiles, not a brake pre-trajectory before them (a state beyond the
    # limits): then the path itself is checked too.
    braked = has_brake(rows)
    if not ws.keep and not braked:
        return True  # a convex region holding the path's box's corners holds the path
    if not braked and (workspace_keep_out_margin(ws, x, y, z) > bound):
        return True  # farther from the keep-out zone than the braking can carry it
    # a keep-out zone (the wire's) or a brake: the braking path itself, at every control step
    steps = math.ceil(duration / dt - 1e-9)
    path = path_positions(rows, duration, dt, steps)
    return workspace_all_inside(ws, path)


class CartesianLimiter:
    """Moves a pose towards a (moving) target under speed, acceleration and jerk limits.

    With a ``workspace`` (cone and floor), a camera that can stop inside it never leaves it:
    each step's next state is accepted only if the camera could still brake to rest inside
    (the box spanned by its braking path, per axis, with its eight corners inside the convex
    cone and above the floor); otherwise the camera brakes along the braking path of the
    state before, which was checked the same way. A jerk-limited camera arriving at a goal on
    the floor therefore no longer overshoots below it.

    The Python around ruckig is compiled: the target's finite check, its rotation vector and
    the clipped target velocity (:func:`_prepare`), the next pose and the start of the stop
    check (:func:`_advance`), the braking path's check (:func:`_path_inside`), with the
    workspace's compiled queries (``workspace.region.workspace_margin`` and the others).

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
        self._buf = np.zeros(18)  # ruckig's positions and target velocity (_prepare)
        self._moving_target = False  # the last step had a target velocity
        self.status = _FINISHED
        self._workspace: WorkspaceBound | None = None
        self._ws_state: WorkspaceState = NO_WORKSPACE
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
        self._ws_state = NO_WORKSPACE if workspace is None else workspace.kernel_state

    def _can_stop_inside(self, p: list[float], v: list[float], a: list[float]) -> bool:
        """Whether a camera at ``p`` (m) moving with ``v``, ``a`` (world) can brake inside."""
        V, A, J = self._stop_limits
        code, bound = _stop_start(
            self._ws_state, p[0], p[1], p[2], v[0], v[1], v[2], a[0], a[1], a[2], V, A, J
        )
        return code == 1 if code != 2 else self._path_inside(p, v, a, bound)

    def _path_inside(self, p: list[float], v: list[float], a: list[float], bound: float) -> bool:
        """Whether the braking path from ``p`` (m), ``v``, ``a`` (world) stays inside.

        ``bound``: its :func:`_stop_bound`, m (:func:`_path_inside`).
        """
        inp = self._stop_inp
        inp.current_position = p
        inp.current_velocity = v
        inp.current_acceleration = a
        if self._stop_otg.calculate(inp, self._stop_traj) not in _RUCKIG_OK:
            return False
        # (ruckig's position_extrema counts the target position 0 under velocity control)
        traj = self._stop_traj
        rows = profile_rows(traj)
        return bool(
            _path_inside(self._ws_state, rows, traj.duration, self.dt, p[0], p[1], p[2], bound)
        )

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
        _advance(
            self._ws_state, self._T_next, T, self._target_flat, False, False,
            x, y, z, rx, ry, rz, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
        )  # fmt: skip
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
        """Ruckig fails on rare round-off residue near rest (~1e-16): snap it to 0 and retry."""
        inp.current_velocity = _snap(self._v, _SNAP_VEL)
        inp.current_acceleration = _snap(self._acc, _SNAP_ACC)
        inp.target_position = [
            c if abs(t - c) < _SNAP_POS else t
            for t, c in zip(inp.target_position, inp.current_position, strict=True)
        ]
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
        flat = T_new.reshape(16) if T_new.size == 16 else _NOT_A_POSE
        tw = _NO_TWIST
        if twist is not None:
            tw = twist
            if type(tw) is not np.ndarray or tw.dtype is not _F64 or tw.ndim != 1:
                try:
                    tw = np.ravel(np.asarray(twist, dtype=float))
                except (TypeError, ValueError):  # not numbers: no twist, as a NaN one
                    tw = _NO_TWIST
        code = _prepare(
            flat, self._target_flat, self._arrived_at, tw, self._T, self._vmax, self._buf
        )
        rejected = code & _TARGET_REJECTED
        if rejected:
            flat = self._target_flat
        else:
            self._target, self._target_flat = T_new, flat
        moving = code & _TARGET_MOVING
        b = self._buf.tolist()
        if moving or self._moving_target:
            self._inp.target_velocity = b[12:18] if moving else [0.0] * 6
            self._moving_target = bool(moving)
            if moving:
                self.status = _MOVING
        if self.status is _FINISHED and code & _TARGET_SAME:
            return self._T.copy()  # at rest on an unchanged target: nothing to do
        # Re-anchor the orientation DoFs at the current orientation: current rotation vector 0,
        # target = log(R_cur^T R_target) (body frame, |θ| ≤ π) (_prepare).
        inp = self._inp
        inp.current_position = b[0:6]
        inp.target_position = b[6:12]
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
        V, A, J = self._stop_limits
        code, bound = _advance(
            self._ws_state, self._T_next, self._T, flat, arriving, check,
            new[0], new[1], new[2], new[3], new[4], new[5],
            v[0], v[1], v[2], a[0], a[1], a[2], V, A, J,
        )  # fmt: skip
        if check:
            # (arriving: at rest, code 0 or 1)
            stoppable = code == 1 if code != 2 else self._path_inside(new[:3], v[:3], a[:3], bound)
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


_NO_JOINTS = np.zeros(0)
_NO_JOINTS.setflags(write=False)
_EXACT = ActuatorStatus.EXACT  # (an enum member read once)


class FreeCamera:
    """The free 6-DoF camera (the paper's simulated endoscope) behind the ``Actuator`` interface.

    It has no joints and reaches every command, within the Cartesian limits of its
    :class:`CartesianLimiter`; it starts at the whole-task overview pose.

    Parameters
    ----------
    limits : MotionLimits
        Speed, acceleration and jerk norms.
    dt : float
        Control period, s.
    workspace : WorkspaceBound, optional
        Where the camera may be: once it can stop inside, it never leaves
        (:class:`CartesianLimiter`).
    """

    kind = ArmKind.FREE
    follows_twist = True  # the limiter tracks the command's velocity

    def __init__(
        self, limits: MotionLimits, dt: float, workspace: WorkspaceBound | None = None
    ) -> None:
        self.limiter = CartesianLimiter(limits, dt, workspace)

    @property
    def joint_names(self) -> tuple[str, ...]:
        """No joints."""
        return ()

    @property
    def q(self) -> FloatArray:
        """No joints: ``(0,)``."""
        return _NO_JOINTS

    def start_view(self, task_cfg: TaskConfig, camera: StereoCamera) -> tuple[FloatArray, float]:
        """The free camera starts at the overview pose itself, looking at the task centre."""
        T_overview = overview_camera_pose(task_cfg, camera)
        look = float(np.linalg.norm(task_centre(task_cfg) - T_overview[:3, 3]))
        return T_overview, look

    def reset(self, T_world_cam: object, look_distance: float | None = None) -> FloatArray:
        """Start at rest at ``T_world_cam`` (4, 4); returns it."""
        T = as_pose(T_world_cam, "T_world_cam")
        self.limiter.reset(T)
        return T

    def stall(self, joint: int | None) -> None:
        """No joint to stall: only ``None`` is accepted."""
        if joint is not None:
            raise ValueError(f"joint: the free camera has no joint {joint}")

    def step(
        self, T_world_cmd: FloatArray, look_distance: float, twist: FloatArray | None = None
    ) -> ActuatorStep:
        """One limiter step towards the command (a non-finite one keeps the last valid target).

        ``twist`` (6,): the command's velocity, linear then angular, world, m/s and rad/s.
        """
        T = self.limiter.step(T_world_cmd, twist)
        return ActuatorStep(T, _NO_JOINTS, T_world_cmd, _EXACT, 0.0, 0.0, True)
