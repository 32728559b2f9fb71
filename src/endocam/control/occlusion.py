r"""What the wire's near part and the ring's rim hide of the ring's hole from a candidate eye.

The ``endocam-visible`` camera (:mod:`endocam.control.policies.visible`) chooses its side of
the ring and its tilt off the normal by what each candidate eye would see of the **closing
gap**: where the wire will touch the ring's rim, and the 0.5 mm gap there just before it does
(the study's measure, :func:`endocam.study.observability.gap_hidden_by`). Everything here is a
cheap geometric stand-in for that measure's ray casts, on the pre-operative wire model (as the
wire clearance, :mod:`endocam.control.clearance`) and the observed ring pose:

1. **Where the gap closes** (:func:`gap_points`). ``M`` points ``q_j`` on the ring's core
   circle; the nearest wire point ``p_j`` to each (on the wire's polyline near the ring,
   :func:`wire_window`); the gap direction :math:`\hat u_j = (q_j - p_j)/|q_j - p_j|`; the
   gap point :math:`g_j = p_j + (r_w + \tfrac12 \cdot 0.5\,\mathrm{mm})\,\hat u_j` (the middle of
   a 0.5 mm gap, as the touch detector places its contact point) and the weight
   :math:`w_j = \exp(-\max(c_j, 0)/\lambda)` of the clearance :math:`c_j = |q_j - p_j| - r -
   r_w`: the rim points nearest the wire, where the next touch is likeliest, count most.
2. **Hidden** (:func:`hidden`): the straight segment from an eye to a gap point, stopped
   ``tolerance`` short of it (the ray cast's allowance, ``DEFAULT_RAY_TOLERANCE``: a point is
   not hidden by the tubes it sits between), passes within ``r_w`` of the wire's centre line,
   within ``r_h`` of the ring's handle, or within ``r`` of the ring's core circle (the rim,
   sampled every ``RIM_SAMPLE_M`` along the segment inside the ring's bounding sphere).
3. **Resolved** (:func:`gap_spans`): 0.5 mm of gap along :math:`\hat u_j` spans
   :math:`0.5\,\mathrm{mm} \cdot f \sqrt{1 - (\hat u_j \cdot \hat s)^2} / Z` px in the image
   (:math:`\hat s` the line of sight, ``Z`` the depth): a gap opening along the line of sight
   shows nothing however clear it is.

4. **The contact's neighbourhood** (:func:`contact_points`): the rim point nearest the wire
   (searched every 1°) and gap points evenly within an arc of rim either side of it, equally
   weighted: the ``endocam-visible`` tilt is judged on these (the side on item 1's).

:func:`view_scores` combines them: per candidate view, the weighted share of the gap points
in sight and resolved, per eye. Arrays are numpy, world frame, metres; a call with ~40
candidates, 12 rim points and a 60 mm window takes about a millisecond, so the policy scores
a few times per second, not every control step.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from endocam.control.sightline import Occluders, Sight
from endocam.geometry import FloatArray
from endocam.task.config import RingConfig
from endocam.task.wire import Wire

__all__ = [
    "GAP_M",
    "RAY_TOLERANCE_M",
    "GapPoints",
    "RingShape",
    "contact_points",
    "direction_table",
    "eye_positions",
    "gap_points",
    "gap_points_along",
    "gap_spans",
    "hidden",
    "occluders",
    "polyline_distances_sq",
    "segment_distances",
    "sight",
    "view_directions",
    "view_scores",
    "wire_window",
]

GAP_M = 0.5e-3  # m: the gap whose closing is judged (the study's GAP_SEEN)
RAY_TOLERANCE_M = 2.0e-3  # m: the ray cast's allowance before a point (DEFAULT_RAY_TOLERANCE)
RIM_SAMPLE_M = 0.4e-3  # m: spacing of the samples along a ray tested against the rim
WINDOW_SPACING_M = 2.0e-3  # m: spacing of the wire polyline near the ring (sagitta ≪ r_w)
CONTACT_SEARCH = 360  # count: rim angles searched for the contact (1°: 0.09 mm of a 5 mm rim)
WEIGHT_FLOOR = 0.2  # unitless: gap points weighing less than this share of the most are dropped
_EPS = 1e-12  # m or unitless: below this a length or a direction is degenerate
_UP = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class RingShape:
    """The ring's geometry the scorer needs (SI): a known instrument, as in the task's config.

    Attributes
    ----------
    major, minor : float
        Core-circle radius ``R`` and tube radius ``r``, m.
    handle_length, handle_radius : float
        The handle: a rod from the core circle along the ring's +x, m.
    """

    major: float
    minor: float
    handle_length: float
    handle_radius: float

    @classmethod
    def of(cls, ring: RingConfig) -> RingShape:
        """The shape of a task's ring."""
        return cls(ring.major_radius, ring.minor_radius, ring.handle_length, ring.handle_radius)


