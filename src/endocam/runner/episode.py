"""The episode runner: a ring trajectory, a camera policy and the camera's motion, in fixed steps.

Time advances at the control rate. Each step the policy sees the ring pose as it was
``sensing_latency`` seconds ago, the measured camera pose and the instrument tips; its command
goes through the camera's actuator model (Cartesian speed/acceleration limits, and optionally a
dVRK arm's IK and joint limits), so the camera never teleports. Rendering is separate
(:mod:`endocam.runner.outputs`): the control loop runs headless and is deterministic, so the same
config and seed give identical logs.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numba import njit

from endocam.camera import StereoCamera
from endocam.config import ExperimentConfig
from endocam.control.types import Observation, PolicyContext, TrackingState
from endocam.faults import StepFaults, apply_observation_faults, fault_schedule
from endocam.geometry import FloatArray
from endocam.kernels import dot3
from endocam.metrics import (
    center_error_3d,
    image_centering_error,
    orientation_error,
    ring_out_of_view,
    saturate_image_error,
)
from endocam.registry import POLICIES, make_policy
from endocam.robot.actuator import ActuatorStatus, ActuatorStep, ArmKind
from endocam.robot.carriers import make_actuator
from endocam.task.config import MAX_CONTROL_POINTS
from endocam.task.instruments import instrument_tips
from endocam.task.layout import overview_camera_pose
from endocam.task.touches import TouchReport, touch_events
from endocam.task.trajectory import RingTrajectory, TrajectoryKind, capture_times, make_trajectory
from endocam.task.wire import Wire

UNREACHABLE = "unreachable"
"""Log state of a step whose goal the carrier concedes (``ActuatorStep.reachable`` is false)."""
LOG_STATES = (*(s.value for s in TrackingState), UNREACHABLE)
"""Every value of the log's ``state`` column: the controller's states, then the carrier's."""


DEFAULT_SEED = 1  # noise seed of `endocam run`, `demo` and a sweep that names none


@dataclass(frozen=True)
class EpisodeSpec:
    """Which episode to run.

    Attributes
    ----------
    policy : str
        A registered policy name (``endocam policies``).
    trajectory : TrajectoryKind
        ``ideal`` or ``noisy``.
    control_points : int
        Control points along the wire (≥ 2); the paper uses 36 and 71.
    seed : int
        Noise seed of a noisy trajectory (ignored by ``ideal``).
    """

    policy: str
    trajectory: TrajectoryKind
    control_points: int
    seed: int = 0

    def __post_init__(self) -> None:
        if not 2 <= self.control_points <= MAX_CONTROL_POINTS:
            raise ValueError(
                f"control_points must be in 2..{MAX_CONTROL_POINTS}, got {self.control_points}"
            )
        if self.seed < 0:
            raise ValueError(f"seed must be ≥ 0, got {self.seed}")


@dataclass(frozen=True)
class EpisodeLog:
    """Everything one episode produced, per control step (N steps), SI.

    Attributes
    ----------
    t : (N,)
        Time, s.
    T_world_ring : (N, 4, 4)
        True ring pose (ring z = face normal), m.
    T_world_ring_sensed : (N, 4, 4)
        Ring pose the policy saw (delayed by the sensing latency), m.
    T_world_cam : (N, 4, 4)
        Camera (optical frame) pose at the start of each step, m.
    T_world_cmd : (N, 4, 4)
        Camera pose the policy commanded, m.
    state : (N,)
        :class:`TrackingState` values (strings).
    reason : list of str
        The policy's one-line reason per step ("" while plainly tracking).
    d_f : (N,)
        Working distance in use, m.
    p_world_tips : (N, 2, 3)
        PSM1 and PSM2 tip positions, m.
    contact : (N,)
        Whether the ring touches the wire at ``t`` (from the ground-truth touch events).
    clearance : (N,)
        Ring–wire clearance at ``t``, m (negative = interpenetration).
    joints : (N, J) or None
        Joint positions of the camera arm at the start of each step, when the camera is
        carried by one (rad / m); ``T_world_cam[k] = FK(joints[k])``.
    joint_names : tuple of str
        Names of the ``joints`` columns (``()`` without an arm).
    arm : str
        What carried the camera: ``free``, ``psm`` or ``ecm``.
    goal_position_error : (N,) or None
        With an arm: distance from the commanded camera goal to the camera pose the joints
        head for (the nearest feasible view or pose), m; 0 when the goal is reached exactly.
    goal_orientation_error : (N,) or None
        With an arm: angle between the commanded orientation and that target's, rad: the
        view the arm concedes (for the ECM, what its missing DoF cannot deliver).
    fault : (N,) or None
        Injected faults active at each step (:mod:`endocam.faults`), ``+``-joined; ``None``
        (logged as empty) without faults.
    """

    t: FloatArray
    T_world_ring: FloatArray
    T_world_ring_sensed: FloatArray
    T_world_cam: FloatArray
    T_world_cmd: FloatArray
    state: np.ndarray
    reason: list[str]
    d_f: FloatArray
    p_world_tips: FloatArray
    contact: np.ndarray
    clearance: FloatArray
    joints: FloatArray | None = None
    joint_names: tuple[str, ...] = ()
    arm: str = ArmKind.FREE.value
    goal_position_error: FloatArray | None = None
    goal_orientation_error: FloatArray | None = None
    fault: np.ndarray | None = None


