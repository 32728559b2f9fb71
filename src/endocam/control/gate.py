"""The observation gate: ring poses checked for staleness and plausible motion before use.

* :func:`is_stale`: a ring pose too old (or stamped in the future) to act on.
* :class:`RingGate`: a ring pose that moved or turned faster than plausible since the last
  accepted one is refused (the camera holds); its rule (:func:`gate_decide`,
  :func:`gate_commit`) is compiled, so the policies' own kernels run it too.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np
from numba import njit
from numba.extending import register_jitable
from numpy.typing import NDArray

from endocam.geometry import FloatArray
from endocam.kernels import dist3
from endocam.workspace.cone import ConeWorkspace

BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.integer]

STALE_REASON = "ring pose stale (older than ring_max_age, or stamped in the future); holding"
CLOCK_TOL = 1e-6  # s, a capture stamp this far after the control time is round-off, not a fault


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


class GateBounds(NamedTuple):
    """How fast a real ring can move: the gate's bounds (:class:`RingGate`'s parameters)."""

    max_speed: float  # m/s, fastest plausible ring centre
    max_rate: float  # rad/s, fastest plausible turn of the ring normal
    horizon: float  # s, longest time the bounds grow over
    reacquire: float  # s, time without an accepted observation before re-acquiring


class GateMemory(NamedTuple):
    """One remembered ring observation; arrays, updated in place by :func:`gate_remember`."""

    held: BoolArray  # (1,), whether there is one
    t: FloatArray  # (1,), when it was seen, s
    centre: FloatArray  # (3,), the ring centre, world, m
    normal: FloatArray  # (3,), the ring's unit normal, world


class GateState(NamedTuple):
    """The gate's memory (:attr:`RingGate.state`): what compiled callers pass, updated in place."""

    accepted: GateMemory  # the last accepted observation: the reference for the bounds
    seen: GateMemory  # the last finite observation, accepted or not
    rejected: IntArray  # (1,), observations rejected this episode


def _memory() -> GateMemory:
    """An empty :class:`GateMemory`."""
    return GateMemory(np.zeros(1, dtype=np.bool_), np.zeros(1), np.zeros(3), np.zeros(3))


@register_jitable  # also callable from compiled kernels (the same source)
def gate_remember(memory: GateMemory, t: float, x: Sequence[float]) -> None:
    """Store the observation ``x`` (centre (3,), world, m; unit normal (3,)) seen at ``t`` s."""
    memory.held[0] = True
    memory.t[0] = t
    for i in range(3):
        memory.centre[i] = x[i]
        memory.normal[i] = x[3 + i]


@register_jitable  # also callable from compiled kernels (the same source)
def gate_agrees(memory: GateMemory, bounds: GateBounds, t: float, x: Sequence[float]) -> bool:
    """Whether ``x`` (centre, m; unit normal) at ``t`` (s) agrees with the remembered one.

    The centre moved at most ``max_speed · Δt`` and the normal turned at most
    ``max_rate · Δt``, ``Δt`` the time since ``memory``'s observation capped at ``horizon``.
    """
    dt = min(max(t - memory.t[0], 0.0), bounds.horizon)
    c, n = memory.centre, memory.normal
    dp = dist3(x[0], x[1], x[2], c[0], c[1], c[2])
    cos = x[3] * n[0] + x[4] * n[1] + x[5] * n[2]
    turn = math.acos(max(-1.0, min(1.0, cos)))
    return dp <= bounds.max_speed * dt and turn <= bounds.max_rate * dt


@register_jitable  # also callable from compiled kernels (the same source)
def gate_decide(state: GateState, bounds: GateBounds, t: float, x: Sequence[float]) -> int:
    """:meth:`RingGate.accept`'s rule, up to the workspace: a ``GATE_*`` answer.

    ``state`` and ``bounds``: :class:`RingGate`'s; ``x`` (6,) the ring centre, world, m, and
    its unit normal seen at ``t`` (s). ``GATE_REACQUIRE``: accept if the centre may be
    re-acquired (the gate's ``inside``). Records ``x`` as the last finite observation; the
    caller ends with :func:`gate_commit`.
    """
    accepted, seen = state.accepted, state.seen
    decision = GATE_REJECT
    if not accepted.held[0] or gate_agrees(accepted, bounds, t, x):
        decision = GATE_ACCEPT
    elif t - accepted.t[0] > bounds.reacquire and seen.held[0]:
        age = t - seen.t[0]
        if 0.0 < age <= bounds.horizon and gate_agrees(seen, bounds, t, x):
            decision = GATE_REACQUIRE
    gate_remember(seen, t, x)
    return decision


@register_jitable  # also callable from compiled kernels (the same source)
def gate_commit(state: GateState, t: float, x: Sequence[float], ok: bool) -> None:
    """Record :func:`gate_decide`'s final answer ``ok``: ``x`` at ``t`` is the new reference."""
    if ok:
        gate_remember(state.accepted, t, x)
    else:
        state.rejected[0] += 1


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def _gate_decide_kernel(
    state: GateState, bounds: GateBounds, t: float, x: tuple[float, ...]
) -> int:  # pragma: no cover - compiled
    """:func:`gate_decide` from Python (:meth:`RingGate.accept`)."""
    return gate_decide(state, bounds, t, x)


class RingGate:
    """Gates ring observations by a speed bound before they reach the goal.

    An observation is accepted when its centre moved at most ``max_speed · Δt`` and its normal
    turned at most ``max_rate · Δt`` from the last accepted one, with ``Δt`` the time since
    then, capped at ``horizon`` (so a wild outlier is rejected however long tracking was
    lost). Rejected observations are answered like missing ones: the camera holds. After
    ``reacquire`` seconds without an accepted observation, two consecutive observations (at
    most ``horizon`` apart) that agree with each other are accepted if the ring centre lies in
    the workspace (the cone, given at :meth:`reset`): the ring may really have moved while it
    was lost. (A tracker locked onto a wrong pose inside the cone for longer than that is
    indistinguishable from a moved ring.)

    The rule is compiled (:func:`gate_decide`, :func:`gate_commit` on :attr:`state`, a
    :class:`GateState`, with :attr:`bounds`, a :class:`GateBounds`); the policies' compiled
    steps run it inside their own kernel, with the cone's own ``cone_margin`` as the
    workspace.

    Parameters
    ----------
    max_speed : float
        Fastest plausible ring centre, m/s.
    max_rate : float
        Fastest plausible turn of the ring normal, rad/s.
    horizon : float
        Longest time the bounds grow over, s.
    reacquire : float
        Time without an accepted observation after which consecutive agreeing ones are, s.
    """

    def __init__(self, max_speed: float, max_rate: float, horizon: float, reacquire: float) -> None:
        self.bounds = GateBounds(
            float(max_speed), float(max_rate), float(horizon), float(reacquire)
        )
        self.state = GateState(_memory(), _memory(), np.zeros(1, dtype=np.int64))
        self._inside: Callable[[Sequence[float]], bool] | None = None
        self.cone: ConeWorkspace | None = None  # the workspace, when it is a cone

    @property
    def rejected(self) -> int:
        """Observations rejected this episode."""
        return int(self.state.rejected[0])

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
        for memory in (self.state.accepted, self.state.seen):
            for array in memory:
                array[:] = 0
        self.state.rejected[0] = 0
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
        gate_commit(self.state, t, x, ok)
        return ok