@dataclass(frozen=True)
class GapPoints:
    """Where the ring's rim may meet the wire (module docstring, item 1).

    Attributes
    ----------
    points : (M, 3)
        Gap points ``g_j``, world, m.
    directions : (M, 3)
        Unit gap directions ``û_j`` (wire → rim), world.
    clearances : (M,)
        Rim–wire clearances ``c_j``, m.
    weights : (M,)
        ``exp(-max(c_j, 0) / λ)``, unitless, in (0, 1].
    """

    points: FloatArray
    directions: FloatArray
    clearances: FloatArray
    weights: FloatArray


def wire_window(wire: Wire, p_world: FloatArray, half_length: float) -> FloatArray:
    """The wire's centre line within ``half_length`` (m) of arc either side of ``p_world``.

    ``p_world`` (3,), world, m (the ring centre). Returns (K, 3) points, world, m, about
    ``WINDOW_SPACING_M`` apart (K ≥ 2), consecutive points forming the segments.
    """
    _, k = wire.nearest_surface((float(p_world[0]), float(p_world[1]), float(p_world[2])))
    pts = wire.search_points
    stride = max(1, round(WINDOW_SPACING_M / wire.search_spacing))
    half = max(1, math.ceil(half_length / wire.search_spacing))
    lo, hi = max(0, k - half), min(len(pts) - 1, k + half)
    idx = np.arange(lo, hi + 1, stride)
    if idx[-1] != hi:
        idx = np.append(idx, hi)
    if len(idx) < 2:
        idx = np.array([max(0, hi - 1), hi])
    return np.asarray(pts[idx], dtype=float)


def gap_points(
    T_world_ring: FloatArray,
    window: FloatArray,
    ring: RingShape,
    wire_radius: float,
    count: int,
    scale: float,
) -> GapPoints:
    """``count`` gap points around the rim and their weights (module docstring, item 1).

    Parameters
    ----------
    T_world_ring : (4, 4)
        The observed ring pose (z the face normal), world, m.
    window : (K, 3)
        The wire's centre line near the ring (:func:`wire_window`), world, m.
    ring : RingShape
    wire_radius : float
        ``r_w``, m.
    count : int
        Rim points ``M`` (≥ 1), evenly spaced in angle.
    scale : float
        ``λ``, m (> 0): how fast the weight falls with the clearance.
    """
    return gap_points_along([T_world_ring], window, ring, wire_radius, count, scale)[0]


def gap_points_along(
    T_world_rings: Sequence[FloatArray],
    window: FloatArray,
    ring: RingShape,
    wire_radius: float,
    count: int,
    scale: float,
) -> list[GapPoints]:
    """:func:`gap_points` of each ring pose (4, 4), world, m, of ``T_world_rings``.

    ``window`` (K, 3), ``ring``, ``wire_radius``, ``count`` and ``scale`` as
    :func:`gap_points`'s. The poses' rim points are measured against the wire in one batch
    (one set of numpy calls for all of them); each pose's gap points, clearances and weights
    are its own (its weights floored against its own largest).
    """
    phi = np.arange(count) * (2.0 * math.pi / count)
    q = np.concatenate([_rim_points(T, ring, phi) for T in T_world_rings])
    g, u, clearance = _gaps_at(q, window, ring, wire_radius)
    out = []
    for i in range(len(T_world_rings)):
        rows = slice(i * count, (i + 1) * count)
        weights = np.exp(-np.maximum(clearance[rows], 0.0) / scale)
        weights[weights < WEIGHT_FLOOR * np.max(weights)] = 0.0
        out.append(GapPoints(g[rows], u[rows], clearance[rows], weights))
    return out


