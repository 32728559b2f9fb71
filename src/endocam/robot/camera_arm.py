"""The camera carried by a dVRK arm: camera goals → IK → ruckig joint motion → FK camera pose.

:class:`CameraArm` is the episode runner's actuator when ``episode.arm`` is ``psm`` or ``ecm``
(see ``docs/robot.md``, "The camera arm in the episode runner"). Each control step:

1. **IK.** The policy's camera command (world) is expressed in the arm's RCM frame and solved
   in closed form, seeded by the measured joints (one IK per step).
2. **Nearest feasible view.** A goal the arm cannot reach exactly is replaced by the reachable
   view nearest to it that still looks at the same point: the camera is turned about the
   point it looks at (``look_distance`` ahead on its optical axis, the policy's working
   distance) towards the view straight from the port, by the smallest angle the arm can
   deliver (:func:`view_towards_port`; a search over that angle, warm-started from the last
   step). The feature stays centred at the working distance; only the view direction is
   conceded, and the step is flagged ``reachable = False`` with the conceded angle. For the
   ECM, whose optical axis always passes through its RCM, that view is the port view itself.
   If even the port view is out of reach (the point is beyond the insertion stroke), the arm
   approaches the nearest feasible configuration of the goal (bounded least squares).
3. **Joint motion.** :class:`~endocam.robot.arm.SimulatedArm` moves the joints towards the
   target for one control period under ruckig's joint velocity and acceleration limits, never
   beyond the joint limits. The camera's speed is therefore bounded by the arm's joint
   limits, as on a real dVRK; the Cartesian :class:`~endocam.robot.cartesian.CartesianLimiter` is
   the free camera's actuator only.
4. **FK.** The camera pose is ``T_world_rcm · FK(q) · T_tip_cam`` of the new joints: every
   pose the runner logs is one the arm reaches.

The dVRK frames: IK and FK work in the RCM frame (the dVRK's ``local/measured_cp``);
``T_world_rcm`` places the RCM (the port) in the scene, ``T_tip_cam`` mounts the camera on the
tool tip (identity for the ECM, whose tip frame is its optical frame).
"""

from __future__ import annotations

import math

import numpy as np
import ruckig
from numba import njit

from endocam.camera import StereoCamera
from endocam.geometry import UP, FloatArray, as_pose, invert_pose
from endocam.kernels import (
    cross,
    dist3,
    dot3,
    matmul4_into,
    matvec3,
    rotation_angle,
    so3_exp_entries,
)
from endocam.robot.actuator import ActuatorStatus, ActuatorStep, ArmKind, WorkspaceBound
from endocam.robot.arm import (
    ECM_MAX_ACCELERATION,
    ECM_MAX_VELOCITY,
    PSM_MAX_ACCELERATION,
    PSM_MAX_VELOCITY,
    SimulatedArm,
)
from endocam.robot.braking import ROW_LENGTH, float_rows, path_positions, profile_rows
from endocam.robot.dh import (
    Pose12,
    _compose_kernel,
    _points_kernel,
    _pose12_times_kernel,
    pose12_between,
    pose12_from_matrix,
)
from endocam.robot.ecm import _DONE as _ECM_DONE
from endocam.robot.ecm import ECM
from endocam.robot.ecm import _exact_kernel as _ecm_exact_kernel
from endocam.robot.ecm import _solve_kernel as _ecm_solve_kernel
from endocam.robot.kinematics import RcmArm
from endocam.robot.psm import PSM
from endocam.robot.psm import _exact_kernel as _psm_exact_kernel
from endocam.task.config import TaskConfig
from endocam.task.layout import FramingError, port_view
from endocam.view import look_at_columns, rotation_looking_along, vec
from endocam.workspace.cone import cone_floor_margin
from endocam.workspace.region import (
    NO_WORKSPACE,
    Workspace,
    WorkspaceState,
    workspace_all_inside,
)

__all__ = [
    "ARM_START_GAP",
    "REALTIME_NEAREST_MAX_NFEV",
    "VIEW_BISECTIONS",
    "CameraArm",
    "arm_model",
    "arm_start_view",
    "natural_pose",
    "view_towards_port",
]

# count: residual evaluations per nearest-feasible solve in the control loop (≈ 1-3 ms); the
# default 200 costs up to ~50 ms, and a goal sliding along the reach boundary moves little
# between control steps, so a short warm-started solve tracks it.
REALTIME_NEAREST_MAX_NFEV = 10


def arm_model(kind: ArmKind) -> RcmArm:
    """The kinematic model of an arm kind, with the control loop's nearest-feasible budget.

    Raises
    ------
    ValueError
        For ``ArmKind.FREE``.
    """
    if kind is ArmKind.PSM:
        return PSM(nearest_max_nfev=REALTIME_NEAREST_MAX_NFEV)
    if kind is ArmKind.ECM:
        return ECM(nearest_max_nfev=REALTIME_NEAREST_MAX_NFEV)
    raise ValueError(f"kind: {kind.value!r} has no kinematic model")


def natural_pose(model: RcmArm) -> FloatArray:
    """Mid-range configuration: revolute joints at 0 (clipped), insertion at mid-stroke.

    The shaft then points along the RCM frame's −z axis (the direction
    ``SceneConfig.rcm_euler_xyz`` aims into the task).

    Returns
    -------
    q : (n,) ndarray
        rad / m.
    """
    mid = 0.5 * (model.lower + model.upper)
    q = np.where(model.prismatic, mid, 0.0)
    return model.clamp(q)


VIEW_BISECTIONS = 7  # count: the conceded view angle is resolved to θ / 2⁷ (< 1.5° for θ ≤ π)
VIEW_STEPS = 2**VIEW_BISECTIONS  # count: the turn towards the port view is searched in these steps
MAX_COMMAND_RANGE_M = 10.0  # m: a command farther than this from the port is not a camera pose
VIEW_POSITION_TOL_M = 1e-6  # m: an ECM port view whose camera is this close counts as reached
_EPS_AXIS = 1e-12  # unitless: a cross product shorter than this has no direction
PATH_LEAD_M = 0.02  # m: how far ahead of the camera, along its camera-space path, the joints aim
PATH_ENGAGE_M = 0.02  # m: a target farther along the path than this is approached on the path
PATH_ENGAGE_AIM_RAD = math.radians(10.0)  # rad: or a camera aimed this far off its look-at point


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
    found, r0, r1, r2 = _port_rotvec_kernel(T_world_cam, look_distance, p_world_rcm)
    if not found:
        return np.array(T_world_cam, dtype=float)
    return _turned_kernel(T_world_cam, look_distance, r0, r1, r2, fraction)


def _norm(v: FloatArray) -> float:
    """``np.linalg.norm`` of a contiguous 3-vector, m, without its argument handling.

    The same arithmetic (``sqrt(v · v)``, numpy's dot): a sum of squares on Python floats
    can differ in the last bit, and the logs must not.
    """
    return math.sqrt(v.dot(v))


# CameraArm._frames: the (4, 4, 4) poses its kernels take (m)
_F_WORLD_RCM, _F_RCM_WORLD, _F_TIP_CAM, _F_CAM_TIP = 0, 1, 2, 3


@njit(cache=True)  # compiled once, then loaded from the cache
def _so3_exp(x: float, y: float, z: float) -> FloatArray:
    """:func:`endocam.kernels.so3_exp` of the rotation vector ``(x, y, z)`` (rad): (3, 3) array."""
    e = so3_exp_entries(x, y, z)
    R = np.empty((3, 3))
    R[0, 0], R[0, 1], R[0, 2] = e[0], e[1], e[2]
    R[1, 0], R[1, 1], R[1, 2] = e[3], e[4], e[5]
    R[2, 0], R[2, 1], R[2, 2] = e[6], e[7], e[8]
    return R


