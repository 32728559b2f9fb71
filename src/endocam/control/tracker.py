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

The step runs on plain floats (no scipy); its maths from the working distance to the view and
its twist is one compiled call (:func:`_plan_kernel`, docs/conventions.md "Compiled kernels"),
the interpreter's floats bit for bit (``tests/test_tracker_kernel.py``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numba import njit
from numba.extending import register_jitable

from endocam.control.config import ControllerConfig, SideRule, Transfer
from endocam.control.detour import cleared_move
from endocam.control.gate import GateBounds, GateState
from endocam.control.goal import goal_columns
from endocam.control.planner import WaypointPath, advance, intermediate_waypoints
from endocam.control.policies import (
    CAMERA_REASON,
    CHECK_REASONS,
    DETOUR_REASON,
    FREEZE_RELEASE_MARGIN,
    OBS_CAMERA,
    OBS_OK,
    RING_REASON,
    WIRE_REASON,
    _MovingPolicy,
    _observed_kernel,
    observed,
    pose_array,
)
from endocam.control.types import CameraCommand, Observation, PolicyContext, TrackingState
from endocam.control.windows import adjusted_distance, window_code_of
from endocam.geometry import UP, FloatArray
from endocam.kernels import (
    Vec,
    cross,
    dist3,
    dot,
    finite_rows,
    norm,
    unit_checked,
    unit_or_none,
)
from endocam.view import look_at_unchecked, pose_from_columns
from endocam.workspace.cone import Cone, cone_at, cone_margin
from endocam.workspace.keepout import NO_KEEP_OUT, KeepOutState

_EPS = 1e-9  # unitless: shorter directions are degenerate
ORBIT_DONE_ANGLE = math.radians(1.0)  # rad: an orbit this close to its goal direction ends
FLOOR_TOL_M = 1e-9  # m: round-off allowed on the floor height of a built pose


@register_jitable  # also callable from compiled kernels (the same source)
def _angle(a: Vec, b: Vec) -> float:
    """Angle between two unit vectors, rad (atan2 form: accurate near 0 and π)."""
    return math.atan2(norm(cross(a, b)), dot(a, b))


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _ring_push(
    buf: FloatArray, count: np.ndarray, t: float, p: Vec, n: Vec
) -> None:  # pragma: no cover - compiled
    """Append a sample to ``buf`` (L, 7): time (s), centre (3,) world m, unit normal (3,).

    ``count`` (1,): rows in use, oldest first; a full buffer drops its oldest row (a deque
    of length L).
    """
    rows = buf.shape[0]
    if count[0] == rows:
        for r in range(rows - 1):
            for c in range(7):
                buf[r, c] = buf[r + 1, c]
        row = rows - 1
    else:
        row = count[0]
        count[0] += 1
    buf[row, 0] = t
    buf[row, 1], buf[row, 2], buf[row, 3] = p[0], p[1], p[2]
    buf[row, 4], buf[row, 5], buf[row, 6] = n[0], n[1], n[2]


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _ring_predict(buf: FloatArray, count: np.ndarray, m: int, h: float) -> tuple[Vec, Vec]:
    """:meth:`RingPredictor.predict` from its samples ``buf`` (L, 7) and ``count`` (1,).

    Ring centre (m) and unit normal in world, ``h`` s after the newest sample; ``m`` the
    spacing. The interpreter's floats: the same operations in the same order.
    """
    k = count[0] - 1
    t_k = buf[k, 0]
    x = np.empty(6)
    for i in range(6):
        x[i] = buf[k, i + 1]
    if count[0] > m and h != 0.0:
        tau = t_k - buf[k - m, 0]
        if not tau > 0.0:
            pass
        elif count[0] > 2 * m:
            inv = 1.0 / tau
            for i in range(6):
                a0, a1, a2 = buf[k, i + 1], buf[k - m, i + 1], buf[k - 2 * m, i + 1]
                v = (a0 - a1) * inv
                acc = (a0 - 2.0 * a1 + a2) * inv * inv
                x[i] = a0 + (v + 0.5 * acc * tau) * h + 0.5 * acc * h * h
        else:
            f = h / tau
            for i in range(6):
                a0, a1 = buf[k, i + 1], buf[k - m, i + 1]
                x[i] = a0 + (a0 - a1) * f
    ok, n = unit_checked((x[3], x[4], x[5]))
    if not ok:
        n = (buf[k, 4], buf[k, 5], buf[k, 6])
    return (x[0], x[1], x[2]), n


