"""Exhaustive check of the CBTC zone controller's safety rules (SPEC §4) on a small line.

The search drives the **real** units: the :class:`ZoneController` of
``wayside/zone_controller.py`` and one :class:`OnboardCbtc` of
``onboard/cbtc.py`` per train. Nothing of their rules is re-implemented here;
the model only moves the trains, loses reports and plays the operator, and
keeps its own book of what was sent and received, against which the
invariants judge what the units did.

The model (:class:`ZoneModel`): a few trains, all running in direction R, on a
line of a few segments (blocks of whole segments for the conventional mode),
trains shorter than a segment, a report every cycle, no processing delay
(``initial_world`` and ``World`` also take a delay shorter than the cycle; the
model's trains stand at each report, so Pc = Pp either way, SPEC §4). Time
advances in whole report cycles. In each cycle, from every state, the search
tries every combination of:

* the operator's :class:`ManualRelease` of one flagged train, or none (SPEC §4
  step 5);
* for each train: stay, or advance one step if the authority it holds (its
  onboard unit's) reaches that far and it is not braking; or, for a lost train,
  *move while lost* to the first position outside its zone (SPEC §4 step 5:
  the train found outside its zone, which it could only reach against its
  authority);
* for each train: its report reaches the controller, or is lost (at most
  ``max_losses`` in a row, so that trains get lost and are re-detected).

The onboard timer fires at the start of the cycle (it counts the command it
missed in the last one and sends the report), the reports that are not lost
reach the controller, and the controller's timers run until the next cycle
(its commands, Δt after the reports, go to the onboard units: a report that
reaches the controller is answered; a lost report goes unanswered).

The controller and the onboard units are mutable objects, so the states are
deduplicated on an abstract, hashable :class:`Snapshot`: the trains' positions
(on the model's grid), the model's book (reports lost in a row, commands missed
in a row, last reported position, furthest authority end given), and the
units' records of each train with absolute times made relative and running
counters left out (the units' behaviour is the same at any time origin). Each
transition works on a copy of the units as deep as their state goes
(:func:`copy_unit`, checked against ``copy.deepcopy`` by the tests).

The invariants are plain functions of (snapshot before, the cycle's
:class:`Step`, snapshot after, model), so a test can hand the search a broken
controller or onboard unit (``controller_factory`` / ``onboard_factory``) and
watch the matching invariant fail.
"""

from __future__ import annotations

import copy
import dataclasses
import itertools
import math
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from enum import Enum
from typing import Any, TypeVar

from railstop.config.layout import Cbtc
from railstop.messages import ManualRelease, MovementCommand, OnboardPosition, Output, PositionReport
from railstop.onboard.cbtc import OnboardCbtc
from railstop.quantities import kmh_to_mps
from railstop.verify.invariants import Invariant, Violation
from railstop.wayside.zone_controller import TrainStatus, Zone, ZoneController, ZoneMode

_EPS = 1e-6

_U = TypeVar("_U")

ControllerFactory = Callable[..., ZoneController]
OnboardFactory = Callable[..., OnboardCbtc]


def _default_params() -> Cbtc:
    # SPEC §4: the paper's counts (2 missed reports -> lost, 2 missed commands -> emergency brake);
    # the model's cycle is 1 s (SPEC §4: a heartbeat of 0.5-1 s) and the processing delay 0.
    # [interpretation] The safety margin is 0: the authority may reach the obstacle itself (less
    # the uncertainties and the rollback), the tightest case the invariants must still hold for.
    return Cbtc(
        report_period_s=1.0,
        processing_delay_s=0.0,
        missed_reports_lost=2,
        missed_commands_eb=2,
        safety_margin_m=0.0,
        rollback_m=2.0,
    )


def _speed_limit(_: float) -> float:
    return kmh_to_mps(80.0)


def _flat(_: float) -> float:
    return 0.0


