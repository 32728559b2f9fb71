"""Named queries and offscreen rendering of the wire-chaser scene.

:class:`WireChaserScene` owns the MuJoCo model, its data and one ``mujoco.Renderer``. Callers
speak optical-frame poses and world points; nothing above this module touches MuJoCo arrays.
Run headless with the environment variable ``MUJOCO_GL=egl``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Protocol

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray

from endocam.camera import Eye, StereoCamera
from endocam.geometry import FloatArray, as_pose, as_vector3, quat_wxyz_from_R
from endocam.robot.camera_arm import ArmKind, arm_model, natural_pose
from endocam.robot.carriers import arm_mount
from endocam.sim.arm_scene import ArmLink, add_camera_arm
from endocam.sim.scene import (
    CAMERA_BODY,
    EYE_CAMERAS,
    GROUP_LINK,
    N_GROUPS,
    OBSERVER,
    PSM2_BODY,
    RING_BODY,
    TIP_SITES,
    build_spec,
)
from endocam.task.config import TaskConfig
from endocam.task.layout import psm2_pose


class ArmLog(Protocol):
    """What the renderer reads of an episode log to draw its camera arm.

    Attributes
    ----------
    arm : str
        ``ArmKind`` value of the carrier.
    joints : (N, J) ndarray or None
        Joint positions per control step, rad / m; ``None`` for a carrier without joints.
    """

    @property
    def arm(self) -> str:
        """``ArmKind`` value of the carrier."""
        ...

    @property
    def joints(self) -> NDArray[np.float64] | None:
        """Joint positions per control step (N, J), rad / m, or ``None``."""
        ...


DEFAULT_RAY_TOLERANCE = 2.0e-3  # m, occluders closer than this in front of the target are ignored


class WireChaserScene:
    """The rendered wire-chaser world.

    Parameters
    ----------
    task_cfg : TaskConfig
    camera : StereoCamera
        Stereo rig; its intrinsics set the render size and ``fovy``.
    spec : mujoco.MjSpec, optional
        A spec from :func:`endocam.sim.scene.build_spec`, possibly with extra mocap links
        (built from ``task_cfg`` and ``camera`` if omitted).
    arm : ArmKind, optional
        Draw this camera arm (``PSM`` or ``ECM``; ``None`` or ``FREE``: no arm), its RCM at
        ``task_cfg.scene.T_world_rcm`` (:mod:`endocam.sim.arm_scene`); pose it with
        :meth:`set_arm_joints`.
    """

    def __init__(
        self,
        task_cfg: TaskConfig,
        camera: StereoCamera,
        spec: mujoco.MjSpec | None = None,
        arm: ArmKind | None = None,
    ) -> None:
        self.task_cfg = task_cfg
        self.camera = camera
        if spec is None:
            spec = build_spec(task_cfg, camera)
        self.arm = None if arm is ArmKind.FREE else arm
        self._arm_links: tuple[ArmLink, ...] = ()
        if self.arm is not None:
            self._arm_links = add_camera_arm(spec, self.arm, task_cfg.instruments, camera)
            self._arm_model = arm_model(self.arm)
            self._T_world_rcm = arm_mount(self.arm, np.eye(4), task_cfg.scene.T_world_rcm)[0]
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        self._mocap = {
            name: int(self.model.body(name).mocapid[0])
            for name in (RING_BODY, PSM2_BODY, CAMERA_BODY, OBSERVER)
        }
        for link in self._arm_links:
            self._mocap[link.body] = int(self.model.body(link.body).mocapid[0])
        self._cam_ids = {name: int(self.model.camera(name).id) for name in (*EYE_CAMERAS, OBSERVER)}
        self._site_ids = [int(self.model.site(s).id) for s in TIP_SITES]
        self._option = mujoco.MjvOption()
        self._option.geomgroup[:] = 1  # MuJoCo hides groups 3-5 by default; show everything
        k = camera.intrinsics
        self._renderer: mujoco.Renderer | None = mujoco.Renderer(self.model, k.height, k.width)
        flags = self._renderer.scene.flags
        flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
        flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
        flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = 0
        if self.arm is not None:
            self.set_arm_joints(natural_pose(self._arm_model))
        self._update()

    # ---------------------------------------------------------------- state
    def _update(self) -> None:
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)
        for w in self.data.warning:
            if w.number > 0:
                raise RuntimeError(f"MuJoCo warning raised (number {w.number}, info {w.lastinfo})")

    def _set_mocap(self, body: str, T_world_body: FloatArray, update: bool = True) -> None:
        i = self._mocap[body]
        self.data.mocap_pos[i] = T_world_body[:3, 3]
        self.data.mocap_quat[i] = quat_wxyz_from_R(T_world_body[:3, :3])
        if update:
            self._update()

    def set_arm_joints(self, q: ArrayLike | None) -> None:
        """Pose the camera arm's links for joints ``q``, or hide the arm (``None``).

        Parameters
        ----------
        q : (n,) array_like or None
            Joint positions of the arm given at construction, rad / m (e.g. a row of
            ``EpisodeLog.joints``); ``None`` hides the arm's geoms (group ``GROUP_LINK``) in
            rendered images.

        Raises
        ------
        ValueError
            If the scene has no arm and ``q`` is not None, or ``q`` is malformed.
        """
        if q is None:
            self._option.geomgroup[GROUP_LINK] = 0
            return
        if self.arm is None:
            raise ValueError("q: this scene draws no arm (construct it with arm=...)")
        frames = self._T_world_rcm @ self._arm_model.frames(q)
        for link in self._arm_links:
            self._set_mocap(link.body, frames[link.frame], update=False)
        self._update()
        self._option.geomgroup[GROUP_LINK] = 1

    def set_ring_pose(self, T_world_ring: ArrayLike) -> None:
        """Move the ring, its handle and PSM1 (which holds it) to ``T_world_ring`` (4, 4), m."""
        self._set_mocap(RING_BODY, as_pose(T_world_ring, "T_world_ring"))

    def set_psm2_tip(self, p_world_tip: ArrayLike) -> None:
        """Move PSM2 so its tip is at ``p_world_tip`` (3,), m (its shaft keeps its direction).

        Pose it per frame from ``EpisodeLog.p_world_tips[k, 1]``: PSM2 may follow the ring
        (``InstrumentConfig.psm2_idle``).
        """
        self._set_mocap(PSM2_BODY, psm2_pose(self.task_cfg.instruments, p_world_tip))

    def set_camera_pose(self, T_world_cam: ArrayLike) -> None:
        """Move the stereo camera: ``T_world_cam`` (4, 4), optical frame of the rig centre, m."""
        self._set_mocap(CAMERA_BODY, as_pose(T_world_cam, "T_world_cam"))

    def set_mocap_pose(self, body: str, T_world_body: ArrayLike) -> None:
        """Move any named mocap body (e.g. a link added with ``add_mocap_link``), (4, 4), m."""
        T = as_pose(T_world_body, "T_world_body")
        if body not in self._mocap:
            try:
                mocap_id = int(self.model.body(body).mocapid[0])
            except KeyError as exc:
                raise ValueError(f"body {body!r} does not exist") from exc
            if mocap_id < 0:
                raise ValueError(f"body {body!r} is not a mocap body")
            self._mocap[body] = mocap_id
        self._set_mocap(body, T)

    # -------------------------------------------------------------- queries
    @property
    def T_world_cam(self) -> FloatArray:
        """(4, 4) current camera pose (optical frame), m."""
        return self._body_pose(CAMERA_BODY)

    @property
    def T_world_ring(self) -> FloatArray:
        """(4, 4) current ring pose, m."""
        return self._body_pose(RING_BODY)

    def _body_pose(self, body: str) -> FloatArray:
        b = self.model.body(body).id
        T = np.eye(4)
        T[:3, :3] = self.data.xmat[b].reshape(3, 3)
        T[:3, 3] = self.data.xpos[b]
        return T

    def tool_tips(self) -> FloatArray:
        """(2, 3) world positions of the PSM1 and PSM2 tool tips (jaw tips), m."""
        return np.array([self.data.site_xpos[i] for i in self._site_ids], dtype=float)

    def set_arm_from_log(self, log: ArmLog, k: int) -> None:
        """Pose the arm as at control step ``k`` of an episode log (``log.joints[k]``).

        The arm is hidden if that episode's camera was not carried by this scene's arm (a
        free camera, or the other arm kind).
        """
        same = self.arm is not None and log_arm(log) is self.arm
        self.set_arm_joints(log.joints[k] if same and log.joints is not None else None)

    def render(self, eye: Eye = "left") -> NDArray[np.uint8]:
        """Render ``eye``'s image at the camera's resolution: (H, W, 3) uint8 RGB."""
        if eye not in EYE_CAMERAS:
            raise ValueError(f"eye must be 'left' or 'right', got {eye!r}")
        return self._render(self._cam_ids[eye])

    def render_view(self, T_world_view: ArrayLike) -> NDArray[np.uint8]:
        """Render the scene from a free viewpoint (e.g. an overview showing the arms).

        Parameters
        ----------
        T_world_view : (4, 4) array_like
            Viewpoint pose, OpenCV optical frame, m; the image has the stereo camera's
            intrinsics (size and ``fovy``).

        Returns
        -------
        (H, W, 3) uint8 RGB
        """
        self._set_mocap(OBSERVER, as_pose(T_world_view, "T_world_view"))
        return self._render(self._cam_ids[OBSERVER])

    def _render(self, camera_id: int) -> NDArray[np.uint8]:
        if self._renderer is None:
            raise RuntimeError("the scene is closed")
        self._renderer.update_scene(self.data, camera=camera_id, scene_option=self._option)
        return np.asarray(self._renderer.render(), dtype=np.uint8)

    def ray_visible(
        self,
        p_world: ArrayLike,
        T_world_cam: ArrayLike,
        eye: Eye = "left",
        exclude_groups: Sequence[int] = (),
        tolerance: float = DEFAULT_RAY_TOLERANCE,
    ) -> bool:
        """Whether ``p_world`` is unoccluded from ``eye`` (geometry only, not the frustum).

        True when :meth:`occluder` finds nothing in front of the point (same parameters).
        """
        return self.occluder(p_world, T_world_cam, eye, exclude_groups, tolerance) is None

    def occluder(
        self,
        p_world: ArrayLike,
        T_world_cam: ArrayLike,
        eye: Eye = "left",
        exclude_groups: Sequence[int] = (),
        tolerance: float = DEFAULT_RAY_TOLERANCE,
    ) -> str | None:
        """Name of the geom that hides ``p_world`` from ``eye``; ``None`` if nothing does.

        A ray is cast (``mj_ray``) from the eye's optical centre towards the point through every
        geom of the current scene except those in ``exclude_groups`` (geom groups, e.g. the
        target's own group, ``GROUP_*`` in :mod:`endocam.sim.scene`). The point is hidden by the
        first geom hit more than ``tolerance`` before it: a point on a surface (e.g. a ring–wire
        contact point between two 1 mm tubes) is not hidden by the surface it sits on.

        Parameters
        ----------
        p_world : (3,)
            Target point in world, m.
        T_world_cam : (4, 4)
            Camera pose (optical frame), m.
        eye : {"left", "right"}
        exclude_groups : sequence of int
            Geom groups ignored by the ray.
        tolerance : float
            Allowed depth of the first hit before the target, m (≥ 0).

        Returns
        -------
        str or None
            The hiding geom's name (e.g. ``"wire"``, ``"ring_torus"``), or None.
        """
        p = as_vector3(p_world, "p_world")
        T = as_pose(T_world_cam, "T_world_cam")
        if not math.isfinite(tolerance) or tolerance < 0.0:
            raise ValueError(f"tolerance must be ≥ 0 m, got {tolerance}")
        groups = np.ones(N_GROUPS, dtype=np.uint8)
        for g in exclude_groups:
            if not 0 <= g < N_GROUPS:
                raise ValueError(f"exclude_groups entries must be in [0, {N_GROUPS}), got {g}")
            groups[g] = 0
        p_eye = (T @ self.camera.T_cam_eye(eye))[:3, 3]
        vec = p - p_eye
        dist = float(np.linalg.norm(vec))
        if dist <= tolerance:
            return None
        geomid = np.full(1, -1, dtype=np.int32)
        hit = mujoco.mj_ray(self.model, self.data, p_eye, vec / dist, groups, 1, -1, geomid)
        if hit < 0.0 or hit >= dist - tolerance:
            return None
        return self.geom_name(int(geomid[0])) or f"geom {int(geomid[0])}"

    def geom_name(self, geom_id: int) -> str:
        """Name of geom ``geom_id`` (for diagnostics)."""
        return str(self.model.geom(geom_id).name)

    def close(self) -> None:
        """Release the renderer's GL context (idempotent)."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __enter__(self) -> WireChaserScene:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def log_arm(log: ArmLog) -> ArmKind | None:
    """The arm that carried an episode's camera (to draw it), or None for a free camera."""
    return None if log.joints is None else ArmKind(log.arm)
