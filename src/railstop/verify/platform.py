"""Exhaustive check of the platform interlock of SPEC §3: stop sensors -> lamps -> PSD relay -> PSD.

Two breadth-first searches over every reachable state, each driving a real unit
through a small world that gives it every input its real neighbour could give
and more ([interpretation] assume-guarantee: each search takes the other
unit's proven rule as its only assumption, so the two together cover the
wired pair without the product of their states):

**The platform unit** (:class:`~railstop.wayside.platform.PlatformUnit`):

* the train front is in one of five places: approaching, stopped short of
  both sensors, between S2 and S1 (the window), past both, or gone; it moves
  or stands; at a stand the driver may start it again (a correction, a
  departure, or a mistake: the platform cannot stop a driver, it can only
  refuse the PSD and the departure permission);
* every scan the sensors read what they see, except that either may miss
  (a dropout reads "no train"), at most ``max_dropouts`` scans in a row per
  sensor: the debounce is meant to ride out fewer than ``debounce_scans``;
* the PSD opens at any moment the relay is energised (what the PSD control
  guarantees: ``psd-command-only-on-ok`` below) and closes at any moment;
* the signal-open switch goes on and off.

**The PSD control** (:class:`~railstop.wayside.platform.PsdFollower`):

* the relay goes on and off at any moment (whatever the platform unit does);
* the train doors open, close (and may reopen) at a stand, passing through
  opening, open, closing, closed (shut, the lock not yet made) and closed and
  locked; the train starts only with them locked and stops again;
* the CCD camera shows them frame by frame: as they are (``CAMERA``), misread
  as any other shape (at most ``max_misreads`` frames in a row: the control is
  meant to ride out fewer than ``confirm_frames``), or unreadable (without
  bound: a camera may be lost for good); the PSD opens and closes as the
  control commands;
* the lock is made within ``lock_frames`` frames of the leaves shutting (the
  door data's lock time over the camera's frame period): no more frames are
  taken while the doors are shut and not yet locked.

Invariants (data, each a plain function; the tests hand the search a broken
lamp table, unit or control and watch each one fail):

* ``relay-only-on-ok``: after a scan, the PSD relay is energised only with
  OK lit, the train at a stand and its front truly in the window;
* ``departure-psd-closed``: departure is never permitted with the PSD open;
* ``no-lamp-while-moving``: no lamp once a scan has seen the train move;
* ``psd-command-only-on-ok``: the PSD control turns its command to open only
  with the relay energised (OK lit) and the train at a stand;
* ``psd-closes-after-train-locked``: the PSD control turns an open command into
  a close (the PSD starts closing) only with the train doors closed and
  locked, OK lit or not (SPEC §5 order, closing the train doors first; SPEC
  §3: no data link, so the control must know it from the camera; a misread
  frame, or a lost camera, must not shut the PSD on passengers). The one
  exception is what no camera can see: doors the driver reopens after they
  were locked, within the frames the camera may misread in a row.
"""

from __future__ import annotations

import copy
import itertools
import time
from collections import deque
from collections.abc import Callable, Hashable, Iterator, Mapping, Sequence, Set
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

from railstop.messages import (
    DoorCameraFrame,
    PlatformLamps,
    PsdDoorState,
    SignalOpenSwitch,
    StopSensorScan,
)
from railstop.sensors.door_camera import CLOSED, MOVING, OPEN, SHAPES
from railstop.verify.invariants import Invariant, Violation
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
#: The train doors' states at a stand (the door unit's of ``control.doors``, less the faults).
LOCKED = "closed_locked"
DOORS = ("closed_locked", "opening", "open", "closing", "closed")
#: What a correct camera frame shows for each door state (``sensors.door_camera``): "closed"
#: only fully shut, "moving" on the way. [interpretation] The model's "open" door state is the
#: leaves from ``open_fraction`` on (the camera's "open"), its opening and closing the part
#: below: a door's way in and out of "open" is seen as "moving".
CAMERA: Mapping[str, frozenset[str]] = {
    "closed_locked": frozenset({CLOSED}),
    "closed": frozenset({CLOSED}),
    "opening": frozenset({MOVING}),
    "open": frozenset({OPEN}),
    "closing": frozenset({MOVING}),
}
#: The door moves a driver (or an obstacle) starts and the motions that end, at a stand: (from,
#: to, label, the shapes the PSD control must have confirmed first). [interpretation] The train
#: doors take seconds to move and the camera takes a frame every 0.1 s: the control confirms the
#: shape the doors show before they change again (the last 30 % of a closing, "moving", takes
#: about a second) unless the camera is lost. The lock (closed -> closed and locked) is apart:
#: it comes by time.
DOOR_MOVES: tuple[tuple[str, str, str, frozenset[str]], ...] = (
    ("closed_locked", "opening", "train doors open", frozenset({CLOSED})),
    ("opening", "open", "train doors open wide", frozenset({MOVING})),
    ("open", "closing", "train doors close", frozenset({OPEN})),
    ("closing", "closed", "train doors shut", frozenset({MOVING})),
    ("closing", "opening", "train doors reopen", frozenset({MOVING})),
    ("closed", "opening", "train doors reopen", frozenset({CLOSED})),
)


