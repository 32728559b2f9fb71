"""The tool-in-view windows and the working-distance rule (paper Sec. III-C).

:func:`window_status` classifies the instrument tips against a centred inner and outer image
window; :func:`adjust_working_distance` makes the working distance grow by a fixed step per
control step while a tip is outside the outer window, shrink while all are inside the inner
one, and hold in between. The rule is compiled (:func:`window_code`, :func:`adjusted_distance`)
for the policies' own kernels.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numpy as np
from numba.extending import register_jitable

from endocam.camera import MIN_DEPTH, StereoCamera
from endocam.geometry import FloatArray

D_F_STEP = 1.0e-3  # m, working-distance change per control step (paper: ±1 mm)
# window_code's answers (WindowStatus's members, in this order)
WINDOW_OUTSIDE_OUTER, WINDOW_BETWEEN, WINDOW_INSIDE_INNER = 0, 1, 2


class WindowStatus(enum.Enum):
    """Where the instrument tips project relative to the inner and outer image windows."""

    OUTSIDE_OUTER = "outside_outer"  # at least one tip is outside the outer window (or unseen)
    BETWEEN = "between"  # every tip inside the outer window, not all inside the inner one
    INSIDE_INNER = "inside_inner"  # every tip inside the inner window


@dataclass(frozen=True)
class ImageWindows:
    """Centred inner and outer windows as fractions of the image width and height.

    Attributes
    ----------
    inner_frac : float
        Inner window size as a fraction of the image (0 < inner < outer).
    outer_frac : float
        Outer window size as a fraction of the image (≤ 1).
    """

    inner_frac: float = 0.5
    outer_frac: float = 0.9

    def __post_init__(self) -> None:
        if not (0.0 < self.inner_frac < self.outer_frac <= 1.0):
            raise ValueError(
                f"need 0 < inner_frac < outer_frac ≤ 1, got {self.inner_frac}, {self.outer_frac}"
            )


class WindowConstants(NamedTuple):
    """What the compiled window test reads of a camera and its windows (one named argument)."""

    fx: float  # px, focal length along u
    fy: float  # px, focal length along v
    du0: float  # px, the principal point's u less the image centre's
    dv0: float  # px, the principal point's v less the image centre's
    half_baseline: float  # m, half the stereo baseline (each eye's offset along x)
    outer_half_width: float  # px
    outer_half_height: float  # px
    inner_half_width: float  # px
    inner_half_height: float  # px


@dataclass(frozen=True)
class WindowGeometry:
    """Plain-float constants of the window test for one camera (computed once per episode).

    Attributes
    ----------
    fx, fy, cx, cy : float
        Intrinsics, px.
    u0, v0 : float
        Image centre, px.
    half_baseline : float
        Half the stereo baseline, m.
    outer, inner : tuple of float
        Half width and half height of the outer and inner windows, px.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    u0: float
    v0: float
    half_baseline: float
    outer: tuple[float, float]
    inner: tuple[float, float]

    @classmethod
    def of(cls, camera: StereoCamera, windows: ImageWindows) -> WindowGeometry:
        """Constants for ``camera`` and ``windows``."""
        k = camera.intrinsics
        w, h = 0.5 * k.width, 0.5 * k.height
        return cls(
            k.fx,
            k.fy,
            k.cx,
            k.cy,
            w,
            h,
            0.5 * camera.baseline,
            (windows.outer_frac * w, windows.outer_frac * h),
            (windows.inner_frac * w, windows.inner_frac * h),
        )

    @cached_property
    def constants(self) -> WindowConstants:
        """:func:`window_code`'s constants (a tuple of nine floats, in its fields' order)."""
        return WindowConstants(
            self.fx,
            self.fy,
            self.cx - self.u0,
            self.cy - self.v0,
            self.half_baseline,
            *self.outer,
            *self.inner,
        )


def window_status(
    camera: StereoCamera,
    T_world_cam: FloatArray,
    p_world_tips: FloatArray,
    windows: ImageWindows,
) -> WindowStatus:
    """Classify the instrument tips against the windows in both eyes (paper Sec. III-C).

    A tip counts as inside a window only if it projects inside it in both eyes; a tip at or
    behind an eye's image plane is outside every window.

    Parameters
    ----------
    camera : StereoCamera
    T_world_cam : (4, 4)
        Current camera pose, optical frame, m.
    p_world_tips : (K, 3)
        Instrument tip positions in world, m. Tips with non-finite coordinates (tool tracking
        lost) are ignored; with no usable tip the status is ``BETWEEN``, so ``d_f`` holds
        rather than moving the camera closer without knowing where the tools are.
    windows : ImageWindows
    """
    tips = np.asarray(p_world_tips, dtype=float).reshape(-1, 3).tolist()
    return window_status_rows(
        WindowGeometry.of(camera, windows), np.asarray(T_world_cam).tolist(), tips
    )