@dataclass(frozen=True)
class EpisodeResult:
    """An episode's inputs, log, ground truth and per-step tracking errors.

    The errors are measured against the *true* ring pose, in SI: ``image_error`` px (the only
    non-SI quantity, pixels having no SI unit), ``center_error`` m, ``orientation_error`` rad.
    ``image_error`` is raw (NaN behind the camera); summaries use
    :attr:`image_error_saturated`. Both centring errors are measured in the left eye, where the
    paper measures (Sec. V: "with respect to the left image space"): ``center_error`` is the
    distance of the ring centre from the left eye's optical axis; the distance from the axis
    through the eyes' midpoint is :attr:`center_error_mid`.
    """

    config: ExperimentConfig
    spec: EpisodeSpec
    camera: StereoCamera
    trajectory: RingTrajectory
    wire: Wire
    touches: TouchReport
    log: EpisodeLog
    T_world_overview: FloatArray
    image_error: FloatArray = field(repr=False)
    center_error: FloatArray = field(repr=False)
    orientation_error: FloatArray = field(repr=False)

    @cached_property
    def center_error_mid(self) -> FloatArray:
        """(N,) distance of the true ring centre from the axis through the eyes' midpoint, m."""
        return center_error_3d(self.log.T_world_cam, self.log.T_world_ring[:, :3, 3])

    @cached_property
    def ring_out_of_view(self) -> FloatArray:
        """(N,) bool: the true ring centre is outside the left eye's image."""
        return ring_out_of_view(self.camera, self.log.T_world_cam, self.log.T_world_ring[:, :3, 3])

    @cached_property
    def camera_wire_clearance(self) -> FloatArray:
        """(N,) distance from the camera's optical centre to the wire's surface, m (< 0: inside).

        Not bounded by any controller or check yet: looking along the ring normal puts the
        camera on the wire's continuation (README, "Safety under faults").
        """
        return self.wire.surface_distance(self.log.T_world_cam[:, :3, 3])

    @cached_property
    def image_error_saturated(self) -> FloatArray:
        """(N,) image errors, px, a ring out of view counted as the largest in-image error."""
        return saturate_image_error(self.camera, self.image_error, self.ring_out_of_view)


def contact_at(touches: TouchReport, t: FloatArray) -> np.ndarray:
    """(N,) bool: whether ``t`` (s) lies inside a ground-truth touch event."""
    inside = np.zeros(len(t), dtype=bool)
    for ev in touches.events:
        inside |= (t >= ev.t_start) & (t <= ev.t_end)
    return inside


