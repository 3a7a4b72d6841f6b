"""Ground TASC live (issue 17): the stations' wayside units and the trains' onboard units run the
stop kernel's own steps; wired together without delay they give the kernel's stop exactly, and
they fail safe when the wayside falls silent."""

from __future__ import annotations

import numpy as np
import pytest

from railstop.config import default_line, default_vehicle
from railstop.control.line_ato import handover_m
from railstop.control.supervision import EB_TIMEOUT, eb_cause_name
from railstop.live.tasc import (
    TASC_DT_S,
    Reading,
    StationTasc,
    TascStop,
    WaysideTasc,
    pack_readings,
    unpack_readings,
)
from railstop.onboard.tasc_receiver import CONFIG_CODES, RX_EB_T
from railstop.sim.kernel import scenario_arrays
from railstop.sim.scenario import Scenario
from railstop.sim.single import run_stop

LINE = default_line()
VEHICLE = default_vehicle()


def _stop(
    st: StationTasc, *, delay_steps: int = 0, silent_after_s: float = np.inf, until_s: float = 200.0
) -> tuple[TascStop, WaysideTasc]:
    """One nominal stop with the wayside and the train wired directly: every telegram arrives
    ``delay_steps`` steps after it was sent, none after ``silent_after_s`` (the wayside died)."""
    sc, _, _, _ = scenario_arrays(Scenario.nominal(st.station, VEHICLE))
    v = float(sc[0][0])
    wayside = WaysideTasc(st)
    train = TascStop(
        st=st,
        train=2,
        sc=sc[0],
        x_m=handover_m(st.first_detector_m, v),
        v_mps=v,
        rng=np.random.default_rng(0),
        t0_s=0.0,
    )
    air: list[tuple[float, bytes]] = []
    t = 0.0
    while not train.stopped and t < until_s:
        train.step(t)
        if t < silent_after_s:
            wayside.read(2, train.stopped, train.out)
            wayside.repeat(t)
            air += [(t + delay_steps * TASC_DT_S, p) for _, p in wayside.due]
        train.out.clear()
        wayside.due.clear()
        for _, payload in [a for a in air if a[0] <= t + 1e-9]:
            train.deliver(payload)
        air = [a for a in air if a[0] > t + 1e-9]
        t += TASC_DT_S
    return train, wayside


@pytest.mark.parametrize("controller", list(CONFIG_CODES))
def test_live_units_wired_without_delay_give_the_kernels_stop(controller: str) -> None:
    """The wayside unit, the telegram through the codec and the onboard unit with its plant, wired
    without delay, stop where the kernel's detailed stop stops (nominal draw, ideal link) at every
    station of the line, with as many commands."""
    for i, station in enumerate(LINE.stations):
        st = StationTasc.create(i, station, VEHICLE, controller)
        train, wayside = _stop(st)
        ref, _ = run_stop(line=LINE, station=station, vehicle=VEHICLE, controller=controller, seed=1)
        assert train.stopped
        assert round(train.error_m, 6) == pytest.approx(ref.stop_error_m, abs=2e-6), station.name
        assert train.commands == ref.commands
        assert len(wayside.records) == ref.commands_sent
        assert train.result()["emergency_brake"] is None


def test_every_command_record_carries_its_inputs_and_what_went_on_the_air() -> None:
    st = StationTasc.create(0, LINE.stations[0], VEHICLE, "tasc-pwm")
    _, wayside = _stop(st)
    assert wayside.records
    for rec in wayside.records:
        assert rec["station"] == LINE.stations[0].name and rec["train"] == 2
        for key in ("detector", "passage_s", "distance_m", "speed_mps", "command_decel_mps2", "telegram"):
            assert key in rec
        assert rec["telegram_type"].startswith("tasc-")


def test_a_silent_wayside_brings_the_emergency_brake_after_the_supervision_time_out() -> None:
    """DESIGN rule 10 / SPEC §1: the wayside stops sending in mid-stop (its process died); the
    onboard unit applies the emergency brake once no telegram came for supervision_timeout_s."""
    st = StationTasc.create(0, LINE.stations[0], VEHICLE, "tasc-pwm")
    full, _ = _stop(st)
    silent_at = 0.5 * float(full.stop_time_s)
    train, _ = _stop(st, silent_after_s=silent_at)
    assert train.stopped
    assert train.result()["emergency_brake"] == eb_cause_name(EB_TIMEOUT)
    eb_t = float(train.rx[RX_EB_T])
    timeout = LINE.stations[0].tasc.supervision_timeout_s
    repeat = LINE.stations[0].tasc.repeat_period_s
    # The last telegram (a repeat) left at most one repeat period before the silence.
    assert silent_at - repeat + timeout - 1e-6 <= eb_t <= silent_at + timeout + TASC_DT_S + 1e-6


def test_a_train_entering_a_zone_whose_wayside_is_dead_is_braked() -> None:
    st = StationTasc.create(1, LINE.stations[1], VEHICLE, "tasc-brake-controller")
    train, wayside = _stop(st, silent_after_s=0.0)
    assert wayside.records == []
    assert train.stopped and train.commands == 0
    assert train.result()["emergency_brake"] == eb_cause_name(EB_TIMEOUT)


def test_a_late_link_still_stops_the_train_within_tolerance() -> None:
    """80 ms on every telegram (the live processes' order of delay): the stop stays within the
    station's tolerance at every station."""
    for i, station in enumerate(LINE.stations):
        train, _ = _stop(StationTasc.create(i, station, VEHICLE, "tasc-pwm"), delay_steps=8)
        assert abs(train.error_m) <= station.psd_tolerance_m, station.name


def test_sensor_frames_round_trip_and_refuse_a_bad_length() -> None:
    readings = [Reading(12.34, 16.5, False, 0, np.nan), Reading(12.35, np.nan, True, 2, 12.347)]
    train, station, stands, back = unpack_readings(pack_readings(7, 3, True, readings))
    assert (train, station, stands) == (7, 3, True)
    assert back[0].t_s == 12.34 and back[1].passed and back[1].detector == 2
    assert np.isnan(back[1].doppler_mps) and back[1].passage_s == 12.347
    with pytest.raises(ValueError):
        unpack_readings(pack_readings(7, 3, True, readings)[:-1])
