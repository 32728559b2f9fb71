"""The observation gate: ring poses checked for staleness and plausible motion before use.

* :func:`is_stale`: a ring pose too old (or stamped in the future) to act on.
* :class:`RingGate`: a tracker's outlier rejection. Each ring pose is judged against a
  constant-velocity prediction from the *accepted* track; an innovation beyond a bound that
  grows with the ring's largest acceleration but never past a fixed cap
  (:attr:`RingLimits.position_gate`, :attr:`RingLimits.angle_gate`) is refused and the camera
  holds. After a gap (no fresh pose for longer than :attr:`RingLimits.horizon`) the ring is
  taken back once a short run of poses (:attr:`RingLimits.confirm`) bridges to the accepted
  track within the wider gap caps (:func:`gate_bridges`). Its rule (:func:`gate_decide`,
  :func:`gate_commit`) is compiled, so the policies' own kernels run it too.
  :func:`outlier_detected` is the one definition of the outliers it promises to refuse, which
  the safety check (``runner.check``) requires a hold on.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import astuple, dataclass, fields, replace
from typing import Protocol

import numpy as np
from numba import njit
from numba.extending import register_jitable
from numpy.typing import NDArray

from endocam.geometry import FloatArray
from endocam.kernels import dist3, dot3
from endocam.workspace.cone import ConeWorkspace

STALE_REASON = "ring pose stale (older than ring_max_age, or stamped in the future); holding"
CLOCK_TOL = 1e-6  # s, a capture stamp this far after the control time is round-off, not a fault
FLOOR_M = 0.5e-3  # m: the default innovation always allowed (the truth source's position noise)
FLOOR_RAD = math.radians(0.5)  # rad: the default for the normal (the truth source's noise)
MIN_DT = 1e-4  # s: two stamps closer than this give no velocity (a repeated pose)


def is_stale(t: float, t_ring: float | None, max_age: float) -> bool:
    """Whether a ring pose captured at ``t_ring`` (s) is too old to act on at time ``t`` (s).

    Stale: older than ``max_age`` (s), stamped after ``t`` by more than ``CLOCK_TOL``, or a
    non-finite stamp. ``t_ring`` None (an unstamped pose): never stale.
    """
    if t_ring is None:
        return False
    age = t - t_ring
    return not (-CLOCK_TOL <= age <= max_age)


GATE_REJECT, GATE_ACCEPT, GATE_REACQUIRE = 0, 1, 2  # gate_decide's answers


@dataclass(frozen=True)
class RingLimits:
    """How a real ring can move, and how far from its prediction a pose may be.

    Attributes
    ----------
    max_speed : float
        Fastest ring centre, m/s: two poses ``Δt`` apart agree only if the centre moved at
        most ``floor_position + max_speed · Δt``.
    max_rate : float
        Fastest turn of the ring normal, rad/s (same use).
    max_acceleration : float
        Largest acceleration of the ring centre, m/s²: the position innovation allowed after
        ``Δt`` is ``floor_position + ½ a Δt²``, up to ``position_gate``.
    max_angular_acceleration : float
        Largest second derivative of the unit normal, 1/s² (rad/s² for a steady turn): the
        angle innovation allowed is ``floor_angle + ½ α Δt²``, up to ``angle_gate``.
    position_gate : float
        The position innovation's cap, m: a pose farther from the prediction is never taken
        as it comes, however long the gate has refused.
    angle_gate : float
        The normal's innovation cap, rad.
    horizon : float
        Longest gap, s, over which two poses are compared step to step (a longer gap breaks a
        run), and over which a returning pose's reach grows.
    reacquire : float
        A refused run of poses that agree step to step for this long, s, is the ring (it moved,
        or the tracker now sees it there): it is taken, inside the workspace only.
    gap_position : float
        After a gap, m: a refused run that began after the gap is taken once its centre, at the
        run's mid-time, is within ``floor_position + ¼ a Δt²`` (up to this cap) of the bridge
        from the accepted track (:func:`gate_bridges`). Outliers beyond twice it are refused
        after a gap.
    gap_angle : float
        The same for the normal, rad (``floor_angle + ¼ α Δt²``, up to this cap).
    confirm : float
        How long, s, a run that began after a gap must agree step to step before the bridge
        is tried (its velocity is the run's mean; at least two poses).
    floor_position : float
        The innovation always allowed, m: the observation source's position noise (its
        default ``FLOOR_M``, the truth source's; a stereo source's is larger, see
        :meth:`with_floor`).
    floor_angle : float
        The normal's innovation always allowed, rad (default ``FLOOR_RAD``).
    """

    max_speed: float
    max_rate: float
    max_acceleration: float
    max_angular_acceleration: float
    position_gate: float
    angle_gate: float
    horizon: float
    reacquire: float
    gap_position: float
    gap_angle: float
    confirm: float
    floor_position: float = FLOOR_M
    floor_angle: float = FLOOR_RAD

    def with_floor(self, floor_position: float, floor_angle: float) -> RingLimits:
        """These limits for a source with other noise floors.

        ``floor_position`` (m), ``floor_angle`` (rad): each cap (``position_gate``,
        ``gap_position``; ``angle_gate``, ``gap_angle``) raised by the floor's rise over this
        one's (never lowered), so the room a cap leaves for the ring's motion above the noise
        stays as stated. The same floors: these limits.
        """
        rise_m = max(0.0, floor_position - self.floor_position)
        rise_rad = max(0.0, floor_angle - self.floor_angle)
        return replace(
            self,
            position_gate=self.position_gate + rise_m,
            gap_position=self.gap_position + rise_m,
            angle_gate=self.angle_gate + rise_rad,
            gap_angle=self.gap_angle + rise_rad,
            floor_position=floor_position,
            floor_angle=floor_angle,
        )


GATE_BOUNDS = np.dtype([(f.name, np.float64) for f in fields(RingLimits)], align=True)
""":class:`RingLimits` as a record (:attr:`RingGate.bounds` is a (1,) array of it)."""

GateBounds = NDArray[np.void]  # a (1,) array of GATE_BOUNDS


class GateLimits(Protocol):
    """A :data:`GATE_BOUNDS` record as compiled code reads it (its fields, by name)."""

    max_speed: float
    max_rate: float
    max_acceleration: float
    max_angular_acceleration: float
    position_gate: float
    angle_gate: float
    horizon: float
    reacquire: float
    gap_position: float
    gap_angle: float
    confirm: float
    floor_position: float
    floor_angle: float


def outlier_detected(
    distance: float, angle: float, limits: RingLimits, *, after_gap: bool = False
) -> bool:
    """Whether the gate promises to refuse a ring pose ``distance`` (m) and ``angle`` (rad) off.

    One definition for the gate and the safety check. An outlier burst that jumps off a
    continuously observed ring: an offset beyond either innovation cap (``position_gate``,
    ``angle_gate``) is never acted on. One that begins right after a gap (``after_gap``: no
    fresh pose for a while before it) is judged against the bridge across the gap, which
    allows the ring's own motion up to ``gap_position`` / ``gap_angle``: an offset beyond
    twice those caps is never acted on (it lies beyond the cap however the ring moved within
    it); a smaller one may be (the ring itself can end that far off during a gap).
    """
    if after_gap:
        return distance > 2.0 * limits.gap_position or angle > 2.0 * limits.gap_angle
    return distance > limits.position_gate or angle > limits.angle_gate


GATE_MEMORY = np.dtype(
    [
        ("held", np.bool_),  # whether there is one
        ("t", np.float64),  # when it was captured, s
        ("centre", np.float64, (3,)),  # the ring centre, world, m
        ("normal", np.float64, (3,)),  # the ring's unit normal, world
        ("velocity", np.float64, (3,)),  # the centre's velocity, world, m/s
        ("normal_rate", np.float64, (3,)),  # the normal's derivative, world, 1/s
    ],
    align=True,
)
"""One track's last observation and its rates (a record; :func:`gate_remember` stores one)."""

