"""The plant live (issue 17 item 1): the trains' motion, their own sensors and the trackside
sensors, as a process of its own.

The plant stands for the physical world: what moves the trains and what
measures them. It holds each train's true position and speed and moves them
every ``PLANT_STEP_S`` (10 ms) under what the trains' onboard units ask:

* **under the ATO and the CBTC unit** a :class:`Drive` (a target speed, the
  rates to reach it; the emergency drive applies the emergency brake) that a
  tiny speed controller (:func:`drive_demand`) turns into a demand on the one
  train plant of the line (``physics.plant``: traction, the brakes' dead
  time, jerk limit and lag, resistance, the track's gradient, adhesion);
* **under ground TASC** (SPEC §1), from the hand-over point to standstill,
  the stop model's plant (:class:`~railstop.live.tasc.TascPlant`: the ECU's
  load compensation, the brakes' dead time, jerk limit and lag, adhesion,
  resistance, gradient), driven each 10 ms step by the onboard TASC unit's
  :class:`~railstop.live.tasc.BrakeDrive`, answering the train's
  :class:`~railstop.live.tasc.Sense` (tachometer, odometer step,
  transponders). The station's wheel detectors and radar read the train
  (frames to the stations process, as the sensors' wiring).
* **the platforms' stop sensors** read each train standing near a stopping
  point (frames to the platform's WPCS, SPEC §5: PSC is answered only for a
  train its stop sensors see in position).

Between processes (:func:`run_plant`, ``railstop live plant``) the drives come
from the trains process and the plant's state of every train goes back each
step as ``plant`` frames (EN 50159 category 3, as every link here: UDP is an
open network). The TASC coupling is in lock step: the plant sends the
train's sensing for step k + 1 at the end of step k, the trains process runs
its onboard unit's cycle as the frame arrives and answers with the drive for
step k + 1, which the plant uses at its next step: the order of the stop
model, so that the split costs nothing when every drive is on time. A drive
that has not arrived is late (counted): the plant keeps the last one for that
step (a brake controller holds its last command for a cycle).

In one process (``live trains`` without ``--plant``) the same :class:`Plant`
runs inside the trains process, wired directly: only the transport differs.

Fail safe (DESIGN rule 10): a plant that hears no drive from the trains
process for ``DRIVE_TIMEOUT_S`` applies every train's emergency brake (its
onboard units are dead: the brake loop opens) [interpretation: the train's
loop circuit, as on any train whose control is lost]; a trains process that
hears nothing from its plant for ``SENSE_TIMEOUT_S`` applies the emergency
brake of every train and reports it (cause ``plant-lost``).
"""

from __future__ import annotations

import asyncio
import math
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from railstop.config.disturbances import DisturbanceSet
from railstop.config.schema import Line, Vehicle
from railstop.control.line_ato import SPEED_GAIN_PER_S
from railstop.link.safety import MAX_PAYLOAD_BYTES, SafePeers
from railstop.link.udp import Address, UdpEndpoint, open_endpoint
from railstop.live.clock import TimeBase, WallClock
from railstop.live.doors import PLATFORM_BASE, SENSORS_ID, pack_stop_sensed
from railstop.live.drive import HOLD, STOP_SENSOR_SPAN_M, Drive, emergency_drive
from railstop.live.tasc import (
    STATION_BASE,
    TASC_DT_S,
    BrakeDrive,
    Sense,
    StationTasc,
    TascPlant,
    draw_stop,
    pack_readings,
    station_models,
)
from railstop.model.records import KP_EMERGENCY
from railstop.physics.plant import PlantParams, PlantState, plant_step, set_direction, track_gradient

