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
from railstop.config.schema import FieldProblem, _Model
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
    doa: Bit
    dmc: Bit
    doc: Bit
    dcc: Bit
    closed: Literal["keep-closed", "open"]
    open: Literal["keep-open", "close"]
    open_manual: Literal["keep-open", "close"] | None = None


class DoorTiming(_Model):
    train_door_open_s: Seconds
    train_door_close_s: Seconds
    train_door_lock_s: Seconds
    psd_open_s: Seconds
    psd_close_s: Seconds
    psd_lock_s: Seconds
    zero_speed_confirm_s: Seconds
    psc_timeout_s: Seconds
    dwell_s: Seconds
    driver_action_s: Seconds
    obstruction_at_s: Seconds
    obstruction_clear_s: Seconds
    psd_jam_at_s: Seconds
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


class StopConfirmModel(_Model):
    max_psc_attempts: Annotated[int, Field(ge=1, le=10)] = 3
    tolerance: Literal["psd", "manual-line"] = "psd"
    psd_tolerance_m: Annotated[float, Field(gt=0.0, le=2.0, allow_inf_nan=False)] = 0.35
    manual_line_tolerance_m: Annotated[float, Field(gt=0.0, le=2.0, allow_inf_nan=False)] = 0.50
    creep_speed_kmh: Annotated[float, Field(gt=0.0, le=10.0, allow_inf_nan=False)]
    creep_max_m: Annotated[float, Field(gt=0.0, le=20.0, allow_inf_nan=False)]
    creep_settle_s: Seconds

    @property
    def tolerance_m(self) -> float:
        return self.psd_tolerance_m if self.tolerance == "psd" else self.manual_line_tolerance_m

    @property
    def creep_speed_mps(self) -> float:
        return kmh_to_mps(self.creep_speed_kmh)


class DoorLinkModel(_Model):
    """SPEC §5: the train <-> platform door link (DoorCommand up, PsdStatus down) as data."""

    # A preset of railstop/data/media.toml (loop, transponder, radio); checked where it is used.
    medium: Annotated[str, Field(min_length=1, max_length=64)] = "transponder"
    # EN 50159 category: 1 closed system (loop, transponder: security by range), 3 open (radio).
    category: Literal[1, 2, 3] = 1
    exchange_cycle_s: Annotated[float, Field(gt=0.0, le=5.0, allow_inf_nan=False)] = 0.1
    max_age_s: Annotated[float, Field(gt=0.0, le=10.0, allow_inf_nan=False)] = 0.3
    supervision_timeout_s: Annotated[float, Field(gt=0.0, le=30.0, allow_inf_nan=False)] = 0.5
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
    action_table: list[ActionRowModel]
    timing: DoorTiming
    stop_confirm: StopConfirmModel
    train: DoorLayout
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
