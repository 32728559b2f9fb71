"""``endocam robot serve``: the simulated arm and the wire-chaser world as a robot process.

It speaks CRTK over Zenoh (:mod:`endocam.link.messages`): it publishes the state of every
control step and follows ``servo_cp`` — or, for an arm, ``servo_jp``: the camera pose of
those joints, refused beyond the arm's joint limits — through the same carrier (and so the same
joint limits, workspace guard and speed limits) as an in-process episode.

**The dVRK's frames.** An arm's ``measured_cp``, ``setpoint_cp`` and ``servo_cp`` are the
dVRK's tool tip in the arm's base frame (its RCM frame: a stand-alone arm), its joints the
dVRK's; the carrier works with the camera in the world, converted at this edge by
:class:`endocam.robot.dvrk_frames.CrtkFrames` (:func:`endocam.robot.carriers.crtk_frames`).
The free camera has no dVRK counterpart: its poses are the camera's, in the world.

**Time is lock-stepped to the commands.** The simulation advances one control period for each
accepted command — the one stamped with the state it answers — so the same controller gives
the same episode over the link as in-process, whatever the network's timing. Commands stamped
for another step (late, duplicated, reordered) are dropped, never acted on out of order.

**Watchdog.** When no acceptable command arrives for ``watchdog`` seconds (wall clock) the
robot stops servoing (``operating_state`` ``PAUSED``): it commands its own camera pose at rest,
one control period per wall period, so the carrier brakes within its limits and holds while
the world moves on. A command answering the current state resumes servoing (``ENABLED``).

**Refused.** A payload that does not decode as the message of its topic, a non-finite pose,
twist or look distance, a quaternion not of unit length, a ``servo_cp`` whose
``header.frame_id`` is not the base frame of the poses it publishes (``PSM3_base``,
``ECM_base``; ``world`` for the free camera), a look distance ≤ 0 or beyond
:data:`MAX_LOOK_M`: one line on stderr, never a crash, never acted on.

Before the first command the robot republishes the first state every control period for up to
``wait`` seconds (waiting for a controller); it ends (``DISABLED``) when the trajectory ends.
"""

from __future__ import annotations

import math
import queue
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from typing import Any, NamedTuple, TextIO

import numpy as np

from endocam.config import ExperimentConfig
from endocam.geometry import FloatArray
from endocam.link.messages import DISABLED, ENABLED, PAUSED, Codec, Keys, stamp_ns
from endocam.link.world import link_world, zenoh_config
from endocam.robot.actuator import ActuatorStatus, ActuatorStep, ArmKind, GuardAction
from endocam.robot.camera_arm import CameraArm, arm_model
from endocam.robot.carriers import crtk_frames
from endocam.robot.dvrk_frames import CrtkFrames
from endocam.runner.episode import EpisodeSpec
from endocam.runner.step import start_carrier

DEFAULT_WATCHDOG_S = 0.1  # s (wall): 10 control periods at 100 Hz
DEFAULT_WAIT_S = 60.0  # s (wall) the robot waits for a controller's first command
MAX_LOOK_M = 1.0  # m: no look distance inside an abdomen is longer
LOOK_KEY = "endocam/look_distance"
"""Key of the look distance (``std_msgs/Float64``, m) sent just before each ``servo_cp``."""


@dataclass
class ServeStats:
    """What a served episode saw (counts)."""

    steps: int = 0
    """Control steps taken (commanded and held)."""
    commanded: int = 0
    """Steps taken on a controller's command."""
    held: int = 0
    """Steps taken on the watchdog's hold."""
    dropped: int = 0
    """Commands stamped for another step (late, duplicated, reordered)."""
    refused: list[str] = field(default_factory=list)
    """Why each refused message was refused."""
    watchdog_trips: int = 0
    """Times the watchdog stopped servoing."""


def servo_result(out: ActuatorStep) -> FloatArray:
    """The ``endocam/servo_result`` vector of a carrier's answer (``SERVO_RESULT_FIELDS``)."""
    return np.array(
        [
            list(ActuatorStatus).index(out.status),
            float(out.reachable),
            list(GuardAction).index(out.guard),
            out.position_error,
            out.orientation_error,
        ]
    )