_STATUSES = (WindowStatus.OUTSIDE_OUTER, WindowStatus.BETWEEN, WindowStatus.INSIDE_INNER)
_STATUS_CODES = {status: code for code, status in enumerate(_STATUSES)}


@register_jitable  # also callable from compiled kernels (the same source)
def window_code(
    T: Sequence[Sequence[float]] | FloatArray,
    tips: Sequence[Sequence[float]] | FloatArray,
    w: WindowConstants,
) -> int:
    """:func:`window_status_rows` as a ``WINDOW_*`` code (``WindowStatus``'s members in order).

    ``T`` (4, 4) rows of ``T_world_cam`` (m), ``tips`` (K, 3) world, m, rows; ``w``: the
    camera's and the windows' constants.
    """
    half_b = w.half_baseline
    R0, R1, R2 = T[0], T[1], T[2]
    t0, t1, t2 = R0[3], R1[3], R2[3]
    all_inner = True
    usable = False
    for i in range(len(tips)):
        p = tips[i]
        if not math.isfinite(p[0] + p[1] + p[2]):
            continue
        usable = True
        d0, d1, d2 = p[0] - t0, p[1] - t1, p[2] - t2
        # R^T d: the tip in the camera (centre) frame.
        x = R0[0] * d0 + R1[0] * d1 + R2[0] * d2
        y = R0[1] * d0 + R1[1] * d1 + R2[1] * d2
        z = R0[2] * d0 + R1[2] * d1 + R2[2] * d2
        if not z > MIN_DEPTH:  # also catches NaN
            return WINDOW_OUTSIDE_OUTER
        dv = abs(w.fy * y / z + w.dv0)
        for x_eye in (x + half_b, x - half_b):  # left eye at −b/2, right eye at +b/2
            du = abs(w.fx * x_eye / z + w.du0)
            if not (du <= w.outer_half_width and dv <= w.outer_half_height):
                return WINDOW_OUTSIDE_OUTER
            if not (du <= w.inner_half_width and dv <= w.inner_half_height):
                all_inner = False
    if not usable:
        return WINDOW_BETWEEN  # no tool position known: hold d_f, never zoom in blind
    return WINDOW_INSIDE_INNER if all_inner else WINDOW_BETWEEN


@register_jitable  # also callable from compiled kernels (the same source)
def window_code_of(
    T: Sequence[Sequence[float]] | FloatArray,
    tips: Sequence[Sequence[float]] | FloatArray,
    constants: Sequence[float] | FloatArray,
) -> int:
    """:func:`window_code` with its constants as nine floats in :class:`WindowConstants`' order.

    For a caller that keeps them in a parameter array (``WindowGeometry.constants`` copied in).
    """
    c = constants
    w = WindowConstants(c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8])
    return window_code(T, tips, w)


def window_status_rows(
    g: WindowGeometry, T_world_cam: list[list[float]], p_world_tips: list[list[float]]
) -> WindowStatus:
    """:func:`window_status` on plain lists (rows of ``T_world_cam``, tip rows), for the loop."""
    return _STATUSES[window_code_of(T_world_cam, p_world_tips, g.constants)]


@register_jitable  # also callable from compiled kernels (the same source)
def adjusted_distance(d_f: float, code: int, d_min: float, d_max: float, step: float) -> float:
    """:func:`adjust_working_distance` for a :func:`window_code` ``code``, m."""
    if code == WINDOW_OUTSIDE_OUTER:
        d_f += step
    elif code == WINDOW_INSIDE_INNER:
        d_f -= step
    return min(max(d_f, d_min), d_max)


def adjust_working_distance(
    d_f: float, status: WindowStatus, d_min: float, d_max: float, step: float = D_F_STEP
) -> float:
    """One control step of the working-distance rule, clamped to ``[d_min, d_max]`` (m).

    Parameters
    ----------
    d_f : float
        Current working distance, m.
    status : WindowStatus
        Result of :func:`window_status` for the current image.
    d_min, d_max : float
        Allowed range, m.
    step : float
        Change per control step, m (paper: 1 mm).
    """
    return adjusted_distance(d_f, _STATUS_CODES[status], d_min, d_max, step)
