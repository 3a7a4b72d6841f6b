"""The wayside WPCS: the PSD controller of one platform (SPEC §3, §5), a pure unit.

The PSD is on the platform side only. While PSC is high the train and the
WPCS exchange data (SPEC §5): the WPCS receives the train's door signals, its
driving mode and the state of the train doors facing the platform, and acts
on the PSD units with the same action table as the train doors (SPEC §5:
"PSD behaves like the train door"). It adds the rules SPEC states outside the
table:

- without PSC there is no data exchange: the WPCS gives the PSD no command
  (nothing opens; SPEC §5: the PSD state is trusted only while PSC is high);
- closing order: a PSD unit closes only once every train door of its side is
  closed and locked (SPEC §5: train doors first, then PSD);
- the WCC can switch the WPCS to manual (SPEC §5): the platform panel's open
  and close buttons then stand for DOC and DCC, read in the manual column of
  the table; the train's DOA and DMC and the closing order still apply.

A PSD unit can be obstructed or fail to close (jam); staff isolate a failed
unit (closed and locked by hand), which then no longer withholds start
enable. An input a unit cannot take moves the WPCS to its safe state
(``fault``: nothing opens, the train is told, start enable withheld) and
raises ``InterlockError``.
"""

from __future__ import annotations

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


class WpcsState(NamedTuple):
    """The PSD units of the platform (facing the train doors, front first) and the fault latch."""

    side: Side
    units: tuple[DoorState, ...]
    fault: bool = False

    @classmethod
    def closed(cls, side: Side, units: int) -> WpcsState:
        if units < 1:
            raise InterlockError(f"PSD units: must be at least 1 (got {units})")
        return cls(side=side, units=(DoorState.CLOSED_LOCKED,) * units)

    def report(self) -> PsdReport:
        """What goes to the train over the link (the caller sends it only while PSC is high)."""
        return PsdReport(side=self.side, units=self.units, fault=self.fault)


class TrainReport(NamedTuple):
    """What the train tells the WPCS over the link; exists only while PSC is high."""

    signals: DoorSignals
    manual: bool
    doors: tuple[DoorState, ...]  # the train doors facing this platform


def answers_psc(stop_error_m: float, tolerance_m: float) -> bool:
    """SPEC §5: the WPCS replies to the PSC request only for a train inside the stop tolerance.

    (The transponder only talks inside the precise-stop zone: security by range.)
    """
    return abs(stop_error_m) <= tolerance_m


def scan(
    state: WpcsState,
    train: TrainReport | None,
    *,
    wcc_manual: bool,
    panel_open: bool,
    panel_close: bool,
    actions: ActionTable,
    interlocks: Interlocks = Interlocks(),
    doors: DoorTable = DOOR_TRANSITIONS,
) -> WpcsState:
    """One WPCS scan: the action table's command to every PSD unit."""
    if train is None:
        return state  # no PSC, no data exchange: hold the PSD as it is
    side = state.side
    if len(train.doors) != len(state.units):
        raise InterlockError(f"train report: {len(train.doors)} train doors for {len(state.units)} PSD units")
    doa = train.signals.doa(side)
    # SPEC §5: DMC overrides everything; the WPCS's safe state holds the PSD closed the same way.
    dmc = train.signals.dmc(side) or state.fault
    if wcc_manual:
        # SPEC §5: the WCC switches the WPCS to manual: the platform panel's buttons.
        doc, dcc, manual = panel_open, panel_close, True
    else:
        doc, dcc, manual = train.signals.doc, train.signals.dcc, train.manual
    # SPEC §5 order: closing the train doors first, then the PSD.
    train_closed = all(d in interlocks.psd_closes_when_train for d in train.doors)
    changed: list[DoorState] | None = None
    for i, unit in enumerate(state.units):
        column = table_column(unit)
        if column is None:
            continue  # isolated by staff
        action = actions.decide(doa, dmc, doc, dcc, closed=column, manual=manual)
        if action == Action.OPEN:
            if state.fault:
                continue
            inp = DoorInput.OPEN  # SPEC §3: PSD is master; it opens first
        elif action == Action.CLOSE:
            if not train_closed:
                continue
            inp = DoorInput.CLOSE
        else:
            continue
        nxt = doors.get((unit, inp))
        if nxt is None:
            raise InterlockError(
                f"{door_name('PSD', side, i)}: command {inp.value!r} is not allowed in state {unit.value!r}"
            )
        if nxt != unit:
            if changed is None:
                changed = list(state.units)
            changed[i] = nxt
    return state if changed is None else state._replace(units=tuple(changed))


def door_event(state: WpcsState, unit: int, inp: DoorInput, doors: DoorTable = DOOR_TRANSITIONS) -> WpcsState:
    """A physical event at one PSD unit: motion done, obstruction, failure to close, staff isolation."""
    if not 0 <= unit < len(state.units):
        raise InterlockError(f"PSD {state.side.value}{unit + 1}: no such unit (1..{len(state.units)})")
    cur = state.units[unit]
    nxt = doors.get((cur, inp))
    if nxt is None:
        raise InterlockError(
            f"{door_name('PSD', state.side, unit)}: input {inp.value!r} is not allowed in state {cur.value!r}"
        )
    return state._replace(units=(*state.units[:unit], nxt, *state.units[unit + 1 :]))


def safe(state: WpcsState) -> WpcsState:
    """DESIGN rule 10: the WPCS's safe state: nothing opens, the train is told (no start enable)."""
    return state._replace(fault=True)


class Wpcs:
    """The WPCS as an object: ``state`` plus methods; safe state first, then ``InterlockError``."""

    def __init__(
        self,
        *,
        side: Side,
        units: int,
        actions: ActionTable,
        interlocks: Interlocks = Interlocks(),
        doors: DoorTable = DOOR_TRANSITIONS,
    ) -> None:
        self.state = WpcsState.closed(side, units)
        self.actions = actions
        self.interlocks = interlocks
        self.doors = doors

    def scan(
        self,
        train: TrainReport | None,
        *,
        wcc_manual: bool = False,
        panel_open: bool = False,
        panel_close: bool = False,
    ) -> WpcsState:
        try:
            self.state = scan(
                self.state,
                train,
                wcc_manual=wcc_manual,
                panel_open=panel_open,
                panel_close=panel_close,
                actions=self.actions,
                interlocks=self.interlocks,
                doors=self.doors,
            )
        except InterlockError:
            self.state = safe(self.state)
            raise
        return self.state

    def door_event(self, unit: int, inp: DoorInput) -> WpcsState:
        try:
            self.state = door_event(self.state, unit, inp, self.doors)
        except InterlockError:
            self.state = safe(self.state)
            raise
        return self.state
