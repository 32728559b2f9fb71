"""The camera arm's targets: exact IK, the port view, the nearest feasible view, the camera path.

What :class:`~endocam.robot.camera_arm.CameraArm` asks of its arm's kinematics each control
step, compiled where it is array-shaped and hot: a camera pose (world) is turned into the tool
tip's goal in the RCM frame and solved exactly (:func:`exact_joints`); a view the arm cannot
take is turned about the point it looks at towards the port (:func:`port_rotvec`,
:func:`turned_pose`); the ECM's whole answer is one call (:func:`ecm_target`); a far target is
approached along a camera-space path about its look-at point (:func:`path_joints`). The
arm's constants travel as one :class:`ArmIK`; results come back named.

Units: m and rad; poses are (4, 4) homogeneous transforms, world, optical frame (z forward)
unless said otherwise.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit
from numba.extending import overload, register_jitable

from endocam.geometry import FloatArray
from endocam.kernels import cross, dot3, matmul4_into, matvec3, rotation_angle, so3_exp_entries
from endocam.robot.actuator import ArmKind
from endocam.robot.dh import Pose12, pose12_between
from endocam.robot.ecm import SOLVE_DONE, solve12
from endocam.robot.ecm import exact12 as ecm_exact12
from endocam.robot.psm import exact12 as psm_exact12
from endocam.view import look_at_columns

__all__ = [
    "ECM_EXACT",
    "ECM_GOAL_SCIPY",
    "ECM_NEAREST",
    "ECM_PORT_SCIPY",
    "ECM_VIEW",
    "EPS_AXIS",
    "MAX_COMMAND_RANGE_M",
    "PATH_ENGAGE_AIM_RAD",
    "PATH_ENGAGE_M",
    "PATH_LEAD_M",
    "VIEW_BISECTIONS",
    "VIEW_POSITION_TOL_M",
    "VIEW_STEPS",
    "WRIST_JUMP_RAD",
    "ArmIK",
    "EcmIK",
    "EcmTarget",
    "PathStart",
    "PortTurn",
    "PsmIK",
    "TargetError",
    "camera_of_tip",
    "ecm_target",
    "exact_joints",
    "is_camera_command",
    "look_at_matrix",
    "path_joints",
    "path_start",
    "port_rotvec",
    "target_error",
    "tip_goal12",
    "turned_pose",
    "view_search",
    "view_towards_port",
    "wrist_jump",
]

VIEW_BISECTIONS = 7  # count: the conceded view angle is resolved to θ / 2⁷ (< 1.5° for θ ≤ π)
VIEW_STEPS = 2**VIEW_BISECTIONS  # count: the turn towards the port view is searched in these steps
MAX_COMMAND_RANGE_M = 10.0  # m: a command farther than this from the port is not a camera pose
VIEW_POSITION_TOL_M = 1e-6  # m: an ECM port view whose camera is this close counts as reached
EPS_AXIS = 1e-12  # unitless: a cross product shorter than this has no direction
PATH_LEAD_M = 0.02  # m: how far ahead of the camera, along its camera-space path, the joints aim
PATH_ENGAGE_M = 0.02  # m: a target farther along the path than this is approached on the path
PATH_ENGAGE_AIM_RAD = math.radians(10.0)  # rad: or a camera aimed this far off its look-at point
WRIST_JUMP_RAD = 1.0  # rad: a wrist joint target moving this far in one step has jumped


class PsmIK(NamedTuple):
    """A PSM camera arm's constants as its compiled IK reads them (one named argument).

    The type picks the arm's exact IK in compiled code (``psm.exact12``; :class:`EcmIK`:
    ``ecm.exact12``), so a kernel compiled for one arm never compiles the other's.

    Attributes
    ----------
    params : (n, 7) ndarray
        The chain's :attr:`~endocam.robot.dh.DHChain.param_array`.
    consts : ndarray
        The arm model's :attr:`~endocam.robot.kinematics.RcmArm.ik_constants`.
    world_rcm, rcm_world : (4, 4) ndarray
        ``T_world_rcm`` and its inverse, m.
    tip_cam, cam_tip : (4, 4) ndarray
        ``T_tip_cam`` (the camera on the tool tip) and its inverse, m.
    """

    params: FloatArray
    consts: FloatArray
    world_rcm: FloatArray
    rcm_world: FloatArray
    tip_cam: FloatArray
    cam_tip: FloatArray


class EcmIK(NamedTuple):
    """An ECM camera arm's constants as its compiled IK reads them: fields as :class:`PsmIK`."""

    params: FloatArray
    consts: FloatArray
    world_rcm: FloatArray
    rcm_world: FloatArray
    tip_cam: FloatArray
    cam_tip: FloatArray


