"""railstop.jit's scalar maths that both targets compile: rint_1, ceil_1 and floor_1 equal
numpy's, bit for bit."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from railstop.jit import ceil_1, floor_1, rint_1

SPECIAL = [
    0.0,
    -0.0,
    0.5,
    -0.5,
    1.5,
    2.5,
    -2.5,
    0.49999999999999994,
    -0.49999999999999994,
    2.0**51 + 0.5,
    -(2.0**51) - 0.5,
    2.0**52 - 0.5,
    2.0**52,
    -(2.0**52),
    2.0**52 + 1.0,
    1e300,
    -1e300,
    5e-324,
    -5e-324,
    math.inf,
    -math.inf,
    math.nan,
]


def _same(a: float, b: float) -> bool:
    """Equal as float64 bit patterns (NaN equal to NaN, -0.0 not equal to 0.0)."""
    return np.float64(a).tobytes() == np.float64(b).tobytes() or (math.isnan(a) and math.isnan(b))


def test_rint_ceil_and_floor_equal_numpy_on_the_edges() -> None:
    for x in SPECIAL:
        assert _same(rint_1(x), float(np.rint(x))), x
        assert _same(ceil_1(x), float(np.ceil(x))), x
        assert _same(floor_1(x), float(np.floor(x))), x


@settings(max_examples=3000, deadline=None)
@given(st.floats(allow_nan=True, allow_infinity=True, width=64))
def test_rint_ceil_and_floor_equal_numpy(x: float) -> None:
    assert _same(rint_1(x), float(np.rint(x)))
    assert _same(ceil_1(x), float(np.ceil(x)))
    assert _same(floor_1(x), float(np.floor(x)))


@settings(max_examples=2000, deadline=None)
@given(st.integers(min_value=-(2**40), max_value=2**40), st.sampled_from([0.25, 0.5, 0.75]))
def test_halves_and_quarters(n: int, frac: float) -> None:
    for x in (n + frac, n - frac):
        assert _same(rint_1(x), float(np.rint(x)))
        assert _same(ceil_1(x), float(np.ceil(x)))
        assert _same(floor_1(x), float(np.floor(x)))
