"""The km/h helpers: exact round trip and the values a reader knows."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from railstop.quantities import KMH_PER_MPS, MPS_PER_KMH, kmh_to_mps, mps_to_kmh


def test_known_values() -> None:
    assert kmh_to_mps(36.0) == 10.0
    assert mps_to_kmh(10.0) == 36.0
    assert math.isclose(kmh_to_mps(80.0), 22.2222222222, rel_tol=1e-10)
    assert math.isclose(KMH_PER_MPS * MPS_PER_KMH, 1.0, rel_tol=1e-15)


@given(st.floats(min_value=0.0, max_value=1000.0))
def test_round_trip(v_kmh: float) -> None:
    assert math.isclose(mps_to_kmh(kmh_to_mps(v_kmh)), v_kmh, rel_tol=1e-14, abs_tol=1e-12)
