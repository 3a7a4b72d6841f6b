"""The operation of a line: which trains run, when they enter, how long they dwell.

An operation file (TOML, the embedded default ``railstop/data/operation/default.toml``)
is checked against the line it runs on: every station it names must exist.
Trains enter at the line's start (chainage ``entry_m``) at ``entry_speed_kmh``,
one every ``headway_s`` from ``first_entry_s``, or at the times of
``entries_s`` (a timetable), and when the first block is clear; they stop at
every station by the ``controller``, dwell, and leave the line at its end.
**[interpretation]** the source documents describe stations and links, not a
timetable; a regular headway is the usual way to load a metro line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from pydantic import Field, model_validator

from railstop.config.base import FieldProblem, FiniteFloat, Model, NonNegFloat
from railstop.config.loader import data_text, read_toml, validate
from railstop.config.schema import Line
from railstop.controllers import known_controllers
from railstop.errors import ConfigError

DEFAULT_OPERATION = "operation/default.toml"


class StationDwell(Model):
    """A station's dwell, where it differs from the operation's default."""

    # The station, as the line names it (any case); an unknown name is refused.
    name: Annotated[str, Field(min_length=1, max_length=64)]
    # The dwell at this station instead of the operation's dwell_s.
    dwell_s: Annotated[float, Field(ge=5.0, le=600.0, allow_inf_nan=False)]


class Operation(Model):
    # What this operation is for; for the reader, the simulation does not use it.
    description: Annotated[str, Field(max_length=200)] = ""
    # How many trains enter the line (numbered 0, 1, ... in order of entry).
    trains: Annotated[int, Field(ge=1, le=200)] = 12
    # The time between two trains' entries (unless entries_s gives a timetable).
    headway_s: Annotated[float, Field(ge=30.0, le=3600.0, allow_inf_nan=False)] = 120.0
    # When the first train asks to enter; the k-th asks at first_entry_s + k x headway_s.
    first_entry_s: NonNegFloat = 0.0
    # A timetable instead of the headway: the entry times (s), one per train, increasing.
    entries_s: list[NonNegFloat] | None = None
    # How the trains stop at every station: a controller of the station stop or a law loaded with
    # --law.
    controller: str = "tasc-pwm"
    # Where the trains enter (chainage): on the line and before the first station's platform.
    entry_m: FiniteFloat = 0.0
    # The speed at which a train enters, at most the line's speed limit.
    entry_speed_kmh: Annotated[float, Field(gt=0.0, le=200.0, allow_inf_nan=False)] = 60.0
    # How well a train knows its position as it enters (standard deviation): it comes from the
    # section before (a terminal platform or the depot's transfer track) with its position
    # fixed there. [interpretation] within a platform stop's tolerance, about 0.3 m.
    entry_position_sd_m: Annotated[float, Field(ge=0.0, le=50.0, allow_inf_nan=False)] = 0.3
    # The dwell at a station: doors open, passengers, doors closed (SPEC §5's sequence runs
    # within it); per station where it differs.
    dwell_s: Annotated[float, Field(ge=5.0, le=600.0, allow_inf_nan=False)] = 30.0
    # The stations whose dwell differs from dwell_s, each at most once.
    stations: list[StationDwell] = Field(default_factory=list)

    @model_validator(mode="after")
    def _check(self) -> Operation:
        if self.controller not in known_controllers():
            known = ", ".join(known_controllers())
            raise FieldProblem(
                "controller", f"unknown controller; choose one of: {known} (or a law of --law)"
            )
        if self.entries_s is not None:
            if len(self.entries_s) != self.trains:
                raise FieldProblem(
                    "entries_s", f"one entry time per train: {len(self.entries_s)} for {self.trains} trains"
                )
            if any(b <= a for a, b in zip(self.entries_s, self.entries_s[1:], strict=False)):
                raise FieldProblem("entries_s", "entry times must increase")
        # Names match the line's stations in any case (dwell_at_s, load_operation): "Bravo" and
        # "bravo" are the same station, whose second dwell would be silently ignored.
        first: dict[str, int] = {}
        for i, s in enumerate(self.stations):
            j = first.setdefault(s.name.lower(), i)
            if j != i:
                same = "" if self.stations[j].name == s.name else " (names match in any case)"
                raise FieldProblem(
                    f"stations[{i}].name",
                    f"a station's dwell is given twice: also stations[{j}] {self.stations[j].name!r}{same}",
                )
        return self

    def entry_times_s(self) -> list[float]:
        """When each train enters the line (its request; the first block must be clear too)."""
        if self.entries_s is not None:
            return list(self.entries_s)
        return [self.first_entry_s + k * self.headway_s for k in range(self.trains)]

    def dwell_at_s(self, station: str) -> float:
        for s in self.stations:
            if s.name.lower() == station.lower():
                return s.dwell_s
        return self.dwell_s


def operation_source(path: str | Path | None) -> str:
    """How messages name an operation file (``None``: the embedded default)."""
    return f"railstop/data/{DEFAULT_OPERATION}" if path is None else str(path)


def load_operation(path: str | Path | None, line: Line) -> Operation:
    """Load an operation file (``None``: the embedded default) and check it against ``line``."""
    if path is None:
        source, data = data_text(DEFAULT_OPERATION)
    else:
        source, data = str(path), read_toml(Path(path))
        if not data:
            # An empty file (or comments only) is not the embedded operation: a file given names
            # what runs, and a silent 12 trains every 120 s is not what its author meant.
            raise ConfigError(source, "(file)", "the file is empty: give at least trains or headway_s")
    op = validate(Operation, data, source)
    known = {s.name.lower() for s in line.stations}
    for i, s in enumerate(op.stations):
        if s.name.lower() not in known:
            hint = (
                "; the embedded operation is the embedded line's: give --operation FILE for this line "
                "(railstop init DIR writes one to edit)"
                if path is None
                else ""
            )
            raise ConfigError(
                source,
                f"stations[{i}].name",
                f"no such station on line {line.line.name!r} ({', '.join(st.name for st in line.stations)})"
                + hint,
                s.name,
            )
    first = line.stations[0]
    if op.entry_m >= first.platform_start:
        raise ConfigError(
            source,
            "entry_m",
            f"trains must enter before the first station's platform ({first.name}, {first.platform_start} m)",
            op.entry_m,
        )
    end = line.line.length_m if line.line.length_m is not None else line.track.end_m
    if op.entry_m < 0.0 or (end is not None and op.entry_m >= end):
        raise ConfigError(source, "entry_m", f"not on the line (0 .. {end} m)", op.entry_m)
    if op.entry_speed_kmh > line.line.speed_limit_kmh:
        raise ConfigError(
            source,
            "entry_speed_kmh",
            f"above the line's speed limit ({line.line.speed_limit_kmh} km/h)",
            op.entry_speed_kmh,
        )
    return op
