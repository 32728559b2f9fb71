"""``endocam/WireChaser-v0``: the wire-chaser world as a Gymnasium environment.

The agent moves the camera while the ring travels along the wire (the same trajectory,
latency, instrument tips and carriers as :func:`endocam.runner.episode.run_episode`).

**Action** (``Box(-1, 1, (6,))``, chosen by :attr:`WireChaserEnvConfig.action`):

* ``twist``: the free camera's velocity, linear (x, y, z, world) then angular (world), each as
  a fraction of the per-axis limit (``MotionLimits`` norms / √3, m/s and rad/s);
* ``joint_velocity``: the PSM's joint velocities as fractions of the dVRK limits
  (``robot.arm.PSM_MAX_VELOCITY``).

The action moves a set point (a camera pose, or PSM joints) at that velocity; the carrier
heads for the set point within its speed, acceleration and jerk limits (``FreeCamera``) or its
joint limits and IK (``CameraArm``), as it heads for a policy's command in an episode.

**Safety** (the rules of the built-in policies still hold): an action outside [-1, 1] is
clipped; a non-finite one is refused (the set point stays); PSM joints are clipped into their
limits; a set point whose camera would leave the cone workspace (``control.safety``, the RCM
cone of the paper's Sec. III-C) is refused and the camera holds. ``info["safety"]`` names what
happened, ``info["unsafe"]`` says whether any of it did, and the reward pays
``safety_penalty`` for it.

**Observation** (a ``Dict``; poses as position, m, then quaternion w, x, y, z; world frame):
``time`` (1,) s; ``ring_pose`` (7,) the ring as sensed, ``sensing_latency`` late;
``ring_time`` (1,) s, when that pose was captured (the agents pass it on as
``Observation.t_ring``, so the policies' stale-pose hold applies);
``camera_pose`` (7,) the camera's optical frame; ``tool_tips`` (2, 3) PSM1 and PSM2 tips, m;
with ``image_observation``, ``image`` (H, W, 3) uint8: the left eye rendered through
:mod:`endocam.sim` (``render_mode="rgb_array"`` renders the same image).

**Reward** per control step, after the camera moved:
``−(w_px · image error px + w_mm · 3D error mm + w_deg · orientation error deg) − penalty``,
the paper's three errors against the true ring (the image error of a ring out of view counted
as the largest in-image error, as in ``metrics.json``).

``reset(seed=...)`` is deterministic: the seed draws the noisy trajectory's seed
(``options={"trajectory_seed": n}`` picks it, as ``endocam run --seed n``). The episode is
truncated when the trajectory ends.
"""

from __future__ import annotations

import enum
import math
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from pydantic import BaseModel, ConfigDict, Field

from endocam.config import ExperimentConfig
from endocam.control.types import PolicyContext
from endocam.geometry import FloatArray, R_from_quat_wxyz, make_pose, quat_wxyz_from_R, so3_exp
from endocam.geometry import so3_log as so3_log_array
from endocam.metrics import (
    center_error_3d,
    image_centering_error,
    orientation_error,
    ring_out_of_view,
    saturate_image_error,
)
from endocam.robot.actuator import Actuator, ArmKind
from endocam.robot.arm import PSM_MAX_VELOCITY
from endocam.robot.camera_arm import CameraArm
from endocam.runner.step import EpisodeLoop, SetPoint, episode_world, start_carrier
from endocam.task.trajectory import RingTrajectory, TrajectoryKind, make_trajectory
from endocam.task.wire import Wire
from endocam.view import look_distance

ENV_ID = "endocam/WireChaser-v0"
_SQRT3 = math.sqrt(3.0)
SEED_BOUND = 2**31 - 1  # exclusive bound of the trajectory seed drawn by reset(seed=...)
WORLD_BOUND_M = 1.0  # m: |coordinate| bound of the observed positions (the task spans ~0.3 m)


class ActionKind(enum.Enum):
    """What the action commands."""

    TWIST = "twist"
    """The free camera's linear and angular velocity (world)."""
    JOINT_VELOCITY = "joint_velocity"
    """The PSM's joint velocities (the camera on a dVRK PSM)."""


