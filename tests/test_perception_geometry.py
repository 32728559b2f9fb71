"""The estimator's pure parts: segmentation, rim fit, a circle's pose from its conic, the choice.

No rendering: synthetic conics, drawn masks and random HSV images, seeded.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from endocam.camera import StereoCamera
from endocam.geometry import FloatArray
from endocam.perception.disparity import plane_normal
from endocam.perception.ellipse import (
    ImageEllipse,
    centre_image,
    circle_normals,
    core_ellipse,
    fit_rim,
    radius_over_distance,
)
from endocam.perception.estimator import choose_normal
from endocam.perception.segment import HUE_TOL, SAT_MIN, VAL_MIN, ColourKeys, hue_mask, segment
from endocam.task.config import SceneConfig

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)

K = StereoCamera().intrinsics.K
ATOL_UNIT = 1e-9  # unitless, unit vectors and normalised image coordinates from exact conics
RTOL_RADIUS = 1e-9  # unitless, the radius from an exact conic
PLANE_ATOL = 1e-6  # unitless: exact conics, but a least-squares fit of disparities ~1e-3
FIT_TOL_PX = 0.5  # px, a drawn ellipse's fit: half a pixel (the pixel grid's resolution)


def random_circle(rng: np.random.Generator) -> tuple[FloatArray, FloatArray, float]:
    """A circle in front of the eye: centre (3,), m; unit normal (3,) facing the eye; radius, m."""
    p = np.array([rng.uniform(-0.02, 0.02), rng.uniform(-0.02, 0.02), rng.uniform(0.03, 0.12)])
    tilt = rng.uniform(0.0, math.radians(70.0))
    az = rng.uniform(0.0, 2.0 * math.pi)
    n = np.array([math.sin(tilt) * math.cos(az), math.sin(tilt) * math.sin(az), -math.cos(tilt)])
    return p, n, rng.uniform(0.003, 0.008)


def exact_conic(p: FloatArray, n: FloatArray, rho: float) -> FloatArray:
    """(3, 3) normalised image conic of a circle, fitted exactly to 64 of its projected points."""
    e1 = np.cross(n, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    phi = np.linspace(0.0, 2.0 * math.pi, 64, endpoint=False)
    X = p + rho * (np.outer(np.cos(phi), e1) + np.outer(np.sin(phi), e2))
    x, y = X[:, 0] / X[:, 2], X[:, 1] / X[:, 2]
    D = np.stack([x * x, x * y, y * y, x, y, np.ones_like(x)], axis=1)
    a, b, c, d, e, f = np.linalg.svd(D)[2][-1]
    return np.array([[a, b / 2, d / 2], [b / 2, c, e / 2], [d / 2, e / 2, f]])


def test_a_circles_normal_centre_and_radius_from_its_image() -> None:
    rng = np.random.default_rng(0)
    for _ in range(25):
        p, n, rho = random_circle(rng)
        Q = exact_conic(p, n, rho)
        cands = circle_normals(Q)
        assert cands is not None
        err = [np.linalg.norm(c - n) for c in cands]
        assert min(err) < ATOL_UNIT  # the true normal is one of the two
        assert all(c[2] < 0.0 for c in cands)  # both face the eye
        xy = centre_image(Q, n)
        assert xy is not None
        np.testing.assert_allclose(xy, p[:2] / p[2], atol=ATOL_UNIT)
        d = abs(float(n @ p))
        np.testing.assert_allclose(d * radius_over_distance(Q), rho, rtol=RTOL_RADIUS)


def test_the_second_candidate_is_the_mirror_image() -> None:
    """Tilted 40°, the other candidate is ~80° off: one view cannot tell them apart."""
    p = np.array([0.0, 0.0, 0.05])
    n = np.array([math.sin(math.radians(40.0)), 0.0, -math.cos(math.radians(40.0))])
    cands = circle_normals(exact_conic(p, n, 0.005))
    assert cands is not None
    off = sorted(math.degrees(math.acos(min(1.0, abs(float(c @ n))))) for c in cands)
    assert off[0] < 1e-6
    assert 70.0 < off[1] < 90.0


@pytest.mark.parametrize("tilt_deg", [0.0, 1.0, 5.0, 40.0])
def test_the_disparity_plane_gives_the_normal(tilt_deg: float) -> None:
    """Two eyes' exact conics of one circle: the row-matched disparities' plane is its plane,
    along the axis too (where the ellipse's shape barely changes with the tilt)."""
    rng = np.random.default_rng(1)
    baseline = StereoCamera().baseline
    for _ in range(5):
        p, _, rho = random_circle(rng)
        az = rng.uniform(0.0, 2.0 * math.pi)
        tilt = math.radians(tilt_deg)
        sight = -p / np.linalg.norm(p)  # from the ring to the camera
        side = np.cross(sight, [math.cos(az), math.sin(az), 0.0])
        n = math.cos(tilt) * sight + math.sin(tilt) * side / np.linalg.norm(side)
        half = np.array([0.5 * baseline, 0.0, 0.0])  # the eyes sit at ∓baseline/2 along x
        got = plane_normal(exact_conic(p + half, n, rho), exact_conic(p - half, n, rho))
        assert got is not None
        assert got[2] < 0.0  # faces the eyes
        np.testing.assert_allclose(got, n, atol=PLANE_ATOL)


def test_not_an_ellipse_gives_none() -> None:
    no_points = np.eye(3)  # x² + y² + z² = 0: an imaginary cone
    assert circle_normals(no_points) is None
    assert math.isnan(radius_over_distance(no_points))


def test_the_pair_that_agrees_is_chosen() -> None:
    n = np.array([0.3, 0.1, -0.9])
    n /= np.linalg.norm(n)
    mirror_l = np.array([-0.4, 0.1, -0.9])
    mirror_r = np.array([-0.35, 0.2, -0.9])
    close = n + np.array([0.01, 0.0, 0.0])
    unit = [v / np.linalg.norm(v) for v in (mirror_l, mirror_r, close)]
    for left, right in [((n, unit[0]), (unit[1], unit[2])), ((unit[0], n), (unit[2], unit[1]))]:
        choice = choose_normal(left, right)
        assert math.acos(min(1.0, float(choice.n @ n))) < math.radians(1.0)
        assert choice.margin > 0.0
        assert choice.separation > math.radians(30.0)


@pytest.mark.parametrize("hue", [0, 5, 11, 90, 168, 175, 179])
def test_hue_mask_is_the_circular_hue_rule(hue: int) -> None:
    """``cv2.inRange`` over one or two intervals equals the circular distance rule."""
    rng = np.random.default_rng(hue)
    hsv = np.stack(
        [
            rng.integers(0, 180, size=(64, 64)),
            rng.integers(0, 256, size=(64, 64)),
            rng.integers(0, 256, size=(64, 64)),
        ],
        axis=-1,
    ).astype(np.uint8)
    d = np.abs(hsv[..., 0].astype(np.int16) - hue)
    d = np.minimum(d, 180 - d)
    expected = (d <= HUE_TOL) & (hsv[..., 1] >= SAT_MIN) & (hsv[..., 2] >= VAL_MIN)
    np.testing.assert_array_equal(hue_mask(hsv, hue), expected)


def test_segmenting_a_frame_without_the_ring_or_the_wire() -> None:
    """No ring-hued pixel at all (an empty box for the labelling): empty masks, no crash."""
    keys = ColourKeys.from_scene(SceneConfig())
    grey = np.full((24, 32, 3), 128, dtype=np.uint8)
    ring, wire = segment(grey, keys)
    assert ring.shape == wire.shape == (24, 32)
    assert not ring.any() and not wire.any()
    speck = grey.copy()
    speck[5, 5] = (255, 158, 13)  # one ring-coloured pixel: a component under MIN_RING_PX
    assert not segment(speck, keys)[0].any()


PIXEL_CENTRE_PX = 0.5  # px: pixel (i, j)'s centre is (j + 0.5, i + 0.5) (docs/conventions.md)


def drawn_ring(centre: tuple[int, int], axes: tuple[int, int], angle_deg: float) -> np.ndarray:
    """(240, 320) bool mask of a filled elliptical ring (tube 6 px wide).

    OpenCV draws on pixel indices: the ring's centre is ``centre + PIXEL_CENTRE_PX`` in image
    coordinates.
    """
    mask = np.zeros((240, 320), np.uint8)
    cv2.ellipse(mask, centre, axes, angle_deg, 0, 360, 1, -1)
    inner = (axes[0] - 6, axes[1] - 6)
    cv2.ellipse(mask, centre, inner, angle_deg, 0, 360, 0, -1)
    return mask.astype(bool)


def test_the_rim_fit_leaves_out_an_occluders_edge() -> None:
    """A band (the wire) across the rim: its straight cut edges are not the ring's."""
    mask = drawn_ring((160, 120), (50, 35), 20.0)
    wire = np.zeros_like(mask)
    wire[100:112, :] = True  # a horizontal band in front of the ring, 12 px wide
    ring = mask & ~wire
    fit = fit_rim(ring, wire)
    assert fit is not None and fit.points is not None
    centre = np.array([160.0, 120.0]) + PIXEL_CENTRE_PX
    assert np.all(np.abs(fit.centre - centre) < FIT_TOL_PX)
    assert abs(fit.a - 50.5) < FIT_TOL_PX and abs(fit.b - 35.5) < FIT_TOL_PX
    rows = fit.points[:, 1] - PIXEL_CENTRE_PX
    near_band = (rows >= 100 - 2) & (rows <= 111 + 2)  # OCCLUDER_PX
    assert not near_band.any()
    assert fit.coverage < 1.0


def test_the_rim_fit_leaves_out_the_image_border() -> None:
    mask = drawn_ring((300, 120), (50, 40), 0.0)  # 30 px of the ring beyond the right edge
    fit = fit_rim(mask)
    assert fit is not None and fit.points is not None
    assert fit.points[:, 0].max() < 319
    assert abs(fit.centre[0] - (300 + PIXEL_CENTRE_PX)) < 2 * FIT_TOL_PX


def test_ellipse_conic_and_distances_agree() -> None:
    e = ImageEllipse(np.array([100.0, 80.0]), 30.0, 12.0, math.radians(25.0))
    t = np.linspace(0.0, 2.0 * math.pi, 50)
    c, s = math.cos(e.angle), math.sin(e.angle)
    pts = e.centre + np.stack(
        [e.a * np.cos(t) * c - e.b * np.sin(t) * s, e.a * np.cos(t) * s + e.b * np.sin(t) * c], 1
    )
    h = np.c_[pts, np.ones(len(pts))]
    np.testing.assert_allclose(np.einsum("ni,ij,nj->n", h, e.conic(), h), 0.0, atol=1e-9)
    np.testing.assert_allclose(e.distances(pts), 0.0, atol=1e-9)


def test_rim_points_are_pixel_centres() -> None:
    """A disk whose pixels are those with their centre inside it: the fit finds its centre.

    Pixel (i, j) is in the mask when ``(j + ½, i + ½)`` lies within ``rho`` of the centre, so the
    fit is centred on it, not half a pixel up and left (OpenCV's contour indices).
    """
    centre, rho = np.array([100.3, 80.7]), 30.0  # px
    v, u = np.mgrid[0:160, 0:200] + PIXEL_CENTRE_PX
    mask = (u - centre[0]) ** 2 + (v - centre[1]) ** 2 <= rho**2
    fit = fit_rim(mask)
    assert fit is not None
    assert np.all(np.abs(fit.centre - centre) < DISK_CENTRE_TOL_PX)
    assert abs(fit.a - rho) < FIT_TOL_PX and abs(fit.b - rho) < FIT_TOL_PX


DISK_CENTRE_TOL_PX = 0.15  # px: a 30 px disk's pixel staircase moves its fit ~0.05 px
CORE_TOL_PX = 0.08  # px: the per-point offset model misses by ≤ 0.04 px (1 mm tube, 5 cm)
NAIVE_MIN_PX = 0.3  # px: the uniform shrink misses by 0.65-0.71 px in the same views


def torus_outline(T_eye_ring: FloatArray, R: float, r: float) -> FloatArray:
    """(M, 2) px, the exact outer silhouette of a torus in an eye (its contour generator).

    A point ``c + r (cos ψ u + sin ψ n)`` of the tube about the core point ``c`` (radial ``u``,
    face normal ``n``) is on the contour where its surface normal is across the ray:
    ``A cos ψ + B sin ψ = −r`` with ``A = u · c``, ``B = n · c`` (the eye at the origin); of the
    two roots per ``φ``, the one farther from the ring's image centre.
    """
    phi = np.linspace(0.0, 2.0 * math.pi, 720, endpoint=False)
    Rm, t = T_eye_ring[:3, :3], T_eye_ring[:3, 3]
    u = np.stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)], axis=1) @ Rm.T
    n = Rm[:, 2]
    c = t + R * u
    A, B = np.einsum("ij,ij->i", u, c), c @ n
    base, half = np.arctan2(B, A), np.arccos(-r / np.hypot(A, B))
    centre = (K @ (t / t[2]))[:2]
    best = None
    for psi in (base + half, base - half):
        X = c + r * (np.cos(psi)[:, None] * u + np.sin(psi)[:, None] * n)
        uv = (X[:, :2] / X[:, 2:3]) * [K[0, 0], K[1, 1]] + K[:2, 2]
        if best is None:
            best = uv
        else:
            far = np.linalg.norm(uv - centre, axis=1) > np.linalg.norm(best - centre, axis=1)
            best = np.where(far[:, None], uv, best)
    assert best is not None
    return best


