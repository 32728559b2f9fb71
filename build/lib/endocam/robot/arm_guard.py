"""The camera arm's braking guard: a joint step is taken only if the camera can still stop inside.

Each control step, :class:`BrakingGuard` asks where the joints come to rest if each is braked at
its acceleration limit (the stopping point, :func:`stop_point`), and whether the camera stays
inside the workspace along the braking path there, as the arm's own ruckig would drive it
(sampled at every control step, :func:`braking_inside`). A step that would leave no such stop
is undone: the arm brakes towards the stopping point checked the step before. The FK from the
joints to the camera's position in world (:func:`arm_camera_pose`) is compiled with it; the
arm's constants travel as one :class:`GuardConsts`.

Units: m, rad, s; joints rad (revolute) or m (prismatic).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import ruckig
from numba import njit
from numba.extending import register_jitable

from endocam.geometry import FloatArray
from endocam.kernels import dist3
from endocam.robot.actuator import WorkspaceBound
from endocam.robot.arm import SimulatedArm
from endocam.robot.braking import ROW_LENGTH, float_rows, path_positions_into, profile_rows
from endocam.robot.dh import Pose12, compose12, points12, pose12_times
from endocam.workspace.region import (
    NO_WORKSPACE,
    Workspace,
    WorkspaceState,
    workspace_all_inside,
    workspace_margin,
)

__all__ = [
    "ARM_LEVER_SLACK_M",
    "BRAKE_ACC_SHARE",
    "NO_ROWS",
    "PROFILE_READ_STEPS",
    "SLIDE_PUSHES_M",
    "BrakingGuard",
    "BrakingPath",
    "GuardConsts",
    "StopPoint",
    "arm_camera_pose",
    "braking_inside",
    "slid_step",
    "stop_point",
]

# count per joint: a braking path longer than this many control steps per joint is sampled
# from its profiles (robot.braking: reading them costs about as much as 3.5 at_time calls per
# joint, measured on the PSM's paths), a shorter one by ruckig's at_time at each step
PROFILE_READ_STEPS = 3.5

BRAKE_ACC_SHARE = 0.99  # unitless: share of a joint's acceleration limit its braking plans for

# m: added to the camera's distance from the RCM to bound every revolute joint's lever arm on
# the camera (the wrist, the jaw and the camera mount beyond the shaft are shorter than this)
ARM_LEVER_SLACK_M = 0.05


# The slide (BrakingGuard.slide): a joint step the guard refused, turned along the boundary
SLIDE_LEAD_M = 5e-3  # m: the slid set point's camera displacement, at most (first order)
SLIDE_PUSHES_M = (0.5e-3, 2e-3, 5e-3)  # m: how far inwards the slid set point aims (first
# order), tried in turn: the least covers the joints' camera path's curvature over SLIDE_LEAD_M
# (~0.1 mm); the arm's time-synchronised joints leave the joint-space line on their way, so a
# step from rest need not follow it: a larger push turns the motion further inwards
SLIDE_FD_Q = 1e-6  # rad / m: finite-difference step of the camera position's joint Jacobian
SLIDE_FD_M = 1e-5  # m: finite-difference step of the workspace margin's gradient


def slid_step(
    dq: FloatArray, J: FloatArray, g: FloatArray, lead: float, push: float
) -> FloatArray | None:
    r"""A joint step turned along the workspace's boundary: no outward motion, ``push`` inwards.

    The step is first shortened so its camera displacement ``J dq`` is at most ``lead``; then
    the least joint change along :math:`a = J^T g` makes the margin's first-order change
    ``push``:

    .. math:: dq' = dq + \frac{\text{push} - a \cdot dq}{a \cdot a} a

    Parameters
    ----------
    dq : (n,) ndarray
        The joint step towards the command, rad / m.
    J : (3, n) ndarray
        The camera position's joint Jacobian, world, m per rad / m.
    g : (3,) ndarray
        The workspace margin's gradient at the camera (unit length: the inward normal), world.
    lead, push : float
        m.

    Returns
    -------
    (n,) ndarray or None
        ``dq'``; ``None`` when the joints cannot move the camera along ``g`` (``a = 0``) or the
        inputs are not finite.
    """
    v = J @ dq
    nv = float(np.linalg.norm(v))
    if nv > lead:
        dq = dq * (lead / nv)
    a = J.T @ g
    aa = float(a @ a)
    if not (aa > 0.0 and math.isfinite(aa) and np.all(np.isfinite(dq))):
        return None
    return dq + ((push - float(a @ dq)) / aa) * a


class GuardConsts(NamedTuple):
    """A camera arm's constants as the guard's kernels read them (one named argument).

    Attributes
    ----------
    params : (n, 7) ndarray
        The chain's :attr:`~endocam.robot.dh.DHChain.param_array`.
    world_rcm : (4, 4) ndarray
        ``T_world_rcm``, m: where FK starts.
    last_cam : (4, 4) ndarray
        ``T_last_cam``: the camera in the last link's frame, m.
    p_rcm : (3,) ndarray
        The RCM in world, m.
    half_inv_acc : (n,) ndarray
        ``1 / 2a`` per joint at ``BRAKE_ACC_SHARE`` of its limit: the braking distance is
        ``v² · half_inv_acc``, s²/rad or s²/m.
    prismatic : (n,) ndarray of bool
    lower, upper : (n,) ndarray
        Joint limits, rad / m.
    """

    params: FloatArray
    world_rcm: FloatArray
    last_cam: FloatArray
    p_rcm: FloatArray
    half_inv_acc: FloatArray
    prismatic: np.ndarray
    lower: FloatArray
    upper: FloatArray


class StopPoint(NamedTuple):
    """:func:`stop_point`'s answer (the stopping joints themselves are written to an array).

    Attributes
    ----------
    moving : bool
        Any joint moves (a NaN velocity counts).
    slide : float
        The braking's total prismatic travel, m.
    turn : float
        The braking's total revolute travel, rad.
    to_rcm : float
        The camera's distance to the RCM now, m.
    margin : float
        The camera's workspace margin now, m (NaN when not asked).
    """

    moving: bool
    slide: float
    turn: float
    to_rcm: float
    margin: float


class BrakingPath(NamedTuple):
    """A braking path as :func:`braking_inside` samples it.

    Attributes
    ----------
    rows : (n, 49) ndarray
        The ruckig trajectory's :func:`~endocam.robot.braking.profile_rows`; no rows: the
        joints are given already (ruckig's ``at_time``).
    duration : float
        Its length, s.
    dt : float
        The control period, s.
    stop : (n,) ndarray
        Where it comes to rest, rad / m.
    """

    rows: FloatArray
    duration: float
    dt: float
    stop: FloatArray


NO_ROWS = np.empty((0, ROW_LENGTH))  # a BrakingPath whose joints are given (read by at_time)


@register_jitable  # compiled into its callers
def _world_rcm12(g: GuardConsts) -> Pose12:
    """``T_world_rcm`` as 12 floats (rotation row-major, then translation), m."""
    A = g.world_rcm
    return (
        A[0, 0], A[0, 1], A[0, 2], A[1, 0], A[1, 1], A[1, 2], A[2, 0], A[2, 1], A[2, 2],
        A[0, 3], A[1, 3], A[2, 3],
    )  # fmt: skip


@njit(cache=True)  # compiled once, then loaded from the cache
def arm_camera_pose(g: GuardConsts, q: FloatArray) -> FloatArray:
    """The camera pose (4, 4), world, m, for joints ``q`` (n,), rad / m.

    ``T_world_rcm · FK(q) · T_last_cam`` (:func:`~endocam.robot.dh.compose12`).
    """
    out = np.empty((4, 4))
    _camera_pose_into(g, q, out)
    return out


@register_jitable  # compiled into its callers
def _camera_pose_into(g: GuardConsts, q: FloatArray, out: FloatArray) -> None:
    """:func:`arm_camera_pose` into ``out`` (4, 4), m."""
    B = g.last_cam
    rows = (
        (B[0, 0], B[0, 1], B[0, 2], B[0, 3]),
        (B[1, 0], B[1, 1], B[1, 2], B[1, 3]),
        (B[2, 0], B[2, 1], B[2, 2], B[2, 3]),
    )
    P = pose12_times(compose12(g.params, q, 0, g.params.shape[0], _world_rcm12(g)), rows)
    for i in range(3):
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = P[3 * i], P[3 * i + 1], P[3 * i + 2], P[9 + i]
    out[3, 0], out[3, 1], out[3, 2], out[3, 3] = 0.0, 0.0, 0.0, 1.0


@njit(cache=True)  # compiled once, then loaded from the cache
def stop_point(
    g: GuardConsts,
    ws: WorkspaceState,
    check: bool,
    q: FloatArray,
    qd: FloatArray,
    stop: FloatArray,
    T_now: FloatArray,
) -> StopPoint:
    """Where joints ``q`` moving at ``qd`` (n,) stop, braked, and the camera now.

    Writes the stopping point into ``stop`` (n,): each joint braked,
    ``q + qd·|qd|·half_inv_acc``, clipped into its limits; and the camera pose now
    (:func:`arm_camera_pose`) into ``T_now`` (4, 4), m. The margin is the workspace ``ws``'s
    (``workspace.region.workspace_margin``) with ``check``, NaN without.
    """
    n = q.shape[0]
    moving = False
    slide = 0.0
    turn = 0.0
    for i in range(n):
        v = qd[i]
        d = v * abs(v) * g.half_inv_acc[i]
        x = q[i] + d
        lo, hi = g.lower[i], g.upper[i]
        stop[i] = lo if x < lo else (hi if x > hi else x)
        moving = moving or v != 0.0
        if g.prismatic[i]:
            slide += abs(d)
        else:
            turn += abs(d)
    _camera_pose_into(g, q, T_now)
    x, y, z = T_now[0, 3], T_now[1, 3], T_now[2, 3]
    to_rcm = dist3(x, y, z, g.p_rcm[0], g.p_rcm[1], g.p_rcm[2])
    margin = workspace_margin(ws, x, y, z) if check else math.nan
    return StopPoint(moving, slide, turn, to_rcm, margin)


@njit(cache=True)  # compiled once, then loaded from the cache
def braking_inside(
    g: GuardConsts,
    ws: WorkspaceState,
    check: bool,
    path: BrakingPath,
    q_rows: FloatArray,
    points: FloatArray,
) -> bool:
    """The camera's positions along a braking path, and whether the workspace holds them all.

    The joints ``q_rows`` (steps + 1, n), rad / m: given (ruckig's ``at_time`` at every
    control step, then the stop), or, when ``path.rows`` has rows, written here (the path
    sampled at every control step, :func:`~endocam.robot.braking.path_positions_into`, then
    ``path.stop``). Writes the camera's positions into ``points`` (steps + 1, 3), world, m,
    and returns ``workspace_all_inside(ws, points)`` with ``check`` (True without).
    """
    steps = q_rows.shape[0] - 1
    if path.rows.shape[0] > 0:
        path_positions_into(path.rows, path.duration, path.dt, q_rows, steps)
        for j in range(q_rows.shape[1]):
            q_rows[steps, j] = path.stop[j]
    point = (g.last_cam[0, 3], g.last_cam[1, 3], g.last_cam[2, 3])
    points12(g.params, q_rows, _world_rcm12(g), point, points)
    if not check:
        return True
    return workspace_all_inside(ws, points)


def _state(workspace: WorkspaceBound) -> tuple[bool, WorkspaceState]:
    """Whether the kernels can ask ``workspace`` themselves (a plain ``Workspace``), and how."""
    if type(workspace) is Workspace:
        return True, workspace.kernel_state
    return False, NO_WORKSPACE


class BrakingGuard:
    """Keeps a camera arm's camera inside a workspace, once it can stop inside.

    Parameters
    ----------
    consts : GuardConsts
        The arm's chain, mount and braking constants.
    dt : float
        Control period, s.
    vmax, amax : sequence of float
        The arm's joint velocity and acceleration limits (its ruckig's), per joint.
    """

    def __init__(
        self, consts: GuardConsts, dt: float, vmax: tuple[float, ...], amax: tuple[float, ...]
    ) -> None:
        self.consts = consts
        self._dt = dt
        n = len(amax)
        # the braking path as the arm's own ruckig (same limits, synchronised) will drive it
        self.otg = ruckig.Ruckig(n)
        self.inp = ruckig.InputParameter(n)
        self.inp.max_velocity = list(vmax)
        self.inp.max_acceleration = list(amax)
        self.inp.max_jerk = [math.inf] * n
        self.inp.current_acceleration = [0.0] * n  # every braking path starts so
        self.trajectory = ruckig.Trajectory(n)
        self._stop_row = np.empty(n)  # stop_point's stopping point
        self._safe = False  # the camera can stop inside the workspace
        self._stop: list[float] = [0.0] * n  # where the joints stop if braked now
        self.braked = 0  # steps on which the workspace made the arm brake

    def reset(self, arm: SimulatedArm, workspace: WorkspaceBound) -> None:
        """Take the arm's (new) state as the one to brake from."""
        self._stop, self._safe, _ = self.stop_point(arm, workspace)

    def stop_point(
        self, arm: SimulatedArm, workspace: WorkspaceBound
    ) -> tuple[list[float], bool, FloatArray]:
        """Where the joints come to rest braked at their limits, whether that is safe, and FK.

        Safe: the camera now, and at every step of braking to that point, is inside the
        workspace (:meth:`brakes_inside`). The braking path is not checked while the camera is
        farther inside than the braking can carry it (:data:`ARM_LEVER_SLACK_M`).

        Returns
        -------
        stop : list of float
            Joint positions, rad / m.
        safe : bool
        T_world_cam : (4, 4) ndarray
            The camera now, m.
        """
        q, qd = arm.state_view()
        compiled, state = _state(workspace)
        T_now = np.empty((4, 4))
        found = stop_point(self.consts, state, compiled, q, qd, self._stop_row, T_now)
        stop = self._stop_row.tolist()
        margin = found.margin if compiled else workspace.margin(T_now[:3, 3].tolist())
        safe = margin >= 0.0
        if safe and found.moving:
            lever = found.to_rcm + found.slide + ARM_LEVER_SLACK_M
            if not margin > found.slide + lever * found.turn:  # the braking could reach out
                safe = self.brakes_inside(workspace, q.tolist(), qd.tolist(), stop)
        return stop, safe, T_now

    def brakes_inside(
        self, workspace: WorkspaceBound, q: list[float], qd: list[float], stop: list[float]
    ) -> bool:
        """Whether the camera stays inside at every control step of the braking path.

        The path is the arm's joint motion from ``q`` (rad / m) moving at ``qd`` to rest at
        ``stop``, as its ruckig (synchronised joints) drives it: it can leave the straight line
        between the two, so each step's FK is checked, not only the stopping point's.
        """
        inp = self.inp
        inp.current_position = q
        inp.current_velocity = qd
        inp.target_position = stop  # (current_acceleration: 0, set once)
        if self.otg.calculate(inp, self.trajectory) not in (
            ruckig.Result.Working,
            ruckig.Result.Finished,
        ):
            return False
        traj, dt = self.trajectory, self._dt
        duration = traj.duration
        steps = math.ceil(duration / dt - 1e-9)
        n = len(stop)
        # every control step of the path, then where it stops
        if steps > PROFILE_READ_STEPS * len(q):  # read the profiles once, sample compiled
            path = BrakingPath(profile_rows(traj), duration, dt, np.array(stop))
            q_rows = np.empty((steps + 1, n))
        else:  # a short path: fewer calls of ruckig's own sampler than reading the profiles
            at_time = traj.at_time
            flat: list[float] = []
            for i in range(1, steps + 1):
                flat += at_time(min(i * dt, duration))[0]
            flat += stop
            q_rows = float_rows(flat, n)
            path = BrakingPath(NO_ROWS, duration, dt, q_rows[steps])
        points = np.empty((steps + 1, 3))
        compiled, state = _state(workspace)
        inside = braking_inside(self.consts, state, compiled, path, q_rows, points)
        return bool(inside) if compiled else workspace.all_inside(points)

    def accept(self, arm: SimulatedArm, workspace: WorkspaceBound) -> FloatArray | None:
        """Check the joint step the arm has just taken; take its stopping point if it is safe.

        Returns the camera pose after the step (4, 4), m, or ``None`` when the step could take
        the camera out (then nothing changes here: undo it, and try another or :meth:`brake`).
        """
        stop, safe, T_now = self.stop_point(arm, workspace)
        if self._safe and not safe:
            return None
        self._safe, self._stop = safe, stop
        return T_now

    def brake(self, arm: SimulatedArm, before: tuple[FloatArray, FloatArray]) -> None:
        """Undo the step: from ``before`` (joints, velocities), brake towards the checked stop."""
        arm.reset(*before)
        arm.servo_jp(self._stop)  # the stopping point checked the step before
        arm.step()
        self.braked += 1  # on the braking path of a safe state, towards the same stopping point

    def slide(
        self, workspace: WorkspaceBound, q: FloatArray, q_to: FloatArray, push: float
    ) -> FloatArray | None:
        """A joint set point near ``q_to`` whose motion from ``q`` slides along the boundary.

        The step ``q_to − q`` (rad / m) turned by :func:`slid_step` with the camera's joint
        Jacobian (forward differences of :func:`arm_camera_pose`) and the margin's gradient at
        the camera (central differences of ``workspace.margin``): a motion that, to first order,
        keeps to the boundary's tangent plane and aims ``push`` (m) inwards. The guard still
        checks the step it gives (:meth:`accept`). ``None``: no such motion.
        """
        g = self.consts
        p0 = arm_camera_pose(g, q)[:3, 3]
        n = len(q)
        J = np.empty((3, n))
        for i in range(n):
            dq_i = np.array(q, dtype=float)
            dq_i[i] += SLIDE_FD_Q
            J[:, i] = (arm_camera_pose(g, dq_i)[:3, 3] - p0) / SLIDE_FD_Q
        grad = np.empty(3)
        for i in range(3):
            hi, lo = p0.copy(), p0.copy()
            hi[i] += SLIDE_FD_M
            lo[i] -= SLIDE_FD_M
            grad[i] = (workspace.margin(hi.tolist()) - workspace.margin(lo.tolist())) / (
                2.0 * SLIDE_FD_M
            )
        norm = float(np.linalg.norm(grad))
        if not (norm > 0.0 and math.isfinite(norm)):
            return None
        dq = slid_step(np.asarray(q_to) - q, J, grad / norm, SLIDE_LEAD_M, push)
        return None if dq is None else q + dq

    def keep_inside(
        self,
        arm: SimulatedArm,
        workspace: WorkspaceBound,
        before: tuple[FloatArray, FloatArray],
    ) -> FloatArray | None:
        """Undo a joint step that could take the camera out; brake along a checked one.

        ``before``: the joints and their velocities before the step (rad / m, per s). Returns
        the camera pose after the step (4, 4), m, or ``None`` when it braked.
        """
        T_now = self.accept(arm, workspace)
        if T_now is None:
            self.brake(arm, before)
        return T_now
