"""Exhaustive check of the platform interlock of SPEC §3: stop sensors -> lamps -> PSD relay.

Breadth-first over every reachable state of a small world driven through the
real :class:`~railstop.wayside.platform.PlatformUnit`:

* the train front is in one of five places: approaching, stopped short of
  both sensors, between S2 and S1 (the window), past both, or gone; it moves
  or stands; at a stand the driver may start it again (a correction, a
  departure, or a mistake: the platform cannot stop a driver, it can only
  refuse the PSD and the departure permission);
* every scan the sensors read what they see, except that either may miss
  (a dropout reads "no train"), at most ``max_dropouts`` scans in a row per
  sensor: the debounce is meant to ride out fewer than ``debounce_scans``;
* the train doors open and close at a stand (the zero-velocity relay keeps
  them shut while moving); the PSD follows them (SPEC §3: the camera sees
  the doors) but may open only while the relay is energised, and closes at
  any time;
* the signal-open switch goes on and off.

Invariants (data, each a plain function; the tests hand the search a broken
lamp table or unit and watch each one fail):

* ``relay-only-on-ok``: after a scan, the PSD relay is energised only with
  OK lit, the train at a stand and its front truly in the window;
* ``departure-psd-closed``: departure is never permitted with the PSD open;
* ``no-lamp-while-moving``: no lamp once a scan has seen the train move.
"""

from __future__ import annotations

import copy
import itertools
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

from railstop.messages import PsdDoorState, SignalOpenSwitch, StopSensorScan
from railstop.sim.invariants import Invariant, Violation
from railstop.wayside.platform import PlatformUnit

PLACES = ("approach", "short", "window", "over", "gone")
#: What each sensor truly sees for a front in each place: (S2, S1).
TRUTH: Mapping[str, tuple[bool, bool]] = {
    "approach": (False, False),
    "short": (False, False),
    "window": (True, False),
    "over": (True, True),
    "gone": (False, False),  # the whole train has passed (in the model the platform is empty again)
}


@dataclass(frozen=True, slots=True, kw_only=True)
class State:
    place: str
    moving: bool
    train_doors_open: bool
    psd_open: bool
    drop_s2: int  # the sensor's dropouts in a row so far
    drop_s1: int
    scanned_moving: bool  # a scan has seen the train move since it started
    unit: tuple[object, ...]  # the platform unit's state


@dataclass(frozen=True, slots=True, kw_only=True)
class Step:
    before: State
    event: str
    after: State
    lamp: str | None
    psd_enable: bool
    departure_permitted: bool


Check = Callable[[Step], "str | None"]


def _relay_only_on_ok(s: Step) -> str | None:
    # SPEC §3: the PSD operates only while OK is lit, and OK means the front between S2 and S1.
    # Judged at the scans: the platform knows the train only by them (between two scans it
    # still shows what the last one told it).
    a = s.after
    if s.event.startswith("scan") and s.psd_enable and (s.lamp != "OK" or a.moving or a.place != "window"):
        return f"PSD relay energised with lamp {s.lamp}, the front {a.place}, moving={a.moving}"
    return None


def _departure_psd_closed(s: Step) -> str | None:
    # SPEC §3: departure only with the PSD closed (the PSD is master).
    if s.departure_permitted and s.after.psd_open:
        return "departure permitted with the PSD open"
    return None


def _no_lamp_while_moving(s: Step) -> str | None:
    if s.event.startswith("scan") and s.after.moving and s.lamp is not None:
        return f"lamp {s.lamp} lit while the train moves"
    return None


INVARIANTS: tuple[Invariant[Check], ...] = (
    Invariant(
        name="relay-only-on-ok",
        text="after a scan the PSD relay is energised only with OK lit, the train at a stand, its front "
        "between S2 and S1 (with fewer dropouts in a row than the debounce)",
        check=_relay_only_on_ok,
    ),
    Invariant(
        name="departure-psd-closed",
        text="departure is never permitted with the PSD open",
        check=_departure_psd_closed,
    ),
    Invariant(
        name="no-lamp-while-moving",
        text="no lamp once a scan has seen the train move",
        check=_no_lamp_while_moving,
    ),
)


@dataclass(frozen=True, slots=True, kw_only=True)
class VerifyResult:
    states: int
    transitions: int
    violations: int
    counts: dict[str, int]
    examples: tuple[Violation, ...]
    lamps_seen: tuple[str, ...]
    elapsed_s: float


def _snapshot(u: PlatformUnit) -> tuple[object, ...]:
    # Counts beyond the debounce tell nothing more: capped, so that the state space is finite.
    k = u.debounce_scans
    counts = (min(u.s2.trues, k), min(u.s2.falses, k), min(u.s1.trues, k), min(u.s1.falses, k))
    return (
        u.s2.state,
        u.s1.state,
        *counts,
        u.standstill,
        u.psd_closed,
        u.psd_operated,
        u.signal_open,
        u.last,
    )


def _copy(u: PlatformUnit) -> PlatformUnit:
    c = copy.copy(u)
    c.s2 = copy.copy(u.s2)
    c.s1 = copy.copy(u.s1)
    return c