class _Inbox:
    """Commands as they arrive (Zenoh's callback thread → the serving loop), in order."""

    def __init__(self) -> None:
        self.q: queue.Queue[tuple[str, bytes]] = queue.Queue()

    def callback(self, sample: Any) -> None:
        self.q.put((str(sample.key_expr), sample.payload.to_bytes()))


class Robot:
    """One served episode: the carrier, the world row it is at, and what it publishes."""

    def __init__(
        self, config: ExperimentConfig, spec: EpisodeSpec, kind: ArmKind, session: Any
    ) -> None:
        import zenoh

        lw = link_world(config, spec)
        self.world = lw.world
        warm = start_carrier(config, kind, lw.camera, lw.wire, self.world)  # compile the
        warm.actuator.step(warm.T_world_cam, config.controller.d_f)  # kernels now, not later
        carrier = start_carrier(config, kind, lw.camera, lw.wire, self.world)
        self.arm = carrier.actuator
        self.T_cam, self.q = carrier.T_world_cam, self.arm.q
        self.look = float(config.controller.d_f)
        self.dt = 1.0 / config.episode.control_rate
        self.kind = kind
        self.frames = crtk_frames(kind, config.episode.T_tip_cam, config.task.scene.T_world_rcm)
        self.keys = keys = Keys.of(kind)
        self.codec = Codec()
        self.k = 0
        self.pub = {
            key: session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
            for key in (*keys[:4], keys.ring, keys.tip1, keys.tip2, keys.servo_result)
        }

    @property
    def done(self) -> bool:
        """The trajectory has ended."""
        return self.k >= self.world.n

    def publish(self, state: str, out: ActuatorStep | None) -> None:
        """The state of step ``k`` (its operating state last: the controller's cue)."""
        k, w, c, keys = self.k, self.world, self.codec, self.keys
        ns = stamp_ns(k * self.dt)  # = world.t[k] for k < n; the end is stamped n · dt
        if out is not None:
            self.pub[keys.servo_result].put(c.array(servo_result(out)))
            self.pub[keys.setpoint_cp].put(
                c.pose(self.frames.tip_from_camera(out.T_world_target), ns, self.frames.frame_id)
            )
        if k < w.n:
            self.pub[keys.measured_js].put(c.joints(self.arm.joint_names, self.q, ns))
            self.pub[keys.ring].put(c.pose(w.T_world_ring_sensed[k], stamp_ns(w.t_ring[k])))
            self.pub[keys.tip1].put(c.point(w.p_world_tips[k, 0], ns))
            self.pub[keys.tip2].put(c.point(w.p_world_tips[k, 1], ns))
            T_tip = self.frames.tip_from_camera(self.T_cam)
            self.pub[keys.measured_cp].put(c.pose(T_tip, ns, self.frames.frame_id))
        if k >= w.n:
            state = DISABLED
        self.pub[keys.operating_state].put(c.operating_state(state, k < w.n, ns))

    def step(self, T_goal: FloatArray, look: float, twist: FloatArray | None, state: str) -> None:
        """One control period towards ``T_goal``; publishes the next state as ``state``."""
        out = self.arm.step(T_goal, look, twist)
        self.T_cam, self.q, self.look = out.T_world_cam, out.q, look
        self.k += 1
        self.publish(state, out)

    def hold(self) -> None:
        """One control period of the watchdog's hold: the camera's own pose, at rest."""
        self.step(self.T_cam, self.look, None, PAUSED)


class Command(NamedTuple):
    """A whole command, decoded: the pose to head for and what came with it."""

    T_world_cmd: FloatArray
    """(4, 4) the camera pose to head for, world, m (``servo_cp``'s tip pose or ``servo_jp``'s
    joints, converted)."""
    ns: int
    """Its stamp, ns: the state (``k · dt``) it answers."""
    look: float
    """The look distance sent with it, m."""
    twist: FloatArray | None
    """(6,) the feed-forward velocity stamped with it (m/s, rad/s, world), or ``None``."""


JOINT_LIMIT_TOL = 1e-9  # rad / m: a servo_jp this far beyond a joint limit is still inside