GATE_STATE = np.dtype(
    [
        ("accepted", GATE_MEMORY),  # the accepted track: the prediction's reference
        ("seen", GATE_MEMORY),  # the last finite observation's track, accepted or not
        ("first", GATE_MEMORY),  # the refused run's first observation (its rates unused)
        ("refusing", np.bool_),  # whether the last seen observation was refused
        ("onset", np.bool_),  # the refused run began by jumping off the accepted track
        ("gap_run", np.bool_),  # the refused run began after a gap (more than horizon)
        ("run_start", np.float64),  # when the refused run began, s
        ("shift", np.float64, (6,)),  # the run's jump off the accepted track (centre, normal)
        ("jump", np.bool_),  # the decided observation broke from the seen track
        ("after_gap", np.bool_),  # the decided observation came more than horizon after seen
        ("rejected", np.int64),  # observations rejected this episode
    ],
    align=True,
)
"""The gate's memory (:attr:`RingGate.state` is a (1,) array of it, updated in place).

A structured array: named fields, and one array for compiled callers to take.
"""

GateState = NDArray[np.void]  # a (1,) array of GATE_STATE


class GateMemory(Protocol):
    """A :data:`GATE_MEMORY` record as compiled code reads it (its fields, by name)."""

    held: bool
    t: float
    centre: FloatArray
    normal: FloatArray
    velocity: FloatArray
    normal_rate: FloatArray


