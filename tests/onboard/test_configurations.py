"""The onboard configurations as drawn (SPEC §1 claims 9-15, 25) and the train's own control
around TASC: config 1's brake controller input, config 2's switching unit (step SW1-SW3 and PWM
SW11/SW12 variants, switch positions in the trace), config 3's zero-crossing synchronised OR
superposition at waveform level and in a stop."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from railstop.config import default_line, default_vehicle
from railstop.config.schema import Line, Station, Vehicle
from railstop.controllers import TASC_BRAKE_CONTROLLER, TASC_PWM, TASC_STEP, TASC_SWITCHED_PWM
from railstop.onboard.pwm_wave import (
    duty_per_period,
    pwm_wave,
    superimpose,
    synchronised_wave,
    time_grid,
    zero_crossings,
)
from railstop.onboard.tasc_receiver import (
    RX_ACTIVE,
    RX_ONBOARD_DUTY,
    RX_SIZE,
    SWITCH_ONBOARD,
    SWITCH_TRAIN,
    SWITCH_TRANSFER,
    receiver_params,
    receiver_pwm_output_1,
)
from railstop.physics.brake import decel_to_pwm_1
from railstop.sim.single import run_stop
from railstop.wayside.tasc_unit import SignalForm

LINE = default_line()
VEHICLE = default_vehicle()
CARRIER = 50.0


def _with_initial(station: Station, notch: int) -> Station:
    return station.model_copy(update={"tasc": station.tasc.model_copy(update={"initial_brake_notch": notch})})


def _line_with(station: Station) -> Line:
    stations = [station if s.name == station.name else s for s in LINE.stations]
    return LINE.model_copy(update={"stations": stations})


def _stop(controller: str, station: Station, vehicle: Vehicle = VEHICLE):  # type: ignore[no-untyped-def]
    result, batch = run_stop(
        line=_line_with(station), station=station, vehicle=vehicle, controller=controller, seed=0
    )
    assert batch.trace is not None
    return result, batch, batch.trace


# ---------------------------------------------------------------- config 3 at waveform level


def test_patent_example_50_plus_70_is_70_when_phase_locked() -> None:
    t = time_grid(CARRIER, periods=20)
    existing = pwm_wave(0.5, CARRIER, t, phase_s=0.0037)  # the train's signal, any phase
    edges = zero_crossings(existing, t)
    onboard = synchronised_wave(0.7, CARRIER, t, edges)
    ecu = duty_per_period(superimpose(existing, onboard), CARRIER, t - 0.0037)
    # Every whole period after the first lock: exactly the larger duty.
    assert np.allclose(ecu[1:], 0.7, atol=2e-3)
    # The onboard pulses start at the train's edges (phase-locked).
    own_edges = zero_crossings(onboard, t)
    assert np.allclose(own_edges[: edges.size], edges, atol=t[1] - t[0])


def test_out_of_phase_pulses_would_add_up() -> None:
    """Why the zero-crossing detector is there: unsynchronised, the OR is more than either."""
    t = time_grid(CARRIER, periods=20)
    existing = pwm_wave(0.5, CARRIER, t)
    onboard = pwm_wave(0.7, CARRIER, t, phase_s=0.5 / CARRIER)  # half a period late
    ecu = duty_per_period(superimpose(existing, onboard), CARRIER, t)
    assert np.all(ecu > 0.95)


def test_no_train_pulses_onboard_free_runs() -> None:
    t = time_grid(CARRIER, periods=10)
    existing = pwm_wave(0.0, CARRIER, t)
    edges = zero_crossings(existing, t)
    assert edges.size == 0
    ecu = duty_per_period(superimpose(existing, synchronised_wave(0.7, CARRIER, t, edges)), CARRIER, t)
    assert np.allclose(ecu, 0.7, atol=2e-3)


@settings(max_examples=60, deadline=None)
@given(
    existing=st.floats(0.0, 1.0),
    onboard=st.floats(0.0, 1.0),
    phase=st.floats(0.0, 1.0 / CARRIER, exclude_max=True),
)
# The train's signal already high when the record starts: no edge there (a detector that reported
# one locked the onboard clock to it and lost a period).
@example(existing=0.75, onboard=1.0, phase=0.0078125)
def test_kernel_rule_is_the_waveform_or(existing: float, onboard: float, phase: float) -> None:
    """The kernel's scalar rule (the larger duty, latched per period) equals the OR of the
    synchronised waveforms, for any duties and any phase of the train's signal."""
    t = time_grid(CARRIER, periods=6, samples_per_period=2000)
    train = pwm_wave(existing, CARRIER, t, phase_s=phase)
    ours = synchronised_wave(onboard, CARRIER, t, zero_crossings(train, t))
    measured = duty_per_period(superimpose(train, ours), CARRIER, t - phase)[1:]

    rp = receiver_params(TASC_PWM, 6, VEHICLE, LINE.stations[0], 0.01)
    rx = np.zeros(RX_SIZE)
    rx[RX_ACTIVE] = 1.0
    rx[RX_ONBOARD_DUTY] = onboard
    latched = receiver_pwm_output_1(rx, rp, 0, existing)
    assert latched == max(existing, onboard)
    assert np.allclose(measured, latched, atol=2e-3)


