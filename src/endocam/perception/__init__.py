"""Perception: the ring's pose from the stereo endoscope's images, and how those images degrade.

- :mod:`~endocam.perception.segment`: the ring and wire colour segmentation (one
  implementation, shared with the study's video observer);
- :mod:`~endocam.perception.ellipse`: the rim's ellipse in one image, a circle's pose from it;
- :mod:`~endocam.perception.estimator`: :func:`estimate_ring_pose`, the stereo pose estimator;
- :mod:`~endocam.perception.image_model`: sensor noise, motion blur, specular highlights and
  brightness changes, seeded pure functions on images;
- :mod:`~endocam.perception.track`: the track filter between the estimator and the
  controller (centre gains by depth, the step the gate accepts), no OpenCV;
- :mod:`~endocam.perception.loop`: the control loop on perception (``PerceptionConfig``, the
  capture schedule, the estimates' log and errors), no OpenCV.

The names below load their module (and OpenCV) on first use, so ``endocam.config``, which
holds ``PerceptionConfig``, does not import OpenCV. Method, failure modes and measured
accuracy: docs/perception.md.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
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

_HOME = {
    "ColourKeys": "endocam.perception.segment",
    "EstimateResult": "endocam.perception.estimator",
    "EstimateStatus": "endocam.perception.estimator",
    "EstimatorConfig": "endocam.perception.estimator",
    "RingEstimate": "endocam.perception.estimator",
    "RingModel": "endocam.perception.estimator",
    "estimate_ring_detail": "endocam.perception.estimator",
    "estimate_ring_pose": "endocam.perception.estimator",
    "segment": "endocam.perception.segment",
}

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


def __getattr__(name: str) -> Any:
    """Load ``name`` from its module on first use (PEP 562)."""
    home = _HOME.get(name)
    if home is None:
        raise AttributeError(f"module 'endocam.perception' has no attribute {name!r}")
    return getattr(importlib.import_module(home), name)
