"""Ground TASC live (issue 17 item 1): the stations' wayside units and the trains' onboard units as
processes over UDP, running the stop model's own compiled steps.

SPEC §1: wheel detectors and a Doppler radar measure the train; the wayside
TASC unit computes the braking it needs and radios it to the train, whose
onboard unit drives the brakes (the configuration of the operation). One stop
of the stop model is split by place (``model.parts``): each process steps its
own part of the same records, so each runs the stop model's own code.

* **the stations process** (:func:`run_stations`) holds every station's
  wayside unit (:class:`WaysideTasc`). Its sensors' readings arrive from the
  plant as frames (the detectors and the radar are wired to the wayside; the
  frames stand for the wiring), one reading per 10 ms step (the radar's sample
  period); each reading runs the stop model's wayside step
  (``WaysidePart``). A due telegram, quantised as the stop model quantises it,
  is encoded by the codec, wrapped in an EN 50159 category-3 frame and sent to
  the train; the latest telegram is repeated every ``repeat_period_s`` (the
  train's life sign) until the train stands. Every command goes to the office
  with its inputs (SPEC §1 claims 7, 20).
* **the train side**: from the hand-over point to standstill the onboard unit
  (:class:`TascOnboard`, in the trains process) runs, each 10 ms step, the
  telegrams received and the train's sensing through the stop model's
  onboard step (``OnboardPart``: the transponder fixes, the configuration's
  output, the telegram time-out and the overrun guard, the ECU); its brake
  demand drives the stop model's plant (:class:`TascPlant`, in ``live.plant``:
  ``PlantPart``, the actuator's dead time, jerk limit and lag, the motion, the
  wheels and sensors), and the detectors and the radar read the train.
  :class:`TascStop` wires the two in one process in the stop model's order.

Wired without delay on the stop's clock, the three parts give the campaign's
run of the same draw bit for bit (``tests/live/test_live_tasc.py``). Only the clock
and the transport differ from the stop model: the link's delay is the
processes' real one (plus the plant's batching of five readings per 50 ms
step), and its losses are real ones (none on loopback). The train's vehicle
and sensors are one draw of the operation's disturbance set per stop (load,
brake gain and response, wheel, adhesion, detector jitter and misses, radar
noise), as in the line simulation, and its sensors draw from that run's
random streams.

Fail safe (DESIGN rule 10): a stations process that dies stops the telegrams;
the onboard unit's supervision applies the emergency brake after
``supervision_timeout_s`` (SPEC §1; ``onboard.tasc_receiver``), and a train
entering a zone whose wayside is silent gets the same once it is past the
detector by which the wayside must have spoken.
"""

from __future__ import annotations

import asyncio
import math
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from railstop.config import default_line, default_vehicle
from railstop.config.disturbances import DisturbanceSet, draw_track_stop, track_stop_run
from railstop.config.doors import DoorsConfig, load_doors
from railstop.config.scenario import Scenario
from railstop.config.schema import SIM_STEP_S, Line, Station, Vehicle
from railstop.control.line_ato import handover_m
from railstop.control.supervision import EbCause, eb_cause_name
from railstop.link.codec import TelegramError, decode, encode
from railstop.link.safety import SafePeers, frame_ids, sum_counts
from railstop.link.tasc_link import command_records, from_message, office_command, telegram_of, to_message
from railstop.link.udp import Address, open_endpoint
from railstop.live.clock import TimeBase, WallClock
from railstop.live.doors import MAX_TRAINS, SENSORS_ID, Platforms
from railstop.live.office import OfficeClient
from railstop.messages import TEL_FIELDS
from railstop.model.build import KernelModel
from railstop.model.parts import OnboardPart, PlantPart, WaysidePart
from railstop.model.records import (
    KP_REPEAT,
    KP_STOP,
)
from railstop.onboard.tasc_receiver import (
    RX_EB,
    RX_EB_T,
)
from railstop.quantities import kmh_to_mps
from railstop.wayside.tasc_unit import WP_FORM, SignalForm

FloatArray = NDArray[np.float64]

