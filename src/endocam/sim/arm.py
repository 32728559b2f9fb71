"""The camera carried by a dVRK arm: camera goals → IK → ruckig joint motion → FK camera pose.

:class:`CameraArm` is the episode runner's actuator when ``episode.arm`` is ``psm`` or ``ecm``
(see ``docs/robot.md``, "The camera arm in the episode runner"). Each control step:

1. **Goal projection.** The policy's camera command (world) is expressed in the arm's RCM
   frame and solved by IK (:meth:`~endocam.robot.kinematics.RcmArm.solve_camera`, seeded by
   the measured joints). A goal the arm cannot reach is replaced by the camera pose of the
   nearest feasible configuration: the arm *approaches the nearest feasible pose*, and the
   step is flagged ``reachable = False``.
2. **Cartesian limits.** The (now feasible) goal goes through the camera's
   :class:`~endocam.sim.motion.CartesianLimiter` (speed, acceleration, jerk).
   Because the limiter only ever heads for feasible poses, it cannot drift into the region the
   arm cannot reach and drag the arm's set points away from its actual pose.
3. **Joint motion.** The limiter's pose is solved by IK again (seeded by the measured joints;
   skipped when the limiter is at rest on the goal, whose IK step 1 already solved);
   :class:`~endocam.robot.arm.SimulatedArm` moves the joints towards it for one control period
   under ruckig's joint velocity and acceleration limits, never beyond the joint limits.
4. **FK.** The camera pose is ``T_world_rcm · FK(q) · T_tip_cam`` of the new joints: every
   pose the runner logs is one the arm reaches.

The dVRK frames: IK and FK work in the RCM frame (the dVRK's ``local/measured_cp``);
``T_world_rcm`` places the RCM (the port) in the scene, ``T_tip_cam`` mounts the camera on the
tool tip (identity for the ECM, whose tip frame is its optical frame).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

from endocam.config import MotionLimits
from endocam.geometry import FloatArray, as_pose, invert_pose
from endocam.robot import ECM, PSM, IKResult, IKStatus, RcmArm, SimulatedArm
from endocam.robot.dh import compose_links, pose12_from_matrix, pose12_to_matrix
from endocam.sim.motion import CartesianLimiter, MotionStatus

__all__ = [
    "REACH_POSITION_TOL_M",
    "REALTIME_NEAREST_MAX_NFEV",
    "ArmKind",
    "ArmStep",
    "CameraArm",
    "arm_model",
    "natural_pose",
]

REACH_POSITION_TOL_M = 1e-6  # m: an ECM goal position closer than this counts as reached
# count: residual evaluations per nearest-feasible solve in the control loop (≈ 1-3 ms); the
# default 200 costs up to ~50 ms, and a goal sliding along the reach boundary moves little
# between control steps, so a short warm-started solve tracks it.
REALTIME_NEAREST_MAX_NFEV = 10


class ArmKind(enum.Enum):
    """What carries the camera."""

    FREE = "free"
    """No arm: the camera moves under Cartesian limits only."""
    PSM = "psm"
    """A pickup camera held by a dVRK PSM (6 DoF)."""
    ECM = "ecm"
    """The dVRK's 4-DoF endoscope arm (straight 0° scope)."""


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


@dataclass(frozen=True)
class ArmStep:
    """Outcome of one control step of a :class:`CameraArm`.

    Attributes
    ----------
    T_world_cam : (4, 4) ndarray
        Camera pose after the step, ``FK(q)`` in world, optical frame, m.
    q : (n,) ndarray
        Measured joint positions after the step, rad / m.
    goal : IKResult
        IK of the commanded goal (residuals in m / rad, tip frame in the RCM frame).
    reachable : bool
        Whether the arm can reach the commanded goal: PSM — IK status ``OK``; ECM — the goal
        position is reached (the orientation the 4-DoF ECM cannot deliver is its expected
        residual, measured by the orientation error, not an unreachable goal).
    """

    T_world_cam: FloatArray
    q: FloatArray
    goal: IKResult
    reachable: bool


