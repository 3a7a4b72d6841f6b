"""Ground TASC live (issue 17): the stations' wayside units and the trains' onboard units run the
stop kernel's own steps; wired together without delay they give the kernel's stop exactly, and
they fail safe when the wayside falls silent."""

from __future__ import annotations

import numpy as np
import pytest

from railstop.config import default_line, default_vehicle
from railstop.config.disturbances import draw_scenario, load_disturbances
from railstop.config.scenario import station_gradient
from railstop.control.supervision import EB_TIMEOUT, eb_cause_name
from railstop.link.codec import decode
from railstop.link.tasc_link import OFFICE_COMMAND_FIELDS
from railstop.live.tasc import (
    Reading,
    StationTasc,
    pack_readings,
    unpack_readings,
    wired_stop,
)
from railstop.onboard.tasc_receiver import CONFIG_CODES, RX_DEGRADED
from railstop.sim.engine import run_batch
from railstop.sim.single import run_stop
from railstop.streams import RunStreams

LINE = default_line()
VEHICLE = default_vehicle()


@pytest.mark.parametrize("controller", list(CONFIG_CODES))
def test_live_units_wired_without_delay_give_the_kernels_stop(controller: str) -> None:
    """The wayside unit, the telegram through the codec and the onboard unit with its plant, wired
    without delay, stop where the kernel's detailed stop stops (nominal draw, ideal link) at every
    station of the line, with as many commands."""
    for i, station in enumerate(LINE.stations):
        st = StationTasc.create(i, station, VEHICLE, controller)
        train, wayside = wired_stop(st, VEHICLE)
        ref, _ = run_stop(line=LINE, station=station, vehicle=VEHICLE, controller=controller, seed=1)
        assert train.stopped
        assert round(train.error_m, 6) == pytest.approx(ref.stop_error_m, abs=2e-6), station.name
        assert train.commands == ref.commands
        assert len(wayside.records) == ref.commands_sent
        assert train.result()["emergency_brake"] is None


@pytest.mark.parametrize("controller", ["tasc-pwm", "tasc-step"])
def test_live_parts_wired_give_the_campaigns_run_of_the_same_draw_bit_for_bit(controller: str) -> None:
    """DESIGN rule 1, parity (issue 35 item 8): the live processes' parts of the stop (the plant,
    the onboard unit, the wayside; ``model.parts``), wired without delay on the stop's clock with
    every telegram through the codec, give the campaign engine's run of the same draw of the
    standard set (its sensor noise, jitter and misses, brake response, load, adhesion) bit for bit:
    the stop error, the commands and the emergency brake. The link is ideal (the live link's
    delays and losses are its own)."""
    dist = load_disturbances("standard")
    for i, station in enumerate(LINE.stations):
        st = StationTasc.create(i, station, VEHICLE, controller)
        for run in (3, 17):
            streams = RunStreams.for_runs(5, run, 1)
            scenario, _ = draw_scenario(dist, station, VEHICLE, streams)
            zero = np.zeros(1)
            scenario = scenario.with_values(
                gradient=station_gradient(station, 1), radio_latency_s=zero, radio_jitter_s=zero,
                radio_loss_probability=zero, radio_bit_error_rate=zero, radio_outage_duration_s=zero,
            )  # fmt: skip
            train, wayside = wired_stop(st, VEHICLE, scenario=scenario, seed=5, run=run)
            ref = run_batch(
                station=station, vehicle=VEHICLE, scenario=scenario, controller=controller, streams=streams,
                track=LINE.track,
            )  # fmt: skip
            assert train.stopped and bool(ref.stopped[0])
            assert train.error_m == float(ref.stop_error_m[0]), (station.name, run)
            assert train.commands == len(wayside.records) == int(ref.commands_sent[0])
            assert train.result()["emergency_brake"] is None and int(ref.emergency_brake[0]) == 0


def test_every_command_record_carries_its_inputs_and_what_went_on_the_air() -> None:
    st = StationTasc.create(0, LINE.stations[0], VEHICLE, "tasc-pwm")
    _, wayside = wired_stop(st, VEHICLE)
    assert wayside.records
    for rec in wayside.records:
        assert rec["st"] == LINE.stations[0].name and rec["tr"] == 2
        for key in OFFICE_COMMAND_FIELDS:
            assert key in rec
        assert decode(bytes.fromhex(rec["air"])).TYPE.startswith("tasc-")