class JointCommand:
    """``servo_jp`` → the camera pose of those joints, refused outside the arm's joint limits."""

    def __init__(self, kind: ArmKind, arm: object) -> None:
        self.kind, self.arm = kind, arm
        if isinstance(arm, CameraArm):
            model = arm_model(kind)
            self.lower, self.upper = model.lower, model.upper

    def pose(self, q: FloatArray) -> FloatArray:
        """The camera pose (4, 4), world, m, of joints ``q``; ``ValueError`` if refused."""
        if not isinstance(self.arm, CameraArm):
            raise ValueError(f"servo_jp: the {self.kind.value} camera has no joints")
        if q.shape != self.lower.shape:
            raise ValueError(f"servo_jp: {q.size} joint positions, the arm has {self.lower.size}")
        outside = (q < self.lower - JOINT_LIMIT_TOL) | (q > self.upper + JOINT_LIMIT_TOL)
        if np.any(outside):
            raise ValueError(f"servo_jp: joints {np.flatnonzero(outside).tolist()} beyond limits")
        return self.arm.camera_pose(q)


class Verdict(Enum):
    """What the robot does with one message (:meth:`CommandGate.admit`)."""

    ACCEPTED = "accepted"
    """A whole command answering the current state: act on it now."""
    PART = "part"
    """A look distance or a velocity: kept for the ``servo_cp`` / ``servo_jp`` that follows."""
    DROPPED = "dropped"
    """A command stamped for another step (late, duplicated, reordered): never acted on."""
    REFUSED = "refused"
    """Does not decode as its topic's message, or outside the limits: never acted on."""
    IGNORED = "ignored"
    """Not a command of this robot."""


class Admission(NamedTuple):
    """:meth:`CommandGate.admit`'s answer: the verdict, the command (``ACCEPTED``), or why."""

    verdict: Verdict
    command: Command | None = None
    why: str = ""


class CommandGate:
    """The robot's acceptance rules: which message completes a command it may act on, in order.

    A command is the look distance, the velocity (optional, its stamp equal to the pose's) and
    then the ``servo_cp`` (the dVRK's tip in the arm's base frame) or ``servo_jp`` that
    completes it; it is acted on only when it is
    stamped with the state the robot is at (``k · dt``). The look distance (``std_msgs/Float64``)
    has no stamp: it belongs to the next ``servo_cp``, and any refused or completed command
    clears it, so a look distance is used at most once.

    Parameters
    ----------
    keys : Keys
        The robot's key expressions.
    joints : JointCommand
        ``servo_jp``'s conversion (and the arm's joint limits).
    frames : CrtkFrames
        ``servo_cp``'s: the tip pose it carries → the camera pose the carrier heads for.
    dt : float
        Control period, s (stamps are ``k · dt``).
    """

    def __init__(self, keys: Keys, joints: JointCommand, frames: CrtkFrames, dt: float) -> None:
        self.keys, self.joints, self.frames, self.dt = keys, joints, frames, dt
        self.codec = Codec()
        self.commands = (LOOK_KEY, keys.servo_cv, keys.servo_cp, keys.servo_jp)
        self.look: float | None = None
        self.twist: tuple[FloatArray, int] | None = None

    def admit(self, key: str, data: bytes, k: int) -> Admission:
        """The verdict on the message ``data`` on ``key`` while the robot is at step ``k``."""
        if key not in self.commands:
            return Admission(Verdict.IGNORED)
        try:
            cmd = self._feed(key, data)
        except ValueError as exc:
            return Admission(Verdict.REFUSED, why=f"{key}: {exc}")
        if cmd is None:
            return Admission(Verdict.PART)
        if cmd.ns != stamp_ns(k * self.dt):
            return Admission(
                Verdict.DROPPED, why=f"stamped {cmd.ns / 1e9:.6f} s at step {k} ({k * self.dt:g} s)"
            )
        return Admission(Verdict.ACCEPTED, cmd)

    def _feed(self, key: str, data: bytes) -> Command | None:
        """The command completed by this message, if any; ``ValueError`` if it is refused."""
        c = self.codec
        try:
            if key == LOOK_KEY:
                look = c.decode_float64(data)
                if not (math.isfinite(look) and 0.0 < look <= MAX_LOOK_M):
                    raise ValueError(f"look distance {look!r} m outside (0, {MAX_LOOK_M}] m")
                self.look = look
                return None
            if key == self.keys.servo_cv:
                self.twist = c.decode_twist(data)
                return None
            if key == self.keys.servo_jp:
                q, ns = c.decode_joint_command(data)
                T_goal = self.joints.pose(q)
            else:
                T_tip, ns = c.decode_pose(data, self.frames.frame_id)
                T_goal = self.frames.camera_from_tip(T_tip)
        except ValueError:
            self.look, self.twist = None, None
            raise
        paired, twist = self.look, self.twist
        self.look, self.twist = None, None
        if paired is None:
            raise ValueError(f"{key.rsplit('/', 1)[-1]} without its look distance")
        return Command(T_goal, ns, paired, twist[0] if twist and twist[1] == ns else None)


