"""Colour segmentation of the ring and the wire: the one implementation.

The study's video observer (:mod:`endocam.study.observer_frame`) and the stereo pose estimator
(:mod:`endocam.perception.estimator`) both call :func:`segment`. What it knows, as a participant
told about the task does: the colours of the ring and of the wire ("the orange ring, the blue
wire"), as OpenCV hues.

A pixel belongs to an object when, in OpenCV's 8-bit HSV (hue 0..180 ↔ 0..360°), its hue lies
within ``HUE_TOL`` of the object's hue (circularly), its saturation is at least ``SAT_MIN`` and its
value at least ``VAL_MIN``; ring components of fewer than ``MIN_RING_PX`` pixels are dropped.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from endocam.task.config import RGBA, SceneConfig

__all__ = [
    "HUE_TOL",
    "MIN_RING_PX",
    "SAT_MIN",
    "VAL_MIN",
    "ColourKeys",
    "hue_mask",
    "hue_of",
    "segment",
]

HUE_TOL = 12  # OpenCV hue units (0..180 ↔ 0..360°): ±24° around the object's hue
SAT_MIN = 110  # 8-bit saturation: the ring and the wire are saturated, board and walls are not
VAL_MIN = 35  # 8-bit value: darker pixels carry no reliable hue
MIN_RING_PX = 12  # px, smaller orange components are noise (or a ring too small to judge)
HUE_RANGE = 180  # OpenCV's 8-bit hue runs over 0..179


@dataclass(frozen=True)
class ColourKeys:
    """What the observer knows: the hues of the ring and of the wire (OpenCV units, 0..180)."""

    ring_hue: int
    wire_hue: int

    @classmethod
    def from_rgba(cls, ring_rgba: RGBA, wire_rgba: RGBA) -> ColourKeys:
        """Keys from the scene's RGBA colours (components 0..1)."""
        return cls(ring_hue=hue_of(ring_rgba), wire_hue=hue_of(wire_rgba))

    @classmethod
    def from_scene(cls, scene: SceneConfig) -> ColourKeys:
        """Keys of a scene config's ring and wire."""
        return cls.from_rgba(scene.ring_rgba, scene.wire_rgba)


def hue_of(rgba: RGBA) -> int:
    """OpenCV hue (0..180) of an RGBA colour (components 0..1)."""
    rgb = np.clip(np.round(np.asarray(rgba[:3]) * 255.0), 0, 255).astype(np.uint8)
    return int(cv2.cvtColor(rgb.reshape(1, 1, 3), cv2.COLOR_RGB2HSV)[0, 0, 0])


def hue_mask(hsv: NDArray[Any], hue: int) -> NDArray[np.bool_]:
    """Pixels of an (H, W, 3) uint8 OpenCV HSV image within ``HUE_TOL`` of ``hue``: (H, W) bool.

    Saturation ≥ ``SAT_MIN`` and value ≥ ``VAL_MIN`` too. The hue distance is circular
    (``min(|h − hue|, 180 − |h − hue|)``); ``cv2.inRange`` on one or two hue intervals computes
    it several times faster than array arithmetic, with the same integer comparisons.
    """
    lo, hi = hue - HUE_TOL, hue + HUE_TOL
    intervals = [(max(lo, 0), min(hi, HUE_RANGE - 1))]
    if lo < 0:
        intervals.append((lo + HUE_RANGE, HUE_RANGE - 1))
    if hi > HUE_RANGE - 1:
        intervals.append((0, hi - HUE_RANGE))
    masks = [cv2.inRange(hsv, (a, SAT_MIN, VAL_MIN), (b, 255, 255)) for a, b in intervals]
    mask = masks[0] if len(masks) == 1 else cv2.bitwise_or(masks[0], masks[1])
    return np.asarray(mask > 0)


def segment(
    frame_rgb: NDArray[np.uint8], keys: ColourKeys
) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Ring and wire masks of one frame.

    Parameters
    ----------
    frame_rgb : (H, W, 3) uint8
        RGB image.
    keys : ColourKeys

    Returns
    -------
    ring, wire : (H, W) bool
        Ring pixels (components of at least ``MIN_RING_PX``) and wire pixels.
    """
    hsv = cv2.cvtColor(np.ascontiguousarray(frame_rgb), cv2.COLOR_RGB2HSV)
    ring = hue_mask(hsv, keys.ring_hue)
    wire = hue_mask(hsv, keys.wire_hue)
    x, y, w, h = cv2.boundingRect(ring.view(np.uint8))  # label only where the ring can be
    if w == 0 or h == 0:  # no ring-hued pixel (OpenCV must not label an empty array)
        return ring, wire
    roi = ring[y : y + h, x : x + w]
    n, labels, stats, _ = cv2.connectedComponentsWithStats(
        np.ascontiguousarray(roi).view(np.uint8), connectivity=8
    )
    keep = np.zeros(n, dtype=bool)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= MIN_RING_PX
    roi[...] = keep[labels]
    return ring, wire