class RingPredictor:
    r"""Extrapolates the ring centre and normal from delayed, evenly timed samples.

    Velocity and acceleration are finite differences over samples ``spacing`` steps apart:
    with the newest sample ``x_k`` at ``t_k``,

    .. math::

        v_b = \frac{x_k - x_{k-m}}{\tau}, \quad a = \frac{x_k - 2x_{k-m} + x_{k-2m}}{\tau^2},
        \quad x(t_k + h) \approx x_k + (v_b + a\tau/2)\,h + a h^2/2

    (``v_b`` is the velocity at ``t_k − τ/2``). The normal is extrapolated the same way and
    renormalised. With fewer samples it falls back to lower orders. Compiled
    (:func:`_ring_push`, :func:`_ring_predict`; the tracker's step calls them inside its own
    kernel).

    Parameters
    ----------
    spacing : int
        ``m``, samples between the differenced ones (≥ 1).
    """

    def __init__(self, spacing: int) -> None:
        if spacing < 1:
            raise ValueError(f"spacing must be ≥ 1, got {spacing}")
        self.spacing = spacing
        self.buf = np.zeros((2 * spacing + 1, 7))  # (t s, centre m, normal), oldest first
        self.count = np.zeros(1, dtype=np.int64)  # rows of buf in use

    def reset(self) -> None:
        """Forget every sample (after lost tracking: no differencing across a gap)."""
        self.count[0] = 0

    def push(self, t: float, p_world: Vec, n_world: Vec) -> None:
        """Add a sample: time ``t`` (s), ring centre (3,) in world (m), unit normal (3,)."""
        p, n = p_world, n_world
        _ring_push(
            self.buf,
            self.count,
            float(t),
            (float(p[0]), float(p[1]), float(p[2])),
            (float(n[0]), float(n[1]), float(n[2])),
        )

    def predict(self, h: float) -> tuple[Vec, Vec]:
        """Ring centre (m) and unit normal in world, ``h`` seconds after the newest sample."""
        if not self.count[0]:
            raise IndexError("no sample to predict from")
        return _ring_predict(self.buf, self.count, self.spacing, float(h))


# The goal, view and twist of one step (EndocamPolicy's maths), callable from Python and
# compiled inside ``_plan_kernel``. ``cone`` is the cone workspace's constants: apex (3,),
# world, m; unit axis (3,); tan and cos of the half-angle; height, m (``ConeWorkspace``).

Grid = Sequence[Sequence[float]] | FloatArray  # rows of a matrix: lists, tuples or an array


@register_jitable  # also callable from compiled kernels (the same source)
def _view_of(
    p_c: Vec, n: Vec, s: float, d: float, aim_floor: float, cone: Cone
) -> tuple[bool, Vec, float, float]:
    """Feasible viewing direction on side ``s``: (found, unit ``u``, angle to ``s n``, margin).

    The angle in rad, the margin in m.

    ``p_c`` ring centre, world, m; ``n`` unit normal; ``d`` look distance, m; ``aim_floor``
    the lowest camera height aimed at, m. ``u`` points from the ring centre to the camera;
    not found if no direction keeps the camera ``aim_floor`` high. The margin is the
    camera's to the cone, m.
    """
    u: Vec = (s * n[0], s * n[1], s * n[2])
    c = (aim_floor - p_c[2]) / d
    err = 0.0
    if u[2] < c:
        if c > 1.0:
            return False, u, err, 0.0
        horiz = math.hypot(u[0], u[1])
        if not horiz > _EPS:
            return False, u, err, 0.0
        k = math.sqrt(1.0 - c * c) / horiz
        u_c = (u[0] * k, u[1] * k, c)
        err = _angle(u, u_c)
        u = u_c
    a, axis, tan_half, cos_half, height = cone
    margin = cone_margin(
        p_c[0] + d * u[0], p_c[1] + d * u[1], p_c[2] + d * u[2], a, axis, tan_half, cos_half, height
    )
    return True, u, err, margin


@register_jitable  # also callable from compiled kernels (the same source)
def _pose_of(
    p_c: Vec, u: Vec, r: float, has_previous: bool, z_prev: Vec, x_prev: Vec, half_b: float
) -> tuple[Vec, Vec, Vec, Vec]:
    """Look at ``p_c`` from ``p_c + r u`` with a level horizon: columns x, y, z and position.

    ``p_c`` world, m; ``u`` unit; ``r`` m; ``z_prev``, ``x_prev``: the previous pose's axes
    (read if ``has_previous``), for the roll near the vertical; the left eye, ``half_b`` (m)
    left of the centre, on the axis when it is non-zero.
    """
    # ``toward = u`` makes the goal take the side of ``u`` itself: position p_c + r u,
    # optical axis −u, roll from the previous pose near the vertical.
    x, y, z, p = goal_columns(
        p_c, u, r, (0.0, 0.0, 1.0), has_previous, z_prev, x_prev, 0.0, -math.inf, True, u
    )
    if half_b:
        p = (p[0] + half_b * x[0], p[1] + half_b * x[1], p[2] + half_b * x[2])
    return x, y, z, p


@register_jitable  # also callable from compiled kernels (the same source)
def _twist_of(a: Grid, b: Grid, delta: float) -> tuple[float, float, float, float, float, float]:
    """Velocity from pose ``a`` to ``b`` (rows, (4, 4)) over ``delta`` s: linear m/s, angular rad/s.

    World frame. ``R_b R_a^T ≈ I + [ω δ]×``: its skew part gives ω (small angle over one
    control period).
    """
    inv = 1.0 / delta
    # m_ij = R_b[i] · R_a[j]; ``0.0 +`` first, as ``sum`` starts (the same float, signed zeros too)
    b0, b1, b2, a0, a1, a2 = b[0], b[1], b[2], a[0], a[1], a[2]
    m21 = 0.0 + b2[0] * a1[0] + b2[1] * a1[1] + b2[2] * a1[2]
    m12 = 0.0 + b1[0] * a2[0] + b1[1] * a2[1] + b1[2] * a2[2]
    m02 = 0.0 + b0[0] * a2[0] + b0[1] * a2[1] + b0[2] * a2[2]
    m20 = 0.0 + b2[0] * a0[0] + b2[1] * a0[1] + b2[2] * a0[2]
    m10 = 0.0 + b1[0] * a0[0] + b1[1] * a0[1] + b1[2] * a0[2]
    m01 = 0.0 + b0[0] * a1[0] + b0[1] * a1[1] + b0[2] * a1[2]
    return (
        (b0[3] - a0[3]) * inv,
        (b1[3] - a1[3]) * inv,
        (b2[3] - a2[3]) * inv,
        0.5 * (m21 - m12) * inv,
        0.5 * (m02 - m20) * inv,
        0.5 * (m10 - m01) * inv,
    )


