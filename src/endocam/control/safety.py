"""Safety rules of the autonomous camera (paper Sec. III-C).

* :class:`ConeWorkspace`: the camera may only be driven autonomously inside a cone whose tip is the
  remote centre of motion (RCM) and whose axis points at the feature's initial position.
* :func:`window_status` and :func:`adjust_working_distance`: the tool-in-view windows. Instrument
  tips outside the outer image window make the working distance grow by a fixed step per control
  step; all tips inside the inner window make it shrink; in between it holds.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numba import njit
from numba.extending import register_jitable
from numpy.typing import NDArray

from endocam.camera import MIN_DEPTH, StereoCamera
from endocam.geometry import FloatArray
from endocam.kernels import dist3
from endocam.workspace.cone import ConeWorkspace

D_F_STEP = 1.0e-3  # m, working-distance change per control step (paper: ±1 mm)
IntArray = NDArray[np.integer]


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


class WindowStatus(enum.Enum):
    """Where the instrument tips project relative to the inner and outer image windows."""

    OUTSIDE_OUTER = "outside_outer"  # at least one tip is outside the outer window (or unseen)
    BETWEEN = "between"  # every tip inside the outer window, not all inside the inner one
    INSIDE_INNER = "inside_inner"  # every tip inside the inner window


@dataclass(frozen=True)
class ImageWindows:
    """Centred inner and outer windows as fractions of the image width and height.

    Attributes
    ----------
    inner_frac : float
        Inner window size as a fraction of the image (0 < inner < outer).
    outer_frac : float
        Outer window size as a fraction of the image (≤ 1).
    """

    inner_frac: float = 0.5
    outer_frac: float = 0.9

    def __post_init__(self) -> None:
        if not (0.0 < self.inner_frac < self.outer_frac <= 1.0):
            raise ValueError(
                f"need 0 < inner_frac < outer_frac ≤ 1, got {self.inner_frac}, {self.outer_frac}"
            )


@dataclass(frozen=True)
class WindowGeometry:
    """Plain-float constants of the window test for one camera (computed once per episode).

    Attributes
    ----------
    fx, fy, cx, cy : float
        Intrinsics, px.
    u0, v0 : float
        Image centre, px.
    half_baseline : float
        Half the stereo baseline, m.
    outer, inner : tuple of float
        Half width and half height of the outer and inner windows, px.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    u0: float
    v0: float
    half_baseline: float
    outer: tuple[float, float]
    inner: tuple[float, float]

    @classmethod
    def of(cls, camera: StereoCamera, windows: ImageWindows) -> WindowGeometry:
        """Constants for ``camera`` and ``windows``."""
        k = camera.intrinsics
        w, h = 0.5 * k.width, 0.5 * k.height
        return cls(
            k.fx,
            k.fy,
            k.cx,
            k.cy,
            w,
            h,
            0.5 * camera.baseline,
            (windows.outer_frac * w, windows.outer_frac * h),
            (windows.inner_frac * w, windows.inner_frac * h),
        )

    @cached_property
    def constants(self) -> tuple[float, ...]:
        """:func:`window_code`'s constants: ``fx, fy, cx − u0, cy − v0, b/2`` and the windows'.

        px, px, px, px, m, then the outer and inner half widths and heights, px.
        """
        return (
            self.fx,
            self.fy,
            self.cx - self.u0,
            self.cy - self.v0,
            self.half_baseline,
            *self.outer,
            *self.inner,
        )


def window_status(
    camera: StereoCamera,
    T_world_cam: FloatArray,
    p_world_tips: FloatArray,
    windows: ImageWindows,
) -> WindowStatus:
    """Classify the instrument tips against the windows in both eyes (paper Sec. III-C).

    A tip counts as inside a window only if it projects inside it in both eyes; a tip at or
    behind an eye's image plane is outside every window.

    Parameters
    ----------
    camera : StereoCamera
    T_world_cam : (4, 4)
        Current camera pose, optical frame, m.
    p_world_tips : (K, 3)
        Instrument tip positions in world, m. Tips with non-finite coordinates (tool tracking
        lost) are ignored; with no usable tip the status is ``BETWEEN``, so ``d_f`` holds
        rather than moving the camera closer without knowing where the tools are.
    windows : ImageWindows
    """
    tips = np.asarray(p_world_tips, dtype=float).reshape(-1, 3).tolist()
    return window_status_rows(
        WindowGeometry.of(camera, windows), np.asarray(T_world_cam).tolist(), tips
    )


