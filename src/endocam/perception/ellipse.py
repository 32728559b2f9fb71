"""The ring's rim in one image, and a circle's pose from its image ellipse.

Pure functions on arrays (OpenCV and numpy). Pixels follow ``docs/conventions.md``: u right,
v down; normalised image coordinates are ``K⁻¹ (u, v, 1)`` in the eye's optical frame.

* :func:`fit_rim` fits an ellipse to the **outer silhouette** of a ring mask: the external
  contour points of its components that lie on their convex hull (the silhouette's convex outer
  edge; cuts made by the wire or an instrument in front of the ring are concave and left out),
  minus the points on the image border (a cut by the frame). What is left is fitted by
  ``cv2.fitEllipse``; the fit reports its angular coverage (the share of the ellipse's
  perimeter, in ``COVERAGE_BINS`` angular bins, that has supporting points) and its RMS residual.
* :func:`circle_normals` gives the two unit normals of a circle whose image is a given conic
  (the exact perspective solution: the circular sections of the viewing cone; e.g. Kanatani,
  *Geometric Computation for Machine Vision*, 1993, ch. 8). One view cannot tell the two apart;
  the second eye does (:mod:`endocam.perception.estimator`).
* :func:`centre_image` is where the circle's centre projects (the pole of the plane's vanishing
  line), not the ellipse's centre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from endocam.geometry import FloatArray

HULL_TOL_PX = 1.0  # px, contour points this close to the convex hull are on the outer silhouette
BORDER_PX = 1  # px, contour points this close to the image border are cut by the frame
MIN_RIM_POINTS = 12  # fewest silhouette points a fit needs (cv2.fitEllipse needs 5)
COVERAGE_BINS = 36  # angular bins of 10° for the fit's coverage
OCCLUDER_PX = 2  # px, silhouette points this close to an occluder's pixel are left out
TRIM_PX = 1.5  # px, after a first fit, points farther than this (and than TRIM_MAD MADs) go
TRIM_MAD = 3.0  # unitless, the trimming's multiple of the residuals' median absolute deviation
PIXEL_CENTRE_PX = 0.5  # px, contour points are boundary pixels' centres, half a pixel inside


@dataclass(frozen=True)
class ImageEllipse:
    """An ellipse in an image.

    Attributes
    ----------
    centre : (2,)
        Centre (u, v), px.
    a, b : float
        Semi-axes, px, ``a ≥ b > 0``.
    angle : float
        Direction of the ``a`` axis from the u axis towards v, rad.
    coverage : float
        Share of the perimeter with supporting points, in [0, 1] (1 for a synthetic ellipse).
    rms_px : float
        RMS distance of the supporting points from the ellipse, px (0 for a synthetic one).
    points : (N, 2)
        The supporting silhouette points (u, v), px.
    """

    centre: FloatArray
    a: float
    b: float
    angle: float
    coverage: float = 1.0
    rms_px: float = 0.0
    points: FloatArray | None = None

    def shrunk(self, by_px: float) -> ImageEllipse:
        """The ellipse with both semi-axes ``by_px`` shorter (the tube's core from its outline)."""
        a, b = self.a - by_px, self.b - by_px
        if b <= 0.0:
            raise ValueError(f"by_px {by_px} is not smaller than the minor semi-axis {self.b}")
        return ImageEllipse(self.centre, a, b, self.angle, self.coverage, self.rms_px, self.points)

    def shifted(self, offset_px: FloatArray) -> ImageEllipse:
        """The ellipse (and its points) moved by ``offset_px`` (2,), px (a crop's origin)."""
        pts = None if self.points is None else self.points + offset_px
        return ImageEllipse(
            self.centre + offset_px, self.a, self.b, self.angle, self.coverage, self.rms_px, pts
        )

    def conic(self) -> FloatArray:
        """(3, 3) symmetric pixel conic ``C``: ``x̃ᵀ C x̃ = 0`` on the ellipse, ``x̃ = (u, v, 1)``."""
        c, s = math.cos(self.angle), math.sin(self.angle)
        R = np.array([[c, -s], [s, c]])
        A = R @ np.diag([1.0 / self.a**2, 1.0 / self.b**2]) @ R.T
        Ac = A @ self.centre
        C = np.empty((3, 3))
        C[:2, :2] = A
        C[:2, 2] = C[2, :2] = -Ac
        C[2, 2] = float(self.centre @ Ac) - 1.0
        return C

    def distances(self, pts: FloatArray) -> FloatArray:
        """(N,) approximate distances of (N, 2) points (u, v) from the ellipse, px (Sampson)."""
        c, s = math.cos(self.angle), math.sin(self.angle)
        d = np.asarray(pts, dtype=float) - self.centre
        x = (d[:, 0] * c + d[:, 1] * s) / self.a
        y = (-d[:, 0] * s + d[:, 1] * c) / self.b
        f = x * x + y * y - 1.0
        grad = 2.0 * np.hypot(x / self.a, y / self.b)
        return np.asarray(np.abs(f) / np.maximum(grad, 1e-12))


def silhouette_points(
    mask: NDArray[np.bool_], occluder: NDArray[np.bool_] | None = None
) -> FloatArray:
    """Points (u, v) of a mask's outer silhouette: (N, 2), px (see the module docstring).

    Each point is a boundary pixel's centre, ``(j + 0.5, i + 0.5)`` for pixel ``(i, j)``
    (docs/conventions.md; OpenCV's contours give ``(j, i)``).

    ``mask`` : (H, W) bool. ``occluder`` : (H, W) bool or None, pixels of what may hide the
    ring (the wire): silhouette points within ``OCCLUDER_PX`` of one are left out (an edge
    there may be the occluder's, not the ring's). Points on the image border are left out too;
    an empty mask gives (0, 2).
    """
    h, w = mask.shape
    contours, _ = cv2.findContours(mask.view(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return np.zeros((0, 2))
    pts = np.concatenate([c.reshape(-1, 2) for c in contours]).astype(float)
    hull = cv2.convexHull(pts.astype(np.float32)).reshape(-1, 2).astype(float)
    if len(hull) >= 3:
        pts = pts[_distance_to_polygon(pts, hull) <= HULL_TOL_PX]
    inside = (
        (pts[:, 0] >= BORDER_PX)
        & (pts[:, 0] <= w - 1 - BORDER_PX)
        & (pts[:, 1] >= BORDER_PX)
        & (pts[:, 1] <= h - 1 - BORDER_PX)
    )
    pts = pts[inside]
    if occluder is not None and len(pts):
        pts = pts[~_near(occluder, pts)]
    return np.asarray(pts + PIXEL_CENTRE_PX)  # pixel (i, j)'s centre is (j + 0.5, i + 0.5)


def _near(occluder: NDArray[np.bool_], pts: FloatArray) -> NDArray[np.bool_]:
    """(N,) whether each integer point (u, v) of (N, 2) is near a pixel of ``occluder``.

    Near: within ``OCCLUDER_PX`` (a square neighbourhood). ``occluder`` : (H, W) bool, dilated
    in the points' box only.
    """
    h, w = occluder.shape
    r = OCCLUDER_PX
    u0, v0 = (pts.min(axis=0) - r).astype(int).clip(0)
    u1 = min(int(pts[:, 0].max()) + r + 1, w)
    v1 = min(int(pts[:, 1].max()) + r + 1, h)
    roi = occluder[v0:v1, u0:u1].view(np.uint8)
    grown = cv2.dilate(roi, np.ones((2 * r + 1, 2 * r + 1), np.uint8))
    ij = pts.astype(int)
    return np.asarray(grown[ij[:, 1] - v0, ij[:, 0] - u0] > 0)


def _distance_to_polygon(pts: FloatArray, hull: FloatArray) -> FloatArray:
    """(N,) distance of (N, 2) points inside a convex polygon (M, 2) to its boundary.

    Inside a convex polygon, the distance to the boundary is the smallest distance to an
    edge's line: one (N, 2) × (2, M) product.
    """
    edge = np.roll(hull, -1, axis=0) - hull
    length = np.hypot(edge[:, 0], edge[:, 1])
    ok = length > 0.0
    normal = np.stack([edge[ok, 1], -edge[ok, 0]], axis=1) / length[ok, None]
    offset = (normal * hull[ok]).sum(axis=1)
    d = pts @ normal.T - offset  # signed; the polygon's orientation decides the sign
    if d.mean() > 0.0:
        d = -d
    return np.asarray(-d.max(axis=1))


def _fit(pts: FloatArray) -> ImageEllipse | None:
    """``cv2.fitEllipse`` of (N, 2) points as an :class:`ImageEllipse` (a ≥ b), or None."""
    (cu, cv), (d1, d2), angle_deg = cv2.fitEllipse(pts.astype(np.float32))
    if not (math.isfinite(d1) and math.isfinite(d2) and min(d1, d2) > 0.0):
        return None
    angle = math.radians(angle_deg)
    a, b = 0.5 * d1, 0.5 * d2
    if b > a:
        a, b, angle = b, a, angle + 0.5 * math.pi
    return ImageEllipse(np.array([cu, cv]), a, b, angle)


def fit_rim(
    mask: NDArray[np.bool_], occluder: NDArray[np.bool_] | None = None
) -> ImageEllipse | None:
    """The ellipse of a ring mask's outer silhouette, or None (too few silhouette points).

    The silhouette points (:func:`silhouette_points`) are fitted, those farther from the fit
    than ``TRIM_PX`` and ``TRIM_MAD`` median absolute deviations are dropped (an instrument's
    edge, a straight cut), and the rest fitted again.

    Parameters
    ----------
    mask : (H, W) bool
        The ring's pixels (:func:`endocam.perception.segment.segment`).
    occluder : (H, W) bool or None
        Pixels of what may hide the ring (the wire's mask).

    Returns
    -------
    ImageEllipse or None
        Its semi-axes grown by ``PIXEL_CENTRE_PX`` (from boundary pixels' centres to the edge).
    """
    pts = silhouette_points(mask, occluder)
    if len(pts) < MIN_RIM_POINTS:
        return None
    fit = _fit(pts)
    if fit is None:
        return None
    r = fit.distances(pts)
    mad = float(np.median(np.abs(r - np.median(r))))
    keep = r <= max(TRIM_PX, float(np.median(r)) + TRIM_MAD * mad)
    if not keep.all() and keep.sum() >= MIN_RIM_POINTS:
        pts = pts[keep]
        fit = _fit(pts)
        if fit is None:
            return None
    a, b, angle = fit.a, fit.b, fit.angle
    c, s = math.cos(angle), math.sin(angle)
    d = pts - fit.centre
    phi = np.arctan2((-d[:, 0] * s + d[:, 1] * c) / b, (d[:, 0] * c + d[:, 1] * s) / a)
    bins = np.floor((phi + math.pi) / (2.0 * math.pi) * COVERAGE_BINS).astype(int)
    coverage = len(np.unique(np.clip(bins, 0, COVERAGE_BINS - 1))) / COVERAGE_BINS
    rms = float(np.sqrt(np.mean(fit.distances(pts) ** 2)))
    grown = (a + PIXEL_CENTRE_PX, b + PIXEL_CENTRE_PX)
    return ImageEllipse(fit.centre, *grown, angle, coverage, rms, pts)


def normalised_conic(ellipse: ImageEllipse, K: FloatArray) -> FloatArray:
    """(3, 3) conic of ``ellipse`` in normalised image coordinates (``Kᵀ C K``), unit trace."""
    Q = K.T @ ellipse.conic() @ K
    return np.asarray(Q / np.linalg.norm(Q))


def circle_normals(Q: FloatArray) -> tuple[FloatArray, FloatArray] | None:
    r"""The two unit normals of the circles whose image is the normalised conic ``Q`` (3, 3).

    With ``Q``'s eigenvalues ``λ1 ≥ λ2 > 0 > λ3`` (its sign flipped if need be) and eigenvectors
    ``e1, e2, e3``, the planes ``n · x = d`` that cut the cone ``xᵀ Q x = 0`` in circles have

    .. math:: n \propto \sqrt{λ_1 − λ_2}\, e_1 \pm \sqrt{λ_2 − λ_3}\, e_3 ,

    because ``Q − λ2 I`` factors into these two planes. Each normal is returned pointing towards
    the eye (negative z). None when ``Q`` is not an ellipse's cone (signature not (2, 1)).
    """
    lam, V = np.linalg.eigh(Q)  # ascending
    if lam[1] < 0.0:  # two negative: flip the sign
        lam, V = -lam[::-1], V[:, ::-1]
    l3, l2, l1 = lam
    if not (l1 >= l2 > 0.0 > l3):
        return None
    g1 = math.sqrt(max(l1 - l2, 0.0))
    g3 = math.sqrt(l2 - l3)
    out = []
    for sign in (1.0, -1.0):
        n = g1 * V[:, 2] + sign * g3 * V[:, 0]
        n = n / np.linalg.norm(n)
        out.append(-n if n[2] > 0.0 else n)
    return out[0], out[1]


def radius_over_distance(Q: FloatArray) -> float:
    r"""A circle's radius over its plane's distance from the eye, from its image conic alone.

    With ``Q``'s eigenvalues ordered as in :func:`circle_normals`, both circular sections of the
    cone ``xᵀ Q x = 0`` at distance ``d`` (``n · x = d``) have the radius

    .. math:: ρ = d \, \sqrt{−λ_1 λ_3} / λ_2

    (the points of the cone on that plane lie on a sphere through the eye, by the factoring of
    ``Q − λ2 I``). NaN when ``Q`` is not an ellipse's cone.
    """
    lam = np.linalg.eigvalsh(Q)
    if lam[1] < 0.0:
        lam = -lam[::-1]
    l3, l2, l1 = lam
    if not (l1 >= l2 > 0.0 > l3):
        return math.nan
    return math.sqrt(-l1 * l3) / l2


def centre_image(Q: FloatArray, n: FloatArray) -> FloatArray | None:
    """Normalised image (x, y) of the centre of the circle with image ``Q`` and normal ``n``.

    The centre's ray is ``Q⁻¹ n`` (the pole of the plane's vanishing line); (2,), or None when it
    does not point forward.
    """
    try:
        ray = np.linalg.solve(Q, n)
    except np.linalg.LinAlgError:
        return None
    if abs(ray[2]) < 1e-12:
        return None
    return np.asarray(ray[:2] / ray[2])


def core_ellipse(
    fit: ImageEllipse, K: FloatArray, tube: float, p_eye: FloatArray, n: FloatArray
) -> ImageEllipse | None:
    """The core circle's image from a fitted outer silhouette, tube width by perspective.

    ``fit.shrunk(tube_px)`` takes the tube's image width as the same all round the rim: true
    for a ring seen face-on on the optical axis. Off the axis a sphere of radius ``r`` at depth
    ``Z`` images as an ellipse ``r / Z`` wide across the ray and ``r / (Z cos θ)`` along it
    (``θ`` the ray's angle to the axis), and the rim's depth varies across a tilted ring: an eye
    that sees the ring 10–15° off its axis gets a core ~0.3 px too wide on that side, which the
    other eye does not, and the disparity plane tilts by 1–2° (round 15). Here each silhouette
    point moves inwards along the fit's normal by the tube's image half-width in that direction
    at its own depth and ray, and the moved points are fitted again.

    Parameters
    ----------
    fit : ImageEllipse
        The outer silhouette's fit with its ``points`` (N, 2), px.
    K : (3, 3)
        The eye's intrinsics.
    tube : float
        The tube's radius (the ring's minor radius), m.
    p_eye, n : (3,)
        A first estimate of the ring's centre (m) and unit normal in this eye's frame: the
        depths of the rim's points.

    Returns
    -------
    ImageEllipse or None
        The core's ellipse, px (``coverage``, ``rms_px``, ``points`` the fit's), or None
        without points or when a ray misses the plane.
    """
    if fit.points is None or len(fit.points) < MIN_RIM_POINTS:
        return None
    f = np.array([K[0, 0], K[1, 1]])
    x = (fit.points - K[:2, 2]) / f  # (N, 2) normalised
    rays = np.concatenate([x, np.ones((len(x), 1))], axis=1)
    along = rays @ n
    if np.any(np.abs(along) < 1e-9):
        return None
    z = float(n @ p_eye) / along  # (N,) depth where each ray meets the ring's plane
    if not np.all(z > 0.0):
        return None
    # the outward normal of the fitted ellipse at each point, normalised coordinates
    C = K.T @ fit.conic() @ K
    g = rays @ C[:, :2]  # (N, 2) half the conic's gradient
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    c = fit.centre - K[:2, 2]
    outward = np.sign(np.einsum("ij,ij->i", g, x - c / f))
    g *= outward[:, None]
    radial_len = np.linalg.norm(x, axis=1)
    cos_theta2 = 1.0 / (1.0 + radial_len**2)
    radial = x / np.maximum(radial_len, 1e-12)[:, None]
    cos_beta2 = np.einsum("ij,ij->i", g, radial) ** 2
    half = tube / z * np.sqrt(cos_beta2 / cos_theta2 + (1.0 - cos_beta2))
    # the points are boundary pixels' centres, half a pixel inside the edge (fit_rim)
    core = fit.points - g * (half[:, None] * f - PIXEL_CENTRE_PX)
    out = _fit(core)
    if out is None:
        return None
    return ImageEllipse(out.centre, out.a, out.b, out.angle, fit.coverage, fit.rms_px, fit.points)