class CameraArm:
    """A camera on a dVRK arm (PSM or ECM), driven like the free camera's limiter.

    Parameters
    ----------
    kind : ArmKind
        ``PSM`` or ``ECM``.
    T_world_rcm : (4, 4) array_like
        Pose of the arm's RCM frame in world, m.
    T_tip_cam : (4, 4) array_like
        Camera optical frame in the tool-tip frame, m (identity for the ECM's 0° scope).
    limits : MotionLimits
        The camera's Cartesian limits (applied before IK).
    dt : float
        Control period, s.
    """

    def __init__(
        self,
        kind: ArmKind,
        T_world_rcm: object,
        T_tip_cam: object,
        limits: MotionLimits,
        dt: float,
    ) -> None:
        self.kind = kind
        self.model = arm_model(kind)
        self._T_world_rcm = as_pose(np.asarray(T_world_rcm, dtype=float), "T_world_rcm")
        self._T_rcm_world = invert_pose(self._T_world_rcm)
        self._T_tip_cam = as_pose(np.asarray(T_tip_cam, dtype=float), "T_tip_cam")
        self._T_cam_tip = invert_pose(self._T_tip_cam)
        # float forms for the control loop: FK starts at the RCM in world and ends at the camera
        self._world_rcm12 = pose12_from_matrix(self._T_world_rcm)
        T_last_cam = self.model.chain.T_last_tip @ self._T_tip_cam
        self._last_cam_rows = tuple(tuple(row) for row in T_last_cam[:3].tolist())
        self._arm = SimulatedArm(self.model, dt=dt, q0=natural_pose(self.model))
        self._limiter = CartesianLimiter(limits, dt)
        self._q = self._arm.measured_js()[0]
        self._limiter.reset(self.camera_pose(self._q))  # at rest at the mid-range pose

    # ------------------------------------------------------------------ frames
    @property
    def joint_names(self) -> tuple[str, ...]:
        """Joint names from the base outwards."""
        return self.model.joint_names

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

    def _camera_pose(self, q: list[float]) -> FloatArray:
        """``T_world_rcm · FK(q) · T_tip_cam`` on plain floats (unchecked ``q``)."""
        T = compose_links(self.model.chain, q, T0=self._world_rcm12)
        return pose12_to_matrix(T, self._last_cam_rows)

    def camera_poses(self, q: FloatArray) -> FloatArray:
        """:meth:`camera_pose` for joint rows ``q`` (N, n): ``T_world_cam`` (N, 4, 4), m."""
        return np.array([self.camera_pose(row) for row in np.asarray(q, dtype=float)])

    def link_frames(self, q: object) -> FloatArray:
        """World poses of the DH link frames and the tip for joints ``q``: (n + 1, 4, 4), m."""
        return self._T_world_rcm @ self.model.frames(q)

    # ------------------------------------------------------------------ control
    def _solve(self, T_world_cam: FloatArray) -> IKResult:
        T_rcm_tip = self._T_rcm_world @ T_world_cam @ self._T_cam_tip
        return self.model.solve_unchecked(T_rcm_tip, self._q)

    def _reachable(self, result: IKResult) -> bool:
        if self.kind is ArmKind.ECM:
            return result.position_error <= REACH_POSITION_TOL_M
        return result.status is IKStatus.OK

    def reset(self, T_world_cam: object) -> FloatArray:
        """Place the arm, at rest, at the configuration nearest to a camera pose.

        IK is seeded by :func:`natural_pose`; an unreachable pose gives the nearest feasible
        configuration.

        Parameters
        ----------
        T_world_cam : (4, 4) array_like
            Wanted initial camera pose, world, optical frame, m.

        Returns
        -------
        T_world_cam : (4, 4) ndarray
            The initial camera pose actually taken, ``FK(q0)``, m.
        """
        T = as_pose(np.asarray(T_world_cam, dtype=float), "T_world_cam")
        self._q = natural_pose(self.model)
        q0 = self._solve(T).q
        self._arm.reset(q0)
        self._q = self._arm.measured_js()[0]
        T_cam = self.camera_pose(self._q)
        self._limiter.reset(T_cam)
        return T_cam

    def step(self, T_world_cmd: FloatArray) -> ArmStep:
        """One control step towards a commanded camera pose (see the module docstring).

        Parameters
        ----------
        T_world_cmd : (4, 4) ndarray
            Commanded camera pose, world, optical frame, m. A non-finite command is replaced
            by the camera's current pose: the arm brakes to a stop where it is.

        Returns
        -------
        ArmStep
        """
        finite = all(map(math.isfinite, np.ravel(T_world_cmd).tolist()))
        T_goal = T_world_cmd if finite else self._limiter.pose
        goal = self._solve(T_goal)
        reachable = self._reachable(goal)
        if not goal.ok:  # head for the nearest feasible pose instead
            T_goal = self._T_world_rcm @ goal.T_rcm_tip @ self._T_tip_cam
        T_limited = self._limiter.step(T_goal)
        if self._limiter.status is MotionStatus.ARRIVED:
            # the limiter is at rest exactly on the (feasible) goal, whose IK is known
            q_cmd = goal.q
        else:
            q_cmd = self._solve(T_limited).q
        self._arm.servo_jp(q_cmd)
        self._arm.step()
        self._q = self._arm.measured_js()[0]
        return ArmStep(self._camera_pose(self._q.tolist()), self._q.copy(), goal, reachable)
