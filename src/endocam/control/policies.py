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

import enum
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from endocam.camera import StereoCamera
from endocam.control.goal import goal_pose_unchecked, look_at_unchecked
from endocam.control.planner import WaypointPath, advance, intermediate_waypoints
from endocam.control.safety import (
    D_F_STEP,
    ConeWorkspace,
    ImageWindows,
    WindowGeometry,
    adjust_working_distance,
    window_status_rows,
)
from endocam.control.tracker_config import TrackerConfig
from endocam.geometry import UP, FloatArray


class TrackingState(enum.Enum):
    """What a policy is doing this control step."""

    HOLDING = "holding"  # deliberately still (the fixed camera)
    TRACKING = "tracking"  # moving to the goal
    PLANNING = "planning"  # following intermediate way-points around a goal jump
    FROZEN_OUTSIDE_CONE = "frozen_outside_cone"  # goal left the cone workspace; pose held
    LOST_TRACKING = "lost_tracking"  # no valid feature observation; last safe pose held
    UNREACHABLE = "unreachable"  # the arm cannot reach the goal (set by the robot layer)


class SideRule(enum.Enum):
    """Which side of the feature the orientation camera looks from (see ``control.goal``)."""

    UP = "up"
    """The paper's rule: the side above the feature, ``s n·up ≥ 0``."""
    PORT = "port"
    """The side facing the camera arm's RCM, ``s n·(p_rcm − p_c) ≥ 0``."""


