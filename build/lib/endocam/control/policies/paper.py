"""Camera policies: the paper's three conditions behind one small interface, and a registry.

* ``fixed`` (condition I) holds the initial pose, which shows the whole task.
* ``centering`` (condition II) follows the ring centre at the working distance and ignores the
  ring's orientation. Our reading of the paper ("camera movement with a fixed orientation",
  abstract; "the camera initial pose was the same as in the fixed camera condition", Sec. IV-D):
  the camera keeps its initial orientation, hence its initial viewing direction ``z0``, and sits at
  ``p_c − d_f z0`` so the ring centre is on the optical axis.
* ``orientation`` (condition III) is the paper's method: goal on the ring normal with a level
  horizon, way-points around goal jumps, and the safety rules.

Both moving policies obey the same safety rules (cone freeze, tool-in-view windows, lost tracking),
so the comparison isolates the use of orientation. Every command carries a :class:`TrackingState`
and a one-line reason.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from endocam.control.checks import (
    CAMERA_REASON,
    CHECK_REASONS,
    DEGENERATE_REASON,
    OBS_CAMERA,
    OBS_OK,
    RING_REASON,
    RingChecks,
    Sighting,
    pose_array,
    tips_array,
)
from endocam.control.config import ControllerConfig, SideRule
from endocam.control.fixed_signature import FixedSignature
from endocam.control.goal import DistanceRange, SideChoice
from endocam.control.paper_step import PaperMemory, PaperResult, PaperSettings, paper_step
from endocam.control.planner import WaypointPath, advance, intermediate_waypoints
from endocam.control.policies.base import (
    DETOUR_REASON,
    FREEZE_RELEASE_MARGIN,
    WIRE_REASON,
    MovingPolicy,
)
from endocam.control.types import CameraCommand, Observation, PolicyContext, TrackingState
from endocam.geometry import UP, FloatArray
from endocam.kernels import finite_rows
from endocam.view import look_at_unchecked
from endocam.workspace.cone import cone_at
from endocam.workspace.keepout import NO_KEEP_OUT

__all__ = [
    "CenteringPolicy",
    "FixedPolicy",
    "OrientationEcmPolicy",
    "OrientationPolicy",
    "PaperPolicy",
]


class FixedPolicy:
    """Condition I: hold the initial whole-task pose."""

    name = "fixed"

    def __init__(self, config: ControllerConfig | None = None) -> None:
        self.config = config or ControllerConfig()
        self._T: FloatArray | None = None

    def reset(self, context: PolicyContext) -> None:
        """Remember the initial pose."""
        self._T = np.array(context.T_world_cam, dtype=float)

    def step(self, obs: Observation) -> CameraCommand:
        """Return the initial pose, whatever is observed."""
        if self._T is None:
            raise RuntimeError("call reset() before step()")
        return CameraCommand(self._T, TrackingState.HOLDING, self.config.d_f)


class PaperPolicy(MovingPolicy):
    """The paper's moving policies' step (conditions II, III): checks, goal, freeze, way-points.

    A subclass chooses the goal (``_orientation``) and the way-point pose (``_waypoint_pose``).
    """

    name = "paper"
    _orientation = False  # the orientation goal (condition III); else the centering goal

    def reset(self, context: PolicyContext) -> None:
        """Also forget the compiled step's settings (rebuilt at the first step)."""
        super().reset(context)
        self._settings: PaperSettings | None = None
        self._kernel_goal: FloatArray | None = None  # the goal paper_step last gave
        self._kernel_p: list[float] = []  # its position, m, as the kernel checked it

    def _paper_settings(self) -> PaperSettings:
        """:func:`paper_step`'s settings for the episode (the gate's and guard's arrays live)."""
        ctx, cone, geometry = self._ctx, self._cone, self._window_geometry
        assert ctx is not None and cone is not None and geometry is not None  # set by reset()
        cfg, guard, gate = self.config, self.guard, self._gate
        up = (0.0, 0.0, 1.0)
        R0 = np.asarray(ctx.T_world_cam, dtype=float)[:3, :3]
        T0 = np.eye(4)
        T0[:3, :3] = R0
        half_b = 0.5 * ctx.camera.baseline if cfg.centre_left_eye else 0.0
        z0, shift = R0[:, 2].tolist(), (half_b * R0[:, 0]).tolist()
        rcm = np.asarray(ctx.p_world_rcm, dtype=float).tolist()
        port = cfg.side_rule is SideRule.PORT
        return PaperSettings(
            checks=RingChecks(
                cfg.ring_max_age, gate.state, gate.bounds, cone_at(cone.constants, 0), False
            ),
            windows=tuple(geometry.constants),
            distance=DistanceRange(cfg.d_min, cfg.d_max, cfg.d_f_step),
            orientation=self._orientation,
            side=SideChoice(up, cfg.side_hysteresis, cfg.min_camera_height, port, up),
            rcm=(rcm[0], rcm[1], rcm[2]),
            T0=T0,
            z0=(z0[0], z0[1], z0[2]),
            shift=(shift[0], shift[1], shift[2]),
            cone=cone_at(cone.constants, 0),
            jump=cfg.jump_threshold,
            guarded=guard is not None,
            zone=NO_KEEP_OUT if guard is None else guard.kernel_state,
        )

    def _goal(self, seen: Sighting, previous: FloatArray) -> tuple[PaperResult, FloatArray | None]:
        """The compiled step (:func:`paper_step`) on ``seen``: its answer and the goal (4, 4).

        The goal is ``None`` when the checks refused the observation or the ring pose gives
        none (a degenerate normal). ``previous`` (4, 4): the last goal or the camera.
        """
        settings = self._settings
        if settings is None:
            settings = self._settings = self._paper_settings()
            self._paper_call = FixedSignature(paper_step)  # this episode's types
        release = FREEZE_RELEASE_MARGIN if self._frozen_T is not None else 0.0
        memory = PaperMemory(self.d_f, self._path is None, release)
        goal = np.empty((4, 4))  # a new array each step: the goal and the command keep it
        result: PaperResult = self._paper_call(settings, seen, previous, memory, goal)
        if not result.found:
            return result, None
        self._kernel_goal, self._kernel_p = goal, goal[:3, 3].tolist()
        return result, goal

    def _lose(
        self, reason: str, state: TrackingState = TrackingState.LOST_TRACKING
    ) -> CameraCommand:
        """Hold the last command; the goal and the way-point path are planned afresh."""
        self._last_goal = None
        self._path = None
        return self._hold(state, reason)

    def step(self, obs: Observation) -> CameraCommand:
        """Input checks, working distance, goal, cone freeze, way-points — in that order.

        The checks (finite poses, a fresh ring pose, the ring gate), the working distance and
        the goal are one compiled call (:meth:`_goal`). The step's working distance is
        committed only with the command it issues (a hold keeps the last one).
        """
        ctx = self._ctx
        if ctx is None:
            raise RuntimeError("call reset() before step()")
        cfg = self.config
        T_cam = pose_array(obs.T_world_cam)
        T_ring = pose_array(obs.T_world_ring)
        if T_cam is None or (T_ring is None and finite_rows(T_cam) is None):
            return self._hold(TrackingState.LOST_TRACKING, CAMERA_REASON)
        if T_ring is None:
            return self._lose(RING_REASON)
        tips = tips_array(obs.p_world_tips)
        t = float(obs.t)
        t_ring = t if obs.t_ring is None else float(obs.t_ring)  # unstamped: never stale
        previous = self._last_goal if self._last_goal is not None else T_cam
        result, goal = self._goal(Sighting(T_cam, T_ring, tips, t, t_ring), previous)
        if result.check != OBS_OK:
            if result.check == OBS_CAMERA:
                return self._hold(TrackingState.LOST_TRACKING, CAMERA_REASON)
            return self._lose(CHECK_REASONS[result.check])
        if goal is None:
            return self._lose(DEGENERATE_REASON)
        d_f, p_ring, p_now = result.d_f, result.p_ring, result.p_cam
        # cleared by the kernel, with its trace to the goal: only for the very pose it checked
        # (a subclass's ``_goal`` may change it; then the guard checks it here)
        p_kernel = goal[:3, 3].tolist() if goal is self._kernel_goal else None
        cleared = result.guard.cleared and p_kernel == self._kernel_p
        if cleared:
            assert self.guard is not None
            goal = self.guard.passed(goal)
        else:
            goal = self._clear(goal, p_ring, p_now, d_f)
        if goal is None:  # the last command passed the guard: hold it, as a freeze does
            return self._lose(WIRE_REASON, TrackingState.FROZEN_OUTSIDE_CONE)
        if p_kernel is not None and goal is self._kernel_goal:
            p_goal = p_kernel  # the guard passed the kernel's goal itself (unchanged)
        else:
            goal_rows = goal.tolist()
            p_goal = [goal_rows[0][3], goal_rows[1][3], goal_rows[2][3]]
        if goal is self._kernel_goal and p_goal == self._kernel_p:
            margin = result.margin  # the kernel's ConeWorkspace.margin of this very pose
        else:
            margin = self.cone.margin(p_goal)
        # Freeze when the goal leaves the cone; release only once it is FREEZE_RELEASE_MARGIN
        # inside, so a goal grazing the surface does not toggle the camera every step.
        release = FREEZE_RELEASE_MARGIN if self._frozen_T is not None else 0.0
        if not margin >= release:
            if self._frozen_T is None:
                self._frozen_T = T_cam
            self._last_cmd = self._frozen_T
            where = "outside" if margin < 0 else "not yet back inside"
            # on recovery, a far goal is planned from the camera
            return self._lose(
                f"goal {abs(margin) * 1e3:.1f} mm {where} the cone workspace; holding",
                TrackingState.FROZEN_OUTSIDE_CONE,
            )
        self._frozen_T = None

        ref_p = self._last_goal_p if self._last_goal is not None else p_now
        jumped = math.dist(p_goal, ref_p) > cfg.jump_threshold
        self._last_goal = goal
        self._last_goal_p = p_goal
        if jumped and self._path is None:
            self._path = WaypointPath(
                intermediate_waypoints(
                    T_cam[:3, 3], np.array(p_goal), UP, self._lift(p_now), self._lift(p_goal)
                )
            )
            self._s = 0.0
        state, reason = TrackingState.TRACKING, ""
        cmd = goal
        if self._path is not None:
            self._path = self._path.with_goal(np.array(p_goal), UP, self._lift(p_goal))
            p_progress = T_cam[:3, 3]
            offset = obs.p_world_reach_offset
            if offset is not None and all(map(math.isfinite, offset)):
                p_progress = p_progress - np.asarray(offset, dtype=float)
            self._s = advance(
                self._path, self._s, p_progress, cfg.planner_speed * ctx.dt, cfg.planner_lookahead
            )
            if self._s >= self._path.length - 1e-9:
                self._path = None  # arrived: back to plain tracking
            else:
                p = self._path.point_at(self._s)
                wp = self._cleared_waypoint(p, T_ring, goal, p_ring, p_now, d_f)
                if wp is None:
                    return self._lose(WIRE_REASON, TrackingState.FROZEN_OUTSIDE_CONE)
                cmd = wp
                state, reason = TrackingState.PLANNING, "following intermediate way-points"
        # on the plain path (no way-points) the kernel traced the move
        plain = cleared and cmd is goal
        via = self._detoured(cmd, p_ring, p_now, d_f, result.guard if plain else None)
        if via is not None:
            cmd = via
            state, reason = TrackingState.PLANNING, DETOUR_REASON
        return self._issue(cmd, state, d_f, reason)

    def _waypoint_pose(self, p: FloatArray, T_ring: FloatArray, goal: FloatArray) -> FloatArray:
        """Pose at a way-point: look at the ring centre with a level horizon."""
        return look_at_unchecked(p, T_ring[:3, 3], goal, self._last_cmd)

    def _cleared_waypoint(
        self,
        p: FloatArray,
        T_ring: FloatArray,
        goal: FloatArray,
        p_ring: Sequence[float],
        p_now: Sequence[float],
        d_f: float,
    ) -> FloatArray | None:
        """``_clear`` of ``_waypoint_pose(p, T_ring, goal)``: the way-point's command.

        ``p`` (3,) the way-point, ``T_ring`` (4, 4), ``goal`` (4, 4), ``p_ring`` (3,) the
        ring centre, ``p_now`` (3,) the camera, world, m; ``d_f`` the step's working distance.
        """
        return self._clear(self._waypoint_pose(p, T_ring, goal), p_ring, p_now, d_f)


