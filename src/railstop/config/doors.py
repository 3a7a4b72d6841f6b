"""Schema and loader of the door data (``railstop/data/doors.toml``, SPEC §3 and §5).

The schema checks structure (16 distinct rows, valid cells, positive times,
PSD faster than train doors); it deliberately does not check the safety of
the action table: ``railstop doors verify --doors FILE`` proves or refutes an
edited table by exhaustive search.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from types import MappingProxyType
from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from railstop.config.loader import data_text, read_toml, validate
from railstop.config.schema import FieldProblem, Station, Vehicle, _Model
from railstop.errors import ConfigError
from railstop.quantities import kmh_to_mps

DEFAULT_DOORS = "doors.toml"

# SPEC §5 Table 1, the door action table, as the units read it: the 16 rows of the data file as they
# are (``railstop doors verify`` proves or refutes them), with the one reading of them (``decide``).


class Action(StrEnum):
    """The cells of SPEC §5 Table 1."""

    KEEP_CLOSED = "keep-closed"
    OPEN = "open"
    KEEP_OPEN = "keep-open"
    CLOSE = "close"


Signals4 = tuple[int, int, int, int]  # (DOA, DMC, DOC, DCC) of one side, 0 or 1


@dataclass(frozen=True, slots=True, kw_only=True)
class ActionRow:
    """One row of SPEC §5 Table 1: what a closed door and an open door do for these signals."""

    doa: int
    dmc: int
    doc: int
    dcc: int
    closed: Action  # keep-closed | open
    open: Action  # keep-open | close
    open_manual: Action | None = None  # manual driving, where it differs from ``open``

    @property
    def key(self) -> Signals4:
        return (self.doa, self.dmc, self.doc, self.dcc)


@dataclass(frozen=True, slots=True)
class ActionTable:
    """SPEC §5 Table 1 as data: all 16 combinations of (DOA, DMC, DOC, DCC), used as they are.

    ``decide`` is the only reading of the table: a door in the "closed"
    column gets ``open`` or nothing, a door in the "open" column gets
    ``close`` or nothing ("keep" = no command: a moving door finishes its move).
    """

    rows: tuple[ActionRow, ...]
    _lookup: Mapping[tuple[int, int, int, int, bool, bool], Action] = field(
        init=False, repr=False, compare=False
    )

    def __post_init__(self) -> None:
        keys = [r.key for r in self.rows]
        expected = {(a, b, c, d) for a in (0, 1) for b in (0, 1) for c in (0, 1) for d in (0, 1)}
        if len(keys) != 16 or set(keys) != expected:
            raise ConfigError(
                "door action table", "rows", "need the 16 combinations of (DOA, DMC, DOC, DCC) once each"
            )
        lookup: dict[tuple[int, int, int, int, bool, bool], Action] = {}
        for r in self.rows:
            if r.closed not in (Action.KEEP_CLOSED, Action.OPEN):
                raise ConfigError(
                    "door action table", f"{r.key}.closed", "must be open or keep-closed", r.closed
                )
            for manual in (False, True):
                when_open = r.open_manual if (manual and r.open_manual is not None) else r.open
                if when_open not in (Action.KEEP_OPEN, Action.CLOSE):
                    raise ConfigError(
                        "door action table", f"{r.key}.open", "must be close or keep-open", when_open
                    )
                lookup[(*r.key, True, manual)] = r.closed
                lookup[(*r.key, False, manual)] = when_open
        object.__setattr__(self, "_lookup", MappingProxyType(lookup))

    def decide(self, doa: bool, dmc: bool, doc: bool, dcc: bool, *, closed: bool, manual: bool) -> Action:
        """What a door does for these signals (``closed``: the door is now closed)."""
        return self._lookup[(int(doa), int(dmc), int(doc), int(dcc), closed, manual)]

    def row(self, doa: int, dmc: int, doc: int, dcc: int) -> ActionRow:
        for r in self.rows:
            if r.key == (doa, dmc, doc, dcc):
                return r
        raise KeyError((doa, dmc, doc, dcc))  # pragma: no cover - __post_init__ guarantees all 16

    def replace_row(self, new: ActionRow) -> ActionTable:
        """A copy with the row of ``new.key`` replaced (what-if tables, broken tables in tests)."""
        return ActionTable(tuple(new if r.key == new.key else r for r in self.rows))


Bit = Literal[0, 1]
Seconds = Annotated[float, Field(gt=0.0, le=600.0, allow_inf_nan=False)]


class ActionRowModel(_Model):
    # SPEC §5 Table 1: the row's DOA signal, 0 or 1 (manual driving: the door-side selector).
    doa: Bit
    # The row's DMC signal, 0 or 1: an ATC output in both modes, wired with the zero velocity relay.
    dmc: Bit
    # The row's DOC signal, 0 or 1 (manual driving: the door-open button).
    doc: Bit
    # The row's DCC signal, 0 or 1 (manual driving: the door-close button).
    dcc: Bit
    # What a door that is now closed does for these signals: "open" or "keep-closed" (no command).
    closed: Literal["keep-closed", "open"]
    # What a door that is now open does: "close" or "keep-open" (no command: a moving door finishes).
    open: Literal["keep-open", "close"]
    # The same in manual driving, where it differs from open (None: as open).
    open_manual: Literal["keep-open", "close"] | None = None


class DoorTiming(_Model):
    # How long a train door takes to open.
    train_door_open_s: Seconds
    # How long a train door takes to close.
    train_door_close_s: Seconds
    # How long a closed train door takes to lock; the camera's lock_confirm_s of the platform data
    # must be at least this.
    train_door_lock_s: Seconds
    # How long a platform screen door unit takes to open (SPEC §3: faster than a train door).
    psd_open_s: Seconds
    # How long a PSD unit takes to close (SPEC §3: faster than a train door).
    psd_close_s: Seconds
    # How long a closed PSD unit takes to lock.
    psd_lock_s: Seconds
    # The zero velocity relay confirms standstill this long after the wheels stop; then the stop
    # confirmation (SPEC §5 PSC request) starts.
    zero_speed_confirm_s: Seconds
    # SPEC §5: no PSC reply from the WPCS within this long after the request = not in position
    # (at least two link exchange cycles).
    psc_timeout_s: Seconds
    # The dwell proper: from the doors fully open to the close command.
    dwell_s: Seconds
    # Manual driving: the driver acts on a lamp or a door button this long after it lights (or the
    # stop is confirmed).
    driver_action_s: Seconds
    # Fault injection (railstop dwell --obstruct-door): the door is obstructed this long into its
    # closing, inside train_door_close_s; it reopens and holds.
    obstruction_at_s: Seconds
    # The obstacle is cleared this long after the door was obstructed.
    obstruction_clear_s: Seconds
    # Fault injection (railstop dwell --psd-fail): the PSD unit jams this long into its closing,
    # inside psd_close_s.
    psd_jam_at_s: Seconds
    # Staff isolate a jammed PSD unit (or close by hand one the camera holds open) this long after.
    staff_isolation_s: Seconds

    @model_validator(mode="after")
    def _order(self) -> DoorTiming:
        # SPEC §3: PSD doors open and close faster than train doors.
        if self.psd_open_s >= self.train_door_open_s:
            raise FieldProblem(
                "psd_open_s", f"the PSD must open faster than the train doors ({self.train_door_open_s} s)"
            )
        if self.psd_close_s >= self.train_door_close_s:
            raise FieldProblem(
                "psd_close_s", f"the PSD must close faster than the train doors ({self.train_door_close_s} s)"
            )
        if self.obstruction_at_s >= self.train_door_close_s:
            raise FieldProblem(
                "obstruction_at_s", f"must fall inside the closing ({self.train_door_close_s} s)"
            )
        if self.psd_jam_at_s >= self.psd_close_s:
            raise FieldProblem("psd_jam_at_s", f"must fall inside the PSD closing ({self.psd_close_s} s)")
        return self


#: The most doors a side a car may have (``DoorsConfig.check_vehicle``).
MAX_DOORS_PER_CAR = 6
#: The PSD tolerance of a dwell where no station says one (a station's default too: SPEC §1).
DEFAULT_PSD_TOLERANCE_M = 0.35


class StopConfirmModel(_Model):
    # SPEC §5 precise-stop confirmation: after this many PSC requests that time out, fault and
    # emergency brake.
    max_psc_attempts: Annotated[int, Field(ge=1, le=10)] = 3
    # Which stop tolerance the WPCS accepts (it answers PSC only for a train inside it): "psd" =
    # psd_tolerance_m, "manual-line" = manual_line_tolerance_m.
    tolerance: Literal["psd", "manual-line"] = "psd"
    # SPEC §1: the stop tolerance of a line with PSD (±0.35 m for the Korean metro). One tolerance
    # per station: a dwell at a station takes the station's psd_tolerance_m from the line file;
    # left out here (the embedded file does), a value given must equal it (else an error naming
    # both files). It serves alone only where no station is known (``doors verify``).
    psd_tolerance_m: Annotated[float, Field(gt=0.0, le=2.0, allow_inf_nan=False)] | None = None
    # SPEC §3: the door / PSD stop tolerance of the manually driven lines (±500 mm).
    manual_line_tolerance_m: Annotated[float, Field(gt=0.0, le=2.0, allow_inf_nan=False)] = 0.50
    # Position correction (SPEC §5, lamps F / R of SPEC §3): the train creeps towards the stopping
    # point at this speed.
    creep_speed_kmh: Annotated[float, Field(gt=0.0, le=10.0, allow_inf_nan=False)]
    # The longest creep of one correction: it moves by the stop error, at most this.
    creep_max_m: Annotated[float, Field(gt=0.0, le=20.0, allow_inf_nan=False)]
    # After the creep, the time to brake to a stand before the zero velocity relay's confirmation.
    creep_settle_s: Seconds
    # SPEC §5 (SPEC §3 lamps F / R): the creep is a short stop of its own and lands with the stop's
    # inaccuracy: normal(0, this) about the stopping point, drawn per creep ([interpretation], see
    # doors.toml); 0: the creep lands exactly.
    creep_stop_sd_m: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] = 0.08

    @property
    def tolerance_m(self) -> float:
        if self.tolerance == "manual-line":
            return self.manual_line_tolerance_m
        return DEFAULT_PSD_TOLERANCE_M if self.psd_tolerance_m is None else self.psd_tolerance_m

    @property
    def creep_speed_mps(self) -> float:
        return kmh_to_mps(self.creep_speed_kmh)


class DoorLinkModel(_Model):
    """SPEC §5: the train <-> platform door link (DoorCommand up, PsdStatus down) as data."""

    # A preset of railstop/data/media.toml (loop, transponder, radio); checked where it is used.
    medium: Annotated[str, Field(min_length=1, max_length=64)] = "transponder"
    # EN 50159 category: 1 closed system (loop, transponder: security by range), 3 open (radio).
    category: Literal[1, 2, 3] = 1
    # While PSC is requested or high, each end sends its telegram (door-command up, psd-status down)
    # once per this cycle.
    exchange_cycle_s: Annotated[float, Field(gt=0.0, le=5.0, allow_inf_nan=False)] = 0.1
    # The receivers refuse a frame older than this (EN 50159 delay).
    max_age_s: Annotated[float, Field(gt=0.0, le=10.0, allow_inf_nan=False)] = 0.3
    # With PSC high, no valid frame for this long = the link is lost: the train faults and brakes,
    # the WPCS holds the PSD as it is (at least two exchange cycles).
    supervision_timeout_s: Annotated[float, Field(gt=0.0, le=30.0, allow_inf_nan=False)] = 0.5
    # The WPCS checks its stop sensors for this long before it answers a PSC request.
    wpcs_processing_s: Annotated[float, Field(ge=0.0, le=5.0, allow_inf_nan=False)] = 0.05

    @model_validator(mode="after")
    def _order(self) -> DoorLinkModel:
        # One lost frame must not trip the supervision: at least two exchange cycles.
        if self.supervision_timeout_s < 2 * self.exchange_cycle_s:
            raise FieldProblem(
                "supervision_timeout_s",
                f"must be at least two exchange cycles ({2 * self.exchange_cycle_s:g} s)",
            )
        return self


class DoorLayout(_Model):
    # The door link's telegrams name each door facing the platform by one bit, 24 at most
    # (link.codec.MAX_DOOR_UNITS: a 6-car train with 4 doors a car).
    doors_per_side: Annotated[int, Field(ge=1, le=24)]


class DoorsFile(_Model):
    # SPEC §5 Table 1: the 16 rows, one per combination of (DOA, DMC, DOC, DCC), used as written
    # (railstop doors verify proves or refutes an edited table).
    action_table: list[ActionRowModel]
    # The door, PSD and dwell timings.
    timing: DoorTiming
    # SPEC §5 precise-stop confirmation (PSC) and the position correction.
    stop_confirm: StopConfirmModel
    # The train's door layout.
    train: DoorLayout
    # SPEC §5: the train <-> platform door link (door-command up, psd-status down).
    link: DoorLinkModel = DoorLinkModel()

    @model_validator(mode="after")
    def _psc_window(self) -> DoorsFile:
        # A PSC request must see at least two exchanges before it times out.
        cycle = self.link.exchange_cycle_s
        if self.timing.psc_timeout_s < 2 * cycle:
            raise FieldProblem(
                "timing.psc_timeout_s", f"must be at least two link exchange cycles ({2 * cycle:g} s)"
            )
        return self

    @field_validator("action_table")
    @classmethod
    def _sixteen(cls, rows: list[ActionRowModel]) -> list[ActionRowModel]:
        seen: dict[tuple[int, int, int, int], int] = {}
        for i, r in enumerate(rows):
            key = (r.doa, r.dmc, r.doc, r.dcc)
            if key in seen:
                raise ValueError(
                    f"row {i} repeats (DOA, DMC, DOC, DCC) = {key} of row {seen[key]}; "
                    "each of the 16 combinations must appear once"
                )
            seen[key] = i
        if len(rows) != 16:
            raise ValueError(f"need the 16 combinations of (DOA, DMC, DOC, DCC), got {len(rows)} rows")
        return rows


class DoorsConfig:
    """The validated door data plus the action table object the units read."""

    def __init__(self, file: DoorsFile, source: str) -> None:
        self.file = file
        self.source = source
        self.timing = file.timing
        self.stop_confirm = file.stop_confirm
        self.doors_per_side = file.train.doors_per_side
        self.link = file.link
        self.actions = ActionTable(
            tuple(
                ActionRow(
                    doa=r.doa,
                    dmc=r.dmc,
                    doc=r.doc,
                    dcc=r.dcc,
                    closed=Action(r.closed),
                    open=Action(r.open),
                    open_manual=None if r.open_manual is None else Action(r.open_manual),
                )
                for r in file.action_table
            )
        )

    def with_dwell(self, dwell_s: float) -> DoorsConfig:
        """The same door data with the doors standing open for ``dwell_s`` (an operation's dwell)."""
        timing = self.file.timing.model_copy(update={"dwell_s": dwell_s})
        return DoorsConfig(self.file.model_copy(update={"timing": timing}), self.source)

    def at_station(self, station: Station, line_source: str) -> DoorsConfig:
        """The door data of a dwell at ``station``: its PSD tolerance is the station's
        ``psd_tolerance_m`` (one tolerance per station judges the stop, the dwell and the report).
        A doors file that gives its own, different, is refused naming both files."""
        sc = self.file.stop_confirm
        mine = sc.psd_tolerance_m
        if mine is not None and mine != station.psd_tolerance_m:
            raise ConfigError(
                self.source,
                "stop_confirm.psd_tolerance_m",
                f"differs from station {station.name!r}'s psd_tolerance_m ({station.psd_tolerance_m:g} m in "
                f"{line_source}): one tolerance per station; leave it out of the doors file",
                mine,
            )
        if mine == station.psd_tolerance_m:
            return self
        stop = sc.model_copy(update={"psd_tolerance_m": station.psd_tolerance_m})
        return DoorsConfig(self.file.model_copy(update={"stop_confirm": stop}), self.source)

    def check_vehicle(self, vehicle: Vehicle, vehicle_source: str) -> None:
        """The door layout must be the train's: 1 to ``MAX_DOORS_PER_CAR`` doors a side per car
        ([interpretation]: a metro car has 2 to 5; one door unit per PSD unit, SPEC §5). A
        ConfigError naming both files otherwise."""
        n, cars = self.doors_per_side, vehicle.cars
        if not cars <= n <= MAX_DOORS_PER_CAR * cars:
            raise ConfigError(
                self.source,
                "train.doors_per_side",
                f"{n} doors a side for the {cars} cars of {vehicle.name!r} ({vehicle_source}): a car has "
                f"1 to {MAX_DOORS_PER_CAR} doors a side",
                n,
            )

    def fingerprint(self) -> str:
        """A short stable digest of the data (part of a dwell's database key)."""
        text = self.file.model_dump_json()
        return hashlib.sha256(text.encode()).hexdigest()[:12]


def load_doors(path: str | Path | None = None) -> DoorsConfig:
    """Load a door data file; ``None`` gives the embedded default."""
    if path is None:
        source, data = data_text(DEFAULT_DOORS)
    else:
        source, data = str(path), read_toml(Path(path))
    return DoorsConfig(validate(DoorsFile, data, source), source)
