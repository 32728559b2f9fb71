"""One control step of an episode, shared by the runner and the Gymnasium env.

An episode's world (the ring's trajectory, what the camera senses of it, the instrument tips)
does not depend on the camera, so it is computed for every control step up front
(:class:`EpisodeWorld`). :class:`EpisodeLoop` then advances one control period at a time:
given a command (a camera pose to head for, the working distance it was planned at and an
optional velocity) it tells the carrier where to go and what the command looks at, and returns
a named :class:`StepRecord` (the log's row). The episode runner's policy supplies the command
in :func:`endocam.runner.episode.run_episode`; the environment's agent supplies it (a set point
moved by the action) in :class:`endocam.envs.wire_chaser.WireChaserEnv`. Both therefore tell the
carrier the same things.

What the controller senses of the ring comes from a :class:`RingSource` the loop asks each
step: :class:`TruthSource` (the world's delayed true pose, the default) or the stereo
estimator's ``endocam.runner.ring_source.StereoSource`` (``perception.source = "stereo"``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple, Protocol

import numpy as np

from endocam.camera import StereoCamera
from endocam.config import ExperimentConfig
from endocam.control.types import Observation
from endocam.faults import StepFaults
from endocam.geometry import FloatArray
from endocam.robot.actuator import Actuator, ActuatorStep, ArmKind
from endocam.robot.carriers import make_actuator
from endocam.task.instruments import instrument_tips
from endocam.task.trajectory import RingTrajectory, capture_times
from endocam.task.wire import Wire
from endocam.view import look_distance
from endocam.workspace.region import Workspace


@dataclass(frozen=True)
class EpisodeWorld:
    """What happens around the camera, per control step (N steps), SI; world frame.

    Attributes
    ----------
    t : (N,)
        Time, s (``k / control_rate``).
    T_world_ring : (N, 4, 4)
        True ring pose (ring z = face normal), m.
    t_ring : (N,)
        When the ring pose the camera senses at ``t`` was captured, s.
    T_world_ring_sensed : (N, 4, 4)
        The sensed ring pose (the pose at ``t_ring``), m.
    p_world_tips : (N, 2, 3)
        PSM1 and PSM2 tip positions, m.
    """

    t: FloatArray
    T_world_ring: FloatArray
    t_ring: FloatArray
    T_world_ring_sensed: FloatArray
    p_world_tips: FloatArray

    @property
    def n(self) -> int:
        """Number of control steps."""
        return len(self.t)


def control_step_count(duration: float, dt: float) -> int:
    """Control steps of an episode ``duration`` s long at period ``dt`` s: ``t = 0, dt, ...``.

    The last step is at or (by less than 1e-9 of a step, round-off) before ``duration``.
    """
    return math.floor(duration / dt + 1e-9) + 1


def episode_world(config: ExperimentConfig, trajectory: RingTrajectory) -> EpisodeWorld:
    """The world of an episode on ``trajectory``: one row per control step of its duration."""
    ep = config.episode
    dt = 1.0 / ep.control_rate
    n = control_step_count(trajectory.duration, dt)
    t = np.arange(n, dtype=float) * dt
    T_ring = trajectory.poses(t)
    t_ring = capture_times(t, ep.sensing_latency)
    return EpisodeWorld(
        t=t,
        T_world_ring=T_ring,
        t_ring=t_ring,
        T_world_ring_sensed=trajectory.poses(t_ring),
        p_world_tips=instrument_tips(config.task, t, T_ring),
    )


class Carrier(NamedTuple):
    """A camera carrier at the start of an episode.

    Attributes
    ----------
    actuator : Actuator
        The free camera, PSM or ECM, reset to its start view.
    workspace : Workspace
        The cone, floor and wire keep-out zone it keeps the camera in.
    T_world_cam : (4, 4)
        The camera pose it started at, world, optical frame, m.
    """

    actuator: Actuator
    workspace: Workspace
    T_world_cam: FloatArray


def start_carrier(
    config: ExperimentConfig,
    kind: ArmKind,
    camera: StereoCamera,
    wire: Wire,
    world: EpisodeWorld,
) -> Carrier:
    """Make the carrier ``kind`` of an episode and reset it to its view of the whole task.

    The workspace is the policy's cone and floor (the cone's apex at the port, aimed at the
    first sensed ring centre) and the wire's keep-out zone.
    """
    ep = config.episode
    p_rcm = np.array(config.task.scene.rcm_position)
    workspace = config.controller.workspace(p_rcm, world.T_world_ring_sensed[0][:3, 3], wire)
    dt = 1.0 / ep.control_rate
    actuator = make_actuator(
        kind, ep.limits, ep.T_tip_cam, config.task.scene.T_world_rcm, dt, workspace
    )
    T_now = actuator.reset(*actuator.start_view(config.task, camera))
    return Carrier(actuator, workspace, T_now)


class RingSource(Protocol):
    """What the controller senses of the ring, asked once or more per control step."""

    def sense(self, k: int, T_world_cam: FloatArray, q: FloatArray) -> tuple[FloatArray, float]:
        """The ring pose the controller has at step ``k`` and its capture stamp.

        ``T_world_cam`` (4, 4): the camera pose at the start of the step, world, m; ``q``
        (J,): the carrier's joints then (rad / m). Returns ``T_world_ring`` (4, 4), world, m
        (all NaN: nothing sensed yet) and ``t_ring``, s. Asking again for the same ``k`` gives
        the same answer.
        """
        ...


class TruthSource:
    """The world's sensed ring pose: the true pose ``sensing_latency`` late (faults applied)."""

    def __init__(self, world: EpisodeWorld) -> None:
        self._t_ring = world.t_ring.tolist()
        self._sensed = list(world.T_world_ring_sensed)

    def sense(self, k: int, T_world_cam: FloatArray, q: FloatArray) -> tuple[FloatArray, float]:
        """Row ``k`` of the world's sensed poses and stamps (the camera plays no part)."""
        return self._sensed[k], self._t_ring[k]


