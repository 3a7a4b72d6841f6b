"""The onboard CPCS: the train's door controller for both sides (SPEC §5), a pure unit.

Every scan the CPCS reads the door signals (DOA-L/R, DMC-L/R, DOC, DCC from
the ATC, or from the manual controls in manual driving), the zero velocity
relay and what the WPCS reports about the PSD over the link (only while PSC
is high), and gives each door unit the command of the action table (SPEC §5
Table 1, data). It adds only the rules SPEC states outside the table:

- the ZVR's N.C. contact is wired with DMC: a moving train holds its doors closed;
- opening order: a train door opens only once the PSD unit opposite it is open
  (so only the platform side, the side with a PSD, ever opens);
- start enable only with every train door closed and locked, the PSD closed
  and locked and PSC high (SPEC §5 fig. 7).

An input a door unit cannot take moves the CPCS to its safe state (``fault``:
nothing opens, start enable withheld, emergency brake) and raises
``InterlockError`` (DESIGN rules 2 and 10).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

from railstop.config.doors import Action, ActionTable
from railstop.control.doors import (
    DOOR_TRANSITIONS,
    DoorInput,
    DoorSignals,
    DoorState,
    DoorTable,
    Interlocks,
    PsdReport,
    Side,
    door_name,
    table_column,
)
from railstop.errors import InterlockError

SIDES: tuple[Side, Side] = (Side.L, Side.R)


class CpcsState(NamedTuple):
    """The train door units of each side (front first) and the fault latch."""

    left: tuple[DoorState, ...]
    right: tuple[DoorState, ...]
    fault: bool = False

    @classmethod
    def closed(cls, doors_per_side: int) -> CpcsState:
        if doors_per_side < 1:
            raise InterlockError(f"doors_per_side: must be at least 1 (got {doors_per_side})")
        units = (DoorState.CLOSED_LOCKED,) * doors_per_side
        return cls(left=units, right=units)

    def side(self, side: Side) -> tuple[DoorState, ...]:
        return self.left if side == Side.L else self.right

    def with_side(self, side: Side, units: tuple[DoorState, ...]) -> CpcsState:
        return self._replace(left=units) if side == Side.L else self._replace(right=units)


def scan(
    state: CpcsState,
    signals: DoorSignals,
    *,
    manual: bool,
    zero_speed: bool,
    psd: PsdReport | None,
    actions: ActionTable,
    interlocks: Interlocks = Interlocks(),
    doors: DoorTable = DOOR_TRANSITIONS,
) -> CpcsState:
    """One CPCS scan: the action table's command to every door unit of both sides."""
    new_state = state
    for side in SIDES:
        units = state.side(side)
        # SPEC §5: DMC overrides DOA, DOC, DCC (the table's rows say so); the ZVR's
        # N.C. contact is wired with DMC, so while moving DMC is high whatever the ATC says.
        # The CPCS's safe state holds the doors closed the same way.
        dmc = signals.dmc(side) or (interlocks.zvr and not zero_speed) or state.fault
        doa = signals.doa(side)
        changed: list[DoorState] | None = None
        for i, unit in enumerate(units):
            column = table_column(unit)
            if column is None:
                continue  # isolated by staff: out of the door loop, no command
            action = actions.decide(doa, dmc, signals.doc, signals.dcc, closed=column, manual=manual)
            if action == Action.OPEN:
                if state.fault or not _psd_open_opposite(psd, side, i, len(units), interlocks):
                    continue  # SPEC §5 order: the PSD opens first; a train door waits for it
                inp = DoorInput.OPEN
            elif action == Action.CLOSE:
                inp = DoorInput.CLOSE
            else:
                continue  # keep: no command, a moving door finishes its move
            nxt = doors.get((unit, inp))
            if nxt is None:
                raise InterlockError(
                    f"{door_name('train door', side, i)}: command {inp.value!r} is not allowed "
                    f"in state {unit.value!r}"
                )
            if nxt != unit:
                if changed is None:
                    changed = list(units)
                changed[i] = nxt
        if changed is not None:
            new_state = new_state.with_side(side, tuple(changed))
    return new_state


def _psd_open_opposite(psd: PsdReport | None, side: Side, unit: int, n: int, interlocks: Interlocks) -> bool:
    # No report (no PSC), another side (no PSD there: not the platform side) or
    # a WPCS fault: the PSD opposite is not known to be open.
    if psd is None or psd.side != side or psd.fault:
        return False
    if len(psd.units) != n:
        raise InterlockError(
            f"PSD report: {len(psd.units)} PSD units for {n} train doors on side {side.value}"
        )
    return psd.units[unit] in interlocks.train_opens_when_psd