ArmIK = PsmIK | EcmIK
"""A camera arm's IK constants: :class:`PsmIK` or :class:`EcmIK`."""


class PortTurn(NamedTuple):
    """The turn of a camera's optical axis onto the port direction (:func:`port_rotvec`).

    ``found`` False (and a zero ``rotvec``) when the look-at point is at the port.
    ``rotvec``: rotation vector, world, rad.
    """

    found: bool
    rotvec: tuple[float, float, float]


class TargetError(NamedTuple):
    """How far a target pose is from the goal: ``position`` (m) and ``angle`` (rad)."""

    position: float
    angle: float


class EcmTarget(NamedTuple):
    """:func:`ecm_target`'s answer.

    Attributes
    ----------
    outcome : int
        ``ECM_EXACT``, ``ECM_VIEW``, ``ECM_NEAREST``, or ``ECM_PORT_SCIPY`` /
        ``ECM_GOAL_SCIPY`` (the IK needs scipy's nearest in-limit position: the caller goes
        on).
    q : 4-tuple of float
        The joints, rad / m.
    error : TargetError
        How far the target is from the goal (zero but for the view and the nearest pose).
    """

    outcome: int
    q: tuple[float, float, float, float]
    error: TargetError


class PathStart(NamedTuple):
    """Whether the camera-space path is taken, and where it starts (:func:`path_start`).

    Attributes
    ----------
    engage : bool
    r_cur : float
        The camera's distance to the target's look-at point, m.
    alpha : float
        Share of the path to the next pose (0-1).
    u : 3-tuple of float
        Unit direction from the look-at point to the camera, world.
    c : 3-tuple of float
        The target's look-at point, world, m.
    """

    engage: bool
    r_cur: float
    alpha: float
    u: tuple[float, float, float]
    c: tuple[float, float, float]


# EcmTarget.outcome: the answer (exact, the port view, the nearest pose), or the nearest
# in-limit position is needed (scipy, in Python) for the port view or for the goal
ECM_EXACT, ECM_VIEW, ECM_NEAREST, ECM_PORT_SCIPY, ECM_GOAL_SCIPY = range(5)
_NO_ERROR = TargetError(0.0, 0.0)


def view_towards_port(
    T_world_cam: FloatArray, look_distance: float, p_world_rcm: FloatArray, fraction: float
) -> FloatArray:
    """A camera pose moved about the point it looks at, towards the view from the port.

    The camera keeps looking at ``c = p + look_distance · z`` from ``look_distance``; its
    optical axis is turned by ``fraction`` of the smallest rotation that takes ``z`` onto
    ``(c − p_rcm) / |c − p_rcm|``, and its horizon is levelled again (the roll of ``T`` is kept
    only where the view is near vertical, as in :func:`~endocam.control.goal.look_at_pose`).
    ``fraction = 1`` is the port view, whose optical axis passes through the RCM (the view any
    RCM arm can take at a reachable distance).

    Parameters
    ----------
    T_world_cam : (4, 4) ndarray
        Camera pose, world, optical frame (z forward), m.
    look_distance : float
        Distance to the look-at point along z, m (> 0).
    p_world_rcm : (3,) ndarray
        The port, world, m.
    fraction : float
        In [0, 1].

    Returns
    -------
    (4, 4) ndarray
        The turned pose, m. ``T_world_cam`` itself when the look-at point is at the port.
    """
    turn = port_rotvec(T_world_cam, look_distance, p_world_rcm)
    if not turn.found:
        return np.array(T_world_cam, dtype=float)
    return turned_pose(T_world_cam, look_distance, turn.rotvec, fraction)


@register_jitable  # compiled into its callers
def _so3_exp(x: float, y: float, z: float) -> FloatArray:
    """:func:`endocam.kernels.so3_exp` of the rotation vector ``(x, y, z)`` (rad): (3, 3) array."""
    e = so3_exp_entries(x, y, z)
    R = np.empty((3, 3))
    R[0, 0], R[0, 1], R[0, 2] = e[0], e[1], e[2]
    R[1, 0], R[1, 1], R[1, 2] = e[3], e[4], e[5]
    R[2, 0], R[2, 1], R[2, 2] = e[6], e[7], e[8]
    return R