class State(NamedTuple):
    """A state of the platform unit's search (a named tuple: the search makes many of them)."""

    place: str
    moving: bool
    psd_open: bool
    drop_s2: int  # the sensor's dropouts in a row so far
    drop_s1: int
    scanned_moving: bool  # a scan has seen the train move since it started
    unit: tuple[object, ...]  # the platform unit's state


class ControlState(NamedTuple):
    """A state of the PSD control's search."""

    moving: bool
    doors: str  # one of DOORS
    psd_open: bool
    misreads: int  # the camera's misread frames in a row so far
    unlocked_frames: int  # frames taken since the doors shut, the lock not yet made
    left_lock_frames: int  # frames since the doors were last closed and locked (capped)
    follower: tuple[object, ...]  # the PSD control's state


@dataclass(frozen=True, slots=True, kw_only=True)
class Step:
    """One transition of either search (the control's search has no lamp: ``lamp`` None,
    ``psd_enable`` its relay input, ``departure_permitted`` False)."""

    before: State | ControlState
    event: str
    after: State | ControlState
    lamp: str | None
    psd_enable: bool
    departure_permitted: bool
    command_before: bool  # the PSD control's command: open (True) before and after the event
    command_after: bool
    # The train doors were closed and locked and have been reopened since by no more frames than
    # the camera may misread in a row: the control cannot have seen it yet.
    unseen_reopen: bool = False


Check = Callable[[Step], "str | None"]


def _relay_only_on_ok(s: Step) -> str | None:
    # SPEC §3: the PSD operates only while OK is lit, and OK means the front between S2 and S1.
    # Judged at the scans: the platform knows the train only by them (between two scans it
    # still shows what the last one told it).
    a = s.after
    if not isinstance(a, State):
        return None
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
    # SPEC §3: the PSD operates only while OK is lit (fig. 4: sensors -> lamps -> PSD relay; the
    # relay is energised only with OK: relay-only-on-ok). Judged when the command turns to open:
    # an open PSD is held when OK goes dark with the train doors not yet closed and locked
    # (psd-closes-after-train-locked).
    if not isinstance(s.after, ControlState):
        return None
    if not s.command_before and s.command_after and (not s.psd_enable or s.after.moving):
        return f"PSD commanded open with the relay {'on' if s.psd_enable else 'off'}, moving={s.after.moving}"
    return None


def _psd_closes_after_train_locked(s: Step) -> str | None:
    # SPEC §5 order: closing, the train doors first (closed and locked), then the PSD; SPEC §3:
    # the PSD follows the train doors. [interpretation] In every case, OK lit or not: DESIGN
    # rule 10, a PSD never starts closing on a train door that is not closed and locked. A
    # camera cannot see faster than it frames: doors reopened (by the driver) after they were
    # locked, within the misread frames in a row the camera may give, are not yet visible.
    a = s.after
    if not isinstance(a, ControlState):
        return None
    if s.command_before and not s.command_after and a.doors != LOCKED and not s.unseen_reopen:
        return f"PSD commanded closed with the train doors {a.doors}"
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
        text="the PSD control commands the PSD open only with the relay energised (OK lit) and the "
        "train at a stand",
        check=_psd_command_only_on_ok,
    ),
    Invariant(
        name="psd-closes-after-train-locked",
        text="the PSD starts closing only after the train doors are closed and locked, OK lit or not "
        "(fewer misread frames in a row than it confirms; lost frames without bound; the lock made "
        "within the door data's time)",
        check=_psd_closes_after_train_locked,
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
    unit_states: int = 0  # the platform unit's search
    control_states: int = 0  # the PSD control's search


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
        # The closed run matters only to close an open PSD (an "open" frame, which it takes to open
        # one, starts it again): not counted while the command is to close.
        min(f.closed_run, f.locked_after_frames()) if f.command.open else 0,
        f.command,
    )


def _copy(u: PlatformUnit) -> PlatformUnit:
    c = copy.copy(u)
    c.s2 = replace(u.s2)  # the debouncers are the unit's only mutable parts
    c.s1 = replace(u.s1)
    return c


