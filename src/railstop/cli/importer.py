"""``railstop import railml``: a railML 2.x / 3.x file as a railstop line file."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from railstop.cli.common import VehicleOpt, command_group, fail, out

import_app = command_group("Import infrastructure data from other formats as railstop line files.")


@import_app.command(name="railml")
def railml(
    file: Annotated[Path, typer.Argument(help="The railML 2.x or 3.x file.", show_default=False)],
    out_file: Annotated[
        Path, typer.Option("--out", help="The line file to write (never over an existing file).")
    ] = Path("line.toml"),
    track: Annotated[
        list[str] | None,
        typer.Option(
            "--track",
            help="A track the trains run on, by its railML id; repeat in running order "
            "(default: the file's only track).",
            show_default=False,
        ),
    ] = None,
    vehicle: VehicleOpt = None,
    entry_speed_kmh: Annotated[
        float,
        typer.Option(
            "--entry-speed", min=5.0, max=120.0, help="TASC entry speed (km/h) where the line allows it."
        ),
    ] = 60.0,
) -> None:
    """Map a railML file's tracks, gradients, speed sections, signals, track circuits, platform
    edges and stop posts into a railstop line file, with a report of what was not mapped and
    what was assumed (also the head of the written file)."""
    from railstop.config.loader import load_vehicle, parse_toml, validate
    from railstop.config.plausibility import plausibility_problems
    from railstop.config.railml import import_railml, to_toml
    from railstop.config.schema import Line
    from railstop.errors import RailstopError

    if out_file.exists():
        fail(f"{out_file}: exists; railstop import never overwrites a file (choose another --out)")
    try:
        veh = load_vehicle(vehicle)
        imported = import_railml(file, veh, tracks=track, entry_speed_kmh=entry_speed_kmh)
        text = to_toml(imported, str(file))
        # The written file is read back as `railstop check` will read it: a mapping the schema
        # refuses is reported now and not written.
        line = validate(Line, parse_toml(text, str(out_file)), f"{file} -> {out_file}")
    except RailstopError as exc:
        fail(str(exc))
    try:
        out_file.parent.mkdir(parents=True, exist_ok=True)
        with out_file.open("x", encoding="utf-8") as fh:
            fh.write(text)
    except OSError as exc:
        fail(f"{exc.filename or out_file}: {exc.strerror}")
    out.print(
        f"railML {imported.version}: {file} -> {out_file}: line {line.line.name!r}, "
        f"{line.line.length_m:g} m, {len(line.stations)} stations "
        f"({', '.join(s.name for s in line.stations)})",
        highlight=False,
        soft_wrap=True,
    )
    for item in imported.report:
        out.print(f"  - {item}", highlight=False, soft_wrap=True)
    problems = plausibility_problems(line, veh, str(out_file))
    if problems:
        out.print(f"{len(problems)} problems for `railstop check` to fix by hand:", highlight=False)
        for p in problems:
            out.print(f"  - {p}", highlight=False, soft_wrap=True)
    else:
        out.print(f"next: railstop check --line {out_file}", highlight=False)
