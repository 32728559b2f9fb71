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
from numba import njit
from numba.extending import register_jitable

from endocam.control.clearance import ClearanceGuard
from endocam.control.config import ControllerConfig, SideRule
from endocam.control.detour import cleared_move
from endocam.control.gate import (
    CLOCK_TOL,
    STALE_REASON,
    GateBounds,
    GateState,
    gate_commit,
    gate_decide,
)
from endocam.control.goal import goal_columns
from endocam.control.planner import WaypointPath, advance, intermediate_waypoints
from endocam.control.types import (
    CameraCommand,
    Observation,
    PolicyContext,
    TrackingState,
)
from endocam.control.windows import WindowGeometry, adjusted_distance, window_code_of
from endocam.geometry import UP, FloatArray
from endocam.kernels import Vec, dist3, finite_rows, unit_checked
from endocam.view import look_at_unchecked
from endocam.workspace.cone import Cone, ConeWorkspace, cone_at, cone_margin
from endocam.workspace.keepout import NO_KEEP_OUT, KeepOutState
from endocam.workspace.region import Workspace

_UP = (0.0, 0.0, 1.0)  # world up as plain floats
FREEZE_RELEASE_MARGIN = 1e-3  # m, how far back inside the cone the goal must be to unfreeze
LIFT_TOL = 1e-4  # m, resolution of the cone-limited way-point height
_MIN_NORMAL = 1e-9  # unitless, a ring normal shorter than this is degenerate
GATE_REASON = "ring pose rejected by the observation gate (moved too fast); holding"
DETOUR_REASON = "detouring around the wire's clearance zone"
CAMERA_REASON = "camera pose not finite; holding"
RING_REASON = "ring pose missing or not finite"
WIRE_REASON = "no view of the ring keeps the wire clearance inside the workspace; holding"
STALL_STEPS = 10  # control steps a detouring camera may stand still before it steps out
STALL_TOL_M = 1e-9  # m, a camera that moved less than this in a step stood still


# _step_kernel's parameters (``_MovingPolicy._params``), by index
_WINDOW = 0  # the 9 constants of window_code
_D_MIN, _D_MAX, _D_STEP = 9, 10, 11  # m, the working distance's range and step
_KIND = 12  # 0.0: the centering goal, 1.0: the orientation goal
_HYSTERESIS, _MIN_HEIGHT = 13, 14  # rad, m: side_hysteresis, min_camera_height
_PORT_RULE = 15  # 1.0: SideRule.PORT
_RCM = 16  # m, the camera arm's RCM (3)
_Z0, _SHIFT = 19, 22  # the centering goal's optical axis (3) and left-eye shift (3), m
_CONE = 25  # the cone: apex (3), m; axis (3); tan and cos of the half-angle; height, m
_JUMP = 34  # m, jump_threshold
_N_PARAMS = 35
# _step_kernel's results (``_MovingPolicy._out``): the guard's answers on the plain path
_OUT_CLEARED, _OUT_DETOUR, _OUT_VIA = 0, 1, 2  # clear, detour, its way-point (3), m
_OUT_RING, _OUT_CAM = 5, 8  # m, the observed ring centre and camera position (3 each)
_OUT_CHECK = 11  # the observation's check (``observed``: OBS_*)
_OUT_MARGIN = 12  # m, the goal's cone margin (``ConeWorkspace.margin``)
_N_OUT = 13
# ``observed``'s answers: the observation is usable, or why not
OBS_OK, OBS_CAMERA, OBS_RING, OBS_STALE, OBS_DEGENERATE, OBS_GATE = range(6)
CHECK_REASONS = (
    "",
    CAMERA_REASON,
    RING_REASON,
    STALE_REASON,
    "ring pose degenerate (zero normal)",
    GATE_REASON,
)  # the hold's reason per OBS_* answer


@register_jitable  # also callable from compiled kernels (the same source)
def finite_pose(T: FloatArray) -> bool:
    """Whether every entry of ``T`` (4, 4) is finite (``kernels.finite_rows``' test)."""
    for i in range(4):
        for j in range(4):
            if not math.isfinite(T[i, j]):
                return False
    return True


