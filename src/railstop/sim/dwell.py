"""A station dwell in event time: arrival -> PSC -> open -> dwell -> close -> start enable.

The driver wires the pure door units (through ``nodes/doors.step``, the
same wiring the verifier proves) to a clock and to the people who act on
them: the ATC's door sequence in automatic mode, the driver's door-side
selector and buttons in manual mode (SPEC §5), the doors' own motion times,
an obstacle, a PSD unit that fails to close and the staff who isolate it.
Every duration comes from ``railstop/data/doors.toml``.

The train and the platform talk over the door link of SPEC §5
(:class:`~railstop.link.door_link.DoorLink`: codec + EN 50159 safety layer +
a medium of ``media.toml``, the ``[link]`` section of the door data). From
the PSC request on, each end sends its telegram every exchange cycle: the
train a ``door-command`` (its door signals, PSC requested or held), the
platform, once it has answered, a ``psd-status`` (PSC, PSD closed and locked,
start enable). So:

* PSC goes high when the WPCS's reply *arrives*: a request whose replies are
  all lost (or never sent: the WPCS answers only a train its stop sensors see
  in position) times out like a train out of position (SPEC §5);
* with PSC high, the train supervises the status frames: none valid for
  ``supervision_timeout_s`` is a lost link, fault and emergency brake
  ([interpretation], see ``onboard/stop_confirm.py``);
* start enable is given when a status frame reports the PSD closed and locked
  after the train's own doors are (SPEC §5 fig. 7: the PSD state reaches the
  train over the link, and counts only while PSC is high);
* the WPCS acts on the train's last ``door-command`` frame (its door signals,
  its mode, which of its doors are closed and locked), scanning as each one
  arrives: the PSD opens and closes on what the link carried, a lost frame
  delays it, and before the first frame the platform knows no door signal and
  no door locked (the most restrictive view).

Nothing here reads a clock: time is a number the driver advances from one
scheduled event to the next, and the result is a timeline of
``(t_s, signal, value)`` events.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from railstop.config.doors import DoorsConfig
from railstop.control.doors import (
    DoorInput,
    DoorSignals,
    DoorState,
    Side,
    all_open,
    motion_s,
    summarise,
    units_from_link,
)
from railstop.errors import ConfigError, SimulationError
from railstop.link.channel import media_preset
from railstop.link.codec import DoorCommand, PsdStatus
from railstop.link.door_link import DoorLink, DoorLinkCounts, command_signals, door_command, psd_status
from railstop.nodes.doors import (
    Controls,
    DoorModel,
    Event,
    EventKind,
    World,
    emergency_brake,
    psc,
    start_blockers,
    start_enabled,
    step,
)
from railstop.onboard.stop_confirm import StopPhase
from railstop.streams import Stream, seed_u64
from railstop.wayside.wpcs import TrainReport, answers_psc

MODES = ("auto", "manual")
_MAX_CYCLES = 100_000
_MAX_T_S = 3600.0

# The signals of the timeline, in the order they are logged at one instant.
SIGNALS: tuple[str, ...] = (
    "speed_mps",
    "ZVR",
    "stop_error_m",
    "lamp",
    "PSC_request",
    "PSC",
    "creep",
    "DMC-L",
    "DMC-R",
    "DOA-L",
    "DOA-R",
    "DOC",
    "DCC",
    "PSD",
    "train_doors-L",
    "train_doors-R",
    "start_blocked",
    "start_enable",
    "fault",
    "emergency_brake",
    "interlock_error",
    "link",
)


@dataclass(frozen=True, slots=True, kw_only=True)
class DwellEvent:
    t_s: float
    signal: str
    value: int | float | str


@dataclass(frozen=True, slots=True, kw_only=True)
class DwellResult:
    station: str
    platform_side: str
    mode: str
    stop_error_m: float  # where the train first stopped (+ = overrun)
    final_stop_error_m: float  # after the corrections
    tolerance_m: float
    in_tolerance: bool  # the first stop
    psc_attempts: int
    corrections: int
    fault: bool
    emergency_brake: bool
    start_enable_s: float | None
    dwell_total_s: float  # arrival to start enable (or to the fault / the last event)
    outcome: str  # "start-enable" | "fault" | "stalled"
    timeline: tuple[DwellEvent, ...]
    obstruct_door: int | None = None
    psd_fail: int | None = None
    link: DoorLinkCounts | None = None

    def summary(self) -> dict[str, Any]:
        return {
            "station": self.station,
            "platform_side": self.platform_side,
            "mode": self.mode,
            "stop_error_m": self.stop_error_m,
            "final_stop_error_m": self.final_stop_error_m,
            "tolerance_m": self.tolerance_m,
            "in_tolerance": self.in_tolerance,
            "psc_attempts": self.psc_attempts,
            "corrections": self.corrections,
            "fault": self.fault,
            "emergency_brake": self.emergency_brake,
            "start_enable_s": self.start_enable_s,
            "dwell_total_s": self.dwell_total_s,
            "outcome": self.outcome,
            "obstruct_door": self.obstruct_door,
            "psd_fail": self.psd_fail,
            "link": None if self.link is None else self.link.summary(),
            "timeline": [{"t_s": e.t_s, "signal": e.signal, "value": e.value} for e in self.timeline],
        }


def model_for(doors: DoorsConfig) -> DoorModel:
    return DoorModel(actions=doors.actions, max_psc_attempts=doors.stop_confirm.max_psc_attempts)


def make_door_link(
    doors: DoorsConfig,
    *,
    seed: int = 0,
    train_id: int = 1,
    counter: int = 0,
    loss_probability: float | None = None,
    outage: tuple[float, float] | None = None,
) -> DoorLink:
    """The door link of the door data's ``[link]`` section for one dwell.

    Its random generator is a function of (seed, stream, train, counter) only
    (DESIGN rule 7): ``counter`` numbers the dwells of one train.
    ``loss_probability`` overrides the medium's per-frame loss (both ways);
    ``outage`` = (start_s, end_s) loses every frame sent in between (fault injection).
    """
    cfg = doors.link
    try:
        params = media_preset(cfg.medium)
    except ConfigError as exc:  # the bad name is in the door data, not in the media file
        raise ConfigError(doors.source, "link.medium", exc.message, cfg.medium) from None
    if loss_probability is not None:
        params = params.replace(loss_probability=loss_probability)
    entropy = [int(seed_u64(seed)), int(Stream.DOOR_LINK), int(train_id), int(counter)]
    return DoorLink(
        params=params,
        rng=np.random.default_rng(np.random.SeedSequence(entropy)),
        train_id=train_id,
        category=cfg.category,
        max_age_s=cfg.max_age_s,
        timeout_s=cfg.supervision_timeout_s,
        outage=outage,
    )


class SteppedDwell:
    """One dwell from a train that has just stopped ``stop_error_m`` from its stopping point, driven
    by a caller's clock (:meth:`advance_to`, the dwell's time: 0 at the stand; DESIGN rule 1);
    :func:`run_dwell` runs it to its end at once (as the line still does, when the train stands).

    ``obstruct_door`` / ``psd_fail``: the train door / PSD unit (1 = front) on
    the platform side that is obstructed while closing (cleared later) / fails
    to close (isolated by staff later). ``link``: the door link to use (its
    time starts at the stop); default the door data's link drawn from ``seed``.
    """

    def __init__(
        self,
        *,
        doors: DoorsConfig,
        station: str,
        platform_side: Side | str,
        stop_error_m: float,
        mode: str = "auto",
        obstruct_door: int | None = None,
        psd_fail: int | None = None,
        model: DoorModel | None = None,
        link: DoorLink | None = None,
        seed: int = 0,
    ) -> None:
        if mode not in MODES:
            raise SimulationError(f"mode: must be one of {', '.join(MODES)} (got {mode!r})")
        if not math.isfinite(stop_error_m):
            raise SimulationError(f"stop_error_m: must be a finite number (got {stop_error_m!r})")
        side = Side(platform_side)
        n = doors.doors_per_side
        for name, unit in (("obstruct_door", obstruct_door), ("psd_fail", psd_fail)):
            if unit is not None and not 1 <= unit <= n:
                raise SimulationError(f"{name}: door units are numbered 1..{n} (got {unit})")
        self._doors, self._station, self._side, self._mode = doors, station, side, mode
        self._stop_error_m, self._obstruct_door, self._psd_fail = stop_error_m, obstruct_door, psd_fail
        self._run = _Dwell(
            doors=doors,
            model=model or model_for(doors),
            side=side,
            stop_error_m=stop_error_m,
            manual=mode == "manual",
            obstruct=None if obstruct_door is None else obstruct_door - 1,
            psd_fail=None if psd_fail is None else psd_fail - 1,
            link=link if link is not None else make_door_link(doors, seed=seed),
        )
        self._run.start()
        self._closed = False

    def advance_to(self, t_s: float) -> bool:
        """Every event of the dwell due by ``t_s`` (0: the stand); whether the dwell has ended."""
        return self._run.advance_to(t_s)

    @property
    def ended(self) -> bool:
        return self._run.ended

    @property
    def error_m(self) -> float:
        """Where the train stands now from its stopping point (after the corrections so far)."""
        return self._run.error_m

    def result(self) -> DwellResult:
        """The dwell's result (once it has ended; before, as far as it has come)."""
        run = self._run
        if run.ended and not self._closed:
            run._log()  # the last instant of the timeline
            self._closed = True
        w = run.world
        if run.start_enable_s is not None:
            outcome = "start-enable"
        elif w.stop.phase == StopPhase.FAULT:
            outcome = "fault"
        else:
            outcome = "stalled"
        tolerance = self._doors.stop_confirm.tolerance_m
        return DwellResult(
            station=self._station,
            platform_side=self._side.value,
            mode=self._mode,
            stop_error_m=self._stop_error_m,
            final_stop_error_m=round(run.error_m, 6),
            tolerance_m=tolerance,
            in_tolerance=answers_psc(self._stop_error_m, tolerance),
            psc_attempts=run.psc_requests,
            corrections=run.corrections,
            fault=w.stop.phase == StopPhase.FAULT or w.cpcs.fault or w.wpcs.fault,
            emergency_brake=emergency_brake(w),
            start_enable_s=run.start_enable_s,
            dwell_total_s=_r(run.end_s),
            outcome=outcome,
            timeline=tuple(run.timeline),
            obstruct_door=self._obstruct_door,
            psd_fail=self._psd_fail,
            link=run.link.counts,
        )