class Command(Protocol):
    """What :meth:`EpisodeLoop.step` reads of a command (a policy's ``CameraCommand`` is one)."""

    @property
    def T_world_cam(self) -> FloatArray:
        """The camera pose (4, 4) to head for, world, optical frame, m."""
        ...

    @property
    def d_f(self) -> float:
        """The working distance the command was planned at, m."""
        ...

    @property
    def twist(self) -> FloatArray | None:
        """Its velocity (6,), linear then angular, world, m/s and rad/s; ``None``: at rest."""
        ...


class SetPoint(NamedTuple):
    """A command that is not a policy's: the environment's set point.

    Attributes
    ----------
    T_world_cam : (4, 4)
        Camera pose to head for, world, optical frame, m.
    d_f : float
        Working distance, m (the look distance when the ring is not ahead of the set point).
    twist : (6,) or None
        Velocity of the set point (m/s, rad/s); ``None``: arrive at rest.
    """

    T_world_cam: FloatArray
    d_f: float
    twist: FloatArray | None = None


class StepRecord(NamedTuple):
    """What one control step did: the log's row.

    Attributes
    ----------
    k : int
        The step (its world row).
    T_world_cam : (4, 4)
        Camera pose at the start of the step (what its observation showed), m.
    q : (J,)
        The carrier's joints at the start of the step, rad / m (``(0,)`` without joints).
    look_distance : float
        The distance to the point the command looks at that the carrier was told, m.
    carrier : ActuatorStep
        The carrier's answer: the camera after the step, the target it heads for, its errors.
    """

    k: int
    T_world_cam: FloatArray
    q: FloatArray
    look_distance: float
    carrier: ActuatorStep


