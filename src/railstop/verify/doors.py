"""Exhaustive proof of the door interlocks: breadth-first search over every reachable state.

The state is the whole ``World`` of ``nodes/doors.py``: every train door
unit of both sides, every PSD unit, the fault latches of CPCS and WPCS, the
precise-stop confirmation (phase and failed attempts), whether the train moves
and whether it stands in position, for both platform sides. From each state
the search tries every event the outside world can produce there (each door
unit finishing its move, obstructed, jamming, isolated by staff; the train
stopping in or out of position; PSC reply or time-out; the link falling
silent with PSC high; traction) under every
combination of the external inputs: DOA-L/R, DMC-L/R, DOC, DCC (64), driving
mode automatic/manual (2), WPCS automatic or switched to manual by the WCC with
the panel's open/close buttons (1 + 4). No sampling.

Each transition is checked against the invariants below. They are plain
functions of (state before, inputs, event, state after, model), so a test can
hand the search a broken action table, door table, stop-confirmation table or
interlock set and watch the matching invariant fail.
"""

from __future__ import annotations

import functools
import itertools
import time
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

from railstop.control.doors import CLOSED_STATES, LOCKED_STATES, DoorSignals, DoorState, Side
from railstop.nodes.doors import (
    Controls,
    DoorModel,
    Event,
    EventKind,
    World,
    apply_event,
    emergency_brake,
    events,
    psc,
    scan_units,
    start_enabled,
)
from railstop.verify.invariants import Invariant, Violation

CheckFn = Callable[[World, Controls, Event, World, tuple[str, ...], DoorModel], "str | None"]


def _units(world: World) -> list[tuple[str, Side, int, DoorState]]:
    out = [("train door", Side.L, i, u) for i, u in enumerate(world.cpcs.left)]
    out += [("train door", Side.R, i, u) for i, u in enumerate(world.cpcs.right)]
    out += [("PSD", world.wpcs.side, i, u) for i, u in enumerate(world.wpcs.units)]
    return out


def _closed_while_moving(
    before: World, c: Controls, ev: Event, after: World, errors: tuple[str, ...], model: DoorModel
) -> str | None:
    # SPEC §5: the ZVR holds the doors closed while moving; SPEC §3: departure only with PSD closed.
    if not after.moving:
        return None
    for kind, side, i, u in _units(after):
        if u not in CLOSED_STATES:
            return f"{kind} {side.value}{i + 1} is {u.value} while the train moves"
    return None


def _opened(before: DoorState, after: DoorState) -> bool:
    return after == DoorState.OPENING and before != DoorState.OPENING


def _no_open_without_authority(
    before: World, c: Controls, ev: Event, after: World, errors: tuple[str, ...], model: DoorModel
) -> str | None:
    # SPEC §5: DMC overrides DOA, DOC, DCC; open only with DOA=1 and DMC=0 on that side.
    if after.cpcs is before.cpcs and after.wpcs is before.wpcs:
        return None
    s = c.signals
    for kind, side, i in _opened_units(before, after):
        if s.dmc(side) or not s.doa(side):
            return (
                f"{kind} {side.value}{i + 1} opens with DOA-{side.value}={int(s.doa(side))}, "
                f"DMC-{side.value}={int(s.dmc(side))}"
            )
    return None


@functools.lru_cache(maxsize=4096)
def _opened_units(before: World, after: World) -> tuple[tuple[str, Side, int], ...]:
    return tuple(
        (kind, side, i)
        for (kind, side, i, u0), (_, _, _, u1) in zip(_units(before), _units(after), strict=True)
        if _opened(u0, u1)
    )