@njit(cache=True)  # compiled once, then loaded from the cache
def _port_rotvec_kernel(
    T: FloatArray, look_distance: float, p_rcm: FloatArray
) -> tuple[bool, float, float, float]:
    """The rotation vector (rad) taking a camera's optical axis onto the port direction.

    ``T`` (4, 4): the camera, world, m; ``p_rcm`` (3,): the port, world, m. ``(False, …)``
    when the look-at point (``look_distance`` ahead on z, m) is at the port. numpy's floats
    (``np.linalg.norm`` and ``@`` through :mod:`endocam.blasfloat`'s dot).
    """
    z0, z1, z2 = T[0, 2], T[1, 2], T[2, 2]
    v0 = T[0, 3] + look_distance * z0 - p_rcm[0]
    v1 = T[1, 3] + look_distance * z1 - p_rcm[1]
    v2 = T[2, 3] + look_distance * z2 - p_rcm[2]
    norm_v = math.sqrt(dot3(v0, v1, v2, v0, v1, v2))
    if norm_v <= _EPS_AXIS:
        return False, 0.0, 0.0, 0.0
    v0, v1, v2 = v0 / norm_v, v1 / norm_v, v2 / norm_v
    a0, a1, a2 = cross((z0, z1, z2), (v0, v1, v2))
    sin_t, cos_t = math.sqrt(dot3(a0, a1, a2, a0, a1, a2)), dot3(z0, z1, z2, v0, v1, v2)
    if sin_t <= _EPS_AXIS:
        if cos_t > 0.0:
            return True, 0.0, 0.0, 0.0
        a0, a1, a2, sin_t = T[0, 1], T[1, 1], T[2, 1], 1.0  # straight at the port: pan about y
    k = math.atan2(sin_t, cos_t) / sin_t
    return True, a0 * k, a1 * k, a2 * k


@njit(cache=True)  # compiled once, then loaded from the cache
def _look_at_matrix(
    p: tuple[float, float, float], c: tuple[float, float, float], T: FloatArray
) -> FloatArray:
    """:func:`~endocam.view.look_at_unchecked` from ``p`` at ``c`` (world, m), rolled as ``T``.

    A (4, 4) pose, m; a copy of ``T`` (4, 4) when the two points coincide.
    """
    found, x, y, z = look_at_columns(p, c, (T[0, 0], T[1, 0], T[2, 0]))
    out = np.empty((4, 4))
    if not found:
        out[:] = T
        return out
    for i in range(3):
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = x[i], y[i], z[i], p[i]
    out[3, 0], out[3, 1], out[3, 2], out[3, 3] = 0.0, 0.0, 0.0, 1.0
    return out


@njit(cache=True)  # compiled once, then loaded from the cache
def _turned_kernel(
    T: FloatArray, look_distance: float, r0: float, r1: float, r2: float, fraction: float
) -> FloatArray:
    """``T`` (4, 4) moved about its look-at point by ``fraction`` of the rotation ``r`` (rad).

    The look-at point is ``look_distance`` (m) ahead on the optical axis; the horizon is
    levelled again (rolled as ``T`` near vertical). A new (4, 4) pose, world, m.
    """
    R = _so3_exp(fraction * r0, fraction * r1, fraction * r2)
    z0, z1, z2 = T[0, 2], T[1, 2], T[2, 2]
    zt0 = R[0, 0] * z0 + R[0, 1] * z1 + R[0, 2] * z2
    zt1 = R[1, 0] * z0 + R[1, 1] * z1 + R[1, 2] * z2
    zt2 = R[2, 0] * z0 + R[2, 1] * z1 + R[2, 2] * z2
    c0 = T[0, 3] + look_distance * z0
    c1 = T[1, 3] + look_distance * z1
    c2 = T[2, 3] + look_distance * z2
    p = (c0 - look_distance * zt0, c1 - look_distance * zt1, c2 - look_distance * zt2)
    return _look_at_matrix(p, (c0, c1, c2), T)


@njit(cache=True)  # compiled once, then loaded from the cache
def _between12(frames: FloatArray, T: FloatArray) -> Pose12:
    """The tool tip's goal in the RCM frame (12 floats, m) of a camera pose ``T`` (4, 4), world.

    :func:`~endocam.robot.dh.pose12_between` of ``T_rcm_world``, ``T``, ``T_cam_tip``.
    """
    A, B = frames[_F_RCM_WORLD], frames[_F_CAM_TIP]
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
def _exact_into(
    psm: bool,
    params: FloatArray,
    consts: FloatArray,
    frames: FloatArray,
    T: FloatArray,
    seed0: float,
    seed3: float,
    out: FloatArray,
) -> bool:
    """:meth:`CameraArm._exact`: the exact joints of a camera pose ``T`` (4, 4), world, m.

    The arm's compiled exact IK (the PSM's, ``psm`` True, or the ECM's; ``params``, ``consts``:
    its chain's parameters and its constants; seeded by joints 0 and 3 of the measured ones,
    rad; ``two``: 2.0) of the tip goal :func:`_between12`. True and the joints (rad / m) in
    ``out`` (n,) if they exist; False (``out`` untouched) if not.
    """
    goal12 = _between12(frames, T)
    if psm:
        ok, q6 = _psm_exact_kernel(params, consts, goal12, seed0, seed3)
        if ok:
            for i in range(6):
                out[i] = q6[i]
        return ok
    ok4, q4 = _ecm_exact_kernel(params, consts, goal12, seed3)
    if ok4:
        for i in range(4):
            out[i] = q4[i]
    return ok4


@njit(cache=True)  # compiled once, then loaded from the cache
def _tip_goal12(frames: FloatArray, T: FloatArray) -> Pose12:
    """``T_rcm_world @ T @ T_cam_tip`` (numpy's floats) as 12 floats, m: the tip's goal."""
    A, B = np.empty((4, 4)), np.empty((4, 4))
    matmul4_into(frames[_F_RCM_WORLD], T, A)
    matmul4_into(A, frames[_F_CAM_TIP], B)
    return (
        B[0, 0], B[0, 1], B[0, 2], B[1, 0], B[1, 1], B[1, 2], B[2, 0], B[2, 1], B[2, 2],
        B[0, 3], B[1, 3], B[2, 3],
    )  # fmt: skip


@njit(cache=True)  # compiled once, then loaded from the cache
def _reached(frames: FloatArray, T12: Pose12) -> FloatArray:
    """``T_world_rcm @ T_rcm_tip @ T_tip_cam`` (numpy's floats): the camera (4, 4), world, m.

    ``T12``: the tip in the RCM frame (12 floats, m).
    """
    T = np.empty((4, 4))
    for i in range(3):
        T[i, 0], T[i, 1], T[i, 2], T[i, 3] = T12[3 * i], T12[3 * i + 1], T12[3 * i + 2], T12[9 + i]
    T[3, 0], T[3, 1], T[3, 2], T[3, 3] = 0.0, 0.0, 0.0, 1.0
    A, out = np.empty((4, 4)), np.empty((4, 4))
    matmul4_into(frames[_F_WORLD_RCM], T, A)
    matmul4_into(A, frames[_F_TIP_CAM], out)
    return out


# _ecm_target_kernel's outcomes: the answer (exact, the port view, the nearest pose), or the
# nearest in-limit position is needed (scipy, in Python) for the port view or for the goal
_TARGET_EXACT, _TARGET_VIEW, _TARGET_NEAREST, _TARGET_PORT_SCIPY, _TARGET_GOAL_SCIPY = range(5)


