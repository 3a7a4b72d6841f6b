"""The plant as a unit of its own (issue 17 item 1, ``live.plant``): in lock step with the onboard
TASC unit it stops a train where the stop kernel does; its wire carries drives and states
unchanged; it fails safe when the trains' onboard units fall silent, and the trains process does
when the plant does (over real sockets on loopback)."""

from __future__ import annotations

import asyncio
import math

import pytest

from railstop.config import default_line, default_vehicle
from railstop.config.disturbances import load_disturbances
from railstop.control.line_ato import handover_m
from railstop.live.clock import TimeBase
from railstop.live.doors import PLATFORM_BASE
from railstop.live.plant import (
    DRIVE_TIMEOUT_S,
    HOLD,
    HOLD_BAND_MPS,
    PLANT_STEP_S,
    SENSE_TIMEOUT_S,
    Drive,
    DriveRecord,
    Place,
    Plant,
    PlantPort,
    TascPlantData,
    TrainState,
    emergency_drive,
    pack_drives,
    pack_states,
    run_plant,
    unpack_drives,
    unpack_states,
)
from railstop.live.tasc import STATION_BASE, BrakeDrive, Sense, TascOnboard, WaysideTasc, unpack_readings
from railstop.sim.single import run_stop

LINE = default_line()
VEHICLE = default_vehicle()
KEY = bytes(range(32))


def _plant(trains: int = 1, *, sensor_every: int = 5) -> Plant:
    tasc = TascPlantData("tasc-pwm", load_disturbances("nominal"), 1)
    return Plant(
        line=LINE, vehicle=VEHICLE, trains=trains, spacing_m=600.0, master_key=KEY, tasc=tasc,
        sensor_every=sensor_every,
    )  # fmt: skip


@pytest.mark.parametrize("station", range(len(LINE.stations)))
def test_the_plant_in_lock_step_with_the_onboard_unit_stops_where_the_kernel_stops(station: int) -> None:
    """The train handed over at the station's hand-over point at its entry speed (nominal draw);
    the plant's readings go to the wayside and the telegrams to the onboard unit at once: the stop
    error is the kernel's, and so is the count of commands."""
    plant = _plant(sensor_every=1)
    st = plant.models[station]
    v0 = LINE.stations[station].tasc.entry_speed_kmh / 3.6
    car = plant.fleet[0]
    # One step before the hand-over point: the stop begins at the end of the next step.
    car.x_m, car.v_mps = handover_m(st.first_detector_m, v0) - v0 * PLANT_STEP_S, v0
    plant.drive(0, Drive(v0, 0.0, 0.0))
    onboard = TascOnboard(st=st, train=0)
    wayside = WaysideTasc(st)
    plant.begin_tasc(0, station, 0)
    ended = None
    t = 0.0
    for _ in range(30_000):
        plant.step(t, lambda _k, t_s, sense: onboard.cycle(t_s, sense))
        for peer, payload in plant.outgoing:
            # The station's sensor frames go to its wayside; a platform's stop sensors (read every
            # 50 ms once the TASC stop has ended, in the step it ends) are not the wayside's.
            if peer != STATION_BASE + station:
                assert peer == PLATFORM_BASE + station
                continue
            train, _, stands, readings = unpack_readings(payload)
            wayside.read(train, stands, readings)
        plant.outgoing.clear()
        wayside.repeat(t)
        for _, payload in wayside.due:
            onboard.deliver(payload)
        wayside.due.clear()
        ended = next((s for s in plant.states(t) if s.ended), None)
        if ended is not None:
            break
        t = round(t + PLANT_STEP_S, 9)
    assert ended is not None
    ref, _ = run_stop(
        line=LINE, station=LINE.stations[station], vehicle=VEHICLE, controller="tasc-pwm", seed=1
    )
    error = ended.x_m - LINE.stations[station].stop_point_m
    assert error == pytest.approx(ref.stop_error_m, abs=2e-6)
    assert onboard.commands == ref.commands
    assert onboard.eb_cause() is None
    assert plant.late_drives == 0


