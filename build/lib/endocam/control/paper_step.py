"""The paper's moving policies' compiled step: checks, working distance, goal, guard.

:func:`paper_step` is the numeric core of ``PaperPolicy.step`` (``policies/paper.py``), the
``centering`` and ``orientation`` policies (conditions II and III): the input checks and the
ring gate, the windows' working distance, the goal at that distance (the ring centre on the
initial optical axis, or :func:`orientation_goal`), its cone margin, and the wire guard's answer
on the plain path. The decisions (freeze, way-points, detours) stay in Python.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from numba import njit
from numba.extending import register_jitable

from endocam.control.checks import MIN_NORMAL, OBS_OK, RingChecks, Sighting, observed
from endocam.control.goal import DistanceRange, PreviousAxes, SideChoice, goal_columns
from endocam.control.guard_answer import NOT_ASKED, GuardAnswer, ask_guard
from endocam.control.windows import adjusted_distance, window_code_of
from endocam.geometry import FloatArray
from endocam.kernels import Vec, dist3
from endocam.workspace.cone import Cone, cone_margin
from endocam.workspace.keepout import KeepOutState

__all__ = ["PaperMemory", "PaperResult", "PaperSettings", "orientation_goal", "paper_step"]


class PaperSettings(NamedTuple):
    """:func:`paper_step`'s settings for an episode (built once, at its first step).

    Attributes
    ----------
    checks : RingChecks
        The input checks and the ring gate.
    windows : tuple of float
        ``WindowGeometry.constants``.
    distance : DistanceRange
        The working distance's range and step, m.
    orientation : bool
        The orientation goal (condition III); else the centering goal (condition II).
    side : SideChoice
        The orientation goal's side rule; its ``has_toward``: ``SideRule.PORT`` (the direction
        to the port is computed per step from ``rcm``).
    rcm : 3-tuple
        The camera arm's RCM, world, m.
    T0 : (4, 4) array
        The centering goal's orientation (the initial camera's).
    z0, shift : 3-tuples
        The centering goal's optical axis and its left-eye shift, m: camera = ring − d z0 + shift.
    cone : Cone
        The cone workspace's constants (``cone_at``).
    jump : float
        ``jump_threshold``, m.
    guarded : bool
        A wire model is given: ask its guard on the plain path (``zone``).
    zone : KeepOutState
        The guard's compiled state (``ClearanceGuard.kernel_state``).
    """

    checks: RingChecks
    windows: tuple[float, ...]
    distance: DistanceRange
    orientation: bool
    side: SideChoice
    rcm: Vec
    T0: FloatArray
    z0: Vec
    shift: Vec
    cone: Cone
    jump: float
    guarded: bool
    zone: KeepOutState


class PaperMemory(NamedTuple):
    """What the policy remembers into a step.

    ``d_f`` the committed working distance, m; ``plain``: no way-point path under way;
    ``release`` the cone margin a goal needs to end a freeze, m.
    """

    d_f: float
    plain: bool
    release: float


class PaperResult(NamedTuple):
    """:func:`paper_step`'s answer.

    ``check`` the input checks' answer (``checks.OBS_*``; the rest is meaningful for
    ``OBS_OK``); ``d_f`` the step's candidate working distance, m (committed only with a
    command); ``found``: a goal was found (a degenerate ring normal gives none), written into
    ``goal_out``; ``margin`` its cone margin, m; ``p_ring``, ``p_cam`` the observed ring centre
    and camera position, world, m; ``guard`` the wire guard's answer on the plain path.
    """

    check: int
    d_f: float
    found: bool
    margin: float
    p_ring: Vec
    p_cam: Vec
    guard: GuardAnswer


@register_jitable  # also callable from compiled kernels (the same source)
def orientation_goal(
    settings: PaperSettings, T_ring: FloatArray, previous: FloatArray, d_f: float
) -> tuple[bool, tuple[Vec, Vec, Vec, Vec]]:
    """Condition III's goal: (found, its rotation columns x, y, z and position, world, m).

    ``T_ring`` (4, 4) the ring pose, world, m; ``previous`` (4, 4) the last goal (or the
    camera); ``d_f`` the working distance, m. Not found: a degenerate ring normal.
    """
    n = (T_ring[0, 2], T_ring[1, 2], T_ring[2, 2])
    norm = math.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
    up = (0.0, 0.0, 1.0)
    if not norm > MIN_NORMAL:
        return False, (up, up, up, up)
    n = (n[0] / norm, n[1] / norm, n[2] / norm)
    p_c = (T_ring[0, 3], T_ring[1, 3], T_ring[2, 3])
    rule = settings.side
    if rule.has_toward:
        r = settings.rcm
        d = (r[0] - p_c[0], r[1] - p_c[1], r[2] - p_c[2])
        norm_d = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        # a ring at the port itself keeps the paper's rule
        has_toward = norm_d > MIN_NORMAL
        toward = (d[0] / norm_d, d[1] / norm_d, d[2] / norm_d) if has_toward else up
        rule = SideChoice(rule.up, rule.hysteresis, rule.min_height, has_toward, toward)
    axes = PreviousAxes(
        True,
        (previous[0, 2], previous[1, 2], previous[2, 2]),
        (previous[0, 0], previous[1, 0], previous[2, 0]),
    )
    return True, goal_columns(p_c, n, d_f, axes, rule)


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def paper_step(
    settings: PaperSettings,
    seen: Sighting,
    previous: FloatArray,
    memory: PaperMemory,
    goal_out: FloatArray,
) -> PaperResult:  # pragma: no cover - compiled
    """``PaperPolicy.step`` from the input checks to the goal and the guard's answer.

    ``seen``: the observation; ``previous`` (4, 4) the last goal or the camera. The checks and
    the ring gate first (:func:`~endocam.control.checks.observed`): an observation they refuse
    ends the step there. Then the windows' rule on the working distance, then the goal at the
    new distance, written into ``goal_out`` (4, 4; the caller's new array: the goal and the
    command keep it). On the step's plain path (``memory.plain``; the goal's cone margin at
    least ``memory.release``; the goal within ``jump`` of ``previous``) it asks the wire's
    guard (:func:`~endocam.control.guard_answer.ask_guard`, the ring centre the pivot).
    """
    T_cam, T_ring = seen.T_cam, seen.T_ring
    p_cam = (T_cam[0, 3], T_cam[1, 3], T_cam[2, 3])
    p_ring = (T_ring[0, 3], T_ring[1, 3], T_ring[2, 3])
    check = observed(settings.checks, seen)
    if check != OBS_OK:
        return PaperResult(check, memory.d_f, False, math.nan, p_ring, p_cam, NOT_ASKED)
    dist = settings.distance
    code = window_code_of(T_cam, seen.tips, settings.windows)
    d = adjusted_distance(memory.d_f, code, dist.d_min, dist.d_max, dist.step)
    T = goal_out
    for i in range(4):
        for j in range(4):
            T[i, j] = settings.T0[i, j]
    if settings.orientation:
        found, (x, y, z, p) = orientation_goal(settings, T_ring, previous, d)
        if not found:
            return PaperResult(check, d, False, math.nan, p_ring, p_cam, NOT_ASKED)
        for i in range(3):
            T[i, 0], T[i, 1], T[i, 2], T[i, 3] = x[i], y[i], z[i], p[i]
        T[3, 0], T[3, 1], T[3, 2], T[3, 3] = 0.0, 0.0, 0.0, 1.0
    else:  # camera = ring − d z0 + (b/2) x0
        z0, shift = settings.z0, settings.shift
        for i in range(3):
            T[i, 3] = T_ring[i, 3] - d * z0[i] + shift[i]
    g = (T[0, 3], T[1, 3], T[2, 3])
    a, axis, tan_half, cos_half, height = settings.cone
    margin = cone_margin(g[0], g[1], g[2], a, axis, tan_half, cos_half, height)
    p_prev = (previous[0, 3], previous[1, 3], previous[2, 3])
    near = not (dist3(g[0], g[1], g[2], p_prev[0], p_prev[1], p_prev[2]) > settings.jump)
    guard = NOT_ASKED
    if settings.guarded and memory.plain and margin >= memory.release and near:
        guard = ask_guard(settings.zone, g, p_ring, p_cam)
    return PaperResult(check, d, True, margin, p_ring, p_cam, guard)