PLANT_ID = 0x0281  # the plant's end of the trains' wiring (their sensors and actuators)
TRAINS_WIRING_ID = 0x4C00  # the trains process's end of that wiring
PLANT_STEP_S = TASC_DT_S  # the plant's step: the stop model's (10 ms)
SENSOR_EVERY = 5  # trackside readings go out every 5 plant steps (50 ms), as one frame per train
DRIVE_TIMEOUT_S = 0.5  # no drive for this long: every train's emergency brake (fail safe)
SENSE_TIMEOUT_S = 0.5  # no plant state for this long: the trains process brakes every train
#: The trains' load between TASC stops (a stop draws its own) [interpretation]: half way from empty
#: to crush, as the line simulation's trains enter.
LOAD_FACTOR = 0.5
#: The speed controller holds the speed (traction against resistance and gradient) within this of
#: the drive's target, once the brakes are released: the speed-error law alone settles short of
#: the target by the resistance over its gain (0.01-0.03 m/s on the level at 10-25 m/s).
HOLD_BAND_MPS = 0.05

# One drive record: train, kind, integer, four values. Kinds: ATO (integer = 1 for the emergency
# brake; target, accel, decel, relocate), TASC begin (integer = station << 16 | visit), TASC brake
# (integer = step k; demand, braking, eb), place (position).
_DRIVE = struct.Struct(">H B I d d d d")
_ATO, _BEGIN, _BRAKE, _PLACE = 0, 1, 2, 3
# One state record: train, flags, position, speed; under TASC then the sensing (step k, step time,
# tachometer, odometer step, transponder); at the stop's end then its jerk and stop time.
_STATE = struct.Struct(">H B d d")
_SENSE = struct.Struct(">I d d d d")
_END = struct.Struct(">d d")
_F_TASC, _F_ENDED, _F_EB, _F_STOPPED, _F_FRESH, _F_WSP = 1, 2, 4, 8, 16, 32
_HEAD = struct.Struct(">B H")


def initial_positions(line: Line, vehicle: Vehicle, trains: int, spacing_m: float) -> list[float]:
    """Where the trains start: train k ``spacing_m`` behind train k - 1, the first 300 m before the
    line's end; ValueError if they do not fit (none closer to the line's start than its length)."""
    end_m = line.end_m
    out = []
    for k in range(trains):
        x = end_m - 300.0 - k * spacing_m
        if x < vehicle.length_m + 10.0:
            fit = f"{trains} trains {spacing_m:g} m apart do not fit on the {end_m:g} m line"
            raise ValueError(f"--trains / --spacing-m: {fit}")
        out.append(x)
    return out


def drive_demand(drive: Drive, plant: PlantState) -> tuple[float, bool]:
    """The speed controller: the demand (m/s², + traction, - braking) that takes the train towards
    the drive's target, and whether traction holds the speed. Along the running direction: a
    target of 0 (or behind a train still running) brakes at the drive's rate, to a stand and held
    there; within ``HOLD_BAND_MPS`` of the target traction holds the speed (the plant lets it once
    the brakes are released); otherwise the line's ATO law, ``SPEED_GAIN_PER_S`` x the speed error,
    within the rates.
    [interpretation] the simplest controller that turns a target and its rates into a demand."""
    target = drive.target_mps * plant.direction
    if target <= 0.0:
        return -drive.decel_mps2, False
    error = target - plant.v_mps
    if abs(error) <= HOLD_BAND_MPS:
        return 0.0, True
    return min(max(SPEED_GAIN_PER_S * error, -drive.decel_mps2), drive.accel_mps2), False


@dataclass(frozen=True, slots=True)
class Place:
    """The trains process places a train, standing, where it last knew it: what a plant that knows
    nothing of the trains (started, or started again in a running line) is told first."""

    x_m: float


@dataclass(frozen=True, slots=True)
class TrainState:
    """A train as the plant tells the trains process: position, speed; under ground TASC the
    sensing for its next step (``sense``); ``ended``: its TASC stop ended in this state (with the
    stop's jerk and time); ``eb``: the plant applied its emergency brake (fail safe)."""

    train: int
    x_m: float
    v_mps: float
    sense: Sense | None = None
    sense_t_s: float = math.nan
    ended: bool = False
    jerk_mps3: float = math.nan
    stop_time_s: float = math.nan
    eb: bool = False
    fresh: bool = False  # the plant has not been told where its trains are (its start)