def contact_points(
    T_world_ring: FloatArray,
    window: FloatArray,
    ring: RingShape,
    wire_radius: float,
    arc: float,
    count: int,
) -> GapPoints:
    """``count`` gap points, equally weighted, within ``arc`` (m, of rim) of the contact.

    The predicted contact is the rim point nearest the wire (searched every
    ``360° / CONTACT_SEARCH``); the points lie evenly on the core circle from ``arc`` before
    it to ``arc`` after it (one point, ``count`` = 1: the contact itself), each with its gap
    point and direction as in :func:`gap_points`, weight 1. A view is then judged by what it
    shows of the **contact's neighbourhood**, not of the whole rim: where along the rim the
    ring touches is uncertain by a fraction of a millimetre, and a sight line grazing the
    wire there decides whether the touch is seen.

    ``T_world_ring`` (4, 4), world, m; ``window`` (K, 3) the wire near the ring, m;
    ``wire_radius``, ``arc`` m (``arc`` ≥ 0); ``count`` ≥ 1.
    """
    c = np.asarray(T_world_ring, dtype=float)[:3, 3]
    phi = np.arange(CONTACT_SEARCH) * (2.0 * math.pi / CONTACT_SEARCH)
    q = _rim_points(T_world_ring, ring, phi)
    best = float(phi[int(np.argmin(polyline_distances_sq(q - c, np.asarray(window) - c)))])
    half = arc / ring.major  # rad of rim either side
    phi = best + (np.linspace(-half, half, count) if count > 1 else np.zeros(1))
    g, u, clearance = _gaps_at(_rim_points(T_world_ring, ring, phi), window, ring, wire_radius)
    return GapPoints(g, u, clearance, np.ones(len(phi)))


def _rim_points(T_world_ring: FloatArray, ring: RingShape, phi: np.ndarray) -> FloatArray:
    """(M, 3) points of the ring's core circle at the angles ``phi`` (M,), rad, world, m."""
    T = np.asarray(T_world_ring, dtype=float)
    c, e1, e2 = T[:3, 3], T[:3, 0], T[:3, 1]
    return np.asarray(c + ring.major * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2))