@njit(cache=True)  # compiled once, then loaded from the cache
def port_rotvec(T: FloatArray, look_distance: float, p_rcm: FloatArray) -> PortTurn:
    """The rotation vector (rad, world) taking a camera's optical axis onto the port direction.

    ``T`` (4, 4): the camera, world, m; ``p_rcm`` (3,): the port, world, m; the direction is
    from the port to the look-at point (``look_distance`` ahead on z, m). Not found when that
    point is at the port; a camera looking straight at the port is panned about its y axis.
    """
    z0, z1, z2 = T[0, 2], T[1, 2], T[2, 2]
    v0 = T[0, 3] + look_distance * z0 - p_rcm[0]
    v1 = T[1, 3] + look_distance * z1 - p_rcm[1]
    v2 = T[2, 3] + look_distance * z2 - p_rcm[2]
    norm_v = math.sqrt(dot3(v0, v1, v2, v0, v1, v2))
    if norm_v <= EPS_AXIS:
        return PortTurn(False, (0.0, 0.0, 0.0))
    v0, v1, v2 = v0 / norm_v, v1 / norm_v, v2 / norm_v
    a0, a1, a2 = cross((z0, z1, z2), (v0, v1, v2))
    sin_t, cos_t = math.sqrt(dot3(a0, a1, a2, a0, a1, a2)), dot3(z0, z1, z2, v0, v1, v2)
    if sin_t <= EPS_AXIS:
        if cos_t > 0.0:
            return PortTurn(True, (0.0, 0.0, 0.0))
        # straight at the port: half a turn about the camera's y axis
        return PortTurn(True, (math.pi * T[0, 1], math.pi * T[1, 1], math.pi * T[2, 1]))
    k = math.atan2(sin_t, cos_t) / sin_t
    return PortTurn(True, (a0 * k, a1 * k, a2 * k))


@register_jitable  # compiled into its callers (no slice assignment: no error strings compiled)
def _copy4_into(T: FloatArray, out: FloatArray) -> None:
    """``out[:, :] = T`` for two (4, 4) arrays."""
    for i in range(4):
        for j in range(4):
            out[i, j] = T[i, j]


@njit(cache=True)  # compiled once, then loaded from the cache
def look_at_matrix(
    p: tuple[float, float, float], c: tuple[float, float, float], T: FloatArray
) -> FloatArray:
    """:func:`~endocam.view.look_at_unchecked` from ``p`` at ``c`` (world, m), rolled as ``T``.

    A new (4, 4) pose, m; a copy of ``T`` (4, 4) when the two points coincide.
    """
    found, x, y, z = look_at_columns(p, c, (T[0, 0], T[1, 0], T[2, 0]))
    out = np.empty((4, 4))
    if not found:
        _copy4_into(T, out)
        return out
    for i in range(3):
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = x[i], y[i], z[i], p[i]
    out[3, 0], out[3, 1], out[3, 2], out[3, 3] = 0.0, 0.0, 0.0, 1.0
    return out


@njit(cache=True)  # compiled once, then loaded from the cache
def turned_pose(
    T: FloatArray, look_distance: float, rotvec: tuple[float, float, float], fraction: float
) -> FloatArray:
    """``T`` (4, 4) moved about its look-at point by ``fraction`` of ``rotvec`` (rad, world).

    The look-at point is ``look_distance`` (m) ahead on the optical axis and stays where it
    is, at the same distance; the horizon is levelled again (rolled as ``T`` near vertical).
    A new (4, 4) pose, world, m.
    """
    R = _so3_exp(fraction * rotvec[0], fraction * rotvec[1], fraction * rotvec[2])
    z0, z1, z2 = T[0, 2], T[1, 2], T[2, 2]
    zt0, zt1, zt2 = matvec3(R, (z0, z1, z2))
    c0 = T[0, 3] + look_distance * z0
    c1 = T[1, 3] + look_distance * z1
    c2 = T[2, 3] + look_distance * z2
    p = (c0 - look_distance * zt0, c1 - look_distance * zt1, c2 - look_distance * zt2)
    return look_at_matrix(p, (c0, c1, c2), T)


