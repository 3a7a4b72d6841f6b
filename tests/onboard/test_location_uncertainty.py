"""The location uncertainty a CBTC train reports (IEEE 1474.1), from its own positioning unit.

``railstop.onboard.positioning.unit_uncertainty_m``: k standard deviations of the dead reckoning
since the last fix, plus the bound of the slides no accelerometer bridged, plus (without the
learner) the detection delay the document's fix leaves in. The line reports it with every
position and counts every step at which a train's true front lay outside it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from railstop.config import default_line, default_vehicle
from railstop.config.operation import load_operation
from railstop.config.schema import TrackCircuit
from railstop.onboard.positioning import PositioningUnit
from railstop.sim.line import LineSettings, LineSimulation, PositionSettings

CIRCUITS = [TrackCircuit(id=1, start_m=0.0, end_m=500.0), TrackCircuit(id=2, start_m=500.0, end_m=2000.0)]
DT = 0.1
V = 10.0  # m/s
NOMINAL_DELAY_S = 0.3


def _unit(*, learn: bool = True, time_sd_s: list[float] | None = None) -> PositioningUnit:
    pos = default_vehicle().positioning.model_copy(update={"learn": learn})
    return PositioningUnit(
        circuits=CIRCUITS,
        settings=pos,
        n=1,
        cycle_s=DT,
        start_position_m=np.zeros(1),
        boundary_sd_m=[0.2, 0.2],
        delay_spread_s=0.05,
        nominal_delay_s=NOMINAL_DELAY_S,
        time_sd_s=time_sd_s,
    )


class _Run:
    """One train at V on a tachometer that reads true: the clock, the odometer, the unit."""

    def __init__(self, unit: PositioningUnit) -> None:
        self.unit, self.t, self.odo = unit, 0.0, 0.0
        unit.log(clock_time_s=np.array([0.0]), odometer_m=np.array([0.0]), speed_mps=np.array([V]))

    def run(self, seconds: float, *, wheel_mps: float = V, wsp: bool = False) -> None:
        for _ in range(round(seconds / DT)):
            self.t += DT
            self.odo += wheel_mps * DT
            self.unit.log(
                clock_time_s=np.array([self.t]),
                odometer_m=np.array([self.odo]),
                speed_mps=np.array([wheel_mps]),
                wsp_active=np.array([wsp]),
            )

    def fix(self, circuit_id: int, occupied_s: float) -> None:
        rep = self.unit.handle(
            run=np.array([0]), circuit_id=np.array([circuit_id]), gnss_time_s=np.array([occupied_s])
        )
        assert rep.accepted.all()

    def u(self, sigmas: float) -> float:
        return float(self.unit.uncertainty_m(sigmas)[0])


def test_the_bound_is_k_standard_deviations_and_grows_with_the_distance_run() -> None:
    r = _Run(_unit())
    r.run(55.0)  # 550 m: past the start of circuit 2 at 500 m (50.0 s)
    r.fix(2, 50.0 + NOMINAL_DELAY_S)
    one, five = r.u(1.0), r.u(5.0)
    assert one > 0.0 and five == pytest.approx(5.0 * one, rel=1e-12)  # no slide, learner on: only σ
    grown = []
    for _ in range(3):
        r.run(20.0)
        grown.append(r.u(5.0))
    assert five < grown[0] < grown[1] < grown[2]  # the scale's error over the distance since


def test_an_unbridged_slide_adds_its_bound_and_a_fix_clears_it() -> None:
    r = _Run(_unit())
    r.run(1.0)
    r.fix(1, 0.0 + NOMINAL_DELAY_S)
    before = r.u(0.0)
    assert before == 0.0  # no slide, no bias: zero standard deviations leave nothing
    # The WSP acts for 2 s, the wheel at 4 m/s: the train runs between 4 and 10 m/s (a slide),
    # the count is off by at most (10 - 4) m/s per second, 12 m in all.
    r.run(2.0, wheel_mps=4.0, wsp=True)
    assert r.u(0.0) == pytest.approx(12.0, rel=1e-9)
    # A slip from standstill: the wheel at 3 m/s, the train between 0 and 3 m/s, 3 m/s x 1 s more
    # (the speed before the WSP acted was the 4 m/s the wheel had when the WSP let go).
    r.run(1.0, wheel_mps=4.0)  # the WSP lets go: the hold speed is the wheel's again
    r.run(1.0, wheel_mps=3.0, wsp=True)
    assert r.u(0.0) == pytest.approx(12.0 + 3.0, rel=1e-9)
    r.run(48.0)
    r.fix(2, r.t - 1.0)  # the next circuit: the bound of the slides is gone, σ restarts from the fix
    assert r.u(0.0) == 0.0


def test_without_the_learner_the_delay_the_document_leaves_in_is_added_whole() -> None:
    r = _Run(_unit(learn=False))
    r.run(55.0)
    r.fix(2, 50.0 + NOMINAL_DELAY_S)
    # SPEC §2: the circuit's start becomes the position at the occupancy time, when the train
    # was already V x the delay past it: that bias, whole, beside the standard deviations.
    assert r.u(0.0) == pytest.approx(V * NOMINAL_DELAY_S, rel=1e-12)
    assert r.u(5.0) > V * NOMINAL_DELAY_S


def test_a_fix_timed_by_a_free_running_clock_counts_for_less() -> None:
    bounds = []
    for time_sd in (None, [0.0, 1.0]):
        r = _Run(_unit(time_sd_s=time_sd))
        r.run(55.0)
        r.fix(2, 50.0 + NOMINAL_DELAY_S)
        bounds.append(r.u(5.0))
    gnss, free = bounds
    assert free > 1.5 * gnss  # a second's clock error at 10 m/s: the fix says less


def test_a_negative_time_error_is_refused() -> None:
    with pytest.raises(ValueError, match="time_sd_s"):
        _unit(time_sd_s=[0.0, -1.0])
    with pytest.raises(ValueError, match="time_sd_s"):
        _unit(time_sd_s=[0.1])


def _line_run(settings: LineSettings, sigmas: float | None = None) -> dict[str, object]:
    line = default_line()
    if sigmas is not None:
        line = line.model_copy(
            update={"cbtc": line.cbtc.model_copy(update={"position_confidence_sigmas": sigmas})}
        )
    sim = LineSimulation(
        line=line, vehicle=default_vehicle(), operation=load_operation(None, line), seed=3, settings=settings
    )
    summary = sim.run(900.0).summary()
    cbtc = summary["cbtc"]
    assert isinstance(cbtc, dict)
    return cbtc


@pytest.mark.parametrize(
    "settings",
    [
        LineSettings(signalling="cbtc", calibration="cold"),
        LineSettings(
            signalling="cbtc", slide_probability=0.5, position=PositionSettings(accelerometer=False)
        ),
        LineSettings(signalling="cbtc", position=PositionSettings(learn=False)),
    ],
    ids=["cold", "unbridged-slides", "no-learner"],
)
def test_on_the_line_every_train_s_true_front_lies_within_the_bound_it_reports(
    settings: LineSettings,
) -> None:
    cbtc = _line_run(settings)
    assert cbtc["uncertainty_exceeded"] == 0
    margin = cbtc["uncertainty_margin_min_m"]
    assert isinstance(margin, float) and margin > 0.0
    # The bound is the unit's own, not the declared one: it varies with the chain's state.
    assert cbtc["uncertainty_max_m"] != default_line().cbtc.position_uncertainty_m


def test_the_line_counts_a_bound_too_tight_to_hold() -> None:
    """The count can fire: one standard deviation without the learner's delay bias is too tight."""
    cbtc = _line_run(LineSettings(signalling="cbtc", calibration="cold"), sigmas=1.0)
    exceeded = cbtc["uncertainty_exceeded"]
    assert isinstance(exceeded, int) and exceeded > 0
    margin = cbtc["uncertainty_margin_min_m"]
    assert isinstance(margin, float) and margin < 0.0 and math.isfinite(margin)