class CenteringPolicy(PaperPolicy):
    """Condition II: keep the initial orientation, put the ring centre on the optical axis.

    The camera sits at ``ring − d_f z0 + (b/2) x0``: the left eye, ``b/2`` along −x, on the
    line through the ring centre along the initial optical axis ``z0``.
    """

    name = "centering"

    def _waypoint_pose(self, p: FloatArray, T_ring: FloatArray, goal: FloatArray) -> FloatArray:
        T = goal.copy()  # orientation stays fixed on the way too
        T[:3, 3] = p
        return T


class OrientationPolicy(PaperPolicy):
    """Condition III: the paper's orientation-aware camera (goal on the ring normal)."""

    name = "orientation"
    _orientation = True

    def _cleared_waypoint(
        self,
        p: FloatArray,
        T_ring: FloatArray,
        goal: FloatArray,
        p_ring: Sequence[float],
        p_now: Sequence[float],
        d_f: float,
    ) -> FloatArray | None:
        """The way-point's look-at pose and the guard in one compiled call (``apply_look_at``)."""
        guard = self.guard
        if guard is None:
            return self._waypoint_pose(p, T_ring, goal)
        assert self._workspace is not None and self._last_cmd is not None  # set by reset()
        q = p.tolist()
        back_off = max(0.0, self.config.d_max - d_f)  # as _clear's
        return guard.apply_look_at(
            (q[0], q[1], q[2]),
            (p_ring[0], p_ring[1], p_ring[2]),
            goal,
            self._last_cmd,
            self._workspace,
            (p_now[0], p_now[1], p_now[2]),
            back_off,
            check=False,
        )


class OrientationEcmPolicy(OrientationPolicy):
    """The paper's orientation goal, carried out by the 4-DoF ECM (registry entry forces it).

    The goal is condition III's; the ECM's optical axis always passes through its RCM, so the
    camera reaches the goal's position but not, in general, its orientation. The orientation
    error it leaves quantifies what a standard endoscope cannot deliver (paper Sec. I).
    """

    name = "orientation-ecm"