@dataclass
class _Vehicle:
    k: int
    plant: PlantState  # its motion outside a TASC stop (``physics.plant``)
    drive: Drive = HOLD
    tasc: TascPlant | None = None
    brake: BrakeDrive | None = None  # the last TASC drive received
    ended: tuple[float, float] | None = None  # the TASC stop that ended: (jerk, stop time)
    begin: tuple[int, int] | None = None  # a TASC stop to begin: (station, visit)

    @property
    def x_m(self) -> float:
        return self.plant.x_m

    @x_m.setter
    def x_m(self, x_m: float) -> None:
        self.plant.x_m = x_m

    @property
    def v_mps(self) -> float:
        """The speed, signed (+ towards higher chainage)."""
        return self.plant.v_mps * self.plant.direction

    @v_mps.setter
    def v_mps(self, v_mps: float) -> None:
        """Set the speed (a TASC stop moves the train; a test places it): 0 stands, held."""
        p = self.plant
        p.v_mps, p.stopped = abs(v_mps), v_mps == 0.0
        if v_mps != 0.0:
            p.direction = 1 if v_mps > 0.0 else -1


OnboardFn = Callable[[int, float, Sense], BrakeDrive | None]


@dataclass
class TascPlantData:
    """What the plant needs for ground TASC stops: the stations' stop models and the operation's
    disturbance set (one draw per stop, as the line simulation numbers them)."""

    controller: str
    dist: DisturbanceSet
    seed: int


