r"""The ``endocam`` tracker: the paper's orientation goal, followed with less lag and fewer jumps.

The goal is the paper's (Sec. III-B): the camera looks at the ring centre ``p_c`` along the ring
normal ``n`` from the working distance ``d_f`` with a level horizon, under the same safety rules
(cone freeze, tool-in-view windows, lost tracking). What changes is how it is followed; each
ingredient has a switch in :class:`~endocam.control.config.TrackerConfig`:

1. **Keep the side** (``keep_side``). The camera looks from side ``s = ±1`` (position
   ``p_c + s d_f u``). The first side is the paper's, above the feature (``s n·up ≥ 0``). It is
   then kept while its view is feasible: with ``c = (h_min − p_c·up) / d_f`` the direction
   ``u`` is ``s n`` when ``s n·up ≥ c``, else the nearest direction on the sphere with
   ``u·up = c`` (the camera stays ``h_min`` above the board and still looks at ``p_c``), and
   the camera must be inside the cone. The side changes only when the kept view turns more than
   ``side_change_angle`` from the normal (or leaves the cone) and the other side is better.
2. **Orbit transfers** (``side_transfer``). A side change moves the camera along a great
   circle about ``p_c`` at the look distance (over the top when the ends are opposite),
   looking at ``p_c`` with a level horizon, so the ring stays centred; the paper's way-points
   remain available.
3. **Latency compensation** (``predict``, ``feedforward``). The ring's velocity and
   acceleration are differenced from the delayed observations and its pose is extrapolated
   across the sensing delay plus the carrier's lead; the goal's twist (velocity) goes to the
   carrier as its target velocity so steady motion is followed without lag.
4. **Left-eye centring** (``ControllerConfig.centre_left_eye``). The image error is measured
   in the left eye (paper Sec. V), so the left eye's optical axis, ``b/2`` left of the
   midpoint, is put through ``p_c``: the camera is shifted by ``+b/2`` along its x axis.
5. **Direct first approach** (``first_approach``): from the overview pose (and after a freeze
   or lost tracking) the camera goes straight for the goal under its limits.
6. **Shorter look when low** (``shorten_when_low``). When the kept side's view is
   height-limited (``s n·up < c``: a ring low over the board, its normal pointing down on the
   kept side), the camera is held at ``min_camera_height`` and turned off the normal by up to
   tens of degrees. Shortening the look distance ``d`` raises ``c``'s bound ``s n·up ≥ (h_min −
   p_c·up)/d``, so the view turns back to the normal: while every tool tip is between the
   windows (where the paper's rule would hold ``d_f``), ``d_f`` shrinks by ``d_f_step`` per
   step, down to ``d_min`` and only while every tip stays inside the outer window of the
   shortened goal. A tip outside the outer window still lengthens ``d_f`` (safety first).

The step's numbers, from the input checks to the view, its twist and the wire guard's answer,
are one compiled call (:func:`~endocam.control.plan.plan_step`, with named settings, memory and
result); its decisions (freeze, transfer, orbit, way-points, detour, the last gate) are the
Python below. The working distance is committed only with a command (``MovingPolicy._issue``).
``tests/test_tracker_kernel.py`` pins the pieces to numpy and scipy and the episodes to the
safety invariants.
"""

from __future__ import annotations

import math

import numpy as np