def told_look(command: Command, T_world_ring: FloatArray | None, jointed: bool) -> float:
    """The distance to the point ``command`` looks at, as a carrier is told it, m.

    A carrier with joints is told :func:`endocam.view.look_distance` of the sensed ring
    ``T_world_ring`` ((4, 4), world, m); one without joints pivots no view, and with no ring
    sensed (``None``) there is no point to look at: both are told the command's working
    distance ``d_f``. The episode loop and the link's
    controller (:func:`endocam.link.client.run_remote`) both use this rule.
    """
    if not jointed or T_world_ring is None:
        return command.d_f
    return look_distance(command.T_world_cam, T_world_ring, command.d_f)


def target_offset(out: ActuatorStep, command: Command, jointed: bool) -> FloatArray | None:
    """How far the carrier's target lay from ``command``, (3,) world, m; ``None`` without joints.

    The next observation's ``p_world_reach_offset``: the planner measures its progress against
    the view the carrier can reach, not the one it asked for.
    """
    if not jointed:
        return None
    return out.T_world_target[:3, 3] - command.T_world_cam[:3, 3]


class EpisodeLoop:
    """An episode's world and carrier, advanced one control period per :meth:`step`.

    Parameters
    ----------
    world : EpisodeWorld
    carrier : Carrier
        From :func:`start_carrier`.
    faults : StepFaults, optional
        In-loop fault injection (overruns, goals beyond reach, stalled joints).
    source : RingSource, optional
        What the controller senses of the ring; default :class:`TruthSource` of ``world``.

    Attributes
    ----------
    k : int
        The current step: the world row the next observation and command belong to.
    T_world_cam : (4, 4)
        The camera pose now, m.
    q : (J,)
        The carrier's joints now.
    """

    def __init__(
        self,
        world: EpisodeWorld,
        carrier: Carrier,
        faults: StepFaults | None = None,
        source: RingSource | None = None,
    ) -> None:
        self.world = world
        self.actuator = carrier.actuator
        self.faults = faults
        self.jointed = len(carrier.actuator.joint_names) > 0
        """A carrier with joints concedes views it cannot reach (and logs its joints)."""
        self.k = 0
        self.T_world_cam = carrier.T_world_cam
        self.q = carrier.actuator.q
        self.reach_offset: FloatArray | None = None
        """How far the carrier's last target lay from its command, m (``None`` without joints)."""
        self.source: RingSource = TruthSource(world) if source is None else source
        # per step: plain floats and row views made once
        self._t = world.t.tolist()
        self._tips = list(world.p_world_tips)

    @property
    def done(self) -> bool:
        """Whether every step of the world has been taken."""
        return self.k >= len(self._t)

    def observation(self) -> Observation:
        """What a policy sees at the current step (the sensed ring, the camera, the tips)."""
        k = self.k
        T_ring, t_ring = self.source.sense(k, self.T_world_cam, self.q)
        # Observation(...) without its Python-level __new__ (no checks): this runs every step
        return tuple.__new__(
            Observation,
            (self._t[k], T_ring, self.T_world_cam, self._tips[k], self.reach_offset, t_ring),
        )

    def step(self, command: Command) -> StepRecord:
        """One control period: the carrier heads for ``command``; the world moves on one row.

        The carrier is told the command's pose, its velocity and the distance to the point it
        looks at (:func:`endocam.view.look_distance` of the sensed ring, the source's; a
        carrier without joints pivots no view and is told ``d_f``).
        """
        k = self.k
        if k >= len(self._t):
            raise RuntimeError("the episode has ended")
        T_goal, twist = command.T_world_cam, command.twist
        jointed = self.jointed
        T_ring = self.source.sense(k, self.T_world_cam, self.q)[0] if jointed else None
        look = told_look(command, T_ring, jointed)
        if self.faults is None:
            out = self.actuator.step(T_goal, look, twist)
        else:
            out = self.actuator.step(*self.faults.command(k, T_goal, twist, look))
        self.reach_offset = target_offset(out, command, jointed)
        record = StepRecord(k, self.T_world_cam, self.q, look, out)
        self.T_world_cam, self.q = out.T_world_cam, out.q
        self.k = k + 1
        return record