def test_drives_and_states_cross_the_wire_unchanged() -> None:
    drives: list[DriveRecord] = [
        (0, Drive(12.5, 1.0, 1.2)),
        (1, Drive(0.0, 0.0, math.inf, 650.0)),
        (2, (3, 17)),
        (3, BrakeDrive(4711, 0.83, True, False)),
        (4, BrakeDrive(4712, 2.0, True, True)),
        (5, Place(1234.5)),
        (6, emergency_drive(VEHICLE)),
    ] * 5  # more than one frame's records
    payloads = pack_drives(drives)
    assert len(payloads) > 1 and all(len(p) <= 255 for p in payloads)  # the safety layer's limit
    got = [r for p in payloads for r in unpack_drives(p)]
    assert repr(got) == repr(drives)  # NaN (no relocation) compares only by its text
    assert isinstance(got[1][1], Drive) and got[1][1].relocate_m == 650.0
    assert isinstance(got[6][1], Drive) and got[6][1].emergency and not got[0][1].emergency  # type: ignore[union-attr]
    states = [
        TrainState(0, 100.0, 12.0),
        TrainState(1, 200.0, 3.0, Sense(7, 2.9, 0.029, 5510.0, False, True), 1.23),
        TrainState(2, 300.0, 0.0, Sense(8, 0.0, 0.0, math.nan, True, False), 1.24, True, 0.61, 38.4, True),
    ]
    back = [s for p in pack_states(states * 10) for s in unpack_states(p)][:3]
    assert all(len(p) <= 255 for p in pack_states(states * 10))
    assert back[0].x_m == 100.0 and back[0].sense is None and not back[0].ended
    assert back[1].sense == states[1].sense and back[1].sense_t_s == 1.23
    assert back[2].ended and back[2].eb and back[2].jerk_mps3 == 0.61 and back[2].stop_time_s == 38.4
    assert back[2].sense is not None and back[2].sense.stopped and math.isnan(back[2].sense.transponder_m)
    with pytest.raises(ValueError):
        unpack_drives(pack_states(states)[0])  # a state frame is not a drive frame
    flagged = bytearray(pack_drives([(0, Drive(1.0, 1.0, 1.0))])[0])
    flagged[3 + 3 + 3] = 2  # the ATO record's flag (after head, train, kind): neither 0 nor 1
    with pytest.raises(ValueError, match="flag"):
        unpack_drives(bytes(flagged))
    with pytest.raises(ValueError):
        unpack_states(pack_states(states)[0][:-3])


def test_a_fresh_plant_says_so_until_the_trains_are_placed_and_a_place_ends_a_stop() -> None:
    """A plant that has just started does not know where the trains are (``fresh`` in every
    state) until the trains process places them; a train placed stands there, a TASC stop under
    way ended."""
    plant = _plant(trains=2)
    assert all(s.fresh for s in plant.states(0.0))
    st = plant.models[0]
    plant.fleet[1].x_m, plant.fleet[1].v_mps = handover_m(st.first_detector_m, 12.0), 12.0
    plant.drive(1, Drive(12.0, 0.0, 0.0))
    plant.begin_tasc(1, 0, 0)
    plant.step(0.0)
    assert plant.fleet[1].tasc is not None
    plant.place(0, 1000.0)
    plant.place(1, 2000.0)
    plant.step(PLANT_STEP_S)
    states = plant.states(PLANT_STEP_S)
    assert not any(s.fresh for s in states)
    assert [(s.x_m, s.v_mps, s.sense) for s in states] == [(1000.0, 0.0, None), (2000.0, 0.0, None)]


def test_with_the_trains_silent_the_plant_brakes_every_train_at_the_emergency_rate() -> None:
    """DESIGN rule 10: ``eb_all`` (set by the plant process after DRIVE_TIMEOUT_S without a drive)
    stops every train from its speed within the emergency braking distance, a train under TASC
    included (its demand becomes the emergency brake)."""
    plant = _plant(trains=2)
    st = plant.models[1]
    for car in plant.fleet:
        car.v_mps = 15.0
    plant.fleet[1].x_m = handover_m(st.first_detector_m, 15.0)
    plant.drive(0, Drive(15.0, 1.0, 1.0))
    plant.drive(1, Drive(15.0, 0.0, 0.0))  # cruising to the hand-over
    plant.begin_tasc(1, 1, 0)
    plant.step(0.0, lambda _k, t_s, s: BrakeDrive(s.k, 0.0, False, False))  # the stop has begun
    assert plant.fleet[1].tasc is not None and plant.fleet[1].v_mps == 15.0
    start = [car.x_m for car in plant.fleet]
    plant.eb_all = True
    t = PLANT_STEP_S
    for _ in range(2000):
        plant.step(t)  # no drive from anyone
        t += PLANT_STEP_S
    emergency = VEHICLE.brake.emergency_decel_mps2
    for car, x0 in zip(plant.fleet, start, strict=True):
        assert car.v_mps == 0.0
        # Both through their brakes' dead time and lag (the ATO train's plant and the TASC train's).
        assert car.x_m - x0 <= 15.0**2 / (2 * emergency) + 15.0 * 2.0
    assert all(s.eb for s in plant.states(t))


def test_a_tasc_drive_that_has_not_arrived_is_late_and_the_last_one_is_held() -> None:
    plant = _plant()
    st = plant.models[0]
    car = plant.fleet[0]
    car.x_m, car.v_mps = handover_m(st.first_detector_m, 12.0), 12.0
    plant.drive(0, Drive(12.0, 0.0, 0.0))
    plant.begin_tasc(0, 0, 0)
    plant.step(0.0)  # the stop begins at the end of this step
    first = plant.states(0.0)[0].sense
    assert first is not None and first.k == 0
    plant.brake(0, BrakeDrive(0, 0.9, True, False))
    plant.step(PLANT_STEP_S)  # on time
    plant.step(2 * PLANT_STEP_S)  # the drive for step 1 never came
    assert plant.late_drives == 1
    assert car.brake is not None and car.brake.k == 1 and car.brake.demand_mps2 == 0.9


