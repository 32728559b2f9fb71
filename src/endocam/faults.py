"""Fault injection: what a real tracker and a real dVRK get wrong, seeded, per control step.

The ``faults`` section of the experiment config (:class:`FaultsConfig`) gives each fault a rate
(bursts per second, a Poisson process) and a burst length; :func:`fault_schedule` draws, from
the section's seed, which control steps each fault covers (never before ``start_after``: the
cone is fixed from the first observation). The episode runner then

* rewrites the observations before the control loop (:func:`apply_observation_faults`): ring
  pose dropouts (missing), NaN or infinite poses, outliers (an offset and a turned normal), a frozen
  tracker (the same pose repeated), latency spikes (an older pose), tool-tip dropouts;
* and, in the loop, at one hook (:meth:`StepFaults.command`): control-step overruns (the
  carrier receives the command one step late), and on a camera arm a goal beyond the wrist or
  the insertion stroke and a joint that stalls (its setpoint frozen where it is).

Every step's active faults are logged (``fault`` column of ``episode.csv``, ``+``-joined,
empty without a fault). Without a configured fault the schedule is empty and the runner does no
extra work. This module is a leaf (numpy, pydantic): the config and the runner import it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from endocam.geometry import FloatArray
from endocam.task.trajectory import capture_times

_FROZEN = ConfigDict(frozen=True, extra="forbid")
MAX_RATE_HZ = 10.0  # bursts/s: more would be a permanent fault, not a burst
MAX_BURST_S = 10.0  # s: a longer burst is a dead sensor (use a shorter episode)


class FaultSpec(BaseModel):
    """One fault: bursts at ``rate`` per second, each ``burst`` long (0: off)."""

    model_config = _FROZEN

    rate: float = Field(0.0, ge=0.0, le=MAX_RATE_HZ, description="Bursts per second, 1/s.")
    burst: float = Field(0.1, gt=0.0, le=MAX_BURST_S, description="Burst length, s.")


class OutlierFault(FaultSpec):
    """Wrong ring poses: ``distance`` away in a random direction, the normal turned by ``angle``.

    Each burst draws one offset (world) and one axis in the ring's face (the ring's frame),
    so the observed centre is exactly ``distance`` and the observed normal exactly ``angle``
    off the true ones at every step of the burst.
    """

    distance: float = Field(1.0, ge=0.0, le=100.0, description="Position offset, m.")
    angle: float = Field(math.pi, ge=0.0, le=math.pi, description="Rotation offset, rad.")


class LatencyFault(FaultSpec):
    """Latency spikes: the ring pose arrives ``extra_delay`` later than usual."""

    extra_delay: float = Field(0.2, gt=0.0, le=5.0, description="Extra sensing delay, s.")


class ReachFault(FaultSpec):
    """Goals beyond the arm: past the insertion stroke by ``overshoot``, or the wrist turned π."""

    overshoot: float = Field(
        0.3, gt=0.0, le=10.0, description="How far past the command along its view, m."
    )


class FaultsConfig(BaseModel):
    """Which faults to inject (all off by default), and the seed of their schedule."""

    model_config = _FROZEN

    seed: int = Field(0, ge=0, le=2**32 - 1, description="Seed of the fault schedule.")
    start_after: float = Field(
        1.0,
        ge=0.0,
        le=600.0,
        description="No fault before this time, s (the cone is fixed from the first observation).",
    )
    ring_dropout: FaultSpec = Field(default_factory=FaultSpec, description="Ring pose missing.")
    ring_nan: FaultSpec = Field(default_factory=FaultSpec, description="A NaN in the ring pose.")
    ring_inf: FaultSpec = Field(
        default_factory=FaultSpec, description="An infinite value in the ring pose."
    )
    ring_outlier: OutlierFault = Field(
        default_factory=OutlierFault, description="Wild ring poses (metres or 180° away)."
    )
    tracker_frozen: FaultSpec = Field(
        default_factory=FaultSpec, description="The tracker repeats the same ring pose."
    )
    latency_spike: LatencyFault = Field(
        default_factory=LatencyFault, description="Extra sensing delay."
    )
    tip_dropout: FaultSpec = Field(
        default_factory=FaultSpec, description="Instrument tips missing (window rule)."
    )
    step_overrun: FaultSpec = Field(
        default_factory=FaultSpec,
        description="A control step comes late: the carrier receives the previous command.",
    )
    joint_stall: FaultSpec = Field(
        default_factory=FaultSpec,
        description="Camera arm only: one joint (drawn per burst) stalls where it is.",
    )
    goal_beyond_reach: ReachFault = Field(
        default_factory=ReachFault,
        description="Camera arm only: the command goes past the insertion stroke or the wrist.",
    )

    @property
    def any(self) -> bool:
        """Whether any fault is switched on."""
        return any(getattr(self, name).rate > 0.0 for name in FAULT_NAMES)


FAULT_NAMES = (
    "ring_dropout",
    "ring_nan",
    "ring_inf",
    "ring_outlier",
    "tracker_frozen",
    "latency_spike",
    "tip_dropout",
    "step_overrun",
    "joint_stall",
    "goal_beyond_reach",
)
"""Every fault, in the order of the ``fault`` column."""
ARM_FAULTS = frozenset({"joint_stall", "goal_beyond_reach"})
"""Faults of a camera arm (not drawn for the free camera)."""
STEP_FAULTS = frozenset({"step_overrun", "joint_stall", "goal_beyond_reach"})
"""Faults applied inside the control loop (:class:`StepFaults`)."""
OBSERVATION_INVALID_FAULTS = frozenset({"ring_dropout", "ring_nan", "ring_inf", "ring_outlier"})
"""Faults that make the step's ring observation invalid: the controller must hold."""