@njit(cache=True)  # compiled once, then loaded from the cache
def tip_goal12(ik: ArmIK, T: FloatArray) -> Pose12:
    """The tool tip's goal in the RCM frame of a camera pose ``T`` (4, 4), world, m.

    ``T_rcm_world · T · T_cam_tip`` as 12 floats (rotation row-major, then translation, m).
    """
    A, B = ik.rcm_world, ik.cam_tip
    pre12 = (
        A[0, 0], A[0, 1], A[0, 2], A[1, 0], A[1, 1], A[1, 2], A[2, 0], A[2, 1], A[2, 2],
        A[0, 3], A[1, 3], A[2, 3],
    )  # fmt: skip
    post = (
        (B[0, 0], B[0, 1], B[0, 2], B[0, 3]),
        (B[1, 0], B[1, 1], B[1, 2], B[1, 3]),
        (B[2, 0], B[2, 1], B[2, 2], B[2, 3]),
    )
    return pose12_between(pre12, T, post)


@njit(cache=True)  # compiled once, then loaded from the cache
def camera_of_tip(ik: ArmIK, T12: Pose12) -> FloatArray:
    """The camera (4, 4), world, m, of a tool tip ``T12`` (12 floats, RCM frame, m).

    ``T_world_rcm · T_rcm_tip · T_tip_cam``.
    """
    T = np.empty((4, 4))
    for i in range(3):
        T[i, 0], T[i, 1], T[i, 2], T[i, 3] = T12[3 * i], T12[3 * i + 1], T12[3 * i + 2], T12[9 + i]
    T[3, 0], T[3, 1], T[3, 2], T[3, 3] = 0.0, 0.0, 0.0, 1.0
    A, out = np.empty((4, 4)), np.empty((4, 4))
    matmul4_into(ik.world_rcm, T, A)
    matmul4_into(A, ik.tip_cam, out)
    return out


def _exact_into(ik: ArmIK, goal12: Pose12, seed: FloatArray, out: FloatArray) -> bool:
    """The arm's exact IK of a tool-tip goal (12 floats, RCM frame, m) into ``out`` (n,).

    Compiled code only: the overload below picks the PSM's or the ECM's by ``ik``'s type.
    """
    raise NotImplementedError("compiled code only")


def _psm_exact_into(ik: ArmIK, goal12: Pose12, seed: FloatArray, out: FloatArray) -> bool:
    """:func:`_exact_into` on the PSM: ``psm.exact12``, seeded by the outer yaw and the roll."""
    ok, q6 = psm_exact12(ik.params, ik.consts, goal12, seed[0], seed[3])
    if ok:
        for i in range(6):
            out[i] = q6[i]
    return ok


def _ecm_exact_into(ik: ArmIK, goal12: Pose12, seed: FloatArray, out: FloatArray) -> bool:
    """:func:`_exact_into` on the ECM: ``ecm.exact12``, seeded by the roll."""
    ok, q4 = ecm_exact12(ik.params, ik.consts, goal12, seed[3])
    if ok:
        for i in range(4):
            out[i] = q4[i]
    return ok


@overload(_exact_into)
def _exact_into_overload(ik: ArmIK, goal12: Pose12, seed: FloatArray, out: FloatArray) -> object:
    """The arm's own exact IK, chosen by the type of ``ik`` when a kernel is compiled.

    numba calls this with the arguments' numba types (the annotations are the kernels').
    """
    if getattr(ik, "instance_class", None) is PsmIK:
        return _psm_exact_into
    return _ecm_exact_into


@njit(cache=True)  # compiled once, then loaded from the cache
def exact_joints(ik: ArmIK, T: FloatArray, seed: FloatArray, out: FloatArray) -> bool:
    """Whether the arm reaches the camera pose ``T`` (4, 4, world, m) exactly, in its limits.

    The arm's compiled exact IK (:class:`PsmIK`: the PSM's, :class:`EcmIK`: the ECM's) of
    :func:`tip_goal12`, seeded by ``seed`` (n,): the measured joints (their outer yaw and roll
    pick the branch), rad / m. True with the joints (rad / m) written into ``out`` (n,); False
    (``out`` untouched) if there are none.
    """
    return _exact_into(ik, tip_goal12(ik, T), seed, out)


