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
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from endocam.camera import StereoCamera
from endocam.config import ExperimentConfig
from endocam.control.types import CameraCommand, PolicyContext, TrackingState
from endocam.faults import (
    DeliveredFaults,
    StepFaults,
    apply_observation_faults,
    fault_schedule,
)
from endocam.geometry import FloatArray
from endocam.metrics import (
    center_error_3d,
    image_centering_error,
    orientation_error,
    ring_out_of_view,
    saturate_image_error,
)
from endocam.registry import POLICIES, make_policy
from endocam.robot.actuator import ActuatorStatus, ActuatorStep, ArmKind, GuardAction
from endocam.runner.step import EpisodeLoop, StepRecord, episode_world, start_carrier
from endocam.task.config import MAX_CONTROL_POINTS
from endocam.task.layout import overview_camera_pose
from endocam.task.touches import TouchReport, touch_events
from endocam.task.trajectory import RingTrajectory, TrajectoryKind, make_trajectory
from endocam.task.wire import Wire

if TYPE_CHECKING:
    from endocam.perception.loop import EstimateLog

UNREACHABLE = "unreachable"
"""Log state of a step whose goal the carrier concedes (``ActuatorStep.reachable`` is false)."""
BLOCKED = "blocked"
"""Log state of a step the carrier's workspace guard braked: no admissible motion towards the
command (``ActuatorStep.guard`` is ``GuardAction.BRAKED``)."""
BLOCKED_REASON = (
    "no motion towards the command keeps the camera able to stop inside the workspace (cone, "
    "floor, wire zone): braking"
)
LOG_STATES = (*(s.value for s in TrackingState), UNREACHABLE, BLOCKED)
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
        The true ring pose delayed by the sensing latency (faults applied), m: what the policy
        saw on ``perception.source = "truth"`` (on ``stereo``: ``estimates.T_world_ring_seen``).
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
    estimates : EstimateLog or None
        On ``perception.source = "stereo"``: the estimates delivered per step and the frames
        (:mod:`endocam.perception.loop`); ``None`` on ``truth``.
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
    estimates: EstimateLog | None = None


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
    ``unreachable`` (unless the policy is already frozen or has lost tracking); steps on which
    the carrier's workspace guard found no admissible motion towards the command and braked
    are logged as ``blocked`` (the same exceptions).

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
    policy = make_policy(spec.policy, config.controller_on_source)  # unknown names fail first
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
    world = episode_world(config, trajectory)
    true_world = world  # what a stereo source renders (the faults below rewrite the sensing)
    n, t, T_ring = world.n, world.t, world.T_world_ring
    T_overview = overview_camera_pose(config.task, camera)
    kind = episode_arm(config, spec.policy)
    carrier = start_carrier(config, kind, camera, wire, world)
    actuator = carrier.actuator
    schedule = None
    step_faults: StepFaults | None = None
    if config.faults.any:  # faults: the observations rewritten here, a hook in the loop
        schedule = fault_schedule(
            config.faults, n, dt, arm=kind is not ArmKind.FREE, joints=len(actuator.joint_names)
        )
        T_sensed, tips, t_ring = apply_observation_faults(
            schedule,
            t,
            world.T_world_ring_sensed,
            world.p_world_tips,
            trajectory.poses,
            ep.sensing_latency,
        )
        world = replace(world, T_world_ring_sensed=T_sensed, p_world_tips=tips, t_ring=t_ring)
        step_faults = StepFaults(schedule, actuator.stall) if schedule.steps_faulty else None
    policy.reset(
        PolicyContext(
            camera,
            carrier.T_world_cam,
            world.T_world_ring_sensed[0],
            np.array(config.task.scene.rcm_position),
            dt,
            ep.sensing_latency,
            future=trajectory.poses,  # the true trajectory: only non-causal policies read it
            future_duration=float(trajectory.duration),
            follows_twist=actuator.follows_twist,  # a dVRK arm ignores the feed-forward twist
            wire=wire,  # the pre-operative model the camera keeps its clearance from
            ring=config.task.ring,  # the ring's known geometry
        )
    )

    stereo = None
    if config.perception.stereo:  # renders (MuJoCo): imported for a stereo run only
        from endocam.runner.ring_source import StereoSource

        ring_faults = DeliveredFaults(schedule, dt) if schedule is not None else None
        stereo = StereoSource(
            config, true_world, kind, spec.seed, true_world.T_world_ring_sensed[0], ring_faults
        )
    loop = EpisodeLoop(world, carrier, step_faults, stereo)
    log = StepRecorder(n, kind, len(actuator.joint_names))
    chunk = max(1, n // 100)
    observe, policy_step, loop_step, record = loop.observation, policy.step, loop.step, log.record
    try:
        for k in range(n):
            cmd = policy_step(observe())
            record(cmd, loop_step(cmd))
            if progress is not None and (k + 1) % chunk == 0:
                progress(chunk)
    finally:
        if stereo is not None:
            stereo.close()
    if progress is not None and n % chunk:
        progress(n % chunk)

    clearance = np.interp(t, touches.t, touches.clearance)
    jointed = log.jointed
    episode_log = EpisodeLog(
        t=t,
        T_world_ring=T_ring,
        T_world_ring_sensed=world.T_world_ring_sensed,
        T_world_cam=log.T_cam,
        T_world_cmd=log.T_cmd,
        state=np.array(log.state, dtype=str),
        reason=log.reason,
        d_f=np.array(log.d_f, dtype=float),
        p_world_tips=world.p_world_tips,
        contact=contact_at(touches, t),
        clearance=clearance,
        joints=log.joints if jointed else None,
        joint_names=actuator.joint_names,
        arm=kind.value,
        goal_position_error=np.array(log.pos_err, dtype=float) if jointed else None,
        goal_orientation_error=np.array(log.ori_err, dtype=float) if jointed else None,
        fault=schedule.labels() if schedule is not None else None,
        estimates=stereo.log() if stereo is not None else None,
    )
    return EpisodeResult(
        config=config,
        spec=spec,
        camera=camera,
        trajectory=trajectory,
        wire=wire,
        touches=touches,
        log=episode_log,
        T_world_overview=T_overview,
        image_error=image_centering_error(camera, log.T_cam, T_ring[:, :3, 3]),
        center_error=center_error_3d(log.T_cam @ camera.T_cam_left, T_ring[:, :3, 3]),
        orientation_error=orientation_error(log.T_cam, T_ring[:, :3, 2]),
    )


_SAFETY_STATES = (TrackingState.FROZEN_OUTSIDE_CONE, TrackingState.LOST_TRACKING)


class StepRecorder:
    """The runner's log, filled a row per :class:`StepRecord` (n steps, J joints)."""

    def __init__(self, n: int, kind: ArmKind, joints: int) -> None:
        self.kind = kind
        self.jointed = joints > 0  # a carrier with joints logs them and the view it concedes
        self.T_cam = np.empty((n, 4, 4))
        self.T_cmd = np.empty((n, 4, 4))
        self.joints = np.empty((n, joints))
        self.d_f: list[float] = []
        self.state: list[str] = []
        self.reason: list[str] = []
        self.pos_err: list[float] = []
        self.ori_err: list[float] = []

    def record(self, cmd: CameraCommand, rec: StepRecord) -> None:
        """Log step ``rec.k``: the camera before it, the policy's command, the carrier's answer."""
        k, out = rec.k, rec.carrier
        self.T_cam[k] = rec.T_world_cam
        self.T_cmd[k] = cmd.T_world_cam
        self.d_f.append(cmd.d_f)
        if self.jointed:
            self.joints[k] = rec.q
            self.pos_err.append(out.position_error)
            self.ori_err.append(out.orientation_error)
        if out.guard is GuardAction.BRAKED and cmd.state not in _SAFETY_STATES:
            self.state.append(BLOCKED)
            self.reason.append(BLOCKED_REASON)
        elif not out.reachable and cmd.state not in _SAFETY_STATES:
            self.state.append(UNREACHABLE)
            self.reason.append(_unreachable_reason(self.kind, out))
        else:
            self.state.append(cmd.state.value)
            self.reason.append(cmd.reason)


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