@register_jitable  # also callable from compiled kernels (the same source)
def observed(
    T_cam: FloatArray,
    T_ring: FloatArray,
    t: float,
    has_t_ring: bool,
    t_ring: float,
    max_age: float,
    gate: GateState,
    bounds: GateBounds,
    cone: Cone,
    unit_normal: bool,
) -> int:
    """The policies' input checks in their order, the ring gate last: ``OBS_OK`` or why not.

    ``T_cam``, ``T_ring`` (4, 4) the observed camera and ring poses, world, m: not finite,
    ``OBS_CAMERA`` / ``OBS_RING``. The ring pose captured at ``t_ring`` (s; unstamped: not
    ``has_t_ring``) is stale at ``t`` (s) beyond ``max_age`` (s) or ``CLOCK_TOL`` in the
    future (``safety.is_stale``): ``OBS_STALE``. ``unit_normal`` (the tracker): the gate gets
    the unit normal, and a degenerate one is ``OBS_DEGENERATE``; else (the moving policies)
    the gate gets the normal as observed and a degenerate one passes (the goal reports it).
    The gate (``safety.RingGate``: its ``state`` and ``bounds``; re-acquired only inside the
    ``cone``): ``OBS_GATE`` when it rejects.
    """
    if not finite_pose(T_cam):
        return OBS_CAMERA
    if not finite_pose(T_ring):
        return OBS_RING
    if has_t_ring:
        age = t - t_ring
        if not (-CLOCK_TOL <= age <= max_age):
            return OBS_STALE
    n = (T_ring[0, 2], T_ring[1, 2], T_ring[2, 2])
    if unit_normal:
        ok, n = unit_checked(n)
        if not ok:
            return OBS_DEGENERATE
    elif not dist3(n[0], n[1], n[2], 0.0, 0.0, 0.0) > _MIN_NORMAL:  # math.hypot(*n)
        return OBS_OK
    x = (T_ring[0, 3], T_ring[1, 3], T_ring[2, 3], n[0], n[1], n[2])
    decision = gate_decide(gate, bounds, t, x)
    ok = decision == 1
    if decision == 2:  # re-acquired only inside the workspace (ConeWorkspace.contains)
        a, axis, tan_half, cos_half, height = cone
        margin = cone_margin(x[0], x[1], x[2], a, axis, tan_half, cos_half, height)
        ok = math.isfinite(margin) and margin >= 0.0
    gate_commit(gate, t, x, ok)
    return OBS_OK if ok else OBS_GATE


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _observed_kernel(
    T_cam: FloatArray,
    T_ring: FloatArray,
    t: float,
    has_t_ring: bool,
    t_ring: float,
    max_age: float,
    gate: GateState,
    bounds: GateBounds,
    params: FloatArray,
    i_cone: int,
    unit_normal: bool,
) -> int:  # pragma: no cover - compiled
    """:func:`observed` from Python, the cone stored from ``params[i_cone]`` (the oracle's)."""
    cone = cone_at(params, i_cone)
    return observed(T_cam, T_ring, t, has_t_ring, t_ring, max_age, gate, bounds, cone, unit_normal)


def pose_array(T: object) -> FloatArray | None:
    """``T`` as a (4, 4) float array (itself when it is one), or ``None`` (missing, wrong shape).

    The boundary from an observation into the compiled checks (:func:`observed`).
    """
    if type(T) is np.ndarray and T.dtype == np.float64 and T.shape == (4, 4):
        return T
    if T is None:
        return None
    arr = np.asarray(T, dtype=float)
    return arr if arr.shape == (4, 4) else None


