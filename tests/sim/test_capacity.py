"""The CBTC line's analytic minimum headway (``railstop.sim.capacity``) against its data and the line.

- the clearing distance is the train's length, the rollback allowance, the safety margin and
  both trains' uncertainty (the zone controller's authority rule); the clearing time is no less
  than that distance at the traction's acceleration limit from a stand allows;
- the dwell term is the line's own nominal dwell (the same door units) and adds one for one;
- the minimum is a lower bound: trains entering faster than it are served no faster than it at
  the busiest platform.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from railstop.config import default_line, default_vehicle
from railstop.config.operation import StationDwell, load_operation
from railstop.sim.capacity import PlatformHeadway, minimum_headways
from railstop.sim.line import LineSettings, LineSimulation

LINE = default_line()
VEHICLE = default_vehicle()
OPERATION = load_operation(None, LINE)
CBTC = LineSettings(signalling="cbtc")


@pytest.fixture(scope="module")
def headways() -> list[PlatformHeadway]:
    return minimum_headways(LINE, VEHICLE, OPERATION)


def test_terms_follow_the_data(headways: list[PlatformHeadway]) -> None:
    cbtc = LINE.cbtc
    assert [h.station for h in headways] == [s.name for s in LINE.stations]
    for h in headways:
        assert h.clear_m == pytest.approx(
            VEHICLE.length_m + cbtc.rollback_m + cbtc.safety_margin_m + 2.0 * cbtc.position_uncertainty_m
        )
        # From a stand at most the traction's acceleration limit: no quicker than this.
        assert VEHICLE.traction is not None
        assert h.clear_s >= math.sqrt(2.0 * h.clear_m / VEHICLE.traction.max_accel_mps2)
        assert h.clear_s < 2.0 * math.sqrt(2.0 * h.clear_m / VEHICLE.traction.max_accel_mps2)
        assert h.system_s == pytest.approx(cbtc.report_period_s + cbtc.processing_delay_s + 0.05 + 0.1)
        assert h.headway_s == pytest.approx(h.dwell_s + h.clear_s + h.system_s + h.approach_s)
        assert h.trains_per_hour == pytest.approx(3600.0 / h.headway_s)
    # A smaller uncertainty clears sooner.
    small = minimum_headways(LINE, VEHICLE, OPERATION, uncertainty_m=1.0)
    assert all(a.clear_s < b.clear_s for a, b in zip(small, headways, strict=True))


def test_dwell_is_the_lines_nominal_dwell_and_adds_one_for_one(headways: list[PlatformHeadway]) -> None:
    # One train through the line, nominal: each dwell as the line's door units run it.
    op = OPERATION.model_copy(update={"trains": 1})
    sim = LineSimulation(
        line=LINE, vehicle=VEHICLE, operation=op, seed=1, settings=LineSettings(signalling="cbtc")
    )
    sim.run(1800.0, until_gone=True)
    line_dwell = {d.station: d.dwell_s for d in sim.dwells}
    for h in headways:
        assert line_dwell[h.station] == pytest.approx(h.dwell_s, abs=0.02)
    longer = OPERATION.model_copy(
        update={
            "dwell_s": OPERATION.dwell_s + 10.0,
            "stations": [StationDwell(name=s.name, dwell_s=s.dwell_s + 10.0) for s in OPERATION.stations],
        }
    )
    for a, b in zip(minimum_headways(LINE, VEHICLE, longer), headways, strict=True):
        assert a.headway_s - b.headway_s == pytest.approx(10.0, abs=0.02)
        assert a.approach_s == b.approach_s and a.clear_s == b.clear_s


def test_the_minimum_is_a_lower_bound_of_the_simulated_line(headways: list[PlatformHeadway]) -> None:
    least = max(h.headway_s for h in headways)
    op = OPERATION.model_copy(update={"trains": 7, "headway_s": 0.8 * least})
    sim = LineSimulation(
        line=LINE, vehicle=VEHICLE, operation=op, seed=1, settings=LineSettings(signalling="cbtc")
    )
    sim.run(1500.0)
    intervals = []
    for st in LINE.stations:
        arrivals = sorted(s.arrive_s for s in sim.stops if s.station == st.name)
        if len(arrivals) >= 4:
            intervals.append(float(np.median(np.diff(arrivals))))
    assert intervals
    # Entries faster than any platform serves: the busiest is no quicker than its minimum.
    assert max(intervals) >= 0.99 * least