STATION_BASE = 0x0100  # station i's wayside TASC unit: STATION_BASE + i (as tasc_link's WAYSIDE_ID)
TRAIN_TASC_BASE = 0x4000  # train k's onboard TASC unit: TRAIN_TASC_BASE + k
#: The stop model's step (the radar's sample period, SPEC §1: 10 ms).
TASC_DT_S = SIM_STEP_S
#: A train's radio announces itself to the station of its stop this often (association).
HELLO_PERIOD_S = 0.25
#: One reading on the sensor wire: time, radar speed (NaN: none), detector passed, detector index,
#: passage time. A frame carries the train, the station, whether the train stands, the readings.
_READING = struct.Struct(">d d B b d")
_SENSOR_HEAD = struct.Struct(">H H B B")


@dataclass(frozen=True, slots=True)
class Reading:
    """What the station's sensors read at ``t_s``: the radar's speed (NaN: out of range / none)
    and a detector's passage found in the step before (``passed``, ``detector``, ``passage_s``)."""

    t_s: float
    doppler_mps: float
    passed: bool
    detector: int
    passage_s: float


def pack_readings(train: int, station: int, stands: bool, readings: list[Reading]) -> bytes:
    out = [_SENSOR_HEAD.pack(train, station, int(stands), len(readings))]
    out += [_READING.pack(r.t_s, r.doppler_mps, int(r.passed), r.detector, r.passage_s) for r in readings]
    return b"".join(out)


def unpack_readings(payload: bytes) -> tuple[int, int, bool, list[Reading]]:
    """(train, station, stands, readings); ValueError for a payload of the wrong shape."""
    if len(payload) < _SENSOR_HEAD.size:
        raise ValueError("short sensor frame")
    train, station, stands, n = _SENSOR_HEAD.unpack_from(payload)
    if len(payload) != _SENSOR_HEAD.size + n * _READING.size:
        raise ValueError("sensor frame length does not match its count")
    readings = []
    for j in range(n):
        t, dop, passed, det, pass_s = _READING.unpack_from(payload, _SENSOR_HEAD.size + j * _READING.size)
        readings.append(Reading(t, dop, bool(passed), det, pass_s))
    return train, station, bool(stands), readings


@dataclass(frozen=True, slots=True)
class StationTasc:
    """A station's stop model for one onboard configuration: the kernel's arrays (both ends build
    the same from the line, vehicle and controller) and the station's gradient."""

    index: int
    station: Station
    model: KernelModel
    # The station's nominal draw: the parameters of the wayside's and the onboard unit's records
    # (neither computes with the draw; the plant's records take each stop's own draw).
    nominal: Scenario

    @classmethod
    def create(cls, index: int, station: Station, vehicle: Vehicle, controller: str) -> StationTasc:
        model = KernelModel.create(
            station=station,
            vehicle=vehicle,
            controller=controller,
            form=None,
            dt_s=TASC_DT_S,
            max_time_s=300.0,
        )
        return cls(index=index, station=station, model=model, nominal=Scenario.nominal(station, vehicle))

    @property
    def first_detector_m(self) -> float:
        return float(self.model.det_pos[0])


def station_models(line: Line, vehicle: Vehicle, controller: str) -> list[StationTasc]:
    """Every station's stop model (the line's order). ValueError: a station's radar does not sample
    at the stop model's step."""
    return [StationTasc.create(i, st, vehicle, controller) for i, st in enumerate(line.stations)]


# ---------------------------------------------------------------------- the wayside


@dataclass
class _Session:
    train: int
    part: WaysidePart  # the stop model's wayside unit, on its records
    readings: int = 0
    payload: bytes | None = None
    last_sent_s: float = -math.inf
    last_reading_s: float = -math.inf
    commands: int = 0


