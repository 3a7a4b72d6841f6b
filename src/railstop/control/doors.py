"""What the onboard CPCS and the wayside WPCS share: the door action table and the door unit.

SPEC §5 Table 1 (the door action table) is data (``railstop/data/doors.toml``,
DESIGN rule 3): for the four signals of one side (DOA, DMC, DOC, DCC) it says
what a door that is now closed does and what a door that is now open does.
``config.doors.ActionTable`` holds those rows as they are; it never "corrects"
them, so that ``railstop doors verify`` can prove (or refute) an edited table.

A door unit (one train door leaf pair, or one PSD door unit) is a small state
machine with its transitions in ``DOOR_TRANSITIONS`` (DESIGN rule 2). The same
table serves train doors and PSD units (SPEC §5: "PSD behaves like the train
door"); only the durations differ, and they are data too (:func:`motion_s`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from types import MappingProxyType
from typing import NamedTuple

from railstop.config.doors import DoorTiming
from railstop.errors import InterlockError


class Side(StrEnum):
    """A side of the train / of the track, in the running direction (SPEC §5 DOA-L/R, DMC-L/R)."""

    L = "L"
    R = "R"


class DoorState(StrEnum):
    CLOSED_LOCKED = "closed_locked"
    OPENING = "opening"
    OPEN = "open"
    CLOSING = "closing"
    CLOSED = "closed"  # closed, lock not yet made
    OBSTRUCTED = "obstructed"  # closing stopped by an obstacle: the door reopens and holds
    JAMMED = "jammed"  # the unit failed to close
    ISOLATED = "isolated"  # staff closed and locked it by hand and took it out of service


class DoorInput(StrEnum):
    OPEN = "open"  # command from the controller
    CLOSE = "close"  # command from the controller
    DONE = "done"  # the running motion (opening, closing, locking) finished
    OBSTRUCT = "obstruct"  # the door edge detects an obstacle
    CLEAR = "clear"  # the obstacle is gone
    JAM = "jam"  # the unit fails to close
    ISOLATE = "isolate"  # staff isolation of a failed unit


DS = DoorState
DI = DoorInput

# A door unit's transitions (DESIGN rule 2). Pairs that are missing are inputs
# the unit cannot take (a "done" for a door that is not moving, an isolation of
# a healthy door, an open command to an isolated door...): they raise.
DOOR_TRANSITIONS: Mapping[tuple[DoorState, DoorInput], DoorState] = MappingProxyType(
    {
        (DS.CLOSED_LOCKED, DI.OPEN): DS.OPENING,  # unlock and open
        (DS.CLOSED_LOCKED, DI.CLOSE): DS.CLOSED_LOCKED,
        (DS.OPENING, DI.DONE): DS.OPEN,
        (DS.OPENING, DI.CLOSE): DS.CLOSING,  # reverse at once (e.g. DMC raised while opening)
        (DS.OPEN, DI.CLOSE): DS.CLOSING,
        (DS.CLOSING, DI.CLOSE): DS.CLOSING,
        (DS.CLOSING, DI.DONE): DS.CLOSED,
        (DS.CLOSING, DI.OBSTRUCT): DS.OBSTRUCTED,
        (DS.CLOSING, DI.JAM): DS.JAMMED,
        (DS.CLOSED, DI.DONE): DS.CLOSED_LOCKED,  # the lock is made
        (DS.CLOSED, DI.CLOSE): DS.CLOSED,
        (DS.CLOSED, DI.OPEN): DS.OPENING,
        # Once the obstacle is gone the door stands open and waits for the controller's
        # next close command: every closing passes the controller's closing order.
        # (Resuming the closing by itself let a PSD unit close while a train door of
        # its side was opening: the 2-door verification found it.)
        (DS.OBSTRUCTED, DI.CLEAR): DS.OPEN,
        (DS.OBSTRUCTED, DI.CLOSE): DS.OBSTRUCTED,
        (DS.OBSTRUCTED, DI.ISOLATE): DS.ISOLATED,
        (DS.JAMMED, DI.CLOSE): DS.JAMMED,
        (DS.JAMMED, DI.ISOLATE): DS.ISOLATED,
        (DS.ISOLATED, DI.CLOSE): DS.ISOLATED,
    }
)

#: A door unit's transition table (DOOR_TRANSITIONS or a variant the verifier tries).
DoorTable = Mapping[tuple[DoorState, DoorInput], DoorState]


class PsdReport(NamedTuple):
    """What the WPCS tells the train over the link; SPEC §5: trusted only while PSC is high."""

    side: Side
    units: tuple[DoorState, ...]
    fault: bool = False


# The inputs that come from the world (time, obstacles, failures, staff), not
# from the controller; the verifier offers each of them wherever the table has it.
PHYSICAL_INPUTS: tuple[DoorInput, ...] = (DI.DONE, DI.OBSTRUCT, DI.CLEAR, DI.JAM, DI.ISOLATE)

# A door in one of these states is closed (it may still be locking); any other
# door counts as open, fail safe (DESIGN rule 10).
CLOSED_STATES: frozenset[DoorState] = frozenset({DS.CLOSED_LOCKED, DS.CLOSED, DS.ISOLATED})
# Closed and locked: what start enable needs (SPEC §5 fig. 7). An isolated unit
# was closed and locked by hand before staff took it out of the door loop.
LOCKED_STATES: frozenset[DoorState] = frozenset({DS.CLOSED_LOCKED, DS.ISOLATED})
# Which column of the action table a door reads: "closed" for these, "open" otherwise.
# An isolated unit reads neither: the controller gives it no command.
_TABLE_CLOSED: frozenset[DoorState] = frozenset({DS.CLOSED_LOCKED, DS.CLOSED})


def door_mask(units: Sequence[DoorState], states: frozenset[DoorState]) -> int:
    """The door link's mask of ``units`` (bit i: unit i + 1, front first) that are in ``states``."""
    mask = 0
    for i, u in enumerate(units):
        if u in states:
            mask |= 1 << i
    return mask


