"""Pinhole stereo camera model: intrinsics, eye poses and projection to pixels.

The camera frame ``cam`` is the OpenCV optical frame (x right, y down, z forward) at the midpoint
between the eyes; ``T_cam_left`` and ``T_cam_right`` place the eyes at ∓baseline/2 along x.
Pixels follow ``docs/conventions.md``: u right, v down, principal point at the image centre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from endocam.geometry import FloatArray, make_pose

Eye = Literal["left", "right"]

DEFAULT_WIDTH_PX = 640
DEFAULT_HEIGHT_PX = 480
DEFAULT_FOVY = math.radians(60.0)  # rad, vertical field of view (da Vinci-like endoscope)
DEFAULT_BASELINE = 5.0e-3  # m, stereo baseline of a chip-on-tip pickup camera
SCOPE_RADIUS = (
    6.0e-3  # m, half the 12 mm da Vinci stereo endoscope (README, "Camera–wire clearance")
)
MIN_DEPTH = 1e-6  # m, points closer than this to the eye's plane cannot be projected


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of one eye.

    Attributes
    ----------
    width, height : int
        Image size, px.
    fx, fy : float
        Focal lengths, px.
    cx, cy : float
        Principal point, px.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            if not math.isfinite(value):
                raise ValueError(f"{name} must be finite, got {value}")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")

    @classmethod
    def from_fovy(cls, width: int, height: int, fovy: float) -> Intrinsics:
        """Square-pixel intrinsics from the image size (px) and vertical field of view (rad).

        ``fy = (H/2) / tan(fovy/2)``, ``fx = fy``, principal point at the image centre; this is
        the camera MuJoCo renders for ``<camera fovy=...>``.
        """
        if not (0.0 < fovy < math.pi):
            raise ValueError(f"fovy must be in (0, π) rad, got {fovy}")
        fy = 0.5 * height / math.tan(0.5 * fovy)
        return cls(width, height, fy, fy, 0.5 * width, 0.5 * height)

    @classmethod
    def from_K(cls, K: ArrayLike, width: int, height: int) -> Intrinsics:
        """Intrinsics from a (3, 3) camera matrix ``K`` (px) and the image size (px)."""
        K_arr = np.asarray(K, dtype=float)
        if K_arr.shape != (3, 3) or not np.all(np.isfinite(K_arr)):
            raise ValueError("K must be a finite (3, 3) matrix")
        if not np.allclose(K_arr[2], [0.0, 0.0, 1.0]) or K_arr[1, 0] != 0 or K_arr[0, 1] != 0:
            raise ValueError("K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)")
        return cls(width, height, K_arr[0, 0], K_arr[1, 1], K_arr[0, 2], K_arr[1, 2])

    @property
    def K(self) -> FloatArray:
        """Camera matrix (3, 3), px."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def fovy(self) -> float:
        """Vertical field of view, rad."""
        return 2.0 * math.atan(0.5 * self.height / self.fy)

    @property
    def principal_point(self) -> FloatArray:
        """(2,) principal point (cx, cy), px."""
        return np.array([self.cx, self.cy])