class _Search:
    """Breadth-first search shared by both models: states, their units, the first violations."""

    def __init__(self, invariants: Sequence[Invariant[Check]], max_states: int, stop_when_all: bool) -> None:
        self.invariants = invariants
        self.max_states = max_states
        self.stop_when_all = stop_when_all
        self.counts = {inv.name: 0 for inv in invariants}
        self.examples: dict[str, Violation] = {}
        self.transitions = 0

    def run(
        self,
        first: Hashable,
        objects: object,
        successors: Callable[[Any, Any], Iterator[tuple[str, Hashable, object, Step]]],
    ) -> int:
        parent: dict[Hashable, tuple[Hashable, str] | None] = {first: None}
        held: dict[Hashable, object] = {first: objects}
        queue: deque[Hashable] = deque([first])

        def trace(st: Hashable) -> tuple[str, ...]:
            steps: list[str] = []
            cur: Hashable | None = st
            while cur is not None and parent[cur] is not None:
                prev, ev = parent[cur]  # type: ignore[misc]
                steps.append(ev)
                cur = prev
            return tuple(reversed(steps))

        while queue:
            if self.stop_when_all and all(self.counts.values()):
                break
            st = queue.popleft()
            for label, nxt, obj, step in successors(st, held[st]):
                self.transitions += 1
                for inv in self.invariants:
                    why = inv.check(step)
                    if why is not None:
                        self.counts[inv.name] += 1
                        if inv.name not in self.examples:
                            self.examples[inv.name] = Violation(
                                invariant=inv.name, message=why, trace=(*trace(st), label)
                            )
                if nxt not in parent:
                    if len(parent) >= self.max_states:
                        raise RuntimeError(f"more than {self.max_states} states")
                    parent[nxt] = (st, label)
                    held[nxt] = obj
                    queue.append(nxt)
        return len(parent)


def _unit_moves(state: State) -> list[tuple[str, dict[str, Any]]]:
    """The train's moves possible now (the unit learns of them by the next scan)."""
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
        out.append(("start", {"moving": True, "scanned_moving": False}))
    return out


def _unit_successors(
    max_dropouts: int, lamps_seen: set[str]
) -> Callable[[State, PlatformUnit], Iterator[tuple[str, State, PlatformUnit, Step]]]:
    def successors(st: State, base: PlatformUnit) -> Iterator[tuple[str, State, PlatformUnit, Step]]:
        candidates: list[tuple[str, State, PlatformUnit]] = []
        # 1. the train moves (the unit learns of it by the next scan: unchanged).
        for label, change in _unit_moves(st):
            candidates.append((label, st._replace(**change), base))
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
            candidates.append((what, nxt, u))
        # 3. the PSD: it opens only while the relay is energised (the PSD control's guarantee,
        # psd-command-only-on-ok) and may close at any moment.
        relay = base.lamps().psd_enable
        if st.psd_open or relay:
            u = _copy(base)
            u.handle(PsdDoorState(closed_locked=st.psd_open), 0.0)
            label = "PSD closes" if st.psd_open else "PSD opens"
            candidates.append((label, st._replace(psd_open=not st.psd_open), u))
        # 4. the signal-open switch.
        u = _copy(base)
        u.handle(SignalOpenSwitch(on=not base.signal_open), 0.0)
        candidates.append((f"signal-open switch {'off' if base.signal_open else 'on'}", st, u))
        for label, nxt, u in candidates:
            lamps: PlatformLamps = u.lamps()
            if lamps.lamp:
                lamps_seen.add(lamps.lamp)
            nxt = nxt._replace(unit=_snapshot(u))
            step = Step(
                before=st,
                event=label,
                after=nxt,
                lamp=lamps.lamp,
                psd_enable=lamps.psd_enable,
                departure_permitted=lamps.departure_permitted,
                command_before=False,
                command_after=False,
            )
            yield label, nxt, u, step

    return successors