def _train_after_psd(
    before: World, c: Controls, ev: Event, after: World, errors: tuple[str, ...], model: DoorModel
) -> str | None:
    # SPEC §5 order: opening the PSD first, then the train doors (no PSD opposite: never).
    if after.cpcs is before.cpcs:
        return None
    for side in (Side.L, Side.R):
        for i, (u0, u1) in enumerate(zip(before.cpcs.side(side), after.cpcs.side(side), strict=True)):
            if _opened(u0, u1):
                if after.wpcs.side != side:
                    return f"train door {side.value}{i + 1} opens on the side without a platform"
                psd = after.wpcs.units[i]
                if psd != DoorState.OPEN:
                    return f"train door {side.value}{i + 1} opens while the PSD opposite is {psd.value}"
    return None


def _psd_after_train(
    before: World, c: Controls, ev: Event, after: World, errors: tuple[str, ...], model: DoorModel
) -> str | None:
    # SPEC §5 order: closing the train doors first, then the PSD: a PSD unit starts closing only
    # once every train door of its side is closed and locked (SPEC §5 fig. 7's "closed and
    # locked"; a door shut but not yet locked does not count). Judged against LOCKED_STATES, not
    # the model's own interlock set, so that a looser set is caught.
    if after.wpcs is before.wpcs:
        return None
    side = after.wpcs.side
    for i, (u0, u1) in enumerate(zip(before.wpcs.units, after.wpcs.units, strict=True)):
        if u1 == DoorState.CLOSING and u0 != DoorState.CLOSING:
            for j, t in enumerate(after.cpcs.side(side)):
                if t not in LOCKED_STATES:
                    return f"PSD {side.value}{i + 1} closes while train door {side.value}{j + 1} is {t.value}"
    return None


def _start_enable_safe(
    before: World, c: Controls, ev: Event, after: World, errors: tuple[str, ...], model: DoorModel
) -> str | None:
    # SPEC §5 fig. 7: start enable only with everything closed and locked and PSC high.
    if not start_enabled(after, model):
        return None
    if not psc(after):
        return "start enable without PSC"
    for kind, side, i, u in _units(after):
        if u not in LOCKED_STATES:
            return f"start enable while {kind} {side.value}{i + 1} is {u.value}"
    return None


def _attempts_brake(
    before: World, c: Controls, ev: Event, after: World, errors: tuple[str, ...], model: DoorModel
) -> str | None:
    # SPEC §5: after 3 attempts without PSC, fault and emergency brake.
    if after.stop.failed >= model.max_psc_attempts and not emergency_brake(after):
        return f"{after.stop.failed} PSC attempts failed but no emergency brake ({after.stop.phase.value})"
    return None


def _link_lost_brake(
    before: World, c: Controls, ev: Event, after: World, errors: tuple[str, ...], model: DoorModel
) -> str | None:
    # SPEC §5: the PSD state counts only while PSC is high; [interpretation] a link lost with
    # PSC high is the fault (emergency brake), and the train never leaves on it.
    if ev.kind != EventKind.LINK_LOST:
        return None
    if not emergency_brake(after) or start_enabled(after, model) or psc(after):
        return (
            f"link lost with PSC high but {after.stop.phase.value}, no emergency brake or start enable kept"
        )
    return None


def _no_interlock_error(
    before: World, c: Controls, ev: Event, after: World, errors: tuple[str, ...], model: DoorModel
) -> str | None:
    # DESIGN rule 2: the controllers only ever give a unit an input its table allows.
    return errors[0] if errors else None


INVARIANTS: tuple[Invariant[CheckFn], ...] = (
    Invariant(
        name="closed-while-moving",
        text="no train door or PSD door open while speed > 0",
        check=_closed_while_moving,
    ),
    Invariant(
        name="dmc-doa-authority",
        text="nothing opens while DMC = 1 or DOA = 0 on that side",
        check=_no_open_without_authority,
        per_input=True,
    ),
    Invariant(
        name="psd-opens-first",
        text="a train door never opens before the PSD opposite it is open",
        check=_train_after_psd,
    ),
    Invariant(
        name="train-closes-first",
        text="the PSD starts closing only after the train doors of its side are closed and locked",
        check=_psd_after_train,
    ),
    Invariant(
        name="start-enable-safe",
        text="start enable implies every door closed and locked and PSC high",
        check=_start_enable_safe,
    ),
    Invariant(
        name="psc-attempts-brake",
        text="the failed PSC attempts always lead to fault and emergency brake",
        check=_attempts_brake,
    ),
    Invariant(
        name="link-lost-brake",
        text="a link lost with PSC high ends in fault and emergency brake, never in start enable",
        check=_link_lost_brake,
    ),
    Invariant(
        name="no-interlock-error",
        text="no unit is ever given an input its transition table does not allow",
        check=_no_interlock_error,
    ),
)