def fault_names(label: str) -> frozenset[str]:
    """The fault names of one ``fault`` cell (``a+b:2`` → ``{a, b}``)."""
    if not label:
        return frozenset()
    return frozenset(part.split(":")[0] for part in label.split("+"))


@dataclass(frozen=True)
class Burst:
    """One burst of one fault: steps ``[start, stop)`` and its random draw.

    Attributes
    ----------
    start, stop : int
        Control steps covered.
    draw : (4,) ndarray
        Uniform [0, 1) numbers of this burst (direction, axis, joint, variant).
    """

    start: int
    stop: int
    draw: FloatArray


@dataclass(frozen=True)
class FaultSchedule:
    """Which control steps each fault covers in one episode.

    Attributes
    ----------
    config : FaultsConfig
    bursts : dict of str to tuple of Burst
        Per active fault, its bursts in time order.
    n : int
        Control steps of the episode.
    """

    config: FaultsConfig
    bursts: dict[str, tuple[Burst, ...]]
    n: int

    @property
    def empty(self) -> bool:
        """Whether no step has a fault."""
        return not any(self.bursts.values())

    @property
    def steps_faulty(self) -> bool:
        """Whether any in-loop fault (:data:`STEP_FAULTS`) has a burst."""
        return any(self.bursts.get(name) for name in STEP_FAULTS)

    def mask(self, name: str) -> np.ndarray:
        """(n,) bool: steps covered by fault ``name``."""
        m = np.zeros(self.n, dtype=bool)
        for b in self.bursts.get(name, ()):
            m[b.start : b.stop] = True
        return m

    def labels(self) -> np.ndarray:
        """(n,) ``fault`` column: the active faults of each step, ``+``-joined ('' for none)."""
        parts: list[list[str]] = [[] for _ in range(self.n)]
        for name in FAULT_NAMES:
            for b in self.bursts.get(name, ()):
                tag = name
                if name == "joint_stall":
                    tag = f"{name}:{_stalled_joint(b)}"
                for k in range(b.start, b.stop):
                    parts[k].append(tag)
        return np.array(["+".join(p) for p in parts], dtype=object)


def fault_schedule(
    config: FaultsConfig, n: int, dt: float, *, arm: bool, joints: int = 0
) -> FaultSchedule:
    """Draw the bursts of every active fault over ``n`` control steps of ``dt`` seconds.

    Each fault has its own stream (seeded by ``config.seed`` and the fault's index), so
    switching one fault on or off leaves the others' bursts where they were.

    Parameters
    ----------
    config : FaultsConfig
    n : int
        Control steps.
    dt : float
        Control period, s.
    arm : bool
        Whether a camera arm carries the camera (arm faults are drawn only then).
    joints : int
        The arm's joint count (a stalled joint is drawn among them).
    """
    bursts: dict[str, tuple[Burst, ...]] = {}
    first = math.ceil(config.start_after / dt - 1e-9)
    duration = n * dt
    for index, name in enumerate(FAULT_NAMES):
        spec: FaultSpec = getattr(config, name)
        if spec.rate <= 0.0 or (name in ARM_FAULTS and not arm) or first >= n:
            continue
        rng = np.random.default_rng([config.seed, index])
        length = max(1, round(spec.burst / dt))
        found: list[Burst] = []
        t = config.start_after
        while True:
            t += rng.exponential(1.0 / spec.rate)
            if t >= duration:
                break
            start = max(first, math.floor(t / dt))
            draw = rng.random(4)
            if name == "joint_stall":
                draw[2] = math.floor(draw[2] * max(joints, 1))
            found.append(Burst(start, min(n, start + length), draw))
            t = (start + length) * dt  # bursts do not overlap
        bursts[name] = tuple(found)
    return FaultSchedule(config, bursts, n)


