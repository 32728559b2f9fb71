r"""The ``oracle``: a non-causal reference camera that knows the ring's whole future.

It is the reference of ``endocam experiment tracking`` (a bound only for controllers of
endocam's design: it shares their first approach from the start view): the same goal as the
``endocam`` tracker (the paper's orientation goal, Sec. III-B, kept on one side, left eye on the
ring centre), the same safety rules (cone freeze, tool-in-view windows, ``min_camera_height``)
and the same carrier with the same motion limits, but perfect information:

1. **No sensing delay.** The ring pose it acts on is the true pose now, not the one
   ``sensing_latency`` old that causal policies see (``PolicyContext.future``).
2. **The true future instead of a prediction.** The goal is the view of the true ring pose
   ``lead`` seconds ahead (the carrier's lag), and the goal's exact velocity (differenced
   over one control period of the true trajectory) goes to the carrier as its target velocity
   (``CameraCommand.twist``), so steady motion is followed without lag.
3. **An offline side plan.** Before the episode, a dynamic programme over a time grid chooses
   for every time the side ``s = ±1`` the camera looks from, minimising

   .. math::

       \sum_j e_{s_j}(t_j)\,\Delta t + C \cdot \#\{j : s_j \ne s_{j-1}\}

   where :math:`e_s(t)` is the angle between the feasible view on side ``s`` (above
   ``min_camera_height``, inside the cone; see ``EndocamPolicy._view``) and the ring normal,
   rad (an infeasible view costs :data:`INFEASIBLE_COST`), and ``C`` (rad·s) is the orientation
   error a side change costs (the orbit to the other side). At run time the camera follows the
   plan's side ``switch_lead`` seconds ahead, so an orbit is centred on the planned change; a
   planned side whose view is infeasible now falls back to the tracker's side keeping.

The policy is a subclass of :class:`~endocam.control.policies.endocam.EndocamPolicy` whose
predictions are read from a table of the true trajectory (sampled once at reset: no scipy per
step).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from endocam.control.config import ControllerConfig
from endocam.control.policies.endocam import EndocamPolicy
from endocam.control.types import CameraCommand, Observation, PolicyContext
from endocam.geometry import FloatArray
from endocam.kernels import Vec

__all__ = ["INFEASIBLE_COST", "OracleConfig", "OraclePolicy", "RingFuture", "plan_sides"]

INFEASIBLE_COST = math.pi  # rad: per-time cost of a side with no feasible view in the plan
TIE_BREAK = 1e-6  # rad: extra cost of the side below the feature (equal views: the paper's side)


@dataclass(frozen=True)
class OracleConfig:
    """Parameters of the oracle (SI).

    Attributes
    ----------
    lead : float or None
        How far ahead of now the goal is taken, s (the carrier's lag; > 0); ``None``: the
        tracker's ``carrier_lead``, the same lag the causal tracker predicts across.
    feedforward_gain : (2,)
        Gains on the linear and angular parts of the goal velocity given to the carrier (the
        jerk-limited carrier overshoots the corners of a noisy path with the full velocity:
        0.5 measured best, as for the tracker).
    plan_dt : float
        Time step of the side plan, s.
    switch_cost : float
        Orientation error a side change costs in the plan, rad·s (an orbit: about 2–3 s near 90°
        off the normal; 5 measured better than 2).
    switch_lead : float
        How far ahead the run time reads the plan's side, s (about half an orbit).
    velocity_window : float
        The goal velocity given to the carrier is the goal's mean velocity over this window,
        centred on the goal's time, s (the carrier is jerk-limited: the exact velocity of a
        trajectory with corners makes it overshoot; a centred mean needs the future).
    plan : bool
        Follow the offline side plan; off (the default): the tracker's side keeping on the true
        future. The plan weighs only the cone and the floor, not a carrier's reach: on the PSM
        it chose a side the wrist cannot reach (study path t1-36-low: 43° against 2.6°).
    """

    lead: float | None = None
    feedforward_gain: tuple[float, float] = (0.5, 0.5)
    plan_dt: float = 0.05
    switch_cost: float = 5.0
    switch_lead: float = 1.0
    velocity_window: float = 0.03
    plan: bool = False

    def __post_init__(self) -> None:
        for name in ("lead", "plan_dt", "velocity_window"):
            if getattr(self, name) is not None and not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be > 0 s, got {getattr(self, name)}")
        if not self.switch_cost >= 0.0 or not self.switch_lead >= 0.0:
            raise ValueError("switch_cost and switch_lead must be ≥ 0")


class RingFuture:
    """The true ring trajectory sampled on a fixed grid, read with plain floats.

    Parameters
    ----------
    T_world_ring : (N, 4, 4)
        True ring poses at ``t_k = k dt``, world, m.
    dt : float
        Grid period, s.
    """

    def __init__(self, T_world_ring: FloatArray, dt: float) -> None:
        T = np.asarray(T_world_ring, dtype=float)
        if T.ndim != 3 or T.shape[1:] != (4, 4) or len(T) < 1:
            raise ValueError(f"T_world_ring must be (N, 4, 4), got {T.shape}")
        self.dt = float(dt)
        self.poses = T
        self._rows = np.concatenate([T[:, :3, 3], T[:, :3, 2]], axis=1).tolist()

    @classmethod
    def of(cls, context: PolicyContext, pad: float) -> RingFuture:
        """Sample ``context.future`` every ``context.dt`` over the episode plus ``pad`` s."""
        if context.future is None:
            raise ValueError("the oracle needs PolicyContext.future (the true ring trajectory)")
        n = math.floor((context.future_duration + pad) / context.dt + 1e-9) + 2
        return cls(context.future(np.arange(n, dtype=float) * context.dt), context.dt)

    def index(self, t: float) -> int:
        """Grid index nearest to ``t`` (s), clamped."""
        return min(max(round(t / self.dt), 0), len(self._rows) - 1)

    def at(self, t: float) -> tuple[Vec, Vec]:
        """True ring centre (m) and unit normal in world at ``t`` (s), linearly interpolated."""
        x = t / self.dt
        last = len(self._rows) - 1
        k = min(max(math.floor(x), 0), last)
        a = self._rows[k]
        if k >= last or x <= k:
            b, f = a, 0.0
        else:
            b, f = self._rows[k + 1], x - k
        v = [a_i + f * (b_i - a_i) for a_i, b_i in zip(a, b, strict=True)]
        length = math.sqrt(v[3] * v[3] + v[4] * v[4] + v[5] * v[5])
        n = (v[3] / length, v[4] / length, v[5] / length) if length > 0.0 else (a[3], a[4], a[5])
        return (v[0], v[1], v[2]), n


def plan_sides(cost: FloatArray, switch_cost: float) -> list[float]:
    r"""Cheapest side sequence over a time grid (Viterbi over two states).

    Parameters
    ----------
    cost : (M, 2)
        Cost of looking from side ``+1`` (column 0) and ``−1`` (column 1) during grid step
        ``j``, rad·s.
    switch_cost : float
        Cost of one side change, rad·s.

    Returns
    -------
    list of float
        (M,) the side ``±1.0`` at each grid step; the first side is free.
    """
    c = np.asarray(cost, dtype=float)
    m = len(c)
    if m == 0:
        return []
    acc = c[0].copy()
    back = np.zeros((m, 2), dtype=int)
    for j in range(1, m):
        stay, swap = acc, acc[::-1] + switch_cost
        back[j] = np.where(stay <= swap, [0, 1], [1, 0])
        acc = np.minimum(stay, swap) + c[j]
    i = int(np.argmin(acc))
    path = [i]
    for j in range(m - 1, 0, -1):
        i = int(back[j, i])
        path.append(i)
    return [1.0 if i == 0 else -1.0 for i in reversed(path)]


class OraclePolicy(EndocamPolicy):
    """The non-causal reference: the ``endocam`` goal with the true, undelayed future.

    It ignores the sensed ring pose (so it never enters ``lost_tracking``): it exists to
    measure, not to run on a robot.

    See the module docstring. ``reset`` raises ``ValueError`` without ``PolicyContext.future``.
    """

    name = "oracle"
    _given = True  # the compiled step gets the true future (``_give_predictions``)

    def __init__(
        self, config: ControllerConfig | None = None, oracle: OracleConfig | None = None
    ) -> None:
        config = config or ControllerConfig()
        self.oracle = oracle or OracleConfig()
        tracker = config.tracker.model_copy(
            update={
                "keep_side": True,
                "predict": True,
                "feedforward": True,
                "feedforward_gain": self.oracle.feedforward_gain,
            }
        )
        super().__init__(config.model_copy(update={"tracker": tracker}))
        self._future: RingFuture | None = None
        self._plan: list[float] = []

    def reset(self, context: PolicyContext) -> None:
        """Tracker state, the true-trajectory table and the side plan for a new episode."""
        super().reset(context)
        o = self.oracle
        lead = self.tracker.carrier_lead if o.lead is None else o.lead
        self._future = RingFuture.of(context, lead + o.switch_lead + context.dt)
        self._now = 0.0  # s, the time of the step under way
        self._horizon = lead
        self._plan = self._side_plan(context.future_duration) if o.plan else []

    def _side_plan(self, duration: float) -> list[float]:
        """The side for every ``plan_dt`` over ``[0, duration]`` (see the module docstring)."""
        assert self._future is not None
        dt = self.oracle.plan_dt
        m = math.floor(duration / dt + 1e-9) + 1
        d = self.config.d_f
        cost = np.empty((m, 2))
        for j in range(m):
            p_c, n = self._future.at(j * dt)
            for i, s in enumerate((1.0, -1.0)):
                view = self._view(p_c, n, s, d)
                ok = view is not None and view[2] >= 0.0
                err = view[1] if ok and view is not None else INFEASIBLE_COST
                below = s * n[2] < 0.0  # ties go to the paper's side, above the feature
                cost[j, i] = (err + (TIE_BREAK if below else 0.0)) * dt
        return plan_sides(cost, self.oracle.switch_cost)

    def _preferred_side(self) -> float:
        """The plan's side ``switch_lead`` s from now, taken while feasible (0.0: no plan)."""
        if not self._plan:
            return 0.0
        t = self._now + self.oracle.switch_lead
        j = min(max(round(t / self.oracle.plan_dt), 0), len(self._plan) - 1)
        return self._plan[j]

    def _give_predictions(self, t: float, predictions: FloatArray) -> None:
        """The true ring centre (m) and unit normal ``horizon`` and ``horizon + dt`` s after ``t``.

        Written into ``predictions`` (12,), the compiled step's (it predicts nothing itself).
        """
        assert self._future is not None and self._ctx is not None  # set by reset()
        self._now = t
        p1, n1 = self._future.at(t + self._horizon)
        p2, n2 = self._future.at(t + self._horizon + self._ctx.dt)
        predictions[:] = (*p1, *n1, *p2, *n2)

    def _feedforward_twist(self, goal: FloatArray, twist: FloatArray, d_f: float) -> FloatArray:
        """(6,) the goal's mean velocity over ``velocity_window`` centred on ``lead`` from now.

        Linear (m/s) then angular (rad/s), world; the tracker's one-period ``twist`` of
        ``goal`` (4, 4) is replaced by the goals' difference at the window's ends on the
        current side (kept where either end has no feasible view); ``d_f`` the step's working
        distance, m.
        """
        assert self._future is not None  # set by reset()
        w = self.oracle.velocity_window
        t = self._horizon
        poses = []
        for h in (t - 0.5 * w, t + 0.5 * w):
            p_c, n = self._future.at(self._now + h)
            view = self._view(p_c, n, self._side, d_f)
            if view is None:
                return twist
            poses.append(self._pose(p_c, view[0], d_f, goal))
        return EndocamPolicy._twist(poses[0], poses[1], w)

    def step(self, obs: Observation) -> CameraCommand:
        """One step on the true ring pose now (no sensing delay, fresh), whatever ``obs`` sensed."""
        future = self._future
        if future is None:
            raise RuntimeError("call reset() before step()")
        T_true = future.poses[future.index(obs.t)]
        return super().step(obs._replace(T_world_ring=T_true, t_ring=obs.t))