@register_jitable  # also callable from compiled kernels (the same source)
def normal_angle(n: Sequence[float], x: Sequence[float]) -> float:
    """Angle, rad, between the direction ``n`` (3,) (any length > 0) and ``x[3:6]``.

    ``atan2(|n × x|, n · x)``: exact near 0 and π; π for a zero ``n``.
    """
    cx = n[1] * x[5] - n[2] * x[4]
    cy = n[2] * x[3] - n[0] * x[5]
    cz = n[0] * x[4] - n[1] * x[3]
    c = math.sqrt(cx * cx + cy * cy + cz * cz)
    d = dot3(n[0], n[1], n[2], x[3], x[4], x[5])
    if c == 0.0 and d <= 0.0:
        return math.pi
    return math.atan2(c, d)


@register_jitable  # also callable from compiled kernels (the same source)
def gate_fits(
    memory: GateMemory, limits: GateLimits, t: float, x: Sequence[float], shift: Sequence[float]
) -> bool:
    """Whether ``x`` (centre (3,), m; unit normal (3,)) seen at ``t`` (s) fits ``memory``'s track.

    The track (``memory``: a :data:`GATE_MEMORY` record) moved by ``−shift`` (6,: centre, m;
    normal; zeros for the track itself), predicted at constant velocity to ``t``, is within
    ``floor_position + ½ a Δt²`` (capped at ``position_gate``) of the centre and
    ``floor_angle + ½ α Δt²`` (capped at ``angle_gate``) of the normal, ``Δt = |t − memory.t|``.
    """
    dt = t - memory.t
    c, v = memory.centre, memory.velocity
    dp = dist3(
        x[0],
        x[1],
        x[2],
        c[0] - shift[0] + v[0] * dt,
        c[1] - shift[1] + v[1] * dt,
        c[2] - shift[2] + v[2] * dt,
    )
    n, w = memory.normal, memory.normal_rate
    predicted = (
        n[0] - shift[3] + w[0] * dt,
        n[1] - shift[4] + w[1] * dt,
        n[2] - shift[5] + w[2] * dt,
    )
    turn = normal_angle(predicted, x)
    half = 0.5 * dt * dt
    p_tol = min(limits.position_gate, limits.floor_position + half * limits.max_acceleration)
    a_tol = min(limits.angle_gate, limits.floor_angle + half * limits.max_angular_acceleration)
    return dp <= p_tol and turn <= a_tol


