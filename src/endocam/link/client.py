"""``endocam control``: any policy against a robot over Zenoh, through one Actuator-shaped client.

:class:`ZenohArm` is the robot as the episode loop sees an in-process carrier
(:class:`endocam.robot.actuator.Actuator`): ``step`` sends the command — the look distance
(``endocam/look_distance``), the feed-forward velocity (``ARM/servo_cv``) when there is one,
then ``ARM/servo_cp``, all stamped with the state they answer — and returns the carrier's
answer once the robot has published the next state. It converts at its edge: the controller
works with the camera in the world, the wire carries the dVRK's tip in the arm's base frame
(:class:`endocam.robot.dvrk_frames.CrtkFrames`, the registration :meth:`ZenohArm.register`
is given; :func:`registration` derives it from the config, as the robot does). The feed-forward
velocity is sent only to the free camera (world = base, camera = tip), the one carrier that
follows it. :func:`run_remote` is the episode loop of
:func:`endocam.runner.episode.run_episode` with the observations the robot published (the
camera, its joints, the sensed ring, the tips); the ground truth its run files are scored
against (the true ring pose, the touches) is the same world built from the same options.

**The controller holds when the link fails.** When no new state arrives within ``timeout`` s
(wall clock) of a command, when the robot's state stops advancing or jumps (its watchdog held
the arm), when a pose it receives names another frame than the registered one (``measured_cp``,
``setpoint_cp``; the ring: ``world``), or when the robot ends early, the controller sends
nothing more — the robot's watchdog stops the arm — and the episode ends there with the reason
(:class:`LinkLostError`); the run folder holds the steps done and says why in ``link.json``.
"""

from __future__ import annotations

import queue
import time
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from endocam.camera import StereoCamera
from endocam.config import ExperimentConfig
from endocam.control.types import Observation, PolicyContext
from endocam.geometry import FloatArray
from endocam.link.messages import DISABLED, PAUSED, Codec, Keys, stamp_ns
from endocam.link.server import LOOK_KEY
from endocam.link.world import link_world, zenoh_config
from endocam.metrics import center_error_3d, image_centering_error, orientation_error
from endocam.registry import make_policy
from endocam.robot.actuator import ActuatorStatus, ActuatorStep, ArmKind, GuardAction
from endocam.robot.carriers import crtk_frames
from endocam.robot.dvrk_frames import FREE_CAMERA_FRAMES, WORLD_FRAME_ID, CrtkFrames
from endocam.runner.episode import (
    EpisodeLog,
    EpisodeResult,
    EpisodeSpec,
    StepRecorder,
    contact_at,
    episode_arm,
)
from endocam.runner.step import StepRecord, target_offset, told_look
from endocam.task.config import TaskConfig
from endocam.task.layout import overview_camera_pose
from endocam.task.touches import touch_events
from endocam.task.trajectory import RingTrajectory

DEFAULT_TIMEOUT_S = 0.5  # s (wall): the robot answers a command within this, or it is silent
RING_ATOL_M = 1e-9  # m: the robot's sensed ring vs this world's (same options: equal to round-off)


class LinkLostError(Exception):
    """The robot went silent, stopped advancing, held, or ended early: the controller holds."""


class RobotState(NamedTuple):
    """One control step's state as the robot published it (world frame, SI).

    Attributes
    ----------
    k : int
        The step (its stamp over the control period).
    T_world_cam : (4, 4)
        The camera, m: ``ARM/measured_cp`` (the dVRK's tip in the base frame) converted.
    q : (J,)
        ``ARM/measured_js`` positions, rad / m.
    T_world_ring : (4, 4)
        ``ring/measured_cp``: the ring as sensed, m.
    t_ring : float
        Its capture time, s.
    p_world_tips : (2, 3)
        ``PSM1/tip``, ``PSM2/tip``, m.
    """

    k: int
    T_world_cam: FloatArray
    q: FloatArray
    T_world_ring: FloatArray
    t_ring: float
    p_world_tips: FloatArray