def test_plant_process_over_loopback_moves_a_train_and_fails_safe_both_ways() -> None:
    """The plant's loop and the trains process's port over real sockets: a drive moves the train
    and its state comes back; when the drives stop the plant brakes every train; when the plant
    stops the port says the plant is lost after SENSE_TIMEOUT_S."""

    async def scenario() -> tuple[dict[str, object], list[float], bool, int]:
        base = TimeBase(__import__("time").time(), 1.0)
        plant = _plant(trains=2)
        stop_plant = asyncio.Event()
        ready: asyncio.Future[tuple[str, int]] = asyncio.get_running_loop().create_future()
        task = asyncio.create_task(
            run_plant(
                plant=plant,
                local=("127.0.0.1", 0),
                stations=None,
                base=base,
                master_key=KEY,
                stop=stop_plant,
                on_ready=ready.set_result,
            )
        )
        addr = await ready
        from railstop.link.udp import local_for, open_endpoint

        port = PlantPort(2, address=addr, master_key=KEY)
        stop_port = asyncio.Event()
        async with await open_endpoint(local_for(addr)) as ep:
            port.ep = ep
            port.heard_s = base.now_s()
            serving = asyncio.create_task(port.serve(base, stop_port))
            speeds = []
            for _ in range(20):  # 1 s of drives every 50 ms
                now = base.now_s()
                port.tick(now, 0.05, ep, None)
                port.drive(0, Drive(10.0, 1.0, 1.0))
                port.flush(now)
                await asyncio.sleep(0.05)
            speeds.append(port.states[0].v_mps)
            # No drives: the plant brakes every train, through its brakes' dead time and build-up
            # (some 0.8 s) at the emergency rate: 2 s after the time-out it is slower than it was.
            await asyncio.sleep(DRIVE_TIMEOUT_S + 2.0)
            speeds.append(port.states[0].v_mps)
            eb = port.states[0].eb
            stop_plant.set()
            counts = await task
            await asyncio.sleep(SENSE_TIMEOUT_S + 0.2)
            port.tick(base.now_s(), 0.05, ep, None)
            stop_port.set()
            await serving
        return counts, speeds, eb and port.lost, port.losses

    counts, speeds, failed_safe, losses = asyncio.run(scenario())
    assert speeds[0] > 0.5  # the drive moved it
    assert speeds[1] < speeds[0]  # braking at the emergency rate after the drives stopped
    assert failed_safe and losses == 1
    assert counts["drive_lost"] == 1 and counts["refused"] == {}


def _drive(plant: Plant, drive: Drive, seconds: float, t: float = 0.0) -> float:
    """Step the plant under ``drive`` for ``seconds``; the time after."""
    plant.drive(0, drive)
    for _ in range(round(seconds / PLANT_STEP_S)):
        plant.step(t)
        t += PLANT_STEP_S
    return t


def test_a_drive_moves_the_train_through_the_plant_s_traction_and_brakes() -> None:
    """Outside TASC a drive is a demand on the line's train plant (``physics.plant``): the speed
    controller reaches the target and holds it; a stop brakes through the brakes' dead time and
    build-up, so it runs further than v² / 2a but no further than the response's mean delay μ
    (dead time, half the jerk ramp, the lag) adds at v; a correction backs from a stand; the
    emergency drive takes the emergency path."""
    plant = _plant()
    car = plant.fleet[0]
    car.x_m = 1000.0  # level track
    t = _drive(plant, Drive(10.0, 1.0, 1.0), 30.0)
    assert abs(car.v_mps - 10.0) <= HOLD_BAND_MPS
    held = car.v_mps
    t = _drive(plant, Drive(10.0, 1.0, 1.0), 1.0, t)
    assert car.v_mps == held  # traction holds the speed exactly
    brake = VEHICLE.brake
    x0, v0, a = car.x_m, car.v_mps, brake.full_service_mps2
    t = _drive(plant, HOLD, 30.0, t)
    mean = brake.dead_time_s + 0.5 * a / brake.jerk_limit_mps3 + brake.time_constant_s
    assert car.v_mps == 0.0
    assert v0 * v0 / (2 * a) + v0 * brake.dead_time_s < car.x_m - x0 < v0 * v0 / (2 * a) + v0 * mean
    x0 = car.x_m
    t = _drive(plant, Drive(-0.5, math.inf, math.inf), 5.0, t)
    assert car.v_mps == pytest.approx(-0.5, abs=HOLD_BAND_MPS) and car.x_m < x0 - 1.0
    t = _drive(plant, HOLD, 5.0, t)
    t = _drive(plant, Drive(15.0, 1.0, 1.0), 40.0, t)
    x0, v0, e = car.x_m, car.v_mps, brake.emergency_decel_mps2
    _drive(plant, emergency_drive(VEHICLE), 30.0, t)
    assert car.v_mps == 0.0
    assert (
        v0 * v0 / (2 * e) + v0 * brake.dead_time_s
        < car.x_m - x0
        < v0 * v0 / (2 * e) + v0 * (brake.dead_time_s + brake.time_constant_s)
    )