def run_episode(
    config: ExperimentConfig,
    spec: EpisodeSpec,
    *,
    progress: Callable[[int], object] | None = None,
    touches: TouchReport | None = None,
) -> EpisodeResult:
    """Run one headless episode.

    With ``episode.arm`` ``psm`` or ``ecm`` (or a policy that forces an arm, see
    :func:`episode_arm`) the camera is carried by that dVRK arm (:class:`CameraArm`): it
    starts at the configuration nearest to the overview pose, every logged camera pose is
    ``FK(q)`` of the logged joints, and steps whose goal the arm cannot reach are logged as
    ``unreachable`` (unless the policy is already frozen or has lost tracking).

    Parameters
    ----------
    config : ExperimentConfig
    spec : EpisodeSpec
    progress : callable, optional
        Called with the number of control steps done since the last call (for a progress bar).
    touches : TouchReport, optional
        Precomputed ground truth for this trajectory (it does not depend on the policy).

    Returns
    -------
    EpisodeResult
    """
    policy = make_policy(spec.policy, config.controller)  # unknown names fail before any work
    camera = config.camera.stereo()
    wire = Wire(config.task.wire)
    trajectory = make_trajectory(
        config.task, spec.trajectory, spec.control_points, spec.seed, wire=wire
    )
    if touches is None:
        touches = touch_events(
            trajectory, wire, config.task.ring, config.task.trajectory.touch_sample_dt
        )
    ep = config.episode
    dt = 1.0 / ep.control_rate
    n = math.floor(trajectory.duration / dt + 1e-9) + 1
    t = np.arange(n, dtype=float) * dt
    T_ring = trajectory.poses(t)
    t_ring = capture_times(t, ep.sensing_latency)  # when each sensed pose was captured, s
    T_sensed = trajectory.poses(t_ring)
    tips = instrument_tips(config.task, t, T_ring)

    T_overview = overview_camera_pose(config.task, camera)
    p_rcm = np.array(config.task.scene.rcm_position)
    kind = episode_arm(config, spec.policy)
    # the policy's cone and floor, and the wire's clearance zone (the carriers keep out of it)
    workspace = config.controller.workspace(p_rcm, T_sensed[0][:3, 3], wire)
    actuator = make_actuator(
        kind, ep.limits, ep.T_tip_cam, config.task.scene.T_world_rcm, dt, workspace
    )
    T_now = actuator.reset(*actuator.start_view(config.task, camera))
    schedule = None
    step_faults: StepFaults | None = None
    if config.faults.any:  # faults: the observations rewritten here, a hook in the loop
        schedule = fault_schedule(
            config.faults, n, dt, arm=kind is not ArmKind.FREE, joints=len(actuator.joint_names)
        )
        T_sensed, tips, t_ring = apply_observation_faults(
            schedule, t, T_sensed, tips, trajectory.poses, ep.sensing_latency
        )
        step_faults = StepFaults(schedule, actuator.stall) if schedule.steps_faulty else None
    policy.reset(
        PolicyContext(
            camera,
            T_now,
            T_sensed[0],
            p_rcm,
            dt,
            ep.sensing_latency,
            future=trajectory.poses,  # the true trajectory: only non-causal policies read it
            future_duration=float(trajectory.duration),
            follows_twist=actuator.follows_twist,  # a dVRK arm ignores the feed-forward twist
            wire=wire,  # the pre-operative model the camera keeps its clearance from
        )
    )

    T_cam = np.empty((n, 4, 4))
    T_cmd = np.empty((n, 4, 4))
    d_f: list[float] = []
    state: list[str] = []
    reason: list[str] = []
    joint_names = actuator.joint_names
    jointed = len(joint_names) > 0  # a carrier with joints logs them and the view it concedes
    joints = np.empty((n, len(joint_names)))
    pos_err: list[float] = []
    ori_err: list[float] = []
    q_now = actuator.q
    chunk = max(1, n // 100)
    reach_offset: FloatArray | None = None
    # per step: plain floats, row views made in one go, and bound methods (n times each)
    t_s, t_ring_s = t.tolist(), t_ring.tolist()
    sensed, tips_k = list(T_sensed), list(tips)
    policy_step, actuator_step = policy.step, actuator.step
    log_d_f, log_state, log_reason = d_f.append, state.append, reason.append
    make_obs = tuple.__new__  # Observation(...) without its Python-level __new__: no checks
    for k in range(n):
        T_cam[k] = T_now
        T_sensed_k = sensed[k]
        cmd = policy_step(
            make_obs(Observation, (t_s[k], T_sensed_k, T_now, tips_k[k], reach_offset, t_ring_s[k]))
        )
        T_goal, cmd_state, cmd_d_f, cmd_reason, cmd_twist = cmd
        T_cmd[k] = T_goal
        log_d_f(cmd_d_f)
        if jointed:  # the pivot of a conceded view; a carrier without joints concedes none
            joints[k] = q_now
            look = _look_distance(T_goal, T_sensed_k, cmd_d_f)
        else:
            look = cmd_d_f
        if step_faults is None:
            out = actuator_step(T_goal, look, cmd_twist)
        else:
            out = actuator_step(*step_faults.command(k, T_goal, cmd_twist, look))
        if jointed:
            reach_offset = out.T_world_target[:3, 3] - T_goal[:3, 3]
            pos_err.append(out.position_error)
            ori_err.append(out.orientation_error)
        if not out.reachable and cmd_state not in _SAFETY_STATES:
            log_state(UNREACHABLE)
            log_reason(_unreachable_reason(kind, out))
        else:
            log_state(cmd_state.value)
            log_reason(cmd_reason)
        T_now, q_now = out.T_world_cam, out.q
        if progress is not None and (k + 1) % chunk == 0:
            progress(chunk)
    if progress is not None and n % chunk:
        progress(n % chunk)

    clearance = np.interp(t, touches.t, touches.clearance)
    log = EpisodeLog(
        t=t,
        T_world_ring=T_ring,
        T_world_ring_sensed=T_sensed,
        T_world_cam=T_cam,
        T_world_cmd=T_cmd,
        state=np.array(state, dtype=str),
        reason=reason,
        d_f=np.array(d_f, dtype=float),
        p_world_tips=tips,
        contact=contact_at(touches, t),
        clearance=clearance,
        joints=joints if jointed else None,
        joint_names=joint_names,
        arm=kind.value,
        goal_position_error=np.array(pos_err, dtype=float) if jointed else None,
        goal_orientation_error=np.array(ori_err, dtype=float) if jointed else None,
        fault=schedule.labels() if schedule is not None else None,
    )
    return EpisodeResult(
        config=config,
        spec=spec,
        camera=camera,
        trajectory=trajectory,
        wire=wire,
        touches=touches,
        log=log,
        T_world_overview=T_overview,
        image_error=image_centering_error(camera, T_cam, T_ring[:, :3, 3]),
        center_error=center_error_3d(T_cam @ camera.T_cam_left, T_ring[:, :3, 3]),
        orientation_error=orientation_error(T_cam, T_ring[:, :3, 2]),
    )


_MIN_LOOK_M = 1e-3  # m: a ring closer than this along the optical axis gives no look-at point


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _look_distance(
    T_world_cmd: FloatArray, T_world_ring: FloatArray, d_f: float
) -> float:  # pragma: no cover - compiled
    """Depth of the (sensed) ring centre along a commanded optical axis, m; else ``d_f``.

    The nearest feasible view of a command turns about the point the command looks at: the
    ring centre for the tracking goal (at ``d_f``) and for the way-point poses (farther).
    ``T_world_cmd``, ``T_world_ring`` (4, 4), world, m. The depth is numpy's
    ``(T_world_ring[:3, 3] - T_world_cmd[:3, 3]) @ T_world_cmd[:3, 2]`` (BLAS ``ddot``:
    :func:`endocam.blasfloat.dot3`), the same float (``tests/test_runner_kernels.py``).
    """
    R, C = T_world_ring, T_world_cmd
    depth = dot3(R[0, 3] - C[0, 3], R[1, 3] - C[1, 3], R[2, 3] - C[2, 3], C[0, 2], C[1, 2], C[2, 2])
    return depth if depth > _MIN_LOOK_M and math.isfinite(depth) else d_f


_SAFETY_STATES = (TrackingState.FROZEN_OUTSIDE_CONE, TrackingState.LOST_TRACKING)


def episode_arm(config: ExperimentConfig, policy: str) -> ArmKind:
    """The arm that carries the camera: the policy's (``orientation-ecm``) or ``episode.arm``.

    Raises
    ------
    ValueError
        For an unknown policy name.
    """
    if policy not in POLICIES:
        make_policy(policy, config.controller)  # raises ValueError listing the choices
    forced = POLICIES[policy].arm
    return forced if forced is not None else config.episode.arm


def _unreachable_reason(kind: ArmKind, out: ActuatorStep) -> str:
    err_mm = out.position_error * 1e3
    err_deg = math.degrees(out.orientation_error)
    if out.status is ActuatorStatus.VIEW:
        return (
            f"goal unreachable by the {kind.value.upper()}: view turned {err_deg:.1f}° towards "
            "the port, still centred at the working distance"
        )
    return (
        f"goal beyond the {kind.value.upper()}'s reach: approaching the nearest feasible "
        f"pose, {err_mm:.1f} mm and {err_deg:.1f}° away"
    )


def state_fractions(log: EpisodeLog) -> dict[str, float]:
    """Fraction of control steps spent in each state of :data:`LOG_STATES` (all listed)."""
    n = len(log.state)
    return {s: float(np.count_nonzero(log.state == s)) / n for s in LOG_STATES}