def run_dwell(
    *,
    doors: DoorsConfig,
    station: str,
    platform_side: Side | str,
    stop_error_m: float,
    mode: str = "auto",
    obstruct_door: int | None = None,
    psd_fail: int | None = None,
    model: DoorModel | None = None,
    link: DoorLink | None = None,
    seed: int = 0,
) -> DwellResult:
    """Simulate one dwell to its end at once (:class:`SteppedDwell`, its arguments)."""
    dwell = SteppedDwell(
        doors=doors, station=station, platform_side=platform_side, stop_error_m=stop_error_m, mode=mode,
        obstruct_door=obstruct_door, psd_fail=psd_fail, model=model, link=link, seed=seed,
    )  # fmt: skip
    dwell.advance_to(math.inf)
    return dwell.result()


def _r(t_s: float) -> float:
    return round(t_s, 3)


@dataclass(order=True)
class _Pending:
    t_s: float
    seq: int
    action: str = field(compare=False)
    args: tuple[Any, ...] = field(compare=False, default=())


class _Dwell:
    def __init__(
        self,
        *,
        doors: DoorsConfig,
        model: DoorModel,
        side: Side,
        stop_error_m: float,
        manual: bool,
        obstruct: int | None,
        psd_fail: int | None,
        link: DoorLink,
    ) -> None:
        self.cfg = doors
        self.link = link
        self.lcfg = doors.link
        self.timing = doors.timing
        self.sc = doors.stop_confirm
        self.model = model
        self.side = side
        self.manual = manual
        self.obstruct = obstruct
        self.psd_fail = psd_fail
        self.error_m = stop_error_m
        self.world = World.arriving(platform_side=side, doors_per_side=doors.doors_per_side)
        # The platform knows the train only from its door-command frames: nothing yet (no door
        # signal, no door known locked: the most restrictive view).
        self.controls = Controls(
            signals=DoorSignals(),
            manual=manual,
            platform_view=TrainReport(
                signals=DoorSignals(),
                manual=manual,
                doors=units_from_link(doors.doors_per_side, locked_mask=0),
            ),
        )
        self.t_s = 0.0
        self.end_s = 0.0
        self.cycles = 0
        self.queue: list[_Pending] = []
        self.seq = 0
        self.timeline: list[DwellEvent] = []
        self.last: dict[str, int | float | str] = {}
        self.last_key: tuple[Any, ...] | None = None
        self.gen: dict[tuple[str, int], int] = {}
        self.speed_mps = 0.0
        self.creep = "-"
        self.lamp = "-"
        self.corrections = 0
        self.doors_open = False
        self.closing = False
        self.start_enable_s: float | None = None
        self.done = False
        self.injected: set[str] = set()
        self.interlock_error = "-"
        # The door link (SPEC §5): the exchange runs while PSC is requested or high.
        self.exchanging = False
        self.link_state = "-"
        self.platform_psc = False  # the WPCS has answered this train's PSC request
        self.platform_answering = False
        self.arrivals: set[float] = set()  # "arrive" wake-ups already scheduled
        self.start_ready = False  # the train's own start conditions hold; waiting for the PSD status
        self.psc_requests = 0

    # -- the loop -------------------------------------------------------------
    def start(self) -> None:
        """The train has just stood (t = 0): the ZVR confirms standstill a moment later."""
        self._log()
        self._at(self.timing.zero_speed_confirm_s, "standstill")
        self.cycles = 0

    @property
    def ended(self) -> bool:
        """Start enable, the fault, or nothing left to happen (stalled)."""
        return self.done or not self.queue

    def advance_to(self, t_s: float) -> bool:
        """Every event due by ``t_s`` (the dwell's clock: 0 at the stand); whether it has ended."""
        while self.queue and not self.done and self.queue[0].t_s <= t_s:
            item = heapq.heappop(self.queue)
            if item.t_s > self.t_s:
                # Log once per instant, what the signals settled to: the reactions at the
                # same instant (e.g. the ATC's door signals when PSC rises) are one moment.
                self._log()
            self.t_s = item.t_s
            if self.t_s > _MAX_T_S or self.cycles > _MAX_CYCLES:
                raise SimulationError(f"the dwell did not end within {_MAX_T_S:g} s")
            self.cycles += 1
            getattr(self, f"_on_{item.action}")(*item.args)
            self.end_s = self.t_s
        return self.ended

    def _at(self, delay_s: float, action: str, *args: Any) -> None:
        self.seq += 1
        heapq.heappush(self.queue, _Pending(self.t_s + delay_s, self.seq, action, args))

    def _cycle(self, event: Event | None = None, signals: DoorSignals | None = None) -> None:
        """One cycle of the wired units (the event, the WPCS, the CPCS), then the reactions."""
        if signals is not None:
            self.controls = self.controls._replace(signals=signals)
        before = self.world
        self.world, errors = step(before, self.controls, event or Event(EventKind.NONE), self.model)
        if errors:
            self.interlock_error = errors[0]
        self._schedule_doors(before, self.world)
        self._react(before)

    def _side_signals(
        self, *, doa: bool | None = None, dmc: bool | None = None, **others: bool
    ) -> DoorSignals:
        return self.controls.signals.with_side(self.side, doa=doa, dmc=dmc)._replace(**others)

    # -- door motion ------------------------------------------------------------
    def _schedule_doors(self, before: World, after: World) -> None:
        t = self.timing
        pairs = [
            ("train-" + s.value, i, u0, u1)
            for s in (Side.L, Side.R)
            for i, (u0, u1) in enumerate(zip(before.cpcs.side(s), after.cpcs.side(s), strict=True))
        ]
        pairs += [
            ("psd", i, u0, u1)
            for i, (u0, u1) in enumerate(zip(before.wpcs.units, after.wpcs.units, strict=True))
        ]
        for group, i, u0, u1 in pairs:
            if u0 == u1:
                continue
            key = (group, i)
            gen = self.gen.get(key, 0) + 1
            self.gen[key] = gen
            psd = group == "psd"
            motion = motion_s(t, u1, psd=psd)
            if motion is not None:
                self._at(motion, "door", group, i, gen, DoorInput.DONE)
            on_platform = psd or group == "train-" + self.side.value
            # The abnormal cases: an obstacle in a closing train door, a PSD unit that jams.
            if not psd and on_platform and i == self.obstruct:
                if u1 == DoorState.CLOSING and "obstruct" not in self.injected:
                    self.injected.add("obstruct")
                    self._at(t.obstruction_at_s, "door", group, i, gen, DoorInput.OBSTRUCT)
                elif u1 == DoorState.OBSTRUCTED:
                    self._at(t.obstruction_clear_s, "door", group, i, gen, DoorInput.CLEAR)
            if psd and i == self.psd_fail:
                if u1 == DoorState.CLOSING and "jam" not in self.injected:
                    self.injected.add("jam")
                    self._at(t.psd_jam_at_s, "door", group, i, gen, DoorInput.JAM)
                elif u1 == DoorState.JAMMED:
                    self._at(t.staff_isolation_s, "door", group, i, gen, DoorInput.ISOLATE)

    def _on_door(self, group: str, unit: int, gen: int, inp: DoorInput) -> None:
        if self.gen.get((group, unit)) != gen:
            return  # the door has moved on since: a stale completion
        if group == "psd":
            event = Event(EventKind.PSD, self.world.wpcs.side, unit, inp)
        else:
            event = Event(EventKind.TRAIN_DOOR, Side(group.removeprefix("train-")), unit, inp)
        self._cycle(event)

    # -- precise-stop confirmation (SPEC §5) -----------------------------------------
    def _on_standstill(self) -> None:
        tol = self.sc.tolerance_m
        kind = EventKind.STOP_IN if answers_psc(self.error_m, tol) else EventKind.STOP_OUT
        self._cycle(Event(kind))

    def _on_psc_timeout(self, attempt: int) -> None:
        w = self.world
        if w.stop.phase == StopPhase.PSC_WAIT and w.stop.attempts == attempt:
            self._cycle(Event(EventKind.PSC_TIMEOUT))

    # -- the door link (SPEC §5) ------------------------------------------------------
    def _start_exchange(self) -> None:
        if not self.exchanging:
            self.exchanging = True
            self.link_state = "exchange"
            self._at(0.0, "tick")

    def _command(self) -> DoorCommand:
        return door_command(
            self.link.train_id,
            self.controls.signals,
            psc=self.world.stop.phase in (StopPhase.PSC_WAIT, StopPhase.CONFIRMED),
            automatic=not self.manual,
            doors=self.world.cpcs.side(self.side),
        )

    def _status(self) -> PsdStatus:
        wp = self.world.wpcs
        return psd_status(
            self.link.train_id,
            wp.units,
            fault=wp.fault,
            psc=self.platform_psc,
            manual=self.controls.wcc_manual,
            locked=self.model.interlocks.locked,
        )

    def _expect_arrival(self) -> None:
        t = self.link.next_arrival_s()
        if t is not None and t not in self.arrivals:
            self.arrivals.add(t)
            self._at(max(t - self.t_s, 0.0), "arrive", t)

    def _on_tick(self) -> None:
        """One exchange cycle: the train's command up, the platform's status down."""
        phase = self.world.stop.phase
        if phase not in (StopPhase.PSC_WAIT, StopPhase.CONFIRMED):
            self.exchanging = False
            self.link_state = "-"
            return
        if phase == StopPhase.CONFIRMED and self.link.train_timed_out(self.t_s):
            self.link_state = "lost"
            self._cycle(Event(EventKind.LINK_LOST))
            return
        self.link.send_command(self._command(), self.t_s)
        if self.platform_psc:
            self.link.send_status(self._status(), self.t_s)
        self._expect_arrival()
        self._at(self.lcfg.exchange_cycle_s, "tick")

    def _on_arrive(self, t: float) -> None:
        self.arrivals.discard(t)
        for r in self.link.deliver(self.t_s):
            if self.done:
                break
            if r.to == "platform" and isinstance(r.telegram, DoorCommand):
                self._platform_receives(r.telegram)
            elif r.to == "train" and isinstance(r.telegram, PsdStatus):
                self._train_receives(r.telegram)
        self._expect_arrival()

    def _platform_receives(self, cmd: DoorCommand) -> None:
        # SPEC §5: what the WPCS knows of the train is this frame; it scans on it at once.
        view = TrainReport(
            signals=command_signals(cmd),
            manual=not cmd.automatic,
            doors=units_from_link(self.cfg.doors_per_side, locked_mask=cmd.doors_locked),
        )
        if view != self.controls.platform_view:
            self.controls = self.controls._replace(platform_view=view)
            self._cycle()
        if not cmd.psc:
            self.platform_psc = False
            return
        # SPEC §5: the WPCS answers only a train its stop sensors see in position.
        if (
            not self.platform_psc
            and not self.platform_answering
            and answers_psc(self.error_m, self.sc.tolerance_m)
        ):
            self.platform_answering = True
            self._at(self.lcfg.wpcs_processing_s, "platform_answer")

    def _on_platform_answer(self) -> None:
        self.platform_answering = False
        if answers_psc(self.error_m, self.sc.tolerance_m):
            self.platform_psc = True
            self.link.send_status(self._status(), self.t_s)
            self._expect_arrival()

    def _train_receives(self, status: PsdStatus) -> None:
        w = self.world
        if status.psc and w.stop.phase == StopPhase.PSC_WAIT:
            self._cycle(Event(EventKind.PSC_REPLY))  # SPEC §5: the reply makes PSC high
        elif self.start_ready and status.psc and status.psd_closed_locked and status.start_enable:
            self._give_start_enable()

    def _on_move(self) -> None:
        self._cycle(Event(EventKind.MOVE))

    def _on_creep_end(self, distance_m: float) -> None:
        self.error_m -= math.copysign(distance_m, self.error_m)
        self.speed_mps = 0.0
        self.creep = "-"
        self._at(self.timing.zero_speed_confirm_s, "standstill")

    # -- the ATC (automatic) or the driver (manual) ----------------------------------------
    def _on_signals(self, changes: dict[str, bool]) -> None:
        s = self.controls.signals
        for name, value in changes.items():
            if name == "doa":
                s = s.with_side(self.side, doa=value)
            elif name == "dmc":
                s = s.with_side(self.side, dmc=value)
            else:
                s = s._replace(**{name: value})
        self._cycle(signals=s)

    def _on_dwell_end(self) -> None:
        self.closing = True
        if self.manual:
            # The driver: door-side selector off and the close button (manual column of the table).
            self._on_signals({"doa": False, "dcc": True})
        else:
            # SPEC §5: close when DMC = 1 and DCC = 1.
            self._on_signals({"dmc": True, "dcc": True})

    def _react(self, before: World) -> None:
        w = self.world
        t = self.timing
        phase, was = w.stop.phase, before.stop.phase
        if phase != was:
            if phase == StopPhase.PSC_WAIT:
                # SPEC §5: standstill confirmed -> PSC request over the link; no reply within
                # the time-out = not in position.
                self.psc_requests += 1
                self._start_exchange()
                self._at(t.psc_timeout_s, "psc_timeout", w.stop.attempts)
            elif phase == StopPhase.CORRECTING:
                # SPEC §3 lamps: F = stopped short, move forward; R = passed, reverse.
                self.lamp = "F" if self.error_m < 0 else "R"
                self._at(t.driver_action_s if self.manual else 0.0, "move")
            elif phase == StopPhase.CONFIRMED:
                self.lamp = "OK"
                # SPEC §5: with PSC the ATC releases DMC on the platform side (vital, both modes) ...
                if self.manual:
                    self._at(0.0, "signals", {"dmc": False})
                    # ... the driver turns the door-side selector (DOA), then presses open (DOC).
                    self._at(t.driver_action_s, "signals", {"doa": True})
                    self._at(2 * t.driver_action_s, "signals", {"doc": True})
                else:
                    # ... and gives DOA and DOC for that side.
                    self._at(0.0, "signals", {"dmc": False, "doa": True, "doc": True})
            elif phase == StopPhase.FAULT:
                self.done = True
            if phase == StopPhase.CORRECTING:
                self.platform_psc = False  # the train moves away from the PSC it asked for
        if w.moving and not before.moving and phase == StopPhase.CORRECTING:
            distance = min(abs(self.error_m), self.sc.creep_max_m)
            self.corrections += 1
            self.speed_mps = self.sc.creep_speed_mps
            self.creep = self.lamp
            self._at(distance / self.sc.creep_speed_mps + self.sc.creep_settle_s, "creep_end", distance)
        if not self.doors_open and self._platform_doors_open():
            self.doors_open = True
            # Doors open: the ATC drops DOC (the driver releases the button); the dwell runs.
            self._at(0.0, "signals", {"doc": False})
            self._at(t.dwell_s, "dwell_end")
        # Start enable after the doors have closed again (it is also high on arrival,
        # before anything opened, but the dwell is not over then). The train's side holds
        # now; the PSD's reaches the train with the next status frame (SPEC §5 fig. 7).
        self.start_ready = self.closing and self.start_enable_s is None and start_enabled(w, self.model)

    def _give_start_enable(self) -> None:
        self.start_enable_s = _r(self.t_s)
        self.lamp = "S"
        self.done = True
        # The door commands are released; in manual the ATC raises DMC again for the run.
        if self.manual:
            self.controls = self.controls._replace(signals=self._side_signals(dmc=True, dcc=False))
        else:
            self.controls = self.controls._replace(signals=self._side_signals(doa=False, dcc=False))

    def _platform_doors_open(self) -> bool:
        return all_open(self.world.cpcs.side(self.side))

    # -- the timeline -----------------------------------------------------------------
    def _snapshot(self) -> dict[str, int | float | str]:
        w = self.world
        s = self.controls.signals
        blocked = "-"
        if self.closing and self.start_enable_s is None:
            bad = [
                b
                for b in start_blockers(w, self.model)
                if b.endswith((DoorState.OBSTRUCTED.value, DoorState.JAMMED.value)) or "fault" in b
            ]
            blocked = "; ".join(bad) if bad else "-"
        return {
            "speed_mps": round(self.speed_mps, 3),
            "ZVR": int(not w.moving),
            "stop_error_m": round(self.error_m, 3),
            "lamp": self.lamp,
            "PSC_request": w.stop.attempts if w.stop.phase == StopPhase.PSC_WAIT else 0,
            "PSC": int(psc(w)),
            "creep": self.creep,
            "DMC-L": int(s.dmc_l),
            "DMC-R": int(s.dmc_r),
            "DOA-L": int(s.doa_l),
            "DOA-R": int(s.doa_r),
            "DOC": int(s.doc),
            "DCC": int(s.dcc),
            "PSD": summarise(w.wpcs.units, f"{w.wpcs.side.value}"),
            "train_doors-L": summarise(w.cpcs.left, "L"),
            "train_doors-R": summarise(w.cpcs.right, "R"),
            "start_blocked": blocked,
            # Given when a status frame reports the PSD closed and locked (SPEC §5 fig. 7).
            "start_enable": int(self.start_enable_s is not None),
            "fault": int(w.stop.phase == StopPhase.FAULT or w.cpcs.fault or w.wpcs.fault),
            "emergency_brake": int(emergency_brake(w)),
            "interlock_error": self.interlock_error,
            "link": self.link_state,
        }

    def _log(self) -> None:
        # Most instants are link frames that change nothing logged: skip the snapshot then.
        key = (
            self.world,
            self.controls,
            self.lamp,
            self.creep,
            self.speed_mps,
            self.error_m,
            self.closing,
            self.start_enable_s,
            self.interlock_error,
            self.link_state,
        )
        if key == self.last_key:
            return
        self.last_key = key
        snap = self._snapshot()
        t = _r(self.t_s)
        for name in SIGNALS:
            value = snap[name]
            if self.last.get(name) != value or name not in self.last:
                self.timeline.append(DwellEvent(t_s=t, signal=name, value=value))
                self.last[name] = value
