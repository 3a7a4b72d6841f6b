"""The robust loop of the wayside unit (issue 13 item 6, beyond SPEC §1).

- the brake response (equivalent dead time, lag) identified from the Doppler samples:
  recovered from a synthetic record, used in the stop, and never laxer supervision;
- a missed detector's passage filled in from the Doppler-integrated travel.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from railstop.config import default_line, default_vehicle
from railstop.config.scenario import Scenario
from railstop.config.schema import Station
from railstop.control.brake_ident import (
    AFTER_S,
    BEFORE_S,
    identify_response_1,
    noise_variance_1,
)
from railstop.control.tasc import HISTORY, SAMPLES
from railstop.controllers import TASC_PWM
from railstop.model.build import KernelModel
from railstop.sim.engine import BatchResult, run_batch
from railstop.streams import RunStreams
from railstop.wayside.tasc_unit import (
    FILL_MARGIN_M,
    WP_BASE_DELAY,
    WP_LAG,
    WS_DELAY,
    WS_EMERGENCY,
    WS_FILLED,
    WS_LAST_DET,
    WS_SIZE,
    WS_TRAVEL,
    wayside_init_1,
    wayside_observe_1,
    wayside_passage_1,
)

LINE = default_line()
VEHICLE = default_vehicle()
RIVERSIDE = LINE.station("Riverside")
DT = 0.01
NOMINAL_DELAY = VEHICLE.brake.dead_time_s + VEHICLE.brake.time_constant_s
NOMINAL_LAG = VEHICLE.brake.time_constant_s


# ---------------------------------------------------------------- the identifier alone


def _record(
    onset: float, lag: float, gain: float, noise: float, seed: int, *, command: float = 0.6
) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """A radar record of a train at 16 m/s given one braking step at t = 0 (sent then), its
    response starting ``onset`` later with lag ``lag``; the history as a wayside that assumed
    the nominal response would have planned it. Returns (ring, now, values, effects)."""
    n = round((AFTER_S + BEFORE_S) / DT)
    now = AFTER_S
    t = now - DT * np.arange(n)[::-1]  # oldest first
    external = 0.03
    v = 16.0 - external * np.maximum(t, 0.0)
    u = np.maximum(t - onset, 0.0)  # the integral of a first-order step response
    v -= gain * command * (u - lag * (1.0 - np.exp(-u / lag)))
    v *= 1.0 + noise * np.random.default_rng(seed).standard_normal(n)
    values = np.zeros(HISTORY)
    effects = np.full(HISTORY, np.inf)
    values[0] = command
    effects[0] = NOMINAL_DELAY  # sent at 0, planned to act after the nominal delay
    return v, now, values, effects


def _identify(
    ring: np.ndarray, now: float, values: np.ndarray, effects: np.ndarray
) -> tuple[float, float, float]:
    return identify_response_1(
        ring, ring.size - 1, ring.size, DT, now, 0.0, 0.03, values, effects,
        NOMINAL_DELAY, NOMINAL_DELAY, NOMINAL_LAG, np.zeros(SAMPLES),
    )  # fmt: skip


@pytest.mark.parametrize(
    ("onset", "lag"),
    [(0.37, 0.45), (0.15, 0.25), (1.0, 0.9), (0.3, 0.9), (0.9, 0.3)],
)
def test_a_noiseless_response_is_recovered(onset: float, lag: float) -> None:
    ring, now, values, effects = _record(onset, lag, 1.1, 0.0, 0)
    delay, lag_id, gain = _identify(ring, now, values, effects)
    assert delay == pytest.approx(onset + lag, abs=0.03)
    assert lag_id == pytest.approx(lag, abs=0.05)
    assert gain == pytest.approx(1.1, abs=0.02)


@settings(max_examples=25, deadline=None)
@given(
    onset=st.floats(0.15, 1.0),
    lag=st.floats(0.25, 0.9),
    gain=st.floats(0.8, 1.25),
    seed=st.integers(0, 2**31 - 9),
)
def test_the_delay_is_found_through_the_radar_noise(onset: float, lag: float, gain: float, seed: int) -> None:
    """With the wide set's 0.5 % Doppler noise the equivalent dead time comes out within 0.3 s
    (its campaign spread is about 0.09 s), the gain within 10 %: the median over nine noise draws
    of one response, and no single draw wildly off. (A single draw is not held to those bounds:
    at the wide set's slowest corner, onset 1.0 s and lag 0.9 s, the prior towards the nominal
    0.8 s biases the delay by -0.06 to -0.10 s and the gain by -2 to -4 %, with a spread of
    2.5 % between draws, so about 1 draw in 300 ends 10 % off the gain.)"""
    delay_err = []
    gain_err = []
    for k in range(9):
        ring, now, values, effects = _record(onset, lag, gain, 0.005, seed + k)
        delay, _, gain_id = _identify(ring, now, values, effects)
        delay_err.append(delay - (onset + lag))
        gain_err.append((gain_id - gain) / gain)
    assert abs(float(np.median(delay_err))) < 0.3
    assert abs(float(np.median(gain_err))) < 0.1
    assert max(abs(e) for e in delay_err) < 0.5
    assert max(abs(e) for e in gain_err) < 0.2


def test_no_braking_step_identifies_nothing() -> None:
    """A train that never brakes says nothing about its brakes: NaN, the nominal response stays."""
    ring, now, values, effects = _record(0.4, 0.45, 1.0, 0.005, 1, command=0.0)
    assert all(np.isnan(_identify(ring, now, values, effects)))


def test_noise_variance_from_second_differences() -> None:
    rng = np.random.default_rng(3)
    t = np.arange(500) * DT
    ring = 15.0 - 0.7 * t + 0.05 * rng.standard_normal(t.size)
    assert noise_variance_1(ring, ring.size - 1, ring.size) == pytest.approx(0.05**2, rel=0.15)
    ring[:] = 0.0  # out of the radar's range: no estimate
    assert np.isnan(noise_variance_1(ring, ring.size - 1, ring.size))


# ---------------------------------------------------------------- in the stop


def _stops(station: Station, n: int = 1, **values: np.ndarray) -> BatchResult:
    scenario = Scenario.nominal(station=station, vehicle=VEHICLE, n=n).with_values(**values)
    return run_batch(
        station=station,
        vehicle=VEHICLE,
        scenario=scenario,
        controller=TASC_PWM,
        streams=RunStreams.for_runs(5, 0, n),
    )


def _without(station: Station, **tasc: bool) -> Station:
    return station.model_copy(update={"tasc": station.tasc.model_copy(update=tasc)})


SLOW = {
    "dead_time_s": np.array([0.8]),
    "time_constant_s": np.array([0.9]),
    "radio_latency_s": np.array([0.2]),
}


def test_slow_brakes_stop_on_the_mark_once_identified() -> None:
    """Dead time 0.8 s, lag 0.9 s, 200 ms radio (the wide set's corner): identified within
    0.15 s and stopped within ±0.10 m; planned with the nominal response instead the train
    stops short, outside the PSD tolerance."""
    ident = _stops(RIVERSIDE, **SLOW)
    assert ident.brake_delay_identified_s[0] == pytest.approx(0.8 + 0.9 + 0.2, abs=0.15)
    assert ident.brake_lag_identified_s[0] == pytest.approx(0.9, abs=0.15)
    assert abs(ident.stop_error_m[0]) <= 0.10
    nominal = _stops(_without(RIVERSIDE, identify_brake_response=False), **SLOW)
    assert np.isnan(nominal.brake_delay_identified_s[0])
    assert nominal.stop_error_m[0] < -0.35


def test_nominal_brakes_are_identified_as_nominal() -> None:
    ident = _stops(RIVERSIDE, radio_latency_s=np.array([0.0]), doppler_noise_frac=np.array([0.0]))
    assert ident.brake_delay_identified_s[0] == pytest.approx(NOMINAL_DELAY, abs=0.05)
    assert abs(ident.stop_error_m[0]) <= 0.05


def test_the_guard_never_gets_laxer_with_a_fast_identified_brake() -> None:
    """DESIGN rule 10: the overrun guard keeps the larger of the nominal and the identified
    delay. A train too fast for the platform end fires the guard with the delay identified at
    0.1 s exactly as with the nominal one."""
    model = KernelModel.create(
        station=RIVERSIDE, vehicle=VEHICLE, controller=TASC_PWM, form=None, dt_s=DT, max_time_s=150.0
    )
    det = model.det_pos
    third = 2  # 140 m before the stop

    def fires_at(delay: float) -> float:
        """The lowest speed (m/s) at which the guard fires at the third detector."""
        for speed in np.arange(10.0, 30.0, 0.1):
            ws = np.empty(WS_SIZE)
            hv, he, pt, px = np.empty(HISTORY), np.empty(HISTORY), np.empty(3), np.empty(3)
            wayside_init_1(ws, model.wp, hv, he, pt, px)
            ws[WS_DELAY] = delay
            dbuf = np.zeros(model.window)
            wayside_observe_1(ws, model.wp, dbuf, pt, px, det, 0.0, True, third, 0.0, speed)
            wayside_observe_1(ws, model.wp, dbuf, pt, px, det, DT, False, third, 0.0, speed)
            if ws[WS_EMERGENCY] > 0.0:
                return float(speed)
        return np.inf

    assert model.wp[WP_BASE_DELAY] > 0.1 and model.wp[WP_LAG] > 0.0
    nominal = fires_at(model.wp[WP_BASE_DELAY])
    assert np.isfinite(nominal)
    assert fires_at(0.1) == nominal
    assert fires_at(3.0) < nominal  # a slower identified brake makes it fire earlier


# ---------------------------------------------------------------- a missed detector


def test_a_missed_detector_is_filled_in_from_the_doppler() -> None:
    """The unit passed detector 2 (index 1); its travel reaches detector 3 plus the margin with
    no report: the passage is filled in, timed from the travel and the speed."""
    model = KernelModel.create(
        station=RIVERSIDE, vehicle=VEHICLE, controller=TASC_PWM, form=None, dt_s=DT, max_time_s=150.0
    )
    det = model.det_pos
    ws = np.empty(WS_SIZE)
    hv, he, pt, px = np.empty(HISTORY), np.empty(HISTORY), np.empty(3), np.empty(3)
    wayside_init_1(ws, model.wp, hv, he, pt, px)
    dbuf = np.zeros(model.window)
    wayside_observe_1(ws, model.wp, dbuf, pt, px, det, 10.0, True, 1, 10.0, 15.0)
    assert ws[WS_LAST_DET] == 1
    gap = det[2] - det[1]
    ws[WS_TRAVEL] = gap + FILL_MARGIN_M - 0.01
    assert wayside_passage_1(ws, model.wp, px, det, 16.0, False, 1, 10.0, 15.0)[0] is False
    ws[WS_TRAVEL] = gap + FILL_MARGIN_M + 0.3
    passed, detector, at = wayside_passage_1(ws, model.wp, px, det, 16.0, False, 1, 10.0, 15.0)
    assert passed and detector == 2
    assert at == pytest.approx(16.0 - (FILL_MARGIN_M + 0.3) / 15.0)
    assert ws[WS_FILLED] == 1
    # A late report of the detector just filled in is not a second passage.
    wayside_observe_1(ws, model.wp, dbuf, pt, px, det, 16.0, passed, detector, at, 15.0)
    assert wayside_passage_1(ws, model.wp, px, det, 16.1, True, 2, 16.05, 15.0)[0] is False


def test_missed_detectors_cost_no_stop_with_the_radar() -> None:
    """40 stops with every detector missing 30 % of trains. Where the first detector missed
    too, nothing can be filled in (no reference for the travel) and the telegram supervision
    stops the train (DESIGN rule 10); every other stop with up to two passages filled in is
    within the PSD tolerance, and without filling in more stops are lost."""
    n = 40
    miss = {"sensor_miss_probability": np.full(n, 0.3)}
    filled = _stops(RIVERSIDE, n, **miss)
    assert filled.detectors_filled.sum() >= 20
    in_service = filled.emergency_brake == 0
    assert np.all(np.abs(filled.stop_error_m[in_service & (filled.detectors_filled <= 2)]) <= 0.35)
    unfilled = _stops(_without(RIVERSIDE, fill_missed_detectors=False), n, **miss)
    assert np.all(unfilled.detectors_filled == 0)
    assert np.array_equal(unfilled.emergency_brake == 0, in_service)  # the same first misses
    lost_filled = np.sum(np.abs(filled.stop_error_m[in_service]) > 0.35)
    lost_unfilled = np.sum(np.abs(unfilled.stop_error_m[in_service]) > 0.35)
    assert lost_filled <= 1 < lost_unfilled