class WaysideTasc:
    """The wayside TASC unit of one station (SPEC §1), serving the train in its zone: readings in,
    telegram payloads out (``due``), each command's record for the office (``records``). Each
    reading runs the stop model's own wayside step (``model.parts.WaysidePart``)."""

    def __init__(self, st: StationTasc) -> None:
        self.st = st
        self.session: _Session | None = None
        self.due: list[tuple[int, bytes]] = []  # (train, payload) to send now
        self.records: list[dict[str, Any]] = []
        self.stops_served = 0
        self.sensors_lost = 0  # stops ended because their readings stopped

    def _begin(self, train: int) -> _Session:
        return _Session(train=train, part=WaysidePart(self.st.model, self.st.nominal))

    def read(self, train: int, stands: bool, readings: list[Reading]) -> None:
        """The sensors' readings of ``train`` (in time order); a train that stands ends the stop."""
        s = self.session
        if s is None or s.train != train:
            s = self.session = self._begin(train)  # a new train in the zone: a new stop
        form = int(self.st.model.wp[WP_FORM])
        for r in readings:
            if r.t_s <= s.last_reading_s:
                continue  # a reading it already has (a frame sent twice)
            s.last_reading_s = r.t_s
            due = s.part.command(s.readings, r.t_s, r.doppler_mps, r.passed, r.detector, r.passage_s)
            s.readings += 1
            if not due:
                continue
            pending = s.part.pending
            row = telegram_of(pending, SignalForm(form))
            try:
                s.payload = encode(to_message(row, 0, train_id=train))
            except TelegramError:
                continue  # a value the telegram cannot carry: nothing is sent (the train's supervision)
            s.commands += 1
            self.records.append(
                office_record(self.st.station.name, train, s.part.crow, pending, form, s.payload)
            )
            self.due.append((train, s.payload))
            s.last_sent_s = r.t_s
        if stands:
            self.session = None
            self.stops_served += 1

    def repeat(self, now_s: float) -> None:
        """The cyclic repeat of the latest telegram (the train's life sign), until the train stands.

        Fail safe (DESIGN rule 10) [interpretation]: a repeat vouches for a train the unit still
        measures. Once its readings have stopped for ``supervision_timeout_s`` (the sensors' wiring
        cut, or the train gone without saying it stands), it ends the stop and falls silent, so the
        train's own supervision brakes it instead of trusting an old command."""
        s = self.session
        if s is None:
            return
        if now_s - s.last_reading_s > self.st.station.tasc.supervision_timeout_s:
            self.session = None
            self.sensors_lost += 1
            return
        if s.payload is None:
            return
        if now_s - s.last_sent_s >= float(self.st.model.kp[KP_REPEAT]) - 1e-9:
            self.due.append((s.train, s.payload))
            s.last_sent_s = now_s


def office_record(
    station: str, train: int, crow: FloatArray, pending: FloatArray, form: int, payload: bytes
) -> dict[str, Any]:
    """A command as the office stores it (``link.tasc_link.office_command``, the simulators' too), with
    the telegram as it went on the air (``payload``)."""
    rec = command_records(np.append(crow, 0.0)[None, :], SignalForm(form), pending[None, :])[0]
    rec["air"] = payload.hex()
    return office_command(station, train, rec)