_STATUSES = (WindowStatus.OUTSIDE_OUTER, WindowStatus.BETWEEN, WindowStatus.INSIDE_INNER)
_STATUS_CODES = {status: code for code, status in enumerate(_STATUSES)}


@register_jitable  # also callable from compiled kernels (the same source)
def window_code(
    T: Sequence[Sequence[float]] | FloatArray,
    tips: Sequence[Sequence[float]] | FloatArray,
    fx: float,
    fy: float,
    du0: float,
    dv0: float,
    half_b: float,
    hw_out: float,
    hh_out: float,
    hw_in: float,
    hh_in: float,
) -> int:
    """:func:`window_status_rows` as a code: 0 ``OUTSIDE_OUTER``, 1 ``BETWEEN``, 2 ``INSIDE_INNER``.

    ``T`` (4, 4) rows of ``T_world_cam`` (m), ``tips`` (K, 3) world, m, rows; ``fx``, ``fy``
    px; ``du0``, ``dv0``: principal point less the image centre, px; ``half_b`` m; the
    windows' half widths and heights, px.
    """
    R0, R1, R2 = T[0], T[1], T[2]
    t0, t1, t2 = R0[3], R1[3], R2[3]
    all_inner = True
    usable = False
    for i in range(len(tips)):
        p = tips[i]
        if not math.isfinite(p[0] + p[1] + p[2]):
            continue
        usable = True
        d0, d1, d2 = p[0] - t0, p[1] - t1, p[2] - t2
        # R^T d: the tip in the camera (centre) frame.
        x = R0[0] * d0 + R1[0] * d1 + R2[0] * d2
        y = R0[1] * d0 + R1[1] * d1 + R2[1] * d2
        z = R0[2] * d0 + R1[2] * d1 + R2[2] * d2
        if not z > MIN_DEPTH:  # also catches NaN
            return 0
        dv = abs(fy * y / z + dv0)
        for x_eye in (x + half_b, x - half_b):  # left eye at −b/2, right eye at +b/2
            du = abs(fx * x_eye / z + du0)
            if not (du <= hw_out and dv <= hh_out):
                return 0
            if not (du <= hw_in and dv <= hh_in):
                all_inner = False
    if not usable:
        return 1  # no tool position known: hold d_f, never zoom in blind
    return 2 if all_inner else 1


@register_jitable  # also callable from compiled kernels (the same source)
def window_code_of(
    T: Sequence[Sequence[float]] | FloatArray,
    tips: Sequence[Sequence[float]] | FloatArray,
    constants: Sequence[float] | FloatArray,
) -> int:
    """:func:`window_code` with its nine constants in a sequence (``WindowGeometry.constants``)."""
    c = constants
    return window_code(T, tips, c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8])


def window_status_rows(
    g: WindowGeometry, T_world_cam: list[list[float]], p_world_tips: list[list[float]]
) -> WindowStatus:
    """:func:`window_status` on plain lists (rows of ``T_world_cam``, tip rows), for the loop."""
    return _STATUSES[window_code_of(T_world_cam, p_world_tips, g.constants)]


@register_jitable  # also callable from compiled kernels (the same source)
def adjusted_distance(d_f: float, code: int, d_min: float, d_max: float, step: float) -> float:
    """:func:`adjust_working_distance` for a :func:`window_code` ``code``, m."""
    if code == 0:
        d_f += step
    elif code == 2:
        d_f -= step
    return min(max(d_f, d_min), d_max)


def adjust_working_distance(
    d_f: float, status: WindowStatus, d_min: float, d_max: float, step: float = D_F_STEP
) -> float:
    """One control step of the working-distance rule, clamped to ``[d_min, d_max]`` (m).

    Parameters
    ----------
    d_f : float
        Current working distance, m.
    status : WindowStatus
        Result of :func:`window_status` for the current image.
    d_min, d_max : float
        Allowed range, m.
    step : float
        Change per control step, m (paper: 1 mm).
    """
    return adjusted_distance(d_f, _STATUS_CODES[status], d_min, d_max, step)