def test_waveform_inputs_are_checked() -> None:
    t = time_grid(CARRIER, periods=2)
    with pytest.raises(ValueError, match=r"outside 0\.\.1"):
        pwm_wave(1.2, CARRIER, t)
    with pytest.raises(ValueError, match="time_grid"):
        time_grid(0.0, periods=2)


# ---------------------------------------------------------------- the train's own control


@pytest.mark.parametrize("controller", [TASC_BRAKE_CONTROLLER, TASC_STEP, TASC_SWITCHED_PWM, TASC_PWM])
def test_initial_brake_acts_from_the_zone_until_tasc_speaks(controller: str) -> None:
    # Detectors only: the first telegram comes at the second detector, 80 m into the zone.
    station = _with_initial(LINE.station("Riverside").detectors_only(), 2)
    _, batch, tr = _stop(controller, station)
    first = batch.detector_passages_s[0, 0]
    target = tr.target_decel_mps2[:, 0]
    told = np.flatnonzero(np.isfinite(target))[0]  # the first braking telegram taken
    t = tr.t_s[:, 0]
    zone = (t > first + 0.05) & (np.arange(t.size) < told)
    b2 = VEHICLE.brake.notch_decel_mps2[1]
    assert zone.any()
    # The train's own command is B2 from the zone's start, and before TASC speaks the ECU gets it.
    assert np.allclose(tr.own_demand_mps2[zone, 0], b2, atol=0.02)
    assert np.allclose(tr.demand_decel_mps2[zone, 0], tr.own_demand_mps2[zone, 0])
    before = t < first - 0.05
    assert np.all(tr.own_demand_mps2[before, 0] == 0.0)
    assert np.all(tr.demand_decel_mps2[before, 0] == 0.0)
    # The train slowed on its own before TASC spoke.
    assert tr.speed_mps[told, 0] < tr.speed_mps[0, 0] - 1.0


@pytest.mark.parametrize("controller", [TASC_BRAKE_CONTROLLER, TASC_STEP, TASC_SWITCHED_PWM, TASC_PWM])
@pytest.mark.parametrize("station", [s.name for s in LINE.stations])
def test_tasc_takes_over_from_the_initial_brake(controller: str, station: str) -> None:
    # The wayside models the train's own B2 from the first detector on: the nominal stop keeps
    # the ±0.10 m of a stop without it (before that model: +0.13 m for tasc-step at Riverside).
    result, _, _ = _stop(controller, _with_initial(LINE.station(station), 2))
    assert result.emergency_brake is None
    assert abs(result.stop_error_m) < 0.10


@pytest.mark.parametrize("station", [s.name for s in LINE.stations])
def test_detectors_only_with_the_initial_brake_stops_at_every_station(station: str) -> None:
    """Detectors only, the first command comes at the second detector; with the train's own
    initial brake from the first, modelled by the wayside, every default station stops the train
    within the PSD tolerance."""
    result, _, _ = _stop(TASC_STEP, _with_initial(LINE.station(station).detectors_only(), 2))
    assert result.stopped and result.emergency_brake is None
    assert abs(result.stop_error_m) <= LINE.station(station).psd_tolerance_m


def test_without_initial_brake_the_train_holds_its_speed() -> None:
    _, _, tr = _stop(TASC_STEP, _with_initial(LINE.station("Riverside"), 0))
    told = np.flatnonzero(np.isfinite(tr.target_decel_mps2[:, 0]))[0]
    assert np.all(tr.own_demand_mps2[:told, 0] == 0.0)
    assert np.allclose(tr.speed_mps[:told, 0], tr.speed_mps[0, 0])