async def run_stations(
    *,
    line: Line,
    vehicle: Vehicle,
    controller: str,
    local: Address,
    base: TimeBase,
    master_key: bytes,
    stop: asyncio.Event,
    office: OfficeClient | None = None,
    on_ready: Callable[[Address], None] | None = None,
    doors: DoorsConfig | None = None,
    jams: tuple[tuple[int, int], ...] = (),
) -> dict[str, Any]:
    """Every station's wayside units, serving the trains until ``stop``: the TASC unit and the WPCS
    of its platform (``live.doors``, with the door data ``doors``: default the embedded; ``jams``:
    fault injection, (station, PSD unit from 0) that fail to close); return the counts."""
    # Nothing sent before this process started is delivered (EN 50159 repetition across a restart).
    started_s = base.now_s()
    platforms = Platforms(
        line=line, doors=doors or load_doors(), master_key=master_key, jams=jams, started_s=started_s
    )
    models = station_models(line, vehicle, controller)
    wired_stop(models[0], vehicle)  # the compiled steps loaded before the clock starts
    stations = [WaysideTasc(st) for st in models]
    links = {
        w.st.index: SafePeers(
            STATION_BASE + w.st.index,
            master_key,
            max_age_s=line.stations[w.st.index].tasc.max_telegram_age_s,
            # The plant's readings, and the trains' radios announcing themselves (association).
            peers=lambda p: p == SENSORS_ID or TRAIN_TASC_BASE <= p < TRAIN_TASC_BASE + 0x400,
            started_s=started_s,
        )
        for w in stations
    }
    refused: dict[str, int] = {}
    ages: list[float] = []  # each reading frame's age on delivery
    trains_at: dict[int, Address] = {}  # where each train's radio announced itself (telegrams go there)
    door_at: dict[int, Address] = {}  # where each train's door commands come from (statuses go there)
    commands = 0
    clock = WallClock([], step_s=TASC_DT_S, base=base)
    async with await open_endpoint(local) as ep:
        if on_ready is not None:
            on_ready(ep.local_address)

        def poll(now_s: float) -> list[Any]:
            while (got := ep.take()) is not None:
                frame, addr = got
                to = (frame_ids(frame) or (-1, -1))[1]
                if platforms.owns(to):
                    # The platform's WPCS (or the WCC, whose link keeps Unix time).
                    train = platforms.ingest(frame, to, now_s, time.time())
                    if train is not None:
                        door_at[train] = addr
                    continue
                dst = to - STATION_BASE
                if dst not in links:
                    refused["wrong_destination"] = refused.get("wrong_destination", 0) + 1
                    continue
                accepted = links[dst].accept(frame, now_s)
                if accepted is None:
                    continue
                if accepted[0] != SENSORS_ID:
                    # A train's radio associating with the station's (SPEC §1: the wayside radios
                    # the train; [interpretation] its radio must be known to be reached).
                    trains_at[accepted[0] - TRAIN_TASC_BASE] = addr
                    continue
                ages.append(now_s - accepted[1].sent_s)
                try:
                    train, station, stands, readings = unpack_readings(accepted[1].payload)
                except ValueError:
                    refused["bad_readings"] = refused.get("bad_readings", 0) + 1
                    continue
                if station != dst:
                    refused["wrong_station"] = refused.get("wrong_station", 0) + 1
                    continue
                stations[dst].read(train, stands, readings)
            return []

        def plant(now_s: float, step_s: float) -> list[Any]:
            nonlocal commands
            for train, frame in platforms.tick(now_s):
                addr = door_at.get(train)
                if addr is not None:
                    ep.send(frame, addr)
            events = platforms.take_events()
            if office is not None:
                for event in events:
                    office.report("dwell-event", event)
            for w in stations:
                w.repeat(now_s)
                for train, payload in w.due:
                    addr = trains_at.get(train)
                    if addr is not None:
                        ep.send(links[w.st.index].wrap(payload, TRAIN_TASC_BASE + train, now_s), addr)
                w.due.clear()
                commands += len(w.records)
                if office is not None:
                    for rec in w.records:
                        office.report("tasc-command", rec)
                w.records.clear()
            return []

        await clock.run_live(plant, poll, stop)
    sum_counts((lk.rejected for lk in links.values()), into=refused)
    return {
        "stops_served": sum(w.stops_served for w in stations),
        "stops_ended_readings_lost": sum(w.sensors_lost for w in stations),
        "platforms": platforms.counts(),
        "commands": commands,
        "frames_sent": sum(lk.sent for lk in links.values()),
        "readings_frames": sum(lk.delivered for lk in links.values()),
        "delivered": sum(lk.delivered for lk in links.values()) + platforms.delivered(),
        "readings_age_ms": age_summary(ages),
        "refused": refused,
        **clock.timing(),
    }


# ---------------------------------------------------------------------- the train


@dataclass(frozen=True, slots=True)
class Sense:
    """What the train's own sensors tell its onboard TASC unit before step ``k`` (the plant's side
    of the train's wiring): the tachometer's speed, the odometer's last step, the transponder its
    antenna passed in the step before (NaN: none), whether the train stands, and whether its
    wheel-slide protection acts (the tachometer then reads the sliding wheel)."""

    k: int
    tach_mps: float
    odo_step_m: float
    transponder_m: float
    stopped: bool
    wsp: bool


@dataclass(frozen=True, slots=True)
class BrakeDrive:
    """The onboard unit's output for step ``k`` to the train's brakes and traction: the service
    brake demand (through the ECU), whether traction lets go of the approach speed (``braking``),
    and the emergency brake (wire e)."""

    k: int
    demand_mps2: float
    braking: bool
    eb: bool