def test_the_core_is_found_by_perspective_off_the_optical_axis() -> None:
    """A ring 12° off an eye's axis and tilted: its core's image from the exact silhouette.

    The silhouette's points moved half a pixel inwards (boundary pixels' centres, as
    :func:`fit_rim` gives them); the core ellipse must pass through the core circle's image,
    which shrinking the fitted outline by one tube width all round misses on the far side.
    """
    R, r = 5.0e-3, 1.0e-3  # m, the default ring
    rng = np.random.default_rng(3)
    for _ in range(3):
        p = np.array([math.tan(math.radians(12.0)) * 0.05, rng.uniform(-0.003, 0.003), 0.05])
        tilt, az = math.radians(rng.uniform(0.0, 10.0)), rng.uniform(0.0, 2.0 * math.pi)
        sight = -p / np.linalg.norm(p)
        side = np.cross(sight, [math.cos(az), math.sin(az), 0.0])
        n = math.cos(tilt) * sight + math.sin(tilt) * side / np.linalg.norm(side)
        T = np.eye(4)
        T[:3, 2] = n
        T[:3, 0] = np.cross([0.0, 1.0, 0.0], n) / np.linalg.norm(np.cross([0.0, 1.0, 0.0], n))
        T[:3, 1] = np.cross(n, T[:3, 0])
        T[:3, 3] = p
        outline = torus_outline(T, R, r)
        (cu, cv), (d1, d2), ang = cv2.fitEllipse(outline.astype(np.float32))
        inward = -(outline - [cu, cv]) / np.linalg.norm(outline - [cu, cv], axis=1)[:, None]
        pts = outline + PIXEL_CENTRE_PX * inward
        a, b, angle = 0.5 * d1, 0.5 * d2, math.radians(ang)
        if b > a:
            a, b, angle = b, a, angle + 0.5 * math.pi
        fit = ImageEllipse(np.array([cu, cv]), a, b, angle, points=pts)
        phi = np.linspace(0.0, 2.0 * math.pi, 90, endpoint=False)
        e1, e2 = T[:3, 0], T[:3, 1]
        X = p + R * (np.outer(np.cos(phi), e1) + np.outer(np.sin(phi), e2))
        core_px = X[:, :2] / X[:, 2:3] * [K[0, 0], K[1, 1]] + K[:2, 2]
        core = core_ellipse(fit, K, r, p, n)
        assert core is not None
        assert float(np.max(core.distances(core_px))) < CORE_TOL_PX
        naive = fit.shrunk(K[0, 0] * r / p[2])
        assert float(np.max(naive.distances(core_px))) > NAIVE_MIN_PX
