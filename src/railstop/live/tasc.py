"""Ground TASC live (issue 17 item 1): the stations' wayside units and the trains' onboard units as
processes over UDP, running the stop model's own compiled steps.

SPEC §1: wheel detectors and a Doppler radar measure the train; the wayside
TASC unit computes the braking it needs and radios it to the train, whose
onboard unit drives the brakes (the configuration of the operation). Here:

* **the stations process** (:func:`run_stations`) holds every station's
  wayside unit (:class:`WaysideTasc`). Its sensors' readings arrive from the
  plant as frames (the detectors and the radar are wired to the wayside; the
  frames stand for the wiring), one reading per 10 ms step (the radar's sample
  period); each reading runs one ``wayside_step_1`` (the stop kernel's wayside
  step). A due telegram is quantised as the kernel quantises it, encoded by
  the codec, wrapped in an EN 50159 category-3 frame and sent to the train;
  the latest telegram is repeated every ``repeat_period_s`` (the train's life
  sign) until the train stands. Every command goes to the office with its
  inputs (SPEC §1 claims 7, 20).
* **the train side**: from the hand-over point to standstill the onboard unit
  (:class:`TascOnboard`, in the trains process) runs, each 10 ms step, the
  telegrams received and the train's sensing through ``receiver_cycle_1``
  (the kernel's onboard step: the configuration's output, the telegram
  time-out and the overrun guard); its brake demand drives the stop model's
  plant (:class:`TascPlant`, in ``live.plant``: the ECU, the actuator's dead
  time, jerk limit and lag, the train's motion, ``actuator_step_1`` and
  ``motion_step_1``), and the detectors and the radar read the train.
  :class:`TascStop` wires the two in one process in the kernel's order.

Only the clock and the transport differ from the stop model: the link's delay
is the processes' real one (plus the plant's batching of five readings per
50 ms step), and its losses are real ones (none on loopback). The train's
vehicle and sensors are one draw of the operation's disturbance set per stop
(load, brake gain and response, wheel, adhesion, detector jitter and misses,
radar noise), as in the line simulation.

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
from railstop.config.disturbances import DisturbanceSet, draw_scenario
from railstop.config.doors import DoorsConfig, load_doors
from railstop.config.scenario import Scenario, station_gradient
from railstop.config.schema import Line, Station, Vehicle
from railstop.control.line_ato import handover_m
from railstop.control.notch import MOD_SIZE
from railstop.control.supervision import EbCause, eb_cause_name
from railstop.control.tasc import HISTORY, SAMPLES, Approach, BrakeCurves
from railstop.link.codec import TelegramError, decode, encode
from railstop.link.safety import SafePeers, frame_ids, sum_counts
from railstop.link.tasc_link import from_message, to_message
from railstop.link.udp import Address, open_endpoint
from railstop.live.clock import TimeBase, WallClock
from railstop.live.doors import MAX_TRAINS, SENSORS_ID, Platforms
from railstop.live.office import OfficeClient
from railstop.messages import TEL_FIELDS, TEL_SIZE
from railstop.model.build import KernelModel, scenario_arrays
from railstop.model.records import (
    KP_CRUSH,
    KP_DAVIS_A,
    KP_DAVIS_B,
    KP_DAVIS_C,
    KP_DOPPLER_RANGE,
    KP_DOPPLER_REACH,
    KP_EMERGENCY,
    KP_HAS_DOPPLER,
    KP_INITIAL_NOTCH,
    KP_JERK,
    KP_LENGTH,
    KP_QUANT_AGE,
    KP_REPEAT,
    KP_ROTATING,
    KP_SLIDE_SLIP,
    KP_STOP,
    KP_TARE,
    SC_BRAKE_GAIN,
    SC_DEAD_TIME,
    SC_DOPPLER_NOISE,
    SC_LOAD,
    SC_LOW_END,
    SC_LOW_MU,
    SC_LOW_START,
    SC_MISS,
    SC_MU,
    SC_ODO_ERROR,
    SC_SENSOR_JITTER,
    SC_TAU,
    SC_WEIGHING_ERROR,
    SC_WHEEL_D,
)
from railstop.model.step import own_command_1, quantize_telegram_1
from railstop.onboard.tasc_receiver import (
    CFG_PWM,
    CFG_SWITCHED_PWM,
    RP_CONFIG,
    RX_EB,
    RX_EB_T,
    RX_FIRST_RX,
    RX_SIZE,
    receiver_cycle_1,
    receiver_fix_1,
    receiver_init_1,
)
from railstop.physics.brake import actuator_step_1, line_notch, pwm_to_decel_1
from railstop.physics.train import creep_1, mean_gradient_1, motion_step_1
from railstop.quantities import kmh_to_mps
from railstop.sensors.wayside import crossing_time_1, passage_1
from railstop.sim.engine import command_records, telegram_of
from railstop.streams import RunStreams
from railstop.wayside.tasc_unit import CR_SIZE, WP_FORM, WS_SIZE, SignalForm, wayside_init_1, wayside_step_1

FloatArray = NDArray[np.float64]

STATION_BASE = 0x0100  # station i's wayside TASC unit: STATION_BASE + i (as tasc_link's WAYSIDE_ID)
TRAIN_TASC_BASE = 0x4000  # train k's onboard TASC unit: TRAIN_TASC_BASE + k
#: The stop model's step (the radar's sample period, SPEC §1: 10 ms).
TASC_DT_S = 0.01
#: A train's radio announces itself to the station of its stop this often (association).
HELLO_PERIOD_S = 0.25
#: Runs of the disturbance draw per train (as the line simulation): run = train x 100 + visit.
RUNS_PER_TRAIN = 100
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
    grad: tuple[FloatArray, FloatArray, FloatArray]

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
        _, bp, gv, ge = scenario_arrays(Scenario.nominal(station, vehicle))
        return cls(index=index, station=station, model=model, grad=(bp, gv[0], ge[0]))

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
    ws: FloatArray
    dbuf: FloatArray
    pass_t: FloatArray
    pass_x: FloatArray
    wh_v: FloatArray
    wh_e: FloatArray
    taus: FloatArray
    weights: FloatArray
    tele: FloatArray
    crow: FloatArray
    pending: FloatArray
    payload: bytes | None = None
    last_sent_s: float = -math.inf
    last_reading_s: float = -math.inf
    commands: int = 0


class WaysideTasc:
    """The wayside TASC unit of one station (SPEC §1), serving the train in its zone: readings in,
    telegram payloads out (``due``), each command's record for the office (``records``)."""

    def __init__(self, st: StationTasc) -> None:
        self.st = st
        self.session: _Session | None = None
        self.due: list[tuple[int, bytes]] = []  # (train, payload) to send now
        self.records: list[dict[str, Any]] = []
        self.stops_served = 0
        self.sensors_lost = 0  # stops ended because their readings stopped

    def _begin(self, train: int) -> _Session:
        m = self.st.model
        s = _Session(
            train=train,
            ws=np.empty(WS_SIZE),
            dbuf=np.zeros(m.window),
            pass_t=np.empty(3),
            pass_x=np.empty(3),
            wh_v=np.empty(HISTORY),
            wh_e=np.empty(HISTORY),
            taus=np.empty(SAMPLES),
            weights=np.empty(SAMPLES),
            tele=np.empty(TEL_SIZE),
            crow=np.empty(CR_SIZE),
            pending=np.full(TEL_SIZE, np.nan),
        )
        wayside_init_1(s.ws, m.wp, s.wh_v, s.wh_e, s.pass_t, s.pass_x)
        return s

    def read(self, train: int, stands: bool, readings: list[Reading]) -> None:
        """The sensors' readings of ``train`` (in time order); a train that stands ends the stop."""
        s = self.session
        if s is None or s.train != train:
            s = self.session = self._begin(train)  # a new train in the zone: a new stop
        m = self.st.model
        form = int(m.wp[WP_FORM])
        for r in readings:
            if r.t_s <= s.last_reading_s:
                continue  # a reading it already has (a frame sent twice)
            s.last_reading_s = r.t_s
            due = wayside_step_1(
                s.ws, m.wp, s.dbuf, s.pass_t, s.pass_x, m.det_pos, s.wh_v, s.wh_e, s.taus, s.weights,
                BrakeCurves(m.table, m.pwm_duty, m.pwm_decel), Approach(m.det_to_stop, m.ext, self.st.grad),
                r.t_s, r.passed, r.detector, r.passage_s, r.doppler_mps, s.tele, s.crow,
            )  # fmt: skip
            if not due:
                continue
            quantize_telegram_1(s.tele, s.pending, m.quant, m.carried, form, m.kp[KP_QUANT_AGE])
            row = telegram_of(s.pending, SignalForm(form))
            try:
                s.payload = encode(to_message(row, 0, train_id=train))
            except TelegramError:
                continue  # a value the telegram cannot carry: nothing is sent (the train's supervision)
            s.commands += 1
            self.records.append(
                office_record(self.st.station.name, train, s.crow, s.pending, form, s.payload)
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


#: A command's fields in the office's record (SPEC §1 claims 7, 20) and the stop model's names:
#: when it was computed, from which detector's passage (``age``: how long before), the distance to
#: the stop, the radar's speed, the measured and required deceleration, the correction gain, the
#: command, its notch / step, when it takes effect (``eff``: how long after), the emergency-stop
#: flag.
OFFICE_COMMAND_FIELDS: dict[str, str] = {
    "t": "t_s",
    "det": "detector",
    "age": "passage_s",
    "dist": "distance_m",
    "v": "speed_mps",
    "a_meas": "measured_decel_mps2",
    "a_req": "required_decel_mps2",
    "gain": "gain",
    "a_cmd": "command_decel_mps2",
    "notch": "notch",
    "delta": "delta",
    "eff": "effect_s",
    "eb": "emergency",
}


def office_record(
    station: str, train: int, crow: FloatArray, pending: FloatArray, form: int, payload: bytes
) -> dict[str, Any]:
    """A command as the office stores it (SPEC §1 claims 7, 20): the station (``st``) and train
    (``tr``), the command's inputs and what the unit computed (:data:`OFFICE_COMMAND_FIELDS`, at
    millimetre / millisecond resolution) and the telegram as it went on the air (``air``: the codec
    frame in hex). Short names: the office link carries at most 255 bytes a report."""
    rec = command_records(np.append(crow, 0.0)[None, :], SignalForm(form), pending[None, :])[0]
    out: dict[str, Any] = {"st": station, "tr": train}
    rec["passage_s"] = rec["t_s"] - rec["passage_s"]
    rec["effect_s"] -= rec["t_s"]
    for short, name in OFFICE_COMMAND_FIELDS.items():
        v = rec[name]
        if isinstance(v, float):
            v = round(v, 3) if math.isfinite(v) else None
        out[short] = v
    out["air"] = payload.hex()
    return out


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
    antenna passed in the step before (NaN: none), and whether the train stands."""

    k: int
    tach_mps: float
    odo_step_m: float
    transponder_m: float
    stopped: bool


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
    train's own sensors (:class:`Sense`) in, one ``receiver_cycle_1`` (the kernel's onboard step:
    the configuration's output, the telegram time-out and the overrun guard) per 10 ms step, the
    brake demand out (:class:`BrakeDrive`)."""

    st: StationTasc
    train: int
    inbox: list[bytes] = field(default_factory=list)  # telegram payloads received, oldest first
    eb: bool = False
    commands: int = 0
    refused: int = 0

    def __post_init__(self) -> None:
        m = self.st.model
        self.rx = np.empty(RX_SIZE)
        self.mod = np.empty(MOD_SIZE)
        self.rh_v, self.rh_e = np.empty(HISTORY), np.empty(HISTORY)
        receiver_init_1(self.rx, self.mod, self.rh_v, self.rh_e)
        self.tach = np.zeros(m.tach_window)
        self.taus = np.empty(SAMPLES)
        self.pending = np.full(TEL_SIZE, np.nan)
        self.last_payload: bytes | None = None
        self.own_notch, self.own_for = 0, -1
        self.own_duty = math.nan

    def deliver(self, payload: bytes) -> None:
        self.inbox.append(payload)

    def cycle(self, t_s: float, sense: Sense, extra_eb: bool = False) -> BrakeDrive:
        """One 10 ms step at ``t_s``. ``extra_eb``: another unit (CBTC) applies the emergency brake."""
        m, kp = self.st.model, self.st.model.kp
        if math.isfinite(sense.transponder_m):
            # The train's own ATP resets its odometer at the transponders; at the first one its
            # brake controller applies the initial brake step (SPEC §1, as the stop model).
            receiver_fix_1(self.rx, m.rp, sense.transponder_m)
            self.own_notch = int(kp[KP_INITIAL_NOTCH])
        new = copy = False
        for payload in self.inbox:
            if payload == self.last_payload:
                # A cyclic repeat of the telegram it has: a life sign. [interpretation] The codec
                # telegram carries no command number; a new command equal to the last one on the
                # wire tells the unit nothing new, so it is taken as a repeat too.
                copy = True
                continue
            try:
                row = from_message(decode(payload), m.form)
            except TelegramError:
                self.refused += 1
                continue
            for j, name in enumerate(TEL_FIELDS):
                self.pending[j] = float(getattr(row, name)[0])
            self.last_payload, new = payload, True
            self.commands += 1
        self.inbox.clear()
        pwm_train = int(m.rp[RP_CONFIG]) in (CFG_PWM, CFG_SWITCHED_PWM)
        if self.own_notch != self.own_for:
            self.own_duty, _ = own_command_1(self.own_notch, pwm_train, m.table, m.pwm_duty, m.pwm_decel)
            self.own_for = self.own_notch
        notch, duty, eb, _ = receiver_cycle_1(
            self.rx, m.rp, self.mod, self.tach, self.rh_v, self.rh_e, self.taus,
            BrakeCurves(m.table, m.pwm_duty, m.pwm_decel), Approach(m.det_to_stop, m.ext, self.st.grad),
            self.pending, t_s, sense.k, new,
            copy and not new, sense.tach_mps, sense.odo_step_m, self.own_notch, self.own_duty,
        )  # fmt: skip
        self.eb = eb or extra_eb
        braking = math.isfinite(self.rx[RX_FIRST_RX]) or self.eb or self.own_notch > 0
        demand = m.table[line_notch(notch)] if notch >= 0 else pwm_to_decel_1(duty, m.pwm_duty, m.pwm_decel)
        if self.eb:
            demand = kp[KP_EMERGENCY]  # wire e: the emergency brake, whatever the service command
        return BrakeDrive(sense.k, float(demand), bool(braking), self.eb)

    def eb_cause(self) -> str | None:
        """The onboard unit's own emergency brake's cause (None: it applied none)."""
        return eb_cause_name(int(self.rx[RX_EB])) if self.rx[RX_EB] > 0.0 else None


@dataclass
class TascPlant:
    """A train under ground TASC as the plant moves it (the stop model's plant): its brakes (the
    ECU's load compensation, dead time, jerk limit, lag: ``actuator_step_1``), its motion
    (``motion_step_1``: adhesion, resistance, gradient), the wheels and tachometer, the transponders
    under it, and the station's sensors reading it (the readings queued in ``out``), one ``step``
    per 10 ms with the onboard unit's :class:`BrakeDrive`."""

    st: StationTasc
    train: int
    sc: FloatArray
    x_m: float
    v_mps: float
    rng: np.random.Generator
    t0_s: float
    out: list[Reading] = field(default_factory=list)
    stopped: bool = False
    max_jerk: float = 0.0

    def __post_init__(self) -> None:
        m, sc, kp = self.st.model, self.sc, self.st.model.kp
        static = kp[KP_TARE] + sc[SC_LOAD] * kp[KP_CRUSH]
        rotating = kp[KP_TARE] * kp[KP_ROTATING]
        self.static, self.effective = static, static + rotating
        self.believed = static * (1.0 + sc[SC_WEIGHING_ERROR]) + rotating
        self.tach_scale = (sc[SC_WHEEL_D] * (1.0 + sc[SC_ODO_ERROR])) / sc[SC_WHEEL_D]
        self.delay_steps = int(np.rint(sc[SC_DEAD_TIME] / TASC_DT_S))
        self.ring = np.zeros(self.delay_steps + 1)
        self.limited = self.output = self.accel = self.prev_accel = 0.0
        self.lag_alpha = 1.0 - math.exp(-TASC_DT_S / sc[SC_TAU])
        self.sliding = self.prev_counted = False
        self.odo_step = 0.0
        self.k = 0
        self.transponder_next = int(np.searchsorted(m.transponders, self.x_m, side="right"))
        self.transponder_m = math.nan  # passed in the last step
        self.sensor_next = int(np.searchsorted(m.det_pos, self.x_m, side="right"))
        self.passed, self.det_idx, self.pass_s = False, 0, math.nan
        self.stop_time_s = math.nan

    def _doppler(self) -> float:
        kp = self.st.model.kp
        if kp[KP_HAS_DOPPLER] == 0.0:
            return math.nan
        if kp[KP_DOPPLER_REACH] - self.x_m > kp[KP_DOPPLER_RANGE]:
            return 0.0  # out of the radar's range (the stop model's convention)
        noise = self.sc[SC_DOPPLER_NOISE]
        return self.v_mps * (1.0 + noise * self.rng.standard_normal()) if noise > 0.0 else self.v_mps

    def sense(self) -> Sense:
        """What the train's sensors tell its onboard unit before the next step."""
        tach_v = self.v_mps * creep_1(self.sliding, self.st.model.kp[KP_SLIDE_SLIP]) * self.tach_scale
        return Sense(self.k, float(tach_v), float(self.odo_step), self.transponder_m, self.stopped)

    def step(self, t_s: float, drive: BrakeDrive) -> None:
        """One 10 ms step at ``t_s`` under ``drive``: the station's sensors read the train (queued in
        ``out``), then the brakes and the motion; the passages of transponders and detectors."""
        m, kp, sc = self.st.model, self.st.model.kp, self.sc
        self.out.append(Reading(t_s, self._doppler(), self.passed, self.det_idx, self.pass_s))
        self.passed = False
        self.limited, self.output = actuator_step_1(
            self.ring, self.k, self.delay_steps, drive.demand_mps2, self.limited, self.output,
            self.lag_alpha, kp[KP_JERK] * TASC_DT_S, kp[KP_EMERGENCY],
        )  # fmt: skip
        brake_decel = self.output * sc[SC_BRAKE_GAIN] * self.believed / self.effective
        mu = sc[SC_LOW_MU] if sc[SC_LOW_START] <= self.x_m < sc[SC_LOW_END] else sc[SC_MU]
        x0, v0 = self.x_m, self.v_mps
        hold = not drive.braking
        self.x_m, self.v_mps, self.accel, stopped, st, self.sliding = motion_step_1(
            x0, v0, self.stopped, brake_decel, mean_gradient_1(x0, kp[KP_LENGTH], *self.st.grad), mu, hold,
            self.static, self.effective, kp[KP_DAVIS_A], kp[KP_DAVIS_B], kp[KP_DAVIS_C], t_s, TASC_DT_S,
        )  # fmt: skip
        counted = not hold and not stopped
        if counted and self.prev_counted:
            self.max_jerk = max(self.max_jerk, abs(self.accel - self.prev_accel) / TASC_DT_S)
        self.prev_accel, self.prev_counted = self.accel, counted
        if stopped and not self.stopped:
            self.stop_time_s = st
        self.stopped = stopped
        creep = creep_1(self.sliding, kp[KP_SLIDE_SLIP])
        self.odo_step = (self.x_m - x0) * creep * self.tach_scale
        self.transponder_m = math.nan
        if passage_1(m.transponders, self.transponder_next, x0, self.x_m):
            self.transponder_m = float(m.transponders[self.transponder_next])
            self.transponder_next += 1
        if passage_1(m.det_pos, self.sensor_next, x0, self.x_m):
            self.det_idx = self.sensor_next
            jitter = sc[SC_SENSOR_JITTER] * self.rng.standard_normal()
            self.pass_s = t_s + crossing_time_1(x0, v0, self.accel, m.det_pos[self.det_idx]) + jitter
            self.passed = self.rng.uniform() >= sc[SC_MISS]
            self.sensor_next += 1
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
        self,
        *,
        st: StationTasc,
        train: int,
        sc: FloatArray,
        x_m: float,
        v_mps: float,
        rng: np.random.Generator,
        t0_s: float,
    ) -> None:
        self.st, self.train = st, train
        self.onboard = TascOnboard(st=st, train=train)
        self.plant = TascPlant(st=st, train=train, sc=sc, x_m=x_m, v_mps=v_mps, rng=rng, t0_s=t0_s)

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
        return self.plant.result(cause, float(self.onboard.rx[RX_EB_T]), self.onboard.eb)


