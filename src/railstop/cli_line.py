"""``railstop line run``: many trains on the line, one clock (issue 14)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from railstop.cli_common import fail, out
from railstop.errors import RailstopError

line_app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="The line with many trains: fixed-block signalling, station stops by ground TASC, dwells.",
)


@line_app.command("run")
def run_cmd(
    trains: Annotated[
        int | None, typer.Option(min=1, max=200, help="Trains (default: the operation's).")
    ] = None,
    headway_s: Annotated[
        float | None,
        typer.Option(min=30.0, max=3600.0, help="Seconds between entries (default: the operation's)."),
    ] = None,
    duration_s: Annotated[float, typer.Option(min=1.0, max=86400.0, help="Simulated time (s).")] = 3600.0,
    seed: Annotated[int, typer.Option(help="Random seed of the disturbance draws.")] = 1,
    disturbances: Annotated[
        str, typer.Option(help="Disturbance set of every station stop: a built-in set or a TOML file.")
    ] = "nominal",
    plot: Annotated[Path | None, typer.Option(help="Write the time-distance diagram (PNG).")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    line: Annotated[
        Path | None, typer.Option("--line", help="Line TOML file (default: embedded line).")
    ] = None,
    vehicle: Annotated[
        Path | None, typer.Option("--vehicle", help="Vehicle TOML file (default: embedded EMU).")
    ] = None,
    operation: Annotated[
        Path | None, typer.Option("--operation", help="Operation TOML file (default: embedded).")
    ] = None,
) -> None:
    """Run the trains of the operation over the line: entries, running under the fixed-block
    signals, a station stop by ground TASC at every station, dwells; print the summary."""
    from railstop.config import load_line, load_vehicle
    from railstop.config.disturbances import load_disturbances
    from railstop.config.operation import load_operation
    from railstop.provenance import footer, inputs_sha256, stamp
    from railstop.sim.line import LineSimulation
    from railstop.streams import SEED_RANGE, seed_in_range

    if not seed_in_range(seed):
        fail(f"--seed: {SEED_RANGE} (got {seed})")
    try:
        ln = load_line(line)
        veh = load_vehicle(vehicle)
        op = load_operation(operation, ln)
        changes: dict[str, object] = {}
        if trains is not None:
            changes["trains"] = trains
            if op.entries_s is not None:
                fail("--trains: the operation file has a timetable (entries_s); edit it instead")
        if headway_s is not None:
            if op.entries_s is not None:
                fail("--headway-s: the operation file has a timetable (entries_s); edit it instead")
            changes["headway_s"] = headway_s
        if changes:
            op = op.model_validate({**op.model_dump(), **changes})
        dist = load_disturbances(disturbances)
        sim = LineSimulation(line=ln, vehicle=veh, operation=op, disturbances=dist, seed=seed)
        result = sim.run(duration_s)
        summary = result.summary()
        if plot is not None:
            from railstop.report.line_plot import plot_line

            prov = stamp(inputs_sha256(ln.model_dump(), veh.model_dump(), op.model_dump()))
            tph = summary["trains_per_hour"]
            title = (
                f"{ln.line.name}: {summary['exited']} of {op.trains} trains through"
                + (f" ({tph} trains/h)" if tph is not None else "")
                + f", {summary['stops']} stops by {op.controller} ({disturbances}), "
                f"{summary['dwell_faults']} dwell faults"
            )
            plot = plot_line(result, plot, title=title, footer=footer(prov, seed=seed))
    except RailstopError as exc:
        fail(str(exc))
    if as_json:
        print(json.dumps(summary))
        return
    out.print(
        f"{ln.line.name}: {summary['entered']} of {summary['trains']} trains entered, "
        f"{summary['exited']} left "
        f"the line in {duration_s:g} s ({summary['trains_per_hour']} trains/h, mean delay "
        f"{summary['mean_delay_s']} s, least separation {summary['min_separation_m']} m); "
        f"{summary['stops']} station stops by {op.controller}, {summary['stops_within_tolerance']} within "
        f"the PSD tolerance, p99 |error| {summary['stop_error_p99_m']} m, {summary['emergency_brakes']} "
        f"emergency brakes; mean dwell {summary['mean_dwell_s']} s, {summary['dwell_faults']} dwell faults; "
        f"simulated {summary['sim_to_wall']}x faster than real time",
        highlight=False,
        soft_wrap=True,
    )
    if plot is not None:
        out.print(f"plot: {plot}", highlight=False)