def serve(
    config: ExperimentConfig,
    spec: EpisodeSpec,
    kind: ArmKind,
    endpoint: str,
    *,
    watchdog: float = DEFAULT_WATCHDOG_S,
    wait: float = DEFAULT_WAIT_S,
    log: TextIO = sys.stderr,
    ready: Callable[[], object] | None = None,
) -> ServeStats:
    """Serve one episode of ``spec``'s world with carrier ``kind`` on ``endpoint``.

    Returns when the trajectory has ended; raises ``TimeoutError`` when no controller
    commanded anything within ``wait`` s. ``spec.policy`` is not used (the controller's).
    """
    import zenoh

    session = zenoh.open(zenoh_config(endpoint, listen=True))
    try:
        robot = Robot(config, spec, kind, session)
        inbox = _Inbox()
        # one subscriber, remote messages only: the commands in the order they were sent
        sub = session.declare_subscriber("**", inbox.callback, allowed_origin=zenoh.Locality.REMOTE)
        stats = _serve_loop(robot, inbox, watchdog, wait, log, ready)
        for _ in range(3):  # the end, said more than once: a late subscriber still hears it
            robot.publish(DISABLED, None)
            time.sleep(robot.dt)
        sub.undeclare()
    finally:
        session.close()
    return stats


def _serve_loop(
    robot: Robot,
    inbox: _Inbox,
    watchdog: float,
    wait: float,
    log: TextIO,
    ready: Callable[[], object] | None,
) -> ServeStats:
    stats = ServeStats()
    gate = CommandGate(robot.keys, JointCommand(robot.kind, robot.arm), robot.frames, robot.dt)
    mode = "waiting"
    if ready is not None:
        ready()
    robot.publish(ENABLED, None)
    t_wait_end = time.monotonic() + wait
    last_cmd = last_msg = time.monotonic()
    while not robot.done:
        timeout = max(0.0, last_cmd + watchdog - time.monotonic()) if mode == ENABLED else robot.dt
        try:
            key, data = inbox.q.get(timeout=timeout)
        except queue.Empty:
            if mode == "waiting":  # no controller yet: say the first state again
                if time.monotonic() > t_wait_end:
                    raise TimeoutError(
                        f"no controller commanded the robot within {wait:g} s"
                    ) from None
                robot.publish(ENABLED, None)
                continue
            if mode == ENABLED:
                mode = PAUSED
                stats.watchdog_trips += 1
                t = robot.k * robot.dt
                print(
                    f"robot: watchdog: no command for {watchdog:g} s at t = {t:.3f} s: "
                    f"servoing stopped, holding (last message "
                    f"{time.monotonic() - last_msg:.3f} s ago)",
                    file=log,
                )
            robot.hold()
            stats.held += 1
            continue
        last_msg = time.monotonic()
        verdict, cmd, why = gate.admit(key, data, robot.k)
        if verdict is Verdict.REFUSED:
            stats.refused.append(why)
            print(f"robot: refused a message on {why}", file=log)
            continue
        if verdict is Verdict.DROPPED:
            stats.dropped += 1  # late, duplicated or reordered: never acted on
            continue
        if cmd is None:
            continue  # a part of a command, or not a command of this robot
        if mode == PAUSED:
            print(f"robot: command at t = {robot.k * robot.dt:.3f} s: servoing resumed", file=log)
        mode = ENABLED
        robot.step(cmd.T_world_cmd, cmd.look, cmd.twist, ENABLED)
        stats.commanded += 1
        last_cmd = time.monotonic()
    stats.steps = robot.k
    return stats
