"""Perception: the ring's pose from the stereo endoscope's images, and how those images degrade.

- :mod:`~endocam.perception.segment`: the ring and wire colour segmentation (one
  implementation, shared with the study's video observer);
- :mod:`~endocam.perception.ellipse`: the rim's ellipse in one image, a circle's pose from it;
- :mod:`~endocam.perception.estimator`: :func:`estimate_ring_pose`, the stereo pose estimator;
- :mod:`~endocam.perception.image_model`: sensor noise, motion blur, specular highlights and
  brightness changes, seeded pure functions on images.

Method, failure modes and measured accuracy: docs/perception.md.
"""

from endocam.perception.estimator import (
    EstimateResult,
    EstimateStatus,
    EstimatorConfig,
    RingEstimate,
    RingModel,
    estimate_ring_detail,
    estimate_ring_pose,
)
from endocam.perception.segment import ColourKeys, segment

__all__ = [
    "ColourKeys",
    "EstimateResult",
    "EstimateStatus",
    "EstimatorConfig",
    "RingEstimate",
    "RingModel",
    "estimate_ring_detail",
    "estimate_ring_pose",
    "segment",
]
