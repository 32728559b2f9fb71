"""``endocam robot serve``: the simulated arm and the wire-chaser world as a robot process.

It speaks CRTK over Zenoh (:mod:`endocam.link.messages`): it publishes the state of every
control step and follows ``servo_cp`` through the same carrier (and so the same joint limits,
workspace guard and speed limits) as an in-process episode.

**Time is lock-stepped to the commands.** The simulation advances one control period for each
accepted command — the one stamped with the state it answers — so the same controller gives
the same episode over the link as in-process, whatever the network's timing. Commands stamped
for another step (late, duplicated, reordered) are dropped, never acted on out of order.

**Watchdog.** When no acceptable command arrives for ``watchdog`` seconds (wall clock) the
robot stops servoing (``operating_state`` ``PAUSED``): it commands its own camera pose at rest,
one control period per wall period, so the carrier brakes within its limits and holds while
the world moves on. A command answering the current state resumes servoing (``ENABLED``).

**Refused.** A payload that does not decode as the message of its topic, a non-finite pose,
twist or look distance, a quaternion not of unit length, a look distance ≤ 0 or beyond
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
from typing import Any, TextIO

import numpy as np

from endocam.config import ExperimentConfig
from endocam.geometry import FloatArray
from endocam.link.messages import DISABLED, ENABLED, PAUSED, Codec, Keys, stamp_ns
from endocam.link.world import link_world, zenoh_config
from endocam.robot.actuator import ActuatorStatus, ActuatorStep, ArmKind, GuardAction
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

    lw = link_world(config, spec)
    world = lw.world
    warm = start_carrier(config, kind, lw.camera, lw.wire, world)  # compiles the kernels now,
    warm.actuator.step(warm.T_world_cam, config.controller.d_f)  # not on the first command
    carrier = start_carrier(config, kind, lw.camera, lw.wire, world)
    arm = carrier.actuator
    names = arm.joint_names
    dt = 1.0 / config.episode.control_rate
    keys = Keys.of(kind)
    codec = Codec()
    stats = ServeStats()
    inbox = _Inbox()
    session = zenoh.open(zenoh_config(endpoint, listen=True))
    try:
        pub = {
            k: session.declare_publisher(k, congestion_control=zenoh.CongestionControl.BLOCK)
            for k in (*keys[:4], keys.ring, keys.tip1, keys.tip2, keys.servo_result)
        }
        # one subscriber, remote messages only: the commands in the order they were sent
        sub = session.declare_subscriber("**", inbox.callback, allowed_origin=zenoh.Locality.REMOTE)
        T_cam, q = carrier.T_world_cam, arm.q
        look_last = float(config.controller.d_f)

        def publish(k: int, state: str, out: ActuatorStep | None) -> None:
            ns = stamp_ns(k * dt)  # = world.t[k] for k < n; the end is stamped n · dt
            if out is not None:
                pub[keys.servo_result].put(codec.array(servo_result(out)))
                pub[keys.setpoint_cp].put(codec.pose(out.T_world_target, ns))
            if k < world.n:
                pub[keys.measured_js].put(codec.joints(names, q, ns))
                pub[keys.ring].put(
                    codec.pose(world.T_world_ring_sensed[k], stamp_ns(world.t_ring[k]))
                )
                pub[keys.tip1].put(codec.point(world.p_world_tips[k, 0], ns))
                pub[keys.tip2].put(codec.point(world.p_world_tips[k, 1], ns))
                pub[keys.measured_cp].put(codec.pose(T_cam, ns))
            pub[keys.operating_state].put(codec.operating_state(state, k < world.n, ns))  # last

        if ready is not None:
            ready()
        k, mode, out = 0, "waiting", None
        pending: dict[str, Any] = {}
        t_wait_end = time.monotonic() + wait
        last_cmd = time.monotonic()
        publish(0, ENABLED, None)
        while k < world.n:
            now = time.monotonic()
            if mode == "waiting":
                timeout = dt
            elif mode == ENABLED:
                timeout = max(0.0, last_cmd + watchdog - now)
            else:
                timeout = dt
            try:
                key, data = inbox.q.get(timeout=timeout)
            except queue.Empty:
                if mode == "waiting":
                    if time.monotonic() > t_wait_end:
                        raise TimeoutError(f"no controller commanded the robot within {wait:g} s")
                    publish(0, ENABLED, None)
                    continue
                if mode == ENABLED:
                    mode = PAUSED
                    stats.watchdog_trips += 1
                    print(
                        f"robot: watchdog: no command for {watchdog:g} s at t = {world.t[k]:.3f} s:"
                        " servoing stopped, holding",
                        file=log,
                    )
                out = arm.step(T_cam, look_last, None)  # hold: the carrier brakes to rest
                T_cam, q = out.T_world_cam, out.q
                k += 1
                stats.steps += 1
                stats.held += 1
                publish(k, PAUSED if k < world.n else DISABLED, out)
                continue
            ns_now = stamp_ns(float(world.t[k]))
            if key not in (LOOK_KEY, keys.servo_cv, keys.servo_cp):
                continue  # not a command of this robot
            try:
                if key == LOOK_KEY:
                    look = codec.decode_float64(data)
                    if not (math.isfinite(look) and 0.0 < look <= MAX_LOOK_M):
                        raise ValueError(f"look distance {look!r} m outside (0, {MAX_LOOK_M}]")
                    pending["look"] = look
                    continue
                if key == keys.servo_cv:
                    v, ns = codec.decode_twist(data)
                    pending["twist"] = (v, ns)
                    continue
                T_goal, ns = codec.decode_pose(data)
            except ValueError as exc:
                stats.refused.append(f"{key}: {exc}")
                print(f"robot: refused a message on {key}: {exc}", file=log)
                pending.clear()
                continue
            if ns != ns_now or "look" not in pending:
                stats.dropped += 1
                pending.clear()
                continue
            twist_ns = pending.get("twist")
            twist = twist_ns[0] if twist_ns is not None and twist_ns[1] == ns else None
            look_last = float(pending["look"])
            pending.clear()
            if mode == PAUSED:
                print(f"robot: command at t = {world.t[k]:.3f} s: servoing resumed", file=log)
            mode = ENABLED
            out = arm.step(T_goal, look_last, twist)
            T_cam, q = out.T_world_cam, out.q
            last_cmd = time.monotonic()
            k += 1
            stats.steps += 1
            stats.commanded += 1
            publish(k, ENABLED if k < world.n else DISABLED, out)
        for _ in range(3):  # the end, said more than once: a late subscriber still hears it
            publish(world.n, DISABLED, None)
            time.sleep(dt)
        sub.undeclare()
    finally:
        session.close()
    return stats
