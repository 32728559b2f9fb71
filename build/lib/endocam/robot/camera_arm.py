"""The camera carried by a dVRK arm: camera goals → IK → ruckig joint motion → FK camera pose.

:class:`CameraArm` is the episode runner's actuator when ``episode.arm`` is ``psm`` or ``ecm``
(see ``docs/robot.md``, "The camera arm in the episode runner"). Each control step:

1. **IK.** The policy's camera command (world) is expressed in the arm's RCM frame and solved
   in closed form, seeded by the measured joints (one IK per step).
2. **Nearest feasible view.** A goal the arm cannot reach exactly is replaced by the reachable
   view nearest to it that still looks at the same point: the camera is turned about the
   point it looks at (``look_distance`` ahead on its optical axis, the policy's working
   distance) towards the view straight from the port, by the smallest angle the arm can
   deliver (:func:`~endocam.robot.arm_targets.view_towards_port`; a search over that angle,
   warm-started from the last step). The feature stays centred at the working distance;
   only the view direction is conceded, and the step is flagged ``reachable = False`` with the
   conceded angle. For the ECM, whose optical axis always passes through its RCM, that view is
   the port view itself.
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

The compiled targets live in :mod:`endocam.robot.arm_targets`, the workspace's braking guard in
:mod:`endocam.robot.arm_guard`; this module holds the decisions between them.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from endocam.camera import StereoCamera
from endocam.geometry import FloatArray, as_pose, invert_pose
from endocam.robot.actuator import (
    ActuatorStatus,
    ActuatorStep,
    ArmKind,
    GuardAction,
    WorkspaceBound,
)
from endocam.robot.arm import (
    ECM_MAX_ACCELERATION,
    ECM_MAX_VELOCITY,
    PSM_MAX_ACCELERATION,
    PSM_MAX_VELOCITY,
    SimulatedArm,
)
from endocam.robot.arm_guard import (
    BRAKE_ACC_SHARE,
    SLIDE_PUSHES_M,
    BrakingGuard,
    GuardConsts,
    arm_camera_pose,
)
from endocam.robot.arm_targets import (
    ECM_EXACT,
    ECM_NEAREST,
    ECM_PORT_SCIPY,
    ECM_VIEW,
    MAX_COMMAND_RANGE_M,
    VIEW_POSITION_TOL_M,
    ArmIK,
    EcmIK,
    PsmIK,
    TargetError,
    ecm_target,
    exact_joints,
    is_camera_command,
    path_joints,
    port_rotvec,
    target_error,
    view_search,
    view_towards_port,
    wrist_jump,
)
from endocam.robot.ecm import ECM
from endocam.robot.kinematics import RcmArm
from endocam.robot.psm import PSM
from endocam.robot.start_view import ARM_START_GAP, arm_start_view
from endocam.task.config import TaskConfig

__all__ = [
    "ARM_START_GAP",
    "REALTIME_NEAREST_MAX_NFEV",
    "CameraArm",
    "TargetAnswer",
    "arm_model",
    "arm_start_view",
    "natural_pose",
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


class TargetAnswer(NamedTuple):
    """A camera goal's joint target (:meth:`CameraArm.target`) and how far it is from the goal.

    Attributes
    ----------
    q : list of float
        Joint target within the limits, rad / m.
    T : (4, 4) ndarray
        The camera pose of ``q``'s goal: the goal, or the view put in its place, world, m.
    status : ActuatorStatus
    error : TargetError
        How far ``T`` is from the goal: m, rad (zero when exact).
    """

    q: list[float]
    T: FloatArray
    status: ActuatorStatus
    error: TargetError


_NO_ERROR = TargetError(0.0, 0.0)


def _frozen(a: FloatArray) -> FloatArray:
    """``a`` made read-only (and returned).

    The joints, the camera and the targets the compiled kernels read are read-only arrays
    always: numba compiles a kernel once per argument type, and a writable array is another
    type than a read-only one.
    """
    a.setflags(write=False)
    return a


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
        self._T_tip_cam = as_pose(np.asarray(T_tip_cam, dtype=float), "T_tip_cam")
        self._T_cam_tip = invert_pose(self._T_tip_cam)
        self._is_psm = kind is ArmKind.PSM
        ik_kind = PsmIK if self._is_psm else EcmIK
        self.ik: ArmIK = ik_kind(
            self.model.chain.param_array,
            self.model.ik_constants,
            self._T_world_rcm,
            self._T_rcm_world,
            self._T_tip_cam,
            self._T_cam_tip,
        )
        amax = PSM_MAX_ACCELERATION if self._is_psm else ECM_MAX_ACCELERATION
        vmax = PSM_MAX_VELOCITY if self._is_psm else ECM_MAX_VELOCITY
        T_last_cam = self.model.chain.T_last_tip @ self._T_tip_cam
        # braking distance v²/2a, planned at BRAKE_ACC_SHARE of the limit: ruckig can then
        # always reach the stopping point (at the full limit round-off can make it infeasible)
        guard = GuardConsts(
            self.model.chain.param_array,
            self._T_world_rcm,
            T_last_cam,
            self._p_world_rcm,
            np.array([0.5 / (BRAKE_ACC_SHARE * a) for a in amax]),
            np.array(self.model.prismatic),
            self.model.lower.copy(),
            self.model.upper.copy(),
        )
        self.guard = BrakingGuard(guard, dt, vmax, amax)
        self._q_out = np.empty(self.model.n_joints)  # the IK kernels' output row
        self._arm = SimulatedArm(self.model, dt=dt, q0=natural_pose(self.model))
        q = self._arm.measured_js()[0]
        self._T_cam = _frozen(self.camera_pose(q))  # (a writable q, as in step)
        self._q = _frozen(q)
        self._k_prev: int | None = None  # the last conceded turn, VIEW_STEPS (warm start)
        self._last_key: bytes | None = None  # the last goal (bytes) and its look distance
        self._last_look = math.nan
        self._last_target: TargetAnswer | None = None  # the last goal's answer
        self._via_port = False  # on the path through the port view after a target jump
        self._stalled: int | None = None  # a stalled joint (fault injection)
        self._slide_dq: FloatArray | None = None  # the last slid step (rad / m), while sliding
        self.workspace = workspace

    @property
    def braked(self) -> int:
        """Steps on which the workspace made the arm brake."""
        return self.guard.braked

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
        return float(np.linalg.norm(self.camera_pose(q)[:3, 3] - self._p_world_rcm))

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
        return arm_camera_pose(self.guard.consts, self.model.check_q(q))

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

        One compiled call (:func:`~endocam.robot.arm_targets.exact_joints`), seeded by the
        measured joints.
        """
        if exact_joints(self.ik, T_world_cam, self._q, self._q_out):
            return self._q_out.tolist()
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
        found = self._target_errors(T_world_goal, look_distance)
        return found.q, found.T, found.status

    def _target_errors(self, T_world_goal: FloatArray, look_distance: float) -> TargetAnswer:
        """:meth:`target`, and how far its pose is from the goal: m, rad (0 when exact)."""
        if not self._is_psm:
            return self._ecm_target(T_world_goal, look_distance)
        q, T, status = self._psm_target(T_world_goal, look_distance)
        if status is ActuatorStatus.EXACT:
            return TargetAnswer(q, T, status, _NO_ERROR)
        return TargetAnswer(q, T, status, target_error(T, T_world_goal))

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
        turn = port_rotvec(T_world_goal, look_distance, self._p_world_rcm)
        if turn.found:
            view = self._view_search(T_world_goal, look_distance, turn.rotvec)
            if view is not None:
                return view[0], view[1], ActuatorStatus.VIEW
        return self._nearest(T_world_goal)

    def _nearest(self, T_world_goal: FloatArray) -> tuple[list[float], FloatArray, ActuatorStatus]:
        """The nearest configuration of a camera goal (4, 4), world, m, and its camera, m."""
        self._k_prev = None
        result = self.model.solve_unchecked(self._tip_goal(T_world_goal), self._q)
        T_near = _frozen(self._T_world_rcm @ result.T_rcm_tip @ self._T_tip_cam)
        return result.q.tolist(), T_near, ActuatorStatus.NEAREST

    def _ecm_target(self, T_world_goal: FloatArray, look_distance: float) -> TargetAnswer:
        """:meth:`_target_errors` on the ECM: one compiled call (:func:`ecm_target`).

        The 4-DoF scope's only view of the goal's look-at point is its port view; a roll
        beyond its limits is conceded too (the horizon tilts), as long as the view itself is
        reached. scipy's nearest in-limit position, when the IK needs it, is found here.
        """
        T = np.empty((4, 4))
        found = ecm_target(self.ik, self._p_world_rcm, T_world_goal, look_distance, self._q, T)
        q_new = list(found.q)
        if found.outcome == ECM_EXACT:
            self._k_prev = None
            T.setflags(write=False)
            return TargetAnswer(q_new, T, ActuatorStatus.EXACT, _NO_ERROR)
        if found.outcome == ECM_VIEW:
            return TargetAnswer(q_new, _frozen(T), ActuatorStatus.VIEW, found.error)
        if found.outcome == ECM_NEAREST:
            self._k_prev = None
            return TargetAnswer(q_new, T, ActuatorStatus.NEAREST, found.error)
        if found.outcome == ECM_PORT_SCIPY:  # T: the port view
            port = self.model.solve_unchecked(self._tip_goal(T), self._q)
            if port.position_error <= VIEW_POSITION_TOL_M:
                T_reached = self._T_world_rcm @ port.T_rcm_tip @ self._T_tip_cam
                error = target_error(T_reached, T_world_goal)
                return TargetAnswer(port.q.tolist(), _frozen(T_reached), ActuatorStatus.VIEW, error)
        q, T_near, status = self._nearest(T_world_goal)
        return TargetAnswer(q, T_near, status, target_error(T_near, T_world_goal))

    def _view_search(
        self, T_goal: FloatArray, look_distance: float, rotvec: tuple[float, float, float]
    ) -> tuple[list[float], FloatArray] | None:
        """The nearest reachable turn towards the port view (:func:`view_search`), warm-started.

        The turn found (in ``VIEW_STEPS``) is remembered for the next step's search; none
        found: the next search starts cold.
        """
        T = np.empty((4, 4))
        guess = 0 if self._k_prev is None else self._k_prev
        k = view_search(self.ik, T_goal, look_distance, rotvec, guess, self._q, self._q_out, T)
        self._k_prev = k if k > 0 else None
        return (self._q_out.tolist(), _frozen(T)) if k > 0 else None

    def _on_path(self, q_target: list[float], T_target: FloatArray, look: float) -> list[float]:
        """The joint set point of this step: towards ``q_target`` along a camera-space path.

        After a jump of the wrist's target (a side change, or the nearest feasible view crossing
        a reachability gap: the same view from another wrist configuration), the path leads
        through the port view of the look-at point, whose wrist is straight and which both
        configurations reach continuously; it continues to the target once the camera is there.
        """
        if self._via_port:
            T_port = _frozen(view_towards_port(T_target, look, self._p_world_rcm, 1.0))
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
        if path_joints(self.ik, self._T_cam, T_target, look_distance, self._q, self._q_out):
            return self._q_out.tolist()
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
        self._slide_dq = None
        if look_distance is None:
            look_distance = self._port_distance(T)
        self._q = _frozen(natural_pose(self.model))
        q0, _, _ = self.target(T, look_distance)
        self._arm.reset(q0)
        q = self._arm.measured_js()[0]
        self._T_cam = _frozen(self.camera_pose(q))  # (a writable q, as in step)
        self._q = _frozen(q)
        if self.workspace is not None:
            self.guard.reset(self._arm, self.workspace)
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
        if is_camera_command(T_world_cmd, self._p_world_rcm, MAX_COMMAND_RANGE_M):
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
            and (last.status is ActuatorStatus.EXACT or look_distance == self._last_look)
        ):
            found = last  # a held goal (the same bytes): the same answer (exact: at any distance)
        else:
            try:
                found = self._target_errors(T_goal, look_distance)
            except (ArithmeticError, ValueError, np.linalg.LinAlgError):
                # a command no solver can digest (finite but absurd): brake where the arm is
                T_goal = self._T_cam
                found = self._target_errors(T_goal, look_distance)
            self._last_key, self._last_look = key, look_distance
            if last is not None and self.via_port and wrist_jump(self.kind, last.q, found.q):
                self._via_port = True  # the target jumped across a reachability gap
            self._last_target = found
        q_cmd, T_target, approach = found.q, found.T, found.status
        reachable = approach is ActuatorStatus.EXACT or (
            self.kind is ArmKind.ECM and approach is ActuatorStatus.VIEW
        )
        q_line = q_cmd  # the straight joint-space line to the target
        if self.camera_path and approach is not ActuatorStatus.NEAREST:
            q_cmd = self._on_path(q_cmd, T_target, look_distance)
        before = self._arm.state_view()  # (replaced, never written, as the arm moves)
        self._move(q_cmd)
        T_checked = None
        action = GuardAction.FREE
        if self.workspace is not None:
            T_checked = self.guard.accept(self._arm, self.workspace)
            if T_checked is None:
                T_checked = self._admissible(self.workspace, before, q_cmd, q_line)
                action = GuardAction.BRAKED if T_checked is None else GuardAction.SLID
                if T_checked is None:
                    self.guard.brake(self._arm, before)
            else:
                self._slide_dq = None  # the motion towards the command is admissible again
        self._q = self._arm.measured_jp()
        self._T_cam = (
            T_checked if T_checked is not None else arm_camera_pose(self.guard.consts, self._q)
        )
        self._q.setflags(write=False)  # handed out below without a copy
        self._T_cam.setflags(write=False)
        return ActuatorStep(
            self._T_cam,
            self._q,
            T_target,
            approach,
            found.error.position,
            found.error.angle,
            reachable,
            action,
        )

    def _move(self, q_cmd: list[float] | FloatArray, line: bool = False) -> None:
        """One joint step towards the set point ``q_cmd`` (a stalled joint held where it is).

        ``line``: along the straight joint-space line (``SimulatedArm.servo_jp``).
        """
        if self._stalled is not None:
            q_cmd = list(q_cmd)
            q_cmd[self._stalled] = float(self._q[self._stalled])
        self._arm.servo_jp(q_cmd, line)
        self._arm.step()

    def _admissible(
        self,
        workspace: WorkspaceBound,
        before: tuple[FloatArray, FloatArray],
        q_cmd: list[float],
        q_line: list[float],
    ) -> FloatArray | None:
        """The admissible step nearest to a refused one: its camera pose (4, 4), m; else None.

        The guard refused the step towards ``q_cmd`` (rad / m): its stopping point could take
        the camera out. Tried in turn from the state ``before`` (joints, velocities), each
        checked by the guard like any step: the straight joint-space line to the target
        ``q_line`` (when ``q_cmd`` is a camera-path point), the last slid step again (the
        joint line it started: the motion goes on without a new profile), then the step
        towards ``q_cmd``
        and towards ``q_line`` slid along the workspace's boundary (:meth:`BrakingGuard.slide`),
        pushed inwards by each of ``SLIDE_PUSHES_M`` in turn, moved along the joint-space line
        the slide is computed for (phase-synchronised joints).
        ``None``: none is admissible; the arm is left at ``before``'s state after a step.
        """
        straight = q_line is not q_cmd

        def attempt(q_try: list[float] | FloatArray, line: bool = False) -> FloatArray | None:
            self._arm.reset(*before)
            self._move(q_try, line)
            return self.guard.accept(self._arm, workspace)

        if straight and (T := attempt(q_line)) is not None:
            return T
        q0 = before[0]
        if self._slide_dq is not None and (T := attempt(q0 + self._slide_dq, True)) is not None:
            return T  # on along the last slide's line (its motion continues: no new profile)
        for push in SLIDE_PUSHES_M:
            for q_to in (q_cmd, q_line) if straight else (q_cmd,):
                q_try = self.guard.slide(workspace, q0, np.asarray(q_to), push)
                if q_try is not None and (T := attempt(q_try, line=True)) is not None:
                    self._slide_dq = q_try - q0
                    return T
        self._slide_dq = None
        return None
