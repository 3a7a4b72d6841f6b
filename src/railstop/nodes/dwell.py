"""The station dwell's door units by place (SPEC §5): the WPCS at the platform, the train's ATC /
CPCS on the train, each with its doors' own motion; the one wiring of the door units that the
dwell simulation (``sim.dwell``), the line and the live processes (``live.doors``) run.

The same pure units as the door verifier's wiring (``nodes.doors``), split where the door link
splits them:

* :class:`PlatformDoors` (one per station): the WPCS (``wayside.wpcs``) and the PSD units' own
  motion. It answers a train's PSC request only when the platform's stop sensors see that train
  standing inside the stop tolerance (SPEC §5: the transponder talks only inside the
  precise-stop zone; SPEC §3: the stop sensors), after ``wpcs_processing_s``. With PSC high,
  every ``door-command`` it receives runs one WPCS scan with the train's door signals, driving
  mode and locked train doors, and is answered by a ``psd-status`` (PSC, PSD closed and locked,
  start enable, WCC manual, fault, the open PSD units). The WCC (the control room) can switch it
  to manual and press the platform panel's open / close buttons (SPEC §5).
* :class:`TrainDoors` (one per dwell): precise-stop confirmation (``onboard.stop_confirm``), the
  CPCS (``onboard.cpcs``), the ATC's door sequence of automatic operation (SPEC §5: with PSC,
  DMC released and DOA, DOC given for the platform side; doors open, the dwell, then DMC and
  DCC) or the driver's selector and buttons in manual, the train doors' motion, the platform
  lamps and the position correction creep (SPEC §3), and start enable when a status frame
  reports the PSD closed and locked after the train's own doors are (SPEC §5 fig. 7).

Each end knows the other's doors only from the telegrams' bits
(``control.doors.units_from_link``). Both ends are pure: time is an argument, frames are what
the caller sends and delivers (:class:`DwellRun`: over a medium, or wired directly).

Fail safe (DESIGN rule 10): no reply to a PSC request is a train out of position (position
correction, then after the last attempt the SPEC §5 fault: emergency brake); with PSC high, no
valid status for ``supervision_timeout_s`` is a lost link (fault, emergency brake, doors held as
the CPCS's safe state holds them); the WPCS drops a train whose commands have stopped and holds
the PSD as it is (no exchange, no command: SPEC §5).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
from typing import Any, Generic, Protocol, TypeVar

import numpy as np

from railstop.config.doors import DoorsConfig
from railstop.control.doors import (
    LOCKED_STATES,
    DoorInput,
    DoorSignals,
    DoorState,
    PsdReport,
    Side,
    all_open,
    motion_s,
    summarise,
    units_from_link,
)
from railstop.errors import InterlockError
from railstop.link.codec import DoorCommand, PsdStatus
from railstop.link.door_link import Received, command_signals, door_command, psd_status
from railstop.nodes.doors import (
    DoorModel,
    platform_scan,
    psd_event,
    train_door_event,
    train_doors_locked,
    train_scan,
)
from railstop.onboard import cpcs, stop_confirm
from railstop.onboard.cpcs import CpcsState
from railstop.onboard.stop_confirm import StopConfirmState, StopInput, StopPhase
from railstop.streams import Stream, seed_u64
from railstop.wayside.wpcs import TrainReport, WpcsState, answers_psc

#: A stop-sensor reading older than this does not put a train in position.
SENSED_FRESH_S = 1.0
#: The step a dwell is simulated on (the live trains' plant step, ``live.cbtc.STEP_S``, the same).
DWELL_STEP_S = 0.05
#: A time due within this of a step's is due at that step (the steps' sums are not exact in binary).
_EPS_S = 1e-9


_V = TypeVar("_V")


class _Remade(Generic[_V]):
    """A value made by ``make`` from some inputs, made again only when the inputs differ from the
    last call's (a telegram or a report is a value: the units make one again only when what it
    carries has changed)."""

    __slots__ = ("_inputs", "_make", "_value")

    def __init__(self, make: Callable[..., _V]) -> None:
        self._make = make
        self._inputs: tuple[Any, ...] | None = None
        self._value: _V | None = None

    def __call__(self, *inputs: Any) -> _V:
        if self._value is None or self._inputs != inputs:
            self._value = self._make(*inputs)
            self._inputs = inputs
        return self._value


def model_for(doors: DoorsConfig) -> DoorModel:
    """The door model of the door data: its action table and PSC attempts."""
    return DoorModel(actions=doors.actions, max_psc_attempts=doors.stop_confirm.max_psc_attempts)


class DoorMotion:
    """The door units' own motion (the plant): a unit that begins opening, closing or locking
    finishes after the door data's time, unless it has moved on since (a stale completion); other
    physical events (a jam, the staff's isolation) are scheduled the same way (:meth:`schedule`)."""

    def __init__(self, doors: DoorsConfig, *, psd: bool) -> None:
        self.timing = doors.timing
        self.psd = psd
        self._gen: dict[Hashable, int] = {}
        self._pending: list[tuple[float, int, Hashable, int, DoorInput]] = []
        self._first_s = math.inf  # the earliest time in ``_pending``
        self._seq = 0

    def follow(self, key: Hashable, before: DoorState | None, after: DoorState, now_s: float) -> None:
        """``key`` went from ``before`` to ``after`` at ``now_s`` (``before`` None: it is in
        ``after`` already, its motion to be timed from now)."""
        if before == after:
            return
        self._gen[key] = self._gen.get(key, 0) + 1
        motion = motion_s(self.timing, after, psd=self.psd)
        if motion is not None:
            self.schedule(key, now_s + motion, DoorInput.DONE)

    def schedule(self, key: Hashable, at_s: float, inp: DoorInput) -> None:
        """``inp`` happens to ``key`` at ``at_s`` unless the unit moves on before."""
        self._seq += 1
        self._pending.append((at_s, self._seq, key, self._gen.get(key, 0), inp))
        self._first_s = min(self._first_s, at_s)

    def due(self, now_s: float) -> list[tuple[Hashable, DoorInput]]:
        """The events that have happened by ``now_s`` (in the order they happened)."""
        if self._first_s > now_s + _EPS_S:
            return []  # none yet (or none at all)
        done = sorted((p for p in self._pending if p[0] <= now_s + _EPS_S), key=lambda p: (p[0], p[1]))
        self._pending = [p for p in self._pending if p[0] > now_s + _EPS_S]
        self._first_s = min((p[0] for p in self._pending), default=math.inf)
        return [(key, inp) for _, _, key, gen, inp in done if self._gen.get(key, 0) == gen]


# ---------------------------------------------------------------------- the platform


class PlatformDoors:
    """One station's WPCS and PSD (SPEC §5), serving the train standing at its platform."""

    def __init__(self, *, index: int, name: str, side: Side, doors: DoorsConfig, model: DoorModel) -> None:
        self.index = index
        self.name = name
        self.doors = doors
        self.model = model
        self.state = WpcsState.closed(side, doors.doors_per_side)
        self.motion = DoorMotion(doors, psd=True)
        self.train: int | None = None  # the train PSC is high with
        self.asking: int | None = None  # the train whose PSC request is being answered
        self.answer_at_s = math.inf
        self.status_due_s = math.inf  # the next psd-status to the train PSC is high with
        self.sensed: dict[int, tuple[float, float]] = {}  # train -> (stop error, when read)
        self.last_cmd: DoorCommand | None = None
        self.last_cmd_s = -math.inf
        self.wcc_manual = False
        self.panel_open = False
        self.panel_close = False
        self.due: list[tuple[int, PsdStatus]] = []  # (train, status) to send now
        self.events: list[dict[str, Any]] = []  # for the office
        self.was_open = False
        self.jam_next: set[int] = set()  # fault injection: these PSD units jam on their next closing
        self.interlock_error: str | None = None  # the first input the WPCS did not allow
        self._settled: tuple[Any, ...] | None = None  # the last scan's inputs, when it changed nothing
        self._status = _Remade(
            lambda train, units, fault, psc, manual, locked: psd_status(
                train, units, fault=fault, psc=psc, manual=manual, locked=locked
            )
        )
        self.counts = {"psc_answered": 0, "psc_refused": 0, "links_lost": 0, "commands": 0, "other_train": 0}

    # -- inputs ---------------------------------------------------------------------
    def sense(self, train: int, error_m: float, now_s: float) -> None:
        """The stop sensors' reading of ``train`` (NaN: not standing in the platform)."""
        self.sensed[train] = (error_m, now_s)

    def in_position(self, train: int, now_s: float) -> bool:
        got = self.sensed.get(train)
        if got is None or now_s - got[1] > SENSED_FRESH_S or not math.isfinite(got[0]):
            return False
        return answers_psc(got[0], self.doors.stop_confirm.tolerance_m)

    def receive(self, cmd: DoorCommand, now_s: float) -> None:
        """A ``door-command`` from a train."""
        self.counts["commands"] += 1
        if self.train is not None and cmd.train_id != self.train:
            self.counts["other_train"] += 1  # PSC is high with another train: not this one's turn
            return
        if not cmd.psc:
            if self.train == cmd.train_id:
                self._end("psc-off", now_s)  # the train departs or moves to correct its stop
            if self.asking == cmd.train_id:
                self.asking, self.answer_at_s = None, math.inf
            return
        self.last_cmd, self.last_cmd_s = cmd, now_s
        if self.train is None:
            # SPEC §5: the WPCS answers only a train its stop sensors see in position.
            if self.asking is None:
                if self.in_position(cmd.train_id, now_s):
                    self.asking = cmd.train_id
                    self.answer_at_s = now_s + self.doors.link.wpcs_processing_s
                else:
                    self.counts["psc_refused"] += 1
            return
        self._scan(now_s)  # SPEC §5: the WPCS acts on the train's last frame; its status goes each cycle

    def wcc(self, *, manual: bool, panel_open: bool, panel_close: bool, now_s: float) -> None:
        """SPEC §5: the WCC switches the WPCS to manual (the platform panel's open / close buttons
        then stand for DOC and DCC) or back to automatic."""
        changed = manual != self.wcc_manual
        self.wcc_manual = manual
        self.panel_open, self.panel_close = manual and panel_open, manual and panel_close
        if changed:
            self._event("wcc-manual" if manual else "wcc-auto", now_s)
        if self.train is not None:
            self._scan(now_s)

    def tick(self, now_s: float) -> None:
        """The WPCS's own cycle: its PSC answer, the PSD's motion, the supervision of the train."""
        if self.asking is not None and now_s + _EPS_S >= self.answer_at_s:
            train, self.asking, self.answer_at_s = self.asking, None, math.inf
            if self.train is None and self.in_position(train, now_s):
                self.train = train
                self.counts["psc_answered"] += 1
                self._event("psc", now_s)
                self._scan(now_s)
                self.status_due_s = now_s  # the reply at once, then one status every exchange cycle
        for unit, inp in self.motion.due(now_s):
            assert isinstance(unit, int)
            before = self.state
            self.state, error = psd_event(self.state, unit, inp, self.model)
            if error is not None:
                self._interlock(error, now_s)
            self._follow(before, now_s)
            self._scan(now_s)
        if self.train is not None and now_s + _EPS_S >= self.status_due_s:
            # SPEC §5 (the door data's [link]): with PSC high, the platform sends its psd-status
            # every exchange cycle, as the train sends its door-command: a lost frame either way
            # costs one cycle, not the round trip.
            self.due.append((self.train, self.status()))
            self.status_due_s = now_s + self.doors.link.exchange_cycle_s
        if self.train is not None and now_s - self.last_cmd_s > self.doors.link.supervision_timeout_s:
            # The train's commands have stopped with PSC high: no exchange, the PSD held as it is.
            self.counts["links_lost"] += 1
            self._end("link-lost", now_s)

    # -- the unit -------------------------------------------------------------------
    def status(self) -> PsdStatus:
        """The ``psd-status`` of the platform now: the last one again when nothing it is made of
        has changed (a telegram is a value)."""
        return self._status(
            self.train if self.train is not None else 0,
            self.state.units,
            self.state.fault,
            self.train is not None,
            self.wcc_manual,
            self.model.interlocks.locked,
        )

    def _scan(self, now_s: float) -> None:
        cmd = self.last_cmd
        if self.train is None or cmd is None:
            return
        key = (self.state, cmd, self.wcc_manual, self.panel_open, self.panel_close)
        if key == self._settled:
            return  # the scan is pure, and on these inputs it left this state as it was
        n = len(self.state.units)
        train = TrainReport(
            signals=command_signals(cmd),
            manual=not cmd.automatic,
            doors=units_from_link(n, locked_mask=cmd.doors_locked),
        )
        before = self.state
        self.state, error = platform_scan(
            self.state,
            train,
            self.model,
            wcc_manual=self.wcc_manual,
            panel_open=self.panel_open,
            panel_close=self.panel_close,
        )
        if error is not None:  # DESIGN rule 10: the WPCS in its safe state, nothing opens, the train is told
            self._interlock(error, now_s)
        self._settled = key if error is None and self.state == before else None
        self._follow(before, now_s)

    def jam(self, unit: int) -> None:
        """Fault injection: PSD unit ``unit`` (0 = front) fails to close on its next closing; the
        station's staff isolate it ``staff_isolation_s`` later (closed and locked by hand), which
        then no longer withholds start enable (SPEC §3, §5; the door data's timings)."""
        if not 0 <= unit < len(self.state.units):
            raise ValueError(f"PSD unit {unit + 1}: {self.name} has units 1..{len(self.state.units)}")
        self.jam_next.add(unit)

    def _follow(self, before: WpcsState, now_s: float) -> None:
        t = self.doors.timing
        for i, (u0, u1) in enumerate(zip(before.units, self.state.units, strict=True)):
            if u1 == u0:
                continue  # (a unit that did not change: nothing for its motion to follow)
            self.motion.follow(i, u0, u1, now_s)
            if u1 == DoorState.CLOSING and i in self.jam_next:
                self.jam_next.discard(i)
                self.motion.schedule(i, now_s + t.psd_jam_at_s, DoorInput.JAM)
            elif u1 == DoorState.JAMMED:
                self._event("psd-jam", now_s, unit=i + 1)
                self.motion.schedule(i, now_s + t.staff_isolation_s, DoorInput.ISOLATE)
            elif u1 == DoorState.ISOLATED:
                self._event("psd-isolated", now_s, unit=i + 1)
        if all_open(self.state.units) and not self.was_open:
            self.was_open = True
            self._event("psd-open", now_s)
        elif self.was_open and all(u in LOCKED_STATES for u in self.state.units):
            self.was_open = False
            self._event("psd-locked", now_s)

    def _interlock(self, error: str, now_s: float) -> None:
        if self.interlock_error is None:
            self.interlock_error = error
        self._event("fault", now_s, error=error)

    def _end(self, why: str, now_s: float) -> None:
        self._event(why, now_s)
        self.train = None
        self.last_cmd = None
        self.status_due_s = math.inf

    def _event(self, what: str, now_s: float, **more: Any) -> None:
        self.events.append(
            {
                "st": self.name,
                "tr": self.train if self.train is not None else self.asking,
                "ev": what,
                "psd": summarise(self.state.units),
                "wcc": "manual" if self.wcc_manual else "auto",
                "t_s": round(now_s, 2),
                **more,
            }
        )


# ---------------------------------------------------------------------- the train


def dwell_entropy(seed: int, train_id: int, counter: int) -> list[int]:
    """The entropy of one dwell's generator (DESIGN rule 7): (seed, stream, train, dwell)."""
    return [int(seed_u64(seed)), int(Stream.DOOR_LINK), int(train_id), int(counter)]


def creep_rng(seed: int = 0, *, train_id: int = 1, counter: int = 0) -> np.random.Generator:
    """Where a dwell's correction creeps land (SPEC §5): a generator of (seed, train, dwell) only
    (the dwell's entropy and a 1; the door link of the same dwell draws from its counter-based
    streams, ``link.channel.LinkStreams``); the same in the dwell simulation, the line and the live
    trains process."""
    return np.random.default_rng(np.random.SeedSequence([*dwell_entropy(seed, train_id, counter), 1]))


@dataclass
class TrainDoors:
    """A train's dwell at one station (SPEC §5), in automatic operation (the ATC's door sequence) or
    ``manual`` (the driver's door-side selector and buttons, a ``driver_action_s`` after each cue),
    from the moment its wheels stop to start enable (or the fault): ``step`` each plant step; the
    ``door-command`` telegrams to send are queued in ``due``, the ``psd-status`` telegrams received
    go to ``receive``."""

    train: int
    station: int
    station_name: str
    side: Side
    error_m: float  # the stop error (+ = overrun); the correction creep changes it
    doors: DoorsConfig
    model: DoorModel
    t0_s: float
    stop: StopConfirmState = field(default_factory=StopConfirmState)
    carried: CpcsState | None = None  # the doors as an earlier dwell here left them (None: all locked)
    manual: bool = False  # driven by a driver (SPEC §5 manual column): his selector and buttons
    obstruct: int | None = None  # fault injection: this platform-side door (0 = front) is obstructed
    # Where each correction creep lands (normal(0, creep_stop_sd_m) about the stopping point), drawn
    # from this dwell's generator; None: the creep lands exactly (a unit's check, the verifiers).
    creep_rng: np.random.Generator | None = None
    cpcs: CpcsState = field(init=False)
    signals: DoorSignals = field(default_factory=DoorSignals)
    due: list[DoorCommand] = field(default_factory=list)
    moving: bool = False
    done: bool = False
    start_enable_s: float | None = None
    fault: str | None = None
    corrections: int = 0
    psc_requests: int = 0
    events: list[tuple[float, str]] = field(default_factory=list)
    link_lost: bool = False  # PSC was high and the status frames stopped (SPEC §5 fault path)
    lamp: str = "-"  # SPEC §3 platform lamps: F / R (correct forward / back), OK, S (start); - dark
    interlock_error: str | None = None  # the first input a unit did not allow

    def __post_init__(self) -> None:
        self.motion = DoorMotion(self.doors, psd=False)
        self.cpcs = CpcsState.closed(self.doors.doors_per_side)
        if self.carried is not None:
            self.cpcs = self.carried
            # Doors as an earlier dwell here left them (after its fault): a motion under way runs on.
            for side in (Side.L, Side.R):
                for i, u in enumerate(self.cpcs.side(side)):
                    self.motion.follow((side, i), None, u, self.t0_s)
        self.t = self.doors.timing
        self.link = self.doors.link
        self.standstill_at_s = self.t0_s + self.t.zero_speed_confirm_s
        self.psc_deadline_s = math.inf
        self.next_cmd_s = math.inf
        self.status: PsdStatus | None = None
        self.status_s = -math.inf
        self.doors_open = False
        self.dwell_end_s = math.inf
        self.closing = False
        self.creep_left_m = 0.0
        self.creep_dir = 0.0
        self.creep_pending = False
        self.creep_at_s = -math.inf  # the driver moves off this long after the lamp lights
        self.driver: list[tuple[float, dict[str, bool]]] = []  # the driver's actions to come
        self.settle_end_s = math.inf
        self._settled: tuple[Any, ...] | None = None  # the last scan's inputs, when it changed nothing
        self._command = _Remade(
            lambda train, signals, psc, automatic, doors, locked: door_command(
                train, signals, psc=psc, automatic=automatic, doors=doors, locked=locked
            )
        )
        # The PSD report of a status frame, made of these bits of it alone (``_psd``).
        self._psd_report = _Remade(self._make_psd_report)

    # -- inputs -------------------------------------------------------------------------
    def receive(self, status: PsdStatus, now_s: float) -> None:
        if status.train_id != self.train or not status.psc:
            return
        self.status, self.status_s = status, now_s
        if self.stop.phase == StopPhase.PSC_WAIT:
            self._stop_input(StopInput.PSC_REPLY, now_s)  # SPEC §5: the reply makes PSC high
            if self.stop.phase == StopPhase.CONFIRMED:
                if self.manual:
                    # SPEC §5: with PSC the ATC releases DMC (vital, both modes); the driver turns
                    # the door-side selector (DOA), then presses the open button (DOC).
                    self.signals = self.signals.with_side(self.side, dmc=False)
                    act = self.t.driver_action_s
                    self.driver.append((now_s + act, {"doa": True}))
                    self.driver.append((now_s + 2 * act, {"doc": True}))
                else:
                    # SPEC §5: with PSC the ATC releases DMC on the platform side and gives DOA, DOC.
                    self.signals = self.signals.with_side(self.side, dmc=False, doa=True)._replace(doc=True)
        self._scan(now_s)

    @property
    def emergency_brake(self) -> bool:
        return self.stop.phase == StopPhase.FAULT or self.cpcs.fault

    @property
    def phase(self) -> str:
        """Where the dwell is, in a word: the confirmation's phase, or doors open / closing."""
        if self.fault is not None:
            return "fault"
        if self.closing:
            return "closing"
        if self.doors_open:
            return "doors-open"
        return self.stop.phase.value

    @property
    def creep_mps(self) -> float:
        """The correction creep's speed (signed, + = forward), 0 when the train stands."""
        return self.creep_dir * self.doors.stop_confirm.creep_speed_mps if self.creep_left_m > 0.0 else 0.0

    # -- the cycle ----------------------------------------------------------------------
    def step(self, now_s: float, step_s: float) -> float:
        """One plant step; returns how far the train moved (the correction creep, + = forward)."""
        if self.done:
            return 0.0
        moved = 0.0
        if self.creep_left_m > 0.0:
            d = min(self.creep_left_m, self.doors.stop_confirm.creep_speed_mps * step_s)
            self.creep_left_m -= d
            moved = self.creep_dir * d
            self.error_m += moved
            if self.creep_left_m <= 0.0:
                self.settle_end_s = now_s + self.doors.stop_confirm.creep_settle_s
        if now_s + _EPS_S >= self.settle_end_s:
            self.settle_end_s = math.inf
            self.moving = False
            self.standstill_at_s = now_s + self.t.zero_speed_confirm_s
        if now_s + _EPS_S >= self.standstill_at_s:
            self.standstill_at_s = math.inf
            self._stop_input(StopInput.STANDSTILL, now_s)
        phase = self.stop.phase
        if phase == StopPhase.PSC_WAIT and now_s + _EPS_S >= self.psc_deadline_s:
            self._stop_input(StopInput.PSC_TIMEOUT, now_s)  # no reply: not in position
        elif phase == StopPhase.CONFIRMED and now_s - self.status_s > self.link.supervision_timeout_s:
            self.link_lost = True
            self._stop_input(StopInput.LINK_LOST, now_s)
        for key, inp in self.motion.due(now_s):
            assert isinstance(key, tuple)
            side, unit = key
            before = self.cpcs
            self.cpcs, error = train_door_event(self.cpcs, side, unit, inp, self.model)
            if error is not None:
                self._interlock(error, now_s)
            self._follow(before, now_s)
        if now_s + _EPS_S >= self.dwell_end_s:
            self.dwell_end_s = math.inf
            self.closing = True
            if self.manual:
                # The driver: door-side selector off and the close button (the manual column).
                self.signals = self.signals.with_side(self.side, doa=False)._replace(dcc=True)
            else:
                self.signals = self.signals.with_side(self.side, dmc=True)._replace(dcc=True)  # SPEC §5
            self._note(now_s, "close")
        while self.driver and self.driver[0][0] <= now_s + _EPS_S:
            _, changes = self.driver.pop(0)
            s = self.signals
            for name, value in changes.items():
                s = s.with_side(self.side, doa=value) if name == "doa" else s._replace(**{name: value})
            self.signals = s
        self._scan(now_s)
        self._react(now_s)
        if self.creep_pending and now_s + _EPS_S >= self.creep_at_s:
            self._start_creep()
        if self.stop.phase in (StopPhase.PSC_WAIT, StopPhase.CONFIRMED) and now_s >= self.next_cmd_s:
            self.due.append(self.command())
            self.next_cmd_s = now_s + self.link.exchange_cycle_s - 1e-9
        return moved

    def command(self, *, psc: bool | None = None) -> DoorCommand:
        """The ``door-command`` of the train now: the last one again when nothing it is made of has
        changed (a telegram is a value)."""
        return self._command(
            self.train,
            self.signals,
            self.stop.phase in (StopPhase.PSC_WAIT, StopPhase.CONFIRMED) if psc is None else psc,
            not self.manual,
            self.cpcs.side(self.side),
            self.model.interlocks.locked,
        )

    # -- inside -------------------------------------------------------------------------
    def _psd(self, now_s: float) -> PsdReport | None:
        """SPEC §5: the PSD state reaches the train only over the link, and only while PSC is high."""
        st = self.status
        if self.stop.phase != StopPhase.CONFIRMED or st is None:
            return None
        # The report is made of these bits of the frame alone (and the doors per side, fixed).
        return self._psd_report(len(self.cpcs.side(self.side)), st.psd_open, st.psd_closed_locked, st.fault)

    def _make_psd_report(self, n: int, psd_open: int, closed_locked: bool, fault: bool) -> PsdReport:
        locked_mask = (1 << n) - 1 if closed_locked else 0
        units = units_from_link(n, open_mask=psd_open, locked_mask=locked_mask)
        return PsdReport(side=self.side, units=units, fault=fault)

    def _scan(self, now_s: float) -> None:
        psd = self._psd(now_s)
        key = (self.cpcs, self.signals, self.manual, self.moving, psd)
        if key == self._settled:
            return  # the scan is pure, and on these inputs it left this state as it was
        before = self.cpcs
        self.cpcs, error = train_scan(
            self.cpcs, self.signals, self.model, manual=self.manual, moving=self.moving, psd=psd
        )
        if error is not None:  # the CPCS in its safe state: doors held closed, emergency brake
            self._interlock(error, now_s)
        self._settled = key if error is None and self.cpcs == before else None
        self._follow(before, now_s)

    def _follow(self, before: CpcsState, now_s: float) -> None:
        if before == self.cpcs:
            return
        t = self.t
        for side in (Side.L, Side.R):
            for i, (u0, u1) in enumerate(zip(before.side(side), self.cpcs.side(side), strict=True)):
                if u0 == u1:
                    continue  # (a door that did not change: nothing for its motion to follow)
                self.motion.follow((side, i), u0, u1, now_s)
                if side != self.side:
                    continue
                # Fault injection: an obstacle in the closing door (once); the door reopens and holds
                # until it is cleared (the door data's times), withholding start enable meanwhile.
                if u1 == DoorState.CLOSING and i == self.obstruct:
                    self.obstruct = None
                    self.motion.schedule((side, i), now_s + t.obstruction_at_s, DoorInput.OBSTRUCT)
                elif u1 == DoorState.OBSTRUCTED:
                    self._note(now_s, f"door {i + 1} obstructed")
                    self.motion.schedule((side, i), now_s + t.obstruction_clear_s, DoorInput.CLEAR)

    def _stop_input(self, inp: StopInput, now_s: float) -> None:
        was = self.stop.phase
        try:
            self.stop = stop_confirm.step(
                self.stop, inp, max_attempts=self.model.max_psc_attempts, table=self.model.stop
            )
        except InterlockError as exc:
            self.stop = stop_confirm.safe(self.stop)
            self._interlock(str(exc), now_s)
            return
        phase = self.stop.phase
        if phase == was:
            return
        if phase == StopPhase.FAULT:
            # SPEC §5: the attempts used up (or the link lost with PSC high): fault, emergency brake.
            self._fail(f"stop confirmation: {inp.value} in phase {was.value}", now_s)
            return
        self._note(now_s, phase.value)
        if phase == StopPhase.CONFIRMED:
            self.lamp = "OK"  # SPEC §3: in position
        if phase == StopPhase.PSC_WAIT:
            # SPEC §5: standstill confirmed -> PSC request; no reply within the time-out = not in
            # position.
            self.psc_requests += 1
            self.psc_deadline_s = now_s + self.t.psc_timeout_s
            self.next_cmd_s = now_s
        elif phase == StopPhase.CORRECTING:
            # SPEC §3 lamps F / R: a short creep towards the stopping point, at most creep_max_m.
            self.due.append(self.command(psc=False))
            self.lamp = "F" if self.error_m < 0.0 else "R"  # SPEC §3: stopped short / passed
            self.corrections += 1
            self.creep_pending = True
            # SPEC §3 lamps: the driver moves off a moment after the lamp lights; the ATC at once.
            self.creep_at_s = now_s + (self.t.driver_action_s if self.manual else 0.0)

    def _start_creep(self) -> None:
        """SPEC §3 lamps F / R: a short creep towards the stopping point, at most creep_max_m, once
        every train door is closed and locked (the traction interlock of ``nodes.doors``); the
        ATC closes any door still open first (DMC and DCC)."""
        if not train_doors_locked(self.cpcs, self.model):
            self.signals = self.signals.with_side(Side.L, dmc=True, doa=False)
            self.signals = self.signals.with_side(Side.R, dmc=True, doa=False)._replace(doc=False, dcc=True)
            return
        self.creep_pending = False
        self.signals = self.signals._replace(dcc=False)
        self.moving = True
        self.creep_dir = -1.0 if self.error_m > 0.0 else 1.0
        creep = min(abs(self.error_m), self.doors.stop_confirm.creep_max_m)
        sd = self.doors.stop_confirm.creep_stop_sd_m
        if self.creep_rng is not None and sd > 0.0:
            # SPEC §5: the creep is a short stop of its own and lands with a stop's inaccuracy
            # (short of its aim or past it; a creep that would not move at all barely moves).
            creep += float(self.creep_rng.normal(0.0, sd))
        self.creep_left_m = max(creep, 1e-6)

    def _react(self, now_s: float) -> None:
        if self.done or self.stop.phase != StopPhase.CONFIRMED:
            return
        if not self.doors_open and all_open(self.cpcs.side(self.side)):
            # Doors open: the ATC drops DOC; the dwell runs.
            self.doors_open = True
            self.signals = self.signals._replace(doc=False)
            self.dwell_end_s = now_s + self.t.dwell_s
            self._note(now_s, "doors-open")
        st = self.status
        ready = self.closing and cpcs.start_enabled(
            self.cpcs, self._psd(now_s), psc=True, emergency_brake=self.emergency_brake,
            interlocks=self.model.interlocks,
        )  # fmt: skip
        if ready and st is not None and st.psd_closed_locked and st.start_enable:
            # SPEC §5 fig. 7: start enable; the door commands are released, PSC dropped.
            self.start_enable_s = now_s
            self.lamp = "S"  # start
            if self.manual:
                # The door commands released; the ATC raises DMC again for the run.
                self.signals = self.signals.with_side(self.side, dmc=True)._replace(dcc=False)
            else:
                self.signals = self.signals.with_side(self.side, doa=False)._replace(dcc=False)
            self._stop_input(StopInput.DEPART, now_s)
            self.due.append(self.command(psc=False))
            self.done = True
            self._note(now_s, "start-enable")

    def _interlock(self, error: str, now_s: float) -> None:
        """An input a unit did not allow (it is in its safe state now): the dwell's fault."""
        if self.interlock_error is None:
            self.interlock_error = error
        self._fail(error, now_s)

    def _fail(self, why: str, now_s: float) -> None:
        if self.fault is None:
            self.fault = why
            self.done = True
            self._note(now_s, "fault")

    def _note(self, now_s: float, what: str) -> None:
        self.events.append((round(now_s - self.t0_s, 2), what))

    def result(self) -> dict[str, Any]:
        """The dwell as the office stores it."""
        return {
            "station": self.station_name,
            "train": self.train,
            "outcome": "start-enable"
            if self.start_enable_s is not None
            else "fault"
            if self.fault
            else "running",
            "psc_requests": self.psc_requests,
            "corrections": self.corrections,
            "error_m": round(self.error_m, 3),
            "dwell_s": None if self.start_enable_s is None else round(self.start_enable_s - self.t0_s, 2),
            "fault": self.fault,
        }


def dwell_ends(
    doors: DoorsConfig,
    *,
    station: str,
    side: Side,
    error_m: float,
    train_id: int = 1,
    manual: bool = False,
    obstruct: int | None = None,
    psd_jam: int | None = None,
    model: DoorModel | None = None,
    creep: np.random.Generator | None = None,
) -> tuple[TrainDoors, PlatformDoors]:
    """The two ends of one dwell at a platform of its own, from the stand (t = 0): the train
    ``train_id`` standing ``error_m`` from the stopping point, in ``manual`` or automatic; fault
    injection, each a unit on the platform side numbered from 1 (the front): ``obstruct`` a train
    door obstructed while closing, ``psd_jam`` a PSD unit that fails to close; ``creep``: where the
    correction creeps land (None: exactly)."""
    model = model or model_for(doors)
    platform = PlatformDoors(index=0, name=station, side=side, doors=doors, model=model)
    if psd_jam is not None:
        platform.jam(psd_jam - 1)
    train = TrainDoors(
        train=train_id,
        station=0,
        station_name=station,
        side=side,
        error_m=error_m,
        doors=doors,
        model=model,
        t0_s=0.0,
        manual=manual,
        obstruct=None if obstruct is None else obstruct - 1,
        creep_rng=creep,
    )
    return train, platform


def wired_dwell(
    doors: DoorsConfig,
    *,
    error_m: float,
    side: Side = Side.R,
    step_s: float = 0.05,
    platform_silent_after_s: float = math.inf,
    wcc: tuple[tuple[float, bool, bool, bool], ...] = (),
    psd_jam: int | None = None,
    manual: bool = False,
    obstruct: int | None = None,
    until_s: float = 600.0,
    seed: int = 0,
) -> tuple[TrainDoors, PlatformDoors]:
    """One dwell with the train's end and the platform's wired directly in this process, each
    frame delivered at the next step (the live units' check against the dwell simulation): the
    platform falls silent after ``platform_silent_after_s`` (its process died); ``wcc``: the WCC's
    actions, each (at_s, manual, panel_open, panel_close); ``psd_jam``: this PSD unit (1 = front) fails
    to close; the correction creeps land as the dwell simulation's of ``seed`` (train 1)."""
    train, platform = dwell_ends(
        doors, station="P", side=side, error_m=error_m, manual=manual, obstruct=obstruct, psd_jam=psd_jam,
        creep=creep_rng(seed, train_id=1),
    )  # fmt: skip
    run_wired(
        train,
        platform,
        t0_s=0.0,
        step_s=step_s,
        until_s=until_s,
        platform_silent_after_s=platform_silent_after_s,
        wcc=wcc,
    )
    return train, platform


class DoorCarrier(Protocol):
    """What carries the door telegrams between the two ends: the simulated door link
    (``link.door_link.DoorLink``: codec, safety layer and a medium) or :class:`Wired`."""

    def send_command(self, msg: DoorCommand, now_s: float) -> None: ...
    def send_status(self, msg: PsdStatus, now_s: float) -> None: ...
    def deliver(self, now_s: float) -> list[Received]: ...
    def next_arrival_s(self) -> float | None: ...


class Wired:
    """The two ends wired directly: every telegram delivered at the next step, none lost."""

    def __init__(self) -> None:
        self._up: list[DoorCommand] = []
        self._down: list[PsdStatus] = []

    def send_command(self, msg: DoorCommand, now_s: float) -> None:
        self._up.append(msg)

    def send_status(self, msg: PsdStatus, now_s: float) -> None:
        self._down.append(msg)

    def deliver(self, now_s: float) -> list[Received]:
        out = [Received(to="platform", telegram=m, at_s=now_s) for m in self._up]
        out += [Received(to="train", telegram=m, at_s=now_s) for m in self._down]
        self._up, self._down = [], []
        return out

    def next_arrival_s(self) -> float | None:
        return None if not (self._up or self._down) else -math.inf  # at the next step


class DwellRun:
    """One dwell's two ends stepped on one clock (DESIGN rule 1: the simulation's and the line's
    dwell, and the live units' check): each step the telegrams that have arrived are delivered,
    the train's end steps (its creep, doors, confirmation; ``observe(t_s, moved_m)`` after it),
    the platform reads its stop sensors, takes the train's commands and runs its cycle, and what
    each end sends goes onto ``carrier``.

    ``platform_silent_after_s``: the platform (its process) dies then; ``wcc``: the WCC's actions,
    each (at_s, manual, panel_open, panel_close)."""

    def __init__(
        self,
        train: TrainDoors,
        platform: PlatformDoors,
        carrier: DoorCarrier,
        *,
        t0_s: float,
        step_s: float,
        platform_silent_after_s: float = math.inf,
        wcc: tuple[tuple[float, bool, bool, bool], ...] = (),
        observe: Callable[[float, float], None] | None = None,
    ) -> None:
        if not (math.isfinite(step_s) and step_s > 0.0):
            raise ValueError(f"step_s: a positive number of seconds (got {step_s!r})")
        self.train, self.platform, self.carrier = train, platform, carrier
        self.t_s, self.step_s = t0_s, step_s
        self.silent_after_s = platform_silent_after_s
        self.actions = sorted(wcc)
        self.observe = observe

    @property
    def complete(self) -> bool:
        """The train's dwell has ended and nothing is in flight (its last frame, PSC off, is in)."""
        return self.train.done and self.carrier.next_arrival_s() is None

    def step(self) -> None:
        t, train, platform = self.t_s, self.train, self.platform
        got = self.carrier.deliver(t)
        for r in got:
            if r.to == "train" and isinstance(r.telegram, PsdStatus):
                train.receive(r.telegram, t)
        moved = train.step(t, self.step_s)
        if self.observe is not None:
            self.observe(t, moved)
        if t < self.silent_after_s:
            while self.actions and self.actions[0][0] <= t:
                _, manual, panel_open, panel_close = self.actions.pop(0)
                platform.wcc(manual=manual, panel_open=panel_open, panel_close=panel_close, now_s=t)
            # SPEC §3 stop sensors: the train's stop error while it stands, none while it moves.
            platform.sense(train.train, math.nan if train.moving else train.error_m, t)
            for r in got:
                if r.to == "platform" and isinstance(r.telegram, DoorCommand):
                    platform.receive(r.telegram, t)
            platform.tick(t)
            for _, status in platform.due:
                self.carrier.send_status(status, t)
        platform.due.clear()
        for cmd in train.due:
            self.carrier.send_command(cmd, t)
        train.due.clear()
        self.t_s = round(t + self.step_s, 9)


def run_wired(
    train: TrainDoors,
    platform: PlatformDoors,
    *,
    t0_s: float,
    step_s: float,
    until_s: float,
    platform_silent_after_s: float = math.inf,
    wcc: tuple[tuple[float, bool, bool, bool], ...] = (),
    observe: Callable[[float, float], None] | None = None,
) -> None:
    """Step ``train`` and ``platform`` wired directly (:class:`Wired`) from ``t0_s`` until the dwell
    has ended and the train's last frame is delivered, or ``until_s``."""
    run = DwellRun(
        train, platform, Wired(), t0_s=t0_s, step_s=step_s, platform_silent_after_s=platform_silent_after_s,
        wcc=wcc, observe=observe,
    )  # fmt: skip
    while not run.complete and run.t_s < until_s:
        run.step()
