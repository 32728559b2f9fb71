import math

import numpy as np
import pytest
from pydantic import ValidationError

from endocam.task import wire as wire_module
from endocam.task.config import DEFAULT_KNOTS, RingConfig, TaskConfig, WireConfig
from endocam.task.wire import Wire, _ball_kernel, _nearest_kernel

ATOL_M = 1e-9  # m
UNIT_TOL = 1e-9  # unitless
ARC_TOL_M = 1e-6  # m, arc-length parametrisation accuracy over the whole wire


@pytest.fixture(scope="module")
def wire() -> Wire:
    return Wire(WireConfig())


def test_length_in_paper_range_and_above_board(wire: Wire) -> None:
    assert 0.250 <= wire.length <= 0.350
    pts = wire.polyline()
    assert pts[:, 2].min() > wire.radius
    assert pts[:, 2].min() >= 0.020 and pts[:, 2].max() <= 0.070


def test_wire_passes_through_knots(wire: Wire) -> None:
    knots = np.asarray(DEFAULT_KNOTS)
    _, d = zip(*(wire.closest(k) for k in knots), strict=True)
    assert max(d) < 1e-6
    np.testing.assert_allclose(wire.post_tops, knots[[0, -1]], atol=1e-7)
    np.testing.assert_allclose(wire.post_bases[:, 2], 0.0)


def test_rises_falls_and_turns(wire: Wire) -> None:
    t = wire.tangent(np.linspace(0.0, wire.length, 500))
    assert np.any(np.diff(np.sign(t[:, 2])) != 0)  # rises and falls
    assert np.any(np.diff(np.sign(t[:, 1])) != 0)  # turns in plan view


def test_tangents_unit_and_match_finite_differences(wire: Wire) -> None:
    s = np.linspace(0.01, wire.length - 0.01, 200)
    t = wire.tangent(s)
    np.testing.assert_allclose(np.linalg.norm(t, axis=1), 1.0, atol=UNIT_TOL)
    h = 1e-6
    fd = (wire.points(s + h) - wire.points(s - h)) / (2 * h)
    np.testing.assert_allclose(fd, t, atol=1e-5)
    assert wire.tangent(0.1).shape == (3,)


def test_arc_length_parametrisation(wire: Wire) -> None:
    pts = wire.polyline(20001)
    chord_sum = np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1))
    assert abs(chord_sum - wire.length) < ARC_TOL_M
    s = np.array([0.05, 0.1, 0.2])
    d = np.linalg.norm(wire.points(s + 1e-3) - wire.points(s), axis=1)
    np.testing.assert_allclose(d, 1e-3, rtol=1e-3)


def test_closest_recovers_offset_point(wire: Wire) -> None:
    rng = np.random.default_rng(0)
    for s0 in rng.uniform(0.02, wire.length - 0.02, 10):
        t = wire.tangent(s0)
        offset = np.cross(t, rng.normal(size=3))
        offset *= 2e-3 / np.linalg.norm(offset)
        s, d = wire.closest(wire.point(s0) + offset)
        assert abs(s - s0) < 1e-7
        assert abs(d - 2e-3) < 1e-9


def test_out_of_range_arc_length_raises(wire: Wire) -> None:
    with pytest.raises(ValueError, match="s must lie"):
        wire.point(wire.length + 1e-3)
    with pytest.raises(ValueError, match="n must be"):
        wire.polyline(1)


def test_config_validation() -> None:
    with pytest.raises(ValidationError, match="above the board"):
        WireConfig(knots=[(0, 0, 0.0), (0.1, 0, 0.02), (0.2, 0, 0.02), (0.3, 0, 0.02)])
    with pytest.raises(ValidationError, match="at least 4"):
        WireConfig(knots=[(0, 0, 0.02), (0.1, 0, 0.02)])
    with pytest.raises(ValidationError, match="minor_radius"):
        RingConfig(minor_radius=6e-3)
    with pytest.raises(ValidationError, match="hole is too small"):
        TaskConfig(ring=RingConfig(major_radius=2e-3, minor_radius=1.5e-3))
    with pytest.raises(ValidationError):
        TaskConfig.model_validate({"wire": {"radius": -1.0}})
    with pytest.raises(ValidationError):
        TaskConfig.model_validate({"trajectory": {"position_noise": [4e-3, 3e-3]}})
    with pytest.raises(ValidationError):
        TaskConfig.model_validate({"bogus": 1})
    cfg = TaskConfig()
    with pytest.raises(ValidationError):
        cfg.wire.radius = 2.0  # type: ignore[misc]
    assert TaskConfig.model_validate(cfg.model_dump()) == cfg