class Plant:
    """Every train's motion (see the module's notes), one :meth:`step` per 10 ms. Pure: the
    trackside readings to send are queued in ``outgoing`` as (peer id, payload)."""

    def __init__(
        self,
        *,
        line: Line,
        vehicle: Vehicle,
        trains: int,
        spacing_m: float,
        master_key: bytes,
        tasc: TascPlantData | None = None,
        sensor_every: int = SENSOR_EVERY,
    ) -> None:
        """``sensor_every``: the trackside readings leave every this many steps (1: each step)."""
        self.line, self.vehicle = line, vehicle
        self.sensor_every = sensor_every
        starts = initial_positions(line, vehicle, trains, spacing_m)
        self.params = PlantParams.create(
            vehicle, load_factor=LOAD_FACTOR, dt_s=PLANT_STEP_S, gradient=track_gradient(line)
        )
        self.fleet = [_Vehicle(k, PlantState.create(self.params, x_m=x)) for k, x in enumerate(starts)]
        self.tasc = tasc
        self.models: list[StationTasc] = (
            station_models(line, vehicle, tasc.controller) if tasc is not None else []
        )
        self.sensors = SafePeers(SENSORS_ID, master_key, max_age_s=1.0, peers=lambda p: False)
        self.outgoing: list[tuple[int, bytes]] = []
        self.stop_points = [(i, st.stop_point_m) for i, st in enumerate(line.stations)]
        self.steps = 0
        self.late_drives = 0  # TASC steps whose drive had not arrived (the last one held)
        self.eb_all = False  # fail safe: every train's emergency brake (the trains process is silent)
        self.fresh = True  # not yet told where the trains are (the trains process places them)
        self.tasc_stops = 0

    # -- inputs ---------------------------------------------------------------------
    def drive(self, train: int, drive: Drive) -> None:
        self.fleet[train].drive = drive

    def begin_tasc(self, train: int, station: int, visit: int) -> None:
        """Hand the train over to ground TASC at ``station`` (its ``visit``-th stop: its draw)."""
        v = self.fleet[train]
        if v.tasc is None and self.tasc is not None and 0 <= station < len(self.models):
            v.begin = (station, visit)

    def place(self, train: int, x_m: float) -> None:
        """The train stands at ``x_m`` (:class:`Place`); a TASC stop under way there ends."""
        if 0 <= train < len(self.fleet):
            v = self.fleet[train]
            v.plant, v.drive = PlantState.create(self.params, x_m=x_m), HOLD
            v.tasc = v.brake = v.begin = v.ended = None
            self.fresh = False

    def brake(self, train: int, drive: BrakeDrive) -> None:
        """A TASC drive received (in lock step: for the train's next step)."""
        if 0 <= train < len(self.fleet):
            self.fleet[train].brake = drive

    # -- the step -------------------------------------------------------------------
    def step(self, now_s: float, onboard: OnboardFn | None = None) -> None:
        """One 10 ms step at ``now_s``. ``onboard(train, t_s, sense)``: the onboard TASC unit's drive
        for a train's sensing (wired in one process); without it the drive received for that step
        is used (between processes)."""
        dt = PLANT_STEP_S
        for v in self.fleet:
            tp = v.tasc
            if tp is not None:
                sense = tp.sense()
                got = onboard(v.k, now_s, sense) if onboard is not None else v.brake
                if got is None or got.k != sense.k:
                    self.late_drives += 1
                    last = v.brake or BrakeDrive(sense.k, 0.0, False, False)
                    got = BrakeDrive(sense.k, last.demand_mps2, last.braking, last.eb)
                if self.eb_all:
                    got = BrakeDrive(sense.k, float(tp.st.model.kp[KP_EMERGENCY]), True, True)
                v.brake = got
                tp.step(now_s, got)
                v.x_m, v.v_mps = tp.x_m, tp.v_mps
                if tp.stopped:
                    v.ended = (tp.max_jerk, tp.stop_time_s - tp.t0_s)
                    self._readings(tp)
                    v.tasc, v.brake, v.drive = None, None, HOLD
                    v.plant = PlantState.create(self.params, x_m=tp.x_m)  # it stands, held
                elif (self.steps + 1) % self.sensor_every == 0:
                    self._readings(tp)
                continue
            d = v.drive
            if math.isfinite(d.relocate_m):
                v.plant, v.drive = PlantState.create(self.params, x_m=d.relocate_m), HOLD
                continue
            if self.eb_all:
                d = emergency_drive(self.vehicle)
            p = v.plant
            if d.target_mps != 0.0 and p.stopped:
                set_direction(p, 1 if d.target_mps > 0.0 else -1)  # a correction backs from a stand
            demand, hold = drive_demand(d, p)
            plant_step(p, self.params, demand_mps2=demand, t_s=now_s, eb=d.emergency, speed_hold=hold)
        for v in self.fleet:
            if v.begin is not None and v.tasc is None:
                station, visit = v.begin
                self._begin(v, station, visit, now_s + dt)
            v.begin = None
        self.steps += 1
        if self.steps % SENSOR_EVERY == 0:
            self._stop_sensors()  # every 50 ms

    def _begin(self, v: _Vehicle, station: int, visit: int, t0_s: float) -> None:
        assert self.tasc is not None
        st = self.models[station]
        scenario, run = draw_stop(
            self.tasc.dist, st, self.vehicle, seed=self.tasc.seed, train=v.k, visit=visit, speed_mps=v.v_mps
        )
        v.tasc = TascPlant(
            st=st, train=v.k, scenario=scenario, seed=self.tasc.seed, run=run, x_m=v.x_m, t0_s=t0_s
        )
        self.tasc_stops += 1

    def _readings(self, tp: TascPlant) -> None:
        """The station's detectors and radar: the readings since the last frame, to its wayside."""
        payload = pack_readings(tp.train, tp.st.index, tp.stopped, tp.out)
        tp.out.clear()
        self._send(STATION_BASE + tp.st.index, payload)

    def _stop_sensors(self) -> None:
        """Each platform's stop sensors read the trains standing near its stopping point (the
        stop error; NaN for one moving)."""
        for v in self.fleet:
            if v.tasc is not None:
                continue
            for i, stop_m in self.stop_points:
                error = v.x_m - stop_m
                if abs(error) <= STOP_SENSOR_SPAN_M:
                    sensed = error if v.v_mps == 0.0 else math.nan
                    self._send(PLATFORM_BASE + i, pack_stop_sensed(v.k, i, sensed))

    def _send(self, peer: int, payload: bytes) -> None:
        self.outgoing.append((peer, payload))

    # -- what the trains process is told -------------------------------------------
    def states(self, now_s: float) -> list[TrainState]:
        """Every train as it stands after the step at ``now_s`` (one-shot: a TASC stop's end)."""
        out = []
        for v in self.fleet:
            tp = v.tasc
            jerk = stop_t = math.nan
            if v.ended is not None:
                jerk, stop_t = v.ended
            out.append(
                TrainState(
                    train=v.k,
                    x_m=v.x_m,
                    v_mps=v.v_mps,
                    sense=None if tp is None else tp.sense(),
                    sense_t_s=now_s + PLANT_STEP_S,
                    ended=v.ended is not None,
                    jerk_mps3=jerk,
                    stop_time_s=stop_t,
                    eb=self.eb_all,
                    fresh=self.fresh,
                )
            )
            v.ended = None
        return out

    def counts(self) -> dict[str, Any]:
        return {
            "steps": self.steps,
            "tasc_stops": self.tasc_stops,
            "late_tasc_drives": self.late_drives,
            "sensor_frames": self.sensors.sent,
        }


