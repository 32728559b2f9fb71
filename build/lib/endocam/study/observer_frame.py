"""One frame of the automatic observer: colour segmentation and the ring–wire gap it shows.

What the observer knows, as a participant told about the task does: the colours of the ring and
of the wire ("the orange ring, the blue wire") and the ring's shape (a torus whose tube is
``TUBE_FRACTION`` of its outer radius, from :class:`~endocam.task.config.RingConfig`). Nothing
else: no pose, no camera intrinsics, no clearance.

Per frame (:func:`frame_gap_px`):

1. **Segment** the ring and the wire by colour (OpenCV HSV: hue within ``HUE_TOL`` of the
   configured colour's hue, saturation ≥ ``SAT_MIN``, value ≥ ``VAL_MIN``), ring components of
   fewer than ``MIN_RING_PX`` pixels dropped.
2. **The ring's outline**: an ellipse fitted (``cv2.fitEllipse``) to the convex hull of the
   ring's pixels; the hole's outline (the rim's inner edge) is that ellipse shrunk by the tube's
   width, ``2 · TUBE_FRACTION`` of the outline's major semi-axis on both axes.
3. **The wire's band through the hole**: a line fitted (``cv2.fitLine``) to the wire pixels
   inside the hole's outline; ``s`` runs along it, ``q`` across it (px).
4. **The lateral gap** on each side of the band: at the hole's point farthest from the band's
   line on that side (the support point of the hole's ellipse in ``±q``, where the rim's inner
   edge runs parallel to the band), a strip ``±`` one tube radius wide along ``s`` is read
   across the band: from the band's centre line out, the wire's run of pixels, then background,
   then the first ring pixel; the gap is the background between them (px). A side where the wire
   continues over or past that first ring pixel (the wire in front of the rim there, or the band
   not reaching the strip) shows nothing. The frame's gap is the smaller side's; NaN when
   neither side shows one.

Why the support point: if the wire is straight through the hole, the place where it pierces the
ring's plane lies on the band's centre line, and its distance to the hole's outline is at most
the band's lateral distance at the support point. A gap read there is therefore never smaller
than the true one: the wire lying along the rim's inner edge beside the hole (passing in front
of or behind the ring) is not read as contact. It misses touches whose gap closes along the line
of sight or along the band; the validation clips (:mod:`endocam.study.observer_clips`) are views
in which it does not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from endocam.task.config import RGBA, RingConfig, SceneConfig, WireConfig

HUE_TOL = 12  # OpenCV hue units (0..180 ↔ 0..360°): ±24° around the object's hue
SAT_MIN = 110  # 8-bit saturation: the ring and the wire are saturated, board and walls are not
VAL_MIN = 35  # 8-bit value: darker pixels carry no reliable hue
MIN_RING_PX = 12  # px, smaller orange components are noise (or a ring too small to judge)
MIN_BAND_PX = 3  # px, fewest wire pixels inside the hole that make a band
_RING = RingConfig()
_WIRE = WireConfig()
TUBE_FRACTION = _RING.minor_radius / (_RING.major_radius + _RING.minor_radius)  # r / (R + r)
WIRE_FRACTION = _WIRE.radius / (_RING.major_radius + _RING.minor_radius)  # r_w / (R + r)
PIXEL_PX = 1.0  # px, one pixel: adjacent silhouettes have no background between them
BAND_GAP_PX = 1  # px, a hole in the wire's run this small (encoding noise) does not end it
CONTACT_PX = 1.0  # px, a gap this small is contact (the counter's CONTACT_GAP_PX)
RESOLVE_PX = 3.0  # px, a gap this wide is resolvable (the counter's OPEN_GAP_PX)
WIDTH_TOL = 1.25  # unitless, the band may look this much wider than the wire at the ring's depth
# (a wire point nearer the camera than the ring by a fifth of the ring's distance looks wider)
WIDTH_SLACK_PX = 2.0 * PIXEL_PX  # px, encoding blur: one pixel on each edge of the band


# --------------------------------------------------------------------------- segmentation
@dataclass(frozen=True)
class ColourKeys:
    """What the observer knows: the hues of the ring and of the wire (OpenCV units, 0..180)."""

    ring_hue: int
    wire_hue: int

    @classmethod
    def from_rgba(cls, ring_rgba: RGBA, wire_rgba: RGBA) -> ColourKeys:
        """Keys from the scene's RGBA colours (components 0..1)."""
        return cls(ring_hue=_hue(ring_rgba), wire_hue=_hue(wire_rgba))

    @classmethod
    def from_scene(cls, scene: SceneConfig) -> ColourKeys:
        """Keys of a scene config's ring and wire."""
        return cls.from_rgba(scene.ring_rgba, scene.wire_rgba)