@register_jitable  # also callable from compiled kernels (the same source)
def gate_bridges(
    accepted: GateMemory, first: GateMemory, limits: GateLimits, t: float, x: Sequence[float]
) -> bool:
    """Whether the run from ``first`` to ``x`` (6,) at ``t`` (s) continues ``accepted``'s track.

    The run's mid-pose ``m = (first + x) / 2`` at ``t_m = (first.t + t) / 2`` and its mean
    rate ``u = (x − first) / (t − first.t)`` (centre, m and m/s; normal and 1/s) are
    second-order estimates of the ring at ``t_m``. A ring that left the accepted pose ``a``
    (``accepted``: centre, normal, rates ``v``) with acceleration within ``a_max`` is, after
    ``Δt = t_m − accepted.t``, within ``¼ a_max Δt²`` of the trapezoid bridge
    ``a + ½ (v + u) Δt``: ``m`` must be within ``floor_position + ¼ max_acceleration Δt²``
    (up to ``gap_position``) of it, and its normal within ``floor_angle + ¼ max_angular_acceleration
    Δt²`` (up to ``gap_angle``). False for a run shorter than ``MIN_DT``.
    """
    span = t - first.t
    if span < MIN_DT:
        return False
    dt = 0.5 * (first.t + t) - accepted.t
    c, v, f = accepted.centre, accepted.velocity, first.centre
    bridge = [0.0] * 6
    mid = [0.0] * 6
    n, w, g = accepted.normal, accepted.normal_rate, first.normal
    for i in range(3):
        mid[i] = 0.5 * (f[i] + x[i])
        mid[3 + i] = 0.5 * (g[i] + x[3 + i])
        bridge[i] = c[i] + 0.5 * (v[i] + (x[i] - f[i]) / span) * dt
        bridge[3 + i] = n[i] + 0.5 * (w[i] + (x[3 + i] - g[i]) / span) * dt
    dp = dist3(mid[0], mid[1], mid[2], bridge[0], bridge[1], bridge[2])
    turn = normal_angle((bridge[3], bridge[4], bridge[5]), mid)
    quarter = 0.25 * dt * dt
    p_tol = min(limits.gap_position, limits.floor_position + quarter * limits.max_acceleration)
    a_tol = min(limits.gap_angle, limits.floor_angle + quarter * limits.max_angular_acceleration)
    return dp <= p_tol and turn <= a_tol


@register_jitable  # also callable from compiled kernels (the same source)
def gate_step(memory: GateMemory, limits: GateLimits, t: float, x: Sequence[float]) -> bool:
    """Whether ``x`` at ``t`` (s) lies where the ring could have gone since ``memory``'s pose.

    The centre moved at most ``floor_position + max_speed · Δt`` and the normal turned at
    most ``floor_angle + max_rate · Δt``, ``Δt = |t − memory.t|``.
    """
    dt = abs(t - memory.t)
    c, n = memory.centre, memory.normal
    dp = dist3(x[0], x[1], x[2], c[0], c[1], c[2])
    turn = normal_angle((n[0], n[1], n[2]), x)
    return (
        dp <= limits.floor_position + limits.max_speed * dt
        and turn <= limits.floor_angle + limits.max_rate * dt
    )


@register_jitable  # also callable from compiled kernels (the same source)
def gate_offset(memory: GateMemory, t: float, x: Sequence[float]) -> tuple[float, ...]:
    """``x`` (6,) less ``memory``'s track predicted to ``t`` (s): centre, m; unit normal."""
    dt = t - memory.t
    c, v, n, w = memory.centre, memory.velocity, memory.normal, memory.normal_rate
    px, py, pz = n[0] + w[0] * dt, n[1] + w[1] * dt, n[2] + w[2] * dt
    length = math.sqrt(px * px + py * py + pz * pz)
    if length > 0.0:
        px, py, pz = px / length, py / length, pz / length
    return (
        x[0] - c[0] - v[0] * dt,
        x[1] - c[1] - v[1] * dt,
        x[2] - c[2] - v[2] * dt,
        x[3] - px,
        x[4] - py,
        x[5] - pz,
    )


@register_jitable  # also callable from compiled kernels (the same source)
def gate_remember(
    memory: GateMemory, t: float, x: Sequence[float], rates: GateMemory, difference: bool
) -> None:
    """Store ``x`` (centre (3,), m; unit normal (3,)) captured at ``t`` s in ``memory``.

    Its rates: with ``difference``, differenced from ``memory``'s last pose (when it is held
    and at least ``MIN_DT`` apart; else kept); without, those of ``rates`` (another
    :data:`GATE_MEMORY` record, when held; else zero). Compiled callers only.
    """
    dt = t - memory.t
    for i in range(3):
        if difference:
            if memory.held and abs(dt) >= MIN_DT:
                memory.velocity[i] = (x[i] - memory.centre[i]) / dt
                memory.normal_rate[i] = (x[3 + i] - memory.normal[i]) / dt
        else:
            memory.velocity[i] = rates.velocity[i] if rates.held else 0.0
            memory.normal_rate[i] = rates.normal_rate[i] if rates.held else 0.0
        memory.centre[i] = x[i]
        memory.normal[i] = x[3 + i]
    memory.held = True
    memory.t = t


