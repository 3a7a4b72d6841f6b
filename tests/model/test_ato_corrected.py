"""The ``ato-corrected`` baseline: the onboard ATO positioned by SPEC §2 track-circuit corrections."""

from __future__ import annotations

import numpy as np
import pytest

from railstop.config import default_line, default_vehicle
from railstop.config.scenario import Scenario
from railstop.config.schema import Line
from railstop.errors import SimulationError
from railstop.sim.engine import run_batch
from railstop.streams import RunStreams

LINE = default_line()
VEHICLE = default_vehicle()
STATION = LINE.stations[0]


def _line(delay_mean_s: float, delay_spread_s: float, boundary_sd_m: float) -> Line:
    det = LINE.track.detection.model_copy(
        update={
            "delay_mean_s": delay_mean_s,
            "delay_spread_s": delay_spread_s,
            "boundary_sd_jointless_m": boundary_sd_m,
            "boundary_sd_insulated_m": boundary_sd_m,
        }
    )
    return LINE.model_copy(update={"track": LINE.track.model_copy(update={"detection": det})})


def _stop(controller: str, line: Line, odometer_error: float = 0.0) -> float:
    sc = Scenario.nominal(STATION, VEHICLE).with_values(odometer_diameter_error=np.full(1, odometer_error))
    r = run_batch(
        station=STATION,
        vehicle=VEHICLE,
        scenario=sc,
        controller=controller,
        streams=RunStreams.for_runs(1, 0, 1),
        track=line.track,
    )
    return float(r.stop_error_m[0])


def test_exact_circuits_give_the_transponder_ato_accuracy() -> None:
    """Zero detection delay and exact boundaries: every fix is exact, like a transponder."""
    exact = _line(0.0, 0.0, 0.0)
    assert abs(_stop("ato-corrected", exact)) <= 0.2
    # A known constant delay is compensated (the line's nominal delay is the unit's prior).
    assert abs(_stop("ato-corrected", _line(0.3, 0.0, 0.0))) <= 0.2


def test_odometer_scale_error_shows_as_distance_since_the_last_fix() -> None:
    """An odometer assuming a 1.5 % larger wheel counts too far: the ATO believes it is
    further on and stops short, by about 1.5 % of the distance from the last circuit
    boundary to the stop (the transponder ATO's last fix is 25 m out, far closer)."""
    exact = _line(0.0, 0.0, 0.0)
    base = _stop("ato-corrected", exact)
    short = _stop("ato-corrected", exact, odometer_error=0.015)
    starts = np.array([c.start_m for c in LINE.track.circuits])
    last_fix = starts[starts <= STATION.stop_point_m].max()
    expected = -0.015 * (STATION.stop_point_m - last_fix)
    assert short < base
    assert short - base == pytest.approx(expected, abs=0.15 + 0.05 * abs(expected))


def test_needs_track_circuits() -> None:
    sc = Scenario.nominal(STATION, VEHICLE)
    with pytest.raises(SimulationError, match="track circuits"):
        run_batch(
            station=STATION,
            vehicle=VEHICLE,
            scenario=sc,
            controller="ato-corrected",
            streams=RunStreams.for_runs(1, 0, 1),
        )
