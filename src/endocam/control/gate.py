"""The observation gate: ring poses checked for staleness and plausible motion before use.

* :func:`is_stale`: a ring pose too old (or stamped in the future) to act on.
* :class:`RingGate`: a ring pose that moved or turned faster than plausible since the last
  accepted one is refused (the camera holds); its rule (:func:`gate_decide`,
  :func:`gate_commit`) is compiled, so the policies' own kernels run it too.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np
from numba import njit
from numba.extending import register_jitable
from numpy.typing import NDArray

from endocam.geometry import FloatArray
from endocam.kernels import dist3
from endocam.workspace.cone import ConeWorkspace

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


GATE_BOUNDS = np.dtype(
    [
        ("max_speed", np.float64),  # m/s, fastest plausible ring centre
        ("max_rate", np.float64),  # rad/s, fastest plausible turn of the ring normal
        ("horizon", np.float64),  # s, longest time the bounds grow over
        ("reacquire", np.float64),  # s, time without an accepted observation to re-acquire
    ],
    align=True,
)
"""How fast a real ring can move (:attr:`RingGate.bounds` is a (1,) array of it)."""

GateBounds = NDArray[np.void]  # a (1,) array of GATE_BOUNDS


class GateLimits(Protocol):
    """A :data:`GATE_BOUNDS` record as compiled code reads it (its fields, by name)."""

    max_speed: float
    max_rate: float
    horizon: float
    reacquire: float


GATE_MEMORY = np.dtype(
    [
        ("held", np.bool_),  # whether there is one
        ("t", np.float64),  # when it was seen, s
        ("centre", np.float64, (3,)),  # the ring centre, world, m
        ("normal", np.float64, (3,)),  # the ring's unit normal, world
    ],
    align=True,
)
"""One remembered ring observation (a record; :func:`gate_remember` stores one)."""

GATE_STATE = np.dtype(
    [
        ("accepted", GATE_MEMORY),  # the last accepted observation: the bounds' reference
        ("seen", GATE_MEMORY),  # the last finite observation, accepted or not
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


@register_jitable  # also callable from compiled kernels (the same source)
def gate_remember(memory: GateMemory, t: float, x: Sequence[float]) -> None:
    """Store the observation ``x`` (centre (3,), world, m; unit normal (3,)) seen at ``t`` s.

    ``memory``: a :data:`GATE_MEMORY` record (compiled callers only: numba's record views).
    """
    memory.held = True
    memory.t = t
    for i in range(3):
        memory.centre[i] = x[i]
        memory.normal[i] = x[3 + i]


@register_jitable  # also callable from compiled kernels (the same source)
def gate_agrees(memory: GateMemory, limits: GateLimits, t: float, x: Sequence[float]) -> bool:
    """Whether ``x`` (centre, m; unit normal) at ``t`` (s) agrees with the remembered one.

    The centre moved at most ``max_speed · Δt`` and the normal turned at most
    ``max_rate · Δt``, ``Δt`` the time since ``memory``'s observation (a :data:`GATE_MEMORY`
    record) capped at ``horizon`` (``limits``: a :data:`GATE_BOUNDS` record).
    """
    dt = min(max(t - memory.t, 0.0), limits.horizon)
    c, n = memory.centre, memory.normal
    dp = dist3(x[0], x[1], x[2], c[0], c[1], c[2])
    cos = x[3] * n[0] + x[4] * n[1] + x[5] * n[2]
    turn = math.acos(max(-1.0, min(1.0, cos)))
    return dp <= limits.max_speed * dt and turn <= limits.max_rate * dt


@register_jitable  # also callable from compiled kernels (the same source)
def gate_decide(state: GateState, bounds: GateBounds, t: float, x: Sequence[float]) -> int:
    """:meth:`RingGate.accept`'s rule, up to the workspace: a ``GATE_*`` answer.

    ``state`` and ``bounds``: :class:`RingGate`'s; ``x`` (6,) the ring centre, world, m, and
    its unit normal seen at ``t`` (s). ``GATE_REACQUIRE``: accept if the centre may be
    re-acquired (the gate's ``inside``). Records ``x`` as the last finite observation; the
    caller ends with :func:`gate_commit`. Compiled callers only.
    """
    accepted, seen, limits = state[0].accepted, state[0].seen, bounds[0]
    decision = GATE_REJECT
    if not accepted.held or gate_agrees(accepted, limits, t, x):
        decision = GATE_ACCEPT
    elif t - accepted.t > limits.reacquire and seen.held:
        age = t - seen.t
        if 0.0 < age <= limits.horizon and gate_agrees(seen, limits, t, x):
            decision = GATE_REACQUIRE
    gate_remember(seen, t, x)
    return decision


@register_jitable  # also callable from compiled kernels (the same source)
def gate_commit(state: GateState, t: float, x: Sequence[float], ok: bool) -> None:
    """Record :func:`gate_decide`'s final answer ``ok``: ``x`` at ``t`` is the new reference."""
    if ok:
        gate_remember(state[0].accepted, t, x)
    else:
        state[0].rejected += 1


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
    :data:`GATE_STATE` record, with :attr:`bounds`, a :class:`GateBounds`); the policies' compiled
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
        limits = (float(max_speed), float(max_rate), float(horizon), float(reacquire))
        self.bounds: GateBounds = np.array([limits], dtype=GATE_BOUNDS)
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