# ---------------------------------------------------------------------- the wire


DriveRecord = tuple[int, "Drive | tuple[int, int] | BrakeDrive | Place"]


def pack_drives(records: list[DriveRecord]) -> list[bytes]:
    """The trains process's drives as frames' payloads (at most ``_MAX_RECORDS`` a frame)."""
    rows = []
    for train, d in records:
        if isinstance(d, Drive):
            eb = 1 if d.emergency else 0
            rows.append(_DRIVE.pack(train, _ATO, eb, d.target_mps, d.accel_mps2, d.decel_mps2, d.relocate_m))
        elif isinstance(d, BrakeDrive):
            rows.append(_DRIVE.pack(train, _BRAKE, d.k, d.demand_mps2, float(d.braking), float(d.eb), 0.0))
        elif isinstance(d, Place):
            rows.append(_DRIVE.pack(train, _PLACE, 0, d.x_m, 0.0, 0.0, 0.0))
        else:
            station, visit = d
            rows.append(_DRIVE.pack(train, _BEGIN, (station << 16) | visit, 0.0, 0.0, 0.0, 0.0))
    return _chunks(rows, 1)


def unpack_drives(payload: bytes) -> list[DriveRecord]:
    """ValueError for a payload of the wrong shape or an unknown kind."""
    out: list[DriveRecord] = []
    for train, kind, n, a, b, c, d in _rows(payload, 1, _DRIVE):
        if kind == _ATO:
            if n not in (0, 1):
                raise ValueError(f"drive flag {n}: 0 or 1 (the emergency brake)")
            out.append((train, Drive(a, b, c, d, emergency=n == 1)))
        elif kind == _BRAKE:
            out.append((train, BrakeDrive(n, a, b != 0.0, c != 0.0)))
        elif kind == _BEGIN:
            out.append((train, (n >> 16, n & 0xFFFF)))
        elif kind == _PLACE:
            out.append((train, Place(a)))
        else:
            raise ValueError(f"unknown drive kind {kind}")
    return out


