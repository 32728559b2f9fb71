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
from dataclasses import dataclass, field
from functools import cached_property
from typing import Protocol, cast

import numpy as np
from numba import njit
from numba.extending import register_jitable
from numpy.typing import ArrayLike, NDArray

from endocam.camera import MIN_DEPTH, StereoCamera
from endocam.control.clearance import NO_GUARD, _distance, _first_outside
from endocam.control.cone import cone_floor_margin, cone_margin
from endocam.geometry import FloatArray, as_vector3, unit_vector
from endocam.kernels import py_max, py_min
from endocam.pyfloat import dist3

CONE_HEIGHT = 0.30  # m, the PSM-held camera's reach, slightly under the instrument (paper III-C)
CONE_BASE_RADIUS = 0.25  # m; the paper chose 0.10 m for its farther port (docs/world.md)
D_F_STEP = 1.0e-3  # m, working-distance change per control step (paper: ±1 mm)
IntArray = NDArray[np.integer]


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _first_outside_kernel(
    p: FloatArray,
    apex: tuple[float, ...],
    axis: tuple[float, ...],
    tan_half: float,
    cos_half: float,
    height: float,
    floor: float,
) -> int:
    """The first row of ``p`` (N, 3), world, m, outside the cone or below ``floor`` (m); N if none.

    A row is outside when ``min(ConeWorkspace.margin(row), row[2] − floor) >= 0`` fails (a
    non-finite row: the cone's margin is NaN), the margin by :func:`cone_margin`.
    """
    for i in range(p.shape[0]):
        x, y, z = p[i, 0], p[i, 1], p[i, 2]
        margin = cone_margin(x, y, z, apex, axis, tan_half, cos_half, height)
        if not py_min(margin, z - floor) >= 0.0:
            return i
    return p.shape[0]


Cone = tuple[tuple[float, float, float], tuple[float, float, float], float, float, float]


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def _cone_margin_kernel(constants: FloatArray, x: float, y: float, z: float) -> float:
    """:func:`cone_margin` of ``(x, y, z)``, world, m, with the cone's ``constants`` (9,), m."""
    apex, axis, tan_half, cos_half, height = cone_at(constants, 0)
    return cone_margin(x, y, z, apex, axis, tan_half, cos_half, height)


@register_jitable  # also callable from compiled kernels (the same source)
def cone_at(values: Sequence[float] | FloatArray, i: int) -> Cone:
    """The cone's constants stored from ``values[i]`` (:attr:`ConeWorkspace.constants`).

    Apex (3,), world, m; unit axis (3,); tan and cos of the half-angle; height, m.
    """
    v = values
    return (v[i], v[i + 1], v[i + 2]), (v[i + 3], v[i + 4], v[i + 5]), v[i + 6], v[i + 7], v[i + 8]