def all_controls() -> tuple[Controls, ...]:
    """Every combination of the external inputs: 64 signal sets x 2 modes x 5 WPCS controls."""
    out = []
    for bits in itertools.product((False, True), repeat=6):
        signals = DoorSignals(*bits)
        for manual in (False, True):
            out.append(Controls(signals=signals, manual=manual))
            for panel_open, panel_close in itertools.product((False, True), repeat=2):
                out.append(
                    Controls(
                        signals=signals,
                        manual=manual,
                        wcc_manual=True,
                        panel_open=panel_open,
                        panel_close=panel_close,
                    )
                )
    return tuple(out)


@dataclass(frozen=True, slots=True, kw_only=True)
class VerifyResult:
    states: int
    transitions: int
    controls: int  # input combinations tried per event
    doors_per_side: int
    counts: dict[str, int]  # violating transitions per invariant (every invariant listed)
    examples: tuple[Violation, ...]  # the first violation of each violated invariant
    elapsed_s: float
    # What the reachable states contain (evidence that the proof is not vacuous):
    # "train_door" / "psd" -> door states reached, "stop" -> stop phases reached,
    # "moving" -> stop phases in which the train was seen moving.
    coverage: dict[str, tuple[str, ...]]

    @property
    def violations(self) -> int:
        return sum(self.counts.values())

    def summary(self) -> dict[str, object]:
        return {
            "states": self.states,
            "transitions": self.transitions,
            "violations": self.violations,
            "controls_per_event": self.controls,
            "doors_per_side": self.doors_per_side,
            "invariants": self.counts,
            "examples": [
                {"invariant": v.invariant, "message": v.message, "trace": list(v.trace)}
                for v in self.examples
            ],
            "elapsed_s": round(self.elapsed_s, 3),
            "coverage": {k: list(v) for k, v in self.coverage.items()},
        }


def describe(world: World) -> str:
    """A one-line picture of a state."""

    def units(seq: Sequence[DoorState]) -> str:
        return ",".join(u.value for u in seq)

    flags = [
        "moving" if world.moving else "stopped",
        "in-position" if world.in_position else "out-of-position",
        f"stop={world.stop.phase.value}/{world.stop.failed}",
        f"train-L=[{units(world.cpcs.left)}]",
        f"train-R=[{units(world.cpcs.right)}]",
        f"PSD-{world.wpcs.side.value}=[{units(world.wpcs.units)}]",
    ]
    if world.cpcs.fault:
        flags.append("CPCS-fault")
    if world.wpcs.fault:
        flags.append("WPCS-fault")
    return " ".join(flags)


def describe_controls(c: Controls) -> str:
    s = c.signals
    text = (
        f"DOA-L={int(s.doa_l)} DOA-R={int(s.doa_r)} DMC-L={int(s.dmc_l)} DMC-R={int(s.dmc_r)} "
        f"DOC={int(s.doc)} DCC={int(s.dcc)} {'manual' if c.manual else 'auto'}"
    )
    if c.wcc_manual:
        text += f" WCC-manual panel-open={int(c.panel_open)} panel-close={int(c.panel_close)}"
    return text