from endocam.control.checks import (
    CAMERA_REASON,
    CHECK_REASONS,
    OBS_CAMERA,
    OBS_OK,
    RING_REASON,
    RingChecks,
    Sighting,
    pose_array,
    tips_array,
)
from endocam.control.config import ControllerConfig, SideRule, Transfer
from endocam.control.fixed_signature import FixedSignature
from endocam.control.goal import DistanceRange, PreviousAxes, SideChoice
from endocam.control.plan import (
    PlanResult,
    PlanSettings,
    TrackerMemory,
    inside_kernel,
    plan_step,
)
from endocam.control.planner import WaypointPath, advance, intermediate_waypoints
from endocam.control.policies.base import (
    DETOUR_REASON,
    FREEZE_RELEASE_MARGIN,
    WIRE_REASON,
    MovingPolicy,
)
from endocam.control.predictor import RingPredictor
from endocam.control.side_view import MIN_DIRECTION, ViewRule, angle, pose_of, twist_of, view_of
from endocam.control.types import CameraCommand, Observation, PolicyContext, TrackingState
from endocam.geometry import UP, FloatArray
from endocam.kernels import Vec, cross, finite_rows, unit_or_none
from endocam.view import look_at_unchecked, pose_from_columns
from endocam.workspace.cone import cone_at
from endocam.workspace.keepout import NO_KEEP_OUT

__all__ = ["EndocamPolicy"]

ORBIT_DONE_ANGLE = math.radians(1.0)  # rad: an orbit this close to its goal direction ends
FLOOR_TOL_M = 1e-9  # m: round-off allowed on the floor height of a built pose
_UP = (0.0, 0.0, 1.0)  # world up
CONE_REASON = "no view of the ring inside the cone workspace; holding"
LAST_GATE_REASON = "command would leave the cone workspace or go below the floor; holding"