class SafetyEvent(enum.Enum):
    """What the safety rules did with an action (``info["safety"]``)."""

    CLIPPED = "action_clipped"
    """A component outside [-1, 1] was clipped to the limit."""
    NON_FINITE = "non_finite_refused"
    """A NaN or infinite action was refused: the set point stays."""
    JOINT_LIMIT = "joint_limit_clipped"
    """The PSM set point was clipped into the joint limits."""
    OUTSIDE_CONE = "outside_cone_refused"
    """The set point would put the camera outside the cone workspace: refused, the camera holds."""


class WireChaserEnvConfig(BaseModel):
    """The environment: the experiment config, the action and the reward's weights."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    experiment: ExperimentConfig = Field(
        default_factory=ExperimentConfig, description="Task, camera, controller and episode."
    )
    action: ActionKind = Field(ActionKind.TWIST, description="twist or joint_velocity (PSM).")
    trajectory: TrajectoryKind = Field(TrajectoryKind.NOISY, description="ideal or noisy.")
    control_points: int = Field(71, ge=2, description="Control points along the wire.")
    image_observation: bool = Field(False, description="Add the left-eye image (renders).")
    weight_per_px: float = Field(0.01, ge=0.0, description="Reward weight of the image error.")
    weight_per_mm: float = Field(0.1, ge=0.0, description="Reward weight of the 3D error.")
    weight_per_deg: float = Field(
        0.1, ge=0.0, description="Reward weight of the orientation error."
    )
    safety_penalty: float = Field(1.0, ge=0.0, description="Reward lost per unsafe action.")


def pose7(T: FloatArray) -> FloatArray:
    """(7,) position (m) and quaternion (w, x, y, z) of a pose (4, 4)."""
    return np.concatenate([T[:3, 3], quat_wxyz_from_R(T[:3, :3])])


def pose_from7(x: FloatArray) -> FloatArray:
    """The (4, 4) pose of :func:`pose7`'s (7,) form."""
    q = np.asarray(x[3:], dtype=float)
    return make_pose(R_from_quat_wxyz(q / np.linalg.norm(q)), x[:3])


