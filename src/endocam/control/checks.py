"""The moving policies' input checks: finite poses, a fresh ring pose, the ring gate.

:func:`observed` runs them in their order and answers ``OBS_OK`` or why not (``OBS_*``; the
hold's reason in :data:`CHECK_REASONS`). It is ``register_jitable``: the policies' compiled
steps run it inside their own kernel; :func:`observed_kernel` calls it from Python.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit
from numba.extending import register_jitable

from endocam.control.gate import (
    CLOCK_TOL,
    GATE_ACCEPT,
    GATE_REACQUIRE,
    STALE_REASON,
    GateBounds,
    GateState,
    gate_commit,
    gate_decide,
)
from endocam.geometry import FloatArray
from endocam.kernels import dist3, kernel_array, unit_checked
from endocam.workspace.cone import Cone, cone_margin

__all__ = [
    "CAMERA_REASON",
    "CHECK_REASONS",
    "DEGENERATE_REASON",
    "GATE_REASON",
    "MIN_NORMAL",
    "OBS_CAMERA",
    "OBS_DEGENERATE",
    "OBS_GATE",
    "OBS_OK",
    "OBS_RING",
    "OBS_STALE",
    "RING_REASON",
    "RingChecks",
    "Sighting",
    "finite_pose",
    "observed",
    "observed_kernel",
    "pose_array",
    "tips_array",
]

MIN_NORMAL = 1e-9  # unitless, a ring normal shorter than this is degenerate
GATE_REASON = "ring pose rejected by the observation gate (off the ring's predicted track); holding"
CAMERA_REASON = "camera pose not finite; holding"
RING_REASON = "ring pose missing or not finite"
DEGENERATE_REASON = "ring pose degenerate (zero normal)"

# ``observed``'s answers: the observation is usable, or why not
OBS_OK, OBS_CAMERA, OBS_RING, OBS_STALE, OBS_DEGENERATE, OBS_GATE = range(6)
CHECK_REASONS = (
    "",
    CAMERA_REASON,
    RING_REASON,
    STALE_REASON,
    DEGENERATE_REASON,
    GATE_REASON,
)  # the hold's reason per OBS_* answer


class RingChecks(NamedTuple):
    """The input checks' settings for an episode (built once per episode).

    Attributes
    ----------
    max_age : float
        ``ring_max_age``, s: an older ring pose is stale.
    gate : (1,) record array, ``gate.GATE_STATE``
        ``RingGate.state``, updated in place by the checks.
    bounds : (1,) record array, ``gate.GATE_BOUNDS``
        ``RingGate.bounds``.
    cone : Cone
        The cone workspace's constants (``cone_at``): the gate re-acquires only inside it.
    unit_normal : bool
        The gate gets the unit normal and a degenerate one is refused (``OBS_DEGENERATE``;
        the ``endocam`` tracker); else the normal as observed, and a degenerate one passes
        (the paper's policies: their goal reports it).
    """

    max_age: float
    gate: GateState
    bounds: GateBounds
    cone: Cone
    unit_normal: bool


class Sighting(NamedTuple):
    """One observation as the compiled steps read it (world, m; times in s).

    ``T_cam``, ``T_ring`` (4, 4) the camera and ring poses; ``tips`` (K, 3) the instrument
    tips; ``t`` the control time; ``t_ring`` when the ring pose was captured (an unstamped
    pose: ``t``, never stale).
    """

    T_cam: FloatArray
    T_ring: FloatArray
    tips: FloatArray
    t: float
    t_ring: float


@register_jitable  # also callable from compiled kernels (the same source)
def finite_pose(T: FloatArray) -> bool:
    """Whether every entry of ``T`` (4, 4) is finite (``kernels.finite_rows``' test)."""
    for i in range(4):
        for j in range(4):
            if not math.isfinite(T[i, j]):
                return False
    return True


@register_jitable  # also callable from compiled kernels (the same source)
def observed(checks: RingChecks, seen: Sighting) -> int:
    """The input checks in their order, the ring gate last: ``OBS_OK`` or why not.

    ``seen``'s camera or ring pose not finite: ``OBS_CAMERA`` / ``OBS_RING``. The ring pose
    captured at ``seen.t_ring`` is stale at ``seen.t`` beyond ``checks.max_age`` or
    ``CLOCK_TOL`` in the future (``safety.is_stale``): ``OBS_STALE``. Then the normal
    (``checks.unit_normal``) and the gate (``gate.RingGate``'s rule on ``checks.gate``, at
    the pose's capture time ``seen.t_ring``; re-acquired only inside ``checks.cone``):
    ``OBS_GATE`` when it rejects.
    """
    T_ring = seen.T_ring
    if not finite_pose(seen.T_cam):
        return OBS_CAMERA
    if not finite_pose(T_ring):
        return OBS_RING
    age = seen.t - seen.t_ring
    if not (-CLOCK_TOL <= age <= checks.max_age):
        return OBS_STALE
    n = (T_ring[0, 2], T_ring[1, 2], T_ring[2, 2])
    if checks.unit_normal:
        ok, n = unit_checked(n)
        if not ok:
            return OBS_DEGENERATE
    elif not dist3(n[0], n[1], n[2], 0.0, 0.0, 0.0) > MIN_NORMAL:
        return OBS_OK
    x = (T_ring[0, 3], T_ring[1, 3], T_ring[2, 3], n[0], n[1], n[2])
    decision = gate_decide(checks.gate, checks.bounds, seen.t_ring, x)  # at its capture time
    ok = decision == GATE_ACCEPT
    if decision == GATE_REACQUIRE:  # re-acquired only inside the workspace (ConeWorkspace.contains)
        a, axis, tan_half, cos_half, height = checks.cone
        margin = cone_margin(x[0], x[1], x[2], a, axis, tan_half, cos_half, height)
        ok = math.isfinite(margin) and margin >= 0.0
    gate_commit(checks.gate, seen.t_ring, x, ok)
    return OBS_OK if ok else OBS_GATE


@njit(cache=True)  # compiled once, then loaded from __pycache__ (or NUMBA_CACHE_DIR)
def observed_kernel(checks: RingChecks, seen: Sighting) -> int:  # pragma: no cover - compiled
    """:func:`observed` from Python (the oracle's checks)."""
    return observed(checks, seen)


def pose_array(T: object) -> FloatArray | None:
    """``T`` as a (4, 4) float array (itself when it is one), or ``None`` (missing, wrong shape).

    The boundary from an observation into the compiled steps (C-contiguous: they are called
    at a fixed signature, ``fixed_signature.FixedSignature``; writable, a read-only array
    copied: numba compiles a kernel once per argument type, and a read-only array is another
    type, a second compile of the whole step).
    """
    if type(T) is np.ndarray and T.dtype == np.float64 and T.shape == (4, 4):
        return kernel_array(T)
    if T is None:
        return None
    arr = kernel_array(np.asarray(T, dtype=float))
    return arr if arr.shape == (4, 4) else None


def tips_array(tips: object) -> FloatArray:
    """``tips`` as a C-contiguous, writable (K, 3) float array (itself when it is one), world, m.

    Writable as :func:`pose_array`'s poses: a read-only array is copied.
    """
    if type(tips) is np.ndarray and tips.dtype == np.float64 and tips.ndim == 2:
        return kernel_array(tips)
    return kernel_array(np.asarray(tips, dtype=float).reshape(-1, 3))