@njit(cache=True)  # compiled once, then loaded from the cache
def _ecm_target_kernel(
    params: FloatArray,
    consts: FloatArray,
    frames: FloatArray,
    p_rcm: FloatArray,
    T_goal: FloatArray,
    look_distance: float,
    seed3: float,
    T: FloatArray,
) -> tuple[int, tuple[float, float, float, float], float, float]:
    """:meth:`CameraArm.target` on the ECM: ``(outcome, q, position_error, angle_error)``.

    ``outcome``: one of ``_TARGET_*``; the pose ``T`` below is written into ``T`` (4, 4), the
    caller's array (none to box).

    ``_TARGET_EXACT``: the goal ``T_goal`` (4, 4, world, m) is exact, ``q`` its joints (rad /
    m) and ``T`` a copy of it; ``_TARGET_VIEW``: the port view of the goal's look-at point
    (``look_distance`` ahead, m; ``p_rcm`` (3,): the port, m) is reached (within
    ``VIEW_POSITION_TOL_M``), ``q`` its joints and ``T`` the camera there; ``_TARGET_NEAREST``:
    the nearest configuration of the goal, ``q`` and its camera ``T``. ``_TARGET_PORT_SCIPY``
    (``T``: the port view) and ``_TARGET_GOAL_SCIPY``: the ECM's IK needs its nearest in-limit
    position (scipy): the caller goes on from there. The ECM's compiled IK
    (:func:`~endocam.robot.ecm._exact_kernel`, ``_solve_kernel``; ``seed3``: the measured
    roll, rad; ``two``: 2.0) and numpy's products (:mod:`endocam.blasfloat`). Then how far
    ``T`` is from the goal (:func:`_target_error_kernel`: m, rad; 0.0 but for the view and the
    nearest pose).
    """
    ok, q = _ecm_exact_kernel(params, consts, _between12(frames, T_goal), seed3)
    if ok:
        T[:, :] = T_goal
        return _TARGET_EXACT, q, 0.0, 0.0
    found, r0, r1, r2 = _port_rotvec_kernel(T_goal, look_distance, p_rcm)
    if found:
        T_port = _turned_kernel(T_goal, look_distance, r0, r1, r2, 1.0)
        goal = _tip_goal12(frames, T_port)
        outcome, _, q, pos_err, _, T12, _ = _ecm_solve_kernel(params, consts, goal, seed3, None)
        if outcome != _ECM_DONE:
            T[:, :] = T_port
            return _TARGET_PORT_SCIPY, q, 0.0, 0.0
        if pos_err <= VIEW_POSITION_TOL_M:
            T[:, :] = _reached(frames, T12)
            e_pos, e_ang = _target_error_kernel(T, T_goal)
            return _TARGET_VIEW, q, e_pos, e_ang
    goal = _tip_goal12(frames, T_goal)
    outcome, _, q, _, _, T12, _ = _ecm_solve_kernel(params, consts, goal, seed3, None)
    if outcome != _ECM_DONE:
        T[:, :] = T_goal
        return _TARGET_GOAL_SCIPY, q, 0.0, 0.0
    T[:, :] = _reached(frames, T12)
    e_pos, e_ang = _target_error_kernel(T, T_goal)
    return _TARGET_NEAREST, q, e_pos, e_ang


@njit(cache=True)  # compiled once, then loaded from the cache
def _path_kernel(
    psm: bool,
    params: FloatArray,
    consts: FloatArray,
    frames: FloatArray,
    T_cam: FloatArray,
    T_target: FloatArray,
    look_distance: float,
    seed0: float,
    seed3: float,
    out: FloatArray,
) -> bool:
    """:meth:`CameraArm._path_target`: whether the camera-space path is taken, its joints.

    ``T_cam``, ``T_target`` (4, 4): the camera and its target, world, m; ``look_distance``:
    m. True, with the exact joints (rad / m) of the path's next pose in ``out`` (n,), when
    the path is taken (:func:`_path_engage_kernel`) and the arm reaches that pose exactly
    (:func:`_exact_into`; ``psm``, ``params``, ``consts``, ``frames``, the seeds and ``two``
    as there). numpy's floats for its products (:mod:`endocam.blasfloat`).
    """
    engage, r_cur, alpha, u0, u1, u2, c0, c1, c2 = _path_engage_kernel(
        T_cam, T_target, look_distance
    )
    if not engage:
        return False
    g0, g1, g2 = -T_target[0, 2], -T_target[1, 2], -T_target[2, 2]
    a0, a1, a2 = cross((u0, u1, u2), (g0, g1, g2))
    sin_a = math.sqrt(dot3(a0, a1, a2, a0, a1, a2))
    cos_a = dot3(u0, u1, u2, g0, g1, g2)
    ang = math.atan2(sin_a, cos_a)
    if sin_a > _EPS_AXIS:
        k = alpha * ang / sin_a
        r0, r1, r2 = a0 * k, a1 * k, a2 * k
    elif cos_a > 0.0:
        r0, r1, r2 = 0.0, 0.0, 0.0
    else:  # opposite: over the top
        k0, k1, k2 = cross((u0, u1, u2), (0.0, 0.0, 1.0))
        k_norm = math.sqrt(dot3(k0, k1, k2, k0, k1, k2))
        if not k_norm > _EPS_AXIS:
            return False
        k = alpha * ang / k_norm
        r0, r1, r2 = k0 * k, k1 * k, k2 * k
    R = _so3_exp(r0, r1, r2)
    r = r_cur + alpha * (look_distance - r_cur)
    w0, w1, w2 = matvec3(R, (u0, u1, u2))
    p = (c0 + r * w0, c1 + r * w1, c2 + r * w2)
    T_via = _look_at_matrix(p, (c0, c1, c2), T_target)
    return _exact_into(psm, params, consts, frames, T_via, seed0, seed3, out)