class EndocamPolicy(MovingPolicy):
    """The paper's orientation goal with side keeping, orbits, prediction and left-eye centring.

    See the module docstring; the switches live in ``config.tracker``.
    """

    name = "endocam"
    _given = False  # the predictions are given (the oracle's ``_give_predictions``)

    def __init__(self, config: ControllerConfig | None = None) -> None:
        super().__init__(config)
        self.tracker = self.config.tracker
        self._predictor = RingPredictor(1)
        self._side = 0.0  # ±1 once chosen
        self._transfer: Transfer | None = None
        self._u_orbit: Vec = (0.0, 0.0, 1.0)
        self._half_b = 0.0
        self._cleared_view: FloatArray | None = None  # this step's view, cleared by the kernel
        self._view_T = np.eye(4)  # this step's view (plan_step writes it)
        self._horizon = 0.0
        self._settings: PlanSettings | None = None  # plan_step's, per episode
        self._plan_call = FixedSignature(plan_step)
        self.transfers = 0  # transfers started this episode (side changes and approaches)

    def reset(self, context: PolicyContext) -> None:
        """Cone, windows, predictor and side memory for a new episode."""
        super().reset(context)
        tc, cfg = self.tracker, self.config
        self._predictor = RingPredictor(max(1, round(tc.velocity_window / context.dt)))
        self._side = 0.0
        self._transfer = None
        self._half_b = 0.5 * context.camera.baseline if cfg.centre_left_eye else 0.0
        self._aim_floor = cfg.min_camera_height + tc.floor_clearance  # m, goals aim here
        self._cmd_floor = cfg.min_camera_height - FLOOR_TOL_M  # m, commands stay above
        g_lin, g_ang = tc.feedforward_gain
        self._gains = np.array([g_lin, g_lin, g_lin, g_ang, g_ang, g_ang])  # the twist's gains
        self._horizon = context.sensing_latency + tc.carrier_lead if tc.predict else 0.0
        self.transfers = 0
        self._settings = None  # rebuilt at the first step (after a subclass's reset)
        self._view_rule = ViewRule(
            self._aim_floor, self._half_b, tc.side_change_angle, cone_at(self.cone.constants, 0)
        )

    def _plan_settings(self) -> PlanSettings:
        """:func:`plan_step`'s settings for the episode.

        The predictor's, the gate's and the guard's arrays in it are live: the step updates
        them in place.
        """
        ctx, geometry = self._ctx, self._window_geometry
        assert ctx is not None and geometry is not None  # set by reset()
        cfg, tc, gate, guard = self.config, self.tracker, self._gate, self.guard
        rule = self._view_rule
        rcm = np.asarray(ctx.p_world_rcm, dtype=float).tolist()
        port = cfg.side_rule is SideRule.PORT
        pred = self._predictor
        return PlanSettings(
            checks=RingChecks(cfg.ring_max_age, gate.state, gate.bounds, rule.cone, True),
            windows=tuple(geometry.constants),
            distance=DistanceRange(cfg.d_min, cfg.d_max, cfg.d_f_step),
            view_rule=rule,
            keep_side=tc.keep_side,
            shorten=tc.shorten_when_low,
            paper_side=SideChoice(_UP, cfg.side_hysteresis, cfg.min_camera_height, port, _UP),
            rcm=(rcm[0], rcm[1], rcm[2]),
            jump=cfg.jump_threshold,
            cmd_floor=self._cmd_floor,
            samples=pred.buf,
            sample_count=pred.count,
            spacing=pred.spacing,
            given=self._given,
            predictions=np.zeros(12),
            horizon=self._horizon,
            dt=ctx.dt,
            feedforward=tc.feedforward and self._horizon > 0.0 and ctx.follows_twist,
            guarded=guard is not None,
            zone=NO_KEEP_OUT if guard is None else guard.kernel_state,
        )

    # -- the goal (the maths: control.side_view, control.plan) -----------------------------

    def _view(self, p_c: Vec, n: Vec, s: float, d: float) -> tuple[Vec, float, float] | None:
        """Feasible viewing direction on side ``s``: (unit ``u``, angle to ``s n`` rad, margin m).

        ``u`` points from the ring centre to the camera; ``None`` if no direction keeps the
        camera ``min_camera_height`` above the board. The margin is the camera's to the cone.
        (:func:`~endocam.control.side_view.view_of`.)
        """
        view = view_of(self._view_rule, p_c, n, s, d)
        return (view.u, view.error, view.margin) if view.found else None

    def _pose(self, p_c: Vec, u: Vec, r: float, previous: FloatArray | None) -> FloatArray:
        """Look at ``p_c`` from ``p_c + r u`` with a level horizon; left eye on the axis if set.

        (:func:`~endocam.control.side_view.pose_of`; ``previous`` (4, 4) or ``None``: its roll
        is kept near the vertical.)
        """
        axes = PreviousAxes(False, _UP, _UP)  # unread without a previous pose
        if previous is not None:
            R = previous[:3, :3].tolist()
            axes = PreviousAxes(True, (R[0][2], R[1][2], R[2][2]), (R[0][0], R[1][0], R[2][0]))
        x, y, z, p = pose_of(p_c, u, r, axes, self._half_b)
        return pose_from_columns(x, y, z, p)

    @staticmethod
    def _twist(T1: FloatArray, T2: FloatArray, delta: float) -> FloatArray:
        """(6,) velocity from pose ``T1`` to ``T2`` over ``delta`` s: linear, angular in world."""
        return np.array(twist_of(T1.tolist(), T2.tolist(), delta))

    def _preferred_side(self) -> float:
        """A side (±1) to take first while its view is feasible; 0.0: none (the oracle's plan)."""
        return 0.0

    def _give_predictions(self, t: float, predictions: FloatArray) -> None:
        """Write the given predictions at ``t`` (s) into ``predictions`` (12,) (the oracle's).

        The ring centre (m) and unit normal ``horizon`` s ahead, then ``horizon + dt``.
        """
        raise NotImplementedError("only a policy with _given set gives its predictions")

    def _feedforward_twist(self, goal: FloatArray, twist: FloatArray, d_f: float) -> FloatArray:
        """The twist (6,) to command with ``goal`` (4, 4): ``twist``, the goal's one-step one.

        ``d_f``: the step's working distance, m (the oracle's look distance).
        """
        return twist

    def _plan_step(self, obs: Observation, T_cam: FloatArray, T_ring: FloatArray) -> PlanResult:
        """:func:`plan_step` for ``obs``, its camera and ring poses ``T_cam``, ``T_ring`` (4, 4).

        The view's pose goes into ``_view_T``, a new array each step (the goal and the command
        keep it).
        """
        settings = self._settings
        if settings is None:
            settings = self._settings = self._plan_settings()
            self._plan_call = FixedSignature(plan_step)  # this episode's types
        t = float(obs.t)
        t_ring = t if obs.t_ring is None else float(obs.t_ring)  # unstamped: never stale
        if self._given:
            self._give_predictions(t, settings.predictions)
        tips = tips_array(obs.p_world_tips)
        previous = self._last_goal if self._last_goal is not None else self._last_cmd
        assert previous is not None  # set by reset()
        release = FREEZE_RELEASE_MARGIN if self._frozen_T is not None else 0.0
        memory = TrackerMemory(
            self.d_f,
            self._side,
            self._preferred_side(),
            self._last_goal is None,
            self._transfer is None,
            release,
        )
        self._view_T = np.empty((4, 4))
        seen = Sighting(T_cam, T_ring, tips, t, t_ring)
        return self._plan_call(settings, seen, previous, memory, self._view_T)  # plan_step

    # -- the step --------------------------------------------------------------------------

    def _freeze(
        self, why: str, state: TrackingState = TrackingState.FROZEN_OUTSIDE_CONE
    ) -> CameraCommand:
        """Hold the last safe command; the goal and the transfer are planned afresh."""
        self._path = None
        self._transfer = None
        self._last_goal = None
        return self._hold(state, why)

    def _lose(self, reason: str) -> CameraCommand:
        """Lost tracking: hold, and forget the predictor's samples (no differencing a gap)."""
        self._predictor.reset()
        return self._freeze(reason, TrackingState.LOST_TRACKING)

    def step(self, obs: Observation) -> CameraCommand:
        """Checks, working distance, prediction, side, cone freeze, transfers — in that order.

        The step's working distance (the plan's ``d_f``) is committed only with the command it
        issues; a freeze or a hold keeps the last one.
        """
        ctx = self._ctx
        if ctx is None:
            raise RuntimeError("call reset() before step()")
        cfg, tc = self.config, self.tracker
        T_cam = pose_array(obs.T_world_cam)
        T_ring = pose_array(obs.T_world_ring)
        if T_cam is None or (T_ring is None and finite_rows(T_cam) is None):
            return self._hold(TrackingState.LOST_TRACKING, CAMERA_REASON)
        if T_ring is None:
            return self._lose(RING_REASON)

        # the checks (finite poses, a fresh ring pose, the gate), the working distance,
        # prediction, side, view and its twist: one compiled call
        plan = self._plan_step(obs, T_cam, T_ring)
        view = self._view_T
        if plan.check != OBS_OK:
            if plan.check == OBS_CAMERA:
                return self._hold(TrackingState.LOST_TRACKING, CAMERA_REASON)
            return self._lose(CHECK_REASONS[plan.check])
        p_cam, d, p_c = plan.p_cam, plan.d_f, plan.p_c
        margin = -math.inf
        goal = None
        adjusted = False  # the goal was turned off the view for the wire clearance
        if plan.found:
            if plan.guard.cleared:  # the kernel made the guard's check: the view is clear
                assert self.guard is not None
                goal = self.guard.passed(view)
                self._cleared_view = goal  # the pose the kernel's check and trace are for
            else:
                goal = self._clear(view, p_c, p_cam, d)
            if goal is None:
                return self._freeze(WIRE_REASON)
            adjusted = goal is not view
            margin = self.cone.margin(goal[:3, 3]) if adjusted else plan.margin
        release = FREEZE_RELEASE_MARGIN if self._frozen_T is not None else 0.0
        if goal is None or not margin >= release:
            if self._frozen_T is None:
                self._frozen_T = T_cam
            self._last_cmd = self._frozen_T
            return self._freeze(CONE_REASON)
        self._frozen_T = None

        s, u = plan.side, plan.u
        side_changed = bool(self._side) and s != self._side
        fresh = self._last_goal is None
        side_before = self._side
        self._side = s
        self._last_goal = goal
        if side_changed or (fresh and math.dist(goal[:3, 3].tolist(), p_cam) > cfg.jump_threshold):
            self._start(tc.side_transfer if side_changed else tc.first_approach, p_cam, p_c)

        state, reason = TrackingState.TRACKING, ""
        cmd, twist = goal, None
        if self._transfer is Transfer.ORBIT:
            z_cam = tuple(T_cam[:3, 2].tolist())
            orbit = self._orbit(p_c, u, d, p_cam, z_cam)
            if orbit is not None:
                cmd = orbit
                state, reason = TrackingState.PLANNING, "orbiting the ring to the other side"
        elif self._transfer is Transfer.WAYPOINTS:
            wp = self._waypoints(p_c, goal, obs)
            if wp is not None:
                cmd = wp
                state, reason = TrackingState.PLANNING, "following intermediate way-points"
        if state is TrackingState.TRACKING and plan.has_twist:
            # the view's twist (the kernel's); unused below when the goal is not the view
            twist = self._feedforward_twist(goal, np.array(plan.twist), d)
        near_edge = goal[2, 3] <= self._aim_floor + FLOOR_TOL_M or margin < tc.floor_clearance
        if twist is not None and not near_edge and not adjusted:
            twist = twist * self._gains  # linear × g_lin, angular × g_ang (element by element)
        else:
            twist = None  # a goal at the floor or the cone arrives at rest: nothing carries it out
        if cmd is not goal:  # an orbit or way-point pose keeps the clearance too
            cleared = self._clear(cmd, p_c, p_cam, d)
            if cleared is None:
                self._side = side_before
                return self._freeze(WIRE_REASON)
            cmd = cleared
        # on the plain path (no transfer, no freeze) the kernel traced the move to this pose
        plain = plan.guard.cleared and cmd is goal and goal is self._cleared_view
        via = self._detoured(cmd, p_c, p_cam, d, plan.guard if plain else None)
        if via is not None:
            cmd, twist = via, None
            state, reason = TrackingState.PLANNING, DETOUR_REASON
        # last gate: never command outside the workspace (the kernel's test of its own view)
        if not (plan.inside if cmd is view else self._in_workspace(cmd)):
            self._side = side_before
            return self._freeze(LAST_GATE_REASON)
        return self._issue(cmd, state, d, reason, twist)

    def _start(self, kind: Transfer, p_cam: Vec, p_c: Vec) -> None:
        """Begin a transfer of ``kind`` from the camera at ``p_cam`` (m, world)."""
        self.transfers += 1
        self._transfer = None if kind is Transfer.DIRECT else kind
        if kind is Transfer.ORBIT:
            u = unit_or_none((p_cam[0] - p_c[0], p_cam[1] - p_c[1], p_cam[2] - p_c[2]))
            if u is None:
                self._transfer = None
            else:
                self._u_orbit = u
        elif kind is Transfer.WAYPOINTS:
            goal = self._last_goal
            assert goal is not None
            p_goal = goal[:3, 3]
            self._path = WaypointPath(
                intermediate_waypoints(
                    np.array(p_cam),
                    p_goal,
                    UP,
                    self._lift(list(p_cam)),
                    self._lift(p_goal.tolist()),
                )
            )
            self._s = 0.0

    def _orbit(self, p_c: Vec, u_goal: Vec, r: float, p_cam: Vec, z_cam: Vec) -> FloatArray | None:
        """Next orbit pose about ``p_c`` towards the direction ``u_goal``; ``None`` when done.

        The commanded direction turns on the great circle to ``u_goal`` (over the top when the
        two are opposite) at the fastest rate the orbit's per-axis limits allow, and waits
        while the camera's position (seen from ``p_c``) or its optical axis ``z_cam`` (world,
        unit) lags more than ``orbit_lookahead`` behind it. A step whose commanded pose (with
        the left-eye shift) would leave the cone or go below the floor hands over to the
        paper's way-points.
        """
        tc = self.tracker
        u = self._u_orbit
        ang = angle(u, u_goal)
        if ang < ORBIT_DONE_ANGLE:
            self._transfer = None
            return None
        k = unit_or_none(cross(u, u_goal))
        if k is None or ang > math.pi - 1e-3:  # opposite ends: go over the top
            k = unit_or_none(cross(u, (0.0, 0.0, 1.0))) or unit_or_none(cross(u, (1.0, 0.0, 0.0)))
            assert k is not None
        tangent = cross(k, u)  # unit: k ⟂ u
        rate = tc.orbit_max_speed / (r * max(map(abs, tangent)) + MIN_DIRECTION)
        # The camera turns about k; its per-axis share is largest when k is along one axis.
        rate = min(rate, tc.orbit_max_rate)
        to_cam = unit_or_none((p_cam[0] - p_c[0], p_cam[1] - p_c[1], p_cam[2] - p_c[2]))
        keeping_up = (
            to_cam is not None
            and angle(to_cam, u) <= tc.orbit_lookahead
            and angle(z_cam, (-u[0], -u[1], -u[2])) <= tc.orbit_lookahead
        )
        if keeping_up:
            step = min(rate * self._ctx_dt, ang)
            c, sn = math.cos(step), math.sin(step)
            u_next = (
                c * u[0] + sn * tangent[0],
                c * u[1] + sn * tangent[1],
                c * u[2] + sn * tangent[2],
            )
            u = u_next
        # the commanded pose itself (with the left-eye shift) must stay in the workspace, also
        # while waiting: the ring moves on
        T = self._pose(p_c, u, r, self._last_cmd)
        if not self._in_workspace(T):
            goal = self._last_goal
            assert goal is not None
            self._start(Transfer.WAYPOINTS, p_cam, p_c)
            self.transfers -= 1  # the same transfer, another way
            return self._waypoints_pose(p_c, goal)
        self._u_orbit = u
        return T

    def _in_workspace(self, T_world_cmd: FloatArray) -> bool:
        """Whether a commanded pose (4, 4) is inside the cone and above the floor.

        The last gate: computed here (:func:`~endocam.control.plan.inside_kernel`),
        independently of the compiled step's own margin.
        """
        return bool(inside_kernel(T_world_cmd, self._view_rule.cone, self._cmd_floor))

    @property
    def _ctx_dt(self) -> float:
        assert self._ctx is not None
        return self._ctx.dt

    def _waypoints(self, p_c: Vec, goal: FloatArray, obs: Observation) -> FloatArray | None:
        """Next way-point pose (the paper's up-and-over path); ``None`` when arrived."""
        if self._path is None:
            self._transfer = None
            return None
        cfg = self.config
        p_goal = goal[:3, 3]
        self._path = self._path.with_goal(p_goal, UP, self._lift(p_goal.tolist()))
        p_progress = np.asarray(obs.T_world_cam, dtype=float)[:3, 3]
        self._s = advance(
            self._path, self._s, p_progress, cfg.planner_speed * self._ctx_dt, cfg.planner_lookahead
        )
        if self._s >= self._path.length - 1e-9:
            self._path = None
            self._transfer = None
            return None
        return self._waypoints_pose(p_c, goal)

    def _waypoints_pose(self, p_c: Vec, goal: FloatArray) -> FloatArray:
        assert self._path is not None
        p = self._path.point_at(self._s)
        return look_at_unchecked(p, np.array(p_c), goal, self._last_cmd)
