"""The camera-wire clearance guard per control step (``control.clearance``).

Run: make bench, or
  .venv/bin/pytest bench/bench_clearance.py --benchmark-enable -o addopts="" -p no:cacheprovider
Three cases on the default wire: a goal far from the wire (the Lipschitz bound answers, no
nearest-point query), a goal at the wire's continuation (turned or moved back: a few queries)
and the straight move from the camera to a clear goal (``detour``: sphere tracing). An
episode's mean per step is measured whole by ``bench/paired_episode.py`` (README, camera-wire
clearance).

Two more time ``Wire.nearest_surface`` itself: 200 queries near the wire, their grid cells
cached or built anew. Medians on 2026-11-25 (machine loaded, the command above, then the same
file with ``PYTHONPATH=/tmp/base54/src``, the checkout before the compiled nearest-point
kernels): far goal 1.0 µs (1.0 before), goal on the wire 7.4 µs (21), straight move 1.4 µs
(1.4), 200 queries 0.18 ms (1.1) with cached cells and 1.4 ms (7.8) with new ones.
"""

from __future__ import annotations

import numpy as np
import pytest

from endocam.control.clearance import WIRE_CLEARANCE, ClearanceGuard
from endocam.control.goal import goal_pose
from endocam.task.config import WireConfig
from endocam.task.wire import Wire

D_F = 0.05  # m, the default working distance
BACK_OFF = 0.03  # m, d_max − d_f by default


@pytest.fixture(scope="module")
def wire() -> Wire:
    return Wire(WireConfig())


def _near_goal(wire: Wire) -> tuple[np.ndarray, tuple[float, float, float]]:
    """The on-tangent goal that comes closest to the wire, and its ring centre."""
    s_all = wire.length * np.linspace(0.1, 0.9, 81)
    goals = [goal_pose(wire.point(s), wire.tangent(s), D_F) for s in s_all]
    k = int(np.argmin(wire.surface_distance(np.array([T[:3, 3] for T in goals]))))
    return goals[k], tuple(wire.point(s_all[k]).tolist())


def test_guard_far_goal(benchmark, wire: Wire) -> None:
    """A clear goal, 1 mm from the last one: no query (the bound answers)."""
    guard = ClearanceGuard(wire, WIRE_CLEARANCE)
    p_c = wire.point(0.5 * wire.length)
    T = goal_pose(p_c, [0.0, 0.0, 1.0], D_F)
    guard.apply(T, tuple(p_c.tolist()))
    T2 = T.copy()
    T2[0, 3] += 1e-3
    out = benchmark(guard.apply, T2, tuple(p_c.tolist()))
    assert out is T2


def test_guard_goal_on_the_wire(benchmark, wire: Wire) -> None:
    """The paper's goal on the wire's continuation: moved back or turned until clear."""
    guard = ClearanceGuard(wire, WIRE_CLEARANCE)
    T, p_c = _near_goal(wire)
    out = benchmark(guard.apply, T, p_c, None, None, BACK_OFF)
    assert out is not None and out is not T


def test_guard_straight_move(benchmark, wire: Wire) -> None:
    """Sphere tracing a 2 mm move between two clear poses near the wire (no detour)."""
    guard = ClearanceGuard(wire, WIRE_CLEARANCE)
    T, p_c = _near_goal(wire)
    cleared = guard.apply(T, p_c, None, None, BACK_OFF)
    assert cleared is not None
    b = cleared[:3, 3]
    a = b + 2e-3 * cleared[:3, 2]  # the camera 2 mm behind, on the axis (away from the ring)
    assert benchmark(guard.detour, a.tolist(), b.tolist()) is None


def _near_points(wire: Wire) -> list[list[float]]:
    """200 points up to ~1 cm from the wire (seeded), world, m."""
    rng = np.random.default_rng(3)
    s = rng.uniform(0.0, wire.length, 200)
    return (wire.points(s) + rng.normal(size=(200, 3)) * 0.005).tolist()


def test_nearest_surface_cached_cells(benchmark, wire: Wire) -> None:
    """200 nearest-point queries near the wire, their grid cells already built."""
    points = _near_points(wire)
    for p in points:
        wire.nearest_surface(p)
    out = benchmark(lambda: [wire.nearest_surface(p) for p in points])
    assert len(out) == len(points)


def test_nearest_surface_new_cells(benchmark, wire: Wire) -> None:
    """200 nearest-point queries near the wire, every grid cell built anew."""
    points = _near_points(wire)
    wire.nearest_surface(points[0])  # compiled code loaded outside the timing

    def queries() -> list[tuple[float, int]]:
        wire.forget_cells()
        return [wire.nearest_surface(p) for p in points]

    assert len(benchmark(queries)) == len(points)
