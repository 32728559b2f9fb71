"""The data of the control loop: what a policy sees, what it commands, and its state.

Every pose is a (4, 4) ``T_world_*`` ndarray at this boundary (``docs/conventions.md``); the
policies work on plain floats inside (:mod:`endocam.kernels`).
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple, Protocol

import numpy as np

from endocam.camera import StereoCamera
from endocam.geometry import FloatArray
from endocam.task.config import RingConfig
from endocam.task.wire import Wire

__all__ = [
    "CameraCommand",
    "CameraPolicy",
    "Observation",
    "PolicyContext",
    "TrackingState",
]


class TrackingState(enum.Enum):
    """What a policy is doing this control step."""

    HOLDING = "holding"  # deliberately still (the fixed camera)
    TRACKING = "tracking"  # moving to the goal
    PLANNING = "planning"  # following intermediate way-points around a goal jump
    FROZEN_OUTSIDE_CONE = "frozen_outside_cone"  # goal left the cone workspace; pose held
    LOST_TRACKING = "lost_tracking"  # no valid feature observation; last safe pose held


@dataclass(frozen=True)
class PolicyContext:
    """What a policy is told at ``reset``.

    Attributes
    ----------
    camera : StereoCamera
        The stereo camera (intrinsics, baseline).
    T_world_cam : (4, 4)
        Initial camera pose (the fixed condition's whole-task view), optical frame, m.
    T_world_ring : (4, 4)
        The ring pose at initialisation, m (gives the cone axis).
    p_world_rcm : (3,)
        Remote centre of motion of the camera arm = cone tip, m.
    dt : float
        Control period, s.
    sensing_latency : float
        How old the ring pose in each observation is, s (a tracker may predict across it).
    future : callable or None
        The true ring trajectory, for non-causal reference controllers (the ``oracle``):
        ``future(t)`` maps times (N,), s, to true ring poses ``T_world_ring`` (N, 4, 4), world,
        m, undelayed, clamped to ``[0, future_duration]``. Causal policies ignore it.
    future_duration : float
        The span ``future`` covers (the episode's length), s; 0 without a future.
    follows_twist : bool
        Whether the carrier uses a command's velocity (``CameraCommand.twist``); when it does
        not (a dVRK arm), a policy may leave ``twist`` ``None`` rather than compute it.
    wire : Wire or None
        The structure the camera must keep ``ControllerConfig.wire_clearance`` from: a
        pre-operative model (centre line and radius, world, m), as a real system has from
        planning images. ``None``: no model, no clearance constraint.
    ring : RingConfig or None
        The ring's geometry (radii, handle): a known instrument. ``None``: the default ring
        (``RingConfig()``). The ``endocam-visible`` camera judges what the rim hides with it.
    """

    camera: StereoCamera
    T_world_cam: FloatArray
    T_world_ring: FloatArray
    p_world_rcm: FloatArray
    dt: float
    sensing_latency: float = 0.0
    future: Callable[[FloatArray], FloatArray] | None = None
    future_duration: float = 0.0
    follows_twist: bool = True
    wire: Wire | None = None
    ring: RingConfig | None = None


_NO_TIPS = np.zeros((0, 3))
_NO_TIPS.setflags(write=False)


class Observation(NamedTuple):
    """What a policy sees each control step (immutable; a named tuple: cheap per step).

    Attributes
    ----------
    t : float
        Time, s.
    T_world_ring : (4, 4) or None
        Sensed ring pose (ring z = face normal), m; ``None`` or non-finite when tracking is lost.
    T_world_cam : (4, 4)
        Measured camera pose, optical frame, m.
    p_world_tips : (K, 3)
        Instrument tip positions in world, m.
    p_world_reach_offset : (3,) or None
        How far the actuator's target for the previous command lies from that command's
        position, m (world): non-zero when an arm concedes a goal it cannot reach (the
        nearest feasible view). The way-point planner measures the camera's progress against
        where the actuator can put it; ``None``: the actuator reaches what it is sent.
    t_ring : float or None
        When the ring pose was captured, s (the tracker's stamp, on the clock of ``t``). A pose
        older than ``ControllerConfig.ring_max_age`` (a frozen tracker re-sending its last
        pose, a long delay) or stamped in the future is not acted on: the camera holds
        (``lost_tracking``). ``None``: no stamp, the age is not checked.
    """

    t: float
    T_world_ring: FloatArray | None
    T_world_cam: FloatArray
    p_world_tips: FloatArray = _NO_TIPS
    p_world_reach_offset: FloatArray | None = None
    t_ring: float | None = None


class CameraCommand(NamedTuple):
    """A policy's output: the camera pose to move to, and why (immutable named tuple).

    Attributes
    ----------
    T_world_cam : (4, 4)
        Commanded camera pose, optical frame, m.
    state : TrackingState
    d_f : float
        Working distance in use, m.
    reason : str
        One line for the log when the state is not plain tracking.
    twist : (6,) or None
        Velocity of the commanded pose: linear in world (m/s), then angular in world (rad/s).
        A carrier that supports it arrives moving with it (no lag on steady motion);
        ``None``: arrive at rest.
    """

    T_world_cam: FloatArray
    state: TrackingState
    d_f: float
    reason: str = ""
    twist: FloatArray | None = None


class CameraPolicy(Protocol):
    """The interface every camera policy implements."""

    name: str

    def reset(self, context: PolicyContext) -> None:
        """Start an episode."""

    def step(self, obs: Observation) -> CameraCommand:
        """One control step: map an observation to a camera command."""