def test_config3_superimposes_on_the_trains_own_demand() -> None:
    """Config 3 does not replace the train's command: the ECU always sees at least it."""
    _, _, tr = _stop(TASC_PWM, _with_initial(LINE.station("Riverside"), 1))
    own = tr.own_demand_mps2[:, 0]
    demand = tr.demand_decel_mps2[:, 0]
    assert np.any(own > 0.0)
    # Latched once per carrier period (two steps): at least the train's demand of either step.
    own_latched = np.minimum(own, np.concatenate(([own[0]], own[:-1])))
    assert np.all(demand >= own_latched - 1e-9)
    target = tr.target_decel_mps2[:, 0]
    took = np.isfinite(target)
    # Where TASC asks for more, the ECU sees TASC's duty (once latched at the next period).
    assert np.any(demand[took] > own[took] + 0.1)


def test_config3_the_trains_own_step_is_released_at_the_hand_over_its_carrier_stays() -> None:
    """SPEC §1 claims 15, 25: the zero-crossing detector needs the train's own PWM signal; the
    train's own controller keeps its carrier (the released duty, 10 %) and releases its initial
    step once TASC's first command is in ([interpretation]: the OR could only add to it)."""
    result, _, tr = _stop(TASC_PWM, _with_initial(LINE.station("Riverside"), 2))
    own = tr.own_demand_mps2[:, 0]
    told = np.flatnonzero(np.isfinite(tr.target_decel_mps2[:, 0]))[0]
    assert own[:told].max() == pytest.approx(VEHICLE.brake.notch_decel_mps2[1], abs=0.02)
    after = own[told + 1 :]  # from the step after the first command was taken
    assert np.all(after[np.isfinite(after)] == 0.0)
    moving = tr.speed_mps[:, 0] > 0.0
    released = VEHICLE.brake.pwm_duty[1]
    assert np.nanmin(tr.duty[moving, 0]) >= released - 1e-12  # never a dead line while running
    assert result.within_tolerance and result.emergency_brake is None


def test_config3_with_the_trains_own_step_stops_as_well_as_without_it() -> None:
    """Before the hand-over, B2 kept under the OR stopped 30 % of the standard set short (69.9 %
    within ±0.35 m at Riverside); with it, as many runs stop within the tolerance as without
    the train's own step."""
    from railstop.config.disturbances import load_disturbances
    from railstop.sim.campaign import simulate_runs

    standard = load_disturbances("standard")
    shares = []
    for notch in (0, 2):
        station = _with_initial(LINE.station("Riverside"), notch)
        batch, _ = simulate_runs(
            station=station, vehicle=VEHICLE, controller=TASC_PWM, disturbances=standard, seed=5,
            first_run=0, n=1000, track=LINE.track,
        )  # fmt: skip
        shares.append(float(np.mean(np.abs(batch.stop_error_m) <= station.psd_tolerance_m)))
    assert shares[1] >= 0.995 and shares[1] >= shares[0] - 0.003, shares


# ---------------------------------------------------------------- config 2's switching unit


@pytest.mark.parametrize("controller", [TASC_STEP, TASC_SWITCHED_PWM])
def test_switching_unit_changes_over_break_before_make(controller: str) -> None:
    station = _with_initial(LINE.station("Riverside"), 2)
    _, _, tr = _stop(controller, station)
    sw = tr.switch[:, 0]
    target = tr.target_decel_mps2[:, 0]
    told = np.flatnonzero(np.isfinite(target))[0]
    # The train's command until the onboard unit has one, then the transfer, then onboard to the end.
    assert np.all(sw[:told] == SWITCH_TRAIN)
    transfer = np.flatnonzero(sw == SWITCH_TRANSFER)
    steps = round(VEHICLE.brake.switch_transfer_s / 0.01)
    assert transfer.size == steps
    assert np.array_equal(transfer, np.arange(told, told + steps))
    assert np.all(sw[told + steps :] == SWITCH_ONBOARD)
    # While the contacts move the ECU input is open: no service brake is asked for.
    assert np.all(tr.demand_decel_mps2[transfer, 0] == 0.0)
    # Before, the ECU got the train's own B2.
    assert tr.demand_decel_mps2[told - 1, 0] == pytest.approx(VEHICLE.brake.notch_decel_mps2[1], abs=0.02)


def test_stop_result_reports_when_the_switch_went_over() -> None:
    """`railstop stop` says when config 2's ECU input went over: at the first command's arrival
    plus the transfer, from the first detector; no such time without a switching unit."""
    result, batch, tr = _stop(TASC_STEP, LINE.station("Riverside"))
    told = np.flatnonzero(np.isfinite(tr.target_decel_mps2[:, 0]))[0]
    steps = round(VEHICLE.brake.switch_transfer_s / 0.01)
    expected = tr.t_s[told + steps, 0] - batch.detector_passages_s[0, 0]
    assert result.switch_over_s == pytest.approx(expected, abs=1e-3)
    assert _stop(TASC_PWM, LINE.station("Riverside"))[0].switch_over_s is None