@dataclass(frozen=True)
class ConeWorkspace:
    """A solid cone: tip at the RCM, fixed axis, height and base radius (paper Sec. III-C).

    Attributes
    ----------
    apex : (3,)
        Cone tip = RCM position in world, m.
    axis : (3,)
        Unit axis in world, from the tip towards the base.
    height : float
        Distance from the tip to the base along the axis, m (slightly less than the instrument
        length).
    base_radius : float
        Radius of the base disc, m.
    """

    apex: FloatArray
    axis: FloatArray
    height: float
    base_radius: float = CONE_BASE_RADIUS
    _apex: tuple[float, ...] = field(init=False, repr=False, compare=False)
    _axis: tuple[float, ...] = field(init=False, repr=False, compare=False)
    _tan_half: float = field(init=False, repr=False, compare=False)
    _cos_half: float = field(init=False, repr=False, compare=False)
    _constants: FloatArray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        # Plain-float copies for the control loop (endocam.kernels rule).
        tan_half = self.base_radius / self.height
        object.__setattr__(self, "_apex", tuple(np.asarray(self.apex, dtype=float).tolist()))
        object.__setattr__(self, "_axis", tuple(np.asarray(self.axis, dtype=float).tolist()))
        object.__setattr__(self, "_tan_half", tan_half)
        object.__setattr__(self, "_cos_half", 1.0 / math.sqrt(1.0 + tan_half * tan_half))
        object.__setattr__(self, "_constants", np.array(self.constants))

    @classmethod
    def from_rcm(
        cls,
        p_world_rcm: ArrayLike,
        p_world_feature: ArrayLike,
        height: float,
        base_radius: float = CONE_BASE_RADIUS,
    ) -> ConeWorkspace:
        """Cone from the RCM towards the feature's initial position; the axis is fixed after this.

        Parameters
        ----------
        p_world_rcm : (3,)
            RCM position in world, m.
        p_world_feature : (3,)
            The feature's position at initialisation, m.
        height, base_radius : float
            Cone height and base radius, m (both > 0).
        """
        apex = as_vector3(p_world_rcm, "p_world_rcm")
        axis = unit_vector(as_vector3(p_world_feature, "p_world_feature") - apex, "feature - rcm")
        if not (math.isfinite(height) and height > 0):
            raise ValueError(f"height must be > 0 m, got {height}")
        if not (math.isfinite(base_radius) and base_radius > 0):
            raise ValueError(f"base_radius must be > 0 m, got {base_radius}")
        return cls(apex, axis, float(height), float(base_radius))

    def margin(self, p_world: FloatArray | Sequence[float]) -> float:
        """Signed clearance of a point to the cone surface, m: > 0 inside, < 0 outside.

        The margin is the smaller of the distance to the lateral surface (measured perpendicular
        to the axis, scaled to the surface normal) and the distance to the base plane; points
        behind the tip are outside.

        Parameters
        ----------
        p_world : (3,)
            Point in world, m.

        Compiled (:func:`cone_margin`).
        """
        p = p_world.tolist() if isinstance(p_world, np.ndarray) else p_world
        return float(_cone_margin_kernel(self._constants, p[0], p[1], p[2]))

    @property
    def constants(self) -> list[float]:
        """Apex (3,), world, m; unit axis (3,); tan and cos of the half-angle; height, m.

        The order :func:`cone_at` reads (compiled kernels keep them in a parameter array).
        """
        return [*self._apex, *self._axis, self._tan_half, self._cos_half, self.height]

    def first_outside(self, p_world: FloatArray, floor: float = -math.inf) -> int:
        """The first point of ``p_world`` (N, 3), world, m, outside the cone or below ``floor``.

        As ``min(margin(p), p[2] − floor) >= 0`` decides it for each point in turn (compiled:
        :func:`_first_outside_kernel`); N if none.
        """
        p = np.ascontiguousarray(p_world, dtype=float).reshape(-1, 3)
        return int(
            _first_outside_kernel(
                p, self._apex, self._axis, self._tan_half, self._cos_half, self.height, floor
            )
        )

    def contains(self, p_world: FloatArray | Sequence[float]) -> bool:
        """Whether a point (3,) in world, m, is inside the cone or on its surface."""
        margin = self.margin(p_world)
        return math.isfinite(margin) and margin >= 0.0


class KeepOut(Protocol):
    """A region the camera must stay out of (``control.clearance.ClearanceGuard``: the wire)."""

    @property
    def kernel_state(self) -> tuple[object, ...]:
        """Its compiled queries' arguments (``ClearanceGuard.kernel_state``: ``_distance``'s).

        The wire's search arrays, the tube radius (m), the Lipschitz cache (``ref``, ``nref``)
        and the clearance (m): the compiled workspace queries (:func:`workspace_margin`) ask
        the zone through them, the cache shared with :meth:`margin`.
        """
        ...

    def margin(self, p_world: Sequence[float]) -> float:
        """Signed clearance of a camera position (3,), world, m: ≥ 0 outside the region."""
        ...

    def first_outside(self, p_world: FloatArray, count: int) -> int:
        """The first of ``p_world[:count]`` whose :meth:`margin` is not ≥ 0, else ``count``.

        ``p_world`` (N, 3): camera positions, world, m. As :meth:`margin` called on each in
        turn would find it, any cache it keeps left as those calls leave it.
        """
        ...


