"""``railstop check``: a line file (and a vehicle and an operation file) validated."""

from __future__ import annotations

from typing import Annotated

import typer

from railstop.cli.common import LineOpt, OperationOpt, VehicleOpt, fail, out, print_error
from railstop.errors import RailstopError


def check(
    line: LineOpt = None,
    vehicle: VehicleOpt = None,
    operation: OperationOpt = None,
    disturbances: Annotated[
        str | None,
        typer.Option(
            help="Also say which stations' zones a campaign under this disturbance set (standard, "
            "wide, ... or a TOML file) reaches beyond: faster entries or steeper approaches than "
            "the zone is laid out for."
        ),
    ] = None,
) -> None:
    """Validate a line file (and optionally a vehicle and an operation file)."""
    from railstop.config import load_line, load_vehicle
    from railstop.config.disturbances import load_disturbances
    from railstop.config.loader import line_source
    from railstop.config.operation import load_operation
    from railstop.config.plausibility import envelope_note, plausibility_problems

    try:
        ln = load_line(line)
        veh = load_vehicle(vehicle)
        # The embedded operation names the embedded line's stations: a line of one's own is
        # judged on its own unless an operation file for it is given too.
        op = load_operation(operation, ln) if operation is not None or line is None else None
        dist = load_disturbances(disturbances) if disturbances is not None else None
    except RailstopError as exc:
        fail(str(exc))
    problems = plausibility_problems(ln, veh, line_source(line))
    if problems:  # every one, a line each
        for problem in problems[:-1]:
            print_error(str(problem))
        fail(str(problems[-1]))
    src = str(line) if line else "embedded default line"
    blocks = len(ln.signalling.blocks) if ln.signalling is not None else 0
    if op is None:
        service = "operation: none given (--operation FILE checks one against this line)"
    else:
        entry = (
            f"every {op.headway_s:g} s"
            if op.entries_s is None
            else f"at {len(op.entries_s)} timetabled times"
        )
        service = f"operation: {op.trains} trains {entry} ({op.controller})"
    out.print(
        f"ok: {src}: line {ln.line.name!r}, {len(ln.stations)} stations "
        f"({', '.join(s.name for s in ln.stations)}), {len(ln.segments)} segments, {blocks} blocks; "
        f"vehicle {veh.name!r}; {service}",
        highlight=False,
        soft_wrap=True,
    )
    if dist is not None:
        notes = [n for st in ln.stations if (n := envelope_note(st, veh, dist)) is not None]
        for note in notes:
            out.print(f"note: {note}", highlight=False, soft_wrap=True)
        if not notes:
            out.print(f"every zone is laid out for the {dist.name!r} set", highlight=False, soft_wrap=True)