def _stalled_joint(b: Burst) -> int:
    return int(b.draw[2])


def _unit_from(u: float, v: float) -> FloatArray:
    """A unit vector (3,) from two uniform numbers (uniform on the sphere)."""
    z = 2.0 * u - 1.0
    phi = 2.0 * math.pi * v
    r = math.sqrt(max(0.0, 1.0 - z * z))
    return np.array([r * math.cos(phi), r * math.sin(phi), z])


def _rotation(axis: FloatArray, angle: float) -> FloatArray:
    """(3, 3) rotation by ``angle`` (rad) about the unit ``axis`` (Rodrigues)."""
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * K @ K


def _outlier(spec: OutlierFault, b: Burst) -> tuple[FloatArray, FloatArray]:
    """An outlier burst's offset (3,), world, m, and turn (3, 3) of the ring's frame."""
    offset = spec.distance * _unit_from(b.draw[0], b.draw[1])
    phi = 2.0 * math.pi * b.draw[2]  # an axis in the ring's face: the normal turns by angle
    return offset, _rotation(np.array([math.cos(phi), math.sin(phi), 0.0]), spec.angle)


def _bad_entry(b: Burst, value: float) -> tuple[int, int, float]:
    """A NaN/inf burst's entry of the pose's top 3 rows (row, column) and its value."""
    return int(b.draw[0] * 3), int(b.draw[1] * 4), value if b.draw[2] < 0.5 else -value


