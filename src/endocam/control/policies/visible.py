r"""``endocam-visible``: the ``endocam`` tracker, turned to where the touch can be seen.

The paper's orientation view looks along the ring normal, and the normal runs nearly along the
wire: from one end the wire's near part leans over the ring's hole and hides the gap that
closes at a touch. This camera keeps everything of :class:`EndocamPolicy` (the ring centred at
the working distance, prediction, orbits, and every safety rule: the input checks and the
observation gate, the cone freeze, the wire clearance and its detours, the floor, the carriers'
speed and joint limits) and changes one thing: the **viewing axis** it holds the camera on.

Every ``score_period`` s it predicts the ring poses over the next ``lookahead`` s
(``horizon_poses`` of them, beyond the sensing delay; constant velocity from the poses the
tracker's checks and gate accepted, :func:`predicted_pose`) and scores the one where the gap
closes: the prediction **stops at contact**: between the last pose whose
rim is clear of the closing gap ``GAP_M`` and the first that is not, the pose where the rim's
clearance comes down to ``GAP_M`` (:func:`closing_fraction`, :func:`pose_between`); with no
such pose, the closest (a constant velocity carries the ring into the wire, where the gap's
geometry means nothing; the wire stops it, and the touch is where it meets it). The camera
is then on the good view when the gap closes rather than a scoring period, a tilt and an
arm's lag after. If that ring's rim is no closer to the wire than ``engage_clearance``, no
touch is near: nothing is scored, the axis goes back to the normal (the orientation error is
paid only ahead of a likely touch) and the side is held. Otherwise it
scores candidate axes from the predicted ring pose and the pre-operative wire model
(:mod:`endocam.control.occlusion`, compiled in :mod:`endocam.control.sightline`); the scorer
never reads the true ring pose or the touches. On the side ``s = ±1`` the camera is on, the
normal ``s n`` itself (as the tracker takes it, held above the floor) and the directions tilted
``θ ∈ tilts`` (at most ``max_tilt``) off it at ``azimuths`` angles around it; on the other
side, the tracker's own view. A candidate's score is the weighted share of the rim's likely
contact points whose 0.5 mm gap the better of the two eyes (``either_eye``: the study counts a
gap seen from either) would see clear of the wire, the handle and the rim, and resolved
(``resolved_px``), times the **urgency** ``exp(−c / urgency_scale)`` of the rim's clearance
``c`` to the wire (far from a touch, no view is worth a tilt). The side is chosen on that
score; the tilt on a second one, of the **predicted contact's neighbourhood** alone
(``contact_arc``: the rim within 1 mm of arc either side of its point nearest the wire, its
gap points equally weighted, :func:`~endocam.control.occlusion.contact_points`): a
fraction of a millimetre of where the ring touches decides whether the wire's near part
hides it, and the whole rim's share rated well views that hid the contact. Its utility
is the score less ``tilt_cost`` × the orientation error it is expected to pay: its tilt (or the
floor's turn) and its angle beyond ``port_angle`` (an arm concedes a view its wrist cannot
reach). A tilted candidate whose camera would leave the cone (``cone_slack``), go under the
floor or near the wire's clearance zone (``wire_slack``), or turn the view farther from the
port than ``port_angle``, is not taken; the tracker's own view always may be (the tracker and
its guard handle it as before).

* **Tilt** (on the side the camera is on): the best candidate becomes the target when its
  utility beats the current target's by ``tilt_margin``. The axis moves towards the target
  (ruckig) at most at ``tilt_rate`` (rad/s of the offset) and ``tilt_acceleration``, never in
  a jump of its angle or of its rate.
* **Side**: the first is the tracker's (above the feature); the other side is taken only when
  its own view's utility beats this side's best by ``side_margin`` at every scoring for
  ``side_hold`` s (never for a moment's gain, :func:`choose_side`); the camera then moves there
  by the tracker's orbit (``TrackerConfig.side_transfer``), the axis back on the normal, and
  tilts again from there.

The axis reaches the tracker as the observed ring pose with its normal turned to the axis,
:math:`n' = \operatorname{normalize}(n + \tau_\perp)`, where ``τ`` (world) is the axis' offset
and :math:`\tau_\perp` its part across the observed normal (the tracker's step reads only the
ring's centre and normal): ``n'`` moves with the ring, at most ``max_tilt`` from it and at most
``tilt_rate`` faster, its rate changing by at most ``tilt_acceleration``, so the observation
gate (``ring_max_rate``, and the angle innovation it allows) and the predictor see a smooth
normal. A faulty or degenerate ring pose is passed on untouched (the checks answer it).
Without a wire model (``PolicyContext.wire``) nothing is scored and the camera is ``endocam``.

The tilt is the orientation error this camera pays for the view: ``experiment tracking``
reports it (``orientation_error_deg`` against the true normal).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from ruckig import InputParameter, OutputParameter, Result, Ruckig

from endocam.control.checks import OBS_OK
from endocam.control.config import ControllerConfig
from endocam.control.occlusion import (
    GAP_M,
    GapPoints,
    RingShape,
    contact_points,
    direction_table,
    eye_positions,
    gap_points_along,
    occluders,
    sight,
    view_directions,
    wire_window,
)
from endocam.control.plan import PlanResult
from endocam.control.policies.endocam import EndocamPolicy
from endocam.control.policies.visible_config import VisibleConfig
from endocam.control.side_view import angle, view_of
from endocam.control.sightline import view_shares, views_clear
from endocam.control.types import CameraCommand, Observation, PolicyContext
from endocam.geometry import FloatArray
from endocam.task.config import RingConfig

__all__ = [
    "Candidates",
    "SideScore",
    "VisibleConfig",
    "VisiblePolicy",
    "choose_side",
    "closing_fraction",
    "pose_between",
    "predicted_pose",
]

_ZERO = (0.0, 0.0, 0.0)
_MIN_NORMAL = 1e-9  # unitless: a shorter ring normal is degenerate (the checks answer it)
TIME_TOL_S = 1e-9  # s: round-off allowed on the scoring times (sums of periods)


@dataclass(frozen=True)
class SideScore:
    """The best view on one side at one scoring.

    ``utility``: its score less the tilt's cost (``-inf``: no candidate feasible); ``offset``:
    the axis offset ``τ`` (world) that gives it; ``current``: the utility of the side's current
    target (``-inf``: none feasible, or not this side).
    """

    utility: float
    offset: tuple[float, float, float]
    current: float = -math.inf


def choose_side(
    side: float, scores: dict[float, SideScore], since: float | None, t: float, cfg: VisibleConfig
) -> tuple[float, float | None]:
    """The side to look from after a scoring at ``t`` (s), and since when the other is better.

    ``side``: the side now (0: none yet: the better side outright); ``scores`` per side;
    ``since``: when the other side started beating this one by ``side_margin`` (``None``:
    it does not). The other side is returned only once it has done so for ``side_hold`` s.
    """
    if side == 0.0:
        return (1.0 if scores[1.0].utility >= scores[-1.0].utility else -1.0), None
    if not scores[-side].utility > scores[side].utility + cfg.side_margin:
        return side, None
    since = t if since is None else since
    if t - since >= cfg.side_hold - TIME_TOL_S:
        return -side, None
    return side, since


class VisiblePolicy(EndocamPolicy):
    """``endocam`` with its viewing axis turned to where the touch is in sight (see the module)."""

    name = "endocam-visible"

    def __init__(
        self, config: ControllerConfig | None = None, visible: VisibleConfig | None = None
    ) -> None:
        super().__init__(config)
        self.visible = visible or VisibleConfig()
        self._table = direction_table(self.visible.tilts, self.visible.azimuths)
        self._tilt = np.concatenate([[0.0], np.repeat(self.visible.tilts, self.visible.azimuths)])
        self._reset_memory()

    def _reset_memory(self) -> None:
        self._offset = _ZERO  # τ applied, world
        self._tilt_moving = False  # ruckig is moving it (its velocity is ruckig's state)
        self._tilt_target = _ZERO  # the target ruckig moves it to
        self._targets: dict[float, tuple[float, float, float]] = {1.0: _ZERO, -1.0: _ZERO}
        self._want = 0.0  # the side the scorer wants (0: none yet)
        self._since: float | None = None  # when the other side started being better
        self._next_score = -math.inf
        self.side_changes = 0  # side changes the scorer asked for this episode
        self.tilted_steps = 0  # steps the axis was off the normal this episode
        self.last_scores: dict[float, SideScore] = {}
        self.idle_scorings = 0  # scorings skipped this episode (no touch near)
        self.engaged = False  # the last scoring had a touch near
        self._track: deque[tuple[float, FloatArray]] = deque()  # accepted (t_ring s, T_ring)

    def reset(self, context: PolicyContext) -> None:
        """The tracker's reset; the axis back on the normal, no side yet."""
        super().reset(context)
        self._reset_memory()
        self._wire = context.wire
        self._shape = RingShape.of(context.ring or RingConfig())
        self._focal_px = float(context.camera.intrinsics.K[1, 1])
        self._baseline = float(context.camera.baseline)
        self._dt = context.dt
        self._window = max(self.visible.velocity_window, context.dt)
        vc = self.visible
        self._tilt_otg = Ruckig(3, context.dt)  # the offset's motion: rate- and accel-limited
        self._tilt_in, self._tilt_out = InputParameter(3), OutputParameter(3)
        self._tilt_in.max_velocity = [vc.tilt_rate / math.sqrt(3.0)] * 3
        self._tilt_in.max_acceleration = [vc.tilt_acceleration / math.sqrt(3.0)] * 3
        self._tilt_in.current_position = self._tilt_in.target_position = _ZERO  # at rest on it

    def view_axes(self, T_ring: FloatArray | None) -> tuple[FloatArray, FloatArray] | None:
        """The viewing axes (3,) the camera is turned to now, world: the target's, the applied.

        Each is a unit direction from the ring centre to the camera, from the observed ring
        pose ``T_ring`` (4, 4) and the side now. ``None``: no side yet, or no usable normal.
        For benches (what the camera was sent to look along, against where it was).
        """
        n = None if T_ring is None else _unit_normal(np.asarray(T_ring, dtype=float))
        side = self._side if self._side != 0.0 else self._want
        if n is None or side == 0.0:
            return None
        n_arr = np.array(n)
        return _axis(side, n_arr, self._targets[side]), _axis(side, n_arr, self._offset)

    # -- the side ----------------------------------------------------------------------------

    def _preferred_side(self) -> float:
        """The scorer's side while the camera is not on it (the tracker then orbits there)."""
        return self._want if self._want != self._side else 0.0

    # -- the axis ----------------------------------------------------------------------------

    def _plan_step(self, obs: Observation, T_cam: FloatArray, T_ring: FloatArray) -> PlanResult:
        """The tracker's step on the ring pose with its normal turned to the viewing axis."""
        t = float(obs.t)
        t_ring = t if obs.t_ring is None else float(obs.t_ring)
        n = _unit_normal(T_ring)
        if n is not None and self._wire is not None and t >= self._next_score:
            self._next_score = t + self.visible.score_period
            self._score(self._ahead_poses(T_ring, t_ring, t), t)
        self._advance()
        ox, oy, oz = self._offset
        if n is None or (ox == 0.0 and oy == 0.0 and oz == 0.0):
            plan = super()._plan_step(obs, T_cam, T_ring)
        else:
            self.tilted_steps += 1
            plan = super()._plan_step(obs, T_cam, _turned(T_ring, n, self._offset))
        if plan.check == OBS_OK and n is not None:  # the gate took it: a sample to predict from
            self._track.append((t_ring, T_ring.copy()))  # (the caller may reuse its array)
            while len(self._track) > 2 and self._track[1][0] <= t_ring - self._window:
                self._track.popleft()
        return plan

    def _lose(self, reason: str) -> CameraCommand:
        """The tracker's lost tracking; the prediction's samples are forgotten too."""
        self._track.clear()
        return super()._lose(reason)

    def _predicted(self, T_ring: FloatArray, t_ring: float, t_ahead: float) -> FloatArray:
        """The ring pose (4, 4) at ``t_ahead`` (s) from the observed ``T_ring`` stamped ``t_ring``.

        :func:`predicted_pose` from the oldest accepted pose within ``velocity_window`` (only
        poses the tracker's checks and gate took). Without an older pose: ``T_ring`` itself.
        """
        if not self._track:
            return T_ring
        t_old, T_old = self._track[0]
        return predicted_pose(
            T_old, T_ring, t_ring - t_old, t_ahead - t_ring, self.visible.max_predicted_turn
        )

    def _ahead_poses(self, T_ring: FloatArray, t_ring: float, t: float) -> list[FloatArray]:
        """The ring poses (4, 4) predicted over the horizon, the step's own first.

        ``horizon_poses`` poses evenly spaced from ``t`` to ``t + lookahead`` (s): the
        delay-bridged present ... the ``lookahead`` one (one pose: that one alone).
        """
        vc = self.visible
        n = vc.horizon_poses
        if n == 1:
            return [self._predicted(T_ring, t_ring, t + vc.lookahead)]
        return [self._predicted(T_ring, t_ring, t + vc.lookahead * k / (n - 1)) for k in range(n)]

    def _advance(self) -> None:
        """Move the applied offset one step towards the current side's target (ruckig).

        At most ``tilt_rate`` and ``tilt_acceleration`` (per axis over √3): the turned normal
        the tracker is given changes smoothly, never by a jump of its rate.
        """
        side = self._side if self._side != 0.0 else self._want
        target = self._targets.get(side, _ZERO)
        if target == self._offset and not self._tilt_moving:
            return
        inp, out = self._tilt_in, self._tilt_out
        if target != self._tilt_target:  # a new target: ruckig plans afresh from where it is
            inp.target_position = self._tilt_target = target
        result = self._tilt_otg.update(inp, out)
        out.pass_to_input(inp)  # ruckig's state carries on from its own step
        if result == Result.Finished:  # there this step: on the target exactly, at rest
            self._offset, self._tilt_moving = target, False
        elif result == Result.Working:
            x, y, z = out.new_position
            self._offset, self._tilt_moving = (x, y, z), True
        else:
            raise RuntimeError(f"ruckig failed to move the viewing axis towards {target}")

    # -- the scoring -------------------------------------------------------------------------

    def _score(self, T_rings: list[FloatArray], t: float) -> None:
        """Score the candidates where the gap is predicted to close, and decide.

        ``T_rings`` (4, 4) the ring poses predicted over the horizon (:meth:`_ahead_poses`).
        The pose scored is where the rim comes within ``GAP_M`` (the closing gap) of the wire
        (interpolated between the poses either side of it), else the one whose rim comes
        closest: constant velocity carries a
        ring through the wire, but the touch (and the gap the study judges) is where it meets
        it.
        This side's target and the wanted side are updated. When no pose's rim comes within
        ``engage_clearance`` of the wire nothing is scored: the target goes back to the normal
        and the side is held.
        """
        wire, vc = self._wire, self.visible
        assert wire is not None
        if not all(np.isfinite(T).all() for T in T_rings):
            return
        window = wire_window(wire, T_rings[len(T_rings) // 2][:3, 3], vc.window)
        closing: tuple[FloatArray, GapPoints, float] | None = None
        rims: list[float] = []
        along = self._gaps(T_rings, window)  # every pose's at once; read until the gap closes
        for T, gaps in zip(T_rings, along, strict=True):
            rims.append(float(np.min(gaps.clearances)))  # the rim's to the wire, m
            if closing is None or rims[-1] < closing[2]:
                closing = (T, gaps, rims[-1])
            if rims[-1] <= GAP_M:  # the gap closes here
                break
        assert closing is not None
        k, f = closing_fraction(np.array(rims), GAP_M)
        if k > 0 and f < 1.0:  # stop the prediction where the gap closes
            T = pose_between(T_rings[k - 1], T_rings[k], f)
            gaps = self._gaps([T], window)[0]
            closing = (T, gaps, float(np.min(gaps.clearances)))
        T_ring, gaps, nearest = closing[0], closing[1], max(closing[2], 0.0)
        p_c = T_ring[:3, 3]
        n = _unit_normal(T_ring)
        side_now = self._side if self._side != 0.0 else self._want
        if n is None:
            return
        self.engaged = nearest <= vc.engage_clearance
        if not self.engaged:  # no touch near: the normal, the side held
            self.idle_scorings += 1
            self._since = None
            if side_now != 0.0:
                self._targets[side_now] = _ZERO
            return
        n_arr = np.array(n)
        if side_now == 0.0:  # the tracker's first side: above the feature
            side_now = 1.0 if n[2] >= 0.0 else -1.0
        c = self._candidates(p_c, n_arr, side_now)
        left, right = eye_positions(p_c, c.dirs, self.d_f, self._baseline)
        feasible, beyond = self._feasible(c, p_c, left + 0.5 * (right - left))
        eyes, axes = np.vstack([left, right]), np.vstack([-c.dirs, -c.dirs])
        occ = occluders(window, wire.radius, T_ring, self._shape)
        urgency = math.exp(-nearest / vc.urgency_scale)  # a touch near: the view matters
        cost = vc.tilt_cost * (c.tilt + beyond)  # the orientation error it is expected to pay
        scored = np.concatenate([feasible, feasible])  # an infeasible view's eyes: share 0
        focal, px = self._focal_px, vc.resolved_px
        shares = view_shares(eyes, axes, sight(gaps, focal, px), occ, scored)
        rim = self._utility(shares, urgency, cost, feasible)  # the side's: the whole rim's
        near = rim  # the tilt's: the whole rim's, or the contact's neighbourhood's
        if vc.contact_arc > 0.0:
            arc, count = vc.contact_arc, vc.contact_points
            contact = contact_points(T_ring, window, self._shape, wire.radius, arc, count)
            shares = view_shares(eyes, axes, sight(contact, focal, px), occ, scored)
            near = self._utility(shares, urgency, cost, feasible)
        k = c.per_side
        j = int(np.argmax(near[:k]))
        offset = _ZERO if j == 0 else _offset_of(side_now, n_arr, c.dirs[j])
        now = near[0] if self._targets[side_now] == _ZERO else near[k + 1]
        scores = {
            side_now: SideScore(float(np.max(rim[:k])), offset, float(now)),
            -side_now: SideScore(float(rim[k]), _ZERO),  # the other side: its own view
        }
        self.last_scores = scores
        want, self._since = choose_side(side_now, scores, self._since, t, vc)
        if want != self._want and self._want != 0.0:
            self.side_changes += 1
        self._want = want
        if near[j] > now + vc.tilt_margin:
            self._targets[side_now] = offset
        self._targets[-side_now] = _ZERO  # a new side starts on its own view

    def _utility(
        self, shares: FloatArray, urgency: float, cost: FloatArray, feasible: np.ndarray
    ) -> FloatArray:
        """(C,) each candidate's utility: its score less ``cost`` (C,), −inf if not feasible.

        ``shares`` (2C,): the left eyes' shares, then the right eyes'; the score is the
        better eye's (``either_eye``) or their mean, times ``urgency``.
        """
        m = len(cost)
        if self.visible.either_eye:  # the better eye's share: the study counts either eye
            score = urgency * np.maximum(shares[:m], shares[m:])
        else:
            score = urgency * 0.5 * (shares[:m] + shares[m:])
        return np.asarray(np.where(feasible, score - cost, -np.inf), dtype=float)

    def _gaps(self, T_rings: list[FloatArray], window: FloatArray) -> list[GapPoints]:
        """The gap points of the ring at each pose (4, 4) of ``T_rings``, in one batch.

        By the wire's ``window`` (K, 3) (:func:`~endocam.control.occlusion.gap_points_along`).
        """
        vc, wire = self.visible, self._wire
        assert wire is not None
        return gap_points_along(T_rings, window, self._shape, wire.radius, vc.rim_points,
                                vc.weight_scale)  # fmt: skip

    def _candidates(self, p_c: FloatArray, n: FloatArray, side: float) -> Candidates:
        """The candidate axes: this ``side``'s, the other side's own view, this side's target.

        This side's are led by the tracker's own view (on the normal, or held above the
        floor), then the tilted ones; the other side is judged by the tracker's own view
        there (a side change starts from it).
        """
        mine = side * view_directions(n, self._table)  # (C, 3), the first side·n itself
        dirs = np.vstack([mine, -mine[:1], _axis(side, n, self._targets[side])[None]])
        tilt = np.concatenate([self._tilt, [0.0, 0.0]])
        tilt[-1] = _angle(dirs[-1], side * n)
        p, nn = (float(p_c[0]), float(p_c[1]), float(p_c[2])), (float(n[0]), float(n[1]),
                                                                 float(n[2]))  # fmt: skip
        for i, s in ((0, side), (len(mine), -side)):
            base = view_of(self._view_rule, p, nn, s, self.d_f)
            if base.found:
                dirs[i] = base.u  # the tracker's own view (held above the floor)
                tilt[i] = base.error
        return Candidates(dirs, tilt, len(mine))

    def _feasible(
        self, c: Candidates, p_c: FloatArray, centres: FloatArray
    ) -> tuple[np.ndarray, FloatArray]:
        """(C,) whether each candidate may be taken, and how far beyond the port angle, rad.

        The tracker's own views always; a tilted one above the floor, inside the cone by
        ``cone_slack``, clear of the wire by ``wire_slack``, and no farther than ``port_angle``
        from the port's line (or than the tracker's own view). ``centres`` (C, 3): the cameras,
        world, m. Beyond ``port_angle`` an arm concedes the view: that angle is expected
        orientation error.
        """
        vc = self.visible
        assert self._wire is not None and self._ctx is not None
        port = p_c - np.asarray(self._ctx.p_world_rcm, dtype=float)
        port = port / max(float(np.linalg.norm(port)), _MIN_NORMAL)
        cos_port = -(c.dirs @ port)  # the optical axis is -dir
        bases = np.zeros(len(c.dirs), dtype=bool)
        bases[[0, c.per_side]] = True
        limit = np.full(len(c.dirs), min(math.cos(vc.port_angle), cos_port[0]))
        assert self.guard is not None  # a wire model: its guard
        slack = np.array([vc.cone_slack, vc.wire_slack])
        ok = cos_port >= limit
        ok &= views_clear(centres, self._view_rule.cone, self._aim_floor, self.guard.kernel_state,
                          slack)  # fmt: skip
        beyond = np.maximum(np.arccos(np.clip(cos_port, -1.0, 1.0)) - vc.port_angle, 0.0)
        return ok | bases, beyond


class Candidates(NamedTuple):
    """Candidate viewing axes at one scoring.

    ``dirs`` (C, 3) unit directions from the ring centre to the camera, world: this side's
    ``per_side`` (the tracker's own view first), the other side's own view, then this side's
    current target axis; ``tilt`` (C,) each one's angle off its side's normal, rad.
    """

    dirs: FloatArray
    tilt: FloatArray
    per_side: int


def predicted_pose(
    T_old: FloatArray, T_now: FloatArray, tau: float, h: float, max_turn: float
) -> FloatArray:
    r"""The pose (4, 4) ``h`` s after ``T_now`` at the constant velocity from ``T_old`` to it.

    ``T_old``, ``T_now`` (4, 4) world poses ``tau`` s apart (``tau ≤ 0``: ``T_now`` itself).
    First order, as the tracker's predictor (:mod:`endocam.control.predictor`): the centre
    and the frame's z and x axes are extrapolated linearly, :math:`a + (a - a_0)\,k`, and
    the axes made orthonormal again (z first); :math:`k = h/\tau`, cut so that the normal's
    turn since ``T_old`` times ``k`` is at most ``max_turn`` rad.
    """
    T_now = np.asarray(T_now, dtype=float)
    if not tau > TIME_TOL_S:
        return T_now.copy()
    k = h / tau
    a, b = T_now.tolist(), np.asarray(T_old, dtype=float).tolist()  # rows; 3-vectors in floats
    p = [a[i][3] + (a[i][3] - b[i][3]) * k for i in range(3)]
    cos_turn = a[0][2] * b[0][2] + a[1][2] * b[1][2] + a[2][2] * b[2][2]
    turn = math.acos(min(1.0, max(-1.0, cos_turn)))
    if turn * k > max_turn:
        k = max_turn / turn
    z = [a[i][2] + (a[i][2] - b[i][2]) * k for i in range(3)]
    x = [a[i][0] + (a[i][0] - b[i][0]) * k for i in range(3)]
    z_len = math.sqrt(z[0] * z[0] + z[1] * z[1] + z[2] * z[2])
    z = [z[0] / z_len, z[1] / z_len, z[2] / z_len]
    xz = x[0] * z[0] + x[1] * z[1] + x[2] * z[2]
    x = [x[0] - xz * z[0], x[1] - xz * z[1], x[2] - xz * z[2]]
    x_len = math.sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2])
    T = np.eye(4)
    T[:3, 3] = p
    if not x_len > _MIN_NORMAL:  # a half turn extrapolated: the newest frame's axes
        T[:3, :3] = T_now[:3, :3]
        return T
    x = [x[0] / x_len, x[1] / x_len, x[2] / x_len]
    y = [z[1] * x[2] - z[2] * x[1], z[2] * x[0] - z[0] * x[2], z[0] * x[1] - z[1] * x[0]]
    T[:3, :3] = np.array([x, y, z]).T
    return T