class ZenohArm:
    """A robot over Zenoh with the :class:`~endocam.robot.actuator.Actuator` interface.

    Parameters
    ----------
    kind : ArmKind
        The carrier the robot serves (its key expressions: ``PSM3/...``, ``ECM/...``,
        ``camera/...``).
    endpoint : str
        The robot's Zenoh endpoint, e.g. ``tcp/127.0.0.1:7447``.
    dt : float
        Control period, s (the robot's; stamps are ``k · dt``).
    timeout : float
        Wall time, s, the robot has to answer a command (and to show its first state).
    """

    def __init__(
        self, kind: ArmKind, endpoint: str, dt: float, timeout: float = DEFAULT_TIMEOUT_S
    ) -> None:
        self.kind = kind
        self.follows_twist = kind is ArmKind.FREE  # as the in-process carriers
        self.keys = Keys.of(kind)
        self.endpoint, self.dt, self.timeout = endpoint, dt, timeout
        self.codec = Codec()
        self.frames: CrtkFrames | None = FREE_CAMERA_FRAMES if kind is ArmKind.FREE else None
        """Where the wire's poses are (:meth:`register`); an arm has none until registered."""
        self.inbox: queue.Queue[tuple[str, bytes]] = queue.Queue()
        self.state: RobotState | None = None
        self._latest: dict[str, bytes] = {}
        self._pending: list[tuple[str, bytes]] = []
        """Messages received since the last operating state (Zenoh's callback thread only)."""
        self._names: tuple[str, ...] = ()
        self.session: Any = None
        self.pub: dict[str, Any] = {}
        self.received = 0
        """Messages received (all topics)."""

    # -- connection ---------------------------------------------------------------------------

    def register(self, frames: CrtkFrames) -> None:
        """The arm's base frame in world and the camera on its tip (on a rig: the registration)."""
        if self.kind is ArmKind.FREE and not frames.identity:
            raise ValueError("the free camera's poses are the camera's, in the world")
        self.frames = frames

    def _frames(self) -> CrtkFrames:
        if self.frames is None:
            raise ValueError(
                f"the {self.kind.value}'s base frame and camera mount are not registered"
            )
        return self.frames

    def connect(self, wait: float) -> RobotState:
        """Open the link and wait up to ``wait`` s for the robot's first state.

        Already connected: the state it has (the first until a command is sent).
        """
        import zenoh

        if self.session is not None and self.state is not None:
            return self.state
        self._frames()  # registered before anything moves

        self.session = zenoh.open(zenoh_config(self.endpoint, listen=False))
        k = self.keys
        # one subscriber for every key: its callback sees the robot's messages in the order
        # they were sent (separate subscribers' callbacks may interleave)
        self._sub = self.session.declare_subscriber(
            "**", self._on_sample, allowed_origin=zenoh.Locality.REMOTE
        )
        self.pub = {
            key: self.session.declare_publisher(
                key, congestion_control=zenoh.CongestionControl.BLOCK
            )
            for key in (k.servo_cp, k.servo_cv, LOOK_KEY)
        }
        self.state = self.receive(0, wait, first=True)
        return self.state

    def close(self) -> None:
        """Close the link."""
        if self.session is not None:
            self.session.close()
            self.session = None

    def _on_sample(self, sample: Any) -> None:
        # a state's messages reach the inbox together, with its operating state (published
        # last): the controller wakes once per state, not once per message
        key = str(sample.key_expr)
        self._pending.append((key, sample.payload.to_bytes()))
        if key == self.keys.operating_state:
            for message in self._pending:
                self.inbox.put(message)
            self._pending.clear()

    def receive(self, k: int, timeout: float, *, first: bool = False) -> RobotState:
        """Collect messages until the operating state of step ``k`` (all its messages before).

        Older states (repeated, duplicated) and malformed operating states are skipped; a
        state past ``k`` or ``PAUSED`` raises :class:`LinkLostError` at once (the robot held),
        as does silence for ``timeout`` s (wall) or a malformed state of step ``k``.
        """
        deadline = time.monotonic() + timeout
        want = stamp_ns(k * self.dt)
        refused = ""  # why the last first state was not taken (a wrong frame, say)
        while True:
            left = deadline - time.monotonic()
            try:
                key, data = self.inbox.get(timeout=max(left, 0.0))
            except queue.Empty:
                what = "no state from the robot" if first else "the robot went silent"
                raise LinkLostError(
                    f"{what} for {timeout:g} s (waiting for step {k}, t = {k * self.dt:.3f} s)"
                    + (f"; its last state was refused: {refused}" if refused else "")
                ) from None
            self.received += 1
            if key != self.keys.operating_state:
                self._latest[key] = data
                continue
            try:
                state, ns = self.codec.decode_operating_state(data)
            except ValueError:
                continue  # not acted on; the next one decides
            if first and ns == want:
                try:
                    return self._state(k)
                except LinkLostError as exc:
                    refused = str(exc)
                    continue  # joined mid-way through a state: the robot repeats it
            if ns < want or first:
                continue  # an older state repeated (the robot waiting for its first command)
            if ns > want:
                raise LinkLostError(
                    f"the robot's state jumped past step {k} (t = {k * self.dt:.3f} s, "
                    f"state {state}): its watchdog held the arm"
                )
            if state == PAUSED:
                raise LinkLostError(
                    f"the robot's watchdog held the arm at t = {k * self.dt:.3f} s "
                    "(operating_state PAUSED): the command came too late"
                )
            return self._state(k) if state != DISABLED else self._final(k)

    def _state(self, k: int) -> RobotState:
        c, L, keys = self.codec, self._latest, self.keys
        try:
            (T_cam, ns), (T_ring, ns_ring) = c.decode_poses(
                [(L[keys.measured_cp], self._frames().frame_id), (L[keys.ring], WORLD_FRAME_ID)]
            )
            q = c.decode_joints(L[keys.measured_js])
            tips = np.stack([c.decode_point(L[keys.tip1]), c.decode_point(L[keys.tip2])])
        except (KeyError, ValueError) as exc:
            raise LinkLostError(
                f"the robot's state at step {k} is incomplete or malformed: {exc}"
            ) from exc
        if ns != stamp_ns(k * self.dt):
            raise LinkLostError(
                f"the robot's measured_cp is not of step {k}: its state stopped advancing"
            )
        return RobotState(k, self._frames().camera_from_tip(T_cam), q, T_ring, ns_ring / 1e9, tips)

    def _final(self, k: int) -> RobotState:
        assert self.state is not None
        return self.state._replace(k=k)

    # -- the Actuator interface -------------------------------------------------------------

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Names of the robot's joints (from its carrier kind)."""
        from endocam.runner.log_schema import joint_names

        return () if self.kind is ArmKind.FREE else tuple(joint_names(self.kind))

    @property
    def q(self) -> FloatArray:
        """The joints the robot last measured, rad / m."""
        assert self.state is not None
        return self.state.q

    def start_view(self, task_cfg: TaskConfig, camera: StereoCamera) -> tuple[FloatArray, float]:
        """The pose the robot started at (the robot chooses its start), and no look distance."""
        assert self.state is not None
        return self.state.T_world_cam, 0.0

    def reset(self, T_world_cam: object, look_distance: float | None = None) -> FloatArray:
        """The robot starts itself; returns the pose it measured (``T_world_cam`` unused)."""
        assert self.state is not None
        return self.state.T_world_cam

    def stall(self, joint: int | None) -> None:
        """No fault injection over the link."""
        if joint is not None:
            raise ValueError("a robot over the link takes no injected joint faults")

    def step(
        self, T_world_cmd: FloatArray, look_distance: float, twist: FloatArray | None = None
    ) -> ActuatorStep:
        """Command the current step; the robot's answer once it published the next state.

        Raises :class:`LinkLostError` (nothing more is sent) when the robot does not answer.
        """
        assert self.state is not None
        k = self.state.k
        ns = stamp_ns(k * self.dt)
        frames = self._frames()
        self.pub[LOOK_KEY].put(self.codec.float64(look_distance))
        if twist is not None and self.follows_twist:  # the free camera's: world = base
            self.pub[self.keys.servo_cv].put(self.codec.twist(twist, ns))
        T_cmd_tip = frames.tip_from_camera(T_world_cmd)
        self.pub[self.keys.servo_cp].put(self.codec.pose(T_cmd_tip, ns, frames.frame_id))
        self.state = self.receive(k + 1, self.timeout)
        try:
            res = self.codec.decode_array(self._latest[self.keys.servo_result])
            T_tip, _ = self.codec.decode_pose(self._latest[self.keys.setpoint_cp], frames.frame_id)
            return ActuatorStep(
                self.state.T_world_cam,
                self.state.q,
                frames.camera_from_tip(T_tip),
                list(ActuatorStatus)[int(res[0])],
                float(res[3]),
                float(res[4]),
                bool(res[1]),
                list(GuardAction)[int(res[2])],
            )
        except (KeyError, ValueError, IndexError) as exc:
            raise LinkLostError(
                f"the robot's answer to step {k} is missing or malformed: {exc!r}"
            ) from exc