@dataclass
class TascOnboard:
    """A train's onboard TASC unit during one stop (SPEC §1): the telegrams received and the
    train's own sensors (:class:`Sense`) in, the stop model's onboard step (``model.parts``
    ``OnboardPart``: the transponder fixes, the configuration's output, the telegram time-out and
    the overrun guard, the ECU) per 10 ms step, the brake demand out (:class:`BrakeDrive`)."""

    st: StationTasc
    train: int
    inbox: list[bytes] = field(default_factory=list)  # telegram payloads received, oldest first
    eb: bool = False
    commands: int = 0
    refused: int = 0
    extra_eb: bool = False  # another unit (the CBTC) applied the emergency brake

    def __post_init__(self) -> None:
        self.part = OnboardPart(self.st.model, self.st.nominal)
        self.last_payload: bytes | None = None

    @property
    def rx(self) -> FloatArray:
        """The receiver's state (``RX_*``)."""
        rx: FloatArray = self.part.rx
        return rx

    def deliver(self, payload: bytes) -> None:
        self.inbox.append(payload)

    def cycle(self, t_s: float, sense: Sense, extra_eb: bool = False) -> BrakeDrive:
        """One 10 ms step at ``t_s``. ``extra_eb``: another unit (CBTC) applies the emergency brake
        (held to the stand, as the CBTC unit holds its own)."""
        if extra_eb and not self.extra_eb:
            self.extra_eb = True
            self.part.records.emergency_brake(t_s)
        new = copy = False
        pending = self.part.pending
        for payload in self.inbox:
            if payload == self.last_payload:
                # A cyclic repeat of the telegram it has: a life sign. [interpretation] The codec
                # telegram carries no command number; a new command equal to the last one on the
                # wire tells the unit nothing new, so it is taken as a repeat too (a form-8 step
                # carries its step's number, so no two steps are equal on the wire).
                copy = True
                continue
            try:
                row = from_message(decode(payload), self.st.model.form)
            except TelegramError:
                self.refused += 1
                continue
            for j, name in enumerate(TEL_FIELDS):
                pending[j] = float(getattr(row, name)[0])
            self.last_payload, new = payload, True
            self.commands += 1
        self.inbox.clear()
        demand, braking, eb = self.part.cycle(
            sense.k, t_s, sense.tach_mps, sense.odo_step_m, sense.transponder_m, sense.stopped, sense.wsp,
            new, copy and not new,
        )  # fmt: skip
        self.eb = eb
        return BrakeDrive(sense.k, demand, braking, eb)

    def eb_cause(self) -> str | None:
        """The onboard unit's own emergency brake's cause (None: it applied none)."""
        return eb_cause_name(int(self.rx[RX_EB])) if self.rx[RX_EB] > 0.0 else None


class TascPlant:
    """A train under ground TASC as the plant moves it: the stop model's plant
    (``model.parts.PlantPart``: the actuator's dead time, jerk limit and lag, the motion with
    adhesion, resistance and gradient, the wheels, tachometer and transponders) from the stop's
    draw (``scenario``, run ``run`` of ``seed``: its random streams), and the station's sensors
    reading it (the readings queued in ``out``), one :meth:`step` per 10 ms with the onboard unit's
    :class:`BrakeDrive`."""

    def __init__(
        self, *, st: StationTasc, train: int, scenario: Scenario, seed: int, run: int, x_m: float, t0_s: float
    ) -> None:
        self.st, self.train, self.t0_s = st, train, t0_s
        self.part = PlantPart(st.model, scenario, seed=seed, run=run, start_m=x_m)
        self.out: list[Reading] = []
        self.k = 0
        self.stopped = False

    @property
    def x_m(self) -> float:
        return float(self.part.records.train["position_m"])

    @property
    def v_mps(self) -> float:
        return float(self.part.records.train["speed_mps"])

    @property
    def max_jerk(self) -> float:
        return self.part.max_jerk_mps3

    @property
    def stop_time_s(self) -> float:
        return float(self.part.records.train["stop_time_s"])

    def sense(self) -> Sense:
        """What the train's sensors tell its onboard unit before the next step."""
        tach, odo, transponder, stands, wsp = self.part.sense()
        return Sense(self.k, tach, odo, transponder, stands, wsp)

    def step(self, t_s: float, drive: BrakeDrive) -> None:
        """One 10 ms step at ``t_s`` under ``drive``: the station's sensors read the train (queued in
        ``out``), then the brakes, the motion and the train's sensors."""
        stands, doppler, passed, det, pass_s = self.part.step(self.k, t_s, drive.demand_mps2, drive.braking)
        self.out.append(Reading(t_s, doppler, passed, det, pass_s))
        self.stopped = stands
        self.k += 1

    @property
    def error_m(self) -> float:
        return self.x_m - float(self.st.model.kp[KP_STOP])

    def result(self, eb_cause: str | None, eb_t_s: float, extra_eb: bool) -> dict[str, Any]:
        """The stop as the office stores it, with the onboard unit's emergency brake (its cause and
        time on the run's clock; ``extra_eb``: another unit applied it)."""
        return stop_result(
            self.st, self.train, self.error_m, self.stopped, self.max_jerk, self.stop_time_s - self.t0_s,
            eb_cause, eb_t_s, extra_eb,
        )  # fmt: skip