@register_jitable  # compiled into view_search
def _reach(
    ik: ArmIK,
    turn: tuple[FloatArray, float, tuple[float, float, float]],
    k: int,
    seed: FloatArray,
    known: np.ndarray,
    qs: FloatArray,
) -> bool:
    """Whether the arm reaches the turn ``k / VIEW_STEPS`` (joints into ``qs[k]``), memoised.

    ``turn``: the goal (4, 4, world, m), its look distance (m) and the port turn (rad);
    ``known[k]``: −1 not asked yet, 0 no, 1 yes.
    """
    if known[k] < 0:
        T_goal, look, rotvec = turn
        T = turned_pose(T_goal, look, rotvec, k / VIEW_STEPS)
        known[k] = 1 if _exact_into(ik, tip_goal12(ik, T), seed, qs[k]) else 0
    return known[k] == 1


@njit(cache=True)  # compiled once, then loaded from the cache
def view_search(
    ik: ArmIK,
    T_goal: FloatArray,
    look_distance: float,
    rotvec: tuple[float, float, float],
    guess: int,
    seed: FloatArray,
    q_out: FloatArray,
    T_out: FloatArray,
) -> int:
    """A locally smallest reachable turn ``k / VIEW_STEPS`` towards the port view; 0 if none.

    ``T_goal`` (4, 4): the goal, world, m, looking ``look_distance`` (m) ahead; ``rotvec``:
    its :func:`port_rotvec` (rad). Returns the ``k`` in 1…VIEW_STEPS whose turn
    (:func:`turned_pose`) the arm reaches exactly (:func:`exact_joints`, ``seed`` as there)
    while ``k − 1``'s it does not (``k = 0`` is the goal itself), with its joints in ``q_out``
    (n,) and its pose in ``T_out`` (4, 4). Reachability mostly grows along the turn (the port
    view, ``k = VIEW_STEPS``, is the easiest), but not always: a wrist joint can touch its
    limit in the middle of the turn, leaving a gap, and a smaller reachable ``k`` may exist
    below it. Cold (``guess`` ≤ 0) the search bisects over ``k`` (``VIEW_BISECTIONS`` solves
    after the port view); warm (``guess``: the previous step's ``k``) it gallops from there
    towards the boundary, so a boundary that moves little costs two or three solves and the
    view stays on the same side of any gap from step to step (continuity before minimality).
    """
    known = np.full(VIEW_STEPS + 1, -1, dtype=np.int8)
    qs = np.empty((VIEW_STEPS + 1, q_out.shape[0]))
    turn = (T_goal, look_distance, rotvec)
    if guess <= 0:
        lo, hi = 0, VIEW_STEPS
        if not _reach(ik, turn, hi, seed, known, qs):
            return 0
    elif _reach(ik, turn, guess, seed, known, qs):  # gallop down towards the goal
        hi, step = guess, 1
        while True:
            lo = max(hi - step, 0)
            if lo == 0 or not _reach(ik, turn, lo, seed, known, qs):
                break
            hi, step = lo, 2 * step
    else:  # gallop up towards the port view
        lo, step = guess, 1
        while True:
            hi = min(lo + step, VIEW_STEPS)
            if _reach(ik, turn, hi, seed, known, qs):
                break
            if hi == VIEW_STEPS:
                return 0
            lo, step = hi, 2 * step
    while hi - lo > 1:  # lo is not reached (k = 0 is the goal itself), hi is
        mid = (lo + hi) // 2
        if _reach(ik, turn, mid, seed, known, qs):
            hi = mid
        else:
            lo = mid
    for i in range(q_out.shape[0]):
        q_out[i] = qs[hi, i]
    _copy4_into(turned_pose(T_goal, look_distance, rotvec, hi / VIEW_STEPS), T_out)
    return hi


@njit(cache=True)  # compiled once, then loaded from the cache
def target_error(T_target: FloatArray, T_goal: FloatArray) -> TargetError:
    """How far a target pose is from the goal (both (4, 4), world): m, and rad."""
    d0 = T_target[0, 3] - T_goal[0, 3]
    d1 = T_target[1, 3] - T_goal[1, 3]
    d2 = T_target[2, 3] - T_goal[2, 3]
    position = math.sqrt(dot3(d0, d1, d2, d0, d1, d2))
    return TargetError(position, rotation_angle(_rotation_rows(T_target), _rotation_rows(T_goal)))


@register_jitable  # compiled into its callers
def _rotation_rows(T: FloatArray) -> tuple[tuple[float, float, float], ...]:
    """The rotation rows of a pose (4, 4) as three 3-tuples of floats."""
    return (
        (T[0, 0], T[0, 1], T[0, 2]),
        (T[1, 0], T[1, 1], T[1, 2]),
        (T[2, 0], T[2, 1], T[2, 2]),
    )


