"""The train at a platform: CPCS + WPCS + precise-stop confirmation wired together.

The verifier's wiring of the door units (``verify/doors.py`` explores every
``World`` it can reach). The scans and the doors' own events are the
functions here (:func:`platform_scan`, :func:`train_scan`,
:func:`train_door_event`, :func:`psd_event`, :func:`train_doors_locked`),
which the per-place door units of ``nodes/dwell.py`` (the dwell simulation,
the line, live) call too: what is verified is what runs.
A ``World`` is an immutable snapshot; ``step`` advances it by one cycle:

1. one event of the outside world happens (a door finishes its move, an
   obstacle, a jam, a staff isolation, the train stops, the WPCS replies or
   the PSC request times out, the link falls silent with PSC high, the train
   moves), then
2. the WPCS scans (SPEC §3: the PSD is master), then
3. the CPCS scans, seeing the PSD as the WPCS left it.

The train's speed is not a free input: it moves only when its traction
interlock allows (departure with start enable, or the correction creep the
stop confirmation orders with every train door closed and locked). That
interlock is part of what ``railstop doors verify`` checks.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import NamedTuple

from railstop.config.doors import ActionTable
from railstop.control.doors import (
    DOOR_TRANSITIONS,
    PHYSICAL_INPUTS,
    DoorInput,
    DoorSignals,
    DoorState,
    Interlocks,
    PsdReport,
    Side,
)
from railstop.errors import InterlockError
from railstop.onboard import cpcs, stop_confirm
from railstop.onboard.cpcs import CpcsState
from railstop.onboard.stop_confirm import STOP_TRANSITIONS, StopConfirmState, StopInput, StopPhase
from railstop.wayside import wpcs
from railstop.wayside.wpcs import TrainReport, WpcsState


@dataclass(frozen=True, slots=True, kw_only=True)
class DoorModel:
    """Everything that decides how the door system behaves: the tables and the rules."""

    actions: ActionTable
    doors: Mapping[tuple[DoorState, DoorInput], DoorState] = field(default_factory=lambda: DOOR_TRANSITIONS)
    stop: Mapping[tuple[StopPhase, StopInput], StopPhase] = field(default_factory=lambda: STOP_TRANSITIONS)
    interlocks: Interlocks = field(default_factory=Interlocks)
    max_psc_attempts: int = 3


class World(NamedTuple):
    moving: bool
    in_position: bool  # inside the stop tolerance (the WPCS answers PSC)
    stop: StopConfirmState
    cpcs: CpcsState
    wpcs: WpcsState

    @classmethod
    def arriving(cls, *, platform_side: Side, doors_per_side: int) -> World:
        """A train running into the platform, every door closed and locked."""
        return cls(
            moving=True,
            in_position=False,
            stop=StopConfirmState(),
            cpcs=CpcsState.closed(doors_per_side),
            wpcs=WpcsState.closed(platform_side, doors_per_side),
        )


class Controls(NamedTuple):
    """The external inputs of one cycle besides the event."""

    signals: DoorSignals = DoorSignals()
    manual: bool = False  # driving mode
    wcc_manual: bool = False  # the WCC switched the WPCS to manual
    panel_open: bool = False  # the PSD panel's buttons (used only with wcc_manual)
    panel_close: bool = False
    # The train as the platform last received it over the door link (its door-command frame:
    # signals, mode, which doors are closed and locked); None: the train's own of this cycle, an
    # ideal link (the verifier's wiring).
    platform_view: TrainReport | None = None


class EventKind(StrEnum):
    NONE = "none"
    TRAIN_DOOR = "train-door"
    PSD = "psd"
    STOP_IN = "stop-in-position"  # the train comes to a stand inside the tolerance
    STOP_OUT = "stop-out-of-position"
    PSC_REPLY = "psc-reply"
    PSC_TIMEOUT = "psc-timeout"
    LINK_LOST = "link-lost"  # PSC high, the WPCS's status frames stop reaching the train
    MOVE = "move"  # traction: depart (start enable) or creep (correction)


class Event(NamedTuple):
    kind: EventKind
    side: Side | None = None
    unit: int = -1
    door_input: DoorInput | None = None

    def describe(self) -> str:
        if self.kind == EventKind.TRAIN_DOOR and self.side is not None and self.door_input is not None:
            return f"train door {self.side.value}{self.unit + 1} {self.door_input.value}"
        if self.kind == EventKind.PSD and self.side is not None and self.door_input is not None:
            return f"PSD {self.side.value}{self.unit + 1} {self.door_input.value}"
        return self.kind.value


NOTHING = Event(EventKind.NONE)


def platform_scan(
    state: WpcsState,
    train: TrainReport,
    model: DoorModel,
    *,
    wcc_manual: bool = False,
    panel_open: bool = False,
    panel_close: bool = False,
) -> tuple[WpcsState, str | None]:
    """One WPCS scan (SPEC §5) on what the platform knows of the train; an input the unit does not
    allow puts it in its safe state (DESIGN rule 10: nothing opens, the train is told) and is
    returned as the interlock error. The one call of the scan: this wiring, ``nodes.dwell``."""
    try:
        return wpcs.scan(
            state,
            train,
            wcc_manual=wcc_manual,
            panel_open=panel_open,
            panel_close=panel_close,
            actions=model.actions,
            interlocks=model.interlocks,
            doors=model.doors,
        ), None
    except InterlockError as exc:
        return wpcs.safe(state), str(exc)


def train_scan(
    state: CpcsState,
    signals: DoorSignals,
    model: DoorModel,
    *,
    manual: bool,
    moving: bool,
    psd: PsdReport | None,
) -> tuple[CpcsState, str | None]:
    """One CPCS scan (SPEC §5) on the train's door signals and the PSD as the link reported it;
    an input the unit does not allow puts it in its safe state (doors held closed, emergency
    brake), returned as the interlock error. The one call of the scan: this wiring,
    ``nodes.dwell``."""
    try:
        return cpcs.scan(
            state,
            signals,
            manual=manual,
            zero_speed=not moving,
            psd=psd,
            actions=model.actions,
            interlocks=model.interlocks,
            doors=model.doors,
        ), None
    except InterlockError as exc:
        return cpcs.safe(state), str(exc)


def train_door_event(
    state: CpcsState, side: Side, unit: int, inp: DoorInput, model: DoorModel
) -> tuple[CpcsState, str | None]:
    """A train door's own event (it finished moving, an obstacle, ...); one it does not allow puts
    the CPCS in its safe state."""
    try:
        return cpcs.door_event(state, side, unit, inp, model.doors), None
    except InterlockError as exc:
        return cpcs.safe(state), str(exc)


def psd_event(state: WpcsState, unit: int, inp: DoorInput, model: DoorModel) -> tuple[WpcsState, str | None]:
    """A PSD unit's own event; one it does not allow puts the WPCS in its safe state."""
    try:
        return wpcs.door_event(state, unit, inp, model.doors), None
    except InterlockError as exc:
        return wpcs.safe(state), str(exc)