@register_jitable  # also callable from compiled kernels (the same source)
def orientation_goal(
    T_ring: FloatArray, previous: FloatArray, d_f: float, params: FloatArray
) -> tuple[bool, tuple[Vec, Vec, Vec, Vec]]:
    """Condition III's goal: (found, its rotation columns x, y, z and position, world, m).

    ``T_ring`` (4, 4) the ring pose, world, m; ``previous`` (4, 4) the last goal (or the
    camera); ``d_f`` the working distance, m; ``params`` :func:`_step_kernel`'s. Not found:
    a degenerate ring normal.
    """
    n = (T_ring[0, 2], T_ring[1, 2], T_ring[2, 2])
    norm = math.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
    up = (0.0, 0.0, 1.0)
    if not norm > _MIN_NORMAL:
        return False, (up, up, up, up)
    n = (n[0] / norm, n[1] / norm, n[2] / norm)
    p_c = (T_ring[0, 3], T_ring[1, 3], T_ring[2, 3])
    has_toward, toward = False, up
    if params[_PORT_RULE] != 0.0:
        r = (params[_RCM], params[_RCM + 1], params[_RCM + 2])
        d = (r[0] - p_c[0], r[1] - p_c[1], r[2] - p_c[2])
        norm_d = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        if norm_d > _MIN_NORMAL:  # a ring at the port itself keeps the paper's rule
            has_toward, toward = True, (d[0] / norm_d, d[1] / norm_d, d[2] / norm_d)
    columns = goal_columns(
        p_c,
        n,
        d_f,
        up,
        True,
        (previous[0, 2], previous[1, 2], previous[2, 2]),
        (previous[0, 0], previous[1, 0], previous[2, 0]),
        params[_HYSTERESIS],
        params[_MIN_HEIGHT],
        has_toward,
        toward,
    )
    return True, columns


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _step_kernel(
    T_cam: FloatArray,
    T_ring: FloatArray,
    tips: FloatArray,
    previous: FloatArray,
    t: float,
    has_t_ring: bool,
    t_ring: float,
    d_f: float,
    plain: bool,
    release: float,
    goal: FloatArray,
    T0: FloatArray,
    max_age: float,
    gate: GateState,
    bounds: GateBounds,
    params: FloatArray,
    out: FloatArray,
    has_guard: bool,
    zone: KeepOutState,
) -> tuple[float, bool]:  # pragma: no cover - compiled
    """The moving policies' checks, working distance and goal: (``d_f`` m, found).

    ``T_cam``, ``T_ring`` (4, 4) the observed camera and ring poses, world, m; ``tips`` (K, 3)
    world, m; ``previous`` (4, 4) the last goal or the camera; ``T0`` (4, 4) the centering
    goal's orientation; ``d_f`` m; ``params`` (``_N_PARAMS``,) the policy's constants. First the
    input checks and the ring gate (:func:`observed` at ``t`` s, the ring captured at ``t_ring``
    s unless not ``has_t_ring``, ``max_age`` s; the gate's ``state`` and ``bounds``): an
    observation they refuse gives ``out[_OUT_CHECK]`` its reason and ``(d_f, False)``,
    nothing else done. Then the windows' rule (``window_code``, ``adjusted_distance``), then the
    goal at the new distance: the centering one (the ring centre on the initial optical axis) or
    the orientation one (:func:`orientation_goal`; not found: a degenerate normal). The
    interpreter's operations in its order (docs/conventions.md, "Compiled kernels").

    On the step's plain path (``plain``: no way-point path; the goal's cone margin at least
    ``release``, m; the goal within ``jump_threshold`` of ``previous``) it also asks the
    wire's guard (``has_guard``; ``pts`` … ``clearance``: ``ClearanceGuard.kernel_state``)
    what the interpreter would ask next: whether the goal is clear (``ClearanceGuard.apply``'s
    query; the ring centre its pivot) and, if so, whether the move from the camera to it needs
    a detour (``ClearanceGuard.detour``); a goal not clear leaves the guard's cache as it was.
    The goal (4, 4), world, m, is written into ``goal``, the caller's array (numba unpickles
    the type of every array it returns, ~1 us a call); meaningful when found.
    ``out`` (``_N_OUT``,): whether the guard found the goal clear, whether the move needs a
    detour, and its way-point (m); the ring centre and camera position observed (m); the
    checks' answer.
    """
    prm = params
    check = observed(
        T_cam, T_ring, t, has_t_ring, t_ring, max_age, gate, bounds, cone_at(prm, _CONE), False
    )
    out[_OUT_CHECK] = check
    out[_OUT_CLEARED] = out[_OUT_DETOUR] = 0.0
    out[_OUT_MARGIN] = math.nan
    if check != OBS_OK:
        return d_f, False
    for i in range(3):
        out[_OUT_RING + i], out[_OUT_CAM + i] = T_ring[i, 3], T_cam[i, 3]
    code = window_code_of(T_cam, tips, prm[_WINDOW : _WINDOW + 9])
    d = adjusted_distance(d_f, code, prm[_D_MIN], prm[_D_MAX], prm[_D_STEP])
    T = goal
    for i in range(4):
        for j in range(4):
            T[i, j] = T0[i, j]
    found = True
    if prm[_KIND] == 0.0:  # camera = ring − d z0 + (b/2) x0
        for i in range(3):
            T[i, 3] = T_ring[i, 3] - d * prm[_Z0 + i] + prm[_SHIFT + i]
    else:
        found, (x, y, z, p) = orientation_goal(T_ring, previous, d, prm)
        for i in range(3):
            T[i, 0], T[i, 1], T[i, 2], T[i, 3] = x[i], y[i], z[i], p[i]
        T[3, 0], T[3, 1], T[3, 2], T[3, 3] = 0.0, 0.0, 0.0, 1.0
    if not found:
        return d, found
    g = (T[0, 3], T[1, 3], T[2, 3])
    cone = cone_at(prm, _CONE)
    out[_OUT_MARGIN] = margin = cone_margin(
        g[0], g[1], g[2], cone[0], cone[1], cone[2], cone[3], cone[4]
    )
    if not (has_guard and plain):
        return d, found
    c = (T_ring[0, 3], T_ring[1, 3], T_ring[2, 3])  # the guard's pivot: the ring centre
    if margin >= release and not (
        dist3(g[0], g[1], g[2], previous[0, 3], previous[1, 3], previous[2, 3]) > prm[_JUMP]
    ):
        now = (T_cam[0, 3], T_cam[1, 3], T_cam[2, 3])
        cleared, found_via, via = cleared_move(zone, g, c, now)
        out[_OUT_CLEARED] = 1.0 if cleared else 0.0
        out[_OUT_DETOUR] = 1.0 if found_via else 0.0
        for i in range(3):
            out[_OUT_VIA + i] = via[i]
    return d, found


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