def draw_stop(
    dist: DisturbanceSet, st: StationTasc, vehicle: Vehicle, *, seed: int, train: int, visit: int
) -> tuple[FloatArray, np.random.Generator]:
    """The train's vehicle and sensors for one stop: a draw of the disturbance set (the line
    simulation's run numbering: train x 100 + visit) and the random stream of its sensors."""
    run = train * RUNS_PER_TRAIN + visit % RUNS_PER_TRAIN
    streams = RunStreams.for_runs(seed, run, 1)
    scenario, _ = draw_scenario(dist, st.station, vehicle, streams)
    scenario = scenario.with_values(gradient=station_gradient(st.station, 1))
    sc, _, _, _ = scenario_arrays(scenario)
    return sc[0], np.random.default_rng([seed, train, visit])


def wired_stop(
    st: StationTasc,
    vehicle: Vehicle,
    *,
    delay_steps: int = 0,
    silent_after_s: float = math.inf,
    readings_lost_after_s: float = math.inf,
    until_s: float = 300.0,
) -> tuple[TascStop, WaysideTasc]:
    """One nominal stop (the station's entry speed, from its hand-over point) with the wayside and
    the train wired directly in this process: every telegram arrives ``delay_steps`` steps after
    it was sent, none after ``silent_after_s`` (the wayside died); no reading reaches the wayside
    after ``readings_lost_after_s`` (the sensors' wiring cut). The live units' check against
    the stop kernel, and their warm-up (the compiled steps loaded before a live clock starts)."""
    sc, _, _, _ = scenario_arrays(Scenario.nominal(st.station, vehicle))
    v = float(sc[0][0])
    x = handover_m(st.first_detector_m, v)
    wayside = WaysideTasc(st)
    train = TascStop(st=st, train=2, sc=sc[0], x_m=x, v_mps=v, rng=np.random.default_rng(0), t0_s=0.0)
    air: list[tuple[float, bytes]] = []
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
        t += TASC_DT_S
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