class CameraArm:
    """A camera on a dVRK arm (PSM or ECM): one IK, one ruckig joint step and FK per step.

    Parameters
    ----------
    kind : ArmKind
        ``PSM`` or ``ECM``.
    T_world_rcm : (4, 4) array_like
        Pose of the arm's RCM frame in world, m.
    T_tip_cam : (4, 4) array_like
        Camera optical frame in the tool-tip frame, m (identity for the ECM's 0° scope).
    dt : float
        Control period, s.
    workspace : WorkspaceBound, optional
        Where the camera may be (cone and floor). Once the camera can stop inside it, each
        step's joint motion is accepted only if the camera stays inside and the joints'
        stopping point (each joint braked at its acceleration limit) still puts the camera
        inside; otherwise the arm brakes to the stopping point of the step before, which was
        checked the same way. A joint-space path between two goals inside the cone therefore
        no longer swings the camera out of it.
    """

    camera_path: bool = True
    """Approach a far target along a camera-space path about its look-at point (False: the
    straight joint-space line; an ablation switch)."""
    via_port: bool = True
    """After a jump of the wrist's target, pass through the port view (needs ``camera_path``)."""
    follows_twist = False  # the joint motion does not use the command's velocity (yet)

    def __init__(
        self,
        kind: ArmKind,
        T_world_rcm: object,
        T_tip_cam: object,
        dt: float,
        workspace: WorkspaceBound | None = None,
    ) -> None:
        self.kind = kind
        self.model = arm_model(kind)
        self._T_world_rcm = as_pose(np.asarray(T_world_rcm, dtype=float), "T_world_rcm")
        self._T_rcm_world = invert_pose(self._T_world_rcm)
        self._p_world_rcm = self._T_world_rcm[:3, 3].copy()
        self._p_rcm_list = self._p_world_rcm.tolist()
        self._T_tip_cam = as_pose(np.asarray(T_tip_cam, dtype=float), "T_tip_cam")
        self._T_cam_tip = invert_pose(self._T_tip_cam)
        # float forms for the control loop: FK starts at the RCM in world and ends at the camera
        self._world_rcm12 = pose12_from_matrix(self._T_world_rcm)
        self._rcm_world12 = pose12_from_matrix(self._T_rcm_world)
        self._cam_tip_rows = tuple(tuple(row) for row in self._T_cam_tip[:3].tolist())
        T_last_cam = self.model.chain.T_last_tip @ self._T_tip_cam
        self._last_cam_rows = tuple(tuple(row) for row in T_last_cam[:3].tolist())
        self._last_cam_point = (
            self._last_cam_rows[0][3],
            self._last_cam_rows[1][3],
            self._last_cam_rows[2][3],
        )  # the camera's origin in the last link's frame, m
        # _pose_kernel's constants: T_world_rcm (12 floats), T_last_cam's rows, the RCM, m
        self._pose_consts = np.array(
            [*self._world_rcm12, *T_last_cam[:3].ravel().tolist(), *self._p_rcm_list]
        )
        # the kernels' arm state: its poses (_F_*), its IK's constants, an output row
        self._frames = np.ascontiguousarray(
            [self._T_world_rcm, self._T_rcm_world, self._T_tip_cam, self._T_cam_tip], dtype=float
        )
        self._is_psm = kind is ArmKind.PSM
        self._ik_params = self.model.chain._param_array
        self._ik_consts: FloatArray = self.model._consts  # type: ignore[attr-defined]
        self._q_out = np.empty(self.model.n_joints)
        self._stop_row = np.empty(self.model.n_joints)  # _stop_kernel's stopping point
        self._arm = SimulatedArm(self.model, dt=dt, q0=natural_pose(self.model))
        self._q = self._arm.measured_js()[0]
        self._T_cam = self.camera_pose(self._q)
        self._k_prev: int | None = None  # the last conceded turn, in VIEW_STEPS (warm start)
        self._last_key: bytes | None = None  # the last goal (bytes) and its look distance
        self._last_look = math.nan
        # the last goal's answer: joints, target pose, status, position and angle errors
        self._last_target: tuple[list[float], FloatArray, ActuatorStatus, float, float] | None
        self._last_target = None
        self._via_port = False  # on the path through the port view after a target jump
        self._stalled: int | None = None  # a stalled joint (fault injection)
        self.workspace = workspace
        amax = PSM_MAX_ACCELERATION if kind is ArmKind.PSM else ECM_MAX_ACCELERATION
        vmax = PSM_MAX_VELOCITY if kind is ArmKind.PSM else ECM_MAX_VELOCITY
        # braking distance v²/2a, planned at BRAKE_ACC_SHARE of the limit: ruckig can then
        # always reach the stopping point (at the full limit round-off can make it infeasible)
        self._half_inv_acc = [0.5 / (BRAKE_ACC_SHARE * a) for a in amax]  # s²/rad or s²/m
        self._prismatic = self.model.prismatic
        self._stop_consts = np.array(  # _stop_kernel's per-joint constants (rows)
            [
                self._half_inv_acc,
                [1.0 if pri else 0.0 for pri in self._prismatic],
                self.model.lower.tolist(),
                self.model.upper.tolist(),
            ]
        )
        self._dt = dt
        n = len(amax)
        # the braking path as the arm's own ruckig (same limits, synchronised) will drive it
        self._brake_otg = ruckig.Ruckig(n)
        self._brake_inp = ruckig.InputParameter(n)
        self._brake_inp.max_velocity = list(vmax)
        self._brake_inp.max_acceleration = list(amax)
        self._brake_inp.max_jerk = [math.inf] * n
        self._brake_inp.current_acceleration = [0.0] * n  # every braking path starts so
        self._brake_traj = ruckig.Trajectory(n)
        self._safe = False  # the camera can stop inside the workspace
        # the workspace whose cone and floor _stop_kernel has (None: none yet), and those
        self._cone_of: tuple[WorkspaceBound | None, FloatArray | None] = (None, None)
        self._stop: list[float] = self._q.tolist()  # where the joints stop if braked now
        self.braked = 0  # steps on which the workspace made the arm brake

    # ------------------------------------------------------------------ frames
    @property
    def joint_names(self) -> tuple[str, ...]:
        """Joint names from the base outwards."""
        return self.model.joint_names

    def start_view(self, task_cfg: TaskConfig, camera: StereoCamera) -> tuple[FloatArray, float]:
        """The port view of the whole task this arm starts from (:func:`arm_start_view`)."""
        return arm_start_view(self, task_cfg, camera)

    @property
    def p_world_rcm(self) -> FloatArray:
        """(3,) the RCM (the port) in world, m (copy)."""
        return self._p_world_rcm.copy()

    @property
    def shortest_reach(self) -> float:
        """Distance from the RCM to the camera at the shortest insertion, wrist straight, m."""
        q = natural_pose(self.model)
        prismatic = np.array(self.model.prismatic)
        q[prismatic] = self.model.lower[prismatic]
        return _norm(self.camera_pose(q)[:3, 3] - self._p_world_rcm)

    @property
    def q(self) -> FloatArray:
        """Measured joint positions, (n,), rad / m (copy)."""
        return self._q.copy()

    @property
    def arm(self) -> SimulatedArm:
        """The simulated (CRTK-named) arm that moves the joints."""
        return self._arm

    @property
    def T_world_rcm(self) -> FloatArray:
        """(4, 4) RCM frame in world, m (copy)."""
        return self._T_world_rcm.copy()

    @property
    def T_tip_cam(self) -> FloatArray:
        """(4, 4) camera optical frame in the tool-tip frame, m (copy)."""
        return self._T_tip_cam.copy()

    def camera_pose(self, q: object) -> FloatArray:
        """Camera pose for joints ``q`` (n,): ``T_world_cam`` (4, 4), optical frame, m."""
        return self._camera_pose(self.model.check_q(q).tolist())

    def _camera_pose(self, q: list[float] | FloatArray) -> FloatArray:
        """``T_world_rcm · FK(q) · T_tip_cam`` (4, 4), m, on plain floats (unchecked ``q``).

        One compiled call (:func:`_pose_kernel`).
        """
        return _pose_kernel(self.model.chain._param_array, self._pose_consts, np.asarray(q, float))

    def camera_poses(self, q: FloatArray) -> FloatArray:
        """:meth:`camera_pose` for joint rows ``q`` (N, n): ``T_world_cam`` (N, 4, 4), m."""
        return np.array([self.camera_pose(row) for row in np.asarray(q, dtype=float)])

    def link_frames(self, q: object) -> FloatArray:
        """World poses of the DH link frames and the tip for joints ``q``: (n + 1, 4, 4), m."""
        return self._T_world_rcm @ self.model.frames(q)

    # ------------------------------------------------------------------ control
    def _port_distance(self, T_world_cam: FloatArray) -> float:
        """Distance from a camera to the port, m (≥ 1 mm): the default look distance."""
        return max(float(np.linalg.norm(T_world_cam[:3, 3] - self._p_world_rcm)), 1e-3)

    def _tip_goal(self, T_world_cam: FloatArray) -> FloatArray:
        return self._T_rcm_world @ T_world_cam @ self._T_cam_tip

    def _exact(self, T_world_cam: FloatArray) -> list[float] | None:
        """The exact joints (rad / m) of a camera pose (4, 4), world, m; ``None`` if none.

        One compiled call (:func:`_exact_into`), seeded by the measured joints.
        """
        q, out = self._q, self._q_out
        if _exact_into(
            self._is_psm, self._ik_params, self._ik_consts, self._frames, T_world_cam,
            q[0], q[3], out,
        ):  # fmt: skip
            return out.tolist()
        return None

    def target(
        self, T_world_goal: FloatArray, look_distance: float
    ) -> tuple[list[float], FloatArray, ActuatorStatus]:
        """Joint target for a camera goal: exact, nearest feasible view, or nearest pose.

        Parameters
        ----------
        T_world_goal : (4, 4) ndarray
            Camera goal, world, optical frame, m (a valid pose).
        look_distance : float
            Distance from the goal camera to the point it looks at, m (> 0).

        Returns
        -------
        q : list of float
            Joint target within the limits, rad / m.
        T_world_target : (4, 4) ndarray
            The camera pose of ``q``'s goal: the goal, or the view put in its place, m.
        status : ActuatorStatus
        """
        q, T, status, _, _ = self._target_errors(T_world_goal, look_distance)
        return q, T, status

    def _target_errors(
        self, T_world_goal: FloatArray, look_distance: float
    ) -> tuple[list[float], FloatArray, ActuatorStatus, float, float]:
        """:meth:`target`, and how far its pose is from the goal: m, rad (0 when exact)."""
        if not self._is_psm:
            return self._ecm_target(T_world_goal, look_distance)
        q, T, status = self._psm_target(T_world_goal, look_distance)
        if status is ActuatorStatus.EXACT:
            return q, T, status, 0.0, 0.0
        return q, T, status, *_target_error_kernel(T, T_world_goal)

    def _psm_target(
        self, T_world_goal: FloatArray, look_distance: float
    ) -> tuple[list[float], FloatArray, ActuatorStatus]:
        """:meth:`target` on the PSM: exact, the nearest reachable turn towards the port view."""
        q = self._exact(T_world_goal)
        if q is not None:
            self._k_prev = None
            T_target = np.array(T_world_goal, dtype=float)  # not the caller's array
            T_target.setflags(write=False)
            return q, T_target, ActuatorStatus.EXACT
        found, r0, r1, r2 = _port_rotvec_kernel(T_world_goal, look_distance, self._p_world_rcm)
        if found:
            view = self._view_search(T_world_goal, look_distance, (r0, r1, r2))
            if view is not None:
                return view[0], view[1], ActuatorStatus.VIEW
        return self._nearest(T_world_goal)

    def _nearest(self, T_world_goal: FloatArray) -> tuple[list[float], FloatArray, ActuatorStatus]:
        """The nearest configuration of a camera goal (4, 4), world, m, and its camera, m."""
        self._k_prev = None
        result = self.model.solve_unchecked(self._tip_goal(T_world_goal), self._q)
        T_near = self._T_world_rcm @ result.T_rcm_tip @ self._T_tip_cam
        return result.q.tolist(), T_near, ActuatorStatus.NEAREST

    def _ecm_target(
        self, T_world_goal: FloatArray, look_distance: float
    ) -> tuple[list[float], FloatArray, ActuatorStatus, float, float]:
        """:meth:`_target_errors` on the ECM: one compiled call (:func:`_ecm_target_kernel`).

        The 4-DoF scope's only view of the goal's look-at point is its port view; a roll
        beyond its limits is conceded too (the horizon tilts), as long as the view itself is
        reached. scipy's nearest in-limit position, when the IK needs it, is found here.
        """
        q, T = self._q, np.empty((4, 4))
        outcome, q_new, pos_err, ang_err = _ecm_target_kernel(
            self._ik_params, self._ik_consts, self._frames, self._p_world_rcm, T_world_goal,
            look_distance, q[3], T,
        )  # fmt: skip
        if outcome == _TARGET_EXACT:
            self._k_prev = None
            T.setflags(write=False)
            return list(q_new), T, ActuatorStatus.EXACT, 0.0, 0.0
        if outcome == _TARGET_VIEW:
            return list(q_new), T, ActuatorStatus.VIEW, pos_err, ang_err
        if outcome == _TARGET_NEAREST:
            self._k_prev = None
            return list(q_new), T, ActuatorStatus.NEAREST, pos_err, ang_err
        found = None
        if outcome == _TARGET_PORT_SCIPY:  # T: the port view
            port = self.model.solve_unchecked(self._tip_goal(T), self._q)
            if port.position_error <= VIEW_POSITION_TOL_M:
                T_reached = self._T_world_rcm @ port.T_rcm_tip @ self._T_tip_cam
                found = (port.q.tolist(), T_reached, ActuatorStatus.VIEW)
        if found is None:
            found = self._nearest(T_world_goal)
        return (*found, *_target_error_kernel(found[1], T_world_goal))

    def _view_search(
        self, T_goal: FloatArray, look_distance: float, rotvec: tuple[float, float, float]
    ) -> tuple[list[float], FloatArray] | None:
        """A locally smallest reachable turn ``k / VIEW_STEPS`` towards the port view.

        Returns the ``k`` in 1…VIEW_STEPS whose turn the arm reaches while ``k − 1``'s it does
        not (``k = 0`` is the goal itself). Reachability mostly grows along the turn (the port
        view, ``k = VIEW_STEPS``, is the easiest), but not always: a wrist joint can touch its
        limit in the middle of the turn, leaving a gap, and then a smaller reachable ``k`` may
        exist below the gap. Cold, the search bisects over ``k`` (``VIEW_BISECTIONS`` solves
        after the port view); warm (the previous step conceded too), it starts at the previous
        ``k`` and gallops towards the boundary, so a boundary that moves little costs two or
        three solves and the view stays on the same side of any gap from step to step
        (continuity before minimality; at most about ``2 · VIEW_BISECTIONS`` solves when the
        boundary jumps).
        """
        cache: dict[int, tuple[list[float], FloatArray] | None] = {}
        r0, r1, r2 = rotvec

        def reach(k: int) -> tuple[list[float], FloatArray] | None:
            if k not in cache:
                T = _turned_kernel(T_goal, look_distance, r0, r1, r2, k / VIEW_STEPS)
                q = self._exact(T)
                cache[k] = None if q is None else (q, T)
            return cache[k]

        guess = self._k_prev
        if guess is None:
            if reach(VIEW_STEPS) is None:
                return None
            lo, hi = 0, VIEW_STEPS
        elif reach(guess) is not None:  # gallop down towards the goal
            hi, step = guess, 1
            while True:
                lo = max(hi - step, 0)
                if lo == 0 or reach(lo) is None:
                    break
                hi, step = lo, 2 * step
        else:  # gallop up towards the port view
            lo, step = guess, 1
            while True:
                hi = min(lo + step, VIEW_STEPS)
                if reach(hi) is not None:
                    break
                if hi == VIEW_STEPS:
                    self._k_prev = None
                    return None
                lo, step = hi, 2 * step
        while hi - lo > 1:  # reach(lo) is None (k = 0 is the goal itself), reach(hi) is not
            mid = (lo + hi) // 2
            if reach(mid) is None:
                lo = mid
            else:
                hi = mid
        self._k_prev = hi
        return reach(hi)

    def _on_path(self, q_target: list[float], T_target: FloatArray, look: float) -> list[float]:
        """The joint set point of this step: towards ``q_target`` along a camera-space path.

        After a jump of the wrist's target (a side change, or the nearest feasible view crossing
        a reachability gap: the same view from another wrist configuration), the path leads
        through the port view of the look-at point, whose wrist is straight and which both
        configurations reach continuously; it continues to the target once the camera is there.
        """
        if self._via_port:
            T_port = view_towards_port(T_target, look, self._p_world_rcm, 1.0)
            q_via = self._path_target(T_port, look)
            if q_via is not None:
                return q_via
            self._via_port = False  # at the port view (or no path to it): on to the target
        q_via = self._path_target(T_target, look)
        return q_target if q_via is None else q_via

    def _path_target(self, T_target: FloatArray, look_distance: float) -> list[float] | None:
        """Joint target of the next pose on the camera-space path to a far target; else None.

        The path orbits the target's look-at point ``c`` (``look_distance`` ahead of the target on
        its optical axis): the direction from ``c`` to the camera turns on the great circle from
        the current camera's to the target's, the distance changes linearly, and every pose on it
        looks at ``c`` with a level horizon. The pose ``PATH_LEAD_M`` ahead of the current camera
        (path length) is solved in closed form, seeded by the measured joints; the joints then
        move towards it for one step, so a far target is reached along the path instead of the
        straight joint-space line (whose view swings away from ``c``).
        """
        q, out = self._q, self._q_out
        if _path_kernel(
            self._is_psm, self._ik_params, self._ik_consts, self._frames, self._T_cam, T_target,
            look_distance, q[0], q[3], out,
        ):  # fmt: skip
            return out.tolist()
        return None

    def reset(self, T_world_cam: object, look_distance: float | None = None) -> FloatArray:
        """Place the arm, at rest, at the configuration nearest to a camera pose.

        IK is seeded by :func:`natural_pose`; an unreachable pose is treated as in
        :meth:`step` (nearest feasible view, then nearest configuration).

        Parameters
        ----------
        T_world_cam : (4, 4) array_like
            Wanted initial camera pose, world, optical frame, m.
        look_distance : float, optional
            Distance to the point the camera looks at, m; default: the distance from the
            camera to the RCM (the view is turned about a point as far ahead as the port is
            behind).

        Returns
        -------
        T_world_cam : (4, 4) ndarray
            The initial camera pose actually taken, ``FK(q0)``, m.
        """
        T = as_pose(np.asarray(T_world_cam, dtype=float), "T_world_cam")
        if look_distance is not None and not (math.isfinite(look_distance) and look_distance > 0.0):
            raise ValueError(
                f"look_distance: must be a positive number of metres, got {look_distance}"
            )
        self._k_prev = None
        self._last_key, self._last_target = None, None
        self._via_port = False
        if look_distance is None:
            look_distance = self._port_distance(T)
        self._q = natural_pose(self.model)
        q0, _, _ = self.target(T, look_distance)
        self._arm.reset(q0)
        self._q = self._arm.measured_js()[0]
        self._T_cam = self.camera_pose(self._q)
        if self.workspace is not None:
            self._stop, self._safe, _ = self._stop_point()
        return self._T_cam.copy()

    def stall(self, joint: int | None) -> None:
        """Fault injection: joint ``joint`` (index) stalls where it is; ``None``: none stalls.

        A stalled joint's setpoint is frozen at its measured position each step, so its drive
        brakes it within its acceleration limit and holds it; the other joints keep following
        their targets, and the camera goes wherever that takes it (FK of the joints).
        """
        if joint is not None and not 0 <= joint < len(self.joint_names):
            raise ValueError(f"joint: index {joint} outside 0..{len(self.joint_names) - 1}")
        self._stalled = joint

    def step(
        self, T_world_cmd: FloatArray, look_distance: float, twist: FloatArray | None = None
    ) -> ActuatorStep:
        """One control step towards a commanded camera pose (see the module docstring).

        Parameters
        ----------
        T_world_cmd : (4, 4) ndarray
            Commanded camera pose, world, optical frame, m. A non-finite command is replaced
            by the camera's current pose: the arm brakes to a stop where it is.
        look_distance : float
            Distance from the commanded camera to the point it looks at (the policy's working
            distance), m; the pivot of the nearest feasible view. A non-finite or non-positive
            value is replaced by the distance to the RCM.
        twist : (6,) ndarray, optional
            The command's velocity; the joint motion does not use it (yet).

        Returns
        -------
        ActuatorStep

        Notes
        -----
        A goal identical to the last step's reuses its joint target (a conceded view only at the
        same look distance): a held camera (``fixed``, frozen, lost tracking) costs no IK. A
        command more than ``MAX_COMMAND_RANGE_M`` from the port, or one no solver can digest,
        is treated like a non-finite one: the arm brakes where it is.
        """
        if _is_camera_command(T_world_cmd, self._p_world_rcm, MAX_COMMAND_RANGE_M):
            T_goal = T_world_cmd
        else:  # not a camera command: brake where the arm is
            T_goal = self._T_cam
        if not (math.isfinite(look_distance) and look_distance > 0.0):
            look_distance = self._port_distance(T_goal)
        key = T_goal.tobytes()
        last = self._last_target
        if (
            last is not None
            and key == self._last_key
            and (last[2] is ActuatorStatus.EXACT or look_distance == self._last_look)
        ):
            # a held goal (the same bytes): the same answer (exact: at any distance)
            q_cmd, T_target, approach, pos_err, ang_err = last
        else:
            try:
                found = self._target_errors(T_goal, look_distance)
            except (ArithmeticError, ValueError, np.linalg.LinAlgError):
                # a command no solver can digest (finite but absurd): brake where the arm is
                T_goal = self._T_cam
                found = self._target_errors(T_goal, look_distance)
            q_cmd, T_target, approach, pos_err, ang_err = found
            self._last_key, self._last_look = key, look_distance
            if last is not None and self.via_port and _wrist_jump(self.kind, last[0], q_cmd):
                self._via_port = True  # the target jumped across a reachability gap
            self._last_target = found
        reachable = approach is ActuatorStatus.EXACT or (
            self.kind is ArmKind.ECM and approach is ActuatorStatus.VIEW
        )
        if self.camera_path and approach is not ActuatorStatus.NEAREST:
            q_cmd = self._on_path(q_cmd, T_target, look_distance)
        if self.workspace is not None:
            arm = self._arm  # (its arrays are replaced, never written, as it moves)
            q_before, qd_before = arm._q, arm._qd
        if self._stalled is not None:
            q_cmd = list(q_cmd)
            q_cmd[self._stalled] = float(self._q[self._stalled])
        self._arm.servo_jp(q_cmd)
        self._arm.step()
        T_checked = self._keep_inside(q_before, qd_before) if self.workspace is not None else None
        self._q = self._arm.measured_jp()
        self._T_cam = T_checked if T_checked is not None else self._camera_pose(self._q.tolist())
        self._q.setflags(write=False)  # handed out below without a copy
        self._T_cam.setflags(write=False)
        return ActuatorStep(
            self._T_cam,
            self._q,
            T_target,
            approach,
            pos_err,
            ang_err,
            reachable,
        )

    def _stop_point(self) -> tuple[list[float], bool, FloatArray]:
        """Where the joints come to rest braked at their limits, whether that is safe, and FK.

        Safe: the camera now, and at every step of braking to that point, is inside the
        workspace (:meth:`_brakes_inside`). The braking path is not checked while the camera is
        farther inside than the braking can carry it (:data:`ARM_LEVER_SLACK_M`).

        Returns
        -------
        stop : list of float
            Joint positions, rad / m.
        safe : bool
        T_world_cam : (4, 4) ndarray
            The camera now, m.
        """
        ws = self.workspace
        assert ws is not None
        q, qd = self._arm._q, self._arm._qd  # (replaced, never written, as the arm moves)
        if ws is not self._cone_of[0]:  # the cone and floor of a Workspace, for the kernel
            self._cone_of = (ws, _cone_consts(ws))
        cone = self._cone_of[1]
        T_now = np.empty((4, 4))
        moving, slide, turn, to_rcm, m_cone = _stop_kernel(
            self.model.chain._param_array, self._pose_consts, self._stop_consts, q, qd, cone,
            self._stop_row, T_now,
        )  # fmt: skip
        stop = self._stop_row.tolist()
        p = T_now[:3, 3].tolist()
        if cone is None:
            margin = ws.margin(p)
        else:  # Workspace.margin: the cone and the floor (compiled), then the keep-out zone
            keep_out = ws.keep_out  # type: ignore[attr-defined]
            margin = m_cone if keep_out is None else min(m_cone, keep_out.margin(p))
        safe = margin >= 0.0
        if safe and moving:
            lever = to_rcm + slide + ARM_LEVER_SLACK_M
            if not margin > slide + lever * turn:  # the braking could reach the boundary
                safe = self._brakes_inside(q.tolist(), qd.tolist(), stop)
        return stop, safe, T_now

    def _brakes_inside(self, q: list[float], qd: list[float], stop: list[float]) -> bool:
        """Whether the camera stays inside at every control step of the braking path.

        The path is the arm's joint motion from ``q`` (rad / m) moving at ``qd`` to rest at
        ``stop``, as its ruckig (synchronised joints) drives it: it can leave the straight line
        between the two, so each step's FK is checked, not only the stopping point's.
        """
        ws = self.workspace
        assert ws is not None
        inp = self._brake_inp
        inp.current_position = q
        inp.current_velocity = qd
        inp.target_position = stop  # (current_acceleration: 0, set once)
        if self._brake_otg.calculate(inp, self._brake_traj) not in (
            ruckig.Result.Working,
            ruckig.Result.Finished,
        ):
            return False
        traj, dt = self._brake_traj, self._dt
        duration = traj.duration
        steps = math.ceil(duration / dt - 1e-9)
        n = len(stop)
        # every control step of the path, then where it stops; the same floats either way
        if steps > PROFILE_READ_STEPS * len(q):  # read the profiles once, sample compiled
            rows, stop_row = profile_rows(traj), np.array(stop)
            q_rows = np.empty((steps + 1, n))
        else:  # a short path: fewer calls of ruckig's own sampler than reading the profiles
            at_time = traj.at_time
            flat: list[float] = []
            for i in range(1, steps + 1):
                t = i * dt
                flat += at_time(duration if duration < t else t)[0]  # min(t, duration)
            flat += stop
            q_rows = float_rows(flat, n)
            rows, stop_row = _NO_ROWS, q_rows[steps]
        points = np.empty((steps + 1, 3))
        compiled = type(ws) is Workspace  # its query in the same call; any other: its own
        state = ws.kernel_state if isinstance(ws, Workspace) and compiled else NO_WORKSPACE
        inside = _braking_inside_kernel(
            state, compiled, self.model.chain._param_array, rows, duration, dt, stop_row,
            self._world_rcm12, self._last_cam_point, q_rows, points,
        )  # fmt: skip
        return bool(inside) if compiled else ws.all_inside(points)

    def _keep_inside(self, q_before: FloatArray, qd_before: FloatArray) -> FloatArray | None:
        """Undo a joint step that could take the camera out; brake along a checked one.

        Returns the camera pose after the step (4, 4), m, or ``None`` when it braked.
        """
        stop, safe, T_now = self._stop_point()
        if self._safe and not safe:
            self._arm.reset(q_before, qd_before)
            self._arm.servo_jp(self._stop)  # the stopping point checked the step before
            self._arm.step()
            self.braked += 1
            return None  # on the braking path of a safe state, towards the same stopping point
        self._safe, self._stop = safe, stop
        return T_now