def pack_states(states: list[TrainState]) -> list[bytes]:
    rows = []
    for s in states:
        se = s.sense
        flags = (_F_TASC if se else 0) | (_F_ENDED if s.ended else 0) | (_F_EB if s.eb else 0)
        flags |= _F_FRESH if s.fresh else 0
        if se is not None and se.stopped:
            flags |= _F_STOPPED
        if se is not None and se.wsp:
            flags |= _F_WSP
        row = _STATE.pack(s.train, flags, s.x_m, s.v_mps)
        if se is not None:
            row += _SENSE.pack(se.k, s.sense_t_s, se.tach_mps, se.odo_step_m, se.transponder_m)
        if s.ended:
            row += _END.pack(s.jerk_mps3, s.stop_time_s)
        rows.append(row)
    return _chunks(rows, 2)


def unpack_states(payload: bytes) -> list[TrainState]:
    """ValueError for a payload of the wrong shape."""
    _, n = _head(payload, 2)
    out, at = [], _HEAD.size
    try:
        for _ in range(n):
            train, flags, x, v = _STATE.unpack_from(payload, at)
            at += _STATE.size
            sense, t_s, jerk, stop_t = None, math.nan, math.nan, math.nan
            if flags & _F_TASC:
                k, t_s, tach, odo, transp = _SENSE.unpack_from(payload, at)
                at += _SENSE.size
                sense = Sense(k, tach, odo, transp, bool(flags & _F_STOPPED), bool(flags & _F_WSP))
            if flags & _F_ENDED:
                jerk, stop_t = _END.unpack_from(payload, at)
                at += _END.size
            ended, eb, fresh = bool(flags & _F_ENDED), bool(flags & _F_EB), bool(flags & _F_FRESH)
            out.append(TrainState(train, x, v, sense, t_s, ended, jerk, stop_t, eb, fresh))
    except struct.error:
        raise ValueError("plant frame shorter than its records") from None
    if at != len(payload):
        raise ValueError("plant frame length does not match its records")
    return out


def _chunks(rows: list[bytes], kind: int) -> list[bytes]:
    """The rows in payloads of at most MAX_PAYLOAD_BYTES (the safety layer's), each with its head."""
    out: list[bytes] = []
    batch: list[bytes] = []
    size = _HEAD.size
    for row in rows:
        if batch and size + len(row) > MAX_PAYLOAD_BYTES:
            out.append(_HEAD.pack(kind, len(batch)) + b"".join(batch))
            batch, size = [], _HEAD.size
        batch.append(row)
        size += len(row)
    if batch:
        out.append(_HEAD.pack(kind, len(batch)) + b"".join(batch))
    return out


def _head(payload: bytes, kind: int) -> tuple[int, int]:
    if len(payload) < _HEAD.size:
        raise ValueError("short plant frame")
    got, n = _HEAD.unpack_from(payload)
    if got != kind:
        raise ValueError(f"plant frame of kind {got}, expected {kind}")
    return got, n


def _rows(payload: bytes, kind: int, row: struct.Struct) -> list[tuple[Any, ...]]:
    _, n = _head(payload, kind)
    if len(payload) != _HEAD.size + n * row.size:
        raise ValueError("plant frame length does not match its count")
    return [row.unpack_from(payload, _HEAD.size + j * row.size) for j in range(n)]


# ---------------------------------------------------------------------- the plant process


