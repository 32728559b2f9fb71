"""The arm interface in CRTK terms, and a simulated arm driven by ruckig.

CRTK (Collaborative Robotics Toolkit) names the commands a real dVRK arm accepts; the
:class:`CrtkArm` protocol uses the same names so that a thin adapter around the dVRK Python
client can stand in for :class:`SimulatedArm` (see ``docs/robot.md``):

- ``measured_js() -> (q, qd)``: measured joint positions (rad / m) and velocities;
- ``measured_cp() -> T_base_tip``: measured tool-tip pose, (4, 4), m;
- ``servo_jp(q)``: joint set point, streamed every control cycle;
- ``servo_cp(T_base_tip)``: Cartesian set point, streamed every control cycle;
- ``move_jp(q)``: joint goal, the arm plans the motion to rest there.

Frames. The dVRK reports ``measured_cp`` relative to the arm's base frame; for a PSM or ECM
without a configured base frame that is the RCM frame (the dVRK's ``local/measured_cp`` is
always RCM-relative). :class:`SimulatedArm` follows this: poses are ``T_rcm_tip`` unless a
``T_base_rcm`` is given, in which case ``measured_cp`` returns and ``servo_cp`` takes
``T_base_tip = T_base_rcm · T_rcm_tip``.
"""

from __future__ import annotations

import enum
import math
import operator
from typing import Protocol, runtime_checkable

import numpy as np
import ruckig

from endocam.geometry import FloatArray, as_finite_array, as_pose, invert_pose
from endocam.robot.ecm import ECM
from endocam.robot.ik import IKResult, IKStatus
from endocam.robot.kinematics import LIMIT_SLACK, RcmArm
from endocam.robot.psm import PSM

__all__ = [
    "ECM_MAX_ACCELERATION",
    "ECM_MAX_VELOCITY",
    "PSM_MAX_ACCELERATION",
    "PSM_MAX_VELOCITY",
    "CrtkArm",
    "MotionStatus",
    "SimulatedArm",
    "UnreachablePolicy",
]


# Joint trajectory limits: the dVRK's own defaults for its joint trajectories (Reflexxes), set in
# the arm classes' Init() of jhu-dvrk/sawIntuitiveResearchKit (components/code/
# mtsIntuitiveResearchKitPSM.cpp and mtsIntuitiveResearchKitECM.cpp, commits 02d4b7cf and
# 94060de4; docs/robot.md). rad/s, rad/s² (m/s, m/s² for insertion).
# PSM: yaw/pitch 180°/s and 180°/s², insertion 0.2 m/s and 0.2 m/s², roll and wrist
# 3·360°/s and 2·360°/s².
PSM_MAX_VELOCITY = (math.pi, math.pi, 0.2, 6.0 * math.pi, 6.0 * math.pi, 6.0 * math.pi)
PSM_MAX_ACCELERATION = (math.pi, math.pi, 0.2, 4.0 * math.pi, 4.0 * math.pi, 4.0 * math.pi)
# ECM: yaw/pitch 30°/s and 30°/s², insertion 0.05 m/s and 0.05 m/s², roll 20°/s and 30°/s².
ECM_MAX_VELOCITY = (math.radians(30.0), math.radians(30.0), 0.05, math.radians(20.0))
ECM_MAX_ACCELERATION = (math.radians(30.0), math.radians(30.0), 0.05, math.radians(30.0))
RETRY_VELOCITY_SHRINK = 1e-12  # unitless, relative velocity change of a retried cycle


@runtime_checkable
class CrtkArm(Protocol):
    """What a control loop needs from an arm, in CRTK's names (SI units)."""

    def measured_js(self) -> tuple[FloatArray, FloatArray]:
        """Measured joint positions and velocities, each (n,), rad(/s) or m(/s)."""
        ...

    def measured_cp(self) -> FloatArray:
        """Measured tool-tip pose in the arm's base frame (the RCM by default), (4, 4), m."""
        ...

    def servo_jp(self, q: FloatArray) -> object:
        """Stream a joint position set point, (n,), rad / m."""
        ...

    def servo_cp(self, T_base_tip: FloatArray) -> object:
        """Stream a Cartesian set point, (4, 4), base frame, m."""
        ...

    def move_jp(self, q: FloatArray) -> object:
        """Move to a joint goal, (n,), rad / m, along a planned trajectory."""
        ...