# count per joint: a braking path longer than this many control steps per joint is sampled
# from its profiles (robot.braking: reading them costs about as much as 3.5 at_time calls per
# joint, measured on the PSM's paths), a shorter one by ruckig's at_time at each step
PROFILE_READ_STEPS = 3.5

BRAKE_ACC_SHARE = 0.99  # unitless: share of a joint's acceleration limit its braking plans for

# m: added to the camera's distance from the RCM to bound every revolute joint's lever arm on
# the camera (the wrist, the jaw and the camera mount beyond the shaft are shorter than this)
ARM_LEVER_SLACK_M = 0.05


_POSE_T0, _POSE_TIP, _POSE_RCM = 0, 12, 24  # _pose_consts: T_world_rcm, T_last_cam, RCM


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _pose_kernel(params: FloatArray, c: FloatArray, q: FloatArray) -> FloatArray:
    """The camera pose (4, 4), world, m, for joints ``q`` (n,), rad / m.

    ``params``: the chain's (n, 7) parameter array; ``c``: ``CameraArm._pose_consts``. The
    floats of ``pose12_to_matrix(compose_links(chain, q, T0=T_world_rcm), T_last_cam rows)``:
    the same link product, then :func:`~endocam.robot.dh.pose12_times`'s products.
    """
    T0 = (c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8], c[9], c[10], c[11])
    t = _POSE_TIP
    rows = (
        (c[t], c[t + 1], c[t + 2], c[t + 3]),
        (c[t + 4], c[t + 5], c[t + 6], c[t + 7]),
        (c[t + 8], c[t + 9], c[t + 10], c[t + 11]),
    )
    P = _pose12_times_kernel(_compose_kernel(params, q, 0, params.shape[0], T0), rows)
    out = np.empty((4, 4))
    for i in range(3):
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = P[3 * i], P[3 * i + 1], P[3 * i + 2], P[9 + i]
    out[3, 0], out[3, 1], out[3, 2], out[3, 3] = 0.0, 0.0, 0.0, 1.0
    return out


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _stop_kernel(
    params: FloatArray,
    c: FloatArray,
    joints: FloatArray,
    q: FloatArray,
    qd: FloatArray,
    cone: FloatArray | None,
    stop: FloatArray,
    T_now: FloatArray,
) -> tuple[bool, float, float, float, float]:
    """:meth:`CameraArm._stop_point`'s floats for joints ``q`` moving at ``qd`` (n,).

    ``joints`` (4, n): ``v²/2a`` factors (s²/rad or s²/m), prismatic flags (1.0), lower and
    upper limits. Writes the stopping point into ``stop`` (n,) (each joint braked:
    ``q + qd·|qd|·k``, clipped into the limits as ``RcmArm.clamp_floats``) and the camera pose
    now into ``T_now`` (4, 4), m (:func:`_pose_kernel`): arrays from the caller, none to box.
    Returns whether any joint moves (a NaN velocity counts), the braking's total slide (m)
    and turn (rad), the camera's distance to the RCM (CPython's ``math.dist``), m, and its
    margin to the cone and the floor (``Workspace.margin`` without the keep-out zone, m;
    ``cone``: :func:`_cone_consts`; NaN without).
    """
    n = q.shape[0]
    moving = False
    slide = 0.0
    turn = 0.0
    for i in range(n):
        v = qd[i]
        d = v * abs(v) * joints[0, i]
        x = q[i] + d
        lo, hi = joints[2, i], joints[3, i]
        stop[i] = lo if x < lo else (hi if x > hi else x)
        moving = moving or v != 0.0
        if joints[1, i] != 0.0:
            slide += abs(d)
        else:
            turn += abs(d)
    T_now[:, :] = _pose_kernel(params, c, q)
    r = _POSE_RCM
    x, y, z = T_now[0, 3], T_now[1, 3], T_now[2, 3]
    to_rcm = dist3(x, y, z, c[r], c[r + 1], c[r + 2])
    margin = math.nan
    if cone is not None:  # Python's min(cone.margin(p), p[2] - floor)
        margin = cone_floor_margin(x, y, z, cone, cone[9])
    return moving, slide, turn, to_rcm, margin