def test_switch_transfer_time_is_data() -> None:
    brake = VEHICLE.brake.model_copy(update={"switch_transfer_s": 0.0})
    vehicle = VEHICLE.model_copy(update={"brake": brake})
    _, _, tr = _stop(TASC_STEP, LINE.station("Riverside"), vehicle)
    sw = tr.switch[:, 0]
    assert not np.any(sw == SWITCH_TRANSFER)
    assert np.any(sw == SWITCH_ONBOARD)


@pytest.mark.parametrize("controller", [TASC_BRAKE_CONTROLLER, TASC_PWM])
def test_no_switching_unit_outside_config_2(controller: str) -> None:
    _, _, tr = _stop(controller, LINE.station("Riverside"))
    assert np.all(tr.switch[:, 0] == -1)


def test_switched_pwm_drives_the_ecu_with_the_onboard_duty() -> None:
    """Config 2, PWM variant: after the changeover the ECU's duty is the onboard unit's own."""
    _, _, tr = _stop(TASC_SWITCHED_PWM, _with_initial(LINE.station("Riverside"), 3))
    sw = tr.switch[:, 0]
    on = np.flatnonzero(sw == SWITCH_ONBOARD)
    target = tr.target_decel_mps2[on, 0]
    duty = tr.duty[on, 0]
    brake = VEHICLE.brake
    expected = np.array(
        [decel_to_pwm_1(a, np.asarray(brake.pwm_duty), np.asarray(brake.pwm_decel_mps2)) for a in target]
    )
    # Latched once per carrier period: equal to the target's duty within a period of a change.
    assert np.mean(np.isclose(duty, expected, atol=1e-9)) > 0.9
    # Before the changeover the ECU had the train's own B3.
    assert tr.demand_decel_mps2[on[0] - 3, 0] == pytest.approx(brake.notch_decel_mps2[2], abs=0.01)


# ---------------------------------------------------------------- config 2's own cycle (stop model 22)


def _onboard_changes(controller: str, vehicle: Vehicle, form: SignalForm | None = None):  # type: ignore[no-untyped-def]
    _, batch = run_stop(
        line=LINE, station=LINE.station("Riverside"), vehicle=vehicle, controller=controller, seed=0,
        form=form,
    )  # fmt: skip
    assert batch.trace is not None
    tr = batch.trace
    notch = tr.notch[:, 0]
    changes = np.flatnonzero(np.diff(notch) != 0) + 1
    return tr, changes[tr.switch[changes, 0] == SWITCH_ONBOARD]


def test_config2_unit_chooses_its_notch_once_per_its_cycle() -> None:
    """The onboard unit's own modulator (config 2, form 6) changes the notch only on its cycle,
    tasc_cycle_s (5 steps of 10 ms); with a cycle of one step it changes between them too."""
    _, changes = _onboard_changes(TASC_STEP, VEHICLE)
    cycle = round(VEHICLE.brake.tasc_cycle_s / 0.01)
    assert cycle == 5 and changes.size >= 10
    assert set(((changes - changes[0]) % cycle).tolist()) == {0}
    fast = VEHICLE.model_copy(update={"brake": VEHICLE.brake.model_copy(update={"tasc_cycle_s": 0.01})})
    _, fast_changes = _onboard_changes(TASC_STEP, fast)
    assert len(set(((fast_changes - fast_changes[0]) % cycle).tolist())) > 1


@pytest.mark.parametrize("form", [SignalForm.BRAKE_COMMAND, SignalForm.INCREASE_DECREASE])
def test_config2_relays_the_waysides_notch_in_the_step_it_has_it(form: SignalForm) -> None:
    """Forms 7 and 8: the notch the wayside sends reaches the switching unit in the step the
    telegram is taken (its target is that notch's deceleration), not at the unit's next cycle."""
    tr, changes = _onboard_changes(TASC_STEP, VEHICLE, form)
    table = np.concatenate([[0.0], VEHICLE.brake.notch_decel_mps2])
    target = tr.target_decel_mps2[:, 0]
    on = np.flatnonzero((tr.switch[:, 0] == SWITCH_ONBOARD) & np.isfinite(target))
    assert changes.size >= 5
    assert np.array_equal(table[tr.notch[on, 0]], target[on])
    # Telegrams do not wait for the unit's cycle: the changes fall on several phases of it.
    assert len(set(((changes - changes[0]) % 5).tolist())) > 1