def _control_successors(
    misreads_allowed: int, lock_limit: int, camera: Mapping[str, Set[str]]
) -> Callable[[ControlState, PsdFollower], Iterator[tuple[str, ControlState, PsdFollower, Step]]]:
    def successors(
        st: ControlState, base: PsdFollower
    ) -> Iterator[tuple[str, ControlState, PsdFollower, Step]]:
        candidates: list[tuple[str, ControlState, PsdFollower]] = []
        truths = camera[st.doors]
        # 1. the train and its doors (the control learns of them by the next frame: unchanged).
        if st.moving:
            candidates.append(("stop", st._replace(moving=False), base))
        else:
            if st.doors == LOCKED:
                candidates.append(("start", st._replace(moving=True), base))
            if st.doors == "closed":
                locked = st._replace(doors=LOCKED, unlocked_frames=0, left_lock_frames=0)
                candidates.append(("train doors locked", locked, base))
            seen = base.shape if base.camera_ok() else None
            for before, after, label, needs in DOOR_MOVES:
                if st.doors == before and (not base.camera_ok() or seen in needs):
                    left = 0 if before == LOCKED else st.left_lock_frames
                    moved = st._replace(doors=after, unlocked_frames=0, left_lock_frames=left)
                    candidates.append((label, moved, base))
        # 2. a camera frame: the doors as they are, misread as another shape, or unreadable. The
        # lock is made within lock_limit frames of the leaves shutting: none beyond that first.
        if st.doors != "closed" or st.unlocked_frames < lock_limit:
            unlocked = st.unlocked_frames + 1 if st.doors == "closed" else 0
            # Counted up to one beyond the misreads in a row: a reopen the control can no longer miss.
            left = 0 if st.doors == LOCKED else min(st.left_lock_frames + 1, misreads_allowed + 1)
            frames: list[tuple[str, str | None, int]] = [
                (f"camera frame: {shape}", shape, 0) for shape in SHAPES if shape in truths
            ]
            if st.misreads < misreads_allowed:
                frames += [
                    (f"camera frame: {shape} (misread)", shape, st.misreads + 1)
                    for shape in SHAPES
                    if shape not in truths
                ]
            frames.append(("camera frame (unreadable)", None, st.misreads))
            for label, shape, misreads in frames:
                f = copy.copy(base)
                f.handle(DoorCameraFrame(shape=shape), 0.0)
                nxt = st._replace(misreads=misreads, unlocked_frames=unlocked, left_lock_frames=left)
                candidates.append((label, nxt, f))
        # 3. the PSD doors do what the PSD control commands.
        if base.command.open != st.psd_open:
            label = "PSD opens" if base.command.open else "PSD closes"
            candidates.append((label, st._replace(psd_open=base.command.open), base))
        # 4. the relay, whatever the platform unit does.
        f = copy.copy(base)
        on = not base.relay
        f.handle(PlatformLamps(lamp="OK" if on else None, psd_enable=on, departure_permitted=False), 0.0)
        candidates.append((f"relay {'on' if on else 'off'}", st, f))
        for label, nxt, f in candidates:
            nxt = nxt._replace(follower=_follower_snapshot(f))
            step = Step(
                before=st,
                event=label,
                after=nxt,
                lamp=None,
                psd_enable=f.relay,
                departure_permitted=False,
                command_before=base.command.open,
                command_after=f.command.open,
                unseen_reopen=nxt.doors != LOCKED and nxt.left_lock_frames <= misreads_allowed,
            )
            yield label, nxt, f, step

    return successors


def verify(
    unit_factory: Callable[[], PlatformUnit],
    *,
    follower_factory: Callable[[], PsdFollower] = PsdFollower,
    max_dropouts: int = 2,
    max_misreads: int | None = None,
    lock_frames: int | None = None,
    camera: Mapping[str, Set[str]] = CAMERA,
    invariants: Sequence[Invariant[Check]] = INVARIANTS,
    max_states: int = 2_000_000,
    stop_when_all_violated: bool = False,
) -> VerifyResult:
    """Search every state of the platform unit from a train approaching an empty platform, and
    every state of the PSD control from a train standing with its doors locked. ``max_misreads``:
    misread camera frames in a row (default: one fewer than the PSD control confirms).
    ``lock_frames``: the most frames taken between the train doors shutting and their lock
    (default: the PSD control's lock count, the shortest the data allows). ``camera``: the shapes
    a correct frame shows for each door state. ``stop_when_all_violated``: end the search once
    every invariant has a counterexample (a broken unit's check needs no more)."""
    start_t = time.perf_counter()
    search = _Search(invariants, max_states, stop_when_all_violated)
    unit0 = unit_factory()
    first = State(
        place="approach",
        moving=True,
        psd_open=False,
        drop_s2=0,
        drop_s1=0,
        scanned_moving=False,
        unit=_snapshot(unit0),
    )
    lamps: set[str] = set()  # the lamps the search reached, for the record
    unit_states = search.run(first, unit0, _unit_successors(max_dropouts, lamps))
    follower0 = follower_factory()
    misreads_allowed = follower0.confirm_frames - 1 if max_misreads is None else max_misreads
    lock_limit = follower0.lock_frames if lock_frames is None else lock_frames
    control_first = ControlState(
        moving=False,
        doors=LOCKED,
        psd_open=False,
        misreads=0,
        unlocked_frames=0,
        left_lock_frames=0,
        follower=_follower_snapshot(follower0),
    )
    control_states = search.run(
        control_first, follower0, _control_successors(misreads_allowed, lock_limit, camera)
    )
    return VerifyResult(
        states=unit_states + control_states,
        transitions=search.transitions,
        violations=sum(search.counts.values()),
        counts=search.counts,
        examples=tuple(search.examples.values()),
        lamps_seen=tuple(sorted(lamps)),
        elapsed_s=round(time.perf_counter() - start_t, 2),
        unit_states=unit_states,
        control_states=control_states,
    )