# A workspace's compiled queries take its constants as ``state`` (:attr:`Workspace.kernel_state`):
# the cone's constants (9,) (:attr:`ConeWorkspace.constants`), the floor (m), whether there is a
# keep-out zone, then the zone's ``ClearanceGuard.kernel_state`` (the wire's search arrays, the
# tube radius (m), the Lipschitz cache, the clearance (m); placeholders of the same types
# without a zone, never read).
WorkspaceState = tuple[
    FloatArray,
    float,
    bool,
    FloatArray,
    IntArray,
    IntArray,
    IntArray,
    float,
    FloatArray,
    IntArray,
    float,
]


NO_WORKSPACE = cast(WorkspaceState, (np.zeros(9), 0.0, False, *NO_GUARD))
"""A compiled caller's placeholder for no workspace (never read: it asks no query then)."""


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def workspace_margin(
    cone: FloatArray,
    floor: float,
    keep: bool,
    pts: FloatArray,
    table: np.ndarray,
    pool: np.ndarray,
    meta: np.ndarray,
    radius: float,
    ref: FloatArray,
    nref: np.ndarray,
    clearance: float,
    x: float,
    y: float,
    z: float,
) -> float:
    """:meth:`Workspace.margin` of the point ``(x, y, z)``, world, m (``state`` above), m.

    ``min(cone margin, z − floor)``, then with the keep-out zone's margin (its surface distance
    less the clearance: one query at most, the cache updated as ``ClearanceGuard.margin``
    does), Python's ``min`` order; NaN for a non-finite point.
    """
    m = cone_floor_margin(x, y, z, cone, floor)
    if keep:
        zone = workspace_keep_out_margin(
            cone, floor, keep, pts, table, pool, meta, radius, ref, nref, clearance, x, y, z
        )
        return py_min(m, zone)
    return m


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def workspace_keep_out_margin(
    cone: FloatArray,
    floor: float,
    keep: bool,
    pts: FloatArray,
    table: np.ndarray,
    pool: np.ndarray,
    meta: np.ndarray,
    radius: float,
    ref: FloatArray,
    nref: np.ndarray,
    clearance: float,
    x: float,
    y: float,
    z: float,
) -> float:
    """:meth:`Workspace.keep_out_margin` of ``(x, y, z)``, world, m (``state`` above), m.

    The zone's surface distance less the clearance (``ClearanceGuard.margin``: a lower bound
    when positive, one query at most); inf without a zone.
    """
    if not keep:
        return math.inf
    d = _distance(pts, table, pool, meta, radius, ref, nref, clearance, x, y, z, 0.0)
    return d - clearance


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def workspace_all_inside(
    cone: FloatArray,
    floor: float,
    keep: bool,
    pts: FloatArray,
    table: np.ndarray,
    pool: np.ndarray,
    meta: np.ndarray,
    radius: float,
    ref: FloatArray,
    nref: np.ndarray,
    clearance: float,
    p: FloatArray,
) -> bool:
    """:meth:`Workspace.all_inside` of the points ``p`` (N, 3), world, m (``state`` above).

    The cone and the floor for every point (:func:`_first_outside_kernel`), the keep-out zone
    up to the first point they reject, that one included (``ClearanceGuard.first_outside``):
    the zone's cache ends as ``margin`` called on each point in turn would leave it.
    """
    apex, axis, tan_half, cos_half, height = cone_at(cone, 0)
    n = p.shape[0]
    first = _first_outside_kernel(p, apex, axis, tan_half, cos_half, height, floor)
    if not keep:
        return first == n
    count = first + 1 if first + 1 < n else n  # Python's min(first + 1, n)
    inside = _first_outside(pts, table, pool, meta, radius, ref, nref, clearance, p, count)
    return inside == count and first == n