def _cone_consts(ws: WorkspaceBound) -> FloatArray | None:
    """A ``workspace.region.Workspace``'s cone (``ConeWorkspace.constants``) and floor (10,), m.

    ``None`` for any other workspace (its own ``margin`` is asked).
    """
    if type(ws) is not Workspace:
        return None
    consts = np.array([*ws.cone.constants, ws.floor], dtype=float)
    consts.setflags(write=False)
    return consts


_NO_ROWS = np.empty((0, ROW_LENGTH))  # _braking_inside_kernel's rows of a path read by at_time


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _braking_inside_kernel(
    ws: WorkspaceState,
    check: bool,
    params: FloatArray,
    rows: FloatArray,
    duration: float,
    dt: float,
    stop: FloatArray,
    T0: Pose12,
    point: tuple[float, float, float],
    q_rows: FloatArray,
    points: FloatArray,
) -> bool:
    """The camera's positions along a braking path, and whether the workspace holds them all.

    The workspace ``state`` first (``workspace.region.Workspace.kernel_state``; with ``check``
    False it is not asked, and the answer is True). The joints ``q_rows`` (steps + 1, n),
    rad / m: given (ruckig's ``at_time`` at every control step, then ``stop``), or, when
    ``rows`` (n, 49) has rows, written here: the ruckig trajectory ``rows`` of duration
    ``duration`` (s, control period ``dt``) sampled at every control step
    (:func:`~endocam.robot.braking.path_positions`), then ``stop`` (n,). Writes the camera's
    positions into ``points`` (steps + 1, 3), world, m (:func:`~endocam.robot.dh.chain_points`'s
    product; ``T0``: the RCM in world, ``point``: the camera in the last link's frame, m), and
    returns ``Workspace.all_inside(points)`` (``workspace.region.workspace_all_inside``).
    """
    steps = q_rows.shape[0] - 1
    if rows.shape[0] > 0:
        q_rows[:steps] = path_positions(rows, duration, dt, steps)
        q_rows[steps] = stop
    points[:, :] = _points_kernel(params, q_rows, T0, point[0], point[1], point[2])
    if not check:
        return True
    return workspace_all_inside(ws, points)


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _path_engage_kernel(
    T_cam: FloatArray, T_target: FloatArray, look_distance: float
) -> tuple[bool, float, float, float, float, float, float, float, float]:
    """Whether :meth:`CameraArm._path_target` takes the camera-space path, and its start.

    ``T_cam``, ``T_target`` (4, 4): the camera and its target, world, m; ``look_distance``:
    m. Returns ``(engage, r_cur, alpha, u, c)``: the camera's distance to the target's look-at
    point ``c`` (m, world), the share ``alpha`` of the path to the next pose, and the unit
    direction ``u`` from ``c`` to the camera (each 3 floats); only ``engage`` when False.
    The interpreter's floats (libm's ``acos``, CPython's ``hypot``: :func:`hypot2`).
    """
    z0, z1, z2 = T_target[0, 2], T_target[1, 2], T_target[2, 2]
    c0 = T_target[0, 3] + look_distance * z0
    c1 = T_target[1, 3] + look_distance * z1
    c2 = T_target[2, 3] + look_distance * z2
    v0, v1, v2 = T_cam[0, 3] - c0, T_cam[1, 3] - c1, T_cam[2, 3] - c2
    r_cur = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    if not r_cur > _EPS_AXIS:
        return False, r_cur, 0.0, 0.0, 0.0, 0.0, c0, c1, c2
    u0, u1, u2 = v0 / r_cur, v1 / r_cur, v2 / r_cur
    cos_aim = -(u0 * T_cam[0, 2] + u1 * T_cam[1, 2] + u2 * T_cam[2, 2])
    aim = math.acos(_unit_clip(cos_aim))
    cos_t = -(u0 * z0 + u1 * z1 + u2 * z2)
    ang = math.acos(_unit_clip(cos_t))  # coarse: only compared with the thresholds
    travel = math.hypot(look_distance - r_cur, 0.5 * (r_cur + look_distance) * ang)
    if travel <= PATH_ENGAGE_M and aim <= PATH_ENGAGE_AIM_RAD:
        return False, r_cur, 0.0, u0, u1, u2, c0, c1, c2
    alpha = 1.0
    if travel > 0.0:
        lead = PATH_LEAD_M / travel
        alpha = lead if lead < 1.0 else 1.0  # Python's min(1.0, lead)
    if alpha >= 1.0 and aim <= PATH_ENGAGE_AIM_RAD:
        return False, r_cur, alpha, u0, u1, u2, c0, c1, c2
    return True, r_cur, alpha, u0, u1, u2, c0, c1, c2


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _unit_clip(x: float) -> float:
    """Python's ``max(-1.0, min(1.0, x))`` (a NaN gives 1.0, as there)."""
    return max(-1.0, min(1.0, x))