class _MovingPolicy:
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
        cfg = self.config
        params = [0.0] * _N_PARAMS
        params[_WINDOW : _WINDOW + 9] = self._window_geometry.constants
        params[_D_MIN], params[_D_MAX], params[_D_STEP] = cfg.d_min, cfg.d_max, cfg.d_f_step
        params[_HYSTERESIS], params[_MIN_HEIGHT] = cfg.side_hysteresis, cfg.min_camera_height
        params[_PORT_RULE] = 1.0 if cfg.side_rule is SideRule.PORT else 0.0
        params[_RCM : _RCM + 3] = np.asarray(context.p_world_rcm, dtype=float).tolist()
        params[_CONE : _CONE + 9] = self._cone.constants
        params[_JUMP] = cfg.jump_threshold
        self._params = np.array(params)  # _step_kernel's constants
        self._step_out = np.zeros(_N_OUT)  # _step_kernel's results
        self._kernel_goal: FloatArray | None = None  # the goal _step_kernel last gave
        self._kernel_p: list[float] = []  # its position, m, as the kernel checked it
        self._T0 = np.eye(4)  # the centering goal's orientation
        self._kernel_consts: tuple[object, ...] | None = None  # _step_kernel's, at step 1

    @property
    def cone(self) -> ConeWorkspace:
        """The cone workspace fixed at reset."""
        if self._cone is None:
            raise RuntimeError("call reset() before using the policy")
        return self._cone

    def _goal(self, obs: Observation, T_cam: FloatArray, T_ring: FloatArray) -> FloatArray | None:
        """Check ``obs``, set the working distance for its tips, then give the goal (4, 4).

        ``T_cam``, ``T_ring`` (4, 4): the observed camera and ring poses, world, m. ``None``:
        the checks refused the observation (``_step_out[_OUT_CHECK]`` says why) or the ring
        pose gives no goal (a degenerate normal). One compiled call (:func:`_step_kernel`,
        with the subclass's ``_params``).
        """
        tips = obs.p_world_tips
        if not (isinstance(tips, np.ndarray) and tips.ndim == 2):
            tips = np.asarray(tips, dtype=float).reshape(-1, 3)
        previous = self._last_goal if self._last_goal is not None else T_cam
        consts = self._kernel_consts
        if consts is None:
            consts = self._kernel_consts = self._step_constants()
        t_ring = obs.t_ring
        goal = np.empty((4, 4))  # a new array each step: the goal and the command keep it
        self.d_f, found = _step_kernel(
            T_cam,
            T_ring,
            tips,
            previous,
            float(obs.t),
            t_ring is not None,
            0.0 if t_ring is None else float(t_ring),
            self.d_f,
            self._path is None,
            FREEZE_RELEASE_MARGIN if self._frozen_T is not None else 0.0,
            goal,
            *consts,  # type: ignore[arg-type]
        )
        if not found:
            return None
        self._kernel_goal, self._kernel_p = goal, goal[:3, 3].tolist()
        return goal

    def _step_constants(self) -> tuple[object, ...]:
        """:func:`_step_kernel`'s arguments fixed for the episode, from ``T0`` on (a tuple).

        Built at the first step after ``reset`` (a subclass's ``reset`` sets ``_T0``); every
        array in it is updated in place during the episode (the gate's, ``_params``,
        ``_step_out``, the guard's).
        """
        guard, gate = self.guard, self._gate
        return (
            self._T0,
            self.config.ring_max_age,
            gate.state,
            gate.bounds,
            self._params,
            self._step_out,
            guard is not None,
            NO_KEEP_OUT if guard is None else guard.kernel_state,
        )

    def _clear(
        self, T_world_cam: FloatArray, p_world_pivot: Sequence[float], p_world_now: Sequence[float]
    ) -> FloatArray | None:
        """A pose to command kept ``wire_clearance`` from the wire (``control.clearance``).

        ``T_world_cam`` (4, 4) itself when clear or without a wire model; else moved back along
        its optical axis (the look distance grows up to ``d_max``) or, if that does not clear,
        rotated about ``p_world_pivot`` (3,), the ring centre, world, m, towards the camera at
        ``p_world_now`` (3,), m; ``None``: no clear feasible view.
        """
        guard = self.guard
        if guard is None:
            return T_world_cam
        pivot = (p_world_pivot[0], p_world_pivot[1], p_world_pivot[2])
        now = (p_world_now[0], p_world_now[1], p_world_now[2])
        back_off = max(0.0, self.config.d_max - self.d_f)  # the look distance may grow first
        return guard.apply(T_world_cam, pivot, self._workspace, now, back_off)

    def _detoured(
        self,
        T_world_cmd: FloatArray,
        p_world_pivot: Sequence[float],
        p_world_now: Sequence[float],
        traced: tuple[bool, Vec] | None = None,
    ) -> FloatArray | None:
        """A way-point pose around the wire if the straight move to the command crosses it.

        ``None``: the move from the camera at ``p_world_now`` (3,), m, to ``T_world_cmd``
        (4, 4) keeps the clearance (or there is no wire model). The way-point pose looks at
        ``p_world_pivot`` (3,), the ring centre, world, m, with a level horizon, and passes the
        clearance guard itself.

        ``traced``: ``ClearanceGuard.detour``'s answer for this move, (found, way-point), when
        a compiled step asked it already. The way-point pose, the workspace's check of the
        way-point and the guard are one compiled call (``ClearanceGuard.apply_look_at``).
        """
        guard = self.guard
        if guard is None:
            return None
        if traced is None:
            via = guard.detour(p_world_now, T_world_cmd[:3, 3].tolist())
        else:
            via = traced[1] if traced[0] else None
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
        back_off = max(0.0, self.config.d_max - self.d_f)  # as _clear's
        return guard.apply_look_at(
            via, pivot, T_world_cmd, self._last_cmd, self._workspace, now, back_off
        )

    def _hold(self, state: TrackingState, reason: str) -> CameraCommand:
        assert self._last_cmd is not None
        return CameraCommand(self._last_cmd, state, self.d_f, reason)

    def step(self, obs: Observation) -> CameraCommand:
        """Input checks, working distance, goal, cone freeze, way-points — in that order.

        The checks (finite poses, a fresh ring pose, the ring gate; :func:`observed`), the
        working distance and the goal are one compiled call (:meth:`_goal`).
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
            self._last_goal = None
            self._path = None
            return self._hold(TrackingState.LOST_TRACKING, RING_REASON)

        d_f_before = self.d_f
        goal = self._goal(obs, T_cam, T_ring)  # the checks, the working distance, the goal
        out = self._step_out.tolist()
        check = out[_OUT_CHECK]
        if check != OBS_OK:
            if check == OBS_CAMERA:
                return self._hold(TrackingState.LOST_TRACKING, CAMERA_REASON)
            self._last_goal = None
            self._path = None
            return self._hold(TrackingState.LOST_TRACKING, CHECK_REASONS[int(check)])
        if goal is None:
            self.d_f = d_f_before
            self._last_goal = None
            self._path = None
            return self._hold(TrackingState.LOST_TRACKING, "ring pose degenerate (zero normal)")
        p_ring = out[_OUT_RING : _OUT_RING + 3]
        p_now = out[_OUT_CAM : _OUT_CAM + 3]
        # cleared by the kernel, with its trace to the goal: only for the very pose it checked
        # (a subclass's ``_goal`` may change it; then the guard checks it here)
        p_kernel = goal[:3, 3].tolist() if goal is self._kernel_goal else None
        cleared = out[_OUT_CLEARED] != 0.0 and p_kernel == self._kernel_p
        if cleared:
            assert self.guard is not None
            goal = self.guard.passed(goal)
        else:
            goal = self._clear(goal, p_ring, p_now)
        if goal is None:  # the last command passed the guard: hold it, as a freeze does
            self.d_f = d_f_before
            self._last_goal = None
            self._path = None
            return self._hold(TrackingState.FROZEN_OUTSIDE_CONE, WIRE_REASON)
        if p_kernel is not None and goal is self._kernel_goal:
            p_goal = p_kernel  # the guard passed the kernel's goal itself (unchanged)
        else:
            goal_rows = goal.tolist()
            p_goal = [goal_rows[0][3], goal_rows[1][3], goal_rows[2][3]]
        if goal is self._kernel_goal and p_goal == self._kernel_p:
            margin = out[_OUT_MARGIN]  # the kernel's ConeWorkspace.margin of this very pose
        else:
            margin = self.cone.margin(p_goal)
        # Freeze when the goal leaves the cone; release only once it is FREEZE_RELEASE_MARGIN
        # inside, so a goal grazing the surface does not toggle the camera every step.
        release = FREEZE_RELEASE_MARGIN if self._frozen_T is not None else 0.0
        if not margin >= release:
            if self._frozen_T is None:
                self._frozen_T = T_cam
            self.d_f = d_f_before  # the working distance holds with the camera
            self._last_cmd = self._frozen_T
            self._path = None
            self._last_goal = None  # on recovery, a far goal is planned from the camera
            where = "outside" if margin < 0 else "not yet back inside"
            return self._hold(
                TrackingState.FROZEN_OUTSIDE_CONE,
                f"goal {abs(margin) * 1e3:.1f} mm {where} the cone workspace; holding",
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
                wp = self._cleared_waypoint(p, T_ring, goal, p_ring, p_now)
                if wp is None:
                    self._path = None
                    self._last_goal = None
                    return self._hold(TrackingState.FROZEN_OUTSIDE_CONE, WIRE_REASON)
                cmd = wp
                state, reason = TrackingState.PLANNING, "following intermediate way-points"
        if cleared and cmd is goal:  # the plain path: no way-points; the kernel traced the move
            if out[_OUT_DETOUR]:
                p_via = (out[_OUT_VIA], out[_OUT_VIA + 1], out[_OUT_VIA + 2])
                via = self._detoured(cmd, p_ring, p_now, (True, p_via))
            else:  # a straight move: what ``_detoured`` does with no way-point
                self._p_detour, self._stalled = None, 0
                via = None
        else:
            via = self._detoured(cmd, p_ring, p_now)
        if via is not None:
            cmd = via
            state, reason = TrackingState.PLANNING, DETOUR_REASON
        self._last_cmd = cmd
        return CameraCommand(cmd, state, self.d_f, reason)

    def _lift(self, p_world: list[float]) -> float:
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
    ) -> FloatArray | None:
        """``_clear(_waypoint_pose(p, T_ring, goal), p_ring, p_now)``: the way-point's command.

        ``p`` (3,) the way-point, ``T_ring`` (4, 4), ``goal`` (4, 4), ``p_ring`` (3,) the
        ring centre, ``p_now`` (3,) the camera, world, m.
        """
        return self._clear(self._waypoint_pose(p, T_ring, goal), p_ring, p_now)


class _LookingPolicy(_MovingPolicy):
    """A moving policy whose way-point poses look at the ring centre (``_waypoint_pose``)."""

    def _cleared_waypoint(
        self,
        p: FloatArray,
        T_ring: FloatArray,
        goal: FloatArray,
        p_ring: Sequence[float],
        p_now: Sequence[float],
    ) -> FloatArray | None:
        """The way-point's pose and the guard in one compiled call (``apply_look_at``)."""
        guard = self.guard
        if guard is None:
            return self._waypoint_pose(p, T_ring, goal)
        assert self._workspace is not None and self._last_cmd is not None  # set by reset()
        q = p.tolist()
        back_off = max(0.0, self.config.d_max - self.d_f)  # as _clear's
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