def train_doors_locked(state: CpcsState, model: DoorModel) -> bool:
    """Every train door on both sides closed and locked: the correction creep's traction
    interlock (SPEC §3, §5: the PSD never opened, it opens only with PSC)."""
    locked = model.interlocks.locked
    return all(u in locked for u in state.left) and all(u in locked for u in state.right)


def psc(world: World) -> bool:
    return world.stop.phase == StopPhase.CONFIRMED


def emergency_brake(world: World) -> bool:
    """SPEC §5: fault after the PSC attempts, or a CPCS in its safe state."""
    return world.stop.phase == StopPhase.FAULT or world.cpcs.fault


def psd_report(world: World) -> PsdReport | None:
    """SPEC §5: the PSD state reaches the train only while PSC is high."""
    return world.wpcs.report() if psc(world) else None


def start_enabled(world: World, model: DoorModel) -> bool:
    return cpcs.start_enabled(
        world.cpcs,
        psd_report(world),
        psc=psc(world),
        emergency_brake=emergency_brake(world),
        interlocks=model.interlocks,
    )


def start_blockers(world: World, model: DoorModel) -> tuple[str, ...]:
    return cpcs.start_blockers(
        world.cpcs,
        psd_report(world),
        psc=psc(world),
        emergency_brake=emergency_brake(world),
        interlocks=model.interlocks,
    )