@njit(cache=True)  # compiled once, then loaded from the cache
def ecm_target(
    ik: ArmIK,
    p_rcm: FloatArray,
    T_goal: FloatArray,
    look_distance: float,
    seed: FloatArray,
    T: FloatArray,
) -> EcmTarget:
    """``CameraArm.target`` on the ECM, compiled: exact, the port view, or the nearest pose.

    ``T_goal`` (4, 4): the camera goal, world, m; ``look_distance`` (m): how far ahead it
    looks; ``p_rcm`` (3,): the port, world, m; ``seed`` (4,): the measured joints (their roll
    picks the branch). The target pose is written into ``T`` (4, 4), the caller's array.

    ``ECM_EXACT``: the goal is exact, ``T`` a copy of it; ``ECM_VIEW``: the port view of the
    goal's look-at point is reached (within ``VIEW_POSITION_TOL_M``), ``T`` the camera there;
    ``ECM_NEAREST``: the nearest configuration of the goal and its camera. ``ECM_PORT_SCIPY``
    (``T``: the port view) and ``ECM_GOAL_SCIPY``: the ECM's IK needs its nearest in-limit
    position (scipy), and the caller goes on from there.
    """
    ok, q = ecm_exact12(ik.params, ik.consts, tip_goal12(ik, T_goal), seed[3])
    if ok:
        _copy4_into(T_goal, T)
        return EcmTarget(ECM_EXACT, q, _NO_ERROR)
    turn = port_rotvec(T_goal, look_distance, p_rcm)
    if turn.found:
        T_port = turned_pose(T_goal, look_distance, turn.rotvec, 1.0)
        port = solve12(ik.params, ik.consts, tip_goal12(ik, T_port), seed[3], None)
        if port.outcome != SOLVE_DONE:
            _copy4_into(T_port, T)
            return EcmTarget(ECM_PORT_SCIPY, port.q, _NO_ERROR)
        if port.position_error <= VIEW_POSITION_TOL_M:
            _copy4_into(camera_of_tip(ik, port.T12), T)
            return EcmTarget(ECM_VIEW, port.q, target_error(T, T_goal))
    near = solve12(ik.params, ik.consts, tip_goal12(ik, T_goal), seed[3], None)
    if near.outcome != SOLVE_DONE:
        _copy4_into(T_goal, T)
        return EcmTarget(ECM_GOAL_SCIPY, near.q, _NO_ERROR)
    _copy4_into(camera_of_tip(ik, near.T12), T)
    return EcmTarget(ECM_NEAREST, near.q, target_error(T, T_goal))


@register_jitable  # compiled into its callers
def _unit_clip(x: float) -> float:
    """``x`` clipped into [−1, 1] (a NaN gives 1.0)."""
    return max(-1.0, min(1.0, x))


@njit(cache=True)  # compiled once, then loaded from the cache
def path_start(T_cam: FloatArray, T_target: FloatArray, look_distance: float) -> PathStart:
    """Whether ``CameraArm`` takes the camera-space path to a target, and where it starts.

    ``T_cam``, ``T_target`` (4, 4): the camera and its target, world, m; ``look_distance``:
    how far ahead the target looks, m. Not engaged when the target is near along the path
    (``PATH_ENGAGE_M``) and the camera aims at its look-at point (``PATH_ENGAGE_AIM_RAD``),
    or when the path's next pose is the target itself and the aim is good.
    """
    z0, z1, z2 = T_target[0, 2], T_target[1, 2], T_target[2, 2]
    c0 = T_target[0, 3] + look_distance * z0
    c1 = T_target[1, 3] + look_distance * z1
    c2 = T_target[2, 3] + look_distance * z2
    c = (c0, c1, c2)
    v0, v1, v2 = T_cam[0, 3] - c0, T_cam[1, 3] - c1, T_cam[2, 3] - c2
    r_cur = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    if not r_cur > EPS_AXIS:
        return PathStart(False, r_cur, 0.0, (0.0, 0.0, 0.0), c)
    u = (v0 / r_cur, v1 / r_cur, v2 / r_cur)
    cos_aim = -(u[0] * T_cam[0, 2] + u[1] * T_cam[1, 2] + u[2] * T_cam[2, 2])
    aim = math.acos(_unit_clip(cos_aim))
    cos_t = -(u[0] * z0 + u[1] * z1 + u[2] * z2)
    ang = math.acos(_unit_clip(cos_t))  # coarse: only compared with the thresholds
    travel = math.hypot(look_distance - r_cur, 0.5 * (r_cur + look_distance) * ang)
    if travel <= PATH_ENGAGE_M and aim <= PATH_ENGAGE_AIM_RAD:
        return PathStart(False, r_cur, 0.0, u, c)
    alpha = 1.0
    if travel > 0.0:
        alpha = min(1.0, PATH_LEAD_M / travel)
    if alpha >= 1.0 and aim <= PATH_ENGAGE_AIM_RAD:
        return PathStart(False, r_cur, alpha, u, c)
    return PathStart(True, r_cur, alpha, u, c)