def _hue(rgba: RGBA) -> int:
    rgb = np.clip(np.round(np.asarray(rgba[:3]) * 255.0), 0, 255).astype(np.uint8)
    return int(cv2.cvtColor(rgb.reshape(1, 1, 3), cv2.COLOR_RGB2HSV)[0, 0, 0])


def _hue_mask(hsv: NDArray[Any], hue: int) -> NDArray[np.bool_]:
    h = hsv[..., 0].astype(np.int16)
    d = np.abs(h - hue)
    d = np.minimum(d, 180 - d)  # hue is circular
    return np.asarray((d <= HUE_TOL) & (hsv[..., 1] >= SAT_MIN) & (hsv[..., 2] >= VAL_MIN))


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
    ring = _hue_mask(hsv, keys.ring_hue)
    wire = _hue_mask(hsv, keys.wire_hue)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(ring.astype(np.uint8), connectivity=8)
    keep = np.zeros(n, dtype=bool)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= MIN_RING_PX
    return keep[labels], wire


# --------------------------------------------------------------------------- geometry
@dataclass(frozen=True)
class Ellipse:
    """An image ellipse: centre (2,), px; semi-axes ``a`` along ``e1``, ``b`` along ``e2``, px."""

    centre: NDArray[np.float64]
    a: float
    b: float
    e1: NDArray[np.float64]
    e2: NDArray[np.float64]

    def shrunk(self, by_px: float) -> Ellipse:
        """The ellipse with both semi-axes ``by_px`` shorter."""
        return Ellipse(self.centre, self.a - by_px, self.b - by_px, self.e1, self.e2)

    def inside(self, pts: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Which of the (N, 2) points (x, y), px, lie inside."""
        d = pts - self.centre
        return np.asarray(((d @ self.e1) / self.a) ** 2 + ((d @ self.e2) / self.b) ** 2 < 1.0)

    def support(self, n: NDArray[np.float64]) -> NDArray[np.float64]:
        """The point (2,), px, farthest along the unit direction ``n`` (2,)."""
        m = self.a**2 * np.outer(self.e1, self.e1) + self.b**2 * np.outer(self.e2, self.e2)
        return np.asarray(self.centre + m @ n / math.sqrt(float(n @ m @ n)))


def ring_outline(ring: NDArray[np.bool_]) -> Ellipse | None:
    """The ring's outline: an ellipse fitted to the convex hull of its pixels (None: too few)."""
    ys, xs = np.nonzero(ring)
    if xs.size < MIN_RING_PX:
        return None
    hull = cv2.convexHull(np.column_stack([xs, ys]).astype(np.int32))
    if len(hull) < 5:
        return None
    (cx, cy), (d1, d2), angle = cv2.fitEllipse(hull)
    t = math.radians(angle)
    e1 = np.array([math.cos(t), math.sin(t)])
    e2 = np.array([-math.sin(t), math.cos(t)])
    return Ellipse(np.array([cx, cy]), 0.5 * d1, 0.5 * d2, e1, e2)


def frame_gap_px(ring: NDArray[np.bool_], wire: NDArray[np.bool_]) -> float:
    """Lateral gap between the wire's band and the rim's inner edge (see the module docstring).

    Parameters
    ----------
    ring, wire : (H, W) bool
        Masks from :func:`segment`.

    Returns
    -------
    float
        Gap, px (0 = the silhouettes meet); NaN when the frame shows no part of the rim the wire
        could touch (no ring, no wire in its hole, or the place hidden).
    """
    outline = ring_outline(ring)
    if outline is None:
        return math.nan
    scale_px = max(outline.a, outline.b)  # the ring's outer radius R + r, px
    wire_px = WIRE_FRACTION * scale_px  # the wire's radius at the ring's depth, px (= 1 mm)
    if wire_px < RESOLVE_PX:
        return math.nan  # one wire radius spans too few pixels to tell a gap from contact
    tube_px = TUBE_FRACTION * scale_px
    hole = outline.shrunk(2.0 * tube_px)
    reach = math.ceil(scale_px) + 2
    h, w = ring.shape
    cx, cy = outline.centre
    x0, x1 = max(0, int(cx) - reach), min(w, int(cx) + reach + 1)
    y0, y1 = max(0, int(cy) - reach), min(h, int(cy) + reach + 1)
    wy, wx = np.nonzero(wire[y0:y1, x0:x1])
    wire_pts = np.column_stack([wx + x0, wy + y0]).astype(float)
    in_hole = wire_pts[hole.inside(wire_pts)]
    if len(in_hole) < MIN_BAND_PX:
        return math.nan
    vx, vy, px, py = cv2.fitLine(in_hole.astype(np.float32), cv2.DIST_L2, 0, 0.01, 0.01).ravel()
    band = _Band(
        origin=np.array([px, py], dtype=float),
        along=np.array([vx, vy], dtype=float),
        half_strip_px=max(PIXEL_PX, tube_px),
        tube_px=tube_px,
        wire_px=wire_px,
    )
    ry, rx = np.nonzero(ring[y0:y1, x0:x1])
    ring_pts = np.column_stack([rx + x0, ry + y0]).astype(float)
    gaps = [_side_gap(ring_pts, wire_pts, hole, band, sign) for sign in (1.0, -1.0)]
    seen = [g for g in gaps if not math.isnan(g)]
    if not seen or (len(seen) < len(gaps) and min(seen) > CONTACT_PX):
        return math.nan  # one side hidden, the other open: the touch could be on the hidden one
    return min(seen)


@dataclass(frozen=True)
class _Band:
    """The wire's band through the hole, and the ring's scale.

    ``origin`` (2,) and unit ``along`` (2,): the band's line, px; ``half_strip_px``: half the
    strip read across the band; ``tube_px``: the ring tube's radius; ``wire_px``: the wire's
    radius at the ring's depth (all px).
    """

    origin: NDArray[np.float64]
    along: NDArray[np.float64]
    half_strip_px: float
    tube_px: float
    wire_px: float

    @property
    def across(self) -> NDArray[np.float64]:
        """Unit normal (2,) of the band's line."""
        return np.array([-self.along[1], self.along[0]])


def _side_gap(
    ring_pts: NDArray[np.float64],
    wire_pts: NDArray[np.float64],
    hole: Ellipse,
    band: _Band,
    sign: float,
) -> float:
    """The gap (px) on the ``sign · across`` side of the band, at the hole's support point there.

    ``ring_pts``, ``wire_pts``: (N, 2) pixel centres (x, y), px. The strip ``±half_strip_px``
    along the band through the support point is read across it (1 px bins, max-pooled along
    the strip): from the band's centre line out, the wire's run, background, the first rim
    pixel. NaN (nothing seen) when the band does not cross the strip, no rim pixel is in reach,
    the wire continues over or past that rim pixel or its edge lies beyond the hole's outline
    by more than half the tube (the wire in front of the rim hides the place), or the wire's
    run is wider than the wire at the ring's depth allows (``WIDTH_TOL``: that part of the wire
    is nearer the camera than the ring, so its edge beside the rim is not at the ring's plane).
    """
    across = sign * band.across
    p = hole.support(across)
    s_p = float((p - band.origin) @ band.along)
    q_hole = float((p - band.origin) @ across)  # the hole's outline on this side
    n = math.ceil(q_hole + 2.0 * band.tube_px + PIXEL_PX) + 1

    def profile(pts: NDArray[np.float64]) -> NDArray[np.bool_]:
        d = pts - band.origin
        s, q = d @ band.along, d @ across
        pick = (np.abs(s - s_p) <= band.half_strip_px) & (np.abs(q) < n)
        bins = np.zeros(2 * n + 1, dtype=bool)  # bin n + k holds q in [k, k + 1)
        bins[np.floor(q[pick]).astype(int) + n] = True
        return bins

    wire_bins, ring_bins = profile(wire_pts), profile(ring_pts)
    if not wire_bins[n - BAND_GAP_PX - 1 : n + BAND_GAP_PX + 1].any():
        return math.nan  # the band's centre line does not cross the strip
    ring_idx = np.flatnonzero(ring_bins[n:] & ~wire_bins[n:])
    if ring_idx.size == 0:
        return math.nan  # no rim in reach (hidden, or the outline fit off)
    first_ring = int(ring_idx[0])
    if wire_bins[n + first_ring :].any():
        return math.nan  # the wire over or past the rim: the place is hidden in front
    edge = _run_end(wire_bins, n, first_ring, +1)
    if edge > q_hole + band.tube_px:
        return math.nan  # the wire's edge lies over the rim's tube: in front of it, hiding it
    low = _run_end(wire_bins, n, n - 1, -1)
    if edge - low + PIXEL_PX > WIDTH_TOL * 2.0 * band.wire_px + WIDTH_SLACK_PX:
        return math.nan  # wider than the wire at the ring's depth: nearer, in front of the plane
    return float(max(first_ring - edge - PIXEL_PX, 0.0))


def _run_end(bins: NDArray[np.bool_], n: int, limit: int, step: int) -> int:
    """Last bin offset (from the centre bin ``n``) of the wire's run going ``step`` (±1).

    Holes of up to ``BAND_GAP_PX`` bins are bridged; at most ``limit`` bins out.
    """
    k = 0
    while abs(k) + 1 < limit:
        nxt = [n + k + step * j for j in range(1, BAND_GAP_PX + 2)]
        if not any(0 <= i < bins.size and bins[i] for i in nxt):
            break
        k += step
    return k