_NO_PREDICTIONS = np.zeros(0)  # _plan_kernel predicts itself

# _plan_kernel's parameters (``EndocamPolicy._params``), by index
(
    _AIM_FLOOR,  # m, goals keep the camera this high
    _HALF_B,  # m, the left eye's offset (0: centred)
    _D_MIN,
    _D_MAX,
    _D_STEP,  # m, the working distance's range and step
    _SIDE_ANGLE,  # rad, side_change_angle
    _MIN_HEIGHT,  # m, min_camera_height
    _HYSTERESIS,  # rad, side_hysteresis
    _KEEP_SIDE,
    _SHORTEN,
    _PORT_RULE,  # 1.0 / 0.0 flags: keep_side, shorten_when_low, SideRule.PORT
    _WINDOW,  # 9 constants of window_code
) = range(12)
_CONE = _WINDOW + 9  # apex (3), axis (3), tan_half, cos_half, height
_RCM = _CONE + 9  # m, the camera arm's RCM (3)
_JUMP = _RCM + 3  # m, jump_threshold
_CMD_FLOOR = _JUMP + 1  # m, the lowest commanded camera height (the last gate's floor)
_N_PARAMS = _CMD_FLOOR + 1
# _plan_kernel's scalar results (``out``), by index
_OUT_D, _OUT_FOUND, _OUT_SIDE, _OUT_MARGIN, _OUT_TWIST = range(5)
_OUT_P, _OUT_N, _OUT_U = 5, 8, 11  # ring centre (m), normal, view direction: 3 each
_OUT_CLEARED, _OUT_DETOUR, _OUT_VIA = 14, 15, 16  # the guard's answers on the plain path
_OUT_CAM = 19  # m, the observed camera position (3)
_OUT_CHECK = 22  # the observation's checks (``policies.observed``: OBS_*)
_OUT_INSIDE = 23  # the last gate on the view: inside the cone and above the command floor
_N_OUT = 24


@register_jitable  # also callable from compiled kernels (the same source)
def _rows_of(x: Vec, y: Vec, z: Vec, p: Vec) -> FloatArray:
    """``pose_from_columns`` in a compiled kernel: (4, 4) from columns and position."""
    T = np.empty((4, 4))
    for i in range(3):
        T[i, 0], T[i, 1], T[i, 2], T[i, 3] = x[i], y[i], z[i], p[i]
    T[3, 0], T[3, 1], T[3, 2], T[3, 3] = 0.0, 0.0, 0.0, 1.0
    return T


@register_jitable  # also callable from compiled kernels (the same source)
def _choose_of(
    p_c: Vec,
    n: Vec,
    d: float,
    side: float,
    planned: float,
    limit: float,
    aim_floor: float,
    cone: Cone,
) -> tuple[bool, float, Vec]:
    """Side and viewing direction (keep the side while feasible): (found, ``s``, unit ``u``).

    ``side`` the kept side (0: none yet: the paper's, above the feature); ``planned`` a side
    taken first while its view is feasible (0: none; the oracle's plan); ``limit``
    ``side_change_angle``, rad; the rest as :func:`_view_of`'s. Not found: no feasible view.
    """
    if planned != 0.0:
        ok, u, _, margin = _view_of(p_c, n, planned, d, aim_floor, cone)
        if ok and margin >= 0.0:
            return True, planned, u
    s = side if side != 0.0 else (1.0 if n[2] >= 0.0 else -1.0)  # Python's ``side or …``
    ok, u, err, margin = _view_of(p_c, n, s, d, aim_floor, cone)
    if ok and margin >= 0.0 and (err <= limit or side == 0.0):
        return True, s, u
    ok_o, u_o, err_o, margin_o = _view_of(p_c, n, -s, d, aim_floor, cone)
    if ok_o and margin_o >= 0.0:
        if not ok or margin < 0.0 or err_o < err:
            return True, -s, u_o
    if ok and margin >= 0.0:
        return True, s, u  # over the angle, but the other side is no better
    return False, s, u


@register_jitable  # also callable from compiled kernels (the same source)
def _shortened_of(
    p_c: Vec,
    n: Vec,
    d: float,
    side: float,
    previous: Grid,
    tips: Grid,
    params: Sequence[float] | FloatArray,
    cone: Cone,
) -> float:
    """Look distance one ``d_f_step`` shorter if the kept view is height-limited, else ``d`` (m).

    Height-limited: the camera on side ``s`` at ``d`` would sit below ``min_camera_height``
    (``s n·up < (h_min − p_c·up) / d``), so it is turned off the normal. A shorter look
    distance lowers the camera's drop below ``p_c`` and lets it turn back. The step is
    taken only if every tip (``tips`` (K, 3), world, m) stays inside the outer window of the
    shortened goal (the window rule keeps priority: the caller shortens only while every tip
    is between the windows). ``previous`` (4, 4) rows: the last goal or command;
    ``params``: :func:`_plan_kernel`'s.
    """
    prm = params
    aim_floor = prm[_AIM_FLOOR]
    s = side if side != 0.0 else (1.0 if n[2] >= 0.0 else -1.0)  # Python's ``side or …``
    if not s * n[2] * d < aim_floor - p_c[2]:
        return d
    d_next = d - prm[_D_STEP]
    if d_next < prm[_D_MIN]:
        return d
    ok, u, err, _ = _view_of(p_c, n, s, d_next, aim_floor, cone)
    ok_now, _, err_now, _ = _view_of(p_c, n, s, d, aim_floor, cone)
    if not ok or (ok_now and not err < err_now):
        return d  # shorter only where it turns the view towards the normal
    z_prev = (previous[0][2], previous[1][2], previous[2][2])
    x_prev = (previous[0][0], previous[1][0], previous[2][0])
    x, y, z, p = _pose_of(p_c, u, d_next, True, z_prev, x_prev, prm[_HALF_B])
    goal = (
        (x[0], y[0], z[0], p[0]),
        (x[1], y[1], z[1], p[1]),
        (x[2], y[2], z[2], p[2]),
    )
    code = window_code_of(goal, tips, prm[_WINDOW : _WINDOW + 9])
    return d if code == 0 else d_next


