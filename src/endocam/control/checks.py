"""The policies' input checks: finite poses, a fresh ring pose, the ring gate (``observed``)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numba.extending import register_jitable

from endocam.control.safety import (
    CLOCK_TOL,
    STALE_REASON,
    gate_commit,
    gate_decide,
)
from endocam.geometry import FloatArray
from endocam.kernels import (
    dist3,
    unit_checked,
)
from endocam.workspace.cone import Cone, cone_at, cone_margin

MIN_NORMAL = 1e-9  # unitless, a ring normal shorter than this is degenerate
GATE_REASON = "ring pose rejected by the observation gate (moved too fast); holding"
CAMERA_REASON = "camera pose not finite; holding"
RING_REASON = "ring pose missing or not finite"

# ``observed``'s answers: the observation is usable, or why not
OBS_OK, OBS_CAMERA, OBS_RING, OBS_STALE, OBS_DEGENERATE, OBS_GATE = range(6)
CHECK_REASONS = (
    "",
    CAMERA_REASON,
    RING_REASON,
    STALE_REASON,
    "ring pose degenerate (zero normal)",
    GATE_REASON,
)  # the hold's reason per OBS_* answer


@register_jitable  # also callable from compiled kernels (the same source)
def finite_pose(T: FloatArray) -> bool:
    """Whether every entry of ``T`` (4, 4) is finite (``kernels.finite_rows``' test)."""
    for i in range(4):
        for j in range(4):
            if not math.isfinite(T[i, j]):
                return False
    return True


@register_jitable  # also callable from compiled kernels (the same source)
def observed(
    T_cam: FloatArray,
    T_ring: FloatArray,
    t: float,
    has_t_ring: bool,
    t_ring: float,
    max_age: float,
    gate: FloatArray,
    bounds: FloatArray,
    cone: Cone,
    unit_normal: bool,
) -> int:
    """The policies' input checks in their order, the ring gate last: ``OBS_OK`` or why not.

    ``T_cam``, ``T_ring`` (4, 4) the observed camera and ring poses, world, m: not finite,
    ``OBS_CAMERA`` / ``OBS_RING``. The ring pose captured at ``t_ring`` (s; unstamped: not
    ``has_t_ring``) is stale at ``t`` (s) beyond ``max_age`` (s) or ``CLOCK_TOL`` in the
    future (``safety.is_stale``): ``OBS_STALE``. ``unit_normal`` (the tracker): the gate gets
    the unit normal, and a degenerate one is ``OBS_DEGENERATE``; else (the moving policies)
    the gate gets the normal as observed and a degenerate one passes (the goal reports it).
    The gate (``safety.RingGate``: its ``state`` and ``bounds``; re-acquired only inside the
    ``cone``): ``OBS_GATE`` when it rejects.
    """
    if not finite_pose(T_cam):
        return OBS_CAMERA
    if not finite_pose(T_ring):
        return OBS_RING
    if has_t_ring:
        age = t - t_ring
        if not (-CLOCK_TOL <= age <= max_age):
            return OBS_STALE
    n = (T_ring[0, 2], T_ring[1, 2], T_ring[2, 2])
    if unit_normal:
        ok, n = unit_checked(n)
        if not ok:
            return OBS_DEGENERATE
    elif not dist3(n[0], n[1], n[2], 0.0, 0.0, 0.0) > MIN_NORMAL:  # math.hypot(*n)
        return OBS_OK
    x = (T_ring[0, 3], T_ring[1, 3], T_ring[2, 3], n[0], n[1], n[2])
    decision = gate_decide(gate, bounds, t, x)
    ok = decision == 1
    if decision == 2:  # re-acquired only inside the workspace (ConeWorkspace.contains)
        a, axis, tan_half, cos_half, height = cone
        margin = cone_margin(x[0], x[1], x[2], a, axis, tan_half, cos_half, height)
        ok = math.isfinite(margin) and margin >= 0.0
    gate_commit(gate, t, x, ok)
    return OBS_OK if ok else OBS_GATE


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def observed_kernel(
    T_cam: FloatArray,
    T_ring: FloatArray,
    t: float,
    has_t_ring: bool,
    t_ring: float,
    max_age: float,
    gate: FloatArray,
    bounds: FloatArray,
    params: FloatArray,
    i_cone: int,
    unit_normal: bool,
) -> int:  # pragma: no cover - compiled
    """:func:`observed` from Python, the cone stored from ``params[i_cone]`` (the oracle's)."""
    cone = cone_at(params, i_cone)
    return observed(T_cam, T_ring, t, has_t_ring, t_ring, max_age, gate, bounds, cone, unit_normal)


def pose_array(T: object) -> FloatArray | None:
    """``T`` as a (4, 4) float array (itself when it is one), or ``None`` (missing, wrong shape).

    The boundary from an observation into the compiled checks (:func:`observed`).
    """
    if type(T) is np.ndarray and T.dtype == np.float64 and T.shape == (4, 4):
        return T
    if T is None:
        return None
    arr = np.asarray(T, dtype=float)
    return arr if arr.shape == (4, 4) else None