def _gaps_at(
    q: FloatArray, window: FloatArray, ring: RingShape, wire_radius: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Gap points (M, 3), their directions (M, 3) and clearances (M,), m, of rim points ``q``.

    Each rim point's gap lies towards it from its nearest point on the wire's ``window``
    (K, 3), ``GAP_M`` / 2 beyond the wire's surface (module docstring, item 1).
    """
    p = _nearest_on_polyline(q, window)
    gap = q - p
    dist = np.linalg.norm(gap, axis=1)
    u = gap / np.maximum(dist, _EPS)[:, None]
    g = p + (wire_radius + 0.5 * GAP_M) * u
    return g, u, dist - ring.minor - wire_radius


def polyline_distances_sq(q: FloatArray, poly: FloatArray) -> FloatArray:
    """(M,) squared distances of the points ``q`` (M, 3) to the polyline ``poly`` (K, 3), m².

    What :func:`_nearest_on_polyline` finds, without its (M, S, 3) arrays: with ``w = q − a``
    and the segment ``d = b − a``, ``|w − t d|² = |w|² − 2 t w·d + t² |d|²`` at the clamped
    ``t``, every term from (M, S) products. Pass points near the origin (the ring's centre
    subtracted) so that ``|w|²`` keeps its digits.
    """
    a, b = poly[:-1], poly[1:]
    d = b - a  # (S, 3)
    dd = np.maximum(np.einsum("ij,ij->i", d, d), _EPS)  # (S,)
    qa = q @ a.T  # (M, S)
    ww = np.einsum("ij,ij->i", q, q)[:, None] - 2.0 * qa + np.einsum("ij,ij->i", a, a)[None]
    wd = q @ d.T - np.einsum("ij,ij->i", a, d)[None]  # (M, S)
    t = np.clip(wd / dd, 0.0, 1.0)
    return np.asarray(np.min(ww - 2.0 * t * wd + t * t * dd, axis=1), dtype=float)


def _nearest_on_polyline(q: FloatArray, poly: FloatArray) -> FloatArray:
    """(M, 3) nearest points on the polyline ``poly`` (K, 3) to the points ``q`` (M, 3), m."""
    a, b = poly[:-1], poly[1:]
    d = b - a  # (S, 3)
    dd = np.maximum(np.einsum("ij,ij->i", d, d), _EPS)
    t = np.clip(np.einsum("mij,ij->mi", q[:, None, :] - a[None], d) / dd, 0.0, 1.0)  # (M, S)
    near = a[None] + t[..., None] * d[None]  # (M, S, 3)
    k = np.argmin(np.einsum("mij,mij->mi", q[:, None] - near, q[:, None] - near), axis=1)
    return np.asarray(near[np.arange(len(q)), k], dtype=float)


def segment_distances(a: FloatArray, b: FloatArray, p: FloatArray, q: FloatArray) -> FloatArray:
    """Distances (N, S) between segments ``a→b`` (N, 3) and ``p→q`` (S, 3), m.

    The closest points of two segments, clamped to both (Ericson, *Real-Time Collision
    Detection*, 5.1.9), vectorised over every pair.
    """
    d1 = b - a  # (N, 3)
    d2 = q - p  # (S, 3)
    r = a[:, None, :] - p[None, :, :]  # (N, S, 3)
    aa = np.einsum("ij,ij->i", d1, d1)[:, None]  # (N, 1)
    ee = np.einsum("ij,ij->i", d2, d2)[None, :]  # (1, S)
    bb = d1 @ d2.T  # (N, S)
    cc = np.einsum("ik,isk->is", d1, r)
    ff = np.einsum("sk,isk->is", d2, r)
    denom = aa * ee - bb * bb
    safe = denom > _EPS * np.maximum(aa * ee, _EPS)
    s = np.where(safe, np.clip((bb * ff - cc * ee) / np.where(safe, denom, 1.0), 0.0, 1.0), 0.0)
    ee_safe = np.maximum(ee, _EPS)
    t = (bb * s + ff) / ee_safe
    aa_safe = np.maximum(aa, _EPS)
    s = np.where(t < 0.0, np.clip(-cc / aa_safe, 0.0, 1.0), s)
    s = np.where(t > 1.0, np.clip((bb - cc) / aa_safe, 0.0, 1.0), s)
    t = np.clip(t, 0.0, 1.0)
    point = ee <= _EPS  # a zero-length p→q: its point, the nearest on a→b
    s = np.where(point, np.clip(-cc / aa_safe, 0.0, 1.0), s)
    t = np.where(point, 0.0, t)
    gap = r + s[..., None] * d1[:, None, :] - t[..., None] * d2[None, :, :]
    return np.asarray(np.sqrt(np.einsum("isk,isk->is", gap, gap)), dtype=float)


def hidden(
    eyes: FloatArray,
    targets: FloatArray,
    window: FloatArray,
    wire_radius: float,
    T_world_ring: FloatArray,
    ring: RingShape,
) -> np.ndarray:
    """Whether each target is hidden from each eye by the wire, the handle or the rim.

    Parameters
    ----------
    eyes : (E, 3)
        Eye positions, world, m.
    targets : (M, 3)
        Gap points, world, m.
    window : (K, 3)
        The wire's centre line near the ring, world, m (its K − 1 segments are tested).
    wire_radius : float
        ``r_w``, m.
    T_world_ring : (4, 4)
        The ring pose, world, m.
    ring : RingShape

    Returns
    -------
    (E, M) bool
        True: the segment from the eye to ``RAY_TOLERANCE_M`` short of the target passes
        within ``r_w`` of the wire, ``r_h`` of the handle or ``r`` of the core circle.
    """
    E, M = len(eyes), len(targets)
    a = np.repeat(eyes, M, axis=0)  # (E·M, 3)
    g = np.tile(targets, (E, 1))
    ray = g - a
    length = np.linalg.norm(ray, axis=1)
    keep = np.maximum(length - RAY_TOLERANCE_M, 0.0) / np.maximum(length, _EPS)
    b = a + keep[:, None] * ray
    T = np.asarray(T_world_ring, dtype=float)
    c, x_ring, n = T[:3, 3], T[:3, 0], T[:3, 2]
    h0 = c + ring.major * x_ring
    h1 = c + (ring.major + ring.handle_length) * x_ring
    p = np.vstack([window[:-1], h0[None]])
    q = np.vstack([window[1:], h1[None]])
    radii = np.append(np.full(len(window) - 1, wire_radius), ring.handle_radius)
    blocked = np.any(segment_distances(a, b, p, q) < radii[None, :], axis=1)
    blocked |= _through_rim(a, b, c, n, ring)
    return blocked.reshape(E, M)


def _through_rim(
    a: FloatArray, b: FloatArray, c: FloatArray, n: FloatArray, ring: RingShape
) -> np.ndarray:
    """(N,) whether segments ``a→b`` (N, 3) pass within ``r`` of the core circle.

    ``c`` the ring's centre, ``n`` its unit normal; sampled every ``RIM_SAMPLE_M`` (at most)
    along each segment's chord inside the ring's bounding sphere.
    """
    out = np.zeros(len(a), dtype=bool)
    reach = ring.major + ring.minor
    for i in range(len(a)):
        d = b[i] - a[i]
        dd = max(float(d @ d), _EPS)
        w = a[i] - c
        half_b = float(w @ d) / dd
        disc = half_b * half_b - (float(w @ w) - reach * reach) / dd
        if not disc > 0.0:
            continue
        root = math.sqrt(disc)
        t0, t1 = min(max(-half_b - root, 0.0), 1.0), min(max(-half_b + root, 0.0), 1.0)
        if not t1 > t0:
            continue
        samples = max(2, math.ceil((t1 - t0) * math.sqrt(dd) / RIM_SAMPLE_M) + 1)
        x = w + np.linspace(t0, t1, samples)[:, None] * d  # (S, 3), from the ring centre
        h = x @ n
        rho = np.linalg.norm(x - h[:, None] * n, axis=1)
        out[i] = bool(np.min(np.hypot(rho - ring.major, h)) < ring.minor)
    return out


def gap_spans(eyes: FloatArray, axes: FloatArray, gaps: GapPoints, focal_px: float) -> FloatArray:
    """Image length (E, M) of ``GAP_M`` of gap at each gap point seen from each eye, px.

    ``eyes`` (E, 3), world, m; ``axes`` (E, 3) each eye's unit optical axis (world);
    ``focal_px`` the focal length, px. A point behind an eye spans 0 px.
    """
    ray = gaps.points[None, :, :] - eyes[:, None, :]  # (E, M, 3)
    dist = np.maximum(np.linalg.norm(ray, axis=2), _EPS)
    sight = ray / dist[..., None]
    depth = np.einsum("emk,ek->em", ray, axes)
    along = np.einsum("emk,mk->em", sight, gaps.directions)
    across = np.sqrt(np.maximum(1.0 - along * along, 0.0))
    span = GAP_M * focal_px * across / np.maximum(depth, _EPS)
    return np.asarray(np.where(depth > 0.0, span, 0.0), dtype=float)


def direction_table(tilts: FloatArray, azimuths: int) -> FloatArray:
    """Candidate view directions in a normal's frame (1 + T·A, 3): x, y across, z along it.

    The first is the normal itself; then for each tilt in ``tilts`` (T,), rad, ``azimuths``
    directions evenly spaced around it: ``(sin θ cos φ, sin θ sin φ, cos θ)``.
    """
    phi = np.arange(azimuths) * (2.0 * math.pi / max(azimuths, 1))
    rows = [np.array([[0.0, 0.0, 1.0]])]
    for theta in np.asarray(tilts, dtype=float):
        rows.append(
            np.column_stack(
                [
                    math.sin(theta) * np.cos(phi),
                    math.sin(theta) * np.sin(phi),
                    np.full(azimuths, math.cos(theta)),
                ]
            )
        )
    return np.vstack(rows)


def view_directions(n: FloatArray, table: FloatArray) -> FloatArray:
    """The table's directions (C, 3) about the unit normal ``n`` (3,), world.

    ``table`` from :func:`direction_table`; its x axis is world up's part ⟂ ``n`` (world x's
    when ``n`` is vertical), its y axis ``n × x``.
    """
    n0, n1, n2 = float(n[0]), float(n[1]), float(n[2])
    e = (-n2 * n0, -n2 * n1, 1.0 - n2 * n2)  # world up's part ⟂ n
    if e[2] < 1e-12:  # n vertical: world x's part
        e = (1.0 - n0 * n0, -n0 * n1, -n0 * n2)
    k = 1.0 / math.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
    e1 = (e[0] * k, e[1] * k, e[2] * k)
    e2 = (n1 * e1[2] - n2 * e1[1], n2 * e1[0] - n0 * e1[2], n0 * e1[1] - n1 * e1[0])
    return np.asarray(table @ np.array([e1, e2, (n0, n1, n2)]), dtype=float)


def eye_positions(
    p_c: FloatArray, directions: FloatArray, d: float, baseline: float
) -> tuple[FloatArray, FloatArray]:
    """Left and right eyes (C, 3) of cameras at ``d`` m along ``directions`` (C, 3) from ``p_c``.

    The left eye on the line (the tracker centres the left eye), the right one ``baseline`` m
    along the level horizon ``x = normalize(z × up)``, ``z = −direction`` (world x when the view
    is vertical). World, m.
    """
    left = p_c[None, :] + d * directions
    x = np.column_stack([-directions[:, 1], directions[:, 0], np.zeros(len(directions))])
    norm = np.hypot(directions[:, 0], directions[:, 1])  # z × up, z = -direction
    level = norm > 1e-9
    x[level] /= norm[level, None]
    x[~level] = (1.0, 0.0, 0.0)
    return left, left + baseline * x


def view_scores(
    eyes: tuple[FloatArray, FloatArray],
    axes: FloatArray,
    gaps: GapPoints,
    window: FloatArray,
    T_world_ring: FloatArray,
    ring: RingShape,
    wire_radius: float,
    focal_px: float,
    resolved_px: float,
) -> FloatArray:
    """Weighted share of the gap points in sight and resolved, per candidate and eye, (C, 2).

    ``eyes``: left and right eyes (C, 3) each (:func:`eye_positions`); ``axes`` (C, 3) the
    optical axes; ``resolved_px`` the span 0.5 mm of gap needs, px. Column 0 the left eye,
    column 1 the right.
    """
    left, right = eyes
    both = np.vstack([left, right])  # the reference of the compiled sightline.view_shares
    hid = hidden(both, gaps.points, window, wire_radius, T_world_ring, ring)
    spans = gap_spans(both, np.vstack([axes, axes]), gaps, focal_px)
    seen = ~hid & (spans >= resolved_px)  # (2C, M)
    w = gaps.weights / max(float(np.sum(gaps.weights)), _EPS)
    share = seen.astype(float) @ w
    return np.column_stack([share[: len(left)], share[len(left) :]])


def occluders(
    window: FloatArray, wire_radius: float, T_world_ring: FloatArray, ring: RingShape
) -> Occluders:
    """The compiled scorer's occluders around the ring at ``T_world_ring`` (4, 4).

    The wire's segments in ``window`` (K, 3), m, of radius ``wire_radius`` (m), the handle and
    the rim.
    """
    T = np.asarray(T_world_ring, dtype=float)
    c, x_ring = T[:3, 3], T[:3, 0]
    n = T[:3, 2] / max(float(np.linalg.norm(T[:3, 2])), _EPS)
    h0 = c + ring.major * x_ring
    h1 = c + (ring.major + ring.handle_length) * x_ring
    return Occluders(
        np.ascontiguousarray(np.vstack([window[:-1], h0[None]])),
        np.ascontiguousarray(np.vstack([window[1:], h1[None]])),
        np.append(np.full(len(window) - 1, wire_radius), ring.handle_radius),
        np.ascontiguousarray(c),
        np.ascontiguousarray(n),
        ring.major,
        ring.minor,
        RIM_SAMPLE_M,
    )


def sight(gaps: GapPoints, focal_px: float, resolved_px: float) -> Sight:
    """The compiled scorer's gap points: ``gaps``, the focal length and the span needed, px."""
    return Sight(
        np.ascontiguousarray(gaps.points),
        np.ascontiguousarray(gaps.directions),
        np.ascontiguousarray(gaps.weights),
        RAY_TOLERANCE_M,
        GAP_M,
        float(focal_px),
        float(resolved_px),
    )