def all_open(units: Iterable[DoorState]) -> bool:
    """Whether every unit in service (staff-isolated ones aside) is fully open, and there is one."""
    serving = [u for u in units if u != DS.ISOLATED]
    return bool(serving) and all(u == DS.OPEN for u in serving)


def units_from_link(n: int, *, locked_mask: int, open_mask: int = 0) -> tuple[DoorState, ...]:
    """``n`` door units as the far end of the door link knows them (SPEC §5: it sees only what the
    link carries): fully open (``open_mask``), closed and locked (``locked_mask``), else
    ``CLOSING``.

    [interpretation] The link carries a bit or two per unit, not its full state. ``CLOSING``
    stands for every state between open and locked: it lets no door open opposite it and counts
    as not locked, so the far end's interlocks are never looser than they would be with the full
    state (a train door opens only opposite an open PSD unit; the PSD closes only after every
    train door is locked; start enable needs every unit locked)."""
    out = []
    for i in range(n):
        bit = 1 << i
        out.append(DS.OPEN if open_mask & bit else DS.CLOSED_LOCKED if locked_mask & bit else DS.CLOSING)
    return tuple(out)


def door_next(
    state: DoorState,
    inp: DoorInput,
    table: Mapping[tuple[DoorState, DoorInput], DoorState] = DOOR_TRANSITIONS,
    *,
    name: str = "door",
) -> DoorState:
    """The next state of one door unit, or ``InterlockError`` for an input the table does not allow."""
    try:
        return table[(state, inp)]
    except KeyError:
        raise InterlockError(f"{name}: input {inp.value!r} is not allowed in state {state.value!r}") from None


def motion_s(timing: DoorTiming, state: DoorState, *, psd: bool) -> float | None:
    """How long the motion a door unit has just begun lasts (``timing``: the door data): opening,
    closing, or locking once closed (None: ``state`` is not a motion)."""
    if state == DoorState.OPENING:
        return timing.psd_open_s if psd else timing.train_door_open_s
    if state == DoorState.CLOSING:
        return timing.psd_close_s if psd else timing.train_door_close_s
    if state == DoorState.CLOSED:
        return timing.psd_lock_s if psd else timing.train_door_lock_s
    return None


def table_column(state: DoorState) -> bool | None:
    """True: the door reads the "closed" column; False: the "open" column; None: no command (isolated)."""
    if state == DS.ISOLATED:
        return None
    return state in _TABLE_CLOSED


@dataclass(frozen=True, slots=True, kw_only=True)
class Interlocks:
    """The ordering and start-enable rules of SPEC §3 and §5, as data the verifier can vary.

    The defaults are the design; the tests swap in broken sets to show that
    each invariant of ``railstop doors verify`` catches its fault.
    """

    # SPEC §5 order: opening the PSD first, then the train doors. A train door
    # opens only when the PSD unit opposite it is fully open.
    train_opens_when_psd: frozenset[DoorState] = frozenset({DS.OPEN})
    # SPEC §5 order: closing the train doors first, then the PSD. A PSD unit
    # closes only when every train door of its side is closed and locked.
    psd_closes_when_train: frozenset[DoorState] = LOCKED_STATES
    # SPEC §5 fig. 7: what counts as "closed and locked" for start enable.
    locked: frozenset[DoorState] = LOCKED_STATES
    # SPEC §5: the N.C. contact of the zero velocity relay is wired with DMC,
    # so the doors are held closed while the train moves.
    zvr: bool = True


def door_name(kind: str, side: Side, unit: int) -> str:
    """``train door R3`` / ``PSD R3`` (units count from 1 at the front of the train)."""
    return f"{kind} {side.value}{unit + 1}"


def summarise(states: Iterable[DoorState], prefix: str = "") -> str:
    """One word for a group of door units: their common state, or the majority plus the others."""
    seq = list(states)
    if not seq:
        return "none"
    counts: dict[DoorState, int] = {}
    for s in seq:
        counts[s] = counts.get(s, 0) + 1
    if len(counts) == 1:
        return seq[0].value
    major = max(counts, key=lambda s: counts[s])
    others = ", ".join(f"{prefix}{i + 1} {s.value}" for i, s in enumerate(seq) if s != major)
    return f"{major.value} except {others}"


class DoorSignals(NamedTuple):
    """The door signals of SPEC §5, as the ATC (automatic) or the manual controls give them.

    Manual driving: door-side selector <-> DOA, door-open button <-> DOC,
    door-close button <-> DCC; DMC stays an ATC output (vital) in both modes.
    """

    doa_l: bool = False
    doa_r: bool = False
    dmc_l: bool = True
    dmc_r: bool = True
    doc: bool = False
    dcc: bool = False

    def doa(self, side: Side) -> bool:
        return self.doa_l if side == Side.L else self.doa_r

    def dmc(self, side: Side) -> bool:
        return self.dmc_l if side == Side.L else self.dmc_r

    def with_side(self, side: Side, *, doa: bool | None = None, dmc: bool | None = None) -> DoorSignals:
        """A copy with DOA and/or DMC of ``side`` changed."""
        s = self
        if doa is not None:
            s = s._replace(doa_l=doa) if side == Side.L else s._replace(doa_r=doa)
        if dmc is not None:
            s = s._replace(dmc_l=dmc) if side == Side.L else s._replace(dmc_r=dmc)
        return s
