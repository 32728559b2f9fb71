"""The control steps as the interpreter ran them before they were compiled (tests' reference).

Copies of main before r6-ctrl: ``endocam.control.tracker`` (``RingPredictor`` and
``EndocamPolicy``, renamed ``InterpretedRingPredictor`` and ``InterpretedEndocamPolicy``); the
oracle's overrides (``OraclePolicy`` as ``InterpretedOraclePolicy``); the moving policies' step
and goals (``_MovingPolicy.step``, ``CenteringPolicy``'s and ``OrientationPolicy``'s, as
``InterpretedCenteringPolicy`` and ``InterpretedOrientationPolicy``); and the plain-float maths
they called (``view.rotation_columns``, ``control.goal.choose_side`` and
``goal_pose_unchecked``, ``control.safety.window_status_rows``, ``adjust_working_distance`` and
``ConeWorkspace.margin``); the ring gate (``control.safety.RingGate``, as
``InterpretedRingGate``: r7-ctrl compiled it into the steps with the input checks).
``tests/test_tracker_kernel.py`` pins the compiled steps
(``endocam.control.tracker._plan_kernel``, ``control.policies._step_kernel`` and the functions
they compile) to it bit for bit.
"""

# mypy: ignore-errors

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Sequence

import numpy as np

from endocam.camera import MIN_DEPTH
from endocam.control.config import ControllerConfig, SideRule, Transfer
from endocam.control.gate import STALE_REASON, is_stale
from endocam.control.oracle import (
    INFEASIBLE_COST,
    TIE_BREAK,
    OracleConfig,
    RingFuture,
    _FuturePredictor,
    plan_sides,
)
from endocam.control.planner import WaypointPath, advance, intermediate_waypoints
from endocam.control.policies import (
    _MIN_NORMAL,
    _UP,
    DETOUR_REASON,
    FREEZE_RELEASE_MARGIN,
    GATE_REASON,
    WIRE_REASON,
    CenteringPolicy,
    OrientationPolicy,
    _MovingPolicy,
)
from endocam.control.types import CameraCommand, Observation, PolicyContext, TrackingState
from endocam.control.windows import D_F_STEP, WindowGeometry, WindowStatus
from endocam.geometry import UP, FloatArray
from endocam.kernels import Rows, Vec, cross, dot, finite_rows, norm, reject, scaled, unit_or_none
from endocam.view import look_at_unchecked, pose_from_columns

_SIN_HOLD = math.sin(math.radians(2.0))
_SIN_LEVEL = math.sin(math.radians(20.0))
SIDE_HYSTERESIS = math.radians(25.0)
_SIN_SIDE = math.sin(SIDE_HYSTERESIS)
_EPS = 1e-9
ORBIT_DONE_ANGLE = math.radians(1.0)
FLOOR_TOL_M = 1e-9


def cone_margin(cone, p_world) -> float:
    """``ConeWorkspace.margin`` as it was."""
    p = p_world.tolist() if isinstance(p_world, np.ndarray) else p_world
    a = cone._apex
    k = cone._axis
    d0, d1, d2 = p[0] - a[0], p[1] - a[1], p[2] - a[2]
    h = d0 * k[0] + d1 * k[1] + d2 * k[2]
    r0, r1, r2 = d0 - h * k[0], d1 - h * k[1], d2 - h * k[2]
    radial = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    lateral = (h * cone._tan_half - radial) * cone._cos_half
    if not math.isfinite(h + radial):
        return math.nan
    return min(lateral, cone.height - h, h)