@dataclass(frozen=True)
class StereoCamera:
    """A stereo pair: shared intrinsics and a baseline along the camera frame's x axis.

    Attributes
    ----------
    intrinsics : Intrinsics
        Intrinsics of each eye (identical eyes).
    baseline : float
        Distance between the eyes' optical centres, m (≥ 0).
    """

    intrinsics: Intrinsics = field(
        default_factory=lambda: Intrinsics.from_fovy(
            DEFAULT_WIDTH_PX, DEFAULT_HEIGHT_PX, DEFAULT_FOVY
        )
    )
    baseline: float = DEFAULT_BASELINE

    def __post_init__(self) -> None:
        if not math.isfinite(self.baseline) or self.baseline < 0:
            raise ValueError(f"baseline must be finite and ≥ 0 m, got {self.baseline}")

    @property
    def T_cam_left(self) -> FloatArray:
        """(4, 4) pose of the left eye in the camera (centre) frame: −baseline/2 along x."""
        return make_pose(np.eye(3), [-0.5 * self.baseline, 0.0, 0.0])

    @property
    def T_cam_right(self) -> FloatArray:
        """(4, 4) pose of the right eye in the camera (centre) frame: +baseline/2 along x."""
        return make_pose(np.eye(3), [0.5 * self.baseline, 0.0, 0.0])

    def T_cam_eye(self, eye: Eye) -> FloatArray:
        """(4, 4) pose of ``eye`` ("left" or "right") in the camera frame."""
        if eye == "left":
            return self.T_cam_left
        if eye == "right":
            return self.T_cam_right
        raise ValueError(f"eye must be 'left' or 'right', got {eye!r}")

    def project(
        self, T_world_cam: FloatArray, p_world: FloatArray, eye: Eye = "left"
    ) -> FloatArray:
        """Project world points into ``eye``'s image.

        Parameters
        ----------
        T_world_cam : (4, 4)
            Camera (centre, optical frame) pose in world, m.
        p_world : (N, 3) or (3,)
            Points in world, m.
        eye : {"left", "right"}

        Returns
        -------
        (N, 2) or (2,)
            Pixel coordinates (u, v), px; NaN for points closer than ``MIN_DEPTH`` to the eye's
            image plane or behind it.
        """
        p = np.asarray(p_world, dtype=float)
        single = p.ndim == 1
        p2 = np.atleast_2d(p)
        T = np.broadcast_to(np.asarray(T_world_cam, dtype=float), (p2.shape[0], 4, 4))
        du, dv, _ = pixel_offsets(self, T, p2, eye)
        k = self.intrinsics
        uv = np.stack([k.cx + du, k.cy + dv], axis=1)
        return uv[0] if single else uv

    def in_image(
        self, T_world_cam: FloatArray, p_world: FloatArray, eye: Eye = "left"
    ) -> np.ndarray:
        """Whether world points (N, 3) or (3,), m, project inside ``eye``'s image: (N,) or ()."""
        uv = self.project(T_world_cam, p_world, eye)
        return inside_image(self.intrinsics, uv[..., 0], uv[..., 1])


def points_in_eye(
    camera: StereoCamera, T_world_cam: FloatArray, p_world: FloatArray, eye: Eye = "left"
) -> FloatArray:
    """World points in an eye's optical frame: the one world → eye transform of the package.

    Parameters
    ----------
    camera : StereoCamera
    T_world_cam : (N, 4, 4) or (4, 4)
        Camera (centre, optical frame) poses in world, m.
    p_world : (N, 3) or (3,)
        One point per pose, world, m.
    eye : {"left", "right"}

    Returns
    -------
    (N, 3)
        ``p_eye = R_world_eye^T (p_world − t_world_eye)``, m.
    """
    T = np.asarray(T_world_cam, dtype=float)
    if T.shape == (4, 4):
        T = T[None]
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise ValueError(f"T_world_cam must have shape (4, 4) or (N, 4, 4), got {T.shape}")
    p = np.asarray(p_world, dtype=float).reshape(-1, 3)
    T_world_eye = T @ camera.T_cam_eye(eye)
    d = p - T_world_eye[:, :3, 3]
    return np.asarray(np.einsum("nji,nj->ni", T_world_eye[:, :3, :3], d))  # R^T (p - t)


def pixel_offsets(
    camera: StereoCamera, T_world_cam: FloatArray, p_world: FloatArray, eye: Eye = "left"
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Pinhole image offsets of points from an eye's principal point, and their depths.

    Parameters
    ----------
    camera : StereoCamera
    T_world_cam : (N, 4, 4) or (4, 4)
        Camera poses, world, m.
    p_world : (N, 3) or (3,)
        One point per pose, world, m.
    eye : {"left", "right"}

    Returns
    -------
    du, dv : (N,)
        ``f_x x / z`` and ``f_y y / z``, px; NaN where ``z < MIN_DEPTH`` (the one depth
        threshold: a point closer to the image plane, or behind it, has no image).
    z : (N,)
        Depth along the optical axis, m.
    """
    p_eye = points_in_eye(camera, T_world_cam, p_world, eye)
    k = camera.intrinsics
    z = p_eye[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        du = k.fx * p_eye[:, 0] / z
        dv = k.fy * p_eye[:, 1] / z
    behind = ~(z >= MIN_DEPTH)
    du[behind] = np.nan
    dv[behind] = np.nan
    return du, dv, z


def inside_image(intrinsics: Intrinsics, u: FloatArray, v: FloatArray) -> np.ndarray:
    """The one image-edge rule: ``0 ≤ u < width`` and ``0 ≤ v < height`` (px); NaN is outside."""
    with np.errstate(invalid="ignore"):
        return np.asarray(
            (u >= 0.0) & (u < intrinsics.width) & (v >= 0.0) & (v < intrinsics.height)
        )
