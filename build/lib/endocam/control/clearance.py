r"""The camera–wire clearance: no commanded camera pose closer than ``wire_clearance`` to the wire.

The orientation goal looks along the ring normal, which is nearly the wire's tangent, so the
on-normal goal sits on the wire's continuation. :class:`ClearanceGuard` filters every pose a
moving policy commands (goal, way-point, orbit): a pose whose optical centre is at least the
clearance ``c`` from the wire's tube surface passes unchanged; a closer one is rotated about the
pivot it looks at (the ring centre) by the smallest angle along an escape direction that restores
the clearance, keeping the pivot at the same place in the camera frame (ring centred, same look
distance) and the horizon level:

.. math::

    u(\theta) = \cos\theta\,u + \sin\theta\,e, \qquad
    \theta_{k+1} = \theta_k + \frac{c + \delta - d(\theta_k)}{r}

``u`` is the unit direction from the pivot to the camera, ``r`` their distance, ``e ⟂ u`` the
escape direction, ``d`` the surface distance and ``δ = AIM_BEYOND``. The distance is 1-Lipschitz
in position and the camera moves at most ``r Δθ`` along the arc, so this conservative
advancement never steps over the first angle clear by ``δ`` (which keeps the chord between two
successive poses clear too). The escape direction is the one remembered from the previous step
(no chatter between two sides of a symmetric wire), else towards where the camera is now (it
need not cross the wire), else the distance's gradient (away from the nearest wire point), each
projected perpendicular to ``u``; then the perpendiculars and the opposite are tried. An angle
is accepted only if the pose is also feasible (inside the workspace, above the floor). If no
direction clears within ``MAX_ESCAPE_ANGLE`` the guard returns ``None`` and the policy holds its
last command, which passed the guard (the wire does not move).

Paths: a command may be clear while the straight move to it is not (the camera on one side of
the wire, the goal on the other). :meth:`ClearanceGuard.detour` sphere-traces that move and, if
it is blocked, gives a way-point that slides along the zone's surface; the policies command it
(state ``planning``). The carriers keep the camera itself out of the zone
(``workspace.region.Workspace.keep_out``), braking like at the cone and the floor.

Cost: the distance is 1-Lipschitz, so a pose within ``d_ref − c`` of the last queried position
``p_ref`` (distance ``d_ref``) is clear without a query; only then is
:meth:`~endocam.task.wire.Wire.nearest_surface` asked (one query), and the search runs only
when too close.

The wire reaches the controller through :class:`~endocam.control.types.PolicyContext` as a
pre-operative model of the structure (its centre line and radius), as a real system would have
from planning images; the ring's pose is still only what the controller observes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from endocam.camera import SCOPE_RADIUS
from endocam.control.detour import detour_fields, lifted
from endocam.control.escape import (
    APPLY_ADJUSTED,
    APPLY_BLOCKED,
    APPLY_CLEAR,
    ESCAPE_MEMORY,
    EscapeMemory,
    GuardState,
    clear_look_at_into,
    clear_pose_into,
)
from endocam.geometry import FloatArray
from endocam.kernels import Vec
from endocam.task.wire import Wire
from endocam.workspace.keepout import (
    CACHE_SIZE,
    KeepOutState,
    keep_out_distance,
    keep_out_first_outside,
)
from endocam.workspace.region import NO_WORKSPACE, Workspace

CLEARANCE_MARGIN = 2.0e-3  # m, beyond the scope's radius: the carriers' tracking deviation
WIRE_CLEARANCE = SCOPE_RADIUS + CLEARANCE_MARGIN  # m, ControllerConfig.wire_clearance default


class ClearanceGuard:
    """Keeps commanded camera positions ``clearance`` from the wire's surface (module docstring).

    Parameters
    ----------
    wire : Wire
        The structure to avoid (its centre line and tube radius), world, m.
    clearance : float
        Smallest distance from the camera's optical centre to the tube's surface, m (≥ 0).
    """

    def __init__(self, wire: Wire, clearance: float) -> None:
        if not (math.isfinite(clearance) and clearance >= 0.0):
            raise ValueError(f"clearance must be ≥ 0 m, got {clearance}")
        self.wire = wire
        self.clearance = float(clearance)
        self._ref = np.zeros((CACHE_SIZE, 4))  # the last queries: point (m), distance (m)
        self._nref = np.zeros(1, dtype=np.int64)  # rows of _ref in use, newest first
        self._state = KeepOutState(
            *wire.query_state, wire.radius, self._ref, self._nref, self.clearance
        )
        self._escape: EscapeMemory = np.zeros(1, dtype=ESCAPE_MEMORY)
        self._unbounded = GuardState(self._state, self._escape, False, NO_WORKSPACE)
        self._workspace: Workspace | None = None  # the last workspace given to apply()
        self._bounded = self._unbounded  # the search's state with that workspace
        self.adjusted = 0  # poses rotated this episode
        self.blocked = 0  # poses with no clear, feasible rotation this episode

    def reset(self) -> None:
        """Forget the cached query and the escape direction (a new episode)."""
        self._nref[0] = 0
        self._escape[0]["held"] = False
        self.adjusted = 0
        self.blocked = 0

    def distance(self, p_world: Sequence[float], exact_below: float = 0.0) -> float:
        """Surface distance of a camera position (3,), world, m; one nearest-point query at most.

        The distance is 1-Lipschitz: while ``d_ref − ‖p − p_ref‖`` (the last queries' distance
        less how far the point moved) is at least ``clearance + exact_below`` (m), that lower
        bound is returned without a query. NaN for a non-finite position. Compiled
        (``workspace.keepout.keep_out_distance``).
        """
        return keep_out_distance(self._state, p_world[0], p_world[1], p_world[2], exact_below)

    @property
    def refs(self) -> list[tuple[list[float], float]]:
        """The cached queries, newest first: (point (3,), world, m; surface distance, m)."""
        return [(row[:3], row[3]) for row in self._ref[: self._nref[0]].tolist()]

    def margin(self, p_world: Sequence[float]) -> float:
        """Signed clearance of a camera position (3,), world, m: ≥ 0 clear (``Workspace``).

        Exact when negative, else possibly a lower bound (:meth:`distance`): a carrier that
        compares it with a braking distance then checks its braking path point by point.
        """
        return self.distance(p_world) - self.clearance

    def first_outside(self, p_world: FloatArray, count: int) -> int:
        """The first of ``p_world[:count]`` whose :meth:`margin` is < 0 (or NaN), else ``count``.

        ``p_world`` (N, 3): camera positions, world, m. :meth:`margin` on each in turn, in
        one compiled call (``keep_out_first_outside``): the cache ends as those calls leave it.
        """
        p = np.ascontiguousarray(p_world, dtype=float).reshape(-1, 3)
        return keep_out_first_outside(self._state, p, count)

    def is_clear(self, p_world: list[float]) -> bool:
        """Whether a camera position (3,), world, m, keeps the clearance (NaN: not clear)."""
        return self.distance(p_world) >= self.clearance

    def apply(
        self,
        T_world_cam: FloatArray,
        p_world_pivot: Vec,
        workspace: Workspace | None = None,
        p_world_now: Vec | None = None,
        back_off: float = 0.0,
    ) -> FloatArray | None:
        """The commanded pose, or the nearest clear one rotated about the pivot; ``None``: none.

        One compiled call (:func:`clear_pose_into`).

        Parameters
        ----------
        T_world_cam : (4, 4)
            Commanded camera pose, optical frame, world, m.
        p_world_pivot : 3-tuple
            The point the pose looks at (the ring centre), world, m: it keeps its place in the
            camera frame.
        workspace : Workspace or None
            Where a camera position may be commanded (``Workspace.margin(p) >= 0``: the cone,
            the floor and its own keep-out guard, whose cache the checks update); ``None``:
            everywhere.
        p_world_now : 3-tuple or None
            Where the camera is now, world, m: without a remembered escape direction the pose
            turns towards it first (the camera need not cross the wire to reach it).
        back_off : float
            How far the pose may first move back along its optical axis, m (the look distance
            grows, the view's direction is kept); it turns only if that does not clear.

        Returns
        -------
        (4, 4) or None
            ``T_world_cam`` itself when clear; a rotated, clear and feasible pose; or ``None``
            (non-finite input, or no clear feasible rotation up to ``MAX_ESCAPE_ANGLE``).
        """
        T = np.empty((4, 4))  # the adjusted pose, if any (a new array: the caller keeps it)
        request = _request(p_world_pivot, p_world_now, back_off)
        guard = self._guard_state(workspace)
        code = clear_pose_into(guard, np.asarray(T_world_cam, dtype=float), request, T)
        if code == APPLY_CLEAR:
            return T_world_cam
        if code == APPLY_ADJUSTED:
            self.adjusted += 1
            return T
        if code == APPLY_BLOCKED:
            self.blocked += 1
        return None

    def apply_look_at(
        self,
        p_world: Vec,
        p_world_pivot: Vec,
        fallback: FloatArray,
        previous: FloatArray,
        workspace: Workspace,
        p_world_now: Vec | None = None,
        back_off: float = 0.0,
        check: bool = True,
    ) -> FloatArray | None:
        """:meth:`apply` of the pose at ``p_world`` looking at the pivot, if it is feasible.

        The pose: ``view.look_at_unchecked(p_world, p_world_pivot, fallback, previous)`` (a
        level horizon, the roll kept from ``previous`` (4, 4) near the vertical; ``fallback``
        (4, 4) itself when the two points coincide). ``None`` when ``p_world`` (3,), world,
        m, is outside the ``workspace`` (``Workspace.margin < 0``; asked only if ``check``),
        else :meth:`apply`'s answer. One compiled call (:func:`clear_look_at_into`).
        """
        p = p_world
        T = np.empty((4, 4))  # the pose, if any (a new array: the caller keeps it)
        look = ((float(p[0]), float(p[1]), float(p[2])), fallback, previous, check)  # a LookAt
        request = _request(p_world_pivot, p_world_now, back_off)
        guard = self._guard_state(workspace)
        code, fell_back = clear_look_at_into(guard, look, request, T)
        if code == APPLY_CLEAR:
            return fallback if fell_back else T
        if code == APPLY_ADJUSTED:
            self.adjusted += 1
            return T
        if code == APPLY_BLOCKED:
            self.blocked += 1
        return None

    def _guard_state(self, workspace: Workspace | None) -> GuardState:
        """The search's state (:class:`~endocam.control.escape.GuardState`) with ``workspace``."""
        if workspace is None:
            return self._unbounded
        if workspace is not self._workspace:
            if type(workspace) is not Workspace:  # a subclass's own margin would go unasked
                raise TypeError(
                    "workspace: the guard's feasibility check is compiled for a "
                    f"workspace.region.Workspace, got {type(workspace).__name__}"
                )
            keep_out = workspace.keep_out
            if keep_out is not None and not isinstance(keep_out, ClearanceGuard):
                raise TypeError("a workspace's keep-out zone must be a ClearanceGuard")
            self._workspace = workspace
            self._bounded = self._unbounded._replace(bounded=True, workspace=workspace.kernel_state)
        return self._bounded

    @property
    def kernel_state(self) -> KeepOutState:
        """The zone compiled callers pass first (``keep_out_distance``, ``detour_waypoint``).

        ``Wire.query_state``'s arrays, the tube radius (m), the Lipschitz cache (``ref``
        (CACHE_SIZE, 4), ``nref`` (1,)) and the clearance (m); the cache is shared, so a
        caller's queries are this guard's.
        """
        return self._state

    def passed(self, T_world_cam: FloatArray) -> FloatArray:
        """:meth:`apply`'s answer for a pose found clear by a compiled caller: the pose itself.

        The caller made :meth:`apply`'s finite check and query (``keep_out_distance``, the same
        cache); this records the pass (no escape direction is remembered).
        """
        self._escape[0]["held"] = False
        return T_world_cam

    def detour(self, p_world_now: Sequence[float], p_world_cmd: Sequence[float]) -> Vec | None:
        """A way-point around the wire when the straight move to the command would cross it.

        The segment from the camera ``p_world_now`` to the commanded position ``p_world_cmd``
        (both (3,), world, m) is sphere-traced: from a point at surface distance ``d`` the next
        ``d − clearance`` of the segment cannot enter the zone (1-Lipschitz), so one query
        clears a short move. If the trace stops at the zone's edge before the command, the
        way-point slides from there along the zone's surface: the remaining direction with its
        component into the wire removed, ``DETOUR_STEP`` long, pushed ``DETOUR_PUSH`` out.
        One compiled call (:func:`~endocam.control.detour.detour_waypoint`).

        Returns
        -------
        3-tuple or None
            The way-point, world, m; ``None`` when the straight move keeps the clearance (or
            an end is not finite).
        """
        a, b = p_world_now, p_world_cmd
        found, via = detour_fields(
            self._state,
            (float(a[0]), float(a[1]), float(a[2])),
            (float(b[0]), float(b[1]), float(b[2])),
        )
        return via if found else None

    def step_out(self, p_world: Sequence[float]) -> Vec | None:
        """``p_world`` (3,), m, moved straight away from the wire to ``DETOUR_PUSH`` past the zone.

        ``None`` when it already lies that far out (or the direction is undefined). The way
        out for a camera standing on the zone's edge: a carrier at rest there may refuse every
        slide along the surface, whose braking path grazes the zone.
        """
        p = (float(p_world[0]), float(p_world[1]), float(p_world[2]))
        out = lifted(self._state, p)
        return out.point if out.found and out.point != p else None


def _request(
    pivot: Sequence[float], now: Sequence[float] | None, back_off: float
) -> tuple[Vec, bool, Vec, float]:
    """:meth:`ClearanceGuard.apply`'s arguments as ``escape.ClearRequest``'s fields (a tuple)."""
    return (
        (float(pivot[0]), float(pivot[1]), float(pivot[2])),
        now is not None,
        (0.0, 0.0, 0.0) if now is None else (float(now[0]), float(now[1]), float(now[2])),
        float(back_off),
    )


def clear_pose_or_none(
    guard: ClearanceGuard | None, T: FloatArray, pivot: Vec, workspace: Workspace | None = None
) -> FloatArray | None:
    """``guard.apply(T, pivot, workspace)``, or ``T`` when there is no guard (no wire model)."""
    return T if guard is None else guard.apply(T, pivot, workspace)


__all__ = ["CLEARANCE_MARGIN", "WIRE_CLEARANCE", "ClearanceGuard", "clear_pose_or_none"]