def _smoothstep(x: float) -> float:
    """Cubic smoothstep on [0, 1]: 0 below 0, 1 above 1, C¹ in between."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    return x * x * (3.0 - 2.0 * x)


def _default_roll_reference(z: Vec) -> Vec:
    """Documented default roll when there is no ``previous``: world x projected, else world y."""
    for ref in ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)):
        x = reject(ref, z)
        length = norm(x)
        if length > 0.1:
            return scaled(x, 1.0 / length)
    raise AssertionError("unreachable: world x and y cannot both be parallel to z")


def rotation_columns(z: Vec, up: Vec, x_prev: Vec | None) -> tuple[Vec, Vec, Vec]:
    """Columns (x, y, z) of ``R_world_cam`` for the unit optical axis ``z``; see the module doc."""
    x_level = cross(z, up)
    c = norm(x_level)
    x_ref: Vec | None = None
    if x_prev is not None:
        x_ref = reject(x_prev, z)
        n_ref = norm(x_ref)
        x_ref = scaled(x_ref, 1.0 / n_ref) if n_ref > _EPS else None
    if x_ref is None:
        if c > _EPS:  # nothing to keep: the level, upright horizon
            return scaled(x_level, 1.0 / c), cross(z, scaled(x_level, 1.0 / c)), z
        x_ref = _default_roll_reference(z)

    if c >= _SIN_LEVEL:
        x = scaled(x_level, 1.0 / c)
    elif c <= _EPS:
        x = x_ref
    else:
        x_level = scaled(x_level, 1.0 / c)
        # Signed roll φ from the level horizon to the reference, about z.
        phi = math.atan2(dot(cross(x_level, x_ref), z), dot(x_level, x_ref))
        phi_max = math.pi * (1.0 - _smoothstep((c - _SIN_HOLD) / (_SIN_LEVEL - _SIN_HOLD)))
        phi = min(max(phi, -phi_max), phi_max)
        y_level = cross(z, x_level)
        cp, sp = math.cos(phi), math.sin(phi)
        x = (
            cp * x_level[0] + sp * y_level[0],
            cp * x_level[1] + sp * y_level[1],
            cp * x_level[2] + sp * y_level[2],
        )
    return x, cross(z, x), z


def choose_side(n: Vec, up: Vec, z_prev: Vec | None, sin_hysteresis: float = _SIN_SIDE) -> float:
    """Sign ``s`` (±1) so the camera at ``p_c + s d_f n`` faces the reference side, with hysteresis.

    Parameters
    ----------
    n : 3-tuple
        Unit feature normal in world.
    up : 3-tuple
        Unit reference direction in world: world up for the paper's "above the tissue" rule,
        or the direction from the feature to the camera arm's port (``SideRule.PORT``).
    z_prev : 3-tuple or None
        Optical axis of the previous ``T_world_cam`` in world; the side it looked from is kept
        while ``s n·up ≥ −sin_hysteresis``.
    sin_hysteresis : float
        Sine of how far past perpendicular to ``up`` the normal may tip before the side
        changes (≥ 0).
    """
    n_up = dot(n, up)
    default = 1.0 if n_up >= 0.0 else -1.0
    if z_prev is None:
        return default
    along = -dot(z_prev, n)  # > 0: the previous camera looked from the +n side
    if abs(along) < _EPS:
        return default
    s_prev = 1.0 if along > 0.0 else -1.0
    if s_prev * n_up >= -sin_hysteresis:
        return s_prev
    return default


def goal_pose_unchecked(
    p_c: Vec,
    n: Vec,
    d_f: float,
    up: Vec,
    previous: FloatArray | None,
    side_hysteresis: float = SIDE_HYSTERESIS,
    min_height: float = -math.inf,
    toward: Vec | None = None,
) -> FloatArray:
    """:func:`goal_pose` without validation, for the control loop; ``n``, ``up`` unit.

    ``toward`` is the unit direction from ``p_c`` to the port (``None``: the paper's side rule).
    """
    ref = up if toward is None else toward
    sin_h = math.sin(side_hysteresis)
    if min_height > -math.inf and toward is None:
        # Keeping the previous side may not take the camera below ``min_height``.
        sin_h = max(0.0, min(sin_h, (dot(p_c, up) - min_height) / d_f))
    if previous is None:
        s = choose_side(n, ref, None)
        x_prev = None
    else:
        R = previous[:3, :3].tolist()
        s = choose_side(n, ref, (R[0][2], R[1][2], R[2][2]), sin_h)
        x_prev = (R[0][0], R[1][0], R[2][0])
    if toward is not None and min_height > -math.inf:
        # the port side may never put the camera below ``min_height`` when the other side is higher
        h_c, n_up = dot(p_c, up), dot(n, up)
        if h_c + s * d_f * n_up < min_height and s * n_up < 0.0:
            s = -s
    z = scaled(n, -s)
    x, y, zz = rotation_columns(z, up, x_prev)
    p = (p_c[0] - d_f * z[0], p_c[1] - d_f * z[1], p_c[2] - d_f * z[2])
    return pose_from_columns(x, y, zz, p)


def window_status_rows(
    g: WindowGeometry, T_world_cam: list[list[float]], p_world_tips: list[list[float]]
) -> WindowStatus:
    """:func:`window_status` on plain lists (rows of ``T_world_cam``, tip rows), for the loop."""
    T = T_world_cam
    R0, R1, R2 = T[0], T[1], T[2]
    t0, t1, t2 = R0[3], R1[3], R2[3]
    hw_out, hh_out = g.outer
    hw_in, hh_in = g.inner
    fx, fy, du0, dv0, half_b = g.fx, g.fy, g.cx - g.u0, g.cy - g.v0, g.half_baseline
    all_inner = True
    usable = False
    for p in p_world_tips:
        if not math.isfinite(p[0] + p[1] + p[2]):
            continue
        usable = True
        d0, d1, d2 = p[0] - t0, p[1] - t1, p[2] - t2
        # R^T d: the tip in the camera (centre) frame.
        x = R0[0] * d0 + R1[0] * d1 + R2[0] * d2
        y = R0[1] * d0 + R1[1] * d1 + R2[1] * d2
        z = R0[2] * d0 + R1[2] * d1 + R2[2] * d2
        if not z > MIN_DEPTH:  # also catches NaN
            return WindowStatus.OUTSIDE_OUTER
        dv = abs(fy * y / z + dv0)
        for x_eye in (x + half_b, x - half_b):  # left eye at −b/2, right eye at +b/2
            du = abs(fx * x_eye / z + du0)
            if not (du <= hw_out and dv <= hh_out):
                return WindowStatus.OUTSIDE_OUTER
            if not (du <= hw_in and dv <= hh_in):
                all_inner = False
    if not usable:
        return WindowStatus.BETWEEN  # no tool position known: hold d_f, never zoom in blind
    return WindowStatus.INSIDE_INNER if all_inner else WindowStatus.BETWEEN


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
    if status is WindowStatus.OUTSIDE_OUTER:
        d_f += step
    elif status is WindowStatus.INSIDE_INNER:
        d_f -= step
    return min(max(d_f, d_min), d_max)


def _angle(a: Vec, b: Vec) -> float:
    """Angle between two unit vectors, rad (atan2 form: accurate near 0 and π)."""
    return math.atan2(norm(cross(a, b)), dot(a, b))


class InterpretedRingPredictor:
    r"""Extrapolates the ring centre and normal from delayed, evenly timed samples.

    Velocity and acceleration are finite differences over samples ``spacing`` steps apart:
    with the newest sample ``x_k`` at ``t_k``,

    .. math::

        v_b = \frac{x_k - x_{k-m}}{\tau}, \quad a = \frac{x_k - 2x_{k-m} + x_{k-2m}}{\tau^2},
        \quad x(t_k + h) \approx x_k + (v_b + a\tau/2)\,h + a h^2/2

    (``v_b`` is the velocity at ``t_k − τ/2``). The normal is extrapolated the same way and
    renormalised. With fewer samples it falls back to lower orders.

    Parameters
    ----------
    spacing : int
        ``m``, samples between the differenced ones (≥ 1).
    """

    def __init__(self, spacing: int) -> None:
        if spacing < 1:
            raise ValueError(f"spacing must be ≥ 1, got {spacing}")
        self.spacing = spacing
        self._buf: deque[tuple[float, list[float]]] = deque(maxlen=2 * spacing + 1)

    def reset(self) -> None:
        """Forget every sample (after lost tracking: no differencing across a gap)."""
        self._buf.clear()

    def push(self, t: float, p_world: Vec, n_world: Vec) -> None:
        """Add a sample: time ``t`` (s), ring centre (3,) in world (m), unit normal (3,)."""
        self._buf.append((t, [*p_world, *n_world]))

    def predict(self, h: float) -> tuple[Vec, Vec]:
        """Ring centre (m) and unit normal in world, ``h`` seconds after the newest sample."""
        buf, m = self._buf, self.spacing
        t_k, x_k = buf[-1]
        if len(buf) <= m or h == 0.0:
            x = x_k
        else:
            t_m, x_m = buf[-1 - m]
            tau = t_k - t_m
            if not tau > 0.0:
                x = x_k
            elif len(buf) > 2 * m:
                _, x_2m = buf[-1 - 2 * m]
                inv = 1.0 / tau
                x = []
                for a0, a1, a2 in zip(x_k, x_m, x_2m, strict=True):
                    v = (a0 - a1) * inv
                    acc = (a0 - 2.0 * a1 + a2) * inv * inv
                    x.append(a0 + (v + 0.5 * acc * tau) * h + 0.5 * acc * h * h)
            else:
                k = h / tau
                x = [a0 + (a0 - a1) * k for a0, a1 in zip(x_k, x_m, strict=True)]
        n = unit_or_none((x[3], x[4], x[5])) or (x_k[3], x_k[4], x_k[5])
        return (x[0], x[1], x[2]), n


class InterpretedRingGate:
    """``control.safety.RingGate`` as it was (before r7-ctrl compiled it)."""

    def __init__(self, max_speed: float, max_rate: float, horizon: float, reacquire: float) -> None:
        self.max_speed, self.max_rate = max_speed, max_rate
        self.horizon, self.reacquire = horizon, reacquire
        self._ref: tuple[float, list[float]] | None = None  # last accepted (t, [p, n])
        self._raw: tuple[float, list[float]] | None = None  # last finite observation
        self._inside: Callable[[Sequence[float]], bool] | None = None
        self.rejected = 0  # observations rejected this episode

    @classmethod
    def of(cls, cfg: ControllerConfig) -> InterpretedRingGate:
        return cls(cfg.ring_max_speed, cfg.ring_max_rate, cfg.ring_gate_horizon, cfg.ring_reacquire)

    def reset(self, inside: Callable[[Sequence[float]], bool] | None = None) -> None:
        self._ref = None
        self._raw = None
        self._inside = inside
        self.rejected = 0

    def _agrees(self, ref: tuple[float, list[float]], t: float, x: list[float]) -> bool:
        t0, x0 = ref
        dt = min(max(t - t0, 0.0), self.horizon)
        dp = math.dist(x[:3], x0[:3])
        cos = x[3] * x0[3] + x[4] * x0[4] + x[5] * x0[5]
        turn = math.acos(max(-1.0, min(1.0, cos)))
        return dp <= self.max_speed * dt and turn <= self.max_rate * dt

    def accept(self, t: float, p_world: Sequence[float], n_world: Sequence[float]) -> bool:
        x = [*p_world, *n_world]
        ref, raw = self._ref, self._raw
        self._raw = (t, x)
        ok = ref is None or self._agrees(ref, t, x)
        if not ok and ref is not None and t - ref[0] > self.reacquire and raw is not None:
            ok = 0.0 < t - raw[0] <= self.horizon and self._agrees(raw, t, x)
            ok = ok and (self._inside is None or self._inside(x[:3]))
        if ok:
            self._ref = (t, x)
        else:
            self.rejected += 1
        return ok


def _interpreted_gate(policy: _MovingPolicy) -> None:
    """Give a reference policy the interpreted gate (after ``_MovingPolicy.reset``)."""
    policy._gate = InterpretedRingGate.of(policy.config)
    policy._gate.reset(policy.cone.contains)


class InterpretedEndocamPolicy(_MovingPolicy):
    """The paper's orientation goal with side keeping, orbits, prediction and left-eye centring.

    See the module docstring; the switches live in ``config.tracker``.
    """

    name = "endocam"

    def __init__(self, config: ControllerConfig | None = None) -> None:
        super().__init__(config)
        self.tracker = self.config.tracker
        self._predictor = InterpretedRingPredictor(1)
        self._side = 0.0  # ±1 once chosen
        self._transfer: Transfer | None = None
        self._u_orbit: Vec = (0.0, 0.0, 1.0)
        self._half_b = 0.0
        self._horizon = 0.0
        self.transfers = 0  # transfers started this episode (side changes and approaches)

    def reset(self, context: PolicyContext) -> None:
        """Cone, windows, predictor and side memory for a new episode."""
        super().reset(context)
        _interpreted_gate(self)
        tc = self.tracker
        self._predictor = InterpretedRingPredictor(max(1, round(tc.velocity_window / context.dt)))
        self._side = 0.0
        self._transfer = None
        self._half_b = 0.5 * context.camera.baseline if self.config.centre_left_eye else 0.0
        self._aim_floor = self.config.min_camera_height + tc.floor_clearance  # m, goals aim here
        self._horizon = context.sensing_latency + tc.carrier_lead if tc.predict else 0.0
        self.transfers = 0

    # -- the goal -------------------------------------------------------------------------

    def _view(self, p_c: Vec, n: Vec, s: float, d: float) -> tuple[Vec, float, float] | None:
        """Feasible viewing direction on side ``s``: (unit ``u``, angle to ``s n`` rad, margin m).

        ``u`` points from the ring centre to the camera; ``None`` if no direction keeps the
        camera ``min_camera_height`` above the board. The margin is the camera's to the cone.
        """
        u: Vec = (s * n[0], s * n[1], s * n[2])
        c = (self._aim_floor - p_c[2]) / d
        err = 0.0
        if u[2] < c:
            if c > 1.0:
                return None
            horiz = math.hypot(u[0], u[1])
            if not horiz > _EPS:
                return None
            k = math.sqrt(1.0 - c * c) / horiz
            u_c = (u[0] * k, u[1] * k, c)
            err = _angle(u, u_c)
            u = u_c
        margin = cone_margin(self.cone, [p_c[0] + d * u[0], p_c[1] + d * u[1], p_c[2] + d * u[2]])
        return u, err, margin

    def _shortened(
        self, p_c: Vec, n: Vec, d: float, previous: FloatArray, tip_rows: list[list[float]]
    ) -> float:
        """Look distance one ``d_f_step`` shorter if the kept view is height-limited, else ``d``.

        Height-limited: the camera on side ``s`` at ``d`` would sit below ``min_camera_height``
        (``s n·up < (h_min − p_c·up) / d``), so it is turned off the normal. A shorter look
        distance lowers the camera's drop below ``p_c`` and lets it turn back. The step is
        taken only if every tip stays inside the outer window of the shortened goal (the
        window rule keeps priority: the caller shortens only while every tip is between the
        windows).
        """
        cfg = self.config
        s = self._side or (1.0 if n[2] >= 0.0 else -1.0)
        if not s * n[2] * d < self._aim_floor - p_c[2]:
            return d
        d_next = d - cfg.d_f_step
        if d_next < cfg.d_min:
            return d
        view = self._view(p_c, n, s, d_next)
        now = self._view(p_c, n, s, d)
        if view is None or (now is not None and not view[1] < now[1]):
            return d  # shorter only where it turns the view towards the normal
        goal = self._pose(p_c, view[0], d_next, previous).tolist()
        assert self._window_geometry is not None  # set by reset()
        status = window_status_rows(self._window_geometry, goal, tip_rows)
        return d if status is WindowStatus.OUTSIDE_OUTER else d_next

    def _choose(self, p_c: Vec, n: Vec, d: float) -> tuple[float, Vec] | None:
        """Side and viewing direction (keep the side while feasible); ``None``: no feasible view."""
        limit = self.tracker.side_change_angle
        s = self._side or (1.0 if n[2] >= 0.0 else -1.0)  # first side: above the feature
        view = self._view(p_c, n, s, d)
        if view is not None and view[2] >= 0.0 and (view[1] <= limit or not self._side):
            return s, view[0]
        other = self._view(p_c, n, -s, d)
        if other is not None and other[2] >= 0.0:
            if view is None or view[2] < 0.0 or other[1] < view[1]:
                return -s, other[0]
        if view is not None and view[2] >= 0.0:
            return s, view[0]  # over the angle, but the other side is no better
        return None

    def _paper_view(self, p_c: Vec, n: Vec, d: float, previous: FloatArray) -> tuple[float, Vec]:
        """Side and direction by the orientation policy's rule (``keep_side`` off)."""
        cfg = self.config
        toward = None
        if cfg.side_rule is SideRule.PORT:
            assert self._ctx is not None
            r = self._ctx.p_world_rcm.tolist()
            toward = unit_or_none((r[0] - p_c[0], r[1] - p_c[1], r[2] - p_c[2]))
        T = goal_pose_unchecked(
            p_c,
            n,
            d,
            _UP,
            previous,
            cfg.side_hysteresis,
            cfg.min_camera_height,
            toward,
        ).tolist()
        z = (T[0][2], T[1][2], T[2][2])
        s = -1.0 if dot(z, n) > 0.0 else 1.0
        return s, (s * n[0], s * n[1], s * n[2])

    def _pose(self, p_c: Vec, u: Vec, r: float, previous: FloatArray | None) -> FloatArray:
        """Look at ``p_c`` from ``p_c + r u`` with a level horizon; left eye on the axis if set."""
        # ``toward = u`` makes the kernel take the side of ``u`` itself: position p_c + r u,
        # optical axis −u, roll from ``previous`` near the vertical.
        T = goal_pose_unchecked(p_c, u, r, _UP, previous, 0.0, -math.inf, u)
        hb = self._half_b
        if hb:
            T[0, 3] += hb * T[0, 0]
            T[1, 3] += hb * T[1, 0]
            T[2, 3] += hb * T[2, 0]
        return T

    @staticmethod
    def _twist(T1: FloatArray, T2: FloatArray, delta: float) -> FloatArray:
        """(6,) velocity from pose ``T1`` to ``T2`` over ``delta`` s: linear, angular in world."""
        a, b = T1.tolist(), T2.tolist()
        inv = 1.0 / delta
        # R2 R1^T ≈ I + [ω δ]×: its skew part gives ω (small angle over one control period).
        # ``0.0 +`` first, as ``sum`` starts (an int 0, the same float result, signed zeros too)
        m = [[0.0 + bi[0] * aj[0] + bi[1] * aj[1] + bi[2] * aj[2] for aj in a[:3]] for bi in b[:3]]
        return np.array(
            [
                (b[0][3] - a[0][3]) * inv,
                (b[1][3] - a[1][3]) * inv,
                (b[2][3] - a[2][3]) * inv,
                0.5 * (m[2][1] - m[1][2]) * inv,
                0.5 * (m[0][2] - m[2][0]) * inv,
                0.5 * (m[1][0] - m[0][1]) * inv,
            ]
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
        cam_rows = finite_rows(obs.T_world_cam)
        if cam_rows is None:
            return self._hold(TrackingState.LOST_TRACKING, "camera pose not finite; holding")
        ring_rows = finite_rows(obs.T_world_ring)
        if ring_rows is None:
            return self._lose("ring pose missing or not finite")
        if is_stale(obs.t, obs.t_ring, cfg.ring_max_age):
            return self._lose(STALE_REASON)
        R = ring_rows
        n_obs = unit_or_none((R[0][2], R[1][2], R[2][2]))
        if n_obs is None:
            return self._lose("ring pose degenerate (zero normal)")
        p_obs = (R[0][3], R[1][3], R[2][3])
        if not self._gate.accept(obs.t, p_obs, n_obs):
            return self._lose(GATE_REASON)
        p_cam = (cam_rows[0][3], cam_rows[1][3], cam_rows[2][3])

        geometry = self._window_geometry
        assert geometry is not None  # set by reset()
        tips = obs.p_world_tips
        tip_rows = tips.tolist() if isinstance(tips, np.ndarray) else list(tips)
        status = window_status_rows(geometry, cam_rows, tip_rows)
        d_before = self.d_f
        self.d_f = adjust_working_distance(self.d_f, status, cfg.d_min, cfg.d_max, cfg.d_f_step)

        self._predictor.push(obs.t, p_obs, n_obs)
        p_c, n = self._predictor.predict(self._horizon)
        previous = self._last_goal if self._last_goal is not None else self._last_cmd
        assert previous is not None  # set by reset()
        if status is WindowStatus.BETWEEN and tc.keep_side and tc.shorten_when_low:
            self.d_f = self._shortened(p_c, n, self.d_f, previous, tip_rows)
        d = self.d_f
        if tc.keep_side:
            chosen = self._choose(p_c, n, d)
        else:
            chosen = self._paper_view(p_c, n, d, previous)
        margin = -math.inf
        goal = None
        adjusted = False  # the goal was turned off the view for the wire clearance
        if chosen is not None:
            s, u = chosen
            view = self._pose(p_c, u, d, previous)
            goal = self._clear(view, p_c, p_cam)
            if goal is None:
                self._path = None
                self._transfer = None
                self._last_goal = None
                self.d_f = d_before
                return self._hold(TrackingState.FROZEN_OUTSIDE_CONE, WIRE_REASON)
            adjusted = goal is not view
            margin = cone_margin(self.cone, goal[:3, 3])
        release = FREEZE_RELEASE_MARGIN if self._frozen_T is not None else 0.0
        if goal is None or not margin >= release:
            if self._frozen_T is None:
                self._frozen_T = np.asarray(obs.T_world_cam, dtype=float)
            self._last_cmd = self._frozen_T
            return self._freeze(d_before, "no view of the ring inside the cone workspace")
        self._frozen_T = None

        side_changed = bool(self._side) and s != self._side
        fresh = self._last_goal is None
        side_before = self._side
        self._side = s
        self._last_goal = goal
        p_goal = goal[:3, 3].tolist()
        if side_changed or (fresh and math.dist(p_goal, p_cam) > cfg.jump_threshold):
            self._start(tc.side_transfer if side_changed else tc.first_approach, p_cam, p_c)

        state, reason = TrackingState.TRACKING, ""
        cmd, twist = goal, None
        if self._transfer is Transfer.ORBIT:
            z_cam = (cam_rows[0][2], cam_rows[1][2], cam_rows[2][2])
            orbit = self._orbit(p_c, u, d, p_cam, z_cam)
            if orbit is not None:
                cmd = orbit
                state, reason = TrackingState.PLANNING, "orbiting the ring to the other side"
        elif self._transfer is Transfer.WAYPOINTS:
            wp = self._waypoints(p_c, goal, obs)
            if wp is not None:
                cmd = wp
                state, reason = TrackingState.PLANNING, "following intermediate way-points"
        feedforward = tc.feedforward and self._horizon > 0.0 and ctx.follows_twist
        if state is TrackingState.TRACKING and feedforward:
            p2, n2 = self._predictor.predict(self._horizon + ctx.dt)
            u2 = self._view(p2, n2, s, d) if tc.keep_side else None
            if u2 is not None:
                twist = self._twist(goal, self._pose(p2, u2[0], d, goal), ctx.dt)
            elif not tc.keep_side:
                twist = self._twist(goal, self._pose(p2, _flip(n2, u, n), d, goal), ctx.dt)
        near_edge = goal[2, 3] <= self._aim_floor + FLOOR_TOL_M or margin < tc.floor_clearance
        if twist is not None and not near_edge and not adjusted:
            g_lin, g_ang = tc.feedforward_gain
            twist[:3] *= g_lin
            twist[3:] *= g_ang
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
        via = self._detoured(cmd, p_c, p_cam)
        if via is not None:
            cmd, twist = via, None
            state, reason = TrackingState.PLANNING, DETOUR_REASON
        if not self._in_workspace(cmd):  # last gate: never command outside the workspace
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
        """Whether a commanded pose (4, 4) is inside the cone and above the floor."""
        p = T_world_cmd[:3, 3].tolist()
        return (
            cone_margin(self.cone, p) >= 0.0 and p[2] >= self.config.min_camera_height - FLOOR_TOL_M
        )

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


def _flip(n2: Vec, u: Vec, n: Vec) -> Vec:
    """``n2`` signed like ``u`` is relative to ``n`` (the side kept for the twist)."""
    s = 1.0 if dot(u, n) >= 0.0 else -1.0
    return (s * n2[0], s * n2[1], s * n2[2])


class InterpretedOraclePolicy(InterpretedEndocamPolicy):
    """The non-causal reference: the ``endocam`` goal with the true, undelayed future.

    It ignores the sensed ring pose (so it never enters ``lost_tracking``): it exists to
    measure, not to run on a robot.

    See the module docstring. ``reset`` raises ``ValueError`` without ``PolicyContext.future``.
    """

    name = "oracle"

    def __init__(
        self, config: ControllerConfig | None = None, oracle: OracleConfig | None = None
    ) -> None:
        config = config or ControllerConfig()
        self.oracle = oracle or OracleConfig()
        tracker = config.tracker.model_copy(
            update={
                "keep_side": True,
                "predict": True,
                "feedforward": True,
                "feedforward_gain": self.oracle.feedforward_gain,
            }
        )
        super().__init__(config.model_copy(update={"tracker": tracker}))
        self._future: RingFuture | None = None
        self._plan: list[float] = []

    def reset(self, context: PolicyContext) -> None:
        """Tracker state, the true-trajectory table and the side plan for a new episode."""
        super().reset(context)
        o = self.oracle
        lead = self.tracker.carrier_lead if o.lead is None else o.lead
        self._future = RingFuture.of(context, lead + o.switch_lead + context.dt)
        self._predictor = _FuturePredictor(self._future)  # type: ignore[assignment]
        self._horizon = lead
        self._plan = self._side_plan(context.future_duration) if o.plan else []

    def _side_plan(self, duration: float) -> list[float]:
        """The side for every ``plan_dt`` over ``[0, duration]`` (see the module docstring)."""
        assert self._future is not None
        dt = self.oracle.plan_dt
        m = math.floor(duration / dt + 1e-9) + 1
        d = self.config.d_f
        cost = np.empty((m, 2))
        for j in range(m):
            p_c, n = self._future.at(j * dt)
            for i, s in enumerate((1.0, -1.0)):
                view = self._view(p_c, n, s, d)
                ok = view is not None and view[2] >= 0.0
                err = view[1] if ok and view is not None else INFEASIBLE_COST
                below = s * n[2] < 0.0  # ties go to the paper's side, above the feature
                cost[j, i] = (err + (TIE_BREAK if below else 0.0)) * dt
        return plan_sides(cost, self.oracle.switch_cost)

    def _planned_side(self) -> float | None:
        """The plan's side ``switch_lead`` s from now (``None`` without a plan)."""
        if not self._plan:
            return None
        t = self._predictor.t + self.oracle.switch_lead  # type: ignore[attr-defined]
        j = min(max(round(t / self.oracle.plan_dt), 0), len(self._plan) - 1)
        return self._plan[j]

    def _choose(self, p_c: Vec, n: Vec, d: float) -> tuple[float, Vec] | None:
        """The planned side while its view is feasible; else the tracker's side keeping."""
        s = self._planned_side()
        if s is not None:
            view = self._view(p_c, n, s, d)
            if view is not None and view[2] >= 0.0:
                return s, view[0]
        return super()._choose(p_c, n, d)

    def _twist(self, T1: FloatArray, T2: FloatArray, delta: float) -> FloatArray:  # type: ignore[override]
        """(6,) the goal's mean velocity over ``velocity_window`` centred on ``lead`` from now.

        Linear (m/s) then angular (rad/s), world; ``T1`` and ``T2`` (the tracker's one-period
        difference) are replaced by the goals at the window's ends on the current side.
        """
        w = self.oracle.velocity_window
        t = self._horizon
        poses = []
        for h in (t - 0.5 * w, t + 0.5 * w):
            p_c, n = self._predictor.predict(h)
            view = self._view(p_c, n, self._side, self.d_f)
            if view is None:
                return InterpretedEndocamPolicy._twist(T1, T2, delta)
            poses.append(self._pose(p_c, view[0], self.d_f, T1))
        return InterpretedEndocamPolicy._twist(poses[0], poses[1], w)

    def step(self, obs: Observation) -> CameraCommand:
        """One step on the true ring pose now (no sensing delay, fresh), whatever ``obs`` sensed."""
        future = self._future
        if future is None:
            raise RuntimeError("call reset() before step()")
        T_true = future.poses[future.index(obs.t)]
        return super().step(obs._replace(T_world_ring=T_true, t_ring=obs.t))


# -- the moving policies (condition II, III) as they were: their step and goals ---------------


class _InterpretedMoving:
    """``_MovingPolicy.step`` as it was (the rest of the class is unchanged)."""

    def reset(self, context: PolicyContext) -> None:
        super().reset(context)
        _interpreted_gate(self)

    def _gated(self, t: float, ring_rows: Rows) -> bool:
        R = ring_rows
        n = (R[0][2], R[1][2], R[2][2])
        if not math.hypot(*n) > _MIN_NORMAL:
            return True
        return self._gate.accept(t, (R[0][3], R[1][3], R[2][3]), n)

    def step(self, obs: Observation) -> CameraCommand:
        """Input checks, working distance, goal, cone freeze, way-points — in that order."""
        ctx = self._ctx
        if ctx is None:
            raise RuntimeError("call reset() before step()")
        cfg = self.config
        cam_rows = finite_rows(obs.T_world_cam)
        if cam_rows is None:
            return self._hold(TrackingState.LOST_TRACKING, "camera pose not finite; holding")
        T_cam = np.asarray(obs.T_world_cam, dtype=float)
        ring_rows = finite_rows(obs.T_world_ring)
        if ring_rows is None:
            self._last_goal = None
            self._path = None
            return self._hold(TrackingState.LOST_TRACKING, "ring pose missing or not finite")
        if is_stale(obs.t, obs.t_ring, cfg.ring_max_age):
            self._last_goal = None
            self._path = None
            return self._hold(TrackingState.LOST_TRACKING, STALE_REASON)
        if not self._gated(obs.t, ring_rows):
            self._last_goal = None
            self._path = None
            return self._hold(TrackingState.LOST_TRACKING, GATE_REASON)
        T_ring = np.asarray(obs.T_world_ring, dtype=float)

        tips = obs.p_world_tips
        tip_rows = tips.tolist() if isinstance(tips, np.ndarray) else list(tips)
        geometry = self._window_geometry
        assert geometry is not None  # set by reset()
        status = window_status_rows(geometry, cam_rows, tip_rows)
        d_f_before = self.d_f
        self.d_f = adjust_working_distance(self.d_f, status, cfg.d_min, cfg.d_max, cfg.d_f_step)

        goal = self._goal(ring_rows, T_cam)
        if goal is None:
            self.d_f = d_f_before
            self._last_goal = None
            self._path = None
            return self._hold(TrackingState.LOST_TRACKING, "ring pose degenerate (zero normal)")
        p_ring = [ring_rows[0][3], ring_rows[1][3], ring_rows[2][3]]
        p_now = [cam_rows[0][3], cam_rows[1][3], cam_rows[2][3]]
        goal = self._clear(goal, p_ring, p_now)
        if goal is None:  # the last command passed the guard: hold it, as a freeze does
            self.d_f = d_f_before
            self._last_goal = None
            self._path = None
            return self._hold(TrackingState.FROZEN_OUTSIDE_CONE, WIRE_REASON)
        goal_rows = goal.tolist()
        p_goal = [goal_rows[0][3], goal_rows[1][3], goal_rows[2][3]]
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

        if self._last_goal is not None:
            ref_p = self._last_goal_p
        else:
            ref_p = [cam_rows[0][3], cam_rows[1][3], cam_rows[2][3]]
        jumped = math.dist(p_goal, ref_p) > cfg.jump_threshold
        self._last_goal = goal
        self._last_goal_p = p_goal
        if jumped and self._path is None:
            p_cam = [cam_rows[0][3], cam_rows[1][3], cam_rows[2][3]]
            self._path = WaypointPath(
                intermediate_waypoints(
                    T_cam[:3, 3], np.array(p_goal), UP, self._lift(p_cam), self._lift(p_goal)
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
                wp = self._clear(self._waypoint_pose(p, T_ring, goal), p_ring, p_now)
                if wp is None:
                    self._path = None
                    self._last_goal = None
                    return self._hold(TrackingState.FROZEN_OUTSIDE_CONE, WIRE_REASON)
                cmd = wp
                state, reason = TrackingState.PLANNING, "following intermediate way-points"
        via = self._detoured(cmd, p_ring, p_now)
        if via is not None:
            cmd = via
            state, reason = TrackingState.PLANNING, DETOUR_REASON
        self._last_cmd = cmd
        return CameraCommand(cmd, state, self.d_f, reason)


class InterpretedCenteringPolicy(_InterpretedMoving, CenteringPolicy):
    """``CenteringPolicy`` as it was."""

    def reset(self, context: PolicyContext) -> None:
        """Also fix the orientation it keeps and the offset of the eye it centres."""
        super().reset(context)
        R0 = np.asarray(context.T_world_cam, dtype=float)[:3, :3]
        self._T0 = np.eye(4)
        self._T0[:3, :3] = R0
        half_b = 0.5 * context.camera.baseline if self.config.centre_left_eye else 0.0
        # camera = ring − d z0 + (b/2) x0: the left eye, b/2 along −x, on the ring's line
        self._z0 = R0[:, 2].tolist()
        self._shift = (half_b * R0[:, 0]).tolist()

    def _goal(self, ring_rows: Rows, T_world_cam: FloatArray) -> FloatArray:
        T = self._T0.copy()
        d, z0, sh = self.d_f, self._z0, self._shift
        for i in range(3):
            T[i, 3] = ring_rows[i][3] - d * z0[i] + sh[i]
        return T


class InterpretedOrientationPolicy(_InterpretedMoving, OrientationPolicy):
    """``OrientationPolicy`` as it was."""

    def _goal(self, ring_rows: Rows, T_world_cam: FloatArray) -> FloatArray | None:
        previous = self._last_goal if self._last_goal is not None else T_world_cam
        T = ring_rows
        n = (T[0][2], T[1][2], T[2][2])
        norm = math.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
        if not norm > _MIN_NORMAL:
            return None
        n = (n[0] / norm, n[1] / norm, n[2] / norm)
        cfg = self.config
        p_c = (T[0][3], T[1][3], T[2][3])
        toward = None
        if cfg.side_rule is SideRule.PORT:
            assert self._ctx is not None
            r = self._ctx.p_world_rcm
            d = (float(r[0]) - p_c[0], float(r[1]) - p_c[1], float(r[2]) - p_c[2])
            norm_d = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
            if norm_d > _MIN_NORMAL:  # a ring at the port itself keeps the paper's rule
                toward = (d[0] / norm_d, d[1] / norm_d, d[2] / norm_d)
        return goal_pose_unchecked(
            p_c,
            n,
            self.d_f,
            _UP,
            previous,
            cfg.side_hysteresis,
            cfg.min_camera_height,
            toward,
        )