def test_a_silent_wayside_leaves_the_train_to_finish_its_stop_on_its_odometry() -> None:
    """The wayside stops sending in mid-stop (its process died): once no telegram came for
    supervision_timeout_s the onboard unit, which had a command, finishes the stop on its own
    odometry (degraded mode) instead of braking at once; the overrun guard still watches it."""
    st = StationTasc.create(0, LINE.stations[0], VEHICLE, "tasc-pwm")
    full, _ = wired_stop(st, VEHICLE)
    silent_at = 0.5 * float(full.stop_time_s)
    train, _ = wired_stop(st, VEHICLE, silent_after_s=silent_at)
    assert train.stopped and train.rx[RX_DEGRADED] == 1.0
    assert train.result()["emergency_brake"] is None
    assert abs(train.error_m) <= LINE.stations[0].psd_tolerance_m


def test_a_wayside_whose_readings_stop_falls_silent_and_the_train_finishes_its_stop() -> None:
    """The sensors' readings stop reaching the wayside in mid-stop (wiring cut): the wayside does not
    keep repeating its last command as a life sign; after supervision_timeout_s without readings it
    ends the stop and falls silent, and the train finishes the stop on its own (degraded mode)."""
    st = StationTasc.create(0, LINE.stations[0], VEHICLE, "tasc-pwm")
    full, _ = wired_stop(st, VEHICLE)
    cut = 0.5 * float(full.stop_time_s)
    train, wayside = wired_stop(st, VEHICLE, readings_lost_after_s=cut)
    assert wayside.sensors_lost == 1 and wayside.session is None
    assert train.stopped and train.rx[RX_DEGRADED] == 1.0
    assert train.result()["emergency_brake"] is None
    assert abs(train.error_m) <= LINE.stations[0].psd_tolerance_m


def test_a_train_entering_a_zone_whose_wayside_is_dead_is_braked() -> None:
    st = StationTasc.create(1, LINE.stations[1], VEHICLE, "tasc-brake-controller")
    train, wayside = wired_stop(st, VEHICLE, silent_after_s=0.0)
    assert wayside.records == []
    assert train.stopped and train.commands == 0
    assert train.result()["emergency_brake"] == eb_cause_name(EB_TIMEOUT)


def test_a_late_link_still_stops_the_train_within_tolerance() -> None:
    """80 ms on every telegram (the live processes' order of delay): the stop stays within the
    station's tolerance at every station."""
    for i, station in enumerate(LINE.stations):
        train, _ = wired_stop(StationTasc.create(i, station, VEHICLE, "tasc-pwm"), VEHICLE, delay_steps=8)
        assert abs(train.error_m) <= station.psd_tolerance_m, station.name


def test_sensor_frames_round_trip_and_refuse_a_bad_length() -> None:
    readings = [Reading(12.34, 16.5, False, 0, np.nan), Reading(12.35, np.nan, True, 2, 12.347)]
    train, station, stands, back = unpack_readings(pack_readings(7, 3, True, readings))
    assert (train, station, stands) == (7, 3, True)
    assert back[0].t_s == 12.34 and back[1].passed and back[1].detector == 2
    assert np.isnan(back[1].doppler_mps) and back[1].passage_s == 12.347
    with pytest.raises(ValueError):
        unpack_readings(pack_readings(7, 3, True, readings)[:-1])


@pytest.mark.parametrize("loss", [0.0, 1.0])
def test_injected_telegram_loss_drops_frames_before_the_safety_layer(loss: float) -> None:
    """``live trains --tasc-loss``: a frame lost on the air never reaches the train's stop; it is
    counted as injected, not as refused by the safety layer."""
    from railstop.config.disturbances import load_disturbances
    from railstop.link.safety import SafePeers
    from railstop.live.tasc import STATION_BASE, TRAIN_TASC_BASE, LiveTasc

    key = bytes(range(32))
    side = LiveTasc(
        line=LINE, vehicle=VEHICLE, controller="tasc-pwm", stations=("127.0.0.1", 9), master_key=key,
        dist=load_disturbances("nominal"), seed=1, loss=loss,
    )  # fmt: skip
    stop = side.begin(0, 0)
    station = SafePeers(STATION_BASE, key, max_age_s=1.0, peers=lambda p: False)
    for i in range(10):
        side.ingest(station.wrap(b"payload", TRAIN_TASC_BASE, 0.01 * i), 0.01 * i)
    counts = side.counts()
    assert counts["telegrams_lost_injected"] == (10 if loss else 0)
    assert len(stop.inbox) == (0 if loss else 10)
    assert counts["telegrams_refused"] == {}