def stop_result(
    st: StationTasc,
    train: int,
    error_m: float,
    stopped: bool,
    jerk_mps3: float,
    stop_time_s: float,
    eb_cause: str | None,
    eb_t_s: float,
    extra_eb: bool,
) -> dict[str, Any]:
    """A TASC stop as the office stores it: the plant's side (error, jerk, the stop's time from its
    start) and the onboard unit's (its emergency brake's cause and time; ``extra_eb``: another
    unit, the CBTC, applied it)."""
    station = st.station
    return {
        "station": station.name,
        "train": train,
        "controller": st.model.controller,
        "error_m": round(error_m, 3),
        "within": abs(error_m) <= station.psd_tolerance_m and stopped,
        "emergency_brake": eb_cause if eb_cause is not None else (EbCause.CBTC.label if extra_eb else None),
        # when the onboard unit applied it (on the run's clock)
        "eb_t_s": round(eb_t_s, 2) if eb_cause is not None else None,
        "jerk_mps3": round(jerk_mps3, 2),
        "stop_time_s": round(stop_time_s, 2) if math.isfinite(stop_time_s) else None,
    }


class TascStop:
    """A train's stop under ground TASC (SPEC §1) from the hand-over point to standstill with its
    onboard unit and the plant in one process: each 10 ms ``step`` the plant's sensing runs the
    onboard unit's cycle, whose drive steps the plant in the same step (the stop model's order)."""

    def __init__(
        self, *, st: StationTasc, train: int, scenario: Scenario, seed: int, run: int, x_m: float, t0_s: float
    ) -> None:
        self.st, self.train = st, train
        self.onboard = TascOnboard(st=st, train=train)
        self.plant = TascPlant(st=st, train=train, scenario=scenario, seed=seed, run=run, x_m=x_m, t0_s=t0_s)

    def deliver(self, payload: bytes) -> None:
        self.onboard.deliver(payload)

    def step(self, t_s: float, extra_eb: bool = False) -> None:
        self.plant.step(t_s, self.onboard.cycle(t_s, self.plant.sense(), extra_eb))

    x_m = property(lambda self: self.plant.x_m)
    v_mps = property(lambda self: self.plant.v_mps)
    stopped = property(lambda self: self.plant.stopped)
    out = property(lambda self: self.plant.out)
    error_m = property(lambda self: self.plant.error_m)
    stop_time_s = property(lambda self: self.plant.stop_time_s)
    commands = property(lambda self: self.onboard.commands)
    rx = property(lambda self: self.onboard.rx)
    inbox = property(lambda self: self.onboard.inbox)
    eb = property(lambda self: self.onboard.eb)

    def result(self) -> dict[str, Any]:
        """The stop as the office stores it."""
        cause = self.onboard.eb_cause()
        return self.plant.result(cause, float(self.onboard.rx[RX_EB_T]), self.onboard.extra_eb)


def draw_stop(
    dist: DisturbanceSet,
    st: StationTasc,
    vehicle: Vehicle,
    *,
    seed: int,
    train: int,
    visit: int,
    speed_mps: float,
) -> tuple[Scenario, int]:
    """The train's vehicle and sensors for one stop: a draw of the disturbance set (the line
    simulation's run numbering: train x 100 + visit, whose random streams its sensors draw from
    too), the station's own gradients and the train's speed at the hand-over: (draw, run)."""
    run = track_stop_run(train, visit)
    return draw_track_stop(dist, st.station, vehicle, seed=seed, run=run, entry_speed_mps=speed_mps), run


