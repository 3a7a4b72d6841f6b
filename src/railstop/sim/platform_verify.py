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
  them shut while moving);
* the CCD camera shows them to the real PSD control
  (:class:`~railstop.wayside.platform.PsdFollower`) frame by frame: as they
  are, misread (at most ``max_misreads`` frames in a row: the control is
  meant to ride out fewer than ``confirm_frames``), or unreadable (without
  bound: a camera may be lost for good); the PSD opens and closes as the
  control commands;
* the signal-open switch goes on and off.

Invariants (data, each a plain function; the tests hand the search a broken
lamp table or unit and watch each one fail):

* ``relay-only-on-ok``: after a scan, the PSD relay is energised only with
  OK lit, the train at a stand and its front truly in the window;
* ``departure-psd-closed``: departure is never permitted with the PSD open;
* ``no-lamp-while-moving``: no lamp once a scan has seen the train move;
* ``psd-command-only-on-ok``: after a scan, the PSD control commands the PSD
  open only with OK lit, the train at a stand and its front in the window;
* ``psd-not-closed-on-open-doors``: the PSD control never turns an open command
  into a close while the train doors are open and the relay is energised (a
  misread frame, or a lost camera, must not shut the PSD on passengers).
"""

from __future__ import annotations

import copy
import itertools
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

from railstop.messages import DoorCameraFrame, PsdDoorState, SignalOpenSwitch, StopSensorScan
from railstop.sim.invariants import Invariant, Violation
from railstop.wayside.platform import PlatformUnit, PsdFollower

PLACES = ("approach", "short", "window", "over", "gone")
#: What each sensor truly sees for a front in each place: (S2, S1).
TRUTH: Mapping[str, tuple[bool, bool]] = {
    "approach": (False, False),
    "short": (False, False),
    "window": (True, False),
    "over": (True, True),
    "gone": (False, False),  # the whole train has passed (in the model the platform is empty again)
}


class State(NamedTuple):
    """A state of the search (a named tuple: the search makes millions of them)."""

    place: str
    moving: bool
    train_doors_open: bool
    psd_open: bool
    drop_s2: int  # the sensor's dropouts in a row so far
    drop_s1: int
    scanned_moving: bool  # a scan has seen the train move since it started
    misreads: int  # the camera's misread frames in a row so far
    unit: tuple[object, ...]  # the platform unit's state
    follower: tuple[object, ...]  # the PSD control's state


@dataclass(frozen=True, slots=True, kw_only=True)
class Step:
    before: State
    event: str
    after: State
    lamp: str | None
    psd_enable: bool
    departure_permitted: bool
    command_before: bool  # the PSD control's command: open (True) before and after the event
    command_after: bool


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


def _psd_command_only_on_ok(s: Step) -> str | None:
    # SPEC §3: the PSD operates only while OK is lit (fig. 4: sensors -> lamps -> PSD relay).
    a = s.after
    if s.event.startswith("scan") and s.command_after and (s.lamp != "OK" or a.moving or a.place != "window"):
        return f"PSD commanded open with lamp {s.lamp}, the front {a.place}, moving={a.moving}"
    return None


def _psd_not_closed_on_open_doors(s: Step) -> str | None:
    # SPEC §3: the PSD follows the train doors; [interpretation] DESIGN rule 10: an unsure camera
    # holds the PSD where it is rather than shut it on passengers in an open train door.
    if s.command_before and not s.command_after and s.after.train_doors_open and s.psd_enable:
        return "PSD commanded closed with the train doors open and OK lit"
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
    Invariant(
        name="psd-command-only-on-ok",
        text="after a scan the PSD control commands the PSD open only with OK lit, the train at a stand, "
        "its front between S2 and S1",
        check=_psd_command_only_on_ok,
    ),
    Invariant(
        name="psd-not-closed-on-open-doors",
        text="the PSD control never closes an open PSD while the train doors are open and OK is lit "
        "(fewer misread camera frames in a row than it confirms; lost frames without bound)",
        check=_psd_not_closed_on_open_doors,
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


def _follower_snapshot(f: PsdFollower) -> tuple[object, ...]:
    # Capped like the unit's counts: a run beyond the confirmation, a loss beyond the limit tell
    # nothing more.
    return (
        f.relay,
        f.shape,
        f.run_shape,
        min(f.run, f.confirm_frames),
        min(f.lost, f.lost_limit_frames),
        f.command,
    )


def _copy(u: PlatformUnit) -> PlatformUnit:
    c = copy.copy(u)
    c.s2 = replace(u.s2)  # the debouncers are the unit's only mutable parts
    c.s1 = replace(u.s1)
    return c


def _moves(state: State) -> list[tuple[str, dict[str, Any]]]:
    """The physical events possible now (the unit learns of them by its inputs)."""
    out: list[tuple[str, dict[str, Any]]] = []
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
    elif not state.moving:
        if not state.train_doors_open:
            out.append(("start", {"moving": True, "scanned_moving": False}))
            out.append(("train doors open", {"train_doors_open": True}))
        else:
            out.append(("train doors close", {"train_doors_open": False}))
    return out


def verify(
    unit_factory: Callable[[], PlatformUnit],
    *,
    follower_factory: Callable[[], PsdFollower] = PsdFollower,
    max_dropouts: int = 2,
    max_misreads: int | None = None,
    invariants: Sequence[Invariant[Check]] = INVARIANTS,
    max_states: int = 2_000_000,
    stop_when_all_violated: bool = False,
) -> VerifyResult:
    """Search every state from a train approaching an empty platform. ``max_misreads``: misread
    camera frames in a row (default: one fewer than the PSD control confirms).
    ``stop_when_all_violated``: end the search once every invariant has a counterexample (a
    broken unit's check needs no more)."""
    start_t = time.perf_counter()
    unit0 = unit_factory()
    follower0 = follower_factory()
    misreads_allowed = follower0.confirm_frames - 1 if max_misreads is None else max_misreads
    first = State(
        place="approach",
        moving=True,
        train_doors_open=False,
        psd_open=False,
        drop_s2=0,
        drop_s1=0,
        scanned_moving=False,
        misreads=0,
        unit=_snapshot(unit0),
        follower=_follower_snapshot(follower0),
    )
    units: dict[State, tuple[PlatformUnit, PsdFollower]] = {first: (unit0, follower0)}
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
        if stop_when_all_violated and all(counts.values()):
            break
        st = queue.popleft()
        base, base_f = units[st]
        candidates: list[tuple[str, State, PlatformUnit, PsdFollower]] = []
        # 1. a physical event (the next scan tells the unit). [interpretation] The train doors take
        # seconds to move and the camera takes a frame every 0.1 s: each door state is seen long
        # enough for the PSD control to confirm it before the doors change again (unless the camera
        # is lost, when nothing is confirmed).
        settled = base_f.shape == st.train_doors_open or not base_f.camera_ok()
        for label, change in _moves(st):
            if "doors" in label and not settled:
                continue
            # The unit learns of it by the next scan, the control by the next frame: both unchanged.
            candidates.append((label, st._replace(**change), base, base_f))
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
            nxt = st._replace(drop_s2=n2, drop_s1=n1, scanned_moving=st.scanned_moving or st.moving)
            candidates.append((what, nxt, u, base_f))
        # 3. a camera frame: the doors as they are, misread, or unreadable.
        frames: list[tuple[str, bool | None, int]] = [("camera frame", st.train_doors_open, 0)]
        if st.misreads < misreads_allowed:
            frames.append(("camera frame (misread)", not st.train_doors_open, st.misreads + 1))
        frames.append(("camera frame (unreadable)", None, st.misreads))
        for label, seen, misreads in frames:
            f = copy.copy(base_f)
            f.handle(DoorCameraFrame(doors_open=seen), 0.0)
            candidates.append((label, st._replace(misreads=misreads), base, f))
        # 4. the PSD doors do what the PSD control commands.
        if base_f.command.open != st.psd_open:
            u = _copy(base)
            u.handle(PsdDoorState(closed_locked=not base_f.command.open), 0.0)
            label = "PSD opens" if base_f.command.open else "PSD closes"
            candidates.append((label, st._replace(psd_open=base_f.command.open), u, base_f))
        # 5. the signal-open switch.
        u = _copy(base)
        u.handle(SignalOpenSwitch(on=not base.signal_open), 0.0)
        candidates.append((f"signal-open switch {'off' if base.signal_open else 'on'}", st, u, base_f))
        for label, nxt, u, f in candidates:
            transitions += 1
            lamps_now = u.lamps()
            if lamps_now.psd_enable != f.relay:
                # The PSD relay, as the platform unit now drives it. Objects are shared between
                # states until something changes them: copy before.
                if f is base_f:
                    f = copy.copy(base_f)
                f.handle(lamps_now, 0.0)
            nxt = nxt._replace(unit=_snapshot(u), follower=_follower_snapshot(f))
            if lamps_now.lamp:
                lamps.add(lamps_now.lamp)
            step = Step(
                before=st,
                event=label,
                after=nxt,
                lamp=lamps_now.lamp,
                psd_enable=lamps_now.psd_enable,
                departure_permitted=lamps_now.departure_permitted,
                command_before=base_f.command.open,
                command_after=f.command.open,
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
                units[nxt] = (u, f)
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