def test_surface_distance_matches_the_exact_closest_point() -> None:
    from endocam.task.config import WireConfig
    from endocam.task.wire import Wire

    wire = Wire(WireConfig())
    rng = np.random.default_rng(11)
    s = rng.uniform(0.0, wire.length, 50)
    offsets = rng.normal(size=(50, 3)) * 0.01  # m: points up to a few cm from the wire
    points = wire.points(s) + offsets
    fast = wire.surface_distance(points)
    exact = np.array([wire.closest(p)[1] for p in points]) - wire.radius
    # the nearest search vertex is at most half a spacing further than the exact closest point
    closest_atol_m = 1e-8  # m: Wire.closest's bounded search is exact to ~1e-9 m
    assert np.all(fast >= exact - closest_atol_m)
    assert np.all(fast - exact <= wire.search_spacing / 2 + closest_atol_m)
    assert wire.surface_distance(wire.points(s[:3]))[0] < 0  # on the centre line: inside


NEAREST_ATOL_M = 1e-12  # m: round-off of a distance of order 0.1 m (the tree's and the kernel's)


def _same_nearest(got: tuple[float, int], d: float, k: int, pts: np.ndarray, p) -> None:
    """``got`` is the nearest point (distance ``d``, row ``k``), or another as near (a tie)."""
    d_got, k_got = got
    assert math.isclose(d_got, d, rel_tol=0.0, abs_tol=NEAREST_ATOL_M)
    if k_got != k:
        d_rows = np.linalg.norm(pts[[k_got, k]] - np.asarray(p), axis=1)
        assert abs(d_rows[0] - d_rows[1]) <= NEAREST_ATOL_M


def test_nearest_surface_is_the_trees_answer(wire: Wire) -> None:
    """The grid-cell search near the wire gives the KD-tree's point and distance."""
    rng = np.random.default_rng(7)
    s = rng.uniform(0.0, wire.length, 3000)
    spread = rng.choice([0.002, 0.01, 0.05], size=(3000, 1))  # m: at, near and far from it
    points = wire.points(s) + rng.normal(size=(3000, 3)) * spread
    d_tree = wire.surface_distance(points)
    pts = wire.search_points
    k_tree = [int(np.argmin(np.linalg.norm(pts - p, axis=1))) for p in points]
    for p, d, k in zip(points.tolist(), d_tree.tolist(), k_tree, strict=True):
        _same_nearest(wire.nearest_surface(p), d, k, pts, p)


def test_compiled_nearest_and_ball_are_the_numpy_search() -> None:
    """The nearest-candidate search is numpy's argmin; a cell's ball holds every row near it."""
    rng = np.random.default_rng(5)
    h = 2e-3  # m: the cell's edge
    for _ in range(200):
        n = int(rng.integers(1, 300))
        pts = rng.normal(size=(n, 3)) * rng.choice([1e-3, 1e-2, 1.0])  # m
        p = rng.normal(size=3)
        if n > 1 and rng.random() < 0.2:
            pts[n - 1] = pts[0]  # a tie: the first row wins, as argmin's
        idx_all = rng.permutation(n).astype(np.int32)  # candidates in any order
        start = int(rng.integers(0, n))
        count = int(rng.integers(1, n - start + 1))
        rows = idx_all[start : start + count]
        d = np.linalg.norm(pts[rows] - p, axis=1)
        got_k, got_d = _nearest_kernel(pts, idx_all, start, count, *p.tolist())
        assert math.isclose(got_d, d.min(), rel_tol=0.0, abs_tol=NEAREST_ATOL_M)
        assert got_k in rows[d <= d.min() + NEAREST_ATOL_M]
        idx, d_c = _ball_kernel(pts, *p.tolist(), h)
        d_all = np.linalg.norm(pts - p, axis=1)
        assert math.isclose(d_c, d_all.min(), rel_tol=0.0, abs_tol=NEAREST_ATOL_M)
        radius = d_c + h * math.sqrt(3.0)
        assert np.all(np.diff(idx) > 0)  # increasing rows
        inside = set(np.flatnonzero(d_all <= radius - NEAREST_ATOL_M).tolist())
        slack = wire_module._BALL_SLACK + NEAREST_ATOL_M  # the ball is widened against round-off
        near = set(np.flatnonzero(d_all <= radius + slack).tolist())
        assert inside <= set(idx.tolist()) <= near


def test_cell_cache_starting_afresh_gives_the_same_answers(wire: Wire) -> None:
    """When the cell cache is full it starts afresh: the answers (the tree's) do not change."""
    rng = np.random.default_rng(9)
    points = wire.points(rng.uniform(0.0, wire.length, 400)) + rng.normal(size=(400, 3)) * 0.01
    fresh = Wire(wire.cfg)  # an empty cache
    expected = [fresh.nearest_surface(p) for p in points.tolist()]
    wire._meta[0] = wire_module._MAX_CELLS  # full: the next new cell empties the cache
    assert [wire.nearest_surface(p) for p in points.tolist()] == expected
    assert 0 < wire._meta[0] <= 400  # it started afresh, then cached cells again
    wire.forget_cells()
    assert [wire.nearest_surface(p) for p in points.tolist()] == expected
    with pytest.raises(ValueError):
        wire.nearest_surface([math.nan, 0.0, 0.0])
    with pytest.raises(OverflowError):
        wire.nearest_surface([0.0, math.inf, 0.0])