def _moves(state: State) -> list[tuple[str, dict[str, object]]]:
    """The physical events possible now (the unit learns of them by its inputs)."""
    out: list[tuple[str, dict[str, object]]] = []
    if state.moving and state.scanned_moving:
        # [interpretation] a move between two of the places takes far longer than a scan (50 ms):
        # the platform sees every move at least once.
        nxt = (
            ("short", "window", "over", "gone") if state.place != "approach" else ("short", "window", "over")
        )
        for place in nxt:
            if place == "gone":
                out.append(
                    (
                        "pass: the next train approaches",
                        {"place": "approach", "moving": True, "scanned_moving": False},
                    )
                )
            else:
                out.append((f"stop {place}", {"place": place, "moving": False}))
    else:
        if not state.train_doors_open:
            out.append(("start", {"moving": True, "scanned_moving": False}))
            out.append(("train doors open", {"train_doors_open": True}))
        else:
            out.append(("train doors close", {"train_doors_open": False}))
    return out


def verify(
    unit_factory: Callable[[], PlatformUnit],
    *,
    max_dropouts: int = 2,
    invariants: Sequence[Invariant[Check]] = INVARIANTS,
    max_states: int = 500_000,
) -> VerifyResult:
    """Search every state from a train approaching an empty platform."""
    start_t = time.perf_counter()
    unit0 = unit_factory()
    first = State(
        place="approach",
        moving=True,
        train_doors_open=False,
        psd_open=False,
        drop_s2=0,
        drop_s1=0,
        scanned_moving=False,
        unit=_snapshot(unit0),
    )
    units: dict[State, PlatformUnit] = {first: unit0}
    parent: dict[State, tuple[State, str] | None] = {first: None}
    queue: deque[State] = deque([first])
    counts = {inv.name: 0 for inv in invariants}
    examples: dict[str, Violation] = {}
    transitions = 0
    lamps: set[str] = set()

    def trace(st: State) -> tuple[str, ...]:
        steps: list[str] = []
        cur: State | None = st
        while cur is not None and parent[cur] is not None:
            prev, ev = parent[cur]  # type: ignore[misc]
            steps.append(ev)
            cur = prev
        return tuple(reversed(steps))

    while queue:
        st = queue.popleft()
        base = units[st]
        candidates: list[tuple[str, State, PlatformUnit]] = []
        # 1. a physical event (the next scan tells the unit).
        for label, change in _moves(st):
            u = _copy(base)
            nxt = State(**{**{f: getattr(st, f) for f in State.__dataclass_fields__}, **change})
            candidates.append((label, nxt, u))
        # 2. a scan, with every allowed dropout (a miss reads "no train").
        truth = TRUTH[st.place]
        for d2, d1 in itertools.product((False, True), repeat=2):
            if (d2 and not truth[0]) or (d1 and not truth[1]):
                continue  # nothing to miss
            n2, n1 = (st.drop_s2 + 1 if d2 else 0), (st.drop_s1 + 1 if d1 else 0)
            if n2 > max_dropouts or n1 > max_dropouts:
                continue
            u = _copy(base)
            u.handle(
                StopSensorScan(s2=truth[0] and not d2, s1=truth[1] and not d1, standstill=not st.moving), 0.0
            )
            what = "scan" + (" (S2 missed)" if d2 else "") + (" (S1 missed)" if d1 else "")
            candidates.append(
                (
                    what,
                    State(
                        **{
                            **{f: getattr(st, f) for f in State.__dataclass_fields__},
                            "drop_s2": n2,
                            "drop_s1": n1,
                            "scanned_moving": st.scanned_moving or st.moving,
                        }
                    ),
                    u,
                )
            )
        # 3. the PSD follows the train doors (camera), opening only on the relay.
        if not st.psd_open and st.train_doors_open and base.lamps().psd_enable:
            u = _copy(base)
            u.handle(PsdDoorState(closed_locked=False), 0.0)
            candidates.append(
                (
                    "PSD opens",
                    State(**{**{f: getattr(st, f) for f in State.__dataclass_fields__}, "psd_open": True}),
                    u,
                )
            )
        if st.psd_open and not st.train_doors_open:
            u = _copy(base)
            u.handle(PsdDoorState(closed_locked=True), 0.0)
            candidates.append(
                (
                    "PSD closes",
                    State(**{**{f: getattr(st, f) for f in State.__dataclass_fields__}, "psd_open": False}),
                    u,
                )
            )
        # 4. the signal-open switch.
        u = _copy(base)
        u.handle(SignalOpenSwitch(on=not base.signal_open), 0.0)
        candidates.append((f"signal-open switch {'off' if base.signal_open else 'on'}", st, u))
        for label, nxt, u in candidates:
            transitions += 1
            nxt = State(**{**{f: getattr(nxt, f) for f in State.__dataclass_fields__}, "unit": _snapshot(u)})
            lamps_now = u.lamps()
            if lamps_now.lamp:
                lamps.add(lamps_now.lamp)
            step = Step(
                before=st,
                event=label,
                after=nxt,
                lamp=lamps_now.lamp,
                psd_enable=lamps_now.psd_enable,
                departure_permitted=lamps_now.departure_permitted,
            )
            for inv in invariants:
                why = inv.check(step)
                if why is not None:
                    counts[inv.name] += 1
                    if inv.name not in examples:
                        examples[inv.name] = Violation(
                            invariant=inv.name, message=why, trace=(*trace(st), label)
                        )
            if nxt not in parent:
                if len(parent) >= max_states:
                    raise RuntimeError(f"more than {max_states} states")
                parent[nxt] = (st, label)
                units[nxt] = u
                queue.append(nxt)
    return VerifyResult(
        states=len(parent),
        transitions=transitions,
        violations=sum(counts.values()),
        counts=counts,
        examples=tuple(examples.values()),
        lamps_seen=tuple(sorted(lamps)),
        elapsed_s=round(time.perf_counter() - start_t, 2),
    )