def closing_fraction(clearances: FloatArray, gap: float) -> tuple[int, float]:
    """Where along a predicted path the rim's clearance first comes down to ``gap``.

    ``clearances`` (H,): the rim's clearance to the wire (m) at H poses evenly along the path;
    ``gap`` m. Returns ``(k, f)``: the closing lies a fraction ``f`` in ``[0, 1]`` of the way
    from pose ``k − 1`` to pose ``k`` (the secant through their clearances: a ring moving
    straight at the wire closes its gap linearly). ``(0, 1.0)``: closed at the first pose
    already; ``(H − 1, 1.0)``: not within the path (or a path of one pose).
    """
    c = np.asarray(clearances, dtype=float)
    below = np.flatnonzero(c <= gap)
    if len(below) == 0:
        return len(c) - 1, 1.0
    k = int(below[0])
    if k == 0:
        return 0, 1.0
    drop = float(c[k - 1] - c[k])  # > 0: c[k-1] > gap ≥ c[k]
    return k, min(1.0, max(0.0, float(c[k - 1] - gap) / drop))


def pose_between(T_a: FloatArray, T_b: FloatArray, f: float) -> FloatArray:
    """The pose (4, 4) a fraction ``f`` of the way from ``T_a`` to ``T_b`` (4, 4), world.

    The first-order interpolation of :func:`predicted_pose` (centre, z and x axes linear,
    the axes made orthonormal again): the two poses lie on one predicted path, so this is
    the prediction at the time between them.
    """
    return predicted_pose(T_a, T_b, 1.0, f - 1.0, math.inf)