def registration(config: ExperimentConfig, kind: ArmKind) -> CrtkFrames:
    """Where carrier ``kind``'s CRTK poses are under ``config``: the robot's own frames.

    The arm's base (RCM) frame from ``task.scene`` and the camera on its tip from
    ``episode.tip_cam_*`` (the ECM's: :data:`endocam.robot.dvrk_frames.T_TIP_CAM_ECM`), as
    ``endocam robot serve`` mounts them; on a rig, the registration of the arm to the scene.
    """
    return crtk_frames(kind, config.episode.T_tip_cam, config.task.scene.T_world_rcm)


class PartialTrajectory(RingTrajectory):
    """A trajectory whose episode ended early (the link failed): ``duration`` the steps done."""

    def __init__(self, full: RingTrajectory, duration: float) -> None:
        self.__dict__.update(full.__dict__)
        self._ended = duration

    @property
    def duration(self) -> float:
        """Time of the last step done, s."""
        return self._ended


@dataclass(frozen=True)
class RemoteRun:
    """An episode over the link: its result and why it ended early (``None``: it did not)."""

    result: EpisodeResult
    lost: str | None
    steps: int
    """Control steps commanded."""


def run_remote(
    config: ExperimentConfig, spec: EpisodeSpec, arm: ZenohArm, wait: float
) -> RemoteRun:
    """Run ``spec.policy`` against the robot behind ``arm``; see the module docstring.

    Raises ``ValueError`` when the robot's world is not the one of ``config`` and ``spec``
    (its first sensed ring differs), ``LinkLostError`` when no robot answers within ``wait`` s.
    An arm not yet registered (:meth:`ZenohArm.register`) is given :func:`registration`.
    """
    policy = make_policy(spec.policy, config.controller)
    kind = episode_arm(config, spec.policy)
    if kind is not arm.kind:
        raise ValueError(
            f"policy {spec.policy} needs the {kind.value} carrier, not {arm.kind.value}"
        )
    lw = link_world(config, spec)
    world, camera, trajectory = lw.world, lw.camera, lw.trajectory
    if arm.frames is None:
        arm.register(registration(config, kind))
    first = arm.connect(wait)
    if not np.allclose(
        first.T_world_ring, world.T_world_ring_sensed[0], rtol=0.0, atol=RING_ATOL_M
    ):
        raise ValueError(
            "the robot's ring is not this world's: start it with the same --trajectory, "
            "--control-points, --seed and --config"
        )
    dt = 1.0 / config.episode.control_rate
    policy.reset(
        PolicyContext(
            camera,
            first.T_world_cam,
            first.T_world_ring,
            np.array(config.task.scene.rcm_position),
            dt,
            config.episode.sensing_latency,
            future=trajectory.poses,
            future_duration=float(trajectory.duration),
            follows_twist=arm.follows_twist,
            wire=lw.wire,
            ring=config.task.ring,
        )
    )
    n = world.n
    jointed = bool(arm.joint_names)
    log = StepRecorder(n, kind, len(arm.joint_names))
    reach: FloatArray | None = None
    lost: str | None = None
    m = 0
    for k in range(n):
        s = arm.state
        assert s is not None
        obs = Observation(
            float(world.t[k]), s.T_world_ring, s.T_world_cam, s.p_world_tips, reach, s.t_ring
        )
        cmd = policy.step(obs)
        look = told_look(cmd, s.T_world_ring, jointed)
        try:
            out = arm.step(cmd.T_world_cam, look, cmd.twist)
        except LinkLostError as exc:
            lost = f"controller holding: {exc}"
            break
        reach = target_offset(out, cmd, jointed)
        log.record(cmd, StepRecord(k, s.T_world_cam, s.q, look, out))
        m = k + 1
    if m < 2:
        raise LinkLostError(lost or "the robot ended before the episode began")
    return RemoteRun(_result(config, spec, lw, log, m, kind, arm.joint_names), lost, m)