class CenteringPolicy(_MovingPolicy):
    """Condition II: keep the initial orientation, put the ring centre on the optical axis."""

    name = "centering"

    def reset(self, context: PolicyContext) -> None:
        """Also fix the orientation it keeps and the offset of the eye it centres."""
        super().reset(context)
        R0 = np.asarray(context.T_world_cam, dtype=float)[:3, :3]
        self._T0 = np.eye(4)
        self._T0[:3, :3] = R0
        half_b = 0.5 * context.camera.baseline if self.config.centre_left_eye else 0.0
        # camera = ring − d z0 + (b/2) x0: the left eye, b/2 along −x, on the ring's line
        self._params[_KIND] = 0.0
        self._params[_Z0 : _Z0 + 3] = R0[:, 2]
        self._params[_SHIFT : _SHIFT + 3] = half_b * R0[:, 0]

    def _waypoint_pose(self, p: FloatArray, T_ring: FloatArray, goal: FloatArray) -> FloatArray:
        T = goal.copy()  # orientation stays fixed on the way too
        T[:3, 3] = p
        return T


class OrientationPolicy(_LookingPolicy):
    """Condition III: the paper's orientation-aware camera (goal on the ring normal)."""

    name = "orientation"

    def reset(self, context: PolicyContext) -> None:
        """Also select the orientation goal (:func:`orientation_goal`)."""
        super().reset(context)
        self._params[_KIND] = 1.0


class OrientationEcmPolicy(OrientationPolicy):
    """The paper's orientation goal, carried out by the 4-DoF ECM (registry entry forces it).

    The goal is condition III's; the ECM's optical axis always passes through its RCM, so the
    camera reaches the goal's position but not, in general, its orientation. The orientation
    error it leaves quantifies what a standard endoscope cannot deliver (paper Sec. I).
    """

    name = "orientation-ecm"


__all__ = [
    "CenteringPolicy",
    "FixedPolicy",
    "OrientationEcmPolicy",
    "OrientationPolicy",
]