@register_jitable  # also callable from compiled kernels (the same source)
def _identity_into(T: FloatArray, twist: FloatArray) -> None:  # pragma: no cover - compiled
    """Set ``T`` (4, 4) to the identity and ``twist`` (6,) to zero, in place."""
    for i in range(4):
        for j in range(4):
            T[i, j] = 1.0 if i == j else 0.0
    for i in range(6):
        twist[i] = 0.0


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _plan_kernel(
    T_cam: FloatArray,
    T_ring: FloatArray,
    tips: FloatArray,
    previous: FloatArray,
    t: float,
    check: bool,
    has_t_ring: bool,
    t_ring: float,
    given: FloatArray,
    d_f: float,
    fresh: bool,
    side: float,
    planned: float,
    plain: bool,
    release: float,
    view_out: FloatArray,
    twist_out: FloatArray,
    buf: FloatArray,
    count: np.ndarray,
    spacing: int,
    max_age: float,
    gate: GateState,
    bounds: GateBounds,
    horizon: float,
    dt: float,
    feedforward: bool,
    params: FloatArray,
    out: FloatArray,
    has_guard: bool,
    zone: KeepOutState,
) -> None:  # pragma: no cover - compiled
    """:meth:`EndocamPolicy.step` from the input checks to the view and its twist.

    If ``check``: the input checks and the ring gate first (``policies.observed`` at ``t`` s,
    the ring captured at ``t_ring`` s unless not ``has_t_ring``, ``max_age`` s, the gate's
    ``state`` and ``bounds``), and an observation they refuse ends the step there with
    ``out[_OUT_CHECK]`` its reason. Then working distance (the windows), prediction, shortening,
    side and view, the view's pose and (speculatively) its feed-forward twist, with the
    interpreter's operations in its order (docs/conventions.md, "Compiled kernels").

    ``T_cam``, ``T_ring`` (4, 4): camera and (checked) ring poses, world, m; ``tips`` (K, 3)
    world, m; ``previous`` (4, 4) the last goal or command. ``buf`` (L, 7), ``count`` (1,),
    ``spacing``: the :class:`RingPredictor`, which gets the ring pose at ``t`` (s) and
    predicts ``horizon`` s ahead (and ``horizon + dt`` for the twist, if ``feedforward``) —
    unless ``given`` (12,) holds those two predictions (centre m, normal; the oracle's;
    else (0,)). ``d_f`` m; ``side`` the kept side (0: none yet); ``planned`` a side to take
    while feasible (0: none); ``params`` (``_N_PARAMS``,) the policy's constants.

    On the step's plain path (``plain``: no transfer under way; the view's margin at least
    ``release``, m; no side change; not a far first goal, ``fresh``: no goal before) it also
    asks the wire's guard (``has_guard``; ``pts`` … ``clearance``: ``ClearanceGuard._state``)
    what the interpreter would ask next: whether the view is clear (``ClearanceGuard.apply``'s
    query) and, if so, whether the move from the camera to it needs a detour
    (``ClearanceGuard.detour``). A view not clear leaves the guard's cache as it was.

    Fills ``out`` (``_N_OUT``,): the new working distance (m), whether a view was found,
    its side, its pose's cone margin (m), whether a twist was computed, the predicted ring
    centre (m) and normal, the view direction, whether the guard found the view clear,
    whether the move needs a detour and its way-point (m), the camera's position (m), the
    checks' answer, and the step's last gate on the view (:func:`_inside_of`: inside the cone,
    at or above ``params[_CMD_FLOOR]``), which the step reads when the view is the command.
    Writes the view's pose into ``view_out`` (4, 4) and the goal's twist from
    the view to the next step's into ``twist_out`` (6,): m/s, rad/s, world (meaningful when
    found, and when computed; else the identity and zeros). The caller's arrays, not returned
    ones: numba unpickles the type of every array it returns (~1 us a call).
    """
    prm = params
    cone = cone_at(prm, _CONE)
    out[_OUT_CHECK] = OBS_OK
    if check:
        answer = observed(T_cam, T_ring, t, has_t_ring, t_ring, max_age, gate, bounds, cone, True)
        if answer != OBS_OK:
            out[_OUT_CHECK] = answer
            _identity_into(view_out, twist_out)
            return
    for i in range(3):
        out[_OUT_CAM + i] = T_cam[i, 3]
    code = window_code_of(T_cam, tips, prm[_WINDOW : _WINDOW + 9])
    d_f = adjusted_distance(d_f, code, prm[_D_MIN], prm[_D_MAX], prm[_D_STEP])
    if given.shape[0] == 0:
        _, n_obs = unit_checked((T_ring[0, 2], T_ring[1, 2], T_ring[2, 2]))
        _ring_push(buf, count, t, (T_ring[0, 3], T_ring[1, 3], T_ring[2, 3]), n_obs)
        p_c, n = _ring_predict(buf, count, spacing, horizon)
    else:
        p_c, n = (given[0], given[1], given[2]), (given[3], given[4], given[5])
    aim_floor, half_b = prm[_AIM_FLOOR], prm[_HALF_B]
    keep_side = prm[_KEEP_SIDE] != 0.0
    if code == 1 and keep_side and prm[_SHORTEN] != 0.0:
        d_f = _shortened_of(p_c, n, d_f, side, previous, tips, prm, cone)
    d = d_f
    z_prev = (previous[0, 2], previous[1, 2], previous[2, 2])
    x_prev = (previous[0, 0], previous[1, 0], previous[2, 0])
    if keep_side:
        found, s, u = _choose_of(p_c, n, d, side, planned, prm[_SIDE_ANGLE], aim_floor, cone)
    else:  # the orientation policy's side rule
        has_toward, toward = False, n
        if prm[_PORT_RULE] != 0.0:
            has_toward, toward = unit_checked(
                (prm[_RCM] - p_c[0], prm[_RCM + 1] - p_c[1], prm[_RCM + 2] - p_c[2])
            )
        _, _, zz, _ = goal_columns(
            p_c,
            n,
            d,
            (0.0, 0.0, 1.0),
            True,
            z_prev,
            x_prev,
            prm[_HYSTERESIS],
            prm[_MIN_HEIGHT],
            has_toward,
            toward,
        )
        s = -1.0 if dot(zz, n) > 0.0 else 1.0
        found, u = True, (s * n[0], s * n[1], s * n[2])
    out[_OUT_D] = d
    out[_OUT_FOUND] = 1.0 if found else 0.0
    out[_OUT_SIDE] = s
    out[_OUT_TWIST] = out[_OUT_CLEARED] = out[_OUT_DETOUR] = out[_OUT_INSIDE] = 0.0
    for i in range(3):
        out[_OUT_P + i], out[_OUT_N + i], out[_OUT_U + i] = p_c[i], n[i], u[i]
    if not found:
        _identity_into(view_out, twist_out)
        return
    x, y, z, p = _pose_of(p_c, u, d, True, z_prev, x_prev, half_b)
    view = view_out
    for i in range(3):
        view[i, 0], view[i, 1], view[i, 2], view[i, 3] = x[i], y[i], z[i], p[i]
    view[3, 0], view[3, 1], view[3, 2], view[3, 3] = 0.0, 0.0, 0.0, 1.0
    for i in range(6):
        twist_out[i] = 0.0
    # the last gate on the view, as the step asks it of a command (_inside_kernel's test)
    out[_OUT_INSIDE] = 1.0 if _inside_of(view, prm, prm[_CMD_FLOOR]) else 0.0
    out[_OUT_MARGIN] = margin = cone_margin(
        p[0], p[1], p[2], cone[0], cone[1], cone[2], cone[3], cone[4]
    )
    p_cam = (T_cam[0, 3], T_cam[1, 3], T_cam[2, 3])
    if (
        has_guard
        and plain
        and margin >= release
        and not (side != 0.0 and s != side)
        and not (fresh and dist3(p[0], p[1], p[2], p_cam[0], p_cam[1], p_cam[2]) > prm[_JUMP])
    ):
        # The step's plain path (no transfer under way or starting, no freeze): the view is
        # the command unless the guard turns it. ``ClearanceGuard.apply``'s check, then (if
        # clear) ``detour``'s trace from the camera; not clear: the cache is put back, the
        # interpreter asks again.
        cleared, found_via, via = cleared_move(zone, p, p_c, p_cam)
        out[_OUT_CLEARED] = 1.0 if cleared else 0.0
        out[_OUT_DETOUR] = 1.0 if found_via else 0.0
        for i in range(3):
            out[_OUT_VIA + i] = via[i]
    if not feedforward:
        return
    if given.shape[0] == 0:
        p2, n2 = _ring_predict(buf, count, spacing, horizon + dt)
    else:
        p2, n2 = (given[6], given[7], given[8]), (given[9], given[10], given[11])
    if keep_side:
        has_u2, u2, _, _ = _view_of(p2, n2, s, d, aim_floor, cone)
    else:
        k = 1.0 if dot(u, n) >= 0.0 else -1.0  # ``n2`` signed like ``u`` is relative to ``n``
        has_u2, u2 = True, (k * n2[0], k * n2[1], k * n2[2])
    if has_u2:  # the next goal, its roll from this one
        x2, y2, z2, p2_cam = _pose_of(p2, u2, d, True, z, x, half_b)
        v = _twist_of(view, _rows_of(x2, y2, z2, p2_cam), dt)
        for i in range(6):
            twist_out[i] = v[i]
        out[_OUT_TWIST] = 1.0


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _inside_kernel(T: FloatArray, params: FloatArray, floor: float) -> bool:  # pragma: no cover
    """Whether the pose ``T`` (4, 4), world, m, is inside the cone and at or above ``floor`` (m).

    ``ConeWorkspace.margin(p) >= 0`` (the cone stored in ``params``, :func:`_plan_kernel`'s)
    and ``p[2] >= floor`` for its position ``p`` (:func:`_inside_of`).
    """
    return _inside_of(T, params, floor)