@njit(cache=True)  # compiled once, then loaded from the cache
def path_joints(
    ik: ArmIK,
    T_cam: FloatArray,
    T_target: FloatArray,
    look_distance: float,
    seed: FloatArray,
    out: FloatArray,
) -> bool:
    """The exact joints of the next pose on the camera-space path to a far target.

    The path orbits the target's look-at point ``c`` (``look_distance`` ahead of ``T_target``
    on its optical axis, m): the direction from ``c`` to the camera turns on the great circle
    from the current camera's (``T_cam``) to the target's, the distance changes linearly, and
    every pose looks at ``c`` with a level horizon. True, with the joints (rad / m) of the
    pose ``PATH_LEAD_M`` ahead in ``out`` (n,), when the path is taken (:func:`path_start`)
    and the arm reaches that pose exactly (:func:`exact_joints`, ``seed`` as there).
    """
    start = path_start(T_cam, T_target, look_distance)
    if not start.engage:
        return False
    u, alpha = start.u, start.alpha
    g = (-T_target[0, 2], -T_target[1, 2], -T_target[2, 2])
    a0, a1, a2 = cross(u, g)
    sin_a = math.sqrt(dot3(a0, a1, a2, a0, a1, a2))
    cos_a = dot3(u[0], u[1], u[2], g[0], g[1], g[2])
    ang = math.atan2(sin_a, cos_a)
    if sin_a > EPS_AXIS:
        k = alpha * ang / sin_a
        r0, r1, r2 = a0 * k, a1 * k, a2 * k
    elif cos_a > 0.0:
        r0, r1, r2 = 0.0, 0.0, 0.0
    else:  # opposite: over the top
        k0, k1, k2 = cross(u, (0.0, 0.0, 1.0))
        k_norm = math.sqrt(dot3(k0, k1, k2, k0, k1, k2))
        if not k_norm > EPS_AXIS:
            return False
        k = alpha * ang / k_norm
        r0, r1, r2 = k0 * k, k1 * k, k2 * k
    w0, w1, w2 = matvec3(_so3_exp(r0, r1, r2), u)
    r = start.r_cur + alpha * (look_distance - start.r_cur)
    c = start.c
    T_via = look_at_matrix((c[0] + r * w0, c[1] + r * w1, c[2] + r * w2), c, T_target)
    return _exact_into(ik, tip_goal12(ik, T_via), seed, out)


@njit(cache=True)  # compiled once, then loaded from the cache
def is_camera_command(T: FloatArray, p_rcm: FloatArray, reach: float) -> bool:
    """Whether a command (4, 4) is finite with its camera within ``reach`` (m) of ``p_rcm``.

    ``p_rcm`` (3,): the port, world, m; the distance is the largest of the three coordinate
    differences (``np.abs(T[:3, 3] − p_rcm).max() <= reach``).
    """
    for i in range(T.shape[0]):
        for j in range(T.shape[1]):
            if not math.isfinite(T[i, j]):
                return False
    for i in range(3):
        if not abs(T[i, 3] - p_rcm[i]) <= reach:
            return False
    return True


def wrist_jump(kind: ArmKind, q_before: list[float], q_after: list[float]) -> bool:
    """Whether a PSM's wrist (roll, pitch, yaw) target moved more than ``WRIST_JUMP_RAD``.

    ``q_before``, ``q_after``: the PSM's six joint targets, rad / m. A NaN first stays (as
    Python's ``max``); always False on the ECM.
    """
    if kind is not ArmKind.PSM:
        return False
    jump = max(abs(a - b) for a, b in zip(q_before[3:6], q_after[3:6], strict=True))
    return jump > WRIST_JUMP_RAD