async def run_plant(
    *,
    plant: Plant,
    local: Address,
    stations: Address | None,
    base: TimeBase,
    master_key: bytes,
    stop: asyncio.Event,
    on_ready: Callable[[Address], None] | None = None,
) -> dict[str, Any]:
    """Move the trains until ``stop``: drives from the trains process (it is heard at the address
    its frames come from), every train's state back each step; the trackside readings to the
    stations process. Returns the counts."""
    # Nothing sent before this process started is delivered: a drive its previous incarnation
    # followed is not followed again (EN 50159 repetition across a restart of the plant).
    wiring = SafePeers(
        PLANT_ID, master_key, max_age_s=1.0, peers=lambda p: p == TRAINS_WIRING_ID, started_s=base.now_s()
    )
    clock = WallClock([], step_s=PLANT_STEP_S, base=base)
    trains_at: Address | None = None
    last_drive_s = -math.inf
    refused_payloads = 0
    drive_lost = 0
    async with await open_endpoint(local) as ep:
        if on_ready is not None:
            on_ready(ep.local_address)

        def poll(now_s: float) -> list[Any]:
            nonlocal trains_at, last_drive_s, refused_payloads
            while (got := ep.take()) is not None:
                frame, addr = got
                ok = wiring.accept(frame, now_s)
                if ok is None:
                    continue
                try:
                    records = unpack_drives(ok[1].payload)
                except ValueError:
                    refused_payloads += 1
                    continue
                trains_at, last_drive_s = addr, now_s
                for train, d in records:
                    if not 0 <= train < len(plant.fleet):
                        continue
                    if isinstance(d, Drive):
                        plant.drive(train, d)
                    elif isinstance(d, BrakeDrive):
                        plant.brake(train, d)
                    elif isinstance(d, Place):
                        plant.place(train, d.x_m)
                    else:
                        plant.begin_tasc(train, *d)
            return []

        def step(now_s: float, step_s: float) -> list[Any]:
            nonlocal drive_lost
            # Supervised from the first drive on (until then every train stands, held).
            lost = trains_at is not None and now_s - last_drive_s > DRIVE_TIMEOUT_S
            if lost and not plant.eb_all:
                drive_lost += 1
            plant.eb_all = lost  # fail safe: the trains' onboard units are silent
            plant.step(now_s)
            _send_out(ep, plant, stations, now_s)
            if trains_at is not None:
                for payload in pack_states(plant.states(now_s)):
                    ep.send(wiring.wrap(payload, TRAINS_WIRING_ID, now_s), trains_at)
            return []

        await clock.run_live(step, poll, stop)
    return {
        **clock.timing(),
        **plant.counts(),
        "drive_lost": drive_lost,
        "delivered": wiring.delivered,
        "refused": _refused(wiring, refused_payloads),
        "trains": [{"train": v.k, "x_m": round(v.x_m, 2), "v_mps": round(v.v_mps, 3)} for v in plant.fleet],
    }


def _refused(wiring: SafePeers, payloads: int) -> dict[str, int]:
    """Frames refused by the safety layer, by reason, and those whose payload did not parse."""
    return {**wiring.rejected, **({"payload": payloads} if payloads else {})}


def _send_out(ep: UdpEndpoint, plant: Plant, stations: Address | None, now_s: float) -> None:
    """The trackside readings to the stations process, stamped as they leave."""
    for peer, payload in plant.outgoing:
        if stations is not None:
            ep.send(plant.sensors.wrap(payload, peer, now_s), stations)
    plant.outgoing.clear()


# ---------------------------------------------------------------------- the trains process's side


