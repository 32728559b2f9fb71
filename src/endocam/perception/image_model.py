"""Images as a real endoscope gives them: motion blur, brightness, specular highlights, noise.

Seeded pure functions on (H, W, 3) uint8 RGB images; nothing here changes the study videos
unless a caller applies it. :func:`degrade` applies, in the order light meets the sensor:

1. **motion blur** (:func:`motion_blur`): the image smeared along the ring's image velocity over
   the exposure (a line kernel ``|v| · exposure`` long);
2. **brightness** (:func:`scale_brightness`): one gain drawn per frame (auto-exposure and light
   source changes);
3. **specular highlights** (:func:`add_highlights`): saturated white blobs with a Gaussian
   falloff, at given candidate sites (e.g. on the ring's rim: wet, shiny surfaces) or anywhere;
4. **sensor noise** (:func:`add_noise`): shot noise (variance ∝ signal) plus read noise, then
   rounding to 8 bits.

The defaults (:class:`ImageModelConfig`) and where each comes from are in docs/perception.md
("The image model"); none was measured on a real endoscope, and each is stated as such.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

FULL_SCALE_DN = 255.0  # DN, 8-bit full scale


@dataclass(frozen=True)
class ImageModelConfig:
    """What :func:`degrade` does to an image (defaults: docs/perception.md, "The image model").

    Attributes
    ----------
    exposure : float
        Exposure time, s (≥ 0): the motion blur is the image velocity times this.
    gain_range : (2,) float
        A per-frame brightness gain is drawn uniformly from this range (unitless, > 0).
    highlight_rate : float
        Mean number of specular highlights per frame (Poisson, ≥ 0).
    highlight_radius_px : (2,) float
        Highlight radii (Gaussian sigma) drawn uniformly from this range, px (> 0).
    read_noise_dn : float
        Read-noise standard deviation, DN (8-bit, ≥ 0).
    shot_noise_dn : float
        Shot-noise standard deviation at full scale, DN (≥ 0); it scales as √signal.
    """

    exposure: float = 1.0 / 60.0
    gain_range: tuple[float, float] = (0.75, 1.25)
    highlight_rate: float = 3.0
    highlight_radius_px: tuple[float, float] = (1.5, 4.0)
    read_noise_dn: float = 2.0
    shot_noise_dn: float = 4.0

    def __post_init__(self) -> None:
        for name in ("exposure", "highlight_rate", "read_noise_dn", "shot_noise_dn"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be finite and ≥ 0, got {value}")
        for name in ("gain_range", "highlight_radius_px"):
            lo, hi = getattr(self, name)
            if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 < lo <= hi):
                raise ValueError(f"{name} must be 0 < low ≤ high, got {(lo, hi)}")


def _check_image(image: NDArray[np.uint8]) -> NDArray[np.uint8]:
    a = np.asarray(image)
    if a.ndim != 3 or a.shape[2] != 3 or a.dtype != np.uint8:
        raise ValueError(f"image must be an (H, W, 3) uint8 RGB array, got {a.shape} {a.dtype}")
    return a


def motion_blur(image: NDArray[np.uint8], blur_px: ArrayLike) -> NDArray[np.uint8]:
    """``image`` (H, W, 3) uint8 smeared along ``blur_px`` (2,) = (du, dv), px, centred.

    A box kernel along the segment (anti-aliased line of length ``|blur_px|``); under one pixel
    returns a copy. A blur longer than the image's diagonal is shortened to it (a longer one
    smears the image no more, and its square kernel would grow without bound).
    """
    img = _check_image(image)
    d = np.asarray(blur_px, dtype=float).reshape(2)
    if not np.all(np.isfinite(d)):
        raise ValueError(f"blur_px must be finite, got {d}")
    length = float(np.hypot(*d))
    diagonal = float(np.hypot(*img.shape[:2]))
    if length > diagonal:
        d, length = d * (diagonal / length), diagonal
    if length < 1.0:
        return img.copy()
    half = math.ceil(0.5 * length) + 1
    size = 2 * half + 1
    kernel = np.zeros((size, size), dtype=np.float32)
    shift = 4  # sub-pixel line end points (cv2.line's fixed-point shift)
    scale = 1 << shift
    a = np.round((half - 0.5 * d) * scale).astype(int)
    b = np.round((half + 0.5 * d) * scale).astype(int)
    cv2.line(kernel, (int(a[0]), int(a[1])), (int(b[0]), int(b[1])), 1.0, 1, cv2.LINE_AA, shift)
    kernel /= kernel.sum()
    return np.asarray(cv2.filter2D(img, -1, kernel, borderType=cv2.BORDER_REFLECT))


def scale_brightness(image: NDArray[np.uint8], gain: float) -> NDArray[np.uint8]:
    """``image`` (H, W, 3) uint8 times ``gain`` (> 0), saturating at 255."""
    img = _check_image(image)
    if not (math.isfinite(gain) and gain > 0.0):
        raise ValueError(f"gain must be finite and > 0, got {gain}")
    return np.asarray(cv2.convertScaleAbs(img, alpha=gain))


def add_highlights(
    image: NDArray[np.uint8], centres_px: ArrayLike, radii_px: ArrayLike
) -> NDArray[np.uint8]:
    """Specular highlights: white blobs blended over ``image`` (H, W, 3) uint8.

    ``centres_px`` : (N, 2) (u, v), px; ``radii_px`` : (N,) Gaussian sigmas, px. Each blob's
    weight is ``exp(−r² / 2σ²)`` (1 at its centre: saturated white there).
    """
    img = _check_image(image)
    c = np.asarray(centres_px, dtype=float).reshape(-1, 2)
    s = np.asarray(radii_px, dtype=float).reshape(-1)
    if len(c) != len(s) or not (np.all(np.isfinite(c)) and np.all(s > 0.0)):
        raise ValueError("centres_px (N, 2) and radii_px (N,) must match, finite, radii > 0")
    h, w = img.shape[:2]
    out = img.astype(np.float32)
    for (u, v), sigma in zip(c, s, strict=True):
        r = math.ceil(3.0 * sigma)
        u0, u1 = max(int(u) - r, 0), min(int(u) + r + 1, w)
        v0, v1 = max(int(v) - r, 0), min(int(v) + r + 1, h)
        if u0 >= u1 or v0 >= v1:
            continue
        uu, vv = np.meshgrid(np.arange(u0, u1), np.arange(v0, v1))
        wgt = np.exp(-((uu - u) ** 2 + (vv - v) ** 2) / (2.0 * sigma**2))[..., None]
        patch = out[v0:v1, u0:u1]
        out[v0:v1, u0:u1] = patch + wgt * (FULL_SCALE_DN - patch)
    return np.asarray(np.clip(np.round(out), 0, 255), dtype=np.uint8)


def add_noise(
    image: NDArray[np.uint8], read_noise_dn: float, shot_noise_dn: float, rng: np.random.Generator
) -> NDArray[np.uint8]:
    """Sensor noise on ``image`` (H, W, 3) uint8: Gaussian, σ² = read² + shot² · signal / 255.

    ``read_noise_dn``, ``shot_noise_dn`` : DN (≥ 0; the shot noise's σ at full scale).
    """
    img = _check_image(image)
    x = img.astype(np.float32)
    sigma = np.sqrt(read_noise_dn**2 + shot_noise_dn**2 * x / FULL_SCALE_DN)
    x += sigma * rng.standard_normal(x.shape, dtype=np.float32)
    return np.asarray(np.clip(np.round(x), 0, 255), dtype=np.uint8)


def degrade(
    image: NDArray[np.uint8],
    config: ImageModelConfig,
    rng: np.random.Generator,
    velocity_px_s: ArrayLike = (0.0, 0.0),
    sites_px: ArrayLike | None = None,
) -> NDArray[np.uint8]:
    """One frame through the image model (see the module docstring for the order).

    Parameters
    ----------
    image : (H, W, 3) uint8
        A rendered RGB image.
    config : ImageModelConfig
    rng : numpy.random.Generator
        The frame's draws (gain, highlights, noise); seed it per frame for repeatable frames.
    velocity_px_s : (2,)
        The image velocity of what the image is about (the ring, from the camera's and the
        ring's motion), px/s; the blur is this times ``config.exposure``.
    sites_px : (M, 2) or None
        Candidate highlight centres (u, v), px, e.g. the ring's projected rim; None: anywhere.

    Returns
    -------
    (H, W, 3) uint8
    """
    img = _check_image(image)
    h, w = img.shape[:2]
    out = motion_blur(img, np.asarray(velocity_px_s, dtype=float) * config.exposure)
    out = scale_brightness(out, float(rng.uniform(*config.gain_range)))
    n = int(rng.poisson(config.highlight_rate))
    if n:
        if sites_px is None or len(np.asarray(sites_px)) == 0:
            centres = rng.uniform((0.0, 0.0), (w, h), size=(n, 2))
        else:
            sites = np.asarray(sites_px, dtype=float).reshape(-1, 2)
            centres = sites[rng.integers(0, len(sites), size=n)]
        out = add_highlights(out, centres, rng.uniform(*config.highlight_radius_px, size=n))
    return add_noise(out, config.read_noise_dn, config.shot_noise_dn, rng)
