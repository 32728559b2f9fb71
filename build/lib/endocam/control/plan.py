"""The ``endocam`` tracker's compiled step: checks, distance, prediction, side, view, twist.

:func:`plan_step` is the numeric core of ``EndocamPolicy.step`` (``policies/endocam.py``): the
input checks and the ring gate, the windows' working distance, the ring's prediction across the
delay, shortening, the side and its view, the view's pose and its feed-forward twist, and the
wire guard's answer on the plain path. The step's decisions (freeze, transfer, orbit, detour)
stay in Python and read its :class:`PlanResult`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit
from numba.extending import register_jitable

from endocam.control.checks import OBS_OK, RingChecks, Sighting, observed
from endocam.control.goal import DistanceRange, PreviousAxes, SideChoice, goal_columns
from endocam.control.guard_answer import NOT_ASKED, GuardAnswer, ask_guard
from endocam.control.predictor import ring_predict, ring_push
from endocam.control.side_view import (
    ViewRule,
    choose_of,
    pose_of,
    rows_of,
    shortened_of,
    twist_of,
    view_of,
)
from endocam.control.windows import adjusted_distance, window_code_of
from endocam.geometry import FloatArray
from endocam.kernels import Vec, dist3, dot, unit_checked
from endocam.workspace.cone import Cone, cone_margin
from endocam.workspace.keepout import KeepOutState

__all__ = [
    "PlanResult",
    "PlanSettings",
    "TrackerMemory",
    "inside_kernel",
    "inside_of",
    "plan_step",
]

Twist = tuple[float, float, float, float, float, float]
_NO_TWIST: Twist = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


class PlanSettings(NamedTuple):
    """:func:`plan_step`'s settings for an episode (built once, at its first step).

    Attributes
    ----------
    checks : RingChecks
        The input checks and the ring gate.
    windows : tuple of float
        ``WindowGeometry.constants``.
    distance : DistanceRange
        The working distance's range and step, m.
    view_rule : ViewRule
        The kept side's view (aim floor, left eye, side-change angle, cone).
    keep_side, shorten : bool
        ``TrackerConfig.keep_side`` and ``shorten_when_low``.
    paper_side : SideChoice
        Without ``keep_side``: the orientation policy's side rule (its ``toward``, the port
        direction, is computed per step from ``rcm``).
    rcm : 3-tuple
        The camera arm's RCM, world, m.
    jump : float
        ``jump_threshold``, m.
    cmd_floor : float
        The lowest commanded camera height, m (the last gate's floor).
    samples, sample_count : arrays
        The :class:`~endocam.control.predictor.RingPredictor`'s samples and their count.
    spacing : int
        Its spacing, samples.
    given : bool
        The predictions are given (the oracle's, in ``predictions``), not made here.
    predictions : (12,) array
        Given: the ring centre (m) and unit normal ``horizon`` s ahead, then ``horizon + dt``.
    horizon, dt : float
        How far ahead the view is taken and the control period, s.
    feedforward : bool
        Compute the view's twist (the goal's velocity) for the carrier.
    guarded : bool
        A wire model is given: ask its guard on the plain path (``zone``).
    zone : KeepOutState
        The guard's compiled state (``ClearanceGuard.kernel_state``).
    """

    checks: RingChecks
    windows: tuple[float, ...]
    distance: DistanceRange
    view_rule: ViewRule
    keep_side: bool
    shorten: bool
    paper_side: SideChoice
    rcm: Vec
    jump: float
    cmd_floor: float
    samples: FloatArray
    sample_count: np.ndarray
    spacing: int
    given: bool
    predictions: FloatArray
    horizon: float
    dt: float
    feedforward: bool
    guarded: bool
    zone: KeepOutState


class TrackerMemory(NamedTuple):
    """What the tracker remembers into a step.

    ``d_f`` the committed working distance, m; ``side`` the kept side (0: none yet);
    ``planned`` a side to take first while feasible (0: none; the oracle's plan); ``fresh``: no
    goal before (a far first goal starts a transfer); ``plain``: no transfer under way;
    ``release`` the cone margin a view needs to end a freeze, m.
    """

    d_f: float
    side: float
    planned: float
    fresh: bool
    plain: bool
    release: float


class PlanResult(NamedTuple):
    """:func:`plan_step`'s answer.

    Attributes
    ----------
    check : int
        The input checks' answer (``checks.OBS_*``); the rest is meaningful for ``OBS_OK``.
    d_f : float
        The step's candidate working distance, m (committed only with a command).
    found : bool
        A feasible view was found; then ``view_out`` holds its pose.
    side : float
        Its side, ±1.
    u : 3-tuple
        Its direction from the ring centre to the camera, unit.
    p_c : 3-tuple
        The (predicted) ring centre, world, m.
    p_cam : 3-tuple
        The observed camera position, world, m.
    margin : float
        The view's cone margin, m.
    inside : bool
        The last gate on the view: inside the cone and at or above ``cmd_floor``.
    has_twist : bool
        ``twist`` was computed: the view's velocity to the next step's view, linear m/s then
        angular rad/s, world.
    twist : 6-tuple
    guard : GuardAnswer
        The wire guard's answer on the plain path (not asked: ``cleared`` false).
    """

    check: int
    d_f: float
    found: bool
    side: float
    u: Vec
    p_c: Vec
    p_cam: Vec
    margin: float
    inside: bool
    has_twist: bool
    twist: Twist
    guard: GuardAnswer


@register_jitable  # also callable from compiled kernels (the same source)
def inside_of(T: FloatArray, cone: Cone, floor: float) -> bool:
    """Whether the pose ``T`` (4, 4), world, m, is inside ``cone`` and at or above ``floor`` (m).

    ``ConeWorkspace.margin(p) >= 0 and p[2] >= floor`` for its position ``p``.
    """
    a, axis, tan_half, cos_half, height = cone
    p = (T[0, 3], T[1, 3], T[2, 3])
    inside = cone_margin(p[0], p[1], p[2], a, axis, tan_half, cos_half, height) >= 0.0
    return inside and p[2] >= floor


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def inside_kernel(T: FloatArray, cone: Cone, floor: float) -> bool:  # pragma: no cover
    """:func:`inside_of` from Python: the tracker's last gate on a command."""
    return inside_of(T, cone, floor)


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def plan_step(
    settings: PlanSettings,
    seen: Sighting,
    previous: FloatArray,
    memory: TrackerMemory,
    view_out: FloatArray,
) -> PlanResult:  # pragma: no cover - compiled
    """``EndocamPolicy.step`` from the input checks to the view, its twist and the guard.

    ``seen``: the observation (the camera's and ring's poses, the tips, the times);
    ``previous`` (4, 4) the last goal or command; ``memory`` what the tracker remembers.
    The checks and the ring gate first (:func:`~endocam.control.checks.observed`): an
    observation they refuse ends the step there. Then the working distance (the windows'
    rule), the ring's prediction (pushed into the predictor's samples, unless ``given``),
    shortening, side and view, the view's pose (written into ``view_out`` (4, 4), the
    caller's new array: the goal and the command keep it), its last gate, and the
    feed-forward twist. On the step's plain path (no transfer under way, the view's margin at
    least ``memory.release``, no side change, not a far first goal) it asks the wire's guard
    (:func:`~endocam.control.guard_answer.ask_guard`).
    """
    p_cam = (seen.T_cam[0, 3], seen.T_cam[1, 3], seen.T_cam[2, 3])
    check = observed(settings.checks, seen)
    if check != OBS_OK:
        return PlanResult(
            check, memory.d_f, False, 0.0, p_cam, p_cam, p_cam, 0.0, False, False, _NO_TWIST,
            NOT_ASKED,
        )  # fmt: skip
    T_ring = seen.T_ring
    dist = settings.distance
    code = window_code_of(seen.T_cam, seen.tips, settings.windows)
    d = adjusted_distance(memory.d_f, code, dist.d_min, dist.d_max, dist.step)
    given = settings.predictions
    if settings.given:
        p_c, n = (given[0], given[1], given[2]), (given[3], given[4], given[5])
    else:
        _, n_obs = unit_checked((T_ring[0, 2], T_ring[1, 2], T_ring[2, 2]))
        ring_push(
            settings.samples,
            settings.sample_count,
            seen.t,
            (T_ring[0, 3], T_ring[1, 3], T_ring[2, 3]),
            n_obs,
        )
        p_c, n = ring_predict(
            settings.samples, settings.sample_count, settings.spacing, settings.horizon
        )
    rule = settings.view_rule
    side = memory.side
    if code == 1 and settings.keep_side and settings.shorten:
        d = shortened_of(rule, dist, settings.windows, p_c, n, d, side, previous, seen.tips)
    axes = PreviousAxes(
        True,
        (previous[0, 2], previous[1, 2], previous[2, 2]),
        (previous[0, 0], previous[1, 0], previous[2, 0]),
    )
    if settings.keep_side:
        found, s, u = choose_of(rule, p_c, n, d, side, memory.planned)
    else:  # the orientation policy's side rule
        paper = settings.paper_side
        if paper.has_toward:
            r = settings.rcm
            has_toward, toward = unit_checked((r[0] - p_c[0], r[1] - p_c[1], r[2] - p_c[2]))
            paper = SideChoice(paper.up, paper.hysteresis, paper.min_height, has_toward, toward)
        _, _, z_goal, _ = goal_columns(p_c, n, d, axes, paper)
        s = -1.0 if dot(z_goal, n) > 0.0 else 1.0
        found, u = True, (s * n[0], s * n[1], s * n[2])
    if not found:
        return PlanResult(
            check, d, False, s, u, p_c, p_cam, 0.0, False, False, _NO_TWIST, NOT_ASKED
        )
    x, y, z, p = pose_of(p_c, u, d, axes, rule.half_b)
    view = view_out
    for i in range(3):
        view[i, 0], view[i, 1], view[i, 2], view[i, 3] = x[i], y[i], z[i], p[i]
    view[3, 0], view[3, 1], view[3, 2], view[3, 3] = 0.0, 0.0, 0.0, 1.0
    inside = inside_of(view, rule.cone, settings.cmd_floor)  # the last gate, as on a command
    a, axis, tan_half, cos_half, height = rule.cone
    margin = cone_margin(p[0], p[1], p[2], a, axis, tan_half, cos_half, height)
    far_first = (
        memory.fresh and dist3(p[0], p[1], p[2], p_cam[0], p_cam[1], p_cam[2]) > settings.jump
    )
    side_changed = side != 0.0 and s != side
    plain = memory.plain and margin >= memory.release and not side_changed and not far_first
    guard = NOT_ASKED
    if (
        settings.guarded and plain
    ):  # the plain path: the view is the command unless the guard turns it
        guard = ask_guard(settings.zone, p, p_c, p_cam)
    has_twist, twist = False, _NO_TWIST
    if settings.feedforward:
        if settings.given:
            p2, n2 = (given[6], given[7], given[8]), (given[9], given[10], given[11])
        else:
            p2, n2 = ring_predict(
                settings.samples,
                settings.sample_count,
                settings.spacing,
                settings.horizon + settings.dt,
            )
        if settings.keep_side:
            next_view = view_of(rule, p2, n2, s, d)
            has_u2, u2 = next_view.found, next_view.u
        else:
            k = 1.0 if dot(u, n) >= 0.0 else -1.0  # ``n2`` signed like ``u`` is relative to ``n``
            has_u2, u2 = True, (k * n2[0], k * n2[1], k * n2[2])
        if has_u2:  # the next goal, its roll from this one
            x2, y2, z2, p2_cam = pose_of(p2, u2, d, PreviousAxes(True, z, x), rule.half_b)
            has_twist, twist = True, twist_of(view, rows_of(x2, y2, z2, p2_cam), settings.dt)
    return PlanResult(check, d, True, s, u, p_c, p_cam, margin, inside, has_twist, twist, guard)
