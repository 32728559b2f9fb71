"""The ring's pose from one eye, when the other's view of the rim is hidden.

A wire or an instrument in front of one eye's view of the ring (the eyes are 5 mm apart, and
the wire a few millimetres from the lens hides the ring from one and not the other) left the
stereo estimator without a pose, and the controller held: for up to 4 s on the PSM's
``ideal-36``, while the other eye saw the whole rim (round 15, docs/perception.md). One eye
still gives the pose of a circle of known radius, up to the circle's two-fold choice of
normal: the core's conic gives both normals (:func:`~endocam.perception.ellipse.circle_normals`),
its radius over its distance (:func:`~endocam.perception.ellipse.radius_over_distance`) gives
the distance from the known ``R``, and the centre lies on the ray ``Q⁻¹ n``. The choice is
left to a prior normal (the track's), which one eye cannot replace: without a prior, or when
the prior does not single out one hypothesis, there is no pose.

Pure functions on arrays; the eye's own optical frame, m.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from endocam.geometry import FloatArray
from endocam.perception.ellipse import (
    ImageEllipse,
    centre_image,
    circle_normals,
    core_ellipse,
    normalised_conic,
    radius_over_distance,
)

__all__ = ["PriorChoice", "mono_pose"]


class PriorChoice(NamedTuple):
    """How a prior normal picks one of a circle's two normals.

    Attributes
    ----------
    fraction : float
        The nearer hypothesis must lie within this fraction of the hypotheses' separation of
        the prior (so the other lies at least ``1 − fraction`` of it away), in (0, 0.5).
    close : float
        rad: hypotheses closer together than this are both near the truth; the nearer is taken.
    """

    fraction: float
    close: float


def _pose_from_core(
    Q: FloatArray, R: float, prior: FloatArray, choice: PriorChoice
) -> tuple[FloatArray, FloatArray] | None:
    """Centre (3,), m, and unit normal (3,) of the circle of radius ``R`` imaged as ``Q``.

    The normal is the hypothesis ``choice`` takes for ``prior`` (3,), up to sign; None when it
    takes neither or when ``Q`` is not an ellipse's cone.
    """
    cands = circle_normals(Q)
    ratio = radius_over_distance(Q)
    if cands is None or not ratio > 0.0:
        return None
    off = [math.acos(min(1.0, abs(float(c @ prior)))) for c in cands]
    apart = math.acos(min(1.0, abs(float(cands[0] @ cands[1]))))
    near = int(np.argmin(off))
    if apart > choice.close and off[near] > choice.fraction * apart:
        return None
    n = cands[near]
    xy = centre_image(Q, n)
    if xy is None:
        return None
    ray = np.array([xy[0], xy[1], 1.0])
    along = float(n @ ray)
    if not along < 0.0:  # n faces the eye: the plane n · X = −d lies in front of it
        return None
    p = ray * (R / ratio) / -along
    return np.asarray(p), np.asarray(n)


def mono_pose(
    fit: ImageEllipse,
    K: FloatArray,
    radii: tuple[float, float],
    prior: FloatArray,
    choice: PriorChoice,
) -> tuple[FloatArray, FloatArray] | None:
    """The ring's centre and normal in one eye's frame from its rim fit, or None.

    Parameters
    ----------
    fit : ImageEllipse
        The eye's outer-silhouette fit with its points, px.
    K : (3, 3)
        The eye's intrinsics.
    radii : (R, r)
        The ring's core and tube radii, m.
    prior : (3,)
        The normal the ring is expected to have, unit, this eye's frame (the sign is free).
    choice : PriorChoice
        How the prior picks one of the two normals (each pass; None if it picks neither).

    Returns
    -------
    (p, n) or None
        Centre (3,), m, and unit normal (3,) facing the eye; first from the outline less the
        tube's image width at the outline's own distance, then once more from the core by
        perspective (:func:`~endocam.perception.ellipse.core_ellipse`).
    """
    R, r = radii
    outer = normalised_conic(fit, K)
    ratio = radius_over_distance(outer)
    if not ratio > 0.0:
        return None
    z = (R + r) / ratio  # m: the outline is about the circle of radius R + r
    if not K[0, 0] * r / z < fit.b:
        return None
    first = _pose_from_core(normalised_conic(fit.shrunk(K[0, 0] * r / z), K), R, prior, choice)
    if first is None:
        return None
    core = core_ellipse(fit, K, r, *first)
    if core is None:
        return first
    return _pose_from_core(normalised_conic(core, K), R, prior, choice) or first