def _unit_normal(T_ring: FloatArray) -> tuple[float, float, float] | None:
    """The ring pose's unit normal (its z column), or ``None``.

    ``None``: the normal is not finite or degenerate (the tracker's checks answer it).
    """
    x, y, z = float(T_ring[0, 2]), float(T_ring[1, 2]), float(T_ring[2, 2])
    length = math.sqrt(x * x + y * y + z * z)
    if not (math.isfinite(length) and length > _MIN_NORMAL):
        return None
    return (x / length, y / length, z / length)


def _turned(
    T_ring: FloatArray, n: tuple[float, float, float], offset: tuple[float, float, float]
) -> FloatArray:
    """``T_ring`` (4, 4) with its normal turned to ``normalize(n + τ⊥)`` (a new array)."""
    k = offset[0] * n[0] + offset[1] * n[1] + offset[2] * n[2]
    a = (n[0] + offset[0] - k * n[0], n[1] + offset[1] - k * n[1], n[2] + offset[2] - k * n[2])
    length = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    T = T_ring.copy()
    T[0, 2], T[1, 2], T[2, 2] = a[0] / length, a[1] / length, a[2] / length
    return T


def _offset_of(s: float, n: FloatArray, v: FloatArray) -> tuple[float, float, float]:
    """The offset ``τ ⟂ n`` (world) whose axis ``s normalize(n + τ)`` is ``v`` (unit, world)."""
    a = s * v
    tau = a / float(a @ n) - n
    return (float(tau[0]), float(tau[1]), float(tau[2]))


def _axis(s: float, n: FloatArray, offset: tuple[float, float, float]) -> FloatArray:
    """The viewing direction ``s normalize(n + τ⊥)`` (3,) of an offset, world."""
    k = offset[0] * n[0] + offset[1] * n[1] + offset[2] * n[2]
    a = (n[0] + offset[0] - k * n[0], n[1] + offset[1] - k * n[1], n[2] + offset[2] - k * n[2])
    length = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    return np.array([s * a[0] / length, s * a[1] / length, s * a[2] / length])


def _angle(a: FloatArray, b: FloatArray) -> float:
    """Angle between unit vectors (3,), rad (:func:`~endocam.control.side_view.angle`)."""
    return angle((float(a[0]), float(a[1]), float(a[2])), (float(b[0]), float(b[1]), float(b[2])))