def verify(
    model: DoorModel,
    *,
    doors_per_side: int = 1,
    invariants: Sequence[Invariant[CheckFn]] = INVARIANTS,
    max_states: int = 2_000_000,
    stop_on_violation: bool = False,
) -> VerifyResult:
    """Explore every state reachable from a train arriving at either platform side.

    ``stop_on_violation``: return at the first violation (the tests of broken
    tables only need to see that one is found).
    """
    if doors_per_side < 1:
        raise ValueError(f"doors_per_side: must be at least 1 (got {doors_per_side})")
    start = time.perf_counter()
    controls = all_controls()
    initial = [World.arriving(platform_side=side, doors_per_side=doors_per_side) for side in (Side.L, Side.R)]
    parent: dict[World, tuple[World, Controls, Event] | None] = {w: None for w in initial}
    queue: deque[World] = deque(initial)
    counts = {inv.name: 0 for inv in invariants}
    examples: dict[str, Violation] = {}
    transitions = 0
    while queue:
        world = queue.popleft()
        for event in events(world, model):
            mid, e1 = apply_event(world, event, model)
            memo: dict[object, object] = {}
            groups: dict[tuple[World, str | None], list[Controls]] = {}
            for c in controls:
                groups.setdefault(scan_units(mid, c, model, memo), []).append(c)
            transitions += len(controls)
            for (after, e2), group in groups.items():
                errors = tuple(e for e in (e1, e2) if e is not None)
                for inv in invariants:
                    for c in group if inv.per_input else group[:1]:
                        message = inv.check(world, c, event, after, errors, model)
                        if message is None:
                            continue
                        counts[inv.name] += 1 if inv.per_input else len(group)
                        if inv.name not in examples:
                            trace = (*_trace(parent, world), f"{describe_controls(c)}; {event.describe()}")
                            examples[inv.name] = Violation(
                                invariant=inv.name, message=message, trace=(*trace, f"-> {describe(after)}")
                            )
                        if stop_on_violation:
                            return _result(
                                parent,
                                transitions,
                                controls,
                                doors_per_side,
                                counts,
                                examples,
                                invariants,
                                start,
                            )
                if after not in parent:
                    if len(parent) >= max_states:
                        raise RuntimeError(f"more than {max_states} states: the model is not finite enough")
                    parent[after] = (world, group[0], event)
                    queue.append(after)
    return _result(parent, transitions, controls, doors_per_side, counts, examples, invariants, start)


def _result(
    parent: dict[World, tuple[World, Controls, Event] | None],
    transitions: int,
    controls: tuple[Controls, ...],
    doors_per_side: int,
    counts: dict[str, int],
    examples: dict[str, Violation],
    invariants: Sequence[Invariant[CheckFn]],
    start: float,
) -> VerifyResult:
    return VerifyResult(
        states=len(parent),
        transitions=transitions,
        controls=len(controls),
        doors_per_side=doors_per_side,
        counts=counts,
        examples=tuple(examples[i.name] for i in invariants if i.name in examples),
        elapsed_s=time.perf_counter() - start,
        coverage=_coverage(parent),
    )


def _coverage(states: Iterable[World]) -> dict[str, tuple[str, ...]]:
    train: set[str] = set()
    psd: set[str] = set()
    stop: set[str] = set()
    moving: set[str] = set()
    for w in states:
        train.update(u.value for u in (*w.cpcs.left, *w.cpcs.right))
        psd.update(u.value for u in w.wpcs.units)
        stop.add(w.stop.phase.value)
        if w.moving:
            moving.add(w.stop.phase.value)
    return {
        "train_door": tuple(sorted(train)),
        "psd": tuple(sorted(psd)),
        "stop": tuple(sorted(stop)),
        "moving": tuple(sorted(moving)),
    }


def _trace(parent: dict[World, tuple[World, Controls, Event] | None], world: World) -> list[str]:
    lines: list[str] = []
    cur: World | None = world
    while cur is not None:
        link = parent[cur]
        lines.append(describe(cur))
        if link is None:
            break
        prev, c, ev = link
        lines.append(f"{describe_controls(c)}; {ev.describe()}")
        cur = prev
    lines.reverse()
    return lines