def traction(world: World, model: DoorModel) -> str | None:
    """What the train's traction interlock allows now: "depart", "creep" or None."""
    if world.moving or emergency_brake(world):
        return None
    phase = world.stop.phase
    if phase == StopPhase.CONFIRMED and start_enabled(world, model):
        return "depart"
    if phase == StopPhase.CORRECTING and train_doors_locked(world.cpcs, model):
        return "creep"  # the correction creep
    return None


def events(world: World, model: DoorModel) -> list[Event]:
    """Every event the outside world can produce now (the verifier tries each one)."""
    out = [NOTHING]
    doors = model.doors
    for side in (Side.L, Side.R):
        for i, u in enumerate(world.cpcs.side(side)):
            for inp in PHYSICAL_INPUTS:
                if (u, inp) in doors:
                    out.append(Event(EventKind.TRAIN_DOOR, side, i, inp))
    for i, u in enumerate(world.wpcs.units):
        for inp in PHYSICAL_INPUTS:
            if (u, inp) in doors:
                out.append(Event(EventKind.PSD, world.wpcs.side, i, inp))
    if world.moving:
        out.append(Event(EventKind.STOP_IN))
        out.append(Event(EventKind.STOP_OUT))
    else:
        phase = world.stop.phase
        # The WPCS answers only a train in position; the reply can always be lost.
        if world.in_position and (phase, StopInput.PSC_REPLY) in model.stop:
            out.append(Event(EventKind.PSC_REPLY))
        if (phase, StopInput.PSC_TIMEOUT) in model.stop or (phase, StopInput.PSC_TIMEOUT_LAST) in model.stop:
            out.append(Event(EventKind.PSC_TIMEOUT))
        # ... and with PSC high the link can fall silent at any moment.
        if (phase, StopInput.LINK_LOST) in model.stop:
            out.append(Event(EventKind.LINK_LOST))
        if traction(world, model) is not None:
            out.append(Event(EventKind.MOVE))
    return out


def apply_event(world: World, event: Event, model: DoorModel) -> tuple[World, str | None]:
    """Step 1 of a cycle; an input a unit does not allow puts that unit in its safe state."""
    kind = event.kind
    if kind == EventKind.NONE:
        return world, None
    if kind == EventKind.TRAIN_DOOR:
        if event.side is None or event.door_input is None:
            why = f"event {event}: a train door event needs a side and an input"
            return world._replace(cpcs=cpcs.safe(world.cpcs)), why
        c_state, error = train_door_event(world.cpcs, event.side, event.unit, event.door_input, model)
        return world._replace(cpcs=c_state), error
    if kind == EventKind.PSD:
        if event.door_input is None:
            return world._replace(wpcs=wpcs.safe(world.wpcs)), f"event {event}: a PSD event needs an input"
        w_state, error = psd_event(world.wpcs, event.unit, event.door_input, model)
        return world._replace(wpcs=w_state), error
    try:
        if kind in (EventKind.STOP_IN, EventKind.STOP_OUT):
            if not world.moving:
                raise InterlockError("stop event for a train at standstill")
            stop = _stop_step(world.stop, StopInput.STANDSTILL, model)
            return world._replace(moving=False, in_position=kind == EventKind.STOP_IN, stop=stop), None
        if kind == EventKind.PSC_REPLY:
            return world._replace(stop=_stop_step(world.stop, StopInput.PSC_REPLY, model)), None
        if kind == EventKind.PSC_TIMEOUT:
            return world._replace(stop=_stop_step(world.stop, StopInput.PSC_TIMEOUT, model)), None
        if kind == EventKind.LINK_LOST:
            return world._replace(stop=_stop_step(world.stop, StopInput.LINK_LOST, model)), None
        if kind == EventKind.MOVE:
            allowed = traction(world, model)
            if allowed is None:
                raise InterlockError("traction: the train may not move now")
            if allowed == "depart":
                return world._replace(moving=True, stop=_stop_step(world.stop, StopInput.DEPART, model)), None
            return world._replace(moving=True), None
    except InterlockError as exc:
        return world._replace(stop=stop_confirm.safe(world.stop)), str(exc)
    raise InterlockError(f"unknown event {event!r}")  # pragma: no cover - EventKind is closed