@njit(cache=True)  # compiled once, then loaded from the cache
def _target_error_kernel(T_target: FloatArray, T_goal: FloatArray) -> tuple[float, float]:
    """How far a target pose is from the goal (both (4, 4), world): m, and rad.

    numpy's ``np.linalg.norm`` of the positions' difference (its dot: :mod:`endocam.blasfloat`)
    and :func:`~endocam.kernels.rotation_angle` of their rotations (``two``: 2.0, passed at run
    time: a constant exponent would be folded into a product).
    """
    d0 = T_target[0, 3] - T_goal[0, 3]
    d1 = T_target[1, 3] - T_goal[1, 3]
    d2 = T_target[2, 3] - T_goal[2, 3]
    pos_err = math.sqrt(dot3(d0, d1, d2, d0, d1, d2))
    return pos_err, rotation_angle(_rotation_rows(T_target), _rotation_rows(T_goal))


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _rotation_rows(T: FloatArray) -> tuple[tuple[float, float, float], ...]:
    """The rotation rows of a pose (4, 4) as three 3-tuples of floats."""
    return (
        (T[0, 0], T[0, 1], T[0, 2]),
        (T[1, 0], T[1, 1], T[1, 2]),
        (T[2, 0], T[2, 1], T[2, 2]),
    )


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _is_camera_command(T: FloatArray, p_rcm: FloatArray, reach: float) -> bool:
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