@register_jitable  # also callable from compiled kernels (the same source)
def gate_decide(state: GateState, bounds: GateBounds, t: float, x: Sequence[float]) -> int:
    """:meth:`RingGate.accept`'s rule, up to the workspace: a ``GATE_*`` answer.

    ``state`` and ``bounds``: :class:`RingGate`'s; ``x`` (6,) the ring centre, world, m, and
    its unit normal captured at ``t`` (s). While tracking, ``x`` is accepted when it fits the
    accepted track (:func:`gate_fits`). While refusing, ``x`` that continues the refused run
    (fits its track and :func:`gate_step`, at most ``horizon`` later) is refused until the
    run, if it began after a gap, has lasted ``confirm`` s and bridges to the accepted track
    (:func:`gate_bridges`: accepted), or until it has lasted ``reacquire`` s (then
    ``GATE_REACQUIRE``: accepted if inside the workspace); ``x`` that breaks from the run is
    accepted when it fits the accepted track,
    or when the run began by jumping off that track and ``x`` fits the run's track less that
    jump (the ring back after an outlier burst: the run moved as the ring did).
    Records ``x`` as the last seen observation; the caller ends with :func:`gate_commit`.
    Compiled callers only.
    """
    st, limits = state[0], bounds[0]
    accepted, seen = st.accepted, st.seen
    still = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    after_gap = not seen.held or abs(t - seen.t) > limits.horizon
    jump = (
        after_gap or not gate_fits(seen, limits, t, x, still) or not gate_step(seen, limits, t, x)
    )
    decision = GATE_REJECT
    if not accepted.held:
        decision = GATE_ACCEPT
    elif not st.refusing:
        if gate_fits(accepted, limits, t, x, still):
            decision = GATE_ACCEPT
    elif not jump:  # the refused run goes on
        lasted = t - st.run_start
        confirmed = st.gap_run and lasted + CLOCK_TOL >= limits.confirm
        if confirmed and gate_bridges(accepted, st.first, limits, t, x):
            decision = GATE_ACCEPT  # after a gap: the run continues the accepted track
        elif lasted >= limits.reacquire:
            decision = GATE_REACQUIRE
    elif gate_fits(accepted, limits, t, x, still):
        decision = GATE_ACCEPT
    elif st.onset and not after_gap:
        s = st.shift
        if gate_fits(seen, limits, t, x, (s[0], s[1], s[2], s[3], s[4], s[5])):
            decision = GATE_ACCEPT  # back: the run's track less the jump it began with
    st.jump = jump
    st.after_gap = after_gap
    gate_remember(seen, t, x, accepted, not jump)  # a jump keeps the accepted rates
    return decision


@register_jitable  # also callable from compiled kernels (the same source)
def gate_commit(state: GateState, t: float, x: Sequence[float], ok: bool) -> None:
    """Record :func:`gate_decide`'s final answer ``ok`` for ``x`` at ``t``.

    Accepted: ``x`` and its rates (the seen track's, or differenced from the accepted pose
    when it returns from a refused run) are the new reference. Refused: counted, and a new
    refused run begins unless ``x`` continues one (``x`` its first pose; a run that begins
    after a gap may be taken by the bridge, one that jumps off the accepted track by the
    return test).
    """
    st = state[0]
    if ok:
        # back from a refused run: the mean rates across it; else the seen track's rates
        back = st.refusing and st.jump
        gate_remember(st.accepted, t, x, st.seen, back)
        st.refusing = False
        return
    st.rejected += 1
    if not st.refusing or st.jump:
        st.onset = not st.refusing and not st.after_gap
        st.gap_run = st.after_gap
        st.run_start = t
        gate_remember(st.first, t, x, st.first, False)
        if st.onset:  # the jump off the accepted track
            offset = gate_offset(st.accepted, t, x)
            for i in range(6):
                st.shift[i] = offset[i]
    st.refusing = True


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def _gate_decide_kernel(
    state: GateState, bounds: GateBounds, t: float, x: tuple[float, ...]
) -> int:  # pragma: no cover - compiled
    """:func:`gate_decide` from Python (:meth:`RingGate.accept`)."""
    return gate_decide(state, bounds, t, x)


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def _gate_commit_kernel(
    state: GateState, t: float, x: tuple[float, ...], ok: bool
) -> None:  # pragma: no cover - compiled
    """:func:`gate_commit` from Python (:meth:`RingGate.accept`)."""
    gate_commit(state, t, x, ok)


