"""Where the camera may be: the cone, the floor and the wire's keep-out zone, with named queries.

:class:`Workspace` is what both the controllers (their goals) and the carriers (every step they
take, and every braking path) keep the camera inside. Its compiled queries take one named
:class:`WorkspaceState`; the carriers' own kernels call them directly.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit

from endocam.geometry import FloatArray
from endocam.workspace.cone import ConeWorkspace, cone_at, cone_first_outside, cone_floor_margin
from endocam.workspace.keepout import (
    NO_KEEP_OUT,
    KeepOut,
    KeepOutState,
    keep_out_distance,
    keep_out_first_outside,
)

__all__ = [
    "NO_WORKSPACE",
    "Workspace",
    "WorkspaceState",
    "workspace_all_inside",
    "workspace_keep_out_margin",
    "workspace_margin",
]


class WorkspaceState(NamedTuple):
    """A workspace as its compiled queries read it (one named argument).

    Attributes
    ----------
    cone : (9,) float
        :attr:`ConeWorkspace.constants`: apex (world, m), unit axis, tan and cos of the
        half-angle, height (m).
    floor : float
        Lowest camera height (world z), m.
    keep : bool
        Whether there is a keep-out zone (``zone`` is a placeholder otherwise, never read).
    zone : KeepOutState
        The keep-out zone's state.
    """

    cone: FloatArray
    floor: float
    keep: bool
    zone: KeepOutState


NO_WORKSPACE = WorkspaceState(np.zeros(9), 0.0, False, NO_KEEP_OUT)
"""A compiled caller's placeholder for no workspace (never read: it asks no query then)."""


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def workspace_keep_out_margin(ws: WorkspaceState, x: float, y: float, z: float) -> float:
    """:meth:`Workspace.keep_out_margin` of ``(x, y, z)``, world, m: inf without a zone, m.

    The zone's surface distance less the clearance (a lower bound when positive).
    """
    if not ws.keep:
        return math.inf
    return keep_out_distance(ws.zone, x, y, z, 0.0) - ws.zone.clearance


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def workspace_margin(ws: WorkspaceState, x: float, y: float, z: float) -> float:
    """:meth:`Workspace.margin` of the point ``(x, y, z)``, world, m: > 0 inside, m.

    ``min(cone margin, z − floor, keep-out margin)``; NaN for a non-finite point.
    """
    m = cone_floor_margin(x, y, z, ws.cone, ws.floor)
    if ws.keep:
        return min(m, workspace_keep_out_margin(ws, x, y, z))
    return m


@njit(cache=True)  # compiled once, then loaded from the cache (endocam._numba_cache)
def workspace_all_inside(ws: WorkspaceState, p: FloatArray) -> bool:
    """:meth:`Workspace.all_inside` of the points ``p`` (N, 3), world, m.

    The cone and the floor for every point, the keep-out zone up to the first point they
    reject (that one included): the zone's cache ends as ``margin`` called on each point in
    turn would leave it.
    """
    apex, axis, tan_half, cos_half, height = cone_at(ws.cone, 0)
    n = p.shape[0]
    first = cone_first_outside(p, apex, axis, tan_half, cos_half, height, ws.floor)
    if not ws.keep:
        return first == n
    count = min(first + 1, n)
    inside = keep_out_first_outside(ws.zone, p, count)
    return inside == count and first == n


@dataclass(frozen=True)
class Workspace:
    """Where the camera may be: inside the cone workspace, at or above the floor, off the wire.

    The carriers keep the camera here (``robot.actuator.WorkspaceBound``), whatever they are
    commanded; the controllers' goals stay inside it too.

    Attributes
    ----------
    cone : ConeWorkspace
    floor : float
        Lowest camera height (world z), m: the tissue plane plus the minimum height
        (``ControllerConfig.min_camera_height``).
    keep_out : KeepOut or None
        The wire's clearance zone (``ControllerConfig.wire_clearance`` around the wire's
        surface); ``None``: no structure model.
    """

    cone: ConeWorkspace
    floor: float
    keep_out: KeepOut | None = None
    _state: WorkspaceState = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        keep = self.keep_out is not None
        zone = self.keep_out.kernel_state if self.keep_out is not None else NO_KEEP_OUT
        state = WorkspaceState(self.cone.constant_array, float(self.floor), keep, zone)
        object.__setattr__(self, "_state", state)

    @property
    def kernel_state(self) -> WorkspaceState:
        """The state compiled queries take (:func:`workspace_margin` and the others)."""
        return self._state

    @property
    def convex(self) -> bool:
        """Whether the region is convex: the cone and the floor are, a keep-out zone is not."""
        return self.keep_out is None

    def keep_out_margin(self, p_world: FloatArray | Sequence[float]) -> float:
        """Signed clearance of a point (3,) in world, m, to the keep-out zone alone (inf: none)."""
        p = p_world.tolist() if isinstance(p_world, np.ndarray) else p_world
        return float(workspace_keep_out_margin(self._state, p[0], p[1], p[2]))

    def margin(self, p_world: FloatArray | Sequence[float]) -> float:
        """Signed clearance of a point (3,) in world, m: > 0 inside, < 0 outside (NaN: unknown).

        ``min(cone margin, height above the floor, keep-out margin)``.
        """
        p = p_world.tolist() if isinstance(p_world, np.ndarray) else p_world
        return float(workspace_margin(self._state, p[0], p[1], p[2]))

    def all_inside(self, p_world: FloatArray) -> bool:
        """Whether every point (N, 3), world, m, is inside: ``all(margin(p) >= 0 for p in …)``."""
        p = np.ascontiguousarray(p_world, dtype=float).reshape(-1, 3)
        return bool(workspace_all_inside(self._state, p))