def _stop_step(state: StopConfirmState, inp: StopInput, model: DoorModel) -> StopConfirmState:
    return stop_confirm.step(state, inp, max_attempts=model.max_psc_attempts, table=model.stop)


def scan_units(
    world: World, controls: Controls, model: DoorModel, memo: dict[object, object] | None = None
) -> tuple[World, str | None]:
    """Steps 2 and 3 of a cycle: the WPCS scans, then the CPCS.

    ``memo`` (optional, for one ``world`` only) remembers scan results: the
    scans are pure, and the verifier calls this for 640 input combinations of
    the same world, most of which look alike to each unit.
    """
    error = None
    confirmed = psc(world)
    w_state = world.wpcs
    side = w_state.side
    if confirmed:
        view = controls.platform_view
        w_key: object | None = None
        if view is None:  # the verifier's ideal link: the scan depends on these inputs only
            s = controls.signals
            if controls.wcc_manual:
                w_key = ("wpcs", s.doa(side), s.dmc(side), controls.panel_open, controls.panel_close, True)
            else:
                w_key = ("wpcs", s.doa(side), s.dmc(side), s.doc, s.dcc, controls.manual)
        cached = None if memo is None or w_key is None else memo.get(w_key)
        if cached is not None:
            w_state, error = cached  # type: ignore[misc]
        else:
            # SPEC §5 over the link: the WPCS acts on the train's last door-command frame; without
            # one, on the train's own signals of this cycle.
            own = world.cpcs.side(side)
            train = view if view is not None else TrainReport(controls.signals, controls.manual, own)
            w_state, error = platform_scan(
                w_state,
                train,
                model,
                wcc_manual=controls.wcc_manual,
                panel_open=controls.panel_open,
                panel_close=controls.panel_close,
            )
            if memo is not None and w_key is not None:
                memo[w_key] = (w_state, error)
    c_key = ("cpcs", controls.signals, controls.manual, w_state)
    cached = None if memo is None else memo.get(c_key)
    if cached is not None:
        c_state, c_error = cached  # type: ignore[misc]
    else:
        c_state, c_error = train_scan(
            world.cpcs,
            controls.signals,
            model,
            manual=controls.manual,
            moving=world.moving,
            psd=w_state.report() if confirmed else None,
        )
        if memo is not None:
            memo[c_key] = (c_state, c_error)
    error = c_error or error
    if c_state is world.cpcs and w_state is world.wpcs:
        return world, error
    return world._replace(cpcs=c_state, wpcs=w_state), error


def step(world: World, controls: Controls, event: Event, model: DoorModel) -> tuple[World, tuple[str, ...]]:
    """One cycle: the event, then the WPCS scan, then the CPCS scan; returns the interlock errors."""
    after_event, e1 = apply_event(world, event, model)
    after, e2 = scan_units(after_event, controls, model)
    return after, tuple(e for e in (e1, e2) if e is not None)