class RingGate:
    """A tracker's outlier rejection for ring poses, before they reach the goal.

    Each pose is judged against a constant-velocity prediction from the accepted track (rates
    differenced from the last two accepted poses); the innovation allowed grows with the
    ring's largest acceleration over the time since the last accepted pose, but never past
    :attr:`RingLimits.position_gate` and :attr:`RingLimits.angle_gate`. A refused pose starts
    a refused run; the poses that continue it (agree with it step to step) are refused too,
    so an outlier is not taken by waiting. A pose that breaks from the run is accepted when it
    fits the prediction, or, if the run began by jumping off the accepted track, when it fits
    the run's track less that jump: the true ring back after an outlier burst (the run moved
    as the ring did), however far the ring went meanwhile. A run that has agreed with itself
    for ``reacquire`` s is taken if its centre lies in the workspace (the cone, given at
    :meth:`reset`): the ring moved while it was lost, or a persistent offset is the ring as
    the tracker now sees it. A refused run that began after a gap (no fresh pose for more
    than ``horizon``) is taken sooner, once it has agreed for ``confirm`` s and bridges to
    the accepted track within ``gap_position`` / ``gap_angle`` (:func:`gate_bridges`): the
    ring moved while unseen.

    Refused poses are answered like missing ones: the camera holds. Times are capture
    stamps (a latency spike's older pose is predicted at its own time).

    The rule is compiled (:func:`gate_decide`, :func:`gate_commit` on :attr:`state`, a
    :data:`GATE_STATE` record, with :attr:`bounds`, a :class:`GateBounds`); the policies' compiled
    steps run it inside their own kernel, with the cone's own ``cone_margin`` as the
    workspace.

    Parameters
    ----------
    limits : RingLimits
    """

    def __init__(self, limits: RingLimits) -> None:
        self.limits = limits
        self.bounds: GateBounds = np.array([astuple(limits)], dtype=GATE_BOUNDS)
        self.state: GateState = np.zeros(1, dtype=GATE_STATE)
        self._inside: Callable[[Sequence[float]], bool] | None = None
        self.cone: ConeWorkspace | None = None  # the workspace, when it is a cone

    @property
    def rejected(self) -> int:
        """Observations rejected this episode."""
        return int(self.state[0]["rejected"])

    def reset(
        self,
        inside: Callable[[Sequence[float]], bool] | None = None,
        *,
        cone: ConeWorkspace | None = None,
    ) -> None:
        """Forget every observation (a new episode).

        ``inside(p_world)``: whether a ring centre (3,), world, m, may be re-acquired;
        ``None``: anywhere. ``cone``: the cone workspace instead (its ``contains``; compiled
        callers test it themselves).
        """
        self.state[:] = np.zeros(1, dtype=GATE_STATE)
        self.cone = cone
        self._inside = cone.contains if cone is not None else inside

    def accept(self, t: float, p_world: Sequence[float], n_world: Sequence[float]) -> bool:
        """Whether to use the ring centre ``p_world`` (3,), m, and unit normal (3,) seen at t."""
        p, n = p_world, n_world
        x = (float(p[0]), float(p[1]), float(p[2]), float(n[0]), float(n[1]), float(n[2]))
        decision = _gate_decide_kernel(self.state, self.bounds, float(t), x)
        ok = decision == GATE_ACCEPT or (
            decision == GATE_REACQUIRE
            and (self._inside is None or self._inside([x[0], x[1], x[2]]))
        )
        _gate_commit_kernel(self.state, float(t), x, ok)
        return ok