def door_event(
    state: CpcsState, side: Side, unit: int, inp: DoorInput, doors: DoorTable = DOOR_TRANSITIONS
) -> CpcsState:
    """A physical event at one train door unit: motion done, obstruction, failure, staff isolation."""
    units = state.side(side)
    if not 0 <= unit < len(units):
        raise InterlockError(f"train door {side.value}{unit + 1}: no such door (1..{len(units)})")
    nxt = doors.get((units[unit], inp))
    if nxt is None:
        raise InterlockError(
            f"{door_name('train door', side, unit)}: input {inp.value!r} is not allowed "
            f"in state {units[unit].value!r}"
        )
    return state.with_side(side, (*units[:unit], nxt, *units[unit + 1 :]))


def safe(state: CpcsState) -> CpcsState:
    """DESIGN rule 10: the CPCS's safe state: doors held closed, no start enable, emergency brake."""
    return state._replace(fault=True)


def start_enabled(
    state: CpcsState,
    psd: PsdReport | None,
    *,
    psc: bool,
    emergency_brake: bool,
    interlocks: Interlocks = Interlocks(),
) -> bool:
    """SPEC §5 fig. 7: START ENABLE only with every train door closed and locked, the PSD
    closed and locked and PSC high (the PSD state is trusted only while PSC is high)."""
    if state.fault or emergency_brake or not psc or psd is None or psd.fault:
        return False
    locked = interlocks.locked
    return (
        all(u in locked for u in state.left)
        and all(u in locked for u in state.right)
        and all(u in locked for u in psd.units)
    )


def start_blockers(
    state: CpcsState,
    psd: PsdReport | None,
    *,
    psc: bool,
    emergency_brake: bool,
    interlocks: Interlocks = Interlocks(),
) -> tuple[str, ...]:
    """Why start enable is withheld, naming each door (empty: start enabled)."""
    out: list[str] = []
    if state.fault:
        out.append("CPCS fault")
    if emergency_brake:
        out.append("emergency brake")
    if not psc:
        out.append("no PSC: precise stop not confirmed, PSD state unknown")
    for side in SIDES:
        for i, u in enumerate(state.side(side)):
            if u not in interlocks.locked:
                out.append(f"{door_name('train door', side, i)} {u.value}")
    if psc:
        if psd is None:
            out.append("no PSD report")
        else:
            if psd.fault:
                out.append("WPCS fault")
            for i, u in enumerate(psd.units):
                if u not in interlocks.locked:
                    out.append(f"{door_name('PSD', psd.side, i)} {u.value}")
    return tuple(out)


@dataclass(frozen=True, slots=True, kw_only=True)
class StartEnable:
    enabled: bool
    blockers: tuple[str, ...]


class Cpcs:
    """The CPCS as an object (h11 style): ``state`` plus methods that advance it.

    On an input the transition table does not allow, the unit moves to its safe
    state first and then raises ``InterlockError``.
    """

    def __init__(
        self,
        *,
        doors_per_side: int,
        actions: ActionTable,
        interlocks: Interlocks = Interlocks(),
        doors: DoorTable = DOOR_TRANSITIONS,
    ) -> None:
        self.state = CpcsState.closed(doors_per_side)
        self.actions = actions
        self.interlocks = interlocks
        self.doors = doors

    def scan(
        self, signals: DoorSignals, *, manual: bool, zero_speed: bool, psd: PsdReport | None
    ) -> CpcsState:
        try:
            self.state = scan(
                self.state,
                signals,
                manual=manual,
                zero_speed=zero_speed,
                psd=psd,
                actions=self.actions,
                interlocks=self.interlocks,
                doors=self.doors,
            )
        except InterlockError:
            self.state = safe(self.state)
            raise
        return self.state

    def door_event(self, side: Side, unit: int, inp: DoorInput) -> CpcsState:
        try:
            self.state = door_event(self.state, side, unit, inp, self.doors)
        except InterlockError:
            self.state = safe(self.state)
            raise
        return self.state

    def start_enable(self, psd: PsdReport | None, *, psc: bool, emergency_brake: bool = False) -> StartEnable:
        blockers = start_blockers(
            self.state, psd, psc=psc, emergency_brake=emergency_brake, interlocks=self.interlocks
        )
        return StartEnable(enabled=not blockers, blockers=blockers)
