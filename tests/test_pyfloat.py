"""The compiled hypot / dist (endocam.pyfloat) give the interpreter's floats, bit for bit."""

from __future__ import annotations

import math
import sys

import numpy as np
from hypothesis import example, given, settings
from hypothesis import strategies as st

from endocam.pyfloat import dist3, hypot2, remainder

N_SWEEP = 1_000_000  # rows per seeded sweep: random inputs compared with the interpreter
TINY = 5e-324  # the smallest subnormal
EDGES = [0.0, -0.0, TINY, -TINY, 2.2250738585072014e-308, 1e-310, 1.0, -1.0, 0.5, 3.0, 4.0]
EDGES += [1.7976931348623157e308, -1.7976931348623157e308, math.inf, -math.inf, math.nan]
FLOATS = st.floats(allow_nan=True, allow_infinity=True, allow_subnormal=True)


def _same(a: float, b: float) -> bool:
    """Identical doubles (NaN equals NaN; the sign of zero counts)."""
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return a == b and math.copysign(1.0, a) == math.copysign(1.0, b)


def test_runs_on_the_interpreter_whose_algorithm_is_reproduced() -> None:
    """The kernels transcribe CPython 3.11's vector_norm (3.12 squares with fma)."""
    assert sys.version_info[:2] == (3, 11)


@settings(max_examples=3000, deadline=None)
@given(FLOATS, FLOATS)
@example(3.0, 4.0)
@example(math.inf, math.nan)
@example(math.nan, -math.inf)
@example(TINY, TINY)
@example(0.0, -0.0)
def test_hypot2_is_math_hypot(x: float, y: float) -> None:
    """Every pair of doubles, NaN, infinities and subnormals included."""
    assert _same(hypot2(x, y), math.hypot(x, y))


@settings(max_examples=3000, deadline=None)
@given(st.tuples(*[FLOATS] * 6))
@example((1.0, 2.0, 3.0, 1.0, 2.0, 3.0))
@example((math.inf, 0.0, math.nan, 0.0, 0.0, 0.0))
@example((1e308, -1e308, 0.0, -1e308, 1e308, 0.0))
def test_dist3_is_math_dist(v: tuple[float, ...]) -> None:
    """Every two 3-points, overflowing differences, NaN and infinities included."""
    assert _same(dist3(*v), math.dist(v[:3], v[3:]))


def test_edge_values_exhaustively() -> None:
    """All pairs and a sample of triples of the special values."""
    for x in EDGES:
        for y in EDGES:
            assert _same(hypot2(x, y), math.hypot(x, y)), (x, y)
            for z in EDGES[::3]:
                v = (x, y, z, z, x, -y)
                assert _same(dist3(*v), math.dist(v[:3], v[3:])), v


def test_seeded_sweep_of_a_million_inputs() -> None:
    """10⁶ pairs over 60 decades, 10⁶ over the whole exponent range, 10⁶ 3-point pairs."""
    rng = np.random.default_rng(20261125)
    wide = rng.normal(size=(N_SWEEP, 2)) * np.exp(rng.uniform(-30.0, 30.0, (N_SWEEP, 2)))
    every = np.ldexp(rng.uniform(-1.0, 1.0, (N_SWEEP, 2)), rng.integers(-1074, 1025, (N_SWEEP, 2)))
    for rows in (wide.tolist(), every.tolist()):
        assert [hypot2(x, y) for x, y in rows] == [math.hypot(x, y) for x, y in rows]
    near = (rng.normal(size=(N_SWEEP, 6)) * 0.05).tolist()  # m: camera-sized points
    assert [dist3(*v) for v in near] == [math.dist(v[:3], v[3:]) for v in near]


def _remainder_or_error(f: object, x: float, y: float) -> float | str:
    try:
        return f(x, y)  # type: ignore[operator, no-any-return]
    except ValueError:
        return "ValueError"


@settings(max_examples=3000, deadline=None)
@given(FLOATS, FLOATS)
@example(7.5, 2.0)
@example(-7.5, 2.0)
@example(5.0, 2.0)
@example(1.0, 0.0)
@example(math.inf, 1.0)
@example(1.0, math.inf)
def test_remainder_is_math_remainder(x: float, y: float) -> None:
    """Every pair, the ties (half way: the even multiple) and the domain errors included."""
    got, want = _remainder_or_error(remainder, x, y), _remainder_or_error(math.remainder, x, y)
    assert got == want if isinstance(want, str) else _same(got, want)  # type: ignore[arg-type]


def test_remainder_sweep_of_a_million_angles() -> None:
    """10⁶ angle differences modulo 2π (the ECM's roll check), halves of 2π among them."""
    rng = np.random.default_rng(20261126)
    two_pi = 2.0 * math.pi
    x = rng.normal(0.0, 20.0, N_SWEEP)
    x[::1000] = np.round(x[::1000] / math.pi) * math.pi  # exact multiples of π: ties
    rows = x.tolist()
    assert [remainder(v, two_pi) for v in rows] == [math.remainder(v, two_pi) for v in rows]