class MotionStatus(enum.Enum):
    """State of a carrier's motion after a step (the joint arm and the Cartesian limiter)."""

    FINISHED = "finished"
    """At the set point and at rest."""
    MOVING = "moving"
    """Moving towards the set point within the velocity / acceleration limits."""
    LIMIT_STOP = "limit_stop"
    """A joint would have crossed its position limit and was stopped hard at it."""
    REJECTED = "rejected"
    """The target was not finite; still heading for the last valid one."""


class UnreachablePolicy(enum.Enum):
    """What ``servo_cp`` does with a pose the arm cannot reach exactly."""

    APPROACH_NEAREST = "approach_nearest"
    """Move to the nearest feasible configuration the IK returns."""
    HOLD = "hold"
    """Keep the previous set point."""


def _default_limits(model: RcmArm) -> tuple[tuple[float, ...], tuple[float, ...]]:
    if isinstance(model, PSM):
        return PSM_MAX_VELOCITY, PSM_MAX_ACCELERATION
    if isinstance(model, ECM):
        return ECM_MAX_VELOCITY, ECM_MAX_ACCELERATION
    raise ValueError("max_velocity, max_acceleration: required for this model")


def _positive_vector(x: object, name: str, n: int, allow_inf: bool = False) -> FloatArray:
    try:
        arr = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: expected {n} positive numbers") from exc
    if arr.shape != (n,) or np.any(np.isnan(arr)) or np.any(arr <= 0.0):
        raise ValueError(f"{name}: expected {n} positive numbers")
    if not allow_inf and not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: must be finite")
    return arr


def _finite_floats(x: object, n: int) -> list[float] | None:
    """``x`` as n finite floats, or None if it is anything else (fast path of servo_jp)."""
    if isinstance(x, np.ndarray):
        if x.shape != (n,):
            return None
        values = x.tolist()
    elif isinstance(x, list | tuple) and len(x) == n:
        values = x  # (read only: the floats below are a new list)
    else:
        return None
    try:
        out = [float(v) for v in values]
    except (TypeError, ValueError):
        return None
    return out if all(map(math.isfinite, out)) else None


