"""Tracking metrics of the paper (Sec. IV-C), vectorised over time.

* image centring error: pixel distance of the projected ring centre from the left eye's principal
  point (raw per frame: NaN behind the camera, unbounded near its image plane; summaries use
  :func:`saturate_image_error`, which counts a ring outside the image as the image's largest
  error);
* 3D centring error: distance from the ring centre to the camera's optical axis (the line through
  the camera centre along its z axis);
* orientation error: the acute angle between the optical axis and the ring normal (the ring
  normal has no preferred sign, so the angle is in [0, π/2]).

Everything is SI here; :func:`summarize` converts to the px / mm / deg reported to people.
"""

from __future__ import annotations

import math

import numpy as np

from endocam.camera import StereoCamera, inside_image, pixel_offsets
from endocam.geometry import FloatArray


def _stack(T: FloatArray, name: str) -> FloatArray:
    arr = np.asarray(T, dtype=float)
    if arr.shape == (4, 4):
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[1:] != (4, 4):
        raise ValueError(f"{name} must have shape (4, 4) or (N, 4, 4), got {arr.shape}")
    return arr


def image_centering_error(
    camera: StereoCamera, T_world_cam: FloatArray, p_world_ring: FloatArray
) -> FloatArray:
    """Pixel distance of the ring centre from the left eye's principal point.

    Parameters
    ----------
    camera : StereoCamera
    T_world_cam : (N, 4, 4) or (4, 4)
        Camera poses (optical frame) in world, m.
    p_world_ring : (N, 3) or (3,)
        Ring centres in world, m.

    Returns
    -------
    (N,)
        Error, px; NaN where the ring centre is closer than ``MIN_DEPTH`` to the left eye's
        image plane.
    """
    du, dv, _ = pixel_offsets(camera, _stack(T_world_cam, "T_world_cam"), p_world_ring)
    return np.asarray(np.hypot(du, dv))


def image_error_bound(camera: StereoCamera) -> float:
    """The largest in-image centring error: principal point to the farthest image corner, px."""
    k = camera.intrinsics
    return math.hypot(max(k.cx, k.width - k.cx), max(k.cy, k.height - k.cy))


def ring_out_of_view(
    camera: StereoCamera, T_world_cam: FloatArray, p_world_ring: FloatArray
) -> FloatArray:
    """Whether the ring centre is outside the left eye's image (or at or behind its plane).

    Parameters
    ----------
    camera : StereoCamera
    T_world_cam : (N, 4, 4) or (4, 4)
        Camera poses (optical frame) in world, m.
    p_world_ring : (N, 3) or (3,)
        Ring centres in world, m.

    Returns
    -------
    (N,) bool
    """
    du, dv, _ = pixel_offsets(camera, _stack(T_world_cam, "T_world_cam"), p_world_ring)
    k = camera.intrinsics
    return np.asarray(~inside_image(k, k.cx + du, k.cy + dv))


def saturate_image_error(
    camera: StereoCamera, error_px: FloatArray, out_of_view: FloatArray | None = None
) -> FloatArray:
    """Image centring errors (N,) with a ring out of view counted as :func:`image_error_bound`.

    A ring centre outside the image (``out_of_view``, from :func:`ring_out_of_view`), behind
    the camera (NaN) or projecting beyond the farthest image corner gets the bound, so a lost
    ring weighs as the worst in-view error: a mean over the episode neither skips it (NaN) nor
    explodes (a ring near the image plane projects to any number).

    Parameters
    ----------
    camera : StereoCamera
    error_px : (N,)
        Raw errors from :func:`image_centering_error`, px.
    out_of_view : (N,) bool, optional
        Steps whose ring centre is outside the image.

    Returns
    -------
    (N,)
        Errors in ``[0, bound]``, px.
    """
    bound = image_error_bound(camera)
    err = np.asarray(error_px, dtype=float)
    lost = ~(np.isfinite(err) & (err < bound))
    if out_of_view is not None:
        lost |= np.asarray(out_of_view, dtype=bool)
    return np.where(lost, bound, err)


def center_error_3d(T_world_cam: FloatArray, p_world_ring: FloatArray) -> FloatArray:
    """Distance from the ring centre to the camera's optical axis (a line), m.

    Parameters
    ----------
    T_world_cam : (N, 4, 4) or (4, 4)
        Camera poses (optical frame) in world, m.
    p_world_ring : (N, 3) or (3,)
        Ring centres in world, m.

    Returns
    -------
    (N,)
        Distance, m.
    """
    T = _stack(T_world_cam, "T_world_cam")
    p = np.asarray(p_world_ring, dtype=float).reshape(-1, 3)
    d = p - T[:, :3, 3]
    z = T[:, :3, 2]
    along = np.einsum("ni,ni->n", d, z)
    return np.asarray(np.linalg.norm(d - along[:, None] * z, axis=1))


def orientation_error(T_world_cam: FloatArray, n_world_ring: FloatArray) -> FloatArray:
    """Acute angle between the optical axis and the ring normal, rad, in [0, π/2].

    Parameters
    ----------
    T_world_cam : (N, 4, 4) or (4, 4)
        Camera poses (optical frame) in world.
    n_world_ring : (N, 3) or (3,)
        Ring face normals in world (any non-zero length, either sign).

    Returns
    -------
    (N,)
        Angle, rad.
    """
    T = _stack(T_world_cam, "T_world_cam")
    n = np.asarray(n_world_ring, dtype=float).reshape(-1, 3)
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    z = T[:, :3, 2]
    cos = np.abs(np.einsum("ni,ni->n", z, n))
    sin = np.linalg.norm(np.cross(z, n), axis=1)
    return np.asarray(np.arctan2(sin, cos))


def summarize(values: FloatArray, scale: float = 1.0) -> dict[str, float | int]:
    """Mean, 95th percentile and maximum of finite values, times ``scale`` (the unit change).

    Parameters
    ----------
    values : (N,)
        Samples in SI (NaN marks samples where the metric is undefined).
    scale : float
        Multiplier to the reported unit, e.g. 1e3 for m → mm.

    Returns
    -------
    dict
        ``{"mean", "p95", "max", "n", "n_undefined"}``; statistics are NaN if no sample is finite.
    """
    v = np.asarray(values, dtype=float)
    ok = np.isfinite(v)
    n_bad = int((~ok).sum())
    if not ok.any():
        nan = math.nan
        return {"mean": nan, "p95": nan, "max": nan, "n": 0, "n_undefined": n_bad}
    good = v[ok] * scale
    return {
        "mean": float(good.mean()),
        "p95": float(np.percentile(good, 95)),
        "max": float(good.max()),
        "n": int(ok.sum()),
        "n_undefined": n_bad,
    }