class ControllerConfig(BaseModel):
    """Parameters of the moving policies, SI units. Validated at construction."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    d_f: float = Field(0.05, gt=0, description="initial working distance, m")
    d_min: float = Field(0.03, gt=0, description="smallest working distance, m")
    d_max: float = Field(0.08, gt=0, description="largest working distance, m")
    d_f_step: float = Field(D_F_STEP, gt=0, description="working-distance change per step, m")
    jump_threshold: float = Field(
        0.02, gt=0, description="goal jump between control steps that triggers way-points, m"
    )
    d_wp: float = Field(0.04, gt=0, description="height of intermediate way-points, m")
    side_hysteresis: float = Field(
        math.radians(25.0),
        ge=0,
        lt=math.pi / 2,
        description="how far below horizontal the ring normal may tip before the orientation "
        "camera changes side, rad",
    )
    side_rule: SideRule = Field(
        SideRule.PORT,
        description="which side of the ring the orientation camera takes: 'up' (the paper: "
        "above the ring) or 'port' (facing the camera arm's RCM, so the camera looks away "
        "from its port, as an RCM arm's wrist must)",
    )
    min_camera_height: float = Field(
        0.015,
        description="lowest camera height above the board (world z) the side hysteresis may "
        "keep, m",
    )
    planner_speed: float = Field(0.15, gt=0, description="progress speed along way-points, m/s")
    planner_lookahead: float = Field(
        0.01, gt=0, description="how far progress may lead the camera's projection, m"
    )
    cone_height: float = Field(
        0.30,
        gt=0,
        description="cone workspace height, m: the PSM-held camera's reach (0.24 m insertion "
        "+ 0.046 m to the tip + 0.015 m mount), as the paper sets it slightly under the "
        "instrument length",
    )
    cone_base_radius: float = Field(
        0.25,
        gt=0,
        description="cone base radius, m (the paper chose 0.10 m empirically for its port; "
        "this port is within the PSM's reach of the wire, hence closer and wider-angled: "
        "see docs/world.md)",
    )
    window_inner_frac: float = Field(0.5, gt=0, le=1, description="inner window, image fraction")
    window_outer_frac: float = Field(0.9, gt=0, le=1, description="outer window, image fraction")
    tracker: TrackerConfig = Field(
        default_factory=TrackerConfig, description="the endocam tracker's switches (policy endocam)"
    )

    @model_validator(mode="after")
    def _check_ranges(self) -> ControllerConfig:
        if not self.d_min <= self.d_f <= self.d_max:
            raise ValueError(
                f"need d_min ≤ d_f ≤ d_max, got {self.d_min}, {self.d_f}, {self.d_max}"
            )
        if not self.window_inner_frac < self.window_outer_frac:
            raise ValueError("window_inner_frac must be smaller than window_outer_frac")
        return self

    @property
    def windows(self) -> ImageWindows:
        """The tool-in-view windows."""
        return ImageWindows(self.window_inner_frac, self.window_outer_frac)


@dataclass(frozen=True)
class PolicyContext:
    """What a policy is told at ``reset``.

    Attributes
    ----------
    camera : StereoCamera
        The stereo camera (intrinsics, baseline).
    T_world_cam : (4, 4)
        Initial camera pose (the fixed condition's whole-task view), optical frame, m.
    T_world_ring : (4, 4)
        The ring pose at initialisation, m (gives the cone axis).
    p_world_rcm : (3,)
        Remote centre of motion of the camera arm = cone tip, m.
    dt : float
        Control period, s.
    sensing_latency : float
        How old the ring pose in each observation is, s (a tracker may predict across it).
    """

    camera: StereoCamera
    T_world_cam: FloatArray
    T_world_ring: FloatArray
    p_world_rcm: FloatArray
    dt: float
    sensing_latency: float = 0.0


@dataclass(frozen=True)
class Observation:
    """What a policy sees each control step.

    Attributes
    ----------
    t : float
        Time, s.
    T_world_ring : (4, 4) or None
        Sensed ring pose (ring z = face normal), m; ``None`` or non-finite when tracking is lost.
    T_world_cam : (4, 4)
        Measured camera pose, optical frame, m.
    p_world_tips : (K, 3)
        Instrument tip positions in world, m.
    p_world_reach_offset : (3,) or None
        How far the actuator's target for the previous command lies from that command's
        position, m (world): non-zero when an arm concedes a goal it cannot reach (the
        nearest feasible view). The way-point planner measures the camera's progress against
        where the actuator can put it; ``None``: the actuator reaches what it is sent.
    """

    t: float
    T_world_ring: FloatArray | None
    T_world_cam: FloatArray
    p_world_tips: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    p_world_reach_offset: FloatArray | None = None


@dataclass(frozen=True)
class CameraCommand:
    """A policy's output: the camera pose to move to, and why.

    Attributes
    ----------
    T_world_cam : (4, 4)
        Commanded camera pose, optical frame, m.
    state : TrackingState
    d_f : float
        Working distance in use, m.
    reason : str
        One line for the log when the state is not plain tracking.
    twist : (6,) or None
        Velocity of the commanded pose: linear in world (m/s), then angular in world (rad/s).
        A carrier that supports it arrives moving with it (no lag on steady motion);
        ``None``: arrive at rest.
    """

    T_world_cam: FloatArray
    state: TrackingState
    d_f: float
    reason: str = ""
    twist: FloatArray | None = None


class CameraPolicy(Protocol):
    """The interface every camera policy implements."""

    name: str

    def reset(self, context: PolicyContext) -> None:
        """Start an episode."""

    def step(self, obs: Observation) -> CameraCommand:
        """One control step: map an observation to a camera command."""


_UP = (0.0, 0.0, 1.0)  # world up as plain floats
FREEZE_RELEASE_MARGIN = 1e-3  # m, how far back inside the cone the goal must be to unfreeze
LIFT_TOL = 1e-4  # m, resolution of the cone-limited way-point height
_MIN_NORMAL = 1e-9  # unitless, a ring normal shorter than this is degenerate


Rows = list[list[float]]


def _rows(T: FloatArray | None) -> Rows | None:
    """Rows of a finite (4, 4) array as plain floats, or ``None`` if missing or not finite."""
    if T is None:
        return None
    arr = T if isinstance(T, np.ndarray) else np.asarray(T, dtype=float)
    if arr.shape != (4, 4):
        return None
    rows: Rows = arr.tolist()
    if not math.isfinite(math.fsum(rows[0] + rows[1] + rows[2] + rows[3])):
        return None  # any NaN or inf makes the sum non-finite
    return rows


def _valid_pose(T: FloatArray | None) -> bool:
    """A (4, 4) array of finite numbers."""
    return _rows(T) is not None


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
        self.d_f = self.config.d_f
        self._last_goal: FloatArray | None = None  # last unplanned goal (jump detection)
        self._last_goal_p: list[float] = []  # its position as plain floats
        self._last_cmd: FloatArray | None = None  # last commanded pose (last safe pose)
        self._frozen_T: FloatArray | None = None
        self._path: WaypointPath | None = None
        self._s = 0.0

    def reset(self, context: PolicyContext) -> None:
        """Fix the cone axis from the RCM to the ring's initial position; clear all memory."""
        self._ctx = context
        self._window_geometry = WindowGeometry.of(context.camera, self._windows)
        self._cone = ConeWorkspace.from_rcm(
            context.p_world_rcm,
            context.T_world_ring[:3, 3],
            self.config.cone_height,
            self.config.cone_base_radius,
        )
        self.d_f = self.config.d_f
        self._last_goal = None
        self._last_cmd = np.array(context.T_world_cam, dtype=float)
        self._frozen_T = None
        self._path = None
        self._s = 0.0

    @property
    def cone(self) -> ConeWorkspace:
        """The cone workspace fixed at reset."""
        if self._cone is None:
            raise RuntimeError("call reset() before using the policy")
        return self._cone

    def _goal(self, T_world_ring: FloatArray, T_world_cam: FloatArray) -> FloatArray | None:
        """The goal ``T_world_cam`` (4, 4), or ``None`` if the ring pose gives none."""
        raise NotImplementedError

    def _goal_rows(
        self, ring_rows: Rows, T_world_ring: FloatArray, T_world_cam: FloatArray
    ) -> FloatArray | None:
        """:meth:`_goal` with the ring pose also given as rows of floats (override to use them)."""
        return self._goal(T_world_ring, T_world_cam)

    def _hold(self, state: TrackingState, reason: str) -> CameraCommand:
        assert self._last_cmd is not None
        return CameraCommand(self._last_cmd, state, self.d_f, reason)

    def step(self, obs: Observation) -> CameraCommand:
        """Input checks, working distance, goal, cone freeze, way-points — in that order."""
        ctx = self._ctx
        if ctx is None:
            raise RuntimeError("call reset() before step()")
        cfg = self.config
        cam_rows = _rows(obs.T_world_cam)
        if cam_rows is None:
            return self._hold(TrackingState.LOST_TRACKING, "camera pose not finite; holding")
        T_cam = np.asarray(obs.T_world_cam, dtype=float)
        ring_rows = _rows(obs.T_world_ring)
        if ring_rows is None:
            self._last_goal = None
            self._path = None
            return self._hold(TrackingState.LOST_TRACKING, "ring pose missing or not finite")
        T_ring = np.asarray(obs.T_world_ring, dtype=float)

        tips = obs.p_world_tips
        tip_rows = tips.tolist() if isinstance(tips, np.ndarray) else list(tips)
        geometry = self._window_geometry
        assert geometry is not None  # set by reset()
        status = window_status_rows(geometry, cam_rows, tip_rows)
        d_f_before = self.d_f
        self.d_f = adjust_working_distance(self.d_f, status, cfg.d_min, cfg.d_max, cfg.d_f_step)

        goal = self._goal_rows(ring_rows, T_ring, T_cam)
        if goal is None:
            self.d_f = d_f_before
            self._last_goal = None
            self._path = None
            return self._hold(TrackingState.LOST_TRACKING, "ring pose degenerate (zero normal)")
        p_goal = goal[:3, 3]
        goal_rows = goal.tolist()
        p_goal_list = [goal_rows[0][3], goal_rows[1][3], goal_rows[2][3]]
        margin = self.cone.margin(p_goal_list)
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
        jumped = math.dist(p_goal_list, ref_p) > cfg.jump_threshold
        self._last_goal = goal
        self._last_goal_p = p_goal_list
        if jumped and self._path is None:
            p_cam = [cam_rows[0][3], cam_rows[1][3], cam_rows[2][3]]
            self._path = WaypointPath(
                intermediate_waypoints(
                    T_cam[:3, 3], p_goal, UP, self._lift(p_cam), self._lift(p_goal_list)
                )
            )
            self._s = 0.0
        state, reason = TrackingState.TRACKING, ""
        cmd = goal
        if self._path is not None:
            self._path = self._path.with_goal(p_goal, UP, self._lift(p_goal_list))
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
                cmd = self._waypoint_pose(p, T_ring, goal)
                state, reason = TrackingState.PLANNING, "following intermediate way-points"
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


class CenteringPolicy(_MovingPolicy):
    """Condition II: keep the initial orientation, put the ring centre on the optical axis."""

    name = "centering"

    def _goal(self, T_world_ring: FloatArray, T_world_cam: FloatArray) -> FloatArray:
        assert self._ctx is not None
        R0 = self._ctx.T_world_cam[:3, :3]
        T = np.eye(4)
        T[:3, :3] = R0
        T[:3, 3] = T_world_ring[:3, 3] - self.d_f * R0[:, 2]
        return T

    def _waypoint_pose(self, p: FloatArray, T_ring: FloatArray, goal: FloatArray) -> FloatArray:
        T = goal.copy()  # orientation stays fixed on the way too
        T[:3, 3] = p
        return T


class OrientationPolicy(_MovingPolicy):
    """Condition III: the paper's orientation-aware camera (goal on the ring normal)."""

    name = "orientation"

    def _goal(self, T_world_ring: FloatArray, T_world_cam: FloatArray) -> FloatArray | None:
        return self._goal_rows(np.asarray(T_world_ring).tolist(), T_world_ring, T_world_cam)

    def _goal_rows(
        self, ring_rows: Rows, T_world_ring: FloatArray, T_world_cam: FloatArray
    ) -> FloatArray | None:
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


class OrientationEcmPolicy(OrientationPolicy):
    """The paper's orientation goal, carried out by the 4-DoF ECM (registry entry forces it).

    The goal is condition III's; the ECM's optical axis always passes through its RCM, so the
    camera reaches the goal's position but not, in general, its orientation. The orientation
    error it leaves quantifies what a standard endoscope cannot deliver (paper Sec. I).
    """

    name = "orientation-ecm"


@dataclass(frozen=True)
class PolicyEntry:
    """A registry entry: how to build a policy, one line to describe it, the arm it needs.

    Attributes
    ----------
    factory : callable
        Builds the policy from a :class:`ControllerConfig`.
    summary : str
        One line for ``endocam policies``.
    arm : {"free", "psm", "ecm"} or None
        The arm that must carry the camera; ``None`` uses the config's ``episode.arm``.
    """

    factory: Callable[[ControllerConfig], CameraPolicy]
    summary: str
    arm: str | None = None


POLICIES: dict[str, PolicyEntry] = {
    "fixed": PolicyEntry(FixedPolicy, "condition I: fixed camera showing the whole task"),
    "centering": PolicyEntry(
        CenteringPolicy, "condition II: follows the ring centre, keeps its initial orientation"
    ),
    "orientation": PolicyEntry(
        OrientationPolicy, "condition III: on the ring normal, level horizon, way-points, safety"
    ),
    "orientation-ecm": PolicyEntry(
        OrientationEcmPolicy,
        "condition III's goal carried out by the 4-DoF dVRK ECM (always uses the ECM)",
        arm="ecm",
    ),
}


def _endocam_tracker(config: ControllerConfig) -> CameraPolicy:
    from endocam.control.tracker import EndocamPolicy  # the tracker builds on this module

    return EndocamPolicy(config)


POLICIES["endocam"] = PolicyEntry(
    _endocam_tracker,
    "orientation goal kept on one side, orbit transfers, latency prediction, left-eye centring",
)


def make_policy(name: str, config: ControllerConfig | None = None) -> CameraPolicy:
    """Build a registered policy by name; unknown names raise ``ValueError`` listing the choices."""
    try:
        entry = POLICIES[name]
    except KeyError:
        choices = ", ".join(POLICIES)
        raise ValueError(f"unknown policy {name!r}; choose one of: {choices}") from None
    return entry.factory(config or ControllerConfig())


__all__ = [
    "POLICIES",
    "CameraCommand",
    "CameraPolicy",
    "CenteringPolicy",
    "ControllerConfig",
    "FixedPolicy",
    "Observation",
    "OrientationEcmPolicy",
    "OrientationPolicy",
    "PolicyContext",
    "PolicyEntry",
    "TrackingState",
    "make_policy",
]