@dataclass(frozen=True, slots=True, kw_only=True)
class ZoneModel:
    """The small line of the search. Trains are numbered 1.. from the rear; all run in R."""

    trains: int = 3
    segments: int = 6
    segment_m: float = 100.0
    segments_per_block: int = 2  # the conventional mode's fixed blocks (200 m)
    overlap_m: float = 50.0  # the conventional zone's overlap beyond both ends
    train_length_m: float = 80.0  # shorter than a segment
    step_m: float = 100.0  # a train advances 0 or 1 step per cycle
    max_losses: int = 3  # reports lost in a row per train, at most
    uncertainty_m: float = 5.0  # every train's reported location uncertainty (IEEE 1474.1)
    params: Cbtc = field(default_factory=_default_params)

    def __post_init__(self) -> None:
        if self.trains < 1:
            raise ValueError(f"trains: at least 1 (got {self.trains})")
        if self.segments < self.trains + 1:
            raise ValueError(f"segments: at least trains + 1 = {self.trains + 1} (got {self.segments})")
        if self.segments_per_block < 1:
            raise ValueError(f"segments_per_block: at least 1 (got {self.segments_per_block})")
        if not 0.0 < self.train_length_m < self.segment_m:
            raise ValueError(f"train_length_m: between 0 and segment_m (got {self.train_length_m})")
        if not 0.0 < self.step_m <= self.segment_m:
            raise ValueError(f"step_m: between 0 and segment_m (got {self.step_m})")
        if self.max_losses < 0:
            raise ValueError(f"max_losses: at least 0 (got {self.max_losses})")
        if not (math.isfinite(self.uncertainty_m) and self.uncertainty_m >= 0.0):
            raise ValueError(f"uncertainty_m: finite and at least 0 (got {self.uncertainty_m})")
        if self.params.processing_delay_s >= self.params.report_period_s:
            raise ValueError("params.processing_delay_s: must be shorter than the report period")

    @property
    def line_end_m(self) -> float:
        return self.segments * self.segment_m

    def segment_list(self) -> list[tuple[float, float]]:
        return [(k * self.segment_m, (k + 1) * self.segment_m) for k in range(self.segments)]

    def block_list(self) -> list[tuple[float, float]]:
        """Blocks of ``segments_per_block`` segments; the last one shorter if they do not divide."""
        b = self.segments_per_block * self.segment_m
        n = -(-self.segments // self.segments_per_block)
        return [(k * b, min((k + 1) * b, self.line_end_m)) for k in range(n)]

    def initial_fronts(self) -> list[float]:
        """Train i (1 = rearmost) with its front in the middle of segment i + 1 (0-based: i), so
        that every train's occupancy straddles a segment boundary (its zone must cover both)."""
        return [(i + 0.5) * self.segment_m for i in range(1, self.trains + 1)]

    def occupancy(self, front_m: float) -> tuple[float, float]:
        """Where a train reported at ``front_m`` may be: its length, its location uncertainty at both
        ends and the rollback allowance behind (IEEE 1474.1)."""
        u = self.uncertainty_m
        return front_m - self.train_length_m - u - self.params.rollback_m, front_m + u


# ---------------------------------------------------------------------- what happens in a cycle


@dataclass(frozen=True, slots=True, kw_only=True)
class TrainAction:
    """What one train does in a cycle: where it goes, and whether its report gets through."""

    train: int
    to_m: float
    deliver: bool
    moved_while_lost: bool = False

    def describe(self, from_m: float) -> str:
        if self.moved_while_lost:
            move = f"moves while lost {from_m:g} -> {self.to_m:g} m"
        elif self.to_m != from_m:
            move = f"advances {from_m:g} -> {self.to_m:g} m"
        else:
            move = f"stands at {from_m:g} m"
        return f"T{self.train} {move}, report {'received' if self.deliver else 'LOST'}"


@dataclass(frozen=True, slots=True, kw_only=True)
class Choice:
    """Everything the outside world decides in one cycle."""

    release: int | None  # the operator's ManualRelease of this (flagged) train
    actions: tuple[TrainAction, ...]


@dataclass(frozen=True, slots=True, kw_only=True)
class TimerRecord:
    """The onboard unit of ``train`` right after its timer fired at the start of the cycle."""

    train: int
    commands_missed: int  # the cycles just ended in a row without a command (the model's count)
    emergency_brake: bool


@dataclass(frozen=True, slots=True, kw_only=True)
class CommandRecord:
    """A command the controller produced, and what it knew when it did."""

    train: int
    front_m: float  # Pc: the reported front (the model's train stands at its report: Pc = Pp)
    authority_m: float
    zones: tuple[Zone, ...]  # the controller's protection zones at that moment
    known: tuple[tuple[int, float], ...]  # (train, last front the controller received), the model's book

    @property
    def end_m(self) -> float:
        return self.front_m + self.authority_m


@dataclass(frozen=True, slots=True, kw_only=True)
class Step:
    """One cycle: what was decided and what the units answered."""

    t_s: float
    releases: tuple[int, ...]  # the trains the operator released (ManualRelease) in the cycle
    actions: tuple[TrainAction, ...]
    timers: tuple[TimerRecord, ...]
    commands: tuple[CommandRecord, ...]

    def action(self, train: int) -> TrainAction | None:
        return next((a for a in self.actions if a.train == train), None)


@dataclass(frozen=True, slots=True, kw_only=True)
class TrainSnapshot:
    train: int
    front_m: float  # where the train really is
    losses: int  # its reports lost in a row (the model's book)
    commands_missed: int  # cycles in a row that ended without a command (the model's book)
    known_m: float | None  # the last front the controller received (the model's book)
    given_end_m: float | None  # the furthest authority end the controller gave it (the model's book)
    intended_end_m: float | None  # the end the controller meant by the last command it got (the book)
    status: TrainStatus  # the controller's
    zone: Zone | None  # the controller's
    emergency_brake: bool  # the onboard unit's
    held_end_m: float | None  # the authority end the onboard unit holds
    unit: tuple[object, ...]  # the rest of the controller's record of the train (for deduplication)
    onboard: tuple[object, ...]  # the rest of the onboard unit's state (for deduplication)


@dataclass(frozen=True, slots=True, kw_only=True)
class Snapshot:
    trains: tuple[TrainSnapshot, ...]

    def train(self, train: int) -> TrainSnapshot:
        return self.trains[train - 1]


_ATOMIC = frozenset({int, float, str, bool, type(None), tuple, frozenset})


_FIELDS: dict[type, tuple[str, ...]] = {}


def _field_names(cls: type) -> tuple[str, ...]:
    names = _FIELDS.get(cls)
    if names is None:
        names = _FIELDS[cls] = tuple(f.name for f in dataclasses.fields(cls))
    return names


def _identity(value: object) -> object:
    return value


def _copy_dict(value: dict[Any, Any]) -> dict[Any, Any]:
    return {k: v if type(v) in _ATOMIC else _copy_value(v) for k, v in value.items()}


def _copy_list(value: list[Any]) -> list[Any]:
    return [v if type(v) in _ATOMIC else _copy_value(v) for v in value]


def _copier_for(cls: type) -> Callable[[Any], Any]:
    """How a value of type ``cls`` is copied: decided once per type (the search copies millions)."""
    if cls in _ATOMIC or issubclass(cls, Enum):
        return _identity
    if issubclass(cls, dict):
        return _copy_dict
    if issubclass(cls, list):
        return _copy_list
    if issubclass(cls, set):
        return set
    params = getattr(cls, "__dataclass_params__", None)
    if params is not None and not params.frozen:
        return _unit_copier_of(cls)
    return _identity  # immutable (frozen dataclasses such as the messages) or shared (parameters, callables)


_COPIERS: dict[type, Callable[[Any], Any]] = {}


def _copy_value(value: object) -> object:
    cls = type(value)
    copier = _COPIERS.get(cls)
    if copier is None:
        copier = _COPIERS[cls] = _copier_for(cls)
    return copier(value)


_SLOTTED: dict[type, tuple[str, ...]] = {}


def _slotted_fields(cls: type) -> tuple[str, ...]:
    """The fields of ``cls`` kept in slots (the rest, and any extra attribute, are in ``__dict__``)."""
    names = _SLOTTED.get(cls)
    if names is None:
        slots = {n for k in cls.__mro__ for n in getattr(k, "__slots__", ())}
        names = _SLOTTED[cls] = tuple(n for n in _field_names(cls) if n in slots)
    return names


def copy_unit(unit: _U) -> _U:
    """A copy of a unit (a mutable dataclass) as deep as its state goes: its dicts, lists, sets and
    mutable dataclasses are copied, recursively; everything else is immutable (numbers, strings,
    enums, tuples of those, frozen dataclasses such as the messages) or the line's shared data (the
    parameters, the callables). Equivalent to ``copy.deepcopy`` for the units here, many times
    faster (tests/verify/test_zones_verify.py compares the two)."""
    return _unit_copier_of(type(unit))(unit)


_UNIT_COPIERS: dict[type, Callable[[Any], Any]] = {}


def _unit_copier_of(cls: type) -> Callable[[Any], Any]:
    copier = _UNIT_COPIERS.get(cls)
    if copier is None:
        copier = _UNIT_COPIERS[cls] = _unit_copier(cls)
    return copier


_COPY_DICT = (
    "    new.__dict__.update({k: v if type(v) in ATOMIC else COPY(v) for k, v in unit.__dict__.items()})"
)


def _generated(name: str, lines: list[str], namespace: dict[str, Any]) -> Callable[..., Any]:
    """The function ``name`` defined by ``lines`` (Python source) in ``namespace``."""
    exec(compile("\n".join(lines) + "\n", f"<railstop.verify.zones {name}>", "exec"), namespace)
    fn: Callable[..., Any] = namespace[name]
    return fn


def _unit_copier(cls: type) -> Callable[[Any], Any]:
    """:func:`copy_unit` for ``cls``, written out once per class: one statement per field, the
    shared decisions (which fields, how a value is copied) taken here rather than per copy (the
    search copies units hundreds of thousands of times)."""
    plain_set = getattr(cls, "__setattr__", object.__setattr__) is object.__setattr__
    lines = ["def copy_unit_of(unit):", "    new = CLS.__new__(CLS)"]
    if cls.__dictoffset__:  # the fields (and any extra attribute) of a class without slots
        lines.append(_COPY_DICT)
    for name in _slotted_fields(cls):
        lines.append(f"    v = unit.{name}")
        value = "v if type(v) in ATOMIC else COPY(v)"
        lines.append(f"    new.{name} = {value}" if plain_set else f"    SET(new, {name!r}, {value})")
    lines.append("    return new")
    namespace = {"CLS": cls, "ATOMIC": _ATOMIC, "COPY": _copy_value, "SET": object.__setattr__}
    return _generated("copy_unit_of", lines, namespace)


def _num(x: float) -> float | None:
    """A float fit for a hashable key: NaN (which is not equal to itself) becomes None."""
    return None if math.isnan(x) else x


def _plain(value: object) -> object:
    """A hashable stand-in for a unit's field."""
    cls = type(value)
    if cls is float:
        return None if value != value else value
    if cls in _ATOMIC or isinstance(value, Enum):
        return value
    if isinstance(value, float):  # a float subclass
        return _num(value)
    if isinstance(value, dict):  # e.g. counters by cause
        return tuple(sorted((repr(k), _plain(v)) for k, v in value.items()))
    if isinstance(value, list | set):
        return tuple(_plain(v) for v in value)
    return value


# The onboard unit's running counters and absolute times: left out of the state (its behaviour
# does not depend on them).
_ONBOARD_SKIP = frozenset(
    {
        "commands",
        "eb_count",
        "eb_causes",
        "foreign_commands",
        "refused_commands",
        "_next_report_s",
        "start_s",
        "params",
    }
)


# How a field enters the snapshot: as it is, or its absolute times made ages (decided per class).
_PLAIN, _WATCHDOG, _REPORT, _ANSWERED, _SENT, _WATCHDOG_AGE = range(6)
_ONBOARD_KINDS = {"_answered_s": _ANSWERED, "watchdog": _WATCHDOG, "_sent": _SENT}


def _onboard_plan(cls: type) -> tuple[tuple[str, int], ...]:
    """The onboard unit's state: its fields but the running counters and absolute times."""
    return tuple((n, _ONBOARD_KINDS.get(n, _PLAIN)) for n in _field_names(cls) if n not in _ONBOARD_SKIP)


#: The types ``_plain`` returns as they are (a float may be NaN, which it makes None).
_AS_IS = _ATOMIC - {float}


def _plain_expression(value: str) -> str:
    """``_plain(value)`` as an expression, with its common cases inline (``value`` a name)."""
    v = value
    return (
        f"{v} if type({v}) in AS_IS else (None if {v} != {v} else {v}) if type({v}) is float else PLAIN({v})"
    )


_SnapshotFn = Callable[[Any, float, float], tuple[object, ...]]


def _snapshot_fn(plan: tuple[tuple[str, int], ...], name: str) -> _SnapshotFn:
    """The hashable stand-in of a unit's fields by ``plan`` (each field's kind), written out once
    per class: ``fn(unit, t_s, report period)`` (the search takes one per train and transition)."""
    lines = [f"def {name}(unit, t_s, period):"]
    parts = []
    for i, (field_name, kind) in enumerate(plan):
        lines.append(f"    v = unit.{field_name}")
        if kind == _PLAIN:
            lines.append(f"    p{i} = {_plain_expression('v')}")
        elif kind == _ANSWERED:  # an absolute time -> its age in cycles
            lines.append(f"    p{i} = None if isinf(v) else round((t_s - v) / period, 6)")
        elif kind == _WATCHDOG_AGE:  # the controller's: its last report's absolute time -> age
            age = "None if isinf(v.fed_s) else round((t_s - v.fed_s) / period, 6)"
            lines.append(f"    p{i} = ({age}, v.missed)")
        elif kind == _WATCHDOG:  # the onboard's, counted on the report cycle: its feed time is never read
            lines.append(f"    p{i} = (v.missed, v.fed_in_cycle)")
        elif kind == _REPORT:  # a kept report without its time
            lines.append("    if isinstance(v, REPORT):")
            lines.append("        v = (v.position_m, v.speed_mps, v.direction)")
            lines.append(f"    p{i} = {_plain_expression('v')}")
        else:  # _SENT: the reports sent, their times made ages
            lines.append(
                f"    p{i} = tuple([(round((t_s - r.time_s) / period, 6), r.position_m, r.speed_mps,"
                " r.uncertainty_m) for r in v])"
            )
        parts.append(f"p{i}")
    lines.append(f"    return ({', '.join(parts)}{',' if len(parts) == 1 else ''})")
    namespace = {"AS_IS": _AS_IS, "PLAIN": _plain, "isinf": math.isinf, "REPORT": PositionReport}
    return _generated(name, lines, namespace)


_SNAPSHOT_FNS: dict[tuple[str, type], _SnapshotFn] = {}


def _snapshot_of(role: str, unit: object, t_s: float, period: float) -> tuple[object, ...]:
    """The snapshot of ``unit`` in its ``role`` (``"onboard"`` or ``"record"``, its plan); the
    plan and its function are made once per class."""
    cls = type(unit)
    fn = _SNAPSHOT_FNS.get((role, cls))
    if fn is None:
        if role == "onboard":
            fn = _snapshot_fn(_onboard_plan(cls), "onboard_snapshot")
        else:
            fn = _snapshot_fn(_record_plan(cls), "record_snapshot")
        _SNAPSHOT_FNS[role, cls] = fn
    return fn(unit, t_s, period)


def _record_plan(cls: type) -> tuple[tuple[str, int], ...]:
    """The controller's record of a train: its watchdog as an age, a kept report without its time."""
    return tuple((n, _WATCHDOG_AGE if n == "watchdog" else _REPORT) for n in _field_names(cls))


class World:
    """The units and the model's book: one state of the search, mutable while a cycle runs."""

    def __init__(
        self,
        model: ZoneModel,
        mode: ZoneMode,
        controller_factory: ControllerFactory = ZoneController,
        onboard_factory: OnboardFactory = OnboardCbtc,
        fronts: Sequence[float] | None = None,
    ) -> None:
        self.model = model
        fronts = list(model.initial_fronts() if fronts is None else fronts)
        self.zc = controller_factory(
            params=model.params,
            segments=model.segment_list(),
            blocks=model.block_list(),
            overlap_m=model.overlap_m,
            train_length_m=model.train_length_m,
            line_end_m=model.line_end_m,
            limit_at=_speed_limit,
            gradient_at=_flat,
            mode=mode,
        )
        self.onboards = [
            onboard_factory(train_id=i + 1, direction="R", params=model.params, curve_decel_mps2=1.0)
            for i in range(len(fronts))
        ]
        self.fronts = fronts
        self.t_s = 0.0  # the cycle to come
        n = len(fronts)
        self.losses = [0] * n
        self.commands_missed = [0] * n
        self.got_command = [False] * n  # in the cycle under way
        self.known: list[float | None] = [None] * n
        self.given_end: list[float | None] = [None] * n
        self.intended_end: list[float | None] = [None] * n
        # The cycle under way:
        self._actions: list[TrainAction] = []
        self._timers: list[TimerRecord] = []
        self._releases: list[int] = []
        self._acted: set[int] = set()

    @property
    def trains(self) -> int:
        return len(self.fronts)

    def clone(self) -> World:
        """An independent copy: the units' state is copied (see :func:`copy_unit`), the model and the
        line's data are shared (never changed)."""
        w = copy.copy(self)
        w.zc = copy_unit(self.zc)
        w.onboards = [copy_unit(ob) for ob in self.onboards]
        names = ("fronts", "losses", "commands_missed", "got_command", "known", "given_end", "intended_end")
        for name in (*names, "_actions"):
            setattr(w, name, list(getattr(self, name)))
        w._timers = list(self._timers)
        w._releases = list(self._releases)
        w._acted = set(self._acted)
        return w

    # ------------------------------------------------------------------ one cycle, piece by piece

    def release(self, train: int) -> None:
        """SPEC §4 step 5: the operator releases the train's zone after visual confirmation."""
        self.zc.handle(ManualRelease(train_id=train), self.t_s)
        self._releases.append(train)

    def turn(self, action: TrainAction) -> None:
        """The train moves, its onboard timer fires (SPEC §4: a cycle without a command is a missed
        command) and sends the report, which reaches the controller or is lost."""
        i = action.train - 1
        if action.train in self._acted:
            raise ValueError(f"train {action.train} has already had its turn this cycle")
        self._acted.add(action.train)
        self.fronts[i] = action.to_m
        ob = self.onboards[i]
        # [interpretation] The model abstracts speed away: a train moves in whole steps between
        # cycles and stands at each report (speed 0), so the onboard speed supervision (tested in
        # the unit tests) stays quiet and the emergency brake releases with the next command.
        position = OnboardPosition(
            position_m=action.to_m, speed_mps=0.0, uncertainty_m=self.model.uncertainty_m
        )
        ob.handle(position, self.t_s)
        self.got_command[i] = False
        outs = ob.on_timer(self.t_s)
        self._timers.append(
            TimerRecord(
                train=action.train,
                commands_missed=self.commands_missed[i],
                emergency_brake=ob.emergency_brake,
            )
        )
        self._actions.append(action)
        if action.deliver:
            self.losses[i] = 0
            for out in outs:
                if isinstance(out.message, PositionReport):
                    self.zc.handle(out.message, self.t_s)
                    self.known[i] = out.message.position_m
        else:
            self.losses[i] += 1

    def has_turned(self, train: int) -> bool:
        """Whether the train has had its turn in the cycle under way."""
        return train in self._acted

    def close(self) -> Step:
        """Trains without a turn stand and report; the controller's timers run until the next cycle;
        its commands reach the onboard units. Returns the cycle's :class:`Step`."""
        for train in range(1, self.trains + 1):
            if train not in self._acted:
                self.turn(TrainAction(train=train, to_m=self.fronts[train - 1], deliver=True))
        t0, t1 = self.t_s, self.t_s + self.model.params.report_period_s
        commands: list[CommandRecord] = []
        now = t0
        while True:
            commands += self._deliver(self.zc.on_timer(now), now)
            deadline = self.zc.next_deadline_s()
            if deadline is None or deadline >= t1 - 1e-9:
                break
            now = max(deadline, now)
        for i, got in enumerate(self.got_command):
            # SPEC §4: a cycle that ends without a command is a missed command.
            self.commands_missed[i] = 0 if got else self.commands_missed[i] + 1
        step = Step(
            t_s=t0,
            releases=tuple(self._releases),
            actions=tuple(self._actions),
            timers=tuple(self._timers),
            commands=tuple(commands),
        )
        self.t_s = t1
        self._actions, self._timers, self._releases, self._acted = [], [], [], set()
        return step

    def _deliver(self, outs: list[Output], now_s: float) -> list[CommandRecord]:
        records: list[CommandRecord] = []
        zones = tuple(self.zc.zones())
        book = tuple((i + 1, k) for i, k in enumerate(self.known) if k is not None)
        for out in outs:
            cmd = out.message
            if not isinstance(cmd, MovementCommand):
                continue
            i = cmd.train_id - 1
            # The model's trains stand at their reports (speed 0), so Pc = Pp (SPEC §4): the
            # reported front.
            known = self.known[i]
            front = self.fronts[i] if known is None else known
            end = front + cmd.authority_m
            prev = self.given_end[i]
            self.given_end[i] = end if prev is None else max(prev, end)
            self.intended_end[i] = end
            self.got_command[i] = True
            self.onboards[i].handle(cmd, now_s)
            records.append(
                CommandRecord(
                    train=cmd.train_id, front_m=front, authority_m=cmd.authority_m, zones=zones, known=book
                )
            )
        return records

    def cycle(self, choice: Choice) -> Step:
        if choice.release is not None:
            self.release(choice.release)
        for action in choice.actions:
            self.turn(action)
        return self.close()

    # ------------------------------------------------------------------ the abstract state

    def status(self, train: int) -> TrainStatus:
        t = self.zc.trains.get(train)
        return TrainStatus.UNKNOWN if t is None else t.status

    def zone(self, train: int) -> Zone | None:
        t = self.zc.trains.get(train)
        return None if t is None else t.zone

    def snapshot(self) -> Snapshot:
        return Snapshot(trains=tuple(self._train_snapshot(i + 1) for i in range(self.trains)))

    def _train_snapshot(self, train: int) -> TrainSnapshot:
        i = train - 1
        ob = self.onboards[i]
        rec = self.zc.trains.get(train)
        period = self.model.params.report_period_s
        unit = () if rec is None else _snapshot_of("record", rec, self.t_s, period)
        onboard = _snapshot_of("onboard", ob, self.t_s, period)
        return TrainSnapshot(
            train=train,
            front_m=self.fronts[i],
            losses=self.losses[i],
            commands_missed=self.commands_missed[i],
            known_m=self.known[i],
            given_end_m=self.given_end[i],
            intended_end_m=self.intended_end[i],
            status=self.status(train),
            zone=self.zone(train),
            emergency_brake=ob.emergency_brake,
            held_end_m=_num(ob.authority_end_m),
            unit=unit,
            onboard=onboard,
        )

    # ------------------------------------------------------------------ the choices of a cycle

    def room_m(self, train: int) -> float:
        """The furthest the train's front can physically be: the rear of the train ahead, or the
        line's end ([interpretation] the model's line has no exit: the trains stop at its end)."""
        x = self.fronts[train - 1]
        ahead = min((f for f in self.fronts if f > x), default=math.inf)
        return min(ahead - self.model.train_length_m, self.model.line_end_m)

    def reach_m(self, train: int) -> float:
        """The furthest the train may go by itself: it obeys the authority its onboard unit holds
        and its emergency brake (SPEC §4); its own position if it may not move."""
        i = train - 1
        x = self.fronts[i]
        ob = self.onboards[i]
        held = ob.authority_end_m
        if ob.emergency_brake or math.isnan(held):
            return x
        return max(x, min(held, self.room_m(train)))

    def options(self, train: int) -> list[TrainAction]:
        """Every action of ``train`` in the cycle to come."""
        m = self.model
        i = train - 1
        x = self.fronts[i]
        tos: list[tuple[float, bool]] = [(x, False)]
        if x + m.step_m <= self.reach_m(train) + _EPS:
            tos.append((x + m.step_m, False))
        zone = self.zone(train)
        if self.status(train) == TrainStatus.LOST and zone is not None:
            # SPEC §4 step 5: found outside its zone; the first grid position whose occupancy leaves it.
            p = x + max(math.floor((zone.end_m - x) / m.step_m + _EPS) + 1, 1) * m.step_m
            if p <= self.room_m(train) + _EPS:
                tos.append((p, True))
        deliveries = [True] + ([False] if self.losses[i] < m.max_losses else [])
        return [
            TrainAction(train=train, to_m=to, deliver=d, moved_while_lost=mwl)
            for (to, mwl), d in itertools.product(tos, deliveries)
        ]

    def choices(self) -> Iterator[Choice]:
        releases: list[int | None] = [None]
        releases += [t for t in range(1, self.trains + 1) if self.status(t) == TrainStatus.FLAGGED]
        per_train = [self.options(t) for t in range(1, self.trains + 1)]
        for release in releases:
            for actions in itertools.product(*per_train):
                yield Choice(release=release, actions=actions)

    def describe(self) -> str:
        return " | ".join(_describe_train(s) for s in self.snapshot().trains)


def _describe_train(s: TrainSnapshot) -> str:
    text = f"T{s.train} {s.front_m:g} m {s.status.value}"
    if s.zone is not None:
        text += f" zone {s.zone.start_m:g}-{s.zone.end_m:g}"
    if s.held_end_m is not None:
        text += f" MA {s.held_end_m:g}"
    if s.emergency_brake:
        text += " EB"
    return text


def describe_choice(choice: Choice, before: Snapshot, t_s: float) -> str:
    parts = [f"t={t_s:g} s:"]
    if choice.release is not None:
        parts.append(f"operator releases T{choice.release};")
    parts.append("; ".join(a.describe(before.train(a.train).front_m) for a in choice.actions))
    return " ".join(parts)


# ---------------------------------------------------------------------- the invariants

CheckFn = Callable[[Snapshot, Step, Snapshot, ZoneModel], "str | None"]


def _authority_clear(before: Snapshot, step: Step, after: Snapshot, model: ZoneModel) -> str | None:
    # SPEC §4: the authority ends behind the train ahead; *following* trains may not enter a
    # protection zone. [interpretation] An authority already inside a zone set since (the
    # conventional zone reaches back over the overlap) is not *extended*: the command is 0.
    # A train ahead of the lost one is not following it: the zone's rounding may reach under
    # it, and it may run on, away from the zone. IEEE 1474.1: the last reported rear less the
    # train ahead's uncertainty and the rollback (model.occupancy), and the end placed for the
    # train's own front plus its uncertainty.
    margin = model.params.safety_margin_m + model.uncertainty_m
    for c in step.commands:
        limit, why = math.inf, ""
        fronts = dict(c.known)
        for z in c.zones:
            owner = fronts.get(z.train_id)
            if owner is not None and owner <= c.front_m + _EPS:
                continue  # the zone's train is behind this one
            if z.train_id != c.train and z.end_m > c.front_m + _EPS:
                lim = max(z.start_m - margin, c.front_m)
                if lim < limit:
                    limit, why = lim, f"the zone {z.start_m:g}-{z.end_m:g} m of T{z.train_id}"
        for other, front in c.known:
            if other != c.train and front > c.front_m + _EPS:
                rear, _ = model.occupancy(front)  # less its uncertainty and the rollback
                lim = max(rear - margin, c.front_m)
                if lim < limit:
                    limit, why = lim, f"the last reported rear {rear:g} m of T{other}"
        if c.end_m > limit + _EPS:
            return (
                f"T{c.train} at {c.front_m:g} m given an authority to {c.end_m:g} m, beyond {why} "
                f"(limit {limit:g} m)"
            )
    return None


def _no_auto_release_outside(before: Snapshot, step: Step, after: Snapshot, model: ZoneModel) -> str | None:
    # SPEC §4 steps 4-5: re-detected inside the zone -> released automatically; outside -> the
    # zone is kept and only an operator's manual release (after visual confirmation) frees it.
    for b in before.trains:
        a = after.train(b.train)
        act = step.action(b.train)
        manual = b.train in step.releases
        reported = act is not None and act.deliver
        inside = False
        if reported and act is not None and b.zone is not None:
            lo, hi = model.occupancy(act.to_m)
            # [interpretation] Only the part of the train on the controlled line is compared.
            lo, hi = max(lo, 0.0), min(hi, model.line_end_m)
            inside = b.zone.start_m - _EPS <= lo and hi <= b.zone.end_m + _EPS
        auto = b.status == TrainStatus.LOST and reported and inside
        # A zone may grow (a flagged train silent again, [interpretation]); never shrink or go.
        kept = (
            a.zone is not None
            and b.zone is not None
            and (a.zone.start_m <= b.zone.start_m + _EPS and a.zone.end_m >= b.zone.end_m - _EPS)
        )
        if b.zone is not None and not kept and not manual and not auto:
            where = f"at {act.to_m:g} m" if act is not None and reported else "without a report"
            return (
                f"T{b.train}'s zone {b.zone.start_m:g}-{b.zone.end_m:g} m ({b.status.value}) "
                f"{'released' if a.zone is None else 'changed'} {where}, no manual release"
            )
        if b.status == TrainStatus.FLAGGED and a.status != TrainStatus.FLAGGED and not manual:
            return f"flagged T{b.train} became {a.status.value} without a manual release"
        outside = b.status == TrainStatus.LOST and reported and not inside and not manual
        if outside and act is not None and (a.status != TrainStatus.FLAGGED or not kept):
            return (
                f"T{b.train} re-detected at {act.to_m:g} m outside its zone but {a.status.value} "
                f"with zone {a.zone}"
            )
    return None


def _missed_commands_brake(before: Snapshot, step: Step, after: Snapshot, model: ZoneModel) -> str | None:
    # SPEC §4: 2 or more consecutive missed commands -> the onboard unit's emergency brake.
    for r in step.timers:
        if r.commands_missed >= model.params.missed_commands_eb and not r.emergency_brake:
            return f"T{r.train} missed {r.commands_missed} commands in a row but is not braking"
    return None


def _lost_train_zone(before: Snapshot, step: Step, after: Snapshot, model: ZoneModel) -> str | None:
    # SPEC §4: 2 or more consecutive missed reports -> the train is lost; its zone covers every
    # segment from its occupancy end to its forward stop point. [interpretation] The forward stop
    # point is the furthest authority end it was given (any of them may be the one it holds).
    # [interpretation] A flagged train whose reports stop again is left out: it is held with
    # authority 0, its last reported occupancy stays an obstacle, and SPEC §4 step 5 keeps its
    # zone as it is until the manual release (see the report of issue 15).
    for s in after.trains:
        if s.losses < model.params.missed_reports_lost or s.status == TrainStatus.FLAGGED:
            continue
        if s.known_m is None:  # never heard of: not on the controlled line
            continue
        lo, hi = model.occupancy(s.known_m)  # with the uncertainty and the rollback
        if s.given_end_m is not None:
            hi = max(hi, s.given_end_m + model.uncertainty_m)  # its true front may stop that far
        # [interpretation] An authority beyond the line's end (the area's exit) is protected up to
        # the end: the zone is made of the line's segments, and beyond them the train leaves.
        lo, hi = max(lo, 0.0), min(hi, model.line_end_m)
        z = s.zone
        if z is None:
            return f"T{s.train} missed {s.losses} reports in a row ({s.status.value}) but has no zone"
        if z.start_m > lo + _EPS or z.end_m < hi - _EPS:
            return (
                f"lost T{s.train}'s zone {z.start_m:g}-{z.end_m:g} m does not cover its last known "
                f"occupancy and authority {lo:g}-{hi:g} m"
            )
    return None


def _authority_end(before: Snapshot, step: Step, after: Snapshot, model: ZoneModel) -> str | None:
    # SPEC §4: the authority is the distance from Pc of the report the command answers; the
    # onboard unit must take the end the controller meant, never one beyond it (which would eat
    # the margin, the uncertainties and the rollback the controller left before the obstacle),
    # and a newer command's shorter authority replaces a longer one.
    for s in after.trains:
        if s.held_end_m is None:
            continue
        if s.intended_end_m is None:
            return f"T{s.train} holds an authority to {s.held_end_m:g} m that no command gave"
        if s.held_end_m > s.intended_end_m + _EPS:
            return (
                f"T{s.train} holds an authority to {s.held_end_m:g} m, beyond the {s.intended_end_m:g} m "
                "the controller meant by its last command"
            )
    return None


INVARIANTS: tuple[Invariant[CheckFn], ...] = (
    Invariant(
        name="authority-clear",
        text="no authority reaches into the zone of a lost train ahead or beyond the last reported rear "
        "of the train ahead less the margin, both uncertainties and the rollback (a train already "
        "inside a zone gets 0)",
        check=_authority_clear,
    ),
    Invariant(
        name="no-auto-release-outside",
        text="a train re-detected outside its zone keeps it, flagged; only a manual release frees it",
        check=_no_auto_release_outside,
    ),
    Invariant(
        name="missed-commands-brake",
        text="a train that missed 2 commands in a row is braking",
        check=_missed_commands_brake,
    ),
    Invariant(
        name="lost-train-zone",
        text="a lost train has a zone covering its last known occupancy and its furthest authority end",
        check=_lost_train_zone,
    ),
    Invariant(
        name="authority-end",
        text="the onboard authority's end is never beyond the end the controller meant by its last command "
        "(so never beyond the obstacle less the margin, the uncertainties and the rollback)",
        check=_authority_end,
    ),
)


# ---------------------------------------------------------------------- the search


@dataclass(frozen=True, slots=True, kw_only=True)
class VerifyResult:
    mode: ZoneMode
    model: ZoneModel
    states: int
    transitions: int
    counts: dict[str, int]  # violating transitions per invariant (every invariant listed)
    examples: tuple[Violation, ...]  # the first violation of each violated invariant
    elapsed_s: float
    # What the search saw happen (evidence that the proof is not vacuous): transitions in which
    # the controller lost a train, released a zone automatically, flagged a train, released one
    # manually; moves while lost; emergency brakes applied; commands with authority 0 because of
    # a zone; and "status-<s>" for every train status reached.
    coverage: dict[str, int]

    @property
    def violations(self) -> int:
        return sum(self.counts.values())

    def summary(self) -> dict[str, object]:
        return {
            "mode": self.mode.value,
            "trains": self.model.trains,
            "segments": self.model.segments,
            "max_losses": self.model.max_losses,
            "states": self.states,
            "transitions": self.transitions,
            "violations": self.violations,
            "invariants": self.counts,
            "examples": [
                {"invariant": v.invariant, "message": v.message, "trace": list(v.trace)}
                for v in self.examples
            ],
            "elapsed_s": round(self.elapsed_s, 3),
            "coverage": self.coverage,
        }


def initial_world(
    model: ZoneModel,
    mode: ZoneMode,
    controller_factory: ControllerFactory = ZoneController,
    onboard_factory: OnboardFactory = OnboardCbtc,
    fronts: Sequence[float] | None = None,
) -> World:
    """The trains standing at their initial fronts (default: ``model.initial_fronts()``) after one
    cycle in which every report got through and was answered. [interpretation] Before it the
    controller knows no train: a train that never reported is not on the controlled line (its
    entry is another procedure), so the search starts with every train known."""
    w = World(model, mode, controller_factory, onboard_factory, fronts)
    w.close()
    return w


def _coverage_of(world: World, before_counts: tuple[int, ...], step: Step, eb_before: int) -> list[str]:
    c = world.zc.counts
    now = (c.lost, c.auto_releases, c.flagged, c.manual_releases)
    keys = []
    for key, b, a in zip(
        ("lost", "auto-release", "flagged", "manual-release"), before_counts, now, strict=True
    ):
        if a > b:
            keys.append(key)
    if any(a.moved_while_lost for a in step.actions):
        keys.append("moved-while-lost")
    if sum(ob.eb_count for ob in world.onboards) > eb_before:
        keys.append("emergency-brake")
    for cmd in step.commands:
        if cmd.authority_m == 0.0 and any(
            z.train_id != cmd.train and z.start_m < cmd.front_m < z.end_m for z in cmd.zones
        ):
            keys.append("held-inside-zone")
            break
    return keys


#: States explored between two calls of ``verify``'s ``progress``.
PROGRESS_EVERY = 500


def verify(
    model: ZoneModel | None = None,
    *,
    mode: ZoneMode = ZoneMode.MINIMAL,
    invariants: Sequence[Invariant[CheckFn]] = INVARIANTS,
    stop_on_violation: bool = False,
    controller_factory: ControllerFactory = ZoneController,
    onboard_factory: OnboardFactory = OnboardCbtc,
    max_states: int = 1_000_000,
    progress: Callable[[int, int], None] | None = None,
) -> VerifyResult:
    """Explore every state reachable from the initial one, cycle by cycle, through the real units.

    ``controller_factory`` / ``onboard_factory``: build the units (a test passes a broken subclass);
    ``stop_on_violation``: return at the first violation. ``progress(explored, found)``: called
    every ``PROGRESS_EVERY`` states explored, with the states found so far (the search's total is
    known only at its end).
    """
    model = ZoneModel() if model is None else model
    mode = ZoneMode(mode)
    start = time.perf_counter()
    w0 = initial_world(model, mode, controller_factory, onboard_factory)
    s0 = w0.snapshot()
    parent: dict[Snapshot, tuple[Snapshot, Choice, float] | None] = {s0: None}
    queue: deque[tuple[Snapshot, World]] = deque([(s0, w0)])
    counts = {inv.name: 0 for inv in invariants}
    examples: dict[str, Violation] = {}
    coverage: dict[str, int] = {f"status-{s.value}": 0 for s in TrainStatus}
    for s in s0.trains:
        coverage[f"status-{s.status.value}"] += 1
    transitions = 0

    def result() -> VerifyResult:
        return VerifyResult(
            mode=mode,
            model=model,
            states=len(parent),
            transitions=transitions,
            counts=counts,
            examples=tuple(examples[i.name] for i in invariants if i.name in examples),
            elapsed_s=time.perf_counter() - start,
            coverage=coverage,
        )

    explored = 0
    while queue:
        snap, world = queue.popleft()
        explored += 1
        if progress is not None and explored % PROGRESS_EVERY == 0:
            progress(explored, len(parent))
        choices = list(world.choices())
        for n, choice in enumerate(choices):
            # The world leaves the queue here: its last choice runs on it, the others on copies.
            w = world if n == len(choices) - 1 else world.clone()
            c = w.zc.counts
            before_counts = (c.lost, c.auto_releases, c.flagged, c.manual_releases)
            eb_before = sum(ob.eb_count for ob in w.onboards)
            t_s = w.t_s
            step = w.cycle(choice)
            after = w.snapshot()
            transitions += 1
            for key in _coverage_of(w, before_counts, step, eb_before):
                coverage[key] = coverage.get(key, 0) + 1
            for inv in invariants:
                message = inv.check(snap, step, after, model)
                if message is None:
                    continue
                counts[inv.name] += 1
                if inv.name not in examples:
                    trace = (*_trace(parent, snap), describe_choice(choice, snap, t_s), f"-> {w.describe()}")
                    examples[inv.name] = Violation(invariant=inv.name, message=message, trace=trace)
                if stop_on_violation:
                    return result()
            if after not in parent:
                if len(parent) >= max_states:
                    raise RuntimeError(f"more than {max_states} states: the model is not finite enough")
                parent[after] = (snap, choice, t_s)
                for s in after.trains:
                    coverage[f"status-{s.status.value}"] += 1
                queue.append((after, w))
    return result()


def describe_snapshot(s: Snapshot) -> str:
    return " | ".join(_describe_train(t) for t in s.trains)


def _trace(parent: dict[Snapshot, tuple[Snapshot, Choice, float] | None], snap: Snapshot) -> list[str]:
    lines: list[str] = []
    cur: Snapshot | None = snap
    while cur is not None:
        lines.append(describe_snapshot(cur))
        link = parent[cur]
        if link is None:
            break
        prev, choice, t_s = link
        lines.append(describe_choice(choice, prev, t_s))
        cur = prev
    lines.reverse()
    return lines
