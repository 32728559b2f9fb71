"""Compiled: the weighted share of gap points each candidate eye sees, clear and resolved.

The loop of :func:`endocam.control.occlusion.view_scores` (numpy, the reference it is pinned
to by ``tests/test_visible.py``) for the ``endocam-visible`` camera: for every eye and every
gap point, the sight line (stopped ``tolerance`` short of the point) is tested against the
occluding capsules (the wire's segments near the ring, the ring's handle) and the ring's rim
(a torus, sampled along the line inside the ring's bounding sphere), and the image length of
the gap there against the pixels it needs. Early exits make a blocked line cheap.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit
from numba.extending import register_jitable

from endocam.geometry import FloatArray
from endocam.workspace.cone import Cone, cone_margin
from endocam.workspace.keepout import KeepOutState, keep_out_nearest

__all__ = ["Occluders", "Sight", "segment_distance", "view_shares", "views_clear"]

_EPS = 1e-12  # m or unitless: below this a length or a direction is degenerate
RIM_COARSE = 5  # count: the rim test tries every RIM_COARSE-th sample first
RIM_HALF = RIM_COARSE // 2 + 1  # count: samples a coarse one answers for, either side


class Occluders(NamedTuple):
    """What may hide a gap point (world, m).

    Attributes
    ----------
    seg_a, seg_b : (S, 3)
        Capsule axes' ends: the wire's segments near the ring, then the handle.
    seg_r : (S,)
        Their radii, m.
    centre, normal : (3,)
        The ring's centre and unit face normal.
    major, minor : float
        The ring's core-circle and tube radii, m.
    rim_step : float
        Spacing of the samples along a sight line tested against the rim, m.
    """

    seg_a: FloatArray
    seg_b: FloatArray
    seg_r: FloatArray
    centre: FloatArray
    normal: FloatArray
    major: float
    minor: float
    rim_step: float


class Sight(NamedTuple):
    """What counts as seeing a gap point.

    Attributes
    ----------
    points, directions : (M, 3)
        Gap points (world, m) and their unit gap directions.
    weights : (M,)
        Their weights (≥ 0; normalised by their sum).
    tolerance : float
        How far short of the point a sight line stops, m (the ray cast's allowance).
    gap : float
        The gap whose image length is measured, m.
    focal_px : float
        Focal length, px.
    resolved_px : float
        The image length the gap needs, px.
    """

    points: FloatArray
    directions: FloatArray
    weights: FloatArray
    tolerance: float
    gap: float
    focal_px: float
    resolved_px: float


@register_jitable  # also callable from compiled kernels (the same source)
def segment_distance(
    a: FloatArray, b: FloatArray, p: FloatArray, q: FloatArray
) -> float:  # pragma: no cover - compiled
    """Distance between segments ``a→b`` and ``p→q`` ((3,) each), m (Ericson 5.1.9)."""
    d1x, d1y, d1z = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    d2x, d2y, d2z = q[0] - p[0], q[1] - p[1], q[2] - p[2]
    rx, ry, rz = a[0] - p[0], a[1] - p[1], a[2] - p[2]
    aa = d1x * d1x + d1y * d1y + d1z * d1z
    ee = d2x * d2x + d2y * d2y + d2z * d2z
    bb = d1x * d2x + d1y * d2y + d1z * d2z
    cc = d1x * rx + d1y * ry + d1z * rz
    ff = d2x * rx + d2y * ry + d2z * rz
    denom = aa * ee - bb * bb
    s = 0.0
    if denom > _EPS * max(aa * ee, _EPS):
        s = min(max((bb * ff - cc * ee) / denom, 0.0), 1.0)
    t = (bb * s + ff) / max(ee, _EPS)
    if t < 0.0 or ee <= _EPS:  # (a zero-length p→q: its point)
        t = 0.0
        s = min(max(-cc / max(aa, _EPS), 0.0), 1.0)
    elif t > 1.0:
        t = 1.0
        s = min(max((bb - cc) / max(aa, _EPS), 0.0), 1.0)
    gx = rx + s * d1x - t * d2x
    gy = ry + s * d1y - t * d2y
    gz = rz + s * d1z - t * d2z
    return math.sqrt(gx * gx + gy * gy + gz * gz)


@register_jitable  # also callable from compiled kernels (the same source)
def _rim_distance(
    wx: float, wy: float, wz: float, dx: float, dy: float, dz: float, t: float, occ: Occluders
) -> float:  # pragma: no cover - compiled
    """Distance from ``w + t d`` (relative to the ring's centre, m) to the core circle, m."""
    n = occ.normal
    x, y, z = wx + t * dx, wy + t * dy, wz + t * dz
    h = x * n[0] + y * n[1] + z * n[2]
    px, py, pz = x - h * n[0], y - h * n[1], z - h * n[2]
    return math.hypot(math.sqrt(px * px + py * py + pz * pz) - occ.major, h)


@register_jitable  # also callable from compiled kernels (the same source)
def _through_rim(a: FloatArray, b: FloatArray, occ: Occluders) -> bool:  # pragma: no cover
    """Whether the segment ``a→b`` passes within ``minor`` of the ring's core circle.

    Sampled every ``rim_step`` (at most) along its chord inside the ring's bounding sphere.
    """
    c = occ.centre
    dx, dy, dz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    dd = max(dx * dx + dy * dy + dz * dz, _EPS)
    wx, wy, wz = a[0] - c[0], a[1] - c[1], a[2] - c[2]
    reach = occ.major + occ.minor
    half_b = (wx * dx + wy * dy + wz * dz) / dd
    disc = half_b * half_b - (wx * wx + wy * wy + wz * wz - reach * reach) / dd
    if not disc > 0.0:
        return False
    root = math.sqrt(disc)
    t0 = min(max(-half_b - root, 0.0), 1.0)
    t1 = min(max(-half_b + root, 0.0), 1.0)
    if not t1 > t0:
        return False
    samples = max(2, math.ceil((t1 - t0) * math.sqrt(dd) / occ.rim_step) + 1)
    # Coarse to fine, with the same answer as every sample: the distance to the core circle is
    # 1-Lipschitz, so a coarse sample at least ``minor + half·spacing`` away clears every
    # sample within ``half`` samples of it; only the others are tried.
    spacing = (t1 - t0) * math.sqrt(dd) / (samples - 1)
    for j in range(0, samples + RIM_COARSE - 1, RIM_COARSE):
        i = min(j, samples - 1)
        if _rim_distance(wx, wy, wz, dx, dy, dz, t0 + (t1 - t0) * i / (samples - 1), occ) >= (
            occ.minor + RIM_HALF * spacing
        ):
            continue
        for k in range(max(0, i - RIM_HALF), min(samples, i + RIM_HALF + 1)):
            t = t0 + (t1 - t0) * k / (samples - 1)
            if _rim_distance(wx, wy, wz, dx, dy, dz, t, occ) < occ.minor:
                return True
    return False


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def view_shares(
    eyes: FloatArray, axes: FloatArray, sight: Sight, occ: Occluders, scored: np.ndarray
) -> FloatArray:  # pragma: no cover - compiled
    """(E,) weighted share of ``sight``'s points each eye sees clear and resolved.

    ``eyes`` (E, 3), world, m; ``axes`` (E, 3) each eye's unit optical axis. A point counts
    when it is in front of the eye, its gap spans ``resolved_px`` and the sight line passes
    every occluder (:func:`endocam.control.occlusion.view_scores`, per eye). ``scored`` (E,)
    bool: an eye not scored (its view cannot be taken anyway) is not traced; its share is 0.
    """
    total = 0.0
    for w in sight.weights:
        total += w
    out = np.zeros(eyes.shape[0])
    if not total > 0.0:
        return out
    end = np.empty(3)
    for e in range(eyes.shape[0]):
        if not scored[e]:
            continue
        eye = eyes[e]
        share = 0.0
        for m in range(sight.points.shape[0]):
            w = sight.weights[m]
            if not w > 0.0:
                continue
            g = sight.points[m]
            rx, ry, rz = g[0] - eye[0], g[1] - eye[1], g[2] - eye[2]
            dist = math.sqrt(rx * rx + ry * ry + rz * rz)
            depth = rx * axes[e, 0] + ry * axes[e, 1] + rz * axes[e, 2]
            if not (depth > 0.0 and dist > _EPS):
                continue
            u = sight.directions[m]
            along = (rx * u[0] + ry * u[1] + rz * u[2]) / dist
            across = math.sqrt(max(1.0 - along * along, 0.0))
            if sight.gap * sight.focal_px * across / depth < sight.resolved_px:
                continue
            keep = max(dist - sight.tolerance, 0.0) / dist
            end[0], end[1], end[2] = eye[0] + keep * rx, eye[1] + keep * ry, eye[2] + keep * rz
            if _through_rim(eye, end, occ):
                continue
            blocked = False
            for s in range(occ.seg_r.shape[0]):
                if segment_distance(eye, end, occ.seg_a[s], occ.seg_b[s]) < occ.seg_r[s]:
                    blocked = True
                    break
            if not blocked:
                share += w
        out[e] = share / total
    return out


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def views_clear(
    cameras: FloatArray, cone: Cone, floor: float, zone: KeepOutState, slack: FloatArray
) -> np.ndarray:  # pragma: no cover - compiled
    """(C,) whether each camera position (C, 3), world, m, may be aimed at.

    At or above ``floor`` (m), inside ``cone`` by ``slack[0]`` (m) and ``slack[1]`` (m)
    beyond the zone's clearance from the wire (``keep_out_nearest``: an exact query).
    """
    a, axis, tan_half, cos_half, height = cone
    out = np.zeros(cameras.shape[0], dtype=np.bool_)
    for i in range(cameras.shape[0]):
        x, y, z = cameras[i, 0], cameras[i, 1], cameras[i, 2]
        if not z >= floor:
            continue
        if not cone_margin(x, y, z, a, axis, tan_half, cos_half, height) >= slack[0]:
            continue
        out[i] = keep_out_nearest(zone, x, y, z).surface >= zone.clearance + slack[1]
    return out