def wired_stop(
    st: StationTasc,
    vehicle: Vehicle,
    *,
    delay_steps: int = 0,
    silent_after_s: float = math.inf,
    readings_lost_after_s: float = math.inf,
    until_s: float = 300.0,
    scenario: Scenario | None = None,
    seed: int = 0,
    run: int = 0,
) -> tuple[TascStop, WaysideTasc]:
    """One stop (default the nominal draw: the station's entry speed; else run ``run`` of ``seed``
    with its draw ``scenario``), from its hand-over point, with the wayside and the train wired
    directly in this process on the stop's own clock (step k at k x 10 ms): every telegram arrives
    ``delay_steps`` steps after it was sent, none after ``silent_after_s`` (the wayside died); no
    reading reaches the wayside after ``readings_lost_after_s`` (the sensors' wiring cut). The
    live units' check against the stop model, and their warm-up (the compiled steps loaded before
    a live clock starts)."""
    draw = scenario if scenario is not None else Scenario.nominal(st.station, vehicle)
    v = float(draw.entry_speed_mps[0])
    x = handover_m(st.first_detector_m, v)
    wayside = WaysideTasc(st)
    train = TascStop(st=st, train=2, scenario=draw, seed=seed, run=run, x_m=x, t0_s=0.0)
    air: list[tuple[float, bytes]] = []
    k = 0
    t = 0.0
    while not train.stopped and t < until_s:
        train.step(t)
        if t < silent_after_s:
            if t < readings_lost_after_s:
                wayside.read(train.train, train.stopped, train.out)
            wayside.repeat(t)
            air += [(t + delay_steps * TASC_DT_S, p) for _, p in wayside.due]
        train.out.clear()
        wayside.due.clear()
        for _, payload in [a for a in air if a[0] <= t + 1e-9]:
            train.deliver(payload)
        air = [a for a in air if a[0] > t + 1e-9]
        k += 1
        t = k * TASC_DT_S  # the stop model's clock, to the bit
    return train, wayside


def warm_up() -> None:
    """Load (or compile into the cache) the live units' compiled steps: one wired stop on the
    embedded line (``railstop compile`` runs it, so that a live process starts on time)."""
    line, vehicle = default_line(), default_vehicle()
    wired_stop(StationTasc.create(0, line.stations[0], vehicle, "tasc-pwm"), vehicle)


# ---------------------------------------------------------------------- the trains process's side


