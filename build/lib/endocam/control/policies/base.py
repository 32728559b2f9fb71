"""What the moving policies share: the safety rules (cone, wire), holds, way-point lifts.

The working distance ``d_f`` is committed state: a step computes a candidate (the windows'
rule, :class:`~endocam.control.goal.DistanceRange`), passes it to the wire guard's back-off,
and commits it only with the command it issues (:meth:`MovingPolicy._issue`); a hold or a
freeze (:meth:`MovingPolicy._hold`) keeps the committed one.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from endocam.control.clearance import ClearanceGuard
from endocam.control.config import ControllerConfig
from endocam.control.guard_answer import GuardAnswer
from endocam.control.planner import WaypointPath
from endocam.control.types import (
    CameraCommand,
    PolicyContext,
    TrackingState,
)
from endocam.control.windows import WindowGeometry
from endocam.geometry import FloatArray
from endocam.workspace.cone import ConeWorkspace
from endocam.workspace.region import Workspace

FREEZE_RELEASE_MARGIN = 1e-3  # m, how far back inside the cone the goal must be to unfreeze
LIFT_TOL = 1e-4  # m, resolution of the cone-limited way-point height
DETOUR_REASON = "detouring around the wire's clearance zone"
WIRE_REASON = "no view of the ring keeps the wire clearance inside the workspace; holding"
STALL_STEPS = 10  # control steps a detouring camera may stand still before it steps out
STALL_TOL_M = 1e-9  # m, a camera that moved less than this in a step stood still


class MovingPolicy:
    """Shared machinery of the moving policies: safety rules and way-point following."""

    name = "moving"

    def __init__(self, config: ControllerConfig | None = None) -> None:
        self.config = config or ControllerConfig()
        self._windows = self.config.windows
        self._window_geometry: WindowGeometry | None = None
        self._ctx: PolicyContext | None = None
        self._cone: ConeWorkspace | None = None
        self._workspace: Workspace | None = None
        self.guard: ClearanceGuard | None = None  # the wire clearance, given a wire model
        self.d_f = self.config.d_f
        self._last_goal: FloatArray | None = None  # last unplanned goal (jump detection)
        self._last_goal_p: list[float] = []  # its position as plain floats
        self._last_cmd: FloatArray | None = None  # last commanded pose (last safe pose)
        self._frozen_T: FloatArray | None = None
        self._path: WaypointPath | None = None
        self._s = 0.0
        self._gate = self.config.ring_gate()

    def reset(self, context: PolicyContext) -> None:
        """Fix the cone axis from the RCM to the ring's initial position; clear all memory."""
        self._ctx = context
        self._window_geometry = WindowGeometry.of(context.camera, self._windows)
        self._workspace = self.config.workspace(
            context.p_world_rcm, context.T_world_ring[:3, 3], context.wire
        )
        self._cone = self._workspace.cone
        self.guard = None
        if context.wire is not None:
            self.guard = ClearanceGuard(context.wire, self.config.wire_clearance)
        self.d_f = self.config.d_f
        self._last_goal = None
        self._last_cmd = np.array(context.T_world_cam, dtype=float)
        self._frozen_T = None
        self._path = None
        self._s = 0.0
        self._gate.reset(cone=self._cone)
        self._p_detour: Sequence[float] | None = None  # the camera at the last detour step, m
        self._stalled = 0  # detour steps the camera has stood still

    @property
    def cone(self) -> ConeWorkspace:
        """The cone workspace fixed at reset."""
        if self._cone is None:
            raise RuntimeError("call reset() before using the policy")
        return self._cone

    def _clear(
        self,
        T_world_cam: FloatArray,
        p_world_pivot: Sequence[float],
        p_world_now: Sequence[float],
        d_f: float,
    ) -> FloatArray | None:
        """A pose to command kept ``wire_clearance`` from the wire (``control.clearance``).

        ``T_world_cam`` (4, 4) itself when clear or without a wire model; else moved back along
        its optical axis (the look distance grows up to ``d_max``) or, if that does not clear,
        rotated about ``p_world_pivot`` (3,), the ring centre, world, m, towards the camera at
        ``p_world_now`` (3,), m; ``None``: no clear feasible view. ``d_f``: the step's working
        distance, m (the look distance may grow from it to ``d_max``).
        """
        guard = self.guard
        if guard is None:
            return T_world_cam
        pivot = (p_world_pivot[0], p_world_pivot[1], p_world_pivot[2])
        now = (p_world_now[0], p_world_now[1], p_world_now[2])
        back_off = max(0.0, self.config.d_max - d_f)  # the look distance may grow first
        return guard.apply(T_world_cam, pivot, self._workspace, now, back_off)

    def _detoured(
        self,
        T_world_cmd: FloatArray,
        p_world_pivot: Sequence[float],
        p_world_now: Sequence[float],
        d_f: float,
        traced: GuardAnswer | None = None,
    ) -> FloatArray | None:
        """A way-point pose around the wire if the straight move to the command crosses it.

        ``None``: the move from the camera at ``p_world_now`` (3,), m, to ``T_world_cmd``
        (4, 4) keeps the clearance (or there is no wire model). The way-point pose looks at
        ``p_world_pivot`` (3,), the ring centre, world, m, with a level horizon, and passes the
        clearance guard itself.

        ``d_f``: the step's working distance, m (``_clear``'s). ``traced``: the guard's answer
        for this move (``detour``, ``via``), when a compiled step asked it already. The
        way-point pose, the workspace's check of the way-point and the guard are one compiled
        call (``ClearanceGuard.apply_look_at``).
        """
        guard = self.guard
        if guard is None:
            return None
        if traced is None:
            via = guard.detour(p_world_now, T_world_cmd[:3, 3].tolist())
        else:
            via = traced.via if traced.detour else None
        before, self._p_detour = self._p_detour, p_world_now
        if via is None:
            self._p_detour, self._stalled = None, 0
            return None
        still = before is not None and math.dist(before, p_world_now) <= STALL_TOL_M
        self._stalled = self._stalled + 1 if still else 0
        if self._stalled >= STALL_STEPS:  # refused at the zone's edge: straight out first
            via = guard.step_out(p_world_now) or via
        # the way-point pose (``look_at_unchecked``), if feasible, through the guard (``_clear``)
        assert self._workspace is not None and self._last_cmd is not None  # set by reset()
        pivot = (p_world_pivot[0], p_world_pivot[1], p_world_pivot[2])
        now = (p_world_now[0], p_world_now[1], p_world_now[2])
        back_off = max(0.0, self.config.d_max - d_f)  # as _clear's
        return guard.apply_look_at(
            via, pivot, T_world_cmd, self._last_cmd, self._workspace, now, back_off
        )

    def _hold(self, state: TrackingState, reason: str) -> CameraCommand:
        """Hold the last command; the working distance stays the committed one."""
        assert self._last_cmd is not None
        return CameraCommand(self._last_cmd, state, self.d_f, reason)

    def _issue(
        self,
        T_world_cmd: FloatArray,
        state: TrackingState,
        d_f: float,
        reason: str = "",
        twist: FloatArray | None = None,
    ) -> CameraCommand:
        """Command ``T_world_cmd`` (4, 4), committing it and the step's working distance ``d_f``.

        The command is the last safe pose a hold returns to; ``d_f`` (m) the distance the next
        step starts from.
        """
        self._last_cmd = T_world_cmd
        self.d_f = d_f
        return CameraCommand(T_world_cmd, state, d_f, reason, twist)

    def _lift(self, p_world: Sequence[float]) -> float:
        """Way-point height above ``p_world``: ``d_wp``, lowered so the way-point stays in the cone.

        The cone is convex, so with both way-points and both ends inside it the whole path is
        inside. A point already outside the cone (the camera at its start pose, say) gets no
        lift: the camera then heads straight for the raised goal way-point, into the cone.
        """
        d_wp = self.config.d_wp
        cone = self.cone
        x, y, z = p_world
        if cone.margin([x, y, z + d_wp]) >= 0.0:
            return d_wp
        if not cone.margin(p_world) >= 0.0:
            return 0.0
        lo, hi = 0.0, d_wp  # inside at lo, outside at hi: bisect to LIFT_TOL
        while hi - lo > LIFT_TOL:
            mid = 0.5 * (lo + hi)
            if cone.margin([x, y, z + mid]) >= 0.0:
                lo = mid
            else:
                hi = mid
        return lo


__all__ = ["DETOUR_REASON", "FREEZE_RELEASE_MARGIN", "STALL_STEPS", "WIRE_REASON", "MovingPolicy"]