class SimulatedArm:
    """A kinematic arm (PSM or ECM) whose joints follow set points under ruckig limits.

    Every :meth:`step` runs one ruckig online-trajectory update (control cycle ``dt``) from
    the current joint state towards the set point, with per-joint velocity, acceleration
    and (optional) jerk limits. Set points are clipped into the joint position limits before
    they reach ruckig, and the new state is clipped again (hard stop, status
    ``LIMIT_STOP``) should a motion ever overshoot, so the joints never leave their limits.

    Parameters
    ----------
    model : RcmArm
        Kinematic model, e.g. ``PSM()`` or ``ECM()``.
    dt : float
        Control cycle, s (> 0).
    max_velocity, max_acceleration : (n,) array_like, optional
        Joint limits, rad/s and rad/s² (m/s, m/s² for prismatic joints). Defaults:
        ``PSM_MAX_*`` / ``ECM_MAX_*`` for those models.
    max_jerk : (n,) array_like, optional
        Jerk limits, rad/s³ or m/s³; default unlimited (acceleration-limited profiles).
    q0 : (n,) array_like, optional
        Initial joint positions (clipped into the limits), default zero clipped.
    T_base_rcm : (4, 4) array_like, optional
        Pose of the RCM in the arm's base frame; default identity (poses are ``T_rcm_tip``).
    unreachable : UnreachablePolicy
        Behaviour of :meth:`servo_cp` for unreachable poses.
    """

    def __init__(
        self,
        model: RcmArm,
        dt: float = 1e-3,
        max_velocity: object | None = None,
        max_acceleration: object | None = None,
        max_jerk: object | None = None,
        q0: object | None = None,
        T_base_rcm: object | None = None,
        unreachable: UnreachablePolicy = UnreachablePolicy.APPROACH_NEAREST,
    ) -> None:
        if not (isinstance(dt, float | int) and np.isfinite(dt) and dt > 0.0):
            raise ValueError("dt: must be a positive finite number of seconds")
        n = model.n_joints
        if max_velocity is None or max_acceleration is None:
            v_default, a_default = _default_limits(model)
            max_velocity = v_default if max_velocity is None else max_velocity
            max_acceleration = a_default if max_acceleration is None else max_acceleration
        self._model = model
        self._dt = float(dt)
        self._max_velocity = _positive_vector(max_velocity, "max_velocity", n)
        self._max_acceleration = _positive_vector(max_acceleration, "max_acceleration", n)
        jerk = np.full(n, np.inf) if max_jerk is None else max_jerk
        self._max_jerk = _positive_vector(jerk, "max_jerk", n, allow_inf=True)
        if T_base_rcm is None:
            self._T_base_rcm: FloatArray | None = None
            self._T_rcm_base: FloatArray | None = None
        else:
            self._T_base_rcm = as_pose(T_base_rcm, "T_base_rcm")
            self._T_rcm_base = invert_pose(self._T_base_rcm)
        self._unreachable = unreachable
        self._lower = model.lower.tolist()
        self._upper = model.upper.tolist()

        self._otg = ruckig.Ruckig(n, self._dt)
        self._inp = ruckig.InputParameter(n)
        self._out = ruckig.OutputParameter(n)
        self._inp.max_velocity = self._max_velocity.tolist()
        self._inp.max_acceleration = self._max_acceleration.tolist()
        self._inp.max_jerk = self._max_jerk.tolist()
        self._line = False  # the last set point's synchronisation: phase (line) or time
        # the community ruckig accepts but does not enforce these; the clamp below does
        self._inp.min_position = self._lower
        self._inp.max_position = self._upper
        self._inp.target_velocity = [0.0] * n
        self._inp.target_acceleration = [0.0] * n

        self._time = 0.0
        self._motion_status = MotionStatus.FINISHED
        self._command_status = IKStatus.OK
        self._last_ik: IKResult | None = None
        q_init = model.default_seed() if q0 is None else model.check_q(q0, "q0")
        self.reset(q_init)

    # ------------------------------------------------------------------ state
    @property
    def model(self) -> RcmArm:
        """The kinematic model."""
        return self._model

    @property
    def dt(self) -> float:
        """Control cycle, s."""
        return self._dt

    @property
    def time(self) -> float:
        """Simulated time since construction / reset, s."""
        return self._time

    @property
    def motion_status(self) -> MotionStatus:
        """Status of the last :meth:`step`."""
        return self._motion_status

    @property
    def command_status(self) -> IKStatus:
        """Status of the last command: ``OK``, ``CLAMPED_TO_LIMITS`` or ``UNREACHABLE``."""
        return self._command_status

    @property
    def last_ik(self) -> IKResult | None:
        """IK result of the last :meth:`servo_cp`, if any."""
        return self._last_ik

    def reset(self, q: object, qd: object | None = None) -> None:
        """Place the arm at ``q`` (clipped into limits) with velocity ``qd`` (default 0).

        Parameters
        ----------
        q : (n,) array_like
            Joint positions, rad / m.
        qd : (n,) array_like, optional
            Joint velocities, rad/s or m/s.
        """
        n = self._model.n_joints
        q_arr = self._model.clamp(self._model.check_q(q, "q"))
        qd_arr = np.zeros(n) if qd is None else as_finite_array(qd, "qd", (n,))
        self._q = q_arr
        self._qd = qd_arr.copy()
        self._qdd = np.zeros(n)
        self._inp.current_position = q_arr.tolist()
        self._inp.current_velocity = qd_arr.tolist()
        self._inp.current_acceleration = [0.0] * n
        self._target = q_arr.copy()
        self._inp.target_position = q_arr.tolist()
        self._time = 0.0
        self._motion_status = MotionStatus.FINISHED

    # ------------------------------------------------------------------ CRTK: measured
    def measured_js(self) -> tuple[FloatArray, FloatArray]:
        """Joint positions and velocities, each (n,), rad(/s) or m(/s) (copies)."""
        return self._q.copy(), self._qd.copy()

    def state_view(self) -> tuple[FloatArray, FloatArray]:
        """Joint positions and velocities, each (n,), rad(/s) or m(/s), without a copy.

        The arrays are replaced, never written, as the arm moves: a caller may keep them as a
        snapshot of this state but must not write them.
        """
        return self._q, self._qd

    def measured_jp(self) -> FloatArray:
        """Joint positions, (n,), rad / m (a copy; CRTK's position-only ``measured_jp``)."""
        return self._q.copy()

    def measured_ja(self) -> FloatArray:
        """Joint accelerations, (n,), rad/s² or m/s² (simulation only)."""
        return self._qdd.copy()

    def measured_cp(self) -> FloatArray:
        """Tool-tip pose, (4, 4), m: ``T_rcm_tip``, or ``T_base_tip`` with a base frame."""
        T = self._model.forward(self._q)
        return T if self._T_base_rcm is None else self._T_base_rcm @ T

    def setpoint_js(self) -> FloatArray:
        """Current joint set point (within limits), (n,), rad / m."""
        return self._target.copy()

    # ------------------------------------------------------------------ CRTK: commands
    def servo_jp(self, q: object, line: bool = False) -> IKStatus:
        """Set the joint set point; clipped into the joint limits.

        Parameters
        ----------
        q : (n,) array_like
            Joint positions, rad / m.
        line : bool
            Move along the straight joint-space line to ``q`` (ruckig's phase synchronisation,
            when the current velocity allows it: from rest always); default: time-synchronised
            joints (they arrive together, each on its own profile, off the line on the way).

        Returns
        -------
        IKStatus
            ``OK``, or ``CLAMPED_TO_LIMITS`` if ``q`` was outside the limits.
        """
        values = _finite_floats(q, self._model.n_joints)
        if values is None:  # raises a ValueError naming the argument
            values = self._model.check_q(q, "q").tolist()
        clipped, inside = self._model.clamp_floats(values)
        status = IKStatus.OK if inside else IKStatus.CLAMPED_TO_LIMITS
        self._target = np.array(clipped)
        self._inp.target_position = clipped
        if line is not self._line:
            self._line = line
            self._inp.synchronization = (
                ruckig.Synchronization.Phase if line else ruckig.Synchronization.Time
            )
        self._command_status = status
        return status

    def move_jp(self, q: object) -> IKStatus:
        """Move to a joint goal (planned to rest by ruckig); see :meth:`servo_jp`.

        In simulation the two differ only in intent: ``move_jp`` is sent once and the arm
        settles (``motion_status`` becomes ``FINISHED``), ``servo_jp`` is streamed.
        """
        return self.servo_jp(q)

    def servo_cp(self, T_base_tip: object) -> IKResult:
        """Set a Cartesian set point via IK (seeded by the current set point).

        Parameters
        ----------
        T_base_tip : (4, 4) array_like
            Goal tip pose in the arm's base frame (the RCM frame by default), m.

        Returns
        -------
        IKResult
            The IK outcome. With ``UnreachablePolicy.APPROACH_NEAREST`` the set point becomes
            ``result.q`` (nearest feasible); with ``HOLD`` a non-OK result keeps the previous
            set point.
        """
        T = as_pose(T_base_tip, "T_base_tip")
        T_rcm_tip = T if self._T_rcm_base is None else self._T_rcm_base @ T
        result = self._model.solve_unchecked(T_rcm_tip, self._target)
        self._last_ik = result
        self._command_status = result.status
        if result.ok or self._unreachable is UnreachablePolicy.APPROACH_NEAREST:
            self._set_target(result.q)
        return result

    def _set_target(self, target: FloatArray) -> None:
        self._target = target
        self._inp.target_position = target.tolist()

    def _retry(self, inp: ruckig.InputParameter, out: ruckig.OutputParameter) -> object:
        """Retry a cycle ruckig refused, the current velocity shrunk by ``RETRY_VELOCITY_SHRINK``.

        Ruckig's profile search fails on rare states whose braking distance equals the distance
        to the target to the last bits (found by the fault property test: the ECM, fault seed
        368, joint 0 at −0.246 rad/s, 0.058 rad before its target). A relative change of 1e-12
        (here 2.5e-13 rad/s) is the same state physically; a second failure is raised.
        """
        inp.current_velocity = [v * (1.0 - RETRY_VELOCITY_SHRINK) for v in inp.current_velocity]
        return self._otg.update(inp, out)

    # ------------------------------------------------------------------ simulation
    def step(self, dt: float | None = None) -> MotionStatus:
        """Advance the joints by ``dt`` (a whole number of control cycles; default one).

        Parameters
        ----------
        dt : float, optional
            Time to advance, s; must be a positive multiple of the control cycle.

        Returns
        -------
        MotionStatus
            Status after the last cycle (``LIMIT_STOP`` if any cycle hit a hard stop).
        """
        if dt is None:  # one control cycle (the control loop's case)
            if self._cycle():
                self._motion_status = MotionStatus.LIMIT_STOP
            return self._motion_status
        else:
            ratio = dt / self._dt if np.isfinite(dt) else np.nan
            cycles = round(ratio) if np.isfinite(ratio) else 0
            if cycles < 1 or abs(ratio - cycles) > 1e-9 * max(1.0, ratio):
                raise ValueError(f"dt: must be a positive multiple of the cycle {self._dt} s")
        hit = False
        for _ in range(cycles):
            hit = self._cycle() or hit
        if hit:
            self._motion_status = MotionStatus.LIMIT_STOP
        return self._motion_status

    def _cycle(self) -> bool:
        inp, out = self._inp, self._out
        try:
            result = self._otg.update(inp, out)
        except ruckig.RuckigError:
            result = self._retry(inp, out)
        if result not in (ruckig.Result.Working, ruckig.Result.Finished):
            raise RuntimeError(f"ruckig failed: {result}")
        pos = out.new_position  # (the binding returns a new list each time)
        vel = out.new_velocity
        acc = out.new_acceleration
        hit = False
        rounded = False
        within = all(map(operator.le, self._lower, pos)) and all(map(operator.le, pos, self._upper))
        if not within:  # (within the limits, the usual case, there is nothing to clip)
            for i, (lo, hi) in enumerate(zip(self._lower, self._upper, strict=True)):
                if pos[i] < lo or pos[i] > hi:
                    overshoot = lo - pos[i] if pos[i] < lo else pos[i] - hi
                    pos[i] = lo if pos[i] < lo else hi
                    if overshoot <= LIMIT_SLACK:  # ruckig round-off when arriving at a limit
                        rounded = True
                        continue
                    vel[i] = 0.0
                    acc[i] = 0.0
                    hit = True
        if hit or rounded:
            inp.current_position = pos
            inp.current_velocity = vel
            inp.current_acceleration = acc
        else:
            out.pass_to_input(inp)
        self._q = np.array(pos)
        self._qd = np.array(vel)
        self._qdd = np.array(acc)
        self._time += self._dt
        if hit:
            self._motion_status = MotionStatus.LIMIT_STOP
        elif result == ruckig.Result.Finished:
            self._motion_status = MotionStatus.FINISHED
        else:
            self._motion_status = MotionStatus.MOVING
        return hit