class LiveTasc:
    """The trains process's side of ground TASC: every station's stop model, the telegrams from
    the stations process (category 3) and each stop's onboard unit. A train is handed over at the
    station's hand-over point (:meth:`begin`); its unit's cycle answers the plant's sensing
    (:meth:`cycle`) until the plant says it stands (:meth:`end`)."""

    def __init__(
        self,
        *,
        line: Line,
        vehicle: Vehicle,
        controller: str,
        stations: Address,
        master_key: bytes,
        dist: DisturbanceSet,
        seed: int,
        loss: float = 0.0,
        trains: int = MAX_TRAINS,
        started_s: float | None = None,
    ) -> None:
        """``loss``: fault injection, each braking telegram frame is lost with this probability
        (drawn from the seed; the link on loopback loses none). ``trains``: the trains of this
        process (0 .. trains - 1): a frame for any other is refused before any link state exists.
        ``started_s``: when this process started on the run's clock; telegrams sent before it are
        refused (``old_session``)."""
        if not 0.0 <= loss <= 1.0:
            raise ValueError(f"--tasc-loss: a probability in [0, 1] (got {loss})")
        if not 1 <= trains <= MAX_TRAINS:
            raise ValueError(f"trains: 1..{MAX_TRAINS} (got {trains})")
        self.trains = trains
        self.started_s = started_s
        self.not_mine = 0  # frames for a train that is not one of this process's (refused)
        self.loss = loss
        self._loss_rng = np.random.default_rng([seed, 0x7A5C])
        self.injected_losses = 0
        self.models = station_models(line, vehicle, controller)
        wired_stop(self.models[0], vehicle)  # the compiled steps loaded before the clock starts
        self.address = stations
        self.master_key = master_key
        self.dist = dist
        self.seed = seed
        n = len(self.models)
        self._rx: dict[int, SafePeers] = {}
        self._is_station = lambda p: STATION_BASE <= p < STATION_BASE + n
        self.active: dict[int, TascOnboard] = {}
        self._hello_s: dict[int, float] = {}
        self.unexpected = 0  # telegrams for a train not stopping at that station
        self.results: list[dict[str, Any]] = []  # every stop, as reported
        self.ages: list[float] = []  # each telegram's age on delivery (s, the run's clock)

    def accepts(self, frame: bytes) -> bool:
        """Whether ``frame`` comes from a station (for :meth:`ingest`)."""
        ids = frame_ids(frame)
        return ids is not None and self._is_station(ids[0])

    def _links(self, train: int) -> SafePeers:
        """Train ``train``'s link (one of this process's trains: the caller checked)."""
        if train not in self._rx:
            self._rx[train] = SafePeers(
                TRAIN_TASC_BASE + train,
                self.master_key,
                max_age_s=max(m.station.tasc.max_telegram_age_s for m in self.models),
                peers=self._is_station,
                started_s=self.started_s,
            )
        return self._rx[train]

    def ingest(self, frame: bytes, now_s: float) -> None:
        """A telegram from a station: checked, and handed to the train's stop at that station."""
        ids = frame_ids(frame)
        if ids is None:
            return
        if self.loss > 0.0 and self._loss_rng.uniform() < self.loss:
            self.injected_losses += 1  # lost on the air (fault injection)
            return
        train = ids[1] - TRAIN_TASC_BASE
        if not 0 <= train < self.trains:
            # A destination that is no train of this process: refused before any link is made
            # for it (a forged header must not make the process hold state; DESIGN rule 9).
            self.not_mine += 1
            return
        got = self._links(train).accept(frame, now_s)
        if got is None:
            return
        self.ages.append(now_s - got[1].sent_s)
        stop = self.active.get(train)
        if stop is None or stop.st.index != got[0] - STATION_BASE:
            self.unexpected += 1
            return
        stop.deliver(got[1].payload)

    def handover_m(self, station: int, speed_mps: float) -> float:
        return handover_m(self.models[station].first_detector_m, speed_mps)

    def entry_mps(self, station: int) -> float:
        return kmh_to_mps(float(self.models[station].station.tasc.entry_speed_kmh))

    def begin(self, train: int, station: int) -> TascOnboard:
        """The train's onboard unit takes over its stop at ``station`` (the plant hands the train
        over at the same time)."""
        onboard = TascOnboard(st=self.models[station], train=train)
        self.active[train] = onboard
        return onboard

    def cycle(self, train: int, t_s: float, sense: Sense, extra_eb: bool) -> BrakeDrive | None:
        """The onboard unit's 10 ms cycle on the train's sensing (None: no stop in progress)."""
        onboard = self.active.get(train)
        return None if onboard is None else onboard.cycle(t_s, sense, extra_eb)

    def end(self, train: int) -> TascOnboard | None:
        self._hello_s.pop(train, None)
        return self.active.pop(train, None)

    def hello(self, now_s: float) -> list[bytes]:
        """The association frames due: each train under a stop announces its radio to the station
        every ``HELLO_PERIOD_S`` (so a station, or one started again, knows where to radio it)."""
        out = []
        for train, onboard in self.active.items():
            if now_s >= self._hello_s.get(train, -math.inf) + HELLO_PERIOD_S:
                self._hello_s[train] = now_s
                out.append(self._links(train).wrap(b"", STATION_BASE + onboard.st.index, now_s))
        return out

    def counts(self) -> dict[str, Any]:
        refused = sum_counts(lk.rejected for lk in self._rx.values())
        if self.not_mine:
            refused["not_a_train_here"] = refused.get("not_a_train_here", 0) + self.not_mine
        return {
            "telegrams_delivered": sum(lk.delivered for lk in self._rx.values()),
            "telegrams_refused": refused,
            "telegrams_unexpected": self.unexpected,
            "telegrams_lost_injected": self.injected_losses,
            "telegram_age_ms": age_summary(self.ages),
            **stop_summary(self.results),
        }


def age_summary(ages: list[float]) -> dict[str, float] | None:
    """How old frames were when delivered (ms on the run's clock): median, p99, max."""
    if not ages:
        return None
    a = np.array(ages) * 1000.0
    return {
        "p50": round(float(np.median(a)), 1),
        "p99": round(float(np.percentile(a, 99)), 1),
        "max": round(float(a.max()), 1),
    }


def stop_summary(results: list[dict[str, Any]]) -> dict[str, Any]:
    """The stops' figures: how many, within tolerance, |error| p99 and max, emergency brakes."""
    errors = np.array([abs(r["error_m"]) for r in results])
    ebs: dict[str, int] = {}
    for r in results:
        if r["emergency_brake"] is not None:
            ebs[r["emergency_brake"]] = ebs.get(r["emergency_brake"], 0) + 1
    return {
        "stops": len(results),
        "within_tolerance": sum(bool(r["within"]) for r in results),
        "abs_error_p99_m": round(float(np.percentile(errors, 99)), 3) if errors.size else None,
        "abs_error_max_m": round(float(errors.max()), 3) if errors.size else None,
        "emergency_brakes": ebs,
    }