def _result(
    config: ExperimentConfig,
    spec: EpisodeSpec,
    lw: Any,
    log: StepRecorder,
    m: int,
    kind: ArmKind,
    names: tuple[str, ...],
) -> EpisodeResult:
    """The episode's result from its first ``m`` recorded steps (all of them: ``m = n``)."""
    world, camera, trajectory = lw.world, lw.camera, lw.trajectory
    if m < world.n:
        trajectory = PartialTrajectory(trajectory, float(world.t[m - 1]))
    t, T_ring = world.t[:m], world.T_world_ring[:m]
    touches = touch_events(
        trajectory, lw.wire, config.task.ring, config.task.trajectory.touch_sample_dt
    )
    jointed = bool(names)
    T_cam = log.T_cam[:m]
    episode_log = EpisodeLog(
        t=t,
        T_world_ring=T_ring,
        T_world_ring_sensed=world.T_world_ring_sensed[:m],
        T_world_cam=T_cam,
        T_world_cmd=log.T_cmd[:m],
        state=np.array(log.state[:m], dtype=str),
        reason=log.reason[:m],
        d_f=np.array(log.d_f[:m], dtype=float),
        p_world_tips=world.p_world_tips[:m],
        contact=contact_at(touches, t),
        clearance=np.interp(t, touches.t, touches.clearance),
        joints=log.joints[:m] if jointed else None,
        joint_names=names,
        arm=kind.value,
        goal_position_error=np.array(log.pos_err[:m], dtype=float) if jointed else None,
        goal_orientation_error=np.array(log.ori_err[:m], dtype=float) if jointed else None,
    )
    return EpisodeResult(
        config=config,
        spec=spec,
        camera=camera,
        trajectory=trajectory,
        wire=lw.wire,
        touches=touches,
        log=episode_log,
        T_world_overview=overview_camera_pose(config.task, camera),
        image_error=image_centering_error(camera, T_cam, T_ring[:, :3, 3]),
        center_error=center_error_3d(T_cam @ camera.T_cam_left, T_ring[:, :3, 3]),
        orientation_error=orientation_error(T_cam, T_ring[:, :3, 2]),
    )
