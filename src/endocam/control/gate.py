"""The observation gate: ring poses checked for staleness and plausible motion before use.

* :func:`is_stale`: a ring pose too old (or stamped in the future) to act on.
* :class:`RingGate`: a ring pose that moved or turned faster than plausible since the last
  accepted one is refused (the camera holds); its rule (:func:`gate_decide`,
  :func:`gate_commit`) is compiled, so the policies' own kernels run it too.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
from numba import njit
from numba.extending import register_jitable

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


# The ring gate's state (``RingGate.state``), by index: the last accepted observation and the
# last finite one (a flag, the time, s, then centre (3,), world, m, and unit normal (3,)), and
# the rejections this episode.
_G_REF, _G_RAW = 0, 8  # has (1.0 / 0.0), t s, x (6,)
_G_REJECTED = 16  # count
_G_N = 17
# The gate's bounds (``RingGate.bounds``): max_speed m/s, max_rate rad/s, horizon s, reacquire s


@register_jitable  # also callable from compiled kernels (the same source)
def _gate_agrees(
    state: FloatArray, i: int, bounds: FloatArray, t: float, x: Sequence[float]
) -> bool:
    """Whether ``x`` (centre m, unit normal) at ``t`` (s) agrees with ``state[i:i + 8]``'s."""
    t0 = state[i + 1]
    dt = min(max(t - t0, 0.0), bounds[2])  # Python's min(max(t − t0, 0), horizon)
    dp = dist3(x[0], x[1], x[2], state[i + 2], state[i + 3], state[i + 4])
    cos = x[3] * state[i + 5] + x[4] * state[i + 6] + x[5] * state[i + 7]
    turn = math.acos(max(-1.0, min(1.0, cos)))  # Python's max(-1, min(1, cos))
    return dp <= bounds[0] * dt and turn <= bounds[1] * dt


@register_jitable  # also callable from compiled kernels (the same source)
def gate_decide(state: FloatArray, bounds: FloatArray, t: float, x: Sequence[float]) -> int:
    """:meth:`RingGate.accept`'s rule, up to the workspace: 0 reject, 1 accept, 2 re-acquire.

    ``state`` (``_G_N``,) and ``bounds`` (4,): :class:`RingGate`'s; ``x`` (6,) the ring
    centre, world, m, and its unit normal seen at ``t`` (s). 2: accept if the centre may be
    re-acquired (the gate's ``inside``). Records ``x`` as the last finite observation; the
    caller ends with :func:`gate_commit`.
    """
    has_ref, has_raw = state[_G_REF] != 0.0, state[_G_RAW] != 0.0
    decision = 1 if not has_ref or _gate_agrees(state, _G_REF, bounds, t, x) else 0
    if decision == 0 and t - state[_G_REF + 1] > bounds[3] and has_raw:
        age = t - state[_G_RAW + 1]
        if 0.0 < age <= bounds[2] and _gate_agrees(state, _G_RAW, bounds, t, x):
            decision = 2
    state[_G_RAW], state[_G_RAW + 1] = 1.0, t
    for i in range(6):
        state[_G_RAW + 2 + i] = x[i]
    return decision


@register_jitable  # also callable from compiled kernels (the same source)
def gate_commit(state: FloatArray, t: float, x: Sequence[float], ok: bool) -> None:
    """Record :func:`gate_decide`'s final answer ``ok``: ``x`` at ``t`` is the new reference."""
    if ok:
        state[_G_REF], state[_G_REF + 1] = 1.0, t
        for i in range(6):
            state[_G_REF + 2 + i] = x[i]
    else:
        state[_G_REJECTED] += 1.0


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _gate_decide_kernel(
    state: FloatArray, bounds: FloatArray, t: float, x: tuple[float, ...]
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

    The rule is compiled (:func:`gate_decide`, :func:`gate_commit` on :attr:`state`); the
    policies' compiled steps run it inside their own kernel, with the cone's own
    :func:`cone_margin` as the workspace.

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
        self.max_speed, self.max_rate = max_speed, max_rate
        self.horizon, self.reacquire = horizon, reacquire
        self.bounds = np.array([max_speed, max_rate, horizon, reacquire], dtype=float)
        self.state = np.zeros(_G_N)  # the last accepted and last finite observations (_G_*)
        self._inside: Callable[[Sequence[float]], bool] | None = None
        self.cone: ConeWorkspace | None = None  # the workspace, when it is a cone

    @property
    def rejected(self) -> int:
        """Observations rejected this episode."""
        return int(self.state[_G_REJECTED])

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
        self.state[:] = 0.0
        self.cone = cone
        self._inside = cone.contains if cone is not None else inside

    def accept(self, t: float, p_world: Sequence[float], n_world: Sequence[float]) -> bool:
        """Whether to use the ring centre ``p_world`` (3,), m, and unit normal (3,) seen at t."""
        p, n = p_world, n_world
        x = (float(p[0]), float(p[1]), float(p[2]), float(n[0]), float(n[1]), float(n[2]))
        decision = _gate_decide_kernel(self.state, self.bounds, float(t), x)
        ok = decision == 1 or (
            decision == 2 and (self._inside is None or self._inside([x[0], x[1], x[2]]))
        )
        gate_commit(self.state, t, x, ok)
        return ok