@dataclass(frozen=True)
class Workspace:
    """Where the camera may be: inside the cone workspace, at or above the floor, off the wire.

    The carriers keep the camera here (``robot.actuator.WorkspaceBound``), whatever they are
    commanded; the controllers' goals stay inside it too.

    Attributes
    ----------
    cone : ConeWorkspace
    floor : float
        Lowest camera height (world z), m: the tissue plane plus the minimum height
        (``ControllerConfig.min_camera_height``).
    keep_out : KeepOut or None
        The wire's clearance zone (``ControllerConfig.wire_clearance`` around the wire's
        surface); ``None``: no structure model.
    """

    cone: ConeWorkspace
    floor: float
    keep_out: KeepOut | None = None
    _state: WorkspaceState = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        keep = self.keep_out is not None
        zone = self.keep_out.kernel_state if self.keep_out is not None else NO_GUARD
        cone = self.cone._constants
        state = cast(WorkspaceState, (cone, float(self.floor), keep, *zone))
        object.__setattr__(self, "_state", state)

    @property
    def kernel_state(self) -> WorkspaceState:
        """The arguments compiled queries take first (:func:`workspace_margin`, ``_all_inside``).

        The cone's constants (9,) (:attr:`ConeWorkspace.constants`), the floor (m), whether
        there is a keep-out zone, and the zone's ``kernel_state`` (placeholders without one);
        the zone's cache is shared with :meth:`margin`.
        """
        return self._state

    @property
    def convex(self) -> bool:
        """Whether the region is convex: the cone and the floor are, a keep-out zone is not."""
        return self.keep_out is None

    def keep_out_margin(self, p_world: Sequence[float]) -> float:
        """Signed clearance of a point (3,) in world, m, to the keep-out zone alone (inf: none).

        A lower bound when positive (``ClearanceGuard.margin``), compiled
        (:func:`workspace_keep_out_margin`).
        """
        p = p_world.tolist() if isinstance(p_world, np.ndarray) else p_world
        return float(workspace_keep_out_margin(*self._state, p[0], p[1], p[2]))

    def margin(self, p_world: FloatArray | Sequence[float]) -> float:
        """Signed clearance of a point (3,) in world, m: > 0 inside, < 0 outside (NaN: unknown).

        ``min(cone margin, height above the floor, keep-out margin)``, compiled
        (:func:`workspace_margin`).
        """
        p = p_world.tolist() if isinstance(p_world, np.ndarray) else p_world
        return float(workspace_margin(*self._state, p[0], p[1], p[2]))

    def all_inside(self, p_world: FloatArray) -> bool:
        """Whether every point (N, 3), world, m, is inside: ``all(margin(p) >= 0 for p in …)``.

        The same answer, and the keep-out zone's cache left as those calls in turn (stopping
        at the first point outside) would leave it, for a whole path at once, compiled
        (:func:`workspace_all_inside`).
        """
        p = np.ascontiguousarray(p_world, dtype=float).reshape(-1, 3)
        return bool(workspace_all_inside(*self._state, p))


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
    dt = py_min(py_max(t - t0, 0.0), bounds[2])  # Python's min(max(t − t0, 0), horizon)
    dp = dist3(x[0], x[1], x[2], state[i + 2], state[i + 3], state[i + 4])
    cos = x[3] * state[i + 5] + x[4] * state[i + 6] + x[5] * state[i + 7]
    turn = math.acos(py_max(-1.0, py_min(1.0, cos)))  # Python's max(-1, min(1, cos))
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
    return py_min(py_max(d_f, d_min), d_max)


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