def apply_observation_faults(
    schedule: FaultSchedule,
    t: FloatArray,
    T_world_ring_sensed: FloatArray,
    p_world_tips: FloatArray,
    poses: object,
    sensing_latency: float,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The observations the controller sees under the schedule's sensing faults.

    Parameters
    ----------
    schedule : FaultSchedule
    t : (N,)
        Control times, s.
    T_world_ring_sensed : (N, 4, 4)
        Delayed ring poses without faults, world, m.
    p_world_tips : (N, K, 3)
        Instrument tips, world, m.
    poses : callable
        The ring trajectory ``poses(ts) -> (M, 4, 4)`` (latency spikes read older poses).
    sensing_latency : float
        The usual sensing delay, s.

    Returns
    -------
    T_world_ring_sensed : (N, 4, 4)
        With faults: a missing pose is all NaN.
    p_world_tips : (N, K, 3)
        With tip dropouts as NaN.
    t_ring : (N,)
        When each ring pose was captured, s (:attr:`Observation.t_ring`): ``t`` minus the
        delay (clipped at 0, as the sensed poses are); a frozen tracker keeps the stamp of the
        pose it repeats, a latency spike's poses are older.
    """
    T = np.array(T_world_ring_sensed, dtype=float)
    t_ring = capture_times(t, sensing_latency)
    tips = np.array(p_world_tips, dtype=float)
    cfg = schedule.config
    for b in schedule.bursts.get("latency_spike", ()):
        delay = sensing_latency + cfg.latency_spike.extra_delay
        t_ring[b.start : b.stop] = capture_times(t[b.start : b.stop], delay)
        T[b.start : b.stop] = poses(t_ring[b.start : b.stop])  # type: ignore[operator]
    for b in schedule.bursts.get("tracker_frozen", ()):
        T[b.start : b.stop] = T[b.start]
        t_ring[b.start : b.stop] = t_ring[b.start]
    for b in schedule.bursts.get("ring_outlier", ()):
        offset, R_ring_outlier = _outlier(cfg.ring_outlier, b)
        T[b.start : b.stop, :3, 3] += offset
        T[b.start : b.stop, :3, :3] = T[b.start : b.stop, :3, :3] @ R_ring_outlier
    for name, value in (("ring_nan", math.nan), ("ring_inf", math.inf)):
        for b in schedule.bursts.get(name, ()):
            i, j, v = _bad_entry(b, value)
            T[b.start : b.stop, i, j] = v
    for b in schedule.bursts.get("ring_dropout", ()):
        T[b.start : b.stop] = math.nan
    for b in schedule.bursts.get("tip_dropout", ()):
        tips[b.start : b.stop] = math.nan
    return T, tips, t_ring


class StepFaults:
    """The in-loop faults of one episode: overruns, goals beyond reach, stalled joints.

    Parameters
    ----------
    schedule : FaultSchedule
    stall : callable
        The carrier's ``stall(joint)``: stall joint ``joint`` (an index), or none (``None``).
    """

    def __init__(self, schedule: FaultSchedule, stall: Callable[[int | None], None]) -> None:
        self._overrun = schedule.mask("step_overrun").tolist()
        self._beyond = [-1.0] * schedule.n
        for b in schedule.bursts.get("goal_beyond_reach", ()):
            self._beyond[b.start : b.stop] = [float(b.draw[0])] * (b.stop - b.start)
        self._stall: list[int | None] = [None] * schedule.n
        for b in schedule.bursts.get("joint_stall", ()):
            self._stall[b.start : b.stop] = [_stalled_joint(b)] * (b.stop - b.start)
        self._set_stall = stall
        self._stalled: int | None = None
        self._overshoot = schedule.config.goal_beyond_reach.overshoot
        self._last: tuple[FloatArray, FloatArray | None] | None = None

    def command(
        self, k: int, T_world_cmd: FloatArray, twist: FloatArray | None, look_distance: float
    ) -> tuple[FloatArray, float, FloatArray | None]:
        """What the carrier receives at step ``k``: command (4, 4), look distance (m), twist.

        Parameters
        ----------
        k : int
            Control step.
        T_world_cmd : (4, 4)
            The policy's command, world, m.
        twist : (6,) or None
            Its velocity (m/s, rad/s).
        look_distance : float
            m.
        """
        sent, sent_twist = T_world_cmd, twist
        if self._overrun[k] and self._last is not None:
            sent, sent_twist = self._last  # the step came late: the previous command again
        variant = self._beyond[k]
        if variant >= 0.0:
            sent = np.array(sent, dtype=float)
            sent_twist = None
            if variant < 0.5:  # past the insertion stroke: further along the view
                sent[:3, 3] += self._overshoot * sent[:3, 2]
            else:  # beyond the wrist: the view turned half a turn about image x
                sent[:3, 1:3] = -sent[:3, 1:3]
        stalled = self._stall[k]
        if stalled != self._stalled:
            self._set_stall(stalled)
            self._stalled = stalled
        self._last = (T_world_cmd, twist)
        return sent, look_distance, sent_twist


RING_FAULTS = (
    "latency_spike",
    "tracker_frozen",
    "ring_outlier",
    "ring_nan",
    "ring_inf",
    "ring_dropout",
)
"""The ring-observation faults, in the order they are applied."""


class DeliveredFaults:
    """The ring faults applied step by step to what a perception source delivers.

    The same schedule, the same draws and the same effects as :func:`apply_observation_faults`
    on the true sensed poses, on the pose the source gives the controller at each step: a
    latency spike gives the pose it gave ``extra_delay`` earlier (with its stamp); a frozen
    tracker gives the pose it gave before the burst, with that pose's stamp (no new estimate:
    it ages, and past ``ring_max_age`` the controller holds, stale); an outlier is displaced
    and turned by the burst's offset and rotation; NaN/inf corrupt the same entry; a dropout
    gives no pose (all NaN: the controller holds at once, as on truth).

    Parameters
    ----------
    schedule : FaultSchedule
    dt : float
        Control period, s.
    """

    def __init__(self, schedule: FaultSchedule, dt: float) -> None:
        self.config = schedule.config
        self._at: list[list[tuple[str, Burst]]] = [[] for _ in range(schedule.n)]
        for name in RING_FAULTS:
            for b in schedule.bursts.get(name, ()):
                for k in range(b.start, b.stop):
                    self._at[k].append((name, b))
        self._lag = max(1, round(self.config.latency_spike.extra_delay / dt))

    def apply(
        self,
        k: int,
        T_given: FloatArray,
        t_given: FloatArray,
        t_captured: FloatArray | None = None,
    ) -> tuple[FloatArray, float]:
        """The faulted pose (4, 4), world, m, and stamp (s) the controller gets at step ``k``.

        ``T_given`` (≥ k + 1, 4, 4) and ``t_given`` (≥ k + 1,): what the source gave (without
        faults) at steps 0 … k, world, m, and s. ``t_captured`` (≥ k + 1,), s: when what it
        gave was captured (a source that predicts its pose to the present stamps it now): an
        old pose repeated (frozen tracker, latency spike) carries its capture time, so the
        controller's stale rule counts the information's age, never less. Default ``t_given``.
        """
        t_old = t_given if t_captured is None else t_captured
        T, t_ring = T_given[k], float(t_given[k])
        for name, b in self._at[k]:
            if name == "latency_spike":
                j = max(0, k - self._lag)
                T, t_ring = T_given[j], float(t_old[j])
            elif name == "ring_dropout":
                T = np.full((4, 4), math.nan)
            elif name == "tracker_frozen":
                j = max(0, b.start - 1)
                T, t_ring = T_given[j], float(t_old[j])
            elif name == "ring_outlier":
                offset, R_ring_outlier = _outlier(self.config.ring_outlier, b)
                T = np.array(T, dtype=float)
                T[:3, 3] += offset
                T[:3, :3] = T[:3, :3] @ R_ring_outlier
            else:
                i, j, v = _bad_entry(b, math.nan if name == "ring_nan" else math.inf)
                T = np.array(T, dtype=float)
                T[i, j] = v
        return T, t_ring