@dataclass
class PlantPort:
    """The trains process's side of the plant: the trains' states in, their drives out. With
    ``plant`` the plant runs in this process (stepped by :meth:`tick`); with ``address`` it is a
    process of its own (:meth:`serve` takes its frames; each TASC sensing is answered as it
    arrives)."""

    trains: int
    plant: Plant | None = None
    address: Address | None = None
    master_key: bytes = b""
    onboard: OnboardFn | None = None
    states: dict[int, TrainState] = field(default_factory=dict)
    ended: dict[int, TrainState] = field(default_factory=dict)
    heard_s: float = -math.inf
    lost: bool = False
    losses: int = 0
    started_s: float | None = None  # when this process started: frames sent before it are refused

    def __post_init__(self) -> None:
        self.wiring = SafePeers(
            TRAINS_WIRING_ID,
            self.master_key,
            max_age_s=1.0,
            peers=lambda p: p == PLANT_ID,
            started_s=self.started_s,
        )
        self.pending: list[DriveRecord] = []
        self.restarts = 0  # plants that came up fresh after one that knew the trains
        self.known = False  # the plant's last state knew where the trains are (not fresh)
        self.refused_payloads = 0
        self.ep: UdpEndpoint | None = None

    def _take(self, states: list[TrainState]) -> list[TrainState]:
        """The states of this process's trains, kept; a record for any other train is refused
        and counted (DESIGN rule 9: it would index no train)."""
        mine = [s for s in states if 0 <= s.train < self.trains]
        if len(mine) < len(states):
            self.wiring.reject("unknown_train")
        for s in mine:
            if s.fresh and self.known:
                self.restarts += 1  # a plant started again in the running line
            self.known = not s.fresh
            self.states[s.train] = s
            if s.ended:
                self.ended[s.train] = s
        return mine

    def drive(self, train: int, drive: Drive) -> None:
        if self.plant is not None:
            self.plant.drive(train, drive)
        else:
            self.pending.append((train, drive))

    def place(self, train: int, x_m: float) -> None:
        if self.plant is not None:
            self.plant.place(train, x_m)
        else:
            self.pending.append((train, Place(x_m)))

    def begin_tasc(self, train: int, station: int, visit: int) -> None:
        if self.plant is not None:
            self.plant.begin_tasc(train, station, visit)
        else:
            self.pending.append((train, (station, visit)))

    def tick(self, now_s: float, step_s: float, ep: UdpEndpoint, stations: Address | None) -> None:
        """The start of the trains process's step: in one process the plant's 10 ms steps over
        ``step_s`` (its trackside frames sent to ``stations``); between processes the check that
        the plant is still heard."""
        if self.plant is not None:
            for j in range(max(1, round(step_s / PLANT_STEP_S))):
                t = now_s + j * PLANT_STEP_S
                self.plant.step(t, self.onboard)
            self._take(self.plant.states(t))  # a stop's end is kept until it is told
            _send_out(ep, self.plant, stations, now_s)
            return
        lost = now_s - self.heard_s > SENSE_TIMEOUT_S
        if lost and not self.lost:
            self.losses += 1
        self.lost = lost

    def flush(self, now_s: float) -> None:
        """The end of the trains process's step: between processes, the drives to the plant."""
        if self.pending and self.address is not None and self.ep is not None:
            for payload in pack_drives(self.pending):
                self.ep.send(self.wiring.wrap(payload, PLANT_ID, now_s), self.address)
        self.pending.clear()

    async def serve(self, base: TimeBase, stop: asyncio.Event) -> None:
        """Between processes: take the plant's frames as they arrive; a train's TASC sensing is
        answered at once with its onboard unit's drive (the lock step)."""
        assert self.ep is not None and self.address is not None
        while not stop.is_set():
            got = await self.ep.recv(timeout_s=0.1)
            if got is None:
                continue
            now_s = base.now_s()
            ok = self.wiring.accept(got[0], now_s)
            if ok is None:
                continue
            try:
                states = unpack_states(ok[1].payload)
            except ValueError:
                self.refused_payloads += 1
                continue
            self.heard_s = now_s
            replies: list[DriveRecord] = []
            for s in self._take(states):
                if s.sense is not None and self.onboard is not None:
                    d = self.onboard(s.train, s.sense_t_s, s.sense)
                    if d is not None:
                        replies.append((s.train, d))
            for payload in pack_drives(replies) if replies else []:
                self.ep.send(self.wiring.wrap(payload, PLANT_ID, now_s), self.address)

    def counts(self) -> dict[str, Any]:
        return {
            "frames_received": self.wiring.delivered,
            "frames_sent": self.wiring.sent,
            "refused": _refused(self.wiring, self.refused_payloads),
            "plant_lost": self.losses,
            "plant_restarts": self.restarts,
        }