class WireChaserEnv(gym.Env[dict[str, np.ndarray], np.ndarray]):
    """The wire chaser as a Gymnasium environment (see the module docstring).

    Parameters
    ----------
    config : WireChaserEnvConfig, optional
    render_mode : {"rgb_array"}, optional
        ``render()`` returns the left eye's image (H, W, 3) uint8.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}  # noqa: RUF012 (gym.Env)

    def __init__(
        self, config: WireChaserEnvConfig | None = None, render_mode: str | None = None
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']}")
        self.config = config if config is not None else WireChaserEnvConfig()
        self.render_mode = render_mode
        exp = self.config.experiment
        self.camera = exp.camera.stereo()
        self.wire = Wire(exp.task.wire)
        self.dt = 1.0 / exp.episode.control_rate
        self.n_steps = math.floor(exp.task.trajectory.duration / self.dt + 1e-9) + 1
        self.arm = ArmKind.FREE if self.config.action is ActionKind.TWIST else ArmKind.PSM
        lim = exp.episode.limits
        if self.arm is ArmKind.FREE:
            v, w = lim.max_linear_speed / _SQRT3, lim.max_angular_speed / _SQRT3
            self._scale = np.array([v, v, v, w, w, w])
        else:
            self._scale = np.array(PSM_MAX_VELOCITY)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(6,), dtype=np.float64)
        b = WORLD_BOUND_M
        low7, high7 = np.array([-b, -b, -b, -1, -1, -1, -1.0]), np.array([b, b, b, 1, 1, 1, 1.0])
        duration = float(exp.task.trajectory.duration)
        obs: dict[str, spaces.Space[Any]] = {
            "time": spaces.Box(0.0, duration, shape=(1,), dtype=np.float64),
            "ring_pose": spaces.Box(low7, high7, dtype=np.float64),
            "ring_time": spaces.Box(0.0, duration, shape=(1,), dtype=np.float64),
            "camera_pose": spaces.Box(low7, high7, dtype=np.float64),
            "tool_tips": spaces.Box(-b, b, shape=(2, 3), dtype=np.float64),
        }
        if self.config.image_observation:
            k = self.camera.intrinsics
            obs["image"] = spaces.Box(0, 255, shape=(k.height, k.width, 3), dtype=np.uint8)
        self.observation_space = spaces.Dict(obs)  # type: ignore[assignment]
        self._scene: Any = None

    # ------------------------------------------------------------------ episode
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Start an episode on a new trajectory; ``options={"trajectory_seed": n}`` picks it."""
        super().reset(seed=seed)
        options = options or {}
        traj_seed = options.get("trajectory_seed")
        if traj_seed is None:
            traj_seed = int(self.np_random.integers(0, SEED_BOUND))
        exp = self.config.experiment
        self.trajectory: RingTrajectory = make_trajectory(
            exp.task, self.config.trajectory, self.config.control_points, traj_seed, wire=self.wire
        )
        self.trajectory_seed = int(traj_seed)
        self.world = episode_world(exp, self.trajectory)
        self._p_rcm = np.array(exp.task.scene.rcm_position)
        # the runner's carrier: it keeps the camera in its cone, above its floor, off the wire
        carrier = start_carrier(exp, self.arm, self.camera, self.wire, self.world)
        self.cone = carrier.workspace.cone
        self.actuator: Actuator = carrier.actuator
        self.loop = EpisodeLoop(self.world, carrier)
        self._setpoint = carrier.T_world_cam.copy()  # the free camera's set point
        self._q_setpoint = np.array(self.loop.q)  # the PSM's joint set point
        return self._observation(), {"t": 0.0, "trajectory_seed": self.trajectory_seed}

    def step(
        self, action: np.ndarray
    ) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        """One control period: move the set point by the action, the carrier follows it."""
        if self.loop.k >= self.n_steps - 1:
            raise RuntimeError("the episode has ended: call reset()")
        events: list[SafetyEvent] = []
        a = np.asarray(action, dtype=float).reshape(-1)
        if a.shape != (6,) or not np.isfinite(a).all():
            events.append(SafetyEvent.NON_FINITE)
            a = np.zeros(6)
        elif np.any(np.abs(a) > 1.0):
            events.append(SafetyEvent.CLIPPED)
            a = np.clip(a, -1.0, 1.0)
        velocity = a * self._scale
        if self.arm is ArmKind.FREE:
            T_set = self._step_free(velocity, events)
        else:
            T_set = self._step_psm(velocity, events)
        # the carrier heads for the set point at rest: a set point that stops is not overshot
        self.loop.step(SetPoint(T_set, self.config.experiment.controller.d_f))
        img, mm, deg = self._errors()
        cfg = self.config
        unsafe = bool(events)
        reward = -(cfg.weight_per_px * img + cfg.weight_per_mm * mm + cfg.weight_per_deg * deg)
        reward -= cfg.safety_penalty if unsafe else 0.0
        info = {
            "t": float(self.world.t[self.loop.k]),
            "safety": tuple(e.value for e in events),
            "unsafe": unsafe,
            "image_error_px": img,
            "center_error_mm": mm,
            "orientation_error_deg": deg,
        }
        truncated = self.loop.k >= self.n_steps - 1
        return self._observation(), float(reward), False, truncated, info

    def _inside(self, T_world_cam: FloatArray) -> bool:
        return self.cone.contains(T_world_cam[:3, 3])

    def _step_free(self, twist: FloatArray, events: list[SafetyEvent]) -> FloatArray:
        S = self._setpoint
        moved = make_pose(so3_exp(twist[3:] * self.dt) @ S[:3, :3], S[:3, 3] + twist[:3] * self.dt)
        if not self._inside(moved):
            events.append(SafetyEvent.OUTSIDE_CONE)
            moved = S
        self._setpoint = moved
        return moved

    def _step_psm(self, qd: FloatArray, events: list[SafetyEvent]) -> FloatArray:
        arm = self.actuator
        assert isinstance(arm, CameraArm)
        wanted = self._q_setpoint + qd * self.dt
        clipped = np.clip(wanted, arm.model.lower, arm.model.upper)
        if not np.array_equal(clipped, wanted):
            events.append(SafetyEvent.JOINT_LIMIT)
        T_set = arm.camera_pose(clipped)
        if not self._inside(T_set):
            events.append(SafetyEvent.OUTSIDE_CONE)
            clipped = self._q_setpoint
            T_set = arm.camera_pose(clipped)
        self._q_setpoint = clipped
        return T_set

    def _errors(self) -> tuple[float, float, float]:
        """The paper's three errors now: image px (saturated), 3D mm (left eye), deg."""
        k, world = self.loop.k, self.world
        T_cam = self.loop.T_world_cam[None]
        p_ring = world.T_world_ring[k : k + 1, :3, 3]
        raw = image_centering_error(self.camera, T_cam, p_ring)
        out = ring_out_of_view(self.camera, T_cam, p_ring)
        img = float(saturate_image_error(self.camera, raw, out)[0])
        mm = 1e3 * float(center_error_3d(T_cam @ self.camera.T_cam_left, p_ring)[0])
        deg = math.degrees(float(orientation_error(T_cam, world.T_world_ring[k : k + 1, :3, 2])[0]))
        return img, mm, deg

    def _observation(self) -> dict[str, np.ndarray]:
        k, world = self.loop.k, self.world
        obs = {
            "time": np.array([world.t[k]]),
            "ring_pose": pose7(world.T_world_ring_sensed[k]),
            "ring_time": np.array([world.t_ring[k]]),
            "camera_pose": pose7(self.loop.T_world_cam),
            "tool_tips": np.array(world.p_world_tips[k], dtype=float),
        }
        if self.config.image_observation:
            obs["image"] = self._render()
        return obs

    # ------------------------------------------------------------------ agents
    def policy_context(self) -> PolicyContext:
        """What a built-in policy is told at reset, as in an episode (``future``: the oracle)."""
        return PolicyContext(
            self.camera,
            self.loop.T_world_cam.copy(),
            self.world.T_world_ring_sensed[0],
            self._p_rcm,
            self.dt,
            self.config.experiment.episode.sensing_latency,
            future=self.trajectory.poses,
            future_duration=float(self.trajectory.duration),
            follows_twist=False,  # action_towards maps the pose alone; a twist would be ignored
            wire=self.wire,
            ring=self.config.experiment.task.ring,
        )

    def action_towards(self, T_world_cmd: FloatArray, d_f: float) -> np.ndarray:
        """(6,) the action that moves the set point to a commanded camera pose (clipped).

        Parameters
        ----------
        T_world_cmd : (4, 4)
            Commanded camera pose, world, optical frame, m.
        d_f : float
            The command's working distance, m. The PSM's conceded view turns about the point
            the command looks at: the sensed ring's depth along the command's axis, else
            ``d_f`` (:func:`endocam.view.look_distance`, as the episode loop tells the
            carrier).
        """
        if self.arm is ArmKind.FREE:
            S = self._setpoint
            v = (T_world_cmd[:3, 3] - S[:3, 3]) / self.dt
            w = so3_log_array(T_world_cmd[:3, :3] @ S[:3, :3].T) / self.dt
            velocity = np.concatenate([v, w])
        else:
            arm = self.actuator
            assert isinstance(arm, CameraArm)
            T_cmd = np.asarray(T_world_cmd, dtype=float)
            look = look_distance(T_cmd, self.world.T_world_ring_sensed[self.loop.k], d_f)
            q_goal, _, _ = arm.target(T_cmd, look)
            velocity = (np.array(q_goal) - self._q_setpoint) / self.dt
        return np.clip(velocity / self._scale, -1.0, 1.0)

    # ------------------------------------------------------------------ rendering
    def _render(self) -> np.ndarray:
        from endocam.sim.render import WireChaserScene

        if self._scene is None:
            exp = self.config.experiment
            self._scene = WireChaserScene(exp.task, self.camera, arm=self.arm)
        k = self.loop.k
        self._scene.set_ring_pose(self.world.T_world_ring[k])
        self._scene.set_psm2_tip(self.world.p_world_tips[k, 1])
        self._scene.set_camera_pose(self.loop.T_world_cam)
        if self.arm is not ArmKind.FREE:
            self._scene.set_arm_joints(self.loop.q)
        return np.array(self._scene.render("left"), dtype=np.uint8)

    def render(self) -> np.ndarray | None:
        """The left eye's image (H, W, 3) uint8 with ``render_mode="rgb_array"``, else None."""
        if self.render_mode != "rgb_array":
            return None
        return self._render()

    def close(self) -> None:
        """Free the renderer."""
        if self._scene is not None:
            self._scene.close()
            self._scene = None