@register_jitable  # also callable from compiled kernels (the same source)
def _inside_of(T: FloatArray, params: FloatArray, floor: float) -> bool:  # pragma: no cover
    """:func:`_inside_kernel`'s test; :func:`_plan_kernel` makes it on its view too."""
    a, axis, tan_half, cos_half, height = cone_at(params, _CONE)
    p = (T[0, 3], T[1, 3], T[2, 3])
    return cone_margin(p[0], p[1], p[2], a, axis, tan_half, cos_half, height) >= 0.0 and (
        p[2] >= floor
    )


class EndocamPolicy(_MovingPolicy):
    """The paper's orientation goal with side keeping, orbits, prediction and left-eye centring.

    See the module docstring; the switches live in ``config.tracker``.
    """

    name = "endocam"

    def __init__(self, config: ControllerConfig | None = None) -> None:
        super().__init__(config)
        self.tracker = self.config.tracker
        self._predictor = RingPredictor(1)
        self._ring = self._predictor  # passed (unused) when the predictor is not a RingPredictor
        self._params = np.zeros(_N_PARAMS)  # _plan_kernel's constants, set by reset()
        self._out = np.zeros(_N_OUT)  # _plan_kernel's scalar results
        self._side = 0.0  # ±1 once chosen
        self._transfer: Transfer | None = None
        self._u_orbit: Vec = (0.0, 0.0, 1.0)
        self._half_b = 0.0
        self._cleared_view: FloatArray | None = None  # this step's view, cleared by the kernel
        self._horizon = 0.0
        self._plan_consts: tuple[object, ...] | None = None  # _plan_kernel's, per episode
        self._given = False  # the predictor is the oracle's (its predictions are given)
        self.transfers = 0  # transfers started this episode (side changes and approaches)

    def reset(self, context: PolicyContext) -> None:
        """Cone, windows, predictor and side memory for a new episode."""
        super().reset(context)
        tc = self.tracker
        self._predictor = RingPredictor(max(1, round(tc.velocity_window / context.dt)))
        self._side = 0.0
        self._transfer = None
        self._half_b = 0.5 * context.camera.baseline if self.config.centre_left_eye else 0.0
        self._aim_floor = self.config.min_camera_height + tc.floor_clearance  # m, goals aim here
        self._cmd_floor = self.config.min_camera_height - FLOOR_TOL_M  # m, commands stay above
        g_lin, g_ang = tc.feedforward_gain
        self._gains = np.array([g_lin, g_lin, g_lin, g_ang, g_ang, g_ang])  # the twist's gains
        self._horizon = context.sensing_latency + tc.carrier_lead if tc.predict else 0.0
        self.transfers = 0
        self._plan_consts = None  # rebuilt at the first step (after a subclass's reset)
        cfg, geometry = self.config, self._window_geometry
        assert geometry is not None  # set by super().reset()
        params = [0.0] * _N_PARAMS
        params[_AIM_FLOOR], params[_HALF_B] = self._aim_floor, self._half_b
        params[_D_MIN], params[_D_MAX], params[_D_STEP] = cfg.d_min, cfg.d_max, cfg.d_f_step
        params[_SIDE_ANGLE] = tc.side_change_angle
        params[_MIN_HEIGHT], params[_HYSTERESIS] = cfg.min_camera_height, cfg.side_hysteresis
        params[_KEEP_SIDE] = 1.0 if tc.keep_side else 0.0
        params[_SHORTEN] = 1.0 if tc.shorten_when_low else 0.0
        params[_PORT_RULE] = 1.0 if cfg.side_rule is SideRule.PORT else 0.0
        params[_WINDOW : _WINDOW + 9] = geometry.constants
        params[_CONE : _CONE + 9] = self.cone.constants
        params[_RCM : _RCM + 3] = np.asarray(context.p_world_rcm, dtype=float).tolist()
        params[_JUMP] = cfg.jump_threshold
        params[_CMD_FLOOR] = self._cmd_floor
        self._params = np.array(params)

    # -- the goal (the maths: the compiled functions above) ---------------------------------

    def _cone_constants(self) -> Cone:
        return cone_at(self.cone.constants, 0)

    def _view(self, p_c: Vec, n: Vec, s: float, d: float) -> tuple[Vec, float, float] | None:
        """Feasible viewing direction on side ``s``: (unit ``u``, angle to ``s n`` rad, margin m).

        ``u`` points from the ring centre to the camera; ``None`` if no direction keeps the
        camera ``min_camera_height`` above the board. The margin is the camera's to the cone.
        (:func:`_view_of`.)
        """
        ok, u, err, margin = _view_of(p_c, n, s, d, self._aim_floor, self._cone_constants())
        return (u, err, margin) if ok else None

    def _pose(self, p_c: Vec, u: Vec, r: float, previous: FloatArray | None) -> FloatArray:
        """Look at ``p_c`` from ``p_c + r u`` with a level horizon; left eye on the axis if set.

        (:func:`_pose_of`; ``previous`` (4, 4) or ``None``: its roll is kept near the vertical.)
        """
        z_prev = x_prev = (0.0, 0.0, 1.0)  # unread without a previous pose
        if previous is not None:
            R = previous[:3, :3].tolist()
            z_prev, x_prev = (R[0][2], R[1][2], R[2][2]), (R[0][0], R[1][0], R[2][0])
        x, y, z, p = _pose_of(p_c, u, r, previous is not None, z_prev, x_prev, self._half_b)
        return pose_from_columns(x, y, z, p)

    @staticmethod
    def _twist(T1: FloatArray, T2: FloatArray, delta: float) -> FloatArray:
        """(6,) velocity from pose ``T1`` to ``T2`` over ``delta`` s: linear, angular in world."""
        return np.array(_twist_of(T1.tolist(), T2.tolist(), delta))

    def _preferred_side(self) -> float:
        """A side (±1) to take first while its view is feasible; 0.0: none (the oracle's plan)."""
        return 0.0

    def _feedforward_twist(self, goal: FloatArray, twist: FloatArray) -> FloatArray:
        """The twist (6,) to command with ``goal`` (4, 4): ``twist``, the goal's one-step one."""
        return twist

    def _plan_view(
        self, obs: Observation, T_cam: FloatArray, T_ring: FloatArray, previous: FloatArray
    ) -> tuple[list[float], FloatArray, FloatArray]:
        """:func:`_plan_kernel` for ``obs``, its camera and ring poses ``T_cam``, ``T_ring`` (4, 4).

        Returns its scalar results (``_OUT_*``; ``_OUT_CHECK``: the checks' answer, the rest
        unset unless ``OBS_OK``), the view's pose (4, 4) and its twist (6,): new arrays each
        step (the goal and the command keep them).
        """
        consts = self._plan_consts
        if consts is None:
            consts = self._plan_consts = self._plan_constants()
        given = _NO_PREDICTIONS
        t_ring, t = obs.t_ring, float(obs.t)
        has_t_ring = t_ring is not None
        t_ring = 0.0 if t_ring is None else float(t_ring)
        check = True
        if self._given:  # the oracle's predictor: the true future
            answer = _observed_kernel(
                T_cam, T_ring, t, has_t_ring, t_ring, self.config.ring_max_age, self._gate.state,
                self._gate.bounds, self._params, _CONE, True,
            )  # fmt: skip
            if answer != OBS_OK:
                self._out[_OUT_CHECK] = answer
                return self._out.tolist(), T_cam, np.zeros(6)
            check = False  # made
            pred = self._predictor
            p_obs = (T_ring[0, 3], T_ring[1, 3], T_ring[2, 3])
            n_obs = unit_or_none((T_ring[0, 2], T_ring[1, 2], T_ring[2, 2]))
            pred.push(obs.t, p_obs, n_obs)  # type: ignore[arg-type]  # the oracle's: unread
            p1, n1 = pred.predict(self._horizon)
            p2, n2 = pred.predict(self._horizon + self._ctx_dt)
            given = np.array([*p1, *n1, *p2, *n2])
        tips = obs.p_world_tips
        if not (isinstance(tips, np.ndarray) and tips.ndim == 2):
            tips = np.asarray(tips, dtype=float).reshape(-1, 3)
        view, twist = np.empty((4, 4)), np.empty(6)
        _plan_kernel(
            T_cam,
            T_ring,
            tips,
            previous,
            t,
            check,
            has_t_ring,
            t_ring,
            given,
            self.d_f,
            self._last_goal is None,
            self._side,
            self._preferred_side(),
            self._transfer is None,
            FREEZE_RELEASE_MARGIN if self._frozen_T is not None else 0.0,
            view,
            twist,
            *consts,  # type: ignore[arg-type]
        )
        return self._out.tolist(), view, twist

    def _plan_constants(self) -> tuple[object, ...]:
        """:func:`_plan_kernel`'s arguments fixed for the episode, from ``buf`` on (a tuple).

        Built at the first step after ``reset`` (a subclass's ``reset`` may replace the
        predictor and the horizon after this class's); every array in it is updated in place
        during the episode (the predictor's, the gate's, ``_params``, ``_out``, the guard's).
        """
        ctx = self._ctx
        assert ctx is not None  # set by reset()
        pred = self._predictor
        self._given = not isinstance(pred, RingPredictor)
        if self._given:
            pred = self._ring  # unused: the oracle's predictions are given
        feedforward = self.tracker.feedforward and self._horizon > 0.0 and ctx.follows_twist
        gate = self._gate
        return (
            pred.buf,
            pred.count,
            pred.spacing,
            self.config.ring_max_age,
            gate.state,
            gate.bounds,
            self._horizon,
            ctx.dt,
            feedforward,
            self._params,
            self._out,
            self.guard is not None,
            NO_KEEP_OUT if self.guard is None else self.guard.kernel_state,
        )

    # -- the step --------------------------------------------------------------------------

    def _freeze(self, d_before: float, why: str) -> CameraCommand:
        """Hold the last safe command; the distance, goal and transfer are planned afresh."""
        self.d_f = d_before
        self._path = None
        self._transfer = None
        self._last_goal = None
        return self._hold(TrackingState.FROZEN_OUTSIDE_CONE, f"{why}; holding")

    def _lose(self, reason: str) -> CameraCommand:
        self._last_goal = None
        self._path = None
        self._transfer = None
        self._predictor.reset()
        return self._hold(TrackingState.LOST_TRACKING, reason)

    def step(self, obs: Observation) -> CameraCommand:
        """Checks, working distance, prediction, side, cone freeze, transfers — in that order."""
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

        previous = self._last_goal if self._last_goal is not None else self._last_cmd
        assert previous is not None  # set by reset()
        d_before = self.d_f
        # the checks (finite poses, a fresh ring pose, the gate), the working distance,
        # prediction, side, view and its twist: one compiled call
        out, view, view_twist = self._plan_view(obs, T_cam, T_ring, previous)
        check = out[_OUT_CHECK]
        if check != OBS_OK:
            if check == OBS_CAMERA:
                return self._hold(TrackingState.LOST_TRACKING, CAMERA_REASON)
            return self._lose(CHECK_REASONS[int(check)])
        p_cam = (out[_OUT_CAM], out[_OUT_CAM + 1], out[_OUT_CAM + 2])
        self.d_f = d = out[_OUT_D]
        p_c = (out[_OUT_P], out[_OUT_P + 1], out[_OUT_P + 2])
        margin = -math.inf
        goal = None
        adjusted = False  # the goal was turned off the view for the wire clearance
        if out[_OUT_FOUND]:
            s = out[_OUT_SIDE]
            u = (out[_OUT_U], out[_OUT_U + 1], out[_OUT_U + 2])
            if out[_OUT_CLEARED]:  # the kernel made the guard's check: the view is clear
                assert self.guard is not None
                goal = self.guard.passed(view)
                self._cleared_view = goal  # the pose the kernel's check and trace are for
            else:
                goal = self._clear(view, p_c, p_cam)
            if goal is None:
                self._path = None
                self._transfer = None
                self._last_goal = None
                self.d_f = d_before
                return self._hold(TrackingState.FROZEN_OUTSIDE_CONE, WIRE_REASON)
            adjusted = goal is not view
            margin = self.cone.margin(goal[:3, 3]) if adjusted else out[_OUT_MARGIN]
        release = FREEZE_RELEASE_MARGIN if self._frozen_T is not None else 0.0
        if goal is None or not margin >= release:
            if self._frozen_T is None:
                self._frozen_T = T_cam
            self._last_cmd = self._frozen_T
            return self._freeze(d_before, "no view of the ring inside the cone workspace")
        self._frozen_T = None

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
        if state is TrackingState.TRACKING and out[_OUT_TWIST]:
            # the view's twist (the kernel's); unused below when the goal is not the view
            twist = self._feedforward_twist(goal, view_twist)
        near_edge = goal[2, 3] <= self._aim_floor + FLOOR_TOL_M or margin < tc.floor_clearance
        if twist is not None and not near_edge and not adjusted:
            twist *= self._gains  # linear × g_lin, angular × g_ang (element by element)
        else:
            twist = None  # a goal at the floor or the cone arrives at rest: nothing carries it out
        if cmd is not goal:  # an orbit or way-point pose keeps the clearance too
            cleared = self._clear(cmd, p_c, p_cam)
            if cleared is None:
                self._side = side_before
                self._path = None
                self._transfer = None
                self._last_goal = None
                self.d_f = d_before
                return self._hold(TrackingState.FROZEN_OUTSIDE_CONE, WIRE_REASON)
            cmd = cleared
        if out[_OUT_CLEARED] and cmd is goal and goal is self._cleared_view:
            # the plain path (no transfer, no freeze): the kernel traced the move to this pose
            if out[_OUT_DETOUR]:
                p_via = (out[_OUT_VIA], out[_OUT_VIA + 1], out[_OUT_VIA + 2])
                via = self._detoured(cmd, p_c, p_cam, (True, p_via))
            else:  # a straight move: what ``_detoured`` does with no way-point
                self._p_detour, self._stalled = None, 0
                via = None
        else:
            via = self._detoured(cmd, p_c, p_cam)
        if via is not None:
            cmd, twist = via, None
            state, reason = TrackingState.PLANNING, DETOUR_REASON
        # last gate: never command outside the workspace (the kernel's test of its own view)
        if not (out[_OUT_INSIDE] if cmd is view else self._in_workspace(cmd)):
            self._side = side_before
            return self._freeze(
                d_before, "command would leave the cone workspace or go below the floor"
            )
        self._last_cmd = cmd
        return CameraCommand(cmd, state, d, reason, twist)

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
        ang = _angle(u, u_goal)
        if ang < ORBIT_DONE_ANGLE:
            self._transfer = None
            return None
        k = unit_or_none(cross(u, u_goal))
        if k is None or ang > math.pi - 1e-3:  # opposite ends: go over the top
            k = unit_or_none(cross(u, (0.0, 0.0, 1.0))) or unit_or_none(cross(u, (1.0, 0.0, 0.0)))
            assert k is not None
        tangent = cross(k, u)  # unit: k ⟂ u
        rate = tc.orbit_max_speed / (r * max(map(abs, tangent)) + _EPS)
        # The camera turns about k; its per-axis share is largest when k is along one axis.
        rate = min(rate, tc.orbit_max_rate)
        to_cam = unit_or_none((p_cam[0] - p_c[0], p_cam[1] - p_c[1], p_cam[2] - p_c[2]))
        keeping_up = (
            to_cam is not None
            and _angle(to_cam, u) <= tc.orbit_lookahead
            and _angle(z_cam, (-u[0], -u[1], -u[2])) <= tc.orbit_lookahead
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

        The last gate: computed here (:func:`_inside_kernel`), independently of the compiled
        step's own margin.
        """
        return bool(_inside_kernel(T_world_cmd, self._params, self._cmd_floor))

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


__all__ = ["EndocamPolicy", "RingPredictor"]