WRIST_JUMP_RAD = 1.0  # rad: a wrist joint target moving this far in one step has jumped


def _wrist_jump(kind: ArmKind, q_before: list[float], q_after: list[float]) -> bool:
    """Whether a PSM's wrist (roll, pitch, yaw) target moved more than ``WRIST_JUMP_RAD``."""
    if kind is not ArmKind.PSM:
        return False
    _, _, _, a3, a4, a5 = q_before  # the PSM's six joints
    _, _, _, b3, b4, b5 = q_after
    jump = abs(a3 - b3)  # Python's max of the three, in its order (a NaN first stays)
    d = abs(a4 - b4)
    if d > jump:
        jump = d
    d = abs(a5 - b5)
    if d > jump:
        jump = d
    return jump > WRIST_JUMP_RAD


# m: the start view keeps the camera at least this far beyond the port (the RCM, in the body
# wall). A scope's view starts where its tip leaves the cannula, whose tip reaches a few cm
# beyond the remote centre (assumed: 3 cm); the arm's own shortest reach may be longer (the
# PSM-held camera with its wrist straight: 0.061 m), and then that is the bound.
ARM_START_GAP = 0.03
START_ROLL_TOL_RAD = 1e-3  # rad: the start view's roll is iterated until the arm's agrees this well
_START_ROLL_ITERATIONS = 6  # count: the default ECM levels its view in 1 framing (roll 0.094 rad)


def arm_start_view(
    arm: CameraArm, task_cfg: TaskConfig, camera: StereoCamera
) -> tuple[FloatArray, float]:
    """The whole-task view a camera on an arm starts from, and the distance it looks at.

    The free camera starts at the overview pose. A camera on an arm starts where a surgeon
    would aim a scope just inserted: looking along a line through the port (the RCM), as near
    to the task as still frames all of it (:func:`~endocam.task.layout.port_view`: the wire,
    its post bases and PSM2's tip in both eyes with ``VIEW_MARGIN`` spare), the camera at least
    ``ARM_START_GAP`` beyond the port and no nearer than the arm reaches with its wrist
    straight. The horizon is level where the arm can level it; a carrier whose roll is at a
    limit there (the 4-DoF ECM) is framed with the roll it takes, found by iterating.

    Parameters
    ----------
    arm : CameraArm
    task_cfg : TaskConfig
    camera : StereoCamera

    Returns
    -------
    T_world_cam : (4, 4) ndarray
        The start view, world, optical frame, m.
    look_distance : float
        m.

    Raises
    ------
    FramingError
        When no view from the port frames the task, or the arm cannot take the view, or the
        view lies outside the arm's workspace (one line naming the problem).
    """
    gap = max(ARM_START_GAP, arm.shortest_reach)
    port = arm.p_world_rcm
    roll = 0.0
    for _ in range(_START_ROLL_ITERATIONS):
        T, look = port_view(task_cfg, camera, vec(port), gap, roll=roll)
        _, T_reached, status = arm.target(T, look)
        reached_roll = _roll_from_level(T_reached)
        if status is ActuatorStatus.NEAREST:
            raise FramingError(
                f"start view: the {arm.kind.value} cannot take the view of the whole task "
                f"from its port {_norm(T[:3, 3] - port):.3f} m ahead"
            )
        if abs(_wrap(reached_roll - roll)) <= START_ROLL_TOL_RAD:
            break
        roll = reached_roll
    else:
        raise FramingError(f"start view: the {arm.kind.value}'s roll did not settle")
    if arm.workspace is not None and arm.workspace.margin(T[:3, 3].tolist()) < 0.0:
        raise FramingError("start view: the view of the whole task is outside the workspace")
    return T, look


def _roll_from_level(T: FloatArray) -> float:
    """Image roll of a camera pose (4, 4) about its optical axis from the level horizon, rad."""
    x_level = rotation_looking_along(T[:3, 2], UP, None)[:, 0]
    x = T[:3, 0]
    return math.atan2(float(np.cross(x_level, x) @ T[:3, 2]), float(x_level @ x))


def _wrap(angle: float) -> float:
    """An angle in (−π, π], rad."""
    return math.atan2(math.sin(angle), math.cos(angle))
